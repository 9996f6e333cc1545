"""``lcmesh router``: a zenoh router (the mesh's hub) listening on ``LCMESH_LISTEN_ENDPOINTS``.

Agents connect to it as clients. Scale-out: a second router on another host links to the first
with ``LCMESH_ROUTER_PEERS`` and its local agents connect to it; zenoh routes between the two.
Run as ``python -m lcmesh.mesh.router`` or ``lcmesh router``.
"""

from __future__ import annotations

import logging
import sys

from lcmesh.mesh.bus import Bus, BusError
from lcmesh.mesh.processes import stop_on_signals
from lcmesh.mesh.settings import MeshSettings

log = logging.getLogger("lcmesh.mesh.router")
ROUTER_STOP_GRACE_S = 10.0


def run_router(settings: MeshSettings | None = None) -> int:
    """Serve until SIGTERM/SIGINT; exit 3 if the listen endpoint can not be opened."""
    settings = settings or MeshSettings()
    logging.basicConfig(level=getattr(logging, settings.log_level.upper(), logging.INFO),
                        format="%(asctime)s router %(levelname)s %(name)s: %(message)s")  # fmt: skip
    stop = stop_on_signals(ROUTER_STOP_GRACE_S, "router")  # the router keeps no state: a hung stop ends it soon
    held = [m for m in map(_held, settings.listen_endpoints) if m]
    if held:  # zenoh's own error says only "Address already in use"; name the holder and how to stop it
        log.error("the router can not listen: %s", "; ".join(held))
        return 3
    try:
        bus = Bus.open_router(settings)
    except BusError as exc:
        log.error("%s", exc)
        return 3
    peers = f", linked to {', '.join(settings.router_peers)}" if settings.router_peers else ""
    log.info("router listening on %s%s", ", ".join(settings.listen_endpoints), peers)
    # a timed wait: a signal that lands on one of zenoh's threads does not interrupt an untimed one, and the
    # handler (which only runs on the main thread) would then wait for the next signal
    while not stop.wait(0.5):
        pass
    bus.close()
    log.info("router stopped")
    return 0


def _held(endpoint: str) -> str | None:
    """Who holds a tcp endpoint's port (None if free, or not tcp)."""
    from lcmesh.mesh.processes import tcp_host_port
    from lcmesh.mesh.service import port_held_message

    if not endpoint.startswith("tcp/"):
        return None
    return port_held_message(tcp_host_port(endpoint)[1], "the router")


if __name__ == "__main__":
    from lcmesh.mesh.processes import tie_to_parent

    tie_to_parent()  # started by a demo: end with it, however it ends
    sys.exit(run_router())

"""``lcmesh router``: a zenoh router (the mesh's hub) listening on ``LCMESH_LISTEN_ENDPOINTS``.

Agents connect to it as clients. Scale-out: a second router on another host links to the first
with ``LCMESH_ROUTER_PEERS`` and its local agents connect to it; zenoh routes between the two.
Run as ``python -m lcmesh.mesh.router`` or ``lcmesh router``.
"""

from __future__ import annotations

import logging
import signal
import sys
import threading

from lcmesh.mesh.bus import Bus, BusError
from lcmesh.mesh.settings import MeshSettings

log = logging.getLogger("lcmesh.mesh.router")


def run_router(settings: MeshSettings | None = None) -> int:
    """Serve until SIGTERM/SIGINT; exit 3 if the listen endpoint can not be opened."""
    settings = settings or MeshSettings()
    logging.basicConfig(level=getattr(logging, settings.log_level.upper(), logging.INFO),
                        format="%(asctime)s router %(levelname)s %(name)s: %(message)s")  # fmt: skip
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    try:
        bus = Bus.open_router(settings)
    except BusError as exc:
        log.error("%s", exc)
        return 3
    peers = f", linked to {', '.join(settings.router_peers)}" if settings.router_peers else ""
    log.info("router listening on %s%s", ", ".join(settings.listen_endpoints), peers)
    stop.wait()
    bus.close()
    log.info("router stopped")
    return 0


if __name__ == "__main__":
    sys.exit(run_router())

"""Run one agent as a process: connect (with retry), start, wait for SIGTERM/SIGINT, stop cleanly."""

from __future__ import annotations

import gc
import logging
import sys
import threading

from lcmesh.mesh import keys
from lcmesh.mesh.agents.registry import load_agent_class
from lcmesh.mesh.bus import Bus, BusError
from lcmesh.mesh.processes import exit_if_stuck, stop_on_signals
from lcmesh.mesh.settings import MeshSettings

log = logging.getLogger("lcmesh.mesh.agents")
EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT, EXIT_NO_ROUTER = 0, 1, 2, 3
# a stop that has not ended the agent by then ends it anyway: above the orchestrator's stop of its agents (asked
# at once, each given `stop_timeout_s`, default 5 s), below the 60 s a test or `lcmesh stop` waits
AGENT_STOP_GRACE_S = 30.0
# told to stop while it still starts (a model loading, a GGUF merging, the twin spinning up): nothing to hand over
# yet, so the forced exit comes sooner
STARTING_STOP_GRACE_S = 5.0
GIL_SWITCH_INTERVAL_S = 0.0005  # a bus callback waits at most this for a busy thread to yield (default 5 ms)


def setup_logging(settings: MeshSettings, name: str) -> None:
    logging.basicConfig(
        level=getattr(logging, settings.log_level.upper(), logging.INFO),
        format=f"%(asctime)s {name} %(levelname)s %(name)s: %(message)s",
    )


def stop_signals(agent_id: str, stop_event: threading.Event) -> tuple[threading.Event, threading.Event]:
    """(`stop_event`, set by SIGTERM/SIGINT; `started`, to set once the agent runs): a signal before `started`
    forces the exit after ``STARTING_STOP_GRACE_S`` if the start does not end by itself, after it
    ``AGENT_STOP_GRACE_S``."""
    started = threading.Event()

    def grace_s() -> float:
        return AGENT_STOP_GRACE_S if started.is_set() else STARTING_STOP_GRACE_S

    return stop_on_signals(grace_s, agent_id, EXIT_FAILED, event=stop_event), started


def run_agent(role: str, settings: MeshSettings | None = None, agent_id: str | None = None) -> int:
    """Run `role` until SIGTERM/SIGINT (exit 0) or a fatal error (non-zero)."""
    settings = settings or MeshSettings()
    agent = load_agent_class(role)(settings, agent_id)
    setup_logging(settings, agent.agent_id)
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    # the agent's own stop event: a SIGTERM during its start-up (the Sensor's spin-up) is seen there too
    stop, started = stop_signals(agent.agent_id, agent.stop_event)
    try:
        bus = Bus.connect(settings, agent.agent_id, role=agent.role)
    except BusError as exc:
        log.error("%s", exc)
        return EXIT_NO_ROUTER
    if stop.is_set():  # told to stop while it connected
        bus.close()
        return EXIT_OK
    try:
        try:
            agent.start(bus)
        except Exception:
            log.exception("%s %s could not start", role, agent.agent_id)
            agent.stop()
            return EXIT_BAD_INPUT
        started.set()
        gc.collect()
        gc.freeze()  # what start-up built stays out of later collections: shorter GC pauses in the loop
        while not stop.wait(0.2):
            if agent.failed.is_set():
                break
        if not stop.is_set():  # a failed agent stops on its own: the same limit
            exit_if_stuck(AGENT_STOP_GRACE_S, agent.agent_id, EXIT_FAILED)
        agent.stop()
    finally:
        bus.close()
    return EXIT_FAILED if agent.failed.is_set() else EXIT_OK


def check_agent(role: str, settings: MeshSettings | None = None, agent_id: str | None = None,
                timeout_s: float = 3.0) -> list[str]:  # fmt: skip
    """Liveliness tokens of `role` (one agent id, or any) on the mesh; a healthcheck."""
    settings = settings or MeshSettings()
    bus = Bus.connect(settings, "healthcheck", role=role, timeout_s=min(timeout_s, settings.connect_timeout_s))
    try:
        key = keys.alive(settings.site, role, agent_id) if agent_id else keys.alive_role(settings.site, role)
        return bus.alive(key, timeout_s=timeout_s)
    finally:
        bus.close()

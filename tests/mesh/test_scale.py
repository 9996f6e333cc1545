"""Scale-out on loopback: two linked routers as two hosts, and several sites on one mesh."""

from __future__ import annotations

from lcmesh.mesh import keys
from lcmesh.mesh.agents.configuration import ConfigurationAgent
from lcmesh.mesh.agents.control import ControlAgent
from lcmesh.mesh.agents.sensor import SensorAgent
from lcmesh.mesh.bus import Bus
from lcmesh.mesh.history import HistoryReader
from lcmesh.mesh.messages import AppliedAction
from tests.mesh.conftest import free_port, make_settings, wait_until


def _start(agents, cls, settings):
    agent = cls(settings)
    bus = Bus.connect(settings, agent.agent_id)
    agent.start(bus)
    agents.append((agent, bus))
    return agent


def _stop(agents, routers):
    for agent, bus in reversed(agents):
        agent.stop()
        bus.close()
    for router in routers:
        router.close()


def test_two_linked_routers_carry_the_control_loop_between_hosts(tmp_path):
    port_a, port_b = free_port(), free_port()
    host_a = make_settings(tmp_path, port_a)
    host_b = host_a.model_copy(update={"router_endpoints": [f"tcp/127.0.0.1:{port_b}"],
                                       "listen_endpoints": [f"tcp/127.0.0.1:{port_b}"],
                                       "router_peers": [f"tcp/127.0.0.1:{port_a}"]})  # fmt: skip
    routers = [Bus.open_router(host_a), Bus.open_router(host_b)]
    agents = []
    try:
        _start(agents, ConfigurationAgent, host_a)
        sensor = _start(agents, SensorAgent, host_a)
        control = _start(agents, ControlAgent, host_b)  # on the other "host"
        assert wait_until(lambda: sensor.tally["proposals_applied"] >= 10, 30), sensor.tally
        assert control.config_doc is not None, "the Configuration agent on host A answered host B"
        watcher = Bus.connect(host_b, "watcher")
        try:
            tokens = watcher.alive(keys.alive_all(host_a.site))
        finally:
            watcher.close()
        assert {keys.parse_alive(t)[1] for t in tokens} >= {"sensor", "control", "configuration"}
    finally:
        _stop(agents, routers)


def test_sites_share_one_mesh_without_crosstalk(tmp_path):
    port = free_port()
    site_a = make_settings(tmp_path / "a", port, site="plant-a", controller="g36")
    site_b = make_settings(tmp_path / "b", port, site="plant-b", controller="static",
                           secrets_dir=site_a.secrets_path)  # one mesh, one router: its passwords  # fmt: skip
    routers = [Bus.open_router(site_a)]
    agents = []
    seen: dict[str, list[AppliedAction]] = {"plant-a": [], "plant-b": []}
    try:
        for settings in (site_a, site_b):
            _start(agents, ControlAgent, settings)
        sensors = [_start(agents, SensorAgent, s) for s in (site_a, site_b)]
        watcher = Bus.connect(site_a, "watcher")
        agents.append((type("Noop", (), {"stop": lambda self: None})(), watcher))
        for site in seen:
            watcher.subscribe(keys.applied(site), AppliedAction, seen[site].append)
        assert wait_until(lambda: all(s.tally["proposals_applied"] >= 8 for s in sensors), 30)
        assert wait_until(lambda: all(len(v) >= 5 for v in seen.values()), 10)
        applied_a = {a.source_controller for a in seen["plant-a"] if not a.fallback}
        applied_b = {a.source_controller for a in seen["plant-b"] if not a.fallback}
        assert applied_a == {"g36"} and applied_b == {"static"}
        assert sensors[0].tally["duplicate_proposals"] == 0 and sensors[1].tally["duplicate_proposals"] == 0
        runs = [HistoryReader(s.history_file).runs() for s in (site_a, site_b)]
        assert runs[0][0]["run_id"] != runs[1][0]["run_id"]
    finally:
        _stop(agents, routers)

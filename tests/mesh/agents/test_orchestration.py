"""The Orchestrator judges its agents by what the router lets each role send, never by what a message claims."""

from __future__ import annotations

from lcmesh.mesh import keys
from lcmesh.mesh.agents.orchestration import OrchestrationAgent
from lcmesh.mesh.messages import AgentStats
from tests.mesh.conftest import wait_until


def _stats(agent_id: str, role: str) -> AgentStats:
    return AgentStats(source=agent_id, role=role, agent_id=agent_id, pid=1, host="elsewhere", uptime_s=1.0,
                      cpu_pct=0.0, rss_bytes=1, threads=1)  # fmt: skip


def test_stats_claiming_to_be_the_sensor_on_another_roles_key_do_not_keep_it_alive(start_agent, bus_as,
                                                                                   mesh_settings):  # fmt: skip
    """"I am the Sensor, alive" from the UI role on its own key is dropped and counted (in the Orchestrator's own stats
    details); the Sensor's stats from the sensor role still count. Old code: the forged stats reset the hang timer."""
    site = mesh_settings.site
    watching = mesh_settings.model_copy(update={"orchestration": mesh_settings.orchestration.model_copy(
        update={"roles": ["sensor"], "supervise": False})})  # fmt: skip
    orchestrator = start_agent(OrchestrationAgent, watching)
    sensor = orchestrator.managed["sensor"]
    own_stats: list[AgentStats] = []
    ui = bus_as("ui")
    ui.subscribe(keys.agent_stats(site, "orchestration"), AgentStats, own_stats.append)
    assert wait_until(lambda: ui.publish(keys.agent_stats(site, "ui"), _stats("sensor", "sensor"))
                      or orchestrator.identity_mismatches["stats"], 30), "the forged stats arrive (and are dropped)"
    assert sensor.last_stats_at is None, "forged stats must not count as the Sensor's"
    assert wait_until(lambda: any(s.details.get("identity_mismatches", {}).get("stats", 0) >= 1 for s in own_stats), 10)
    real = bus_as("sensor")
    assert wait_until(lambda: real.publish(keys.agent_stats(site, "sensor"), _stats("sensor", "sensor"))
                      or sensor.last_stats_at, 30), "the sensor role's own stats count"  # fmt: skip


def test_each_agent_id_belongs_to_the_one_role_the_router_lets_publish_for_it():
    from lcmesh.mesh.security import ROLES, role_of_agent_id

    assert [role_of_agent_id(a) for a in ("sensor", "sensor-2", "ui", "orchestration", "intruder")] == \
        ["sensor", "sensor", "ui", "orchestration", None]  # fmt: skip
    assert not [(a, b) for a in ROLES for b in ROLES if a != b and b.startswith(a)], "the ACL's `R$*` keys overlap"

"""Mesh fixtures: a real zenoh router on a free loopback port, agents in-process or as processes."""

from __future__ import annotations

import time
from collections.abc import Callable

import pytest

from lcmesh.mesh.processes import free_port  # noqa: F401  (tests import it from here)


def wait_until(predicate: Callable[[], object], timeout_s: float = 10.0, interval_s: float = 0.02):
    """The first truthy value of `predicate()`, or None after `timeout_s`."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if value or time.monotonic() > deadline:
            return value
        time.sleep(interval_s)


def make_settings(data_dir, port: int | None = None, **overrides):
    from lcmesh.mesh.settings import MeshSettings

    endpoint = f"tcp/127.0.0.1:{port or free_port()}"
    values = dict(site="test", router_endpoints=[endpoint], listen_endpoints=[endpoint], data_dir=data_dir,
                  controller="g36", speed_factor=300.0, connect_timeout_s=10.0, stats_period_s=0.2)  # fmt: skip
    values.update(overrides)
    return MeshSettings(**values)


@pytest.fixture
def mesh_settings(tmp_path):
    return make_settings(tmp_path / "mesh")


@pytest.fixture
def router(mesh_settings):
    from lcmesh.mesh.bus import Bus

    bus = Bus.open_router(mesh_settings)
    yield bus
    bus.close()


@pytest.fixture
def client(mesh_settings, router):
    from lcmesh.mesh.bus import Bus

    bus = Bus.connect(mesh_settings, "tester")
    yield bus
    bus.close()


@pytest.fixture
def bus_as(mesh_settings, router):
    """bus_as(role) -> a client session authenticated as that bus role (closed after the test)."""
    from lcmesh.mesh.bus import Bus

    opened = []

    def connect(role: str, source: str | None = None):
        opened.append(Bus.connect(mesh_settings, source or f"{role}-tester", role=role))
        return opened[-1]

    yield connect
    for bus in opened:
        bus.close()


@pytest.fixture
def start_agent(mesh_settings, router):
    """start_agent(AgentClass, settings=None, agent_id=None) -> a started in-process agent on its own session."""
    from lcmesh.mesh.bus import Bus

    started = []

    def start(cls, settings=None, agent_id=None):
        settings = settings or mesh_settings
        agent = cls(settings, agent_id)
        bus = Bus.connect(settings, agent.agent_id)
        agent.start(bus)
        started.append((agent, bus))
        return agent

    yield start
    for agent, bus in reversed(started):
        agent.stop()
        bus.close()

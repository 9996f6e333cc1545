"""A real mesh on loopback for the UI tests: router, configuration, sensor, control, maintenance, monitor, UI.

One mesh for the UI tests (agents in-process, each on its own zenoh session; the FMU is real,
history is a real SQLite file); the UI serves HTTP on a free loopback port. A second UI on an
empty site of the same router answers what a UI says when the mesh is not ready.
"""

from __future__ import annotations

import secrets
from contextlib import contextmanager
from dataclasses import dataclass

import httpx
import pytest

from tests.mesh.conftest import free_port, make_settings, wait_until

MESH_ROLES = ("configuration", "sensor", "control", "maintenance", "monitor")


@dataclass
class UiMesh:
    settings: object
    ui: object
    agents: list
    token: str
    url: str

    def client(self, **kw) -> httpx.Client:
        return httpx.Client(base_url=self.url, timeout=20.0, **kw)

    def auth(self) -> dict:
        return {"Authorization": f"Bearer {self.token}"}


def _start(cls, settings, started, **kw):
    from lcmesh.mesh.bus import Bus

    agent = cls(settings, **kw)
    bus = Bus.connect(settings, agent.agent_id)
    started.append((agent, bus))
    agent.start(bus)
    return agent


def _stop(started):
    for agent, bus in reversed(started):
        try:
            agent.stop()
        finally:
            bus.close()


@contextmanager
def running_mesh(data_dir, roles: tuple[str, ...] = MESH_ROLES, **ui_overrides):
    """Router, the agents of `roles` and a UI with a random token, in-process on free loopback ports; ready when given."""
    from lcmesh.mesh.agents.configuration import ConfigurationAgent
    from lcmesh.mesh.agents.control import ControlAgent
    from lcmesh.mesh.agents.maintenance import MaintenanceAgent
    from lcmesh.mesh.agents.monitor import MonitorAgent
    from lcmesh.mesh.agents.sensor import SensorAgent
    from lcmesh.mesh.agents.ui import UiAgent
    from lcmesh.mesh.agents.ui.config import UiSettings
    from lcmesh.mesh.bus import Bus

    classes = {"configuration": ConfigurationAgent, "sensor": SensorAgent, "control": ControlAgent,
               "maintenance": MaintenanceAgent, "monitor": MonitorAgent}  # fmt: skip
    settings = make_settings(data_dir, ui_port=free_port(), speed_factor=300.0)
    token = secrets.token_urlsafe(24)
    ui_settings = UiSettings(**{"api_token": token, "chat_rate_per_min": 1e5, "chat_burst": 10_000, **ui_overrides})
    router = Bus.open_router(settings)
    started: list = []
    try:
        for role in roles:
            _start(classes[role], settings, started)
        ui = _start(UiAgent, settings, started, ui=ui_settings)
        mesh = UiMesh(settings, ui, [a for a, _ in started], token, ui.url)
        with mesh.client() as http:
            assert wait_until(lambda: http.get("/api/health").json()["ready"], 30), "the UI never became ready"
            assert wait_until(lambda: len(http.get("/api/decisions").json()["decisions"]) >= 5, 30)
        yield mesh
    finally:
        _stop(started)
        router.close()


@pytest.fixture(scope="package")
def ui_mesh(tmp_path_factory):
    # package scope: the plant steps at 300x while it runs, so it stops once the UI tests are done instead of
    # burning CPU under every later test of the session
    with running_mesh(tmp_path_factory.mktemp("ui-mesh")) as mesh:
        yield mesh


@pytest.fixture(scope="package")
def empty_ui(ui_mesh, tmp_path_factory):
    """A UI on a site where nothing else runs (same router): the mesh is 'not ready' for it."""
    from lcmesh.mesh.agents.ui import UiAgent
    from lcmesh.mesh.agents.ui.config import UiSettings
    from lcmesh.mesh.settings import MeshSettings

    values = ui_mesh.settings.model_dump()
    values.update(site="empty", data_dir=tmp_path_factory.mktemp("empty-site"), ui_port=free_port(), history_path=None,
                  secrets_dir=ui_mesh.settings.secrets_path)  # the same router: its bus passwords
    settings = MeshSettings(**values)
    started: list = []
    try:
        ui = _start(UiAgent, settings, started,
                    ui=UiSettings(api_token=secrets.token_urlsafe(24), chat_rate_per_min=60, chat_burst=2,
                                  bus_timeout_s=0.5))  # fmt: skip
        yield UiMesh(settings, ui, [ui], ui.ctx.token.value, ui.url)
    finally:
        _stop(started)


@pytest.fixture
def api(ui_mesh):
    with ui_mesh.client() as client:
        yield client

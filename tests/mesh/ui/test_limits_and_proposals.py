"""What the UI answers when the mesh says "not now" or "not any more", over real HTTP on a real mesh on loopback.

A tool over its rate limit or the what-if budget is HTTP 429 with ``Retry-After``; a chat proposal confirmed
after the configuration changed is 409, after ``proposal_max_age_s`` 410; NaN and infinities in a body are
422 naming the field. The Sensor's limits and the UI's wall time run on clocks the tests move by hand.
"""

from __future__ import annotations

import datetime as dt
import secrets
import threading
from contextlib import contextmanager
from dataclasses import dataclass

import httpx
import pytest

from lcmesh.mesh import keys
from lcmesh.mesh.agents.sensor import SensorAgent
from tests.mesh.conftest import free_port, make_settings, wait_until
from tests.mesh.ui.conftest import _start, _stop

SUPPLY_WHATIF = "what if I raise the supply setpoint of cabinet 2 by 1 K?"  # whatif_setpoint: 1 plant minute
PROPOSE = "set the supply setpoint of cabinet 3 to 29 °C"


class FrozenClock:
    """Monotonic seconds that move only when told (the Sensor's tool buckets and what-if budget read it)."""

    def __init__(self) -> None:
        self.now_s = 1000.0

    def __call__(self) -> float:
        return self.now_s


class WallClock:
    """UTC wall time that moves only when told (the UI's chat proposals and their confirmation read it)."""

    def __init__(self) -> None:
        self.now = dt.datetime(2026, 3, 1, 12, 0, tzinfo=dt.timezone.utc)

    def __call__(self) -> dt.datetime:
        return self.now


@dataclass
class Mesh:
    settings: object
    sensor: SensorAgent
    ui: object
    clock: FrozenClock
    wall: WallClock
    http: httpx.Client
    auth: dict


@contextmanager
def _mesh(data_dir):
    from lcmesh.mesh.agents.configuration import ConfigurationAgent
    from lcmesh.mesh.agents.ui import UiAgent
    from lcmesh.mesh.agents.ui.config import UiSettings
    from lcmesh.mesh.bus import Bus
    from lcmesh.mesh.settings import SensorConfig

    clock = FrozenClock()

    class Sensor(SensorAgent):
        pass

    Sensor.clock = clock  # an instance, not a function: not bound as a method
    limits = SensorConfig(tools_rate_per_s=0.5, tools_burst=1, whatif_max_running=1, whatif_plant_minutes_per_min=3.0)
    settings = make_settings(data_dir, ui_port=free_port(), speed_factor=300.0, sensor=limits)
    token = secrets.token_urlsafe(24)
    router = Bus.open_router(settings)
    started: list = []
    try:
        _start(ConfigurationAgent, settings, started)
        sensor = _start(Sensor, settings, started)
        ui = _start(UiAgent, settings, started, ui=UiSettings(api_token=token, planner="rules", chat_rate_per_min=1e5,
                                                                chat_burst=10_000))  # fmt: skip
        wall = WallClock()
        ui.ctx.clock = wall
        with httpx.Client(base_url=ui.url, timeout=30.0) as http:
            assert wait_until(lambda: http.get("/api/health").json()["ready"], 60), "the UI never became ready"
            assert wait_until(lambda: http.get("/api/config").status_code == 200, 30)
            yield Mesh(settings, sensor, ui, clock, wall, http, {"Authorization": f"Bearer {token}"})
    finally:
        _stop(started)
        router.close()


@pytest.fixture(scope="module")
def mesh(tmp_path_factory):
    with _mesh(tmp_path_factory.mktemp("limits")) as m:
        yield m


@pytest.fixture(scope="module")
def operator(mesh):
    """A session as the `operator` role (the command line's)."""
    from lcmesh.mesh.bus import Bus

    bus = Bus.connect(mesh.settings, "operator-tester", role="operator")
    yield bus
    bus.close()


@pytest.fixture
def fresh(mesh):
    """The mesh with every bucket and the budget full again (an hour later on the Sensor's clock)."""
    mesh.clock.now_s += 3600.0
    return mesh


def test_a_rate_limited_tool_answers_429_with_retry_after(fresh, operator):
    http = fresh.http
    first = http.post("/api/chat", json={"message": SUPPLY_WHATIF})
    assert first.status_code == 200 and first.json()["intent"] == "whatif_setpoint", first.text
    limited = http.post("/api/chat", json={"message": SUPPLY_WHATIF})  # the UI's one token is spent (burst 1)
    assert limited.status_code == 429, limited.text
    assert limited.headers["Retry-After"] == "2"  # 0.5 queries/s: one token in 2 s
    assert "rate limited: 0.5 queries/s for tools/whatif_setpoint/ui; retry in 2.0 s" in limited.json()["detail"]
    own_key = keys.tool(fresh.settings.site, "whatif_setpoint", "operator")  # another role's bucket is its own
    replies = operator.query(own_key, b'{"setpoint": "supply", "change": 1}', timeout_s=20.0)
    assert [r.ok for r in replies] == [True], replies
    fresh.clock.now_s += 2.0
    assert http.post("/api/chat", json={"message": SUPPLY_WHATIF}).status_code == 200


def test_the_what_if_budget_answers_429_when_spent_or_busy(fresh, operator):
    http, site = fresh.http, fresh.settings.site
    spend = operator.query(keys.tool(site, "whatif_setpoint", "operator"),
                           b'{"setpoint": "supply", "change": 1, "minutes": 2.5}', timeout_s=20.0)  # fmt: skip
    assert [r.ok for r in spend] == [True], spend  # 2.5 of the 3 plant minutes a minute
    spent = http.post("/api/chat", json={"message": SUPPLY_WHATIF})  # 1 plant minute: 0.5 left
    assert spent.status_code == 429 and spent.headers["Retry-After"] == "10", spent.text  # 3 a minute: 0.5 in 10 s
    assert "the what-if budget of 3 plant minutes a minute is spent (this one needs 1)" in spent.json()["detail"]
    fresh.clock.now_s += 60.0
    big = http.post("/api/chat", json={"message": "what if we lower the supply setpoint by 1 K over the next 5 "
                                                  "minutes?"})  # fmt: skip
    assert big.status_code == 200 and not big.json()["grounded"]  # larger than the budget: a refusal, quoted
    assert "needs 5 plant minutes; the budget is 3 plant minutes a minute" in big.json()["answer"]
    # one what-if at once: one admitted and waiting for the twin holds the only place
    fresh.clock.now_s += 60.0
    replies: list = []
    waiting = threading.Thread(target=lambda: replies.extend(operator.query(
        keys.tool(site, "whatif", "operator"), b'{"steps": 4}', timeout_s=30.0)))  # fmt: skip
    twin = fresh.sensor.twin.lock
    twin.acquire()  # as a long what-if would hold it
    try:
        waiting.start()
        assert wait_until(lambda: fresh.sensor.whatif_budget.running == 1, 20)
        busy = http.post("/api/chat", json={"message": SUPPLY_WHATIF})
    finally:
        twin.release()
        waiting.join()
    assert [r.ok for r in replies] == [True], replies
    assert busy.status_code == 429 and busy.headers["Retry-After"] == "1", busy.text
    assert "1 what-if run(s) already running (at most 1 at once)" in busy.json()["detail"]


def test_a_chat_proposal_is_refused_once_the_config_changed_or_it_aged(fresh):
    http, auth, wall = fresh.http, fresh.auth, fresh.wall
    version = http.get("/api/config").json()["version"]
    command = http.post("/api/chat", json={"message": PROPOSE}).json()["proposed_command"]
    stamp = command["body"]["proposal"]
    assert stamp == {"config_version": version, "made_at": wall.now.isoformat()}
    assert command["expires_at"] == (wall.now + dt.timedelta(minutes=5)).isoformat()
    wall.now += dt.timedelta(minutes=5, seconds=1)
    late = http.post(command["path"], json=command["body"], headers=auth)
    assert late.status_code == 410, late.text
    assert "`proposal.made_at`: this chat proposal was made 301 s ago" in late.json()["detail"]
    assert "expire after 300 s (LCMESH_UI_PROPOSAL_MAX_AGE_S)" in late.json()["detail"]
    command = http.post("/api/chat", json={"message": PROPOSE}).json()["proposed_command"]
    wall.now += dt.timedelta(minutes=4)  # young enough, but the configuration moves on meanwhile
    changed = http.put("/api/config", json={"changes": {"speed_factor": 301.0}, "reason": "test"}, headers=auth)
    assert changed.status_code == 200 and changed.json()["version"] == version + 1, changed.text
    assert wait_until(lambda: fresh.ui.ctx.config_doc().version == version + 1, 20)
    stale = http.post(command["path"], json=command["body"], headers=auth)
    assert stale.status_code == 409, stale.text
    assert stale.json()["detail"] == (f"`proposal.config_version`: the configuration changed since this chat proposal "
                                      f"(version {version} then, {version + 1} now): ask the chat again")  # fmt: skip
    assert http.get("/api/config").json()["version"] == version + 1, "a refused proposal changes nothing"
    command = http.post("/api/chat", json={"message": PROPOSE}).json()["proposed_command"]
    try:
        ok = http.post(command["path"], json=command["body"], headers=auth)
        assert ok.status_code == 200 and ok.json()["config_version"] == version + 2, ok.text
    finally:
        http.post("/api/control/mode", json={"mode": "auto"}, headers=auth)


@pytest.mark.parametrize("token,shown", [("NaN", "nan"), ("Infinity", "inf"), ("-Infinity", "-inf")])
def test_non_finite_numbers_in_a_body_are_422_naming_the_field(mesh, token, shown):
    http, auth = mesh.http, mesh.auth
    version = http.get("/api/config").json()["version"]
    headers = {**auth, "Content-Type": "application/json"}
    r = http.post("/api/control/setpoints", content=f'{{"supply_temp_setpoint_c": {token}}}', headers=headers)
    assert r.status_code == 422 and r.json()["detail"].startswith("`supply_temp_setpoint_c"), r.text
    assert "finite number" in r.json()["detail"]
    r = http.put("/api/config", content=f'{{"changes": {{"guardrails": {{"dp_max_pa": {token}}}}}}}', headers=headers)
    assert r.status_code == 422 and "`changes.guardrails.dp_max_pa` Input should be a finite number" in r.json()[
        "detail"], r.text
    assert http.get("/api/config").json()["version"] == version


def test_non_finite_numbers_in_a_config_change_on_the_bus_are_refused(mesh, operator):
    from lcmesh.mesh.bus import BusError
    from lcmesh.mesh.messages import ConfigDoc

    key = keys.configure(mesh.settings.site, "operator", "all")
    body = b'{"changes": {"guardrails": {"dp_max_pa": Infinity}}, "by": "test"}'
    with pytest.raises(BusError, match=r"`changes.guardrails.dp_max_pa` must be a finite number, got inf"):
        operator.request(key, ConfigDoc, body, timeout_s=10.0)



def test_a_proposal_time_must_be_iso_text_not_a_number():
    """schemathesis found `made_at: 0` taken as Unix seconds (answered 410 instead of 422): the schema says text."""
    import pydantic

    from lcmesh.mesh.agents.ui.schemas import ProposalStamp

    good = ProposalStamp.model_validate({"config_version": 1, "made_at": "2026-11-27T10:00:00+00:00"})
    assert good.made_at.year == 2026
    for bad in (0, 1.5e9, None):
        with pytest.raises(pydantic.ValidationError, match="made_at"):
            ProposalStamp.model_validate({"config_version": 1, "made_at": bad})

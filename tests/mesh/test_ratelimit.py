"""Token buckets and the what-if budget on an injected clock; per-role tool buckets on a real router on loopback."""

from __future__ import annotations

import pytest
from pydantic import BaseModel

from lcmesh.mesh import keys
from lcmesh.mesh.ratelimit import RateLimited, TokenBuckets, WorkBudget, limited_text, retry_after_s
from tests.mesh.conftest import wait_until


class Clock:
    def __init__(self) -> None:
        self.now_s = 50.0

    def __call__(self) -> float:
        return self.now_s


def test_a_burst_then_the_rate_with_the_wait_until_the_next_token():
    clock = Clock()
    buckets = TokenBuckets(rate_per_s=2.0, burst=3, clock=clock)
    assert [buckets.take("tools/whatif") for _ in range(3)] == [0.0, 0.0, 0.0]
    assert buckets.take("tools/whatif") == pytest.approx(0.5)  # one token takes 1 / 2 s
    clock.now_s += 0.2
    assert buckets.take("tools/whatif") == pytest.approx(0.3)  # a refused query spends nothing
    clock.now_s += 0.3
    assert buckets.take("tools/whatif") == 0.0
    assert buckets.take("tools/whatif") == pytest.approx(0.5)
    assert buckets.take("tools/approach") == 0.0  # a bucket per key


def test_an_idle_bucket_refills_to_its_burst_and_no_further():
    clock = Clock()
    buckets = TokenBuckets(rate_per_s=1.0, burst=2, clock=clock)
    assert [buckets.take() for _ in range(3)] == [0.0, 0.0, 1.0]
    clock.now_s += 3600.0
    assert [buckets.take() for _ in range(3)] == [0.0, 0.0, 1.0]
    clock.now_s -= 10.0  # a clock that steps back refills nothing
    assert buckets.take() == pytest.approx(1.0)


def test_the_least_recent_keys_are_forgotten_beyond_max_keys():
    buckets = TokenBuckets(rate_per_s=1.0, burst=1, clock=Clock(), max_keys=2)
    assert [buckets.take(key) for key in ("a", "b", "c")] == [0.0, 0.0, 0.0]
    assert buckets.take("a") == 0.0  # forgotten: full again
    assert buckets.take("c") == pytest.approx(1.0)


@pytest.mark.parametrize("rate_per_s,burst", [(0.0, 1), (-1.0, 1), (1.0, 0)])
def test_bad_limits_say_what_would_be_valid(rate_per_s, burst):
    with pytest.raises(ValueError, match=r"`rate_per_s` > 0 and `burst` >= 1"):
        TokenBuckets(rate_per_s, burst)


def test_a_bucket_spends_a_cost_and_says_how_long_a_larger_one_waits():
    clock = Clock()
    buckets = TokenBuckets(rate_per_s=1.0, burst=10, clock=clock)
    assert buckets.take("plant", cost=8.0) == 0.0
    assert buckets.take("plant", cost=4.0) == pytest.approx(2.0)  # 2 left, 2 more to come at 1 a second
    clock.now_s += 2.0
    assert buckets.take("plant", cost=4.0) == 0.0


def _one_run(budget: WorkBudget, units: float) -> None:
    with budget.run(units):
        pass


def test_the_work_budget_caps_runs_at_once_and_plant_minutes_per_minute():
    clock = Clock()
    budget = WorkBudget(max_running=1, units_per_min=60.0, clock=clock, setting="LCMESH_X")
    with budget.run(30.0):
        assert budget.running == 1
        with pytest.raises(RateLimited, match=r"^rate limited: 1 what-if run\(s\) already running \(at most 1 at "
                                              r"once\); retry in 1\.0 s$") as busy:
            _one_run(budget, 1.0)
        assert busy.value.retry_after_s == 1.0
    assert budget.running == 0  # refused runs spend nothing and hold nothing
    _one_run(budget, 30.0)
    with pytest.raises(RateLimited, match=r"budget of 60 plant minutes a minute is spent \(this one needs 15\); "
                                          r"retry in 15\.0 s") as spent:
        _one_run(budget, 15.0)
    assert spent.value.retry_after_s == 15.0 and budget.running == 0
    clock.now_s += 15.0  # 1 plant minute a second comes back
    _one_run(budget, 15.0)
    with pytest.raises(ValueError, match=r"needs 61 plant minutes; the budget is 60 plant minutes a minute "
                                         r"\(LCMESH_X\): ask for fewer"):
        _one_run(budget, 61.0)


def test_a_refusal_text_carries_its_retry_time_and_nothing_else_does():
    text = limited_text("0.5 queries/s for tools/whatif/ui", 1.93)
    assert text == "rate limited: 0.5 queries/s for tools/whatif/ui; retry in 2.0 s"
    assert retry_after_s(text) == 2.0
    assert retry_after_s(f"the toolbox tool 'whatif': {text}") == 2.0
    assert retry_after_s("`cabinet` must be in 1..5; retry in 2.0 s") is None  # no refusal prefix
    assert retry_after_s("rate limited: but no time") is None


class Answer(BaseModel):
    ok: bool = True


def test_each_role_spends_its_own_tool_bucket_and_may_ask_only_on_its_own_key(bus_as, mesh_settings):
    """A real router on loopback: the key names the asking role, and the router's ACL holds each role to its own."""
    site, clock = mesh_settings.site, Clock()
    sensor = bus_as("sensor")
    sensor.serve(keys.tool_served(site, "heat_balance"), lambda _payload: Answer(),
                 limit=TokenBuckets(rate_per_s=0.5, burst=2, clock=clock))  # fmt: skip
    ui, operator, control = bus_as("ui"), bus_as("operator"), bus_as("control")
    assert wait_until(lambda: control.query(keys.tool(site, "heat_balance", "control"), b"{}", timeout_s=1.0), 20)

    def ask(bus, role: str) -> list:
        return bus.query(keys.tool(site, "heat_balance", role), b"{}", timeout_s=2.0)

    flood = [ask(ui, "ui") for _ in range(3)]
    assert [[r.ok for r in replies] for replies in flood] == [[True], [True], [False]]
    assert flood[2][0].payload.decode() == "rate limited: 0.5 queries/s for tools/heat_balance/ui; retry in 2.0 s"
    assert ask(operator, "operator")[0].ok and ask(control, "control")[0].ok  # their buckets are their own
    # another role's key, or a wildcard that would reach it, is refused by the router: nothing answers
    for key in ("tools/heat_balance/operator", "tools/heat_balance/*", "tools/**", "tools/heat_balance/ui$*"):
        assert ui.query(f"lcmesh/{site}/{key}", b"{}", timeout_s=1.0) == [], key
    assert bus_as("maintenance").query(keys.tool(site, "heat_balance", "maintenance"), b"{}", timeout_s=1.0) == []
    assert [r.ok for r in ask(operator, "operator")] == [True]  # the UI's attempts spent nothing of the operator's
    spelled = ui.query(f"lcmesh/{site}/tools/*/ui", b"{}", timeout_s=2.0)  # another spelling: the same bucket
    assert [r.ok for r in spelled] == [False]
    clock.now_s += 2.0  # one token back for the UI
    assert [r.ok for r in ask(ui, "ui")] == [True]
    assert sensor.counters.snapshot()["rate_limited"] == {"tools/heat_balance/ui": 2}


def test_without_bus_auth_a_wildcard_asker_is_refused_by_the_serving_side(tmp_path):
    from lcmesh.mesh.bus import Bus
    from tests.mesh.conftest import make_settings

    settings = make_settings(tmp_path / "open", bus_auth=False)  # loopback only: the router checks no role
    router = Bus.open_router(settings)
    host, asker = Bus.connect(settings, "sensor"), Bus.connect(settings, "anyone")
    try:
        host.serve(keys.tool_served(settings.site, "approach"), lambda _payload: Answer(),
                   limit=TokenBuckets(rate_per_s=1.0, burst=5, clock=Clock()))  # fmt: skip
        own = keys.tool(settings.site, "approach", "operator")
        assert wait_until(lambda: asker.query(own, b"{}", timeout_s=1.0), 20)
        replies = asker.query(f"lcmesh/{settings.site}/tools/approach/*", b"{}", timeout_s=2.0)
        assert [(r.ok, r.payload.decode()) for r in replies] == [
            (False, "ask tools/approach/<your role>, not tools/approach/*")]  # fmt: skip
    finally:
        asker.close()
        host.close()
        router.close()

"""The tool registry: every tool answers, bad requests get errors that name the field, whatif needs the twin."""

from __future__ import annotations

import json
import threading

import numpy as np
import pytest
from typer.testing import CliRunner

from lcmesh.cli import app
from lcmesh.mesh.tools.registry import TOOLS, ToolContext, catalog, invoke
from lcmesh.twin.system import load_system
from tests.mesh.conftest import wait_until

_LCOPT5_CELL_DESIGN_W = load_system("lcopt-5").towers.cell.design_heat_w  # the parameters below need it at import


@pytest.fixture
def ctx(lcopt5):
    return ToolContext(lcopt5)


@pytest.mark.parametrize(
    "name,payload,key,expected",
    [
        ("heat_balance", {"mass_flow_kg_s": 10, "delta_t_k": 5}, "heat_w", 209_300.0),  # 10 x 4186 x 5
        ("hx_effectiveness", {"ntu": 1.0, "capacity_ratio": 1.0}, "effectiveness", 0.5),  # NTU / (1 + NTU)
        ("hx_effectiveness", {"hot_in_k": 333.15, "hot_out_k": 313.15, "cold_in_k": 293.15, "cold_out_k": 303.15},
         "effectiveness", 0.5),  # 20 K of a 40 K span
        ("approach", {"leaving_water_k": 300.0, "wet_bulb_k": 295.0, "entering_water_k": 305.0}, "range_k", 5.0),
        ("affinity", {"machine": "pump", "speed_from": 1.0, "speed_to": 0.5, "flow": 10, "power_w": 8000},
         "power_w", 1000.0),  # 8 kW x 0.5^3
        # both cells at design heat, 3 K approach at 25 C: air = beta / (3 - alpha) (test_thermo.py)
        ("tower_power", {"heat_w": 2 * _LCOPT5_CELL_DESIGN_W, "approach_k": 3.0, "wet_bulb_k": 298.15}, "fan_speed",
         0.784984),
        ("confidence_interval", {"samples": [1, 2, 3, 4, 5]}, "high", 4.963243),  # 3 + 2.776445 x 1.581139 / sqrt 5
    ],
)  # fmt: skip
def test_each_tool_answers(ctx, name, payload, key, expected):
    result = invoke(name, payload, ctx)
    assert result.ok, result.error
    assert result.result[key] == pytest.approx(expected, abs=1e-5)


BAD_REQUESTS = [
    ("heat_balance", {"mass_flow_kg_s": -1, "delta_t_k": 5},
     "`mass_flow_kg_s`: Input should be greater than or equal to 0 (got -1)"),
    ("heat_balance", {"mass_flow_kg_s": 1, "delta_t": 5},
     "`delta_t`: Extra inputs are not permitted; did you mean 'delta_t_k'?"),
    ("heat_balance", {"mass_flow_kg_s": 1}, "`mass_flow_kg_s` and `delta_t_k` go together"),
    ("heat_balance", {}, "give either `mass_flow_kg_s` and `delta_t_k`, or `cabinet`"),
    ("hx_effectiveness", {"ntu": 1.0, "capacity_ratio": 1.5},
     "`capacity_ratio`: Input should be less than or equal to 1"),
    ("hx_effectiveness", {"hot_in_k": 290, "hot_out_k": 289, "cold_in_k": 300, "cold_out_k": 301},
     "`hot_in_k` (290.0) must be above"),
    ("affinity", {"machine": "compressor", "speed_from": 1, "speed_to": 1, "flow": 1},
     "`machine`: Input should be 'pump' or 'fan'"),
    ("confidence_interval", {"samples": [1.0]}, "`samples`: List should have at least 2 items"),
    ("confidence_interval", {"samples": [1, 2], "method": "bayes"},
     "`method`: Input should be 't', 'bootstrap' or 'percentile'"),
    ("tower_power", {"heat_w": 1e5, "approach_k": 3, "wet_bulb_k": 290, "cells_active": 5},
     "`cells_active` must be <= 2"),
    ("whatif", {"steps": 1000}, "`steps`: Input should be less than or equal to 240"),
    ("approach", {"tower": 0}, "no plant outputs yet"),
    ("heatbalance", {}, "unknown tool 'heatbalance'; did you mean 'heat_balance'?"),
]  # fmt: skip


@pytest.mark.parametrize("name,payload,expected", BAD_REQUESTS)
def test_errors_name_the_field_and_what_is_valid(ctx, name, payload, expected):
    result = invoke(name, payload, ctx)
    assert not result.ok and result.result is None
    assert expected in result.error


def test_payload_as_json_text_and_garbage(ctx):
    good = invoke("heat_balance", '{"mass_flow_kg_s": 2, "delta_t_k": 1}', ctx)
    assert good.result["heat_w"] == pytest.approx(8372.0)
    bad = invoke("heat_balance", "{not json", ctx)
    assert not bad.ok and "not valid JSON" in bad.error


def test_whatif_without_a_plant_is_a_clear_error(ctx):
    result = invoke("whatif", {"supply_temp_setpoint_delta_k": 2}, ctx)
    assert not result.ok and "needs the live twin" in result.error


def test_whatif_and_indexed_tools_on_the_twin(plant):
    cab = plant.system.cabinets
    power = np.full(plant.system.n_blade_groups, 0.8 * cab.design_heat_w / cab.branches)  # valves mid-stroke
    action = plant.default_action()
    for _ in range(300):
        plant.step(power, 290.0, action)
    before = {k: v.copy() for k, v in plant.out.items()}
    ctx = ToolContext(plant.system, plant=plant, lock=threading.RLock(), latest_out=plant.out)
    r = invoke("whatif", {"supply_temp_setpoint_delta_k": 2.0, "cabinets": [1], "steps": 20}, ctx)
    assert r.ok, r.error
    delta = np.array(r.result["delta"]["supply_temp_k"])
    assert delta[1] > 1.5 and np.all(np.abs(np.delete(delta, 1)) < 0.2)  # only cabinet 1 was changed
    assert all(np.array_equal(plant.out[k], before[k]) for k in before)  # the plant is as it was
    bad = invoke("whatif", {"cabinets": [7]}, ctx)
    assert "`cabinets[0]` must be in [0, 4] (zero-based), got 7" in bad.error
    split = invoke("whatif", {"valve_fractions": [[0.5, 0.5]] * 5}, ctx)
    assert "`valve_fractions` must be 5 rows of 3 fractions" in split.error
    hb = invoke("heat_balance", {"cabinet": 1}, ctx)
    assert hb.ok and abs(hb.result["residual_pct"]) < 1.0  # steady state: heat in ~ heat out
    ap = invoke("approach", {"tower": 1}, ctx)
    assert ap.ok and ap.result["approach_k"] == pytest.approx(float(plant.out["approach_k"][1]))


def test_catalog_has_schemas_for_every_tool():
    entries = {e["name"]: e for e in catalog()}
    assert set(entries) == set(TOOLS)
    assert "mass_flow_kg_s" in entries["heat_balance"]["request"]["properties"]
    json.dumps(entries)


def test_cli_tools_call_and_list():
    runner = CliRunner()
    request = '{"machine": "fan", "speed_from": 1, "speed_to": 0.5, "flow": 4}'
    ok = runner.invoke(app, ["tools", "call", "affinity", request])
    assert ok.exit_code == 0, ok.output
    assert json.loads(ok.stdout)["result"]["flow"] == pytest.approx(2.0)
    bad = runner.invoke(app, ["tools", "call", "affinity", '{"machine": "fan"}'])
    assert bad.exit_code == 1 and "`speed_from`: Field required" in bad.stdout
    listing = runner.invoke(app, ["tools", "list", "--schemas"])
    assert listing.exit_code == 0 and "whatif" in json.loads(listing.stdout)["tools"][-1]["name"]


@pytest.mark.parametrize("token,shown", [("NaN", "nan"), ("Infinity", "inf"), ("-Infinity", "-inf"), ("1e999", "inf")])
def test_non_finite_numbers_are_refused_naming_the_field(ctx, token, shown):
    # json.loads lets NaN / Infinity through, and a bare float field (no bounds) let them into the tool
    text = f'{{"samples": [1, 2, {token}], "confidence": 0.9}}'
    result = invoke("confidence_interval", text, ctx)
    assert not result.ok and result.error == (f"invalid ConfidenceIntervalRequest: `samples[2]` must be a finite "
                                              f"number, got {shown}")  # fmt: skip
    parsed = invoke("confidence_interval", {"samples": [1.0, 2.0], "confidence": float(shown)}, ctx)
    assert not parsed.ok and f"`confidence` must be a finite number, got {shown}" in parsed.error
    change = invoke("whatif_setpoint", f'{{"setpoint": "supply", "change": {token}}}', ctx)
    assert not change.ok and f"`change` must be a finite number, got {shown}" in change.error


class _Clock:
    def __init__(self) -> None:
        self.now_s = 100.0

    def __call__(self) -> float:
        return self.now_s


def test_what_ifs_spend_the_plant_minutes_budget_before_they_wait_for_the_twin(plant):
    from lcmesh.mesh.ratelimit import WorkBudget

    clock = _Clock()
    budget = WorkBudget(max_running=1, units_per_min=10.0, clock=clock)
    lock = threading.RLock()
    ctx = ToolContext(plant.system, plant=plant, lock=lock, latest_out=plant.out, budget=budget)
    first = invoke("whatif", {"supply_temp_setpoint_delta_k": 1.0, "steps": 24}, ctx)  # 24 x 15 s = 6 plant minutes
    assert first.ok, first.error
    over = invoke("whatif_setpoint", {"setpoint": "supply", "change": 1.0, "minutes": 5}, ctx)
    assert not over.ok and over.retry_after_s == 6.0, over  # 4 left, 1 more each 6 s
    assert over.error == ("rate limited: the what-if budget of 10 plant minutes a minute is spent (this one needs 5); "
                          "retry in 6.0 s")  # fmt: skip
    assert invoke("heat_balance", {"cabinet": 1}, ctx).ok  # only the what-ifs spend it
    both = invoke("whatif_controller", {"controller": "g36", "current": "static", "minutes": 6}, ctx)
    assert not both.ok and "needs 12 plant minutes; the budget is 10" in both.error  # two courses of 6
    clock.now_s += 6.0
    assert invoke("whatif_setpoint", {"setpoint": "supply", "change": 1.0, "minutes": 5}, ctx).ok
    held = threading.Event()
    release = threading.Event()

    def hold_the_twin():
        with lock:
            held.set()
            release.wait(30)

    holder = threading.Thread(target=hold_the_twin)
    holder.start()
    try:
        assert held.wait(30)
        clock.now_s += 60.0
        waiting = []
        asker = threading.Thread(target=lambda: waiting.append(invoke("whatif", {"steps": 4}, ctx)))
        asker.start()  # admitted (1 run), then waits for the twin
        assert wait_until(lambda: budget.running == 1, 30)
        refused = invoke("whatif", {"steps": 4}, ctx)  # refused at once: it does not queue behind the lock
        assert not refused.ok and refused.retry_after_s == 1.0 and "at most 1 at once" in refused.error
    finally:
        release.set()
        holder.join()
    asker.join()
    assert waiting[0].ok and budget.running == 0



def test_a_request_that_is_not_an_object_is_refused_not_read_as_defaults(ctx):
    """`[]` (falsy) was read as "no arguments" and ran a what-if with its defaults (seen by the garbage test)."""
    for payload in (b"[]", b"0", b'"x"', b"[1, 2]"):
        result = invoke("heat_balance", payload, ctx)
        assert not result.ok and "must be a JSON object" in result.error, payload
    for empty in (b"", b"{}", None):  # no arguments: the defaults, as before
        assert "must be a JSON object" not in (invoke("heat_balance", empty, ctx).error or "")

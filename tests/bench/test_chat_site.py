"""The recorded chat-benchmark site: a real twin run in a real history file, read back with the PlantData shape."""

from __future__ import annotations

from datetime import timedelta

import numpy as np
import pytest

from lcmesh.bench.chat_site import (
    DEFAULT_FAULT, ensure_site, load_manifest, manifest_path, open_site, record_site, site_plant,
)  # fmt: skip
from lcmesh.mesh.tools import registry, whatif

MINUTES = 24  # 96 steps: G36 until minute 6, the tree after, pump fault at minute 12 (a short default site)


@pytest.fixture(scope="module")
def site_path(tmp_path_factory):
    path = tmp_path_factory.mktemp("site") / "site.sqlite"
    record_site(path, minutes=MINUTES)
    return path


@pytest.fixture(scope="module")
def site(site_path):
    with open_site(site_path) as data:
        yield data


def test_every_state_is_recorded_with_its_payload(site):
    m = site.manifest
    rows = site.history().states(fields=("blade_temp_max_k", "it_power_w"))
    assert m.steps == MINUTES * 4 and [r["step"] for r in rows] == list(range(m.steps + 1))
    for step in (0, m.fault_step, m.steps):
        state = site.history().state_at(step)
        assert state is not None and len(state.outputs["branch_temp_k"]) == site.system.cabinets.count * 3
        assert state.faults_active == (step > m.fault_step)  # the fault acts from its step's advance on
    assert m.counts["plant_states"] == len(rows)


def test_actions_name_their_decision_and_controller_and_carry_explanations(site):
    m = site.manifest
    rows = site.history().decisions(limit=1000)
    assert len(rows) == m.steps == m.counts["actions"]
    by_step = {r["step"]: r for r in rows}
    assert {by_step[k]["source_controller"] for k in range(m.switch_step)} == {"g36"}
    assert {by_step[k]["source_controller"] for k in range(m.switch_step, m.steps)} == {"tree"}
    assert len({r["decision_id"] for r in rows}) == m.steps  # one decision per step, none held
    assert all(r["explanation"] and "°C" in r["explanation"] for r in rows)
    explanation = site.history().explanations(decision_id=by_step[m.steps - 1]["decision_id"])[0]
    assert explanation["controller"] == "tree" and explanation["facts"]


def test_configuration_switches_from_g36_to_the_controller_with_who_and_why(site):
    m = site.manifest
    rows = site.history().config_changes()
    assert [(r["version"], r["config"]["controller"]) for r in reversed(rows)] == [(1, "g36"), (2, "tree")]
    assert rows[0]["changed_by"] == "ui/shift-lead" and "tree" in rows[0]["reason"]
    assert rows[0]["changes"] == {"controller": ["g36", "tree"]}
    assert rows[0]["created_at"] == (m.site_start + timedelta(seconds=m.switch_step * m.step_s)).isoformat()
    doc = site.config()
    assert doc.version == 2 and doc.config.controller == "tree" and doc.changed_by == "ui/shift-lead"


def test_the_injected_pump_fault_raises_an_alert_at_its_cabinet(site):
    m = site.manifest
    assert m.fault == DEFAULT_FAULT.model_dump() and m.fault_step == MINUTES * 4 // 2
    pump = [r for r in site.history().alerts(active_only=True) if r["kind"] == "pump_degradation"]
    assert len(pump) == 1 and pump[0]["location"] == f"cabinet_{DEFAULT_FAULT.cabinet}"
    assert m.fault_step < pump[0]["step"] <= m.fault_step + 8  # the model residual sees a 50 % head loss at once
    assert pump[0]["severity"] in ("warning", "critical") and pump[0]["prescription"]
    assert m.counts["alerts"] == len(site.history().alerts()) == len(m.alerts)


def test_site_data_has_the_plant_data_shape_the_chat_tools_read(site):
    m = site.manifest
    assert site.latest_state().step == m.steps and site.latest_state().run_id == m.run_id
    applied = site.applied()
    assert applied.step == m.steps - 1 and applied.source_controller == "tree"
    assert applied.decision_id == site.history().decisions(limit=1)[0]["decision_id"]
    agents = site.agents()
    assert len(agents) == 7 and all(a["alive"] for a in agents)
    ctx = registry.ToolContext(system=site.system, data=site)
    controller = registry.invoke("controller", {}, ctx)
    assert controller.ok and controller.result["configured"] == "tree" and controller.result["since_version"] == 2
    assert controller.result["since"] == m.config_versions[1]["at"]
    assert registry.invoke("agents", {}, ctx).result["alive"] == 7


def test_same_seed_gives_the_same_site_and_another_seed_other_ids(site, tmp_path):
    again = record_site(tmp_path / "again.sqlite", minutes=MINUTES)
    other = record_site(tmp_path / "other.sqlite", minutes=MINUTES, seed=1)
    with open_site(tmp_path / "again.sqlite") as a, open_site(tmp_path / "other.sqlite") as b:
        assert a.latest_state() == site.latest_state()  # every field: outputs, ids, timestamps
        assert a.history().decisions(limit=1000) == site.history().decisions(limit=1000)
        assert b.latest_state().outputs == site.latest_state().outputs and b.latest_state().id != site.latest_state().id
    assert again.alerts == site.manifest.alerts and other.run_id != again.run_id


def test_site_plant_continues_from_the_latest_recorded_state(site, site_path):
    plant = site_plant(site_path)
    try:
        state = site.latest_state()
        for name, values in state.outputs.items():
            np.testing.assert_array_equal(np.ravel(plant.out[name]), values, err_msg=name)
        assert plant.faults.pump_degradation[DEFAULT_FAULT.cabinet - 1] == DEFAULT_FAULT.value
        applied = site.applied().action
        np.testing.assert_array_equal(whatif.current_action(plant).supply_temp_setpoint_k,
                                      applied.supply_temp_setpoint_k)  # fmt: skip
        result = whatif.one_step_whatif(plant, {"supply_temp_setpoint_k": 2.0}, steps=4)
        assert result["delta"]["supply_temp_k"].min() > 0.5  # a warmer supply setpoint warms the supply
        np.testing.assert_array_equal(np.ravel(plant.out["blade_temp_k"]), state.outputs["blade_temp_k"])
    finally:
        plant.close()


def test_ensure_site_records_once_per_parameter_set(tmp_path):
    first = ensure_site(tmp_path, minutes=2, seed=3)
    written = manifest_path(first).stat().st_mtime_ns
    assert ensure_site(tmp_path, minutes=2, seed=3) == first
    assert manifest_path(first).stat().st_mtime_ns == written
    other = ensure_site(tmp_path, minutes=2, seed=4)
    assert other.parent != first.parent and load_manifest(other).seed == 4
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([first.parent.name, other.parent.name])


def test_bad_parameters_say_what_would_be_valid(tmp_path, site_path):
    with pytest.raises(ValueError, match="`minutes` must be a whole number of 15 s steps"):
        record_site(tmp_path / "x.sqlite", minutes=10.1)
    with pytest.raises(ValueError, match=r"`fault_at_min` must be in \[0, 20\)"):
        record_site(tmp_path / "x.sqlite", minutes=20, fault_at_min=30)
    with pytest.raises(FileExistsError, match="new file"):
        record_site(site_path, minutes=MINUTES)
    with pytest.raises(ValueError, match=r"`cabinet` must be in 1\.\.5"):  # found by the twin, at the fault's step
        record_site(tmp_path / "x.sqlite", minutes=2, fault={"kind": "pump_degradation", "cabinet": 9})
    assert not list(tmp_path.iterdir())  # no half site left behind

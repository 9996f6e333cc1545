"""The generated FMU: build, cache, standard compliance, raw runner, state, third-party variable maps."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from lcmesh.mesh.tools import whatif
from lcmesh.twin.fmu_build import build_fmu
from lcmesh.twin.fmu_runner import FmuError, validate_fmu
from lcmesh.twin.plant import Plant, PlantAction
from lcmesh.twin.system import parse_system


def test_build_is_cached_by_content_hash(lcopt5):
    first = build_fmu(lcopt5)
    again = build_fmu(lcopt5)
    assert again.cached and again.path == first.path
    other = build_fmu(parse_system({**lcopt5.model_dump(), "load_skew_seed": 3}))
    assert other.path != first.path


def test_fmu_is_a_standard_fmi2_cs_archive_with_sources(lcopt5):
    built = build_fmu(lcopt5)
    names = set(zipfile.ZipFile(built.path).namelist())
    assert "modelDescription.xml" in names
    assert f"binaries/linux64/{built.model_identifier}.so" in names
    assert {"sources/lcmesh_model.c", "sources/fmi2_glue.c", "sources/model_config.h"} <= names
    assert validate_fmu(built.path) == []


def test_stock_fmpy_simulate_runs_it(lcopt5, tmp_path):
    built = build_fmu(lcopt5)
    out = tmp_path / "sim.csv"
    fmpy_cli = Path(sys.executable).with_name("fmpy")
    subprocess.run(
        [str(fmpy_cli), "simulate", str(built.path), "--stop-time", "900", "--output-interval", "15",
         "--output-file", str(out), "--output-variables", "supply_temp_k[1]", "energy_rejected_j"],
        check=True, capture_output=True, timeout=120,
    )  # fmt: skip
    rows = list(csv.DictReader(out.open()))
    assert len(rows) == 61
    assert float(rows[-1]["energy_rejected_j"]) > 0  # the plant cools down from its initial state
    assert 280 < float(rows[-1]["supply_temp_k[1]"]) < 320


def _run(plant: Plant, steps: int, power_w: float = 100e3) -> np.ndarray:
    action = plant.default_action()
    power = np.full(plant.system.n_blade_groups, power_w)
    temps = []
    for _ in range(steps):
        temps.append(plant.step(power, 290.0, action)["blade_temp_k"].copy())
    return np.array(temps)


def test_reset_without_reload_repeats_the_trajectory(plant):
    first = _run(plant, 40)
    plant.reset()
    np.testing.assert_array_equal(_run(plant, 40), first)


def test_state_save_restore_and_serialize(plant):
    _run(plant, 10)
    state = plant.save_state()
    ahead = _run(plant, 20)
    plant.restore_state(state)
    np.testing.assert_array_equal(_run(plant, 20), ahead)

    blob = plant.runner.serialize_state(state)
    restored = plant.runner.deserialize_state(blob, time=state.time)
    plant.restore_state(restored)
    np.testing.assert_array_equal(_run(plant, 20), ahead)
    with pytest.raises(FmuError, match="DeSerializeFMUstate"):
        plant.runner.deserialize_state(blob[:-8])


def _own_inputs(plant: Plant) -> tuple[np.ndarray, float, PlantAction]:
    """The load, wet bulb and setpoints the plant holds now (what a what-if or a resumed Sensor steps with)."""
    return plant.inp["blade_power_w"].copy(), float(plant.inp["wet_bulb_k"]), whatif.current_action(plant)


def test_restore_state_brings_back_the_inputs_saved_with_it(plant):
    _run(plant, 10)
    saved_inputs = {name: view.copy() for name, view in plant.inp.items()}
    state = plant.save_state()
    ahead = plant.step(*_own_inputs(plant))["blade_temp_k"].copy()
    other = plant.default_action()
    other.supply_temp_setpoint_k += 3.0
    plant.step(np.full(plant.system.n_blade_groups, 40e3), 296.0, other)  # different inputs in every block

    restored = plant.runner.deserialize_state(plant.runner.serialize_state(state), time=state.time)  # a checkpoint
    plant.restore_state(restored)
    for name, values in saved_inputs.items():
        np.testing.assert_array_equal(plant.inp[name], values, err_msg=name)
    np.testing.assert_array_equal(plant.step(*_own_inputs(plant))["blade_temp_k"], ahead)


def test_raw_and_list_api_agree(plant):
    runner = plant.runner
    vrs = runner.vrs("blade_temp_k")
    _run(plant, 5)
    raw = plant.out["blade_temp_k"].copy()
    assert runner.get_real_list(vrs) == pytest.approx(raw.tolist(), abs=0)


def test_unknown_variables_are_refused(plant):
    with pytest.raises(FmuError, match="no Real variable or array 'blade_temperature'"):
        plant.runner.vrs("blade_temperature")


def test_a_third_party_fmu_plugs_in_through_a_variable_map(lcopt5, tmp_path):
    """Rename our FMU's variables LC-Opt style, then drive it through a map file."""
    built = build_fmu(lcopt5)
    renames = {f"blade_temp_k[{k + 1}]": f"FrontierNode.BladeGroup[{k + 1}].T" for k in range(15)}
    renames |= {f"blade_power_w[{k + 1}]": f"FrontierNode.BladeGroup[{k + 1}].Q_flow" for k in range(15)}
    renames["wet_bulb_k"] = "T_owb"
    foreign = tmp_path / "LC_Frontier_5Cabinet.fmu"
    with zipfile.ZipFile(built.path) as src, zipfile.ZipFile(foreign, "w") as dst:
        for item in src.infolist():
            data = src.read(item)
            if item.filename == "modelDescription.xml":
                text = data.decode()
                for old, new in renames.items():
                    text = text.replace(f'name="{old}"', f'name="{new}"')
                data = text.encode()
            dst.writestr(item, data)
    mapping = {
        "blade_temp_k": [renames[f"blade_temp_k[{k + 1}]"] for k in range(15)],
        "blade_power_w": [renames[f"blade_power_w[{k + 1}]"] for k in range(15)],
        "wet_bulb_k": "T_owb",
    }
    map_file = tmp_path / "lcopt-map.json"
    map_file.write_text(json.dumps(mapping))
    with Plant(lcopt5, fmu_path=foreign, variable_map=map_file) as mapped, Plant(lcopt5) as ours:
        np.testing.assert_array_equal(_run(mapped, 10), _run(ours, 10))
    bad = tmp_path / "bad-map.json"
    bad.write_text(json.dumps({**mapping, "blade_temp_k": ["nope"]}))
    with pytest.raises(FmuError, match="unknown FMU variables"):
        Plant(lcopt5, fmu_path=foreign, variable_map=bad)


def test_a_custom_system_builds_and_runs(tmp_path):
    system = parse_system({"name": "custom", "cabinets": {"count": 3, "branches": 4, "blade_groups_per_branch": 5},
                           "towers": {"count": 3, "cells": 3}})  # fmt: skip
    with Plant(system) as plant:
        temps = _run(plant, 20, power_w=5e3)
        assert temps.shape == (20, 60) and np.isfinite(temps).all()
        assert plant.out["cell_fan_power_w"].shape == (3, 3)

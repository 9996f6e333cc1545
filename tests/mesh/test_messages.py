from __future__ import annotations

import json

import numpy as np
import pytest
from pydantic import ValidationError

from lcmesh.mesh.messages import (
    ActionModel, AppliedAction, ConfigUpdate, PlantState, observation_to_plant_state, plant_state_from_outputs,
    plant_state_to_observation,
)  # fmt: skip


def _state(plant, lcopt5, step=3):
    power = np.linspace(1e4, 2e4, lcopt5.n_blade_groups)
    return plant_state_from_outputs(plant.out, source="sensor", system=lcopt5, run_id="r1", step=step,
                                    time_s=step * 15.0, wet_bulb_k=290.0, blade_power_w=power, period_s=0.25)


def test_plant_state_round_trips_every_output_block_with_its_shape(plant, lcopt5):
    msg = _state(plant, lcopt5)
    wire = msg.model_dump_json()
    again = PlantState.model_validate_json(wire)
    obs = plant_state_to_observation(again, lcopt5)
    assert set(obs.out) == set(plant.out)
    for name, value in plant.out.items():
        assert obs.out[name].shape == value.shape, name
        np.testing.assert_array_equal(obs.out[name], value)
    assert obs.wet_bulb_k == 290.0 and obs.time_s == 45.0
    assert obs.blade_power_w.shape == (lcopt5.n_blade_groups,)
    back = observation_to_plant_state(obs, lcopt5, source="sensor", run_id="r1", step=3, period_s=0.25)
    assert back.outputs == again.outputs and back.blade_power_w == again.blade_power_w
    assert again.schema_version == 1 and again.source == "sensor" and again.sent_at.tzinfo is not None


def test_a_block_of_the_wrong_size_is_named(plant, lcopt5):
    data = json.loads(_state(plant, lcopt5).model_dump_json())
    data["outputs"]["branch_temp_k"] = data["outputs"]["branch_temp_k"][:-1]
    with pytest.raises(ValueError, match=r"`outputs.branch_temp_k` must hold 15 values"):
        plant_state_to_observation(PlantState.model_validate(data), lcopt5)
    data["outputs"]["branch_temp_k"].append(300.0)
    data["outputs"]["no_such_block"] = [1.0]
    with pytest.raises(ValueError, match="no_such_block"):
        plant_state_to_observation(PlantState.model_validate(data), lcopt5)


def test_non_finite_numbers_and_unknown_fields_are_refused_at_the_edge(plant, lcopt5):
    data = json.loads(_state(plant, lcopt5).model_dump_json())
    with pytest.raises(ValidationError):
        PlantState.model_validate_json(json.dumps({**data, "wet_bulb_k": "NaN"}))
    with pytest.raises(ValidationError, match="extra"):
        PlantState.model_validate({**data, "surprise": 1})
    with pytest.raises(ValidationError, match="source"):
        PlantState.model_validate({**data, "source": "a/b"})


def test_action_model_round_trips_and_ragged_valves_become_unusable(plant):
    action = plant.default_action()
    model = ActionModel.from_action(action)
    back = model.to_action()
    for a, b in zip(action.astuple(), back.astuple()):
        np.testing.assert_array_equal(a, b)
    ragged = model.model_copy(update={"valve_fractions": [[0.5, 0.5], [1.0]]})
    assert ragged.to_action().valve_fractions.shape == (2, 0)
    applied = AppliedAction(source="sensor", run_id="r", step=0, time_s=0.0, source_controller="g36",
                            source_version="1", action=model)
    assert AppliedAction.model_validate_json(applied.model_dump_json()) == applied


def test_config_update_needs_an_author():
    with pytest.raises(ValidationError, match="by"):
        ConfigUpdate(changes={"controller": "g36"}, by="")


@pytest.mark.parametrize("period", [1.0, 59.0])
def test_a_valve_exercise_period_shorter_than_one_stroke_is_refused_not_raised(period):
    from lcmesh.mesh.messages import MeshConfig
    from lcmesh.mesh.settings import MeshSettings

    for model in (MeshConfig, MeshSettings):
        with pytest.raises(ValidationError, match="valve_exercise_s` must be 0 \\(off\\) or >= 60 s"):
            model(valve_exercise_s=period)
    assert MeshConfig(valve_exercise_s=0).valve_exercise_s == 0
    assert MeshConfig(valve_exercise_s=60).valve_exercise_s == 60

"""ASHRAE G36 trim-and-respond (LC-Opt Appendix K): every branch of Algorithms 1 and 2."""

from __future__ import annotations

import numpy as np
import pytest

from lcmesh.twin.controllers import Observation, make_controller
from lcmesh.twin.controllers.g36 import (
    CoolantParams,
    TowerParams,
    cabinet_requests,
    coolant_trim_respond,
    lwt_trim_respond,
    tower_request,
)

P, T = CoolantParams(), TowerParams()


def test_requests_by_condition_and_priority():
    critical = np.array([True, True, False, False, False])
    warning = np.array([True, False, True, False, False])
    busy_rising = np.array([True, True, True, True, False])
    np.testing.assert_array_equal(cabinet_requests(critical, warning, busy_rising), [3, 3, 2, 1, 0])


def test_coolant_trims_up_with_no_requests():
    assert coolant_trim_respond(25.0, 0, P) == pytest.approx(25.1)


def test_coolant_holds_below_the_request_threshold():
    assert coolant_trim_respond(25.0, 1, P) == 25.0  # 0 < requests < Request_threshold (2)


def test_coolant_responds_per_request():
    assert coolant_trim_respond(25.0, 2, P) == pytest.approx(24.4)
    assert coolant_trim_respond(25.0, 5, P) == pytest.approx(23.5)


def test_coolant_clamped_to_its_range():
    assert coolant_trim_respond(29.95, 0, P) == 30.0
    assert coolant_trim_respond(18.5, 9, P) == 18.0


def test_tower_request_hysteresis():
    assert tower_request(18.8, False, 18.0, T) is True  # < 1.05 x 18 = 18.9: on
    assert tower_request(20.0, True, 18.0, T) is True  # between: held
    assert tower_request(20.0, False, 18.0, T) is False  # between: stays off
    assert tower_request(20.8, True, 18.0, T) is False  # > 1.15 x 18 = 20.7: off


def test_lwt_trims_and_responds():
    assert lwt_trim_respond(20.0, 0, 10.0, T) == pytest.approx(20.1)
    assert lwt_trim_respond(20.0, 1, 10.0, T) == pytest.approx(19.7)


def test_lwt_wet_bulb_reset_to_the_optimal_approach():
    # 13.2 - 0.3 = 12.9 < (10 + 3.5) - 0.5: reset to wet bulb + optimal approach
    assert lwt_trim_respond(13.2, 1, 10.0, T) == pytest.approx(13.5)
    assert lwt_trim_respond(13.5, 1, 10.0, T) == pytest.approx(13.2)  # 13.2 >= 13.0: no reset


def test_lwt_limits():
    assert lwt_trim_respond(29.4, 0, 10.0, T) == 29.4  # LWT_max
    # the minimum (wet bulb + 2.8) wins over LWT_max on a hot day
    assert lwt_trim_respond(29.0, 0, 28.0, T) == pytest.approx(30.8)


def test_g36_controller_responds_to_hot_cabinets(plant):
    g36 = make_controller("g36", plant.system)
    hot = np.full(15, 2.5 * plant.system.cabinets.design_heat_w / 3)  # 2.5x the design branch load
    action = plant.default_action()
    for _ in range(40):  # heat the plant up
        out = plant.step(hot, 291.15, action)
    first = None
    for k in range(160):  # 40 min of G36
        action = g36.act(Observation(out, 291.15, hot, k * 15.0))
        first = first if first is not None else float(action.supply_temp_setpoint_k[0])
        out = plant.step(hot, 291.15, action)
    assert g36.last_requests.sum() >= 2
    assert action.supply_temp_setpoint_k[0] < first - 1.0  # responded: colder coolant
    assert g36.tower_requesting  # the CDUs near COOLANT_min ask the towers for colder water
    assert 2.8 - 1e-9 <= action.lw_setpoint_k[0] - 291.15 <= 3.5 + 1e-9  # between the floor and the reset

"""The Sensor's twin host on the real FMU: what its plant states say about the wet bulb, faults numbered from 1,
what a resumed host holds."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from lcmesh.mesh.agents.twin_host import TwinHost
from lcmesh.mesh.history import Checkpoint
from lcmesh.mesh.messages import FaultRequest
from lcmesh.mesh.tools import whatif


@pytest.fixture
def lcopt_host():
    """The lcopt scenario (+15 K on the recorded wet bulb) plus a 2 K offset of the mesh's own."""
    host = TwinHost("lcopt-5", "frontier-2024-04-07", "lcopt", 2.0, instance_name="twin-host-test")
    yield host
    host.close()


def test_plant_states_carry_the_scenario_and_its_wet_bulb_offset(lcopt_host):
    state = lcopt_host.state_message("sensor", period_s=0.25)
    assert state.scenario == "lcopt" and state.wet_bulb_offset_k == pytest.approx(17.0)
    assert state.wet_bulb_k == pytest.approx(float(lcopt_host.trace.wet_bulb_k[0]))  # the offset is in it already


def test_fault_requests_count_from_one(lcopt_host):
    faults = lcopt_host.inject_fault(FaultRequest(kind="pump_degradation", cabinet=1, value=0.4))
    assert faults["pump_degradation"][0] == 0.4 and sum(faults["pump_degradation"]) == 0.4
    faults = lcopt_host.inject_fault(FaultRequest(kind="cell_out", tower=2, cell=1))
    assert faults["cell_out"] == [[0.0, 0.0], [1.0, 0.0]]
    with pytest.raises(ValueError, match=r"`cabinet` must be in 1\.\.5 \(numbered from 1\), got 6"):
        lcopt_host.inject_fault(FaultRequest(kind="valve_stuck", cabinet=6))
    with pytest.raises(ValueError, match="greater than or equal to 1"):
        FaultRequest(kind="valve_stuck", cabinet=0)


def test_a_resumed_host_holds_the_inputs_of_the_checkpointed_step(lcopt_host):
    action = lcopt_host.plant.default_action()
    lcopt_host.begin(action, spinup_hours=0.0)
    for _ in range(4):
        lcopt_host.advance(action)
    action.supply_temp_setpoint_k += 1.5  # the last step applies a setpoint of its own
    lcopt_host.advance(action)
    blob, extra = lcopt_host.checkpoint(action)
    checkpoint = Checkpoint(lcopt_host.run_id, lcopt_host.step, blob, extra)

    resumed = TwinHost("lcopt-5", "frontier-2024-04-07", "lcopt", 2.0, instance_name="twin-host-resumed")
    try:
        resumed.resume(checkpoint)
        for name, values in lcopt_host.plant.inp.items():
            np.testing.assert_array_equal(resumed.plant.inp[name], values, err_msg=name)
        # a what-if on the resumed host (it holds the plant's own inputs) predicts what the original's does
        change = {"supply_temp_setpoint_k": 2.0}
        ahead = whatif.one_step_whatif(lcopt_host.plant, change, steps=2)
        again = whatif.one_step_whatif(resumed.plant, change, steps=2)
        for name in ("baseline", "predicted"):
            for output, values in ahead[name].items():
                np.testing.assert_array_equal(again[name][output], values, err_msg=f"{name} {output}")
    finally:
        resumed.close()


class SetOnCheck(threading.Event):
    """An event that sets itself on its `n`-th look (a stop that arrives mid-spin-up, at a known step)."""

    def __init__(self, n: int):
        super().__init__()
        self.looks, self.n = 0, n

    def is_set(self) -> bool:
        self.looks += 1
        if self.looks >= self.n:
            self.set()
        return super().is_set()


def test_a_stop_during_the_spin_up_ends_it_between_steps(lcopt_host):
    """The spin-up (240 plant steps for an hour) looks at the stop event before every step: stopped at the 4th look,
    it has run 3 steps, begins no run and leaves the reset state alone; unstopped, it runs them all."""
    action = lcopt_host.plant.default_action()
    stop = SetOnCheck(4)
    assert lcopt_host.begin(action, spinup_hours=1.0, stop=stop) is False
    assert stop.looks == 4 and lcopt_host.plant.n_steps_done == 3 and lcopt_host.run_id == ""
    assert lcopt_host.plant._initial is None, "a cut-short spin-up is not the reset state"
    go_on = SetOnCheck(10**6)
    assert lcopt_host.begin(action, spinup_hours=1.0, stop=go_on) is True
    assert go_on.looks == 240 and lcopt_host.run_id and lcopt_host.step == 0

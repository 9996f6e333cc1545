"""The twin as the Sensor agent runs it: plant, trace, step index, faults, checkpoints.

Step ``k`` of a run applies the trace's row ``k mod n_steps`` (the day repeats), so a run can
go on for as long as the demo does. A checkpoint is the serialized FMU state plus the little
the Sensor keeps beside it (the last safe action, the injected faults), written with the step's
history rows; a restarted Sensor resumes from it at the same step.
"""

from __future__ import annotations

import json
import threading

import numpy as np

from lcmesh.mesh.history import Checkpoint
from lcmesh.mesh.messages import ActionModel, FaultRequest, PlantState, new_id, plant_state_from_outputs
from lcmesh.twin.controllers.base import Observation
from lcmesh.twin.plant import Plant, PlantAction
from lcmesh.twin.system import SystemDescription, load_system
from lcmesh.twin.traces import Trace, load_trace, scenario_named


class TwinHost:
    """A running plant on a trace, stepped by the Sensor."""

    def __init__(
        self, system_name: str, trace_spec: str, scenario: str, wet_bulb_offset_k: float, instance_name: str
    ):
        self.system: SystemDescription = load_system(system_name)
        self.trace: Trace = load_trace(
            trace_spec, self.system, scenario=scenario, wet_bulb_offset_k=wet_bulb_offset_k
        )
        # every plant state says what its wet bulb holds besides the recorded one (the page labels it)
        self.wet_bulb_offset_k = scenario_named(scenario).wet_bulb_offset_k + wet_bulb_offset_k
        self.plant = Plant(self.system, instance_name=instance_name)
        self.lock = threading.RLock()  # held while stepping, injecting faults or running a what-if
        self.power_w = np.zeros(self.system.n_blade_groups)
        self.step = 0
        self.run_id = ""

    @property
    def system_hash(self) -> str:
        return self.system.content_hash()

    def inputs(self, step: int) -> tuple[float, np.ndarray]:
        """Wet bulb and blade power of plant step `step` (into the shared power buffer)."""
        row = step % self.trace.n_steps
        return float(self.trace.wet_bulb_k[row]), self.trace.blade_power_w(row, out=self.power_w)

    def observation(self) -> Observation:
        wet_bulb_k, power = self.inputs(self.step)
        return Observation(self.plant.out, wet_bulb_k, power, self.step * self.system.step_s)

    def begin(self, action: PlantAction, spinup_hours: float, stop: threading.Event | None = None) -> bool:
        """A new run: spin up at the trace's first row with `action`, then step 0. False, and no run begun, if `stop`
        is set during the spin-up (it is checked between steps: a stop does not wait for the warm-up)."""
        wet_bulb_k, power = self.inputs(0)
        with self.lock:
            if spinup_hours > 0 and not self.plant.spin_up(power, wet_bulb_k, action, hours=spinup_hours, stop=stop):
                return False
            self.plant.reset()
        self.run_id, self.step = new_id(), 0
        return True

    def resume(self, checkpoint: Checkpoint) -> PlantAction:
        """Continue `checkpoint`'s run at its step; returns the last safe action it held."""
        with self.lock:
            state = self.plant.runner.deserialize_state(checkpoint.fmu_state, time=checkpoint.step * self.system.step_s)
            self.plant.restore_state(state)
            self.plant.free_state(state)
            extra = json.loads(checkpoint.sensor_state)
            faults = extra.get("faults") or {}
            if faults and self.plant._faults is not None:
                self.plant.set_faults(**{k: np.asarray(v) for k, v in faults.items()})
        self.run_id, self.step = checkpoint.run_id, checkpoint.step
        return ActionModel.model_validate(extra["action"]).to_action()

    def state_message(self, source: str, period_s: float) -> PlantState:
        """The PlantState of the current step (outputs so far, inputs of the coming step)."""
        wet_bulb_k, power = self.inputs(self.step)
        return plant_state_from_outputs(
            self.plant.out, source=source, system=self.system, run_id=self.run_id, step=self.step,
            time_s=self.step * self.system.step_s, wet_bulb_k=wet_bulb_k, blade_power_w=power, period_s=period_s,
            faults_active=self.plant.faults.active, scenario=self.trace.scenario,
            wet_bulb_offset_k=self.wet_bulb_offset_k,
        )  # fmt: skip

    def advance(self, action: PlantAction) -> None:
        """Apply `action` for the current step and step the plant."""
        wet_bulb_k, power = self.inputs(self.step)
        with self.lock:
            self.plant.step(power, wet_bulb_k, action)
        self.step += 1

    def checkpoint(self, last_action: PlantAction) -> tuple[bytes, str]:
        """(serialized FMU state, sensor-state JSON) of the current step."""
        with self.lock:
            state = self.plant.save_state()
            try:
                blob = self.plant.runner.serialize_state(state)
            finally:
                self.plant.free_state(state)
        faults = self.faults() if self.plant.faults.active else {}
        faults.pop("active", None)
        extra = {"action": ActionModel.from_action(last_action).model_dump(), "faults": faults}
        return blob, json.dumps(extra)

    def inject_fault(self, req: FaultRequest) -> dict:
        """Apply a FaultRequest; ValueError naming the field if an index or value is out of range."""
        s = self.system
        C, N, m = s.cabinets.count, s.towers.count, s.towers.cells
        f = self.plant.faults
        with self.lock:
            if req.kind == "clear":
                self.plant.set_faults(pump_degradation=0.0, valve_stuck=0.0, cell_out=0.0, sensor_bias_k=0.0)
            elif req.kind == "cell_out":
                tower, cell = _index("tower", req.tower, N), _index("cell", req.cell, m)
                value = np.array(f.cell_out)
                value[tower, cell] = _range("value", req.value, 0.0, 1.0)
                self.plant.set_faults(cell_out=value)
            else:
                cabinet = _index("cabinet", req.cabinet, C)
                field, low, high = {"pump_degradation": ("pump_degradation", 0.0, 0.95),
                                    "valve_stuck": ("valve_stuck", 0.0, 1.0),
                                    "sensor_bias": ("sensor_bias_k", -20.0, 20.0)}[req.kind]  # fmt: skip
                value = np.array(getattr(f, field))
                value[cabinet] = _range("value", req.value, low, high)
                self.plant.set_faults(**{field: value})
        return self.faults()

    def faults(self) -> dict:
        """The injected faults as lists, and whether any is active."""
        f = self.plant.faults
        return {"pump_degradation": f.pump_degradation.tolist(), "valve_stuck": f.valve_stuck.tolist(),
                "cell_out": f.cell_out.tolist(), "sensor_bias_k": f.sensor_bias_k.tolist(),
                "active": f.active}  # fmt: skip

    def close(self) -> None:
        with self.lock:
            self.plant.close()


def _index(name: str, number: int | None, count: int) -> int:
    """The array index of a 1-based `number` (a FaultRequest's cabinet, tower or cell); ValueError naming it."""
    if number is None or not 1 <= number <= count:
        raise ValueError(f"`{name}` must be in 1..{count} (numbered from 1), got {number}")
    return number - 1


def _range(name: str, value: float, low: float, high: float) -> float:
    if not low <= value <= high:
        raise ValueError(f"`{name}` must be in [{low}, {high}] for this fault, got {value}")
    return value

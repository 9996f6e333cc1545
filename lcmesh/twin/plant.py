"""The twin as typed numpy arrays: one object per running plant, over an FmuRunner.

Inputs and outputs travel in two pre-allocated buffers (one fmi2SetReal and one fmi2GetReal
per step); ``plant.out[name]`` are views into the output buffer, shaped per block.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from lcmesh.twin.fmu_build import build_fmu
from lcmesh.twin.fmu_layout import build_layout
from lcmesh.twin.fmu_runner import FmuRunner, FmuState
from lcmesh.twin.system import SystemDescription

ACTION_BLOCKS = ("supply_temp_setpoint_k", "dp_setpoint_pa", "valve_fraction", "lw_setpoint_k")
FAULT_BLOCKS = ("fault_pump_degradation", "fault_valve_stuck", "fault_cell_out", "fault_sensor_bias_k")
DEVIATION_BLOCKS = ("deviation_hx_ua_factor", "deviation_pump_head_factor", "deviation_ct_approach_factor")
OUTPUT_BLOCKS = (
    "blade_temp_k", "branch_temp_k", "branch_max_temp_k", "branch_power_w", "branch_flow_kg_s",
    "applied_valve_fraction", "supply_temp_k", "supply_temp_measured_k", "return_temp_k",
    "secondary_flow_kg_s", "cabinet_dp_pa", "pump_speed", "cdu_pump_power_w", "primary_valve",
    "primary_flow_kg_s", "primary_return_temp_k", "cdu_heat_w", "applied_supply_setpoint_k",
    "applied_dp_setpoint_pa", "htw_supply_temp_k", "htw_return_temp_k", "htw_flow_kg_s", "htw_pump_power_w",
    "ehx_heat_w", "ct_water_flow_kg_s", "ct_entering_temp_k", "ct_leaving_temp_k", "ct_basin_temp_k",
    "fan_speed", "cells_active", "ct_pump_power_w", "approach_k", "applied_lw_setpoint_k", "cell_fan_power_w",
    "cell_heat_w", "heat_in_w", "heat_rejected_w", "heat_recovered_w", "district_return_temp_k",
    "stored_energy_rate_w", "stored_energy_j", "stored_energy_change_j", "energy_in_j", "energy_rejected_j",
    "energy_recovered_j", "ct_fan_power_w", "pump_power_w", "it_cooling_w", "it_power_w", "throttled_power_w",
)  # fmt: skip


REQUIRED_OUTPUTS = ("blade_temp_k", "branch_temp_k", "branch_power_w", "cell_fan_power_w", "ct_leaving_temp_k")


@dataclass
class PlantAction:
    """Setpoints for one step, SI units: what the controllers decide."""

    supply_temp_setpoint_k: np.ndarray  # (C,)
    dp_setpoint_pa: np.ndarray  # (C,)
    valve_fractions: np.ndarray  # (C, B), rows sum to 1
    lw_setpoint_k: np.ndarray  # (N,)

    def copy(self) -> "PlantAction":
        return PlantAction(*(np.array(a, dtype=float) for a in self.astuple()))

    def astuple(self) -> tuple[np.ndarray, ...]:
        return (self.supply_temp_setpoint_k, self.dp_setpoint_pa, self.valve_fractions, self.lw_setpoint_k)


@dataclass
class Faults:
    """Injected faults (all off by default)."""

    pump_degradation: np.ndarray  # (C,) head loss 0..0.95
    valve_stuck: np.ndarray  # (C,) 1 = primary valve frozen
    cell_out: np.ndarray  # (N, m) 1 = cell out of service
    sensor_bias_k: np.ndarray  # (C,) supply-temperature sensor bias
    active: bool = field(default=False)


@dataclass
class Deviations:
    """How the plant differs from its description (all 1 by default): factors on the described parameters."""

    hx_ua_factor: np.ndarray  # (C,) CDU heat exchanger UA (calibration, fouling)
    pump_head_factor: np.ndarray  # (C,) CDU pump curve head, both terms of a s^2 - b q^2
    ct_approach_factor: np.ndarray  # (N,) the tower approach correlation


class Plant:
    """A running twin of `system`."""

    def __init__(
        self,
        system: SystemDescription,
        *,
        fmu_path: str | Path | None = None,
        variable_map: dict | str | Path | None = None,
        instance_name: str = "lcmesh",
    ):
        self.system = system
        if fmu_path is None:
            built = build_fmu(system)
            self.fmu_path, layout = built.path, built.layout
        else:
            self.fmu_path, layout = Path(fmu_path), build_layout(system)
        self.runner = FmuRunner(self.fmu_path, variable_map=variable_map, instance_name=instance_name)
        C = system.cabinets.count
        N, m = system.towers.count, system.towers.cells
        self.shapes = {b.name: b.shape for b in layout.blocks}
        self._inputs = self.runner.channel("blade_power_w", "wet_bulb_k", *ACTION_BLOCKS)
        self.inp = _views(self._inputs.values, ("blade_power_w", "wet_bulb_k", *ACTION_BLOCKS), self.shapes)
        self._faults = self.runner.channel(*FAULT_BLOCKS) if all(map(self.runner.has, FAULT_BLOCKS)) else None
        has_deviations = all(map(self.runner.has, DEVIATION_BLOCKS))
        self._deviations = self.runner.channel(*DEVIATION_BLOCKS) if has_deviations else None
        present = [b for b in OUTPUT_BLOCKS if self.runner.has(b)]
        missing = [b for b in REQUIRED_OUTPUTS if b not in present]
        if missing:
            raise ValueError(f"{self.fmu_path.name} lacks required outputs {missing}; map them in the variable map")
        self._outputs = self.runner.channel(*present)
        self.out = _views(self._outputs.values, present, self.shapes)
        self.faults = Faults(np.zeros(C), np.zeros(C), np.zeros((N, m)), np.zeros(C))
        self.deviations = Deviations(np.ones(C), np.ones(C), np.ones(N))
        self.step_s = system.step_s
        self._initial: FmuState | None = None
        self.runner.initialize()
        self._outputs.read()
        self.n_steps_done = 0

    def default_action(self) -> PlantAction:
        """The description's design setpoints, equal valve split."""
        s = self.system
        C, B, N = s.cabinets.count, s.cabinets.branches, s.towers.count
        return PlantAction(
            np.full(C, s.cabinets.cdu.supply_temp_setpoint_k),
            np.full(C, s.cabinets.cdu.dp_setpoint_pa),
            np.full((C, B), 1.0 / B),
            np.full(N, s.towers.lw_setpoint_k),
        )

    def step(self, blade_power_w: np.ndarray, wet_bulb_k: float, action: PlantAction) -> dict[str, np.ndarray]:
        """Apply inputs, advance one control step, return the output views (valid until the next step)."""
        inp = self.inp
        inp["blade_power_w"][:] = blade_power_w
        inp["wet_bulb_k"][...] = wet_bulb_k
        inp["supply_temp_setpoint_k"][:] = action.supply_temp_setpoint_k
        inp["dp_setpoint_pa"][:] = action.dp_setpoint_pa
        inp["valve_fraction"][:] = action.valve_fractions
        inp["lw_setpoint_k"][:] = action.lw_setpoint_k
        self._inputs.write()
        self.runner.do_step(self.step_s)
        self._outputs.read()
        self.n_steps_done += 1
        return self.out

    def set_faults(self, **changes: np.ndarray | float) -> None:
        """Change fault inputs, e.g. ``set_faults(pump_degradation=[0.4, 0, 0, 0, 0])``."""
        if self._faults is None:
            raise ValueError("this FMU has no fault inputs")
        _write_inputs(self._faults, self.faults, changes)
        self.faults.active = bool(self._faults.values.any())

    def set_deviations(self, **changes: np.ndarray | float) -> None:
        """Change how the plant differs from its description, e.g. ``set_deviations(hx_ua_factor=0.85)``.

        Factors on the described parameters (1 = as described, clamped to [0.1, 10] in the model). Like the
        fault inputs they travel with the FMU state: ``restore_state`` brings back the ones saved with it.
        """
        if self._deviations is None:
            raise ValueError("this FMU has no deviation inputs")
        _write_inputs(self._deviations, self.deviations, changes)

    # --- state -----------------------------------------------------------
    def spin_up(self, blade_power_w: np.ndarray, wet_bulb_k: float, action: PlantAction, hours: float = 1.0,
                stop: threading.Event | None = None) -> bool:  # fmt: skip
        """Run at constant inputs past the start-up transient, and make that the reset state.

        False, with the reset state untouched, if `stop` is set before the end (checked before every step)."""
        for _ in range(int(round(hours * 3600 / self.step_s))):
            if stop is not None and stop.is_set():
                return False
            self.step(blade_power_w, wet_bulb_k, action)
        if self._initial is not None:
            self.runner.free_state(self._initial)
        self._initial = self.runner.save_state()
        self.n_steps_done = 0
        return True

    def restart(self) -> dict[str, np.ndarray]:
        """Back to the FMU's initial state, forgetting any spun-up state; the faults and deviations set stay set.

        A run that starts here does not depend on what the plant ran before (cells staged on, integrators).
        """
        if self._initial is not None:
            self.runner.free_state(self._initial)
            self._initial = None
        self.runner.reset()
        for channel, mirror in ((self._faults, self.faults), (self._deviations, self.deviations)):
            if channel is not None:
                channel.values[:] = np.concatenate([array.ravel() for array in _input_arrays(mirror)])
                channel.write()
        self._outputs.read()
        self._read_inputs()
        self.n_steps_done = 0
        return self.out

    def reset(self) -> dict[str, np.ndarray]:
        """Back to the spun-up state (or the FMU's initial state), without re-loading."""
        if self._initial is not None:
            self.runner.restore_state(self._initial)
        else:
            self.runner.reset()
        self._outputs.read()
        self._read_inputs()
        self.n_steps_done = 0
        return self.out

    def save_state(self) -> FmuState:
        """The FMU state, inputs included (load, wet bulb, setpoints, faults, deviations)."""
        return self.runner.save_state()

    def restore_state(self, state: FmuState) -> None:
        """Back to `state`: its outputs and every input saved with it (load, wet bulb, setpoints, faults, deviations)."""
        self.runner.restore_state(state)
        self._outputs.read()
        self._read_inputs()

    def _read_inputs(self) -> None:
        """Inputs are FMU state: after a restore, ``inp``, ``faults`` and ``deviations`` show the FMU's.

        Without this a plant resumed from a checkpoint would report (and a what-if would hold) the inputs
        it last stepped with in this process, not the ones the checkpoint's step applied.
        """
        self._inputs.read()  # `inp` are views into this buffer
        for channel, mirror in ((self._faults, self.faults), (self._deviations, self.deviations)):
            if channel is None:
                continue
            values, offset = channel.read(), 0
            for array in _input_arrays(mirror):
                array[...] = values[offset : offset + array.size].reshape(array.shape)
                offset += array.size
        self.faults.active = bool(self._faults is not None and self._faults.values.any())

    def free_state(self, state: FmuState) -> None:
        self.runner.free_state(state)

    def close(self) -> None:
        self.runner.close()

    def __enter__(self) -> "Plant":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _views(buffer: np.ndarray, names, shapes) -> dict[str, np.ndarray]:
    views, offset = {}, 0
    for name in names:
        shape = shapes[name]
        size = int(np.prod(shape)) if shape else 1
        views[name] = buffer[offset : offset + size].reshape(shape)
        offset += size
    return views


def _input_arrays(group) -> list[np.ndarray]:
    """`group`'s input arrays in field order: the FMU input block's layout (faults, deviations)."""
    return [value for value in vars(group).values() if isinstance(value, np.ndarray)]


def _write_inputs(block, group, changes: dict) -> None:
    """Set `changes` on `group`'s arrays, then write them all to the FMU input `block`."""
    for name, value in changes.items():
        getattr(group, name)[...] = value  # AttributeError names a bad field
    block.values[:] = np.concatenate([array.ravel() for array in _input_arrays(group)])
    block.write()

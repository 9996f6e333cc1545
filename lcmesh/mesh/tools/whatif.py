"""What-if look-ahead on the live twin: run a changed action forward from the plant's current state, then restore it.

The FMU saves and restores its full state (fmi2GetFMUstate / fmi2SetFMUstate), so a look-ahead leaves
the plant exactly as it was: the next real step is bit-identical with or without a what-if in between.
Both branches (baseline = the action held as it is, candidate = the changed action) start from the same
saved state and see the same load and wet bulb, so the difference is the action's effect alone.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from lcmesh.twin.plant import Plant, PlantAction

ACTION_FIELDS = ("supply_temp_setpoint_k", "dp_setpoint_pa", "valve_fractions", "lw_setpoint_k")
# The outputs a what-if reports by default: what an operator asks about a setpoint change.
WHATIF_OUTPUTS = (
    "blade_temp_k", "branch_max_temp_k", "supply_temp_k", "return_temp_k", "secondary_flow_kg_s",
    "primary_valve", "cdu_heat_w", "ct_leaving_temp_k", "fan_speed", "cells_active", "approach_k",
    "ct_fan_power_w", "pump_power_w", "it_cooling_w", "htw_supply_temp_k",
)  # fmt: skip
MAX_WHATIF_STEPS = 2880  # 12 h of 15 s steps: beyond that a what-if is a scenario run, not a look-ahead


def current_action(plant: Plant) -> PlantAction:
    """The setpoints the plant holds now (its last inputs), as a PlantAction copy."""
    inp = plant.inp
    return PlantAction(
        np.array(inp["supply_temp_setpoint_k"], dtype=float),
        np.array(inp["dp_setpoint_pa"], dtype=float),
        np.array(inp["valve_fraction"], dtype=float),
        np.array(inp["lw_setpoint_k"], dtype=float),
    )


def apply_delta(base: PlantAction, delta: Mapping[str, float | Sequence[float] | np.ndarray]) -> PlantAction:
    """`base` with `delta` added field by field (e.g. ``{"supply_temp_setpoint_k": 2.0}`` raises every CDU 2 K).

    ``valve_fractions`` in a delta is added too; rows are left for the twin to clamp and normalize.
    """
    unknown = sorted(set(delta) - set(ACTION_FIELDS))
    if unknown:
        raise ValueError(f"unknown action field(s) {unknown}; valid: {', '.join(ACTION_FIELDS)}")
    new = base.copy()
    for name, value in delta.items():
        target = getattr(new, name)
        try:
            target += np.broadcast_to(np.asarray(value, dtype=float), target.shape)
        except ValueError:
            raise ValueError(f"`{name}` delta must broadcast to shape {target.shape}, got {np.shape(value)}") from None
    return new


def _check_action(plant: Plant, action: PlantAction) -> None:
    s = plant.system
    shapes = {
        "supply_temp_setpoint_k": (s.cabinets.count,),
        "dp_setpoint_pa": (s.cabinets.count,),
        "valve_fractions": (s.cabinets.count, s.cabinets.branches),
        "lw_setpoint_k": (s.towers.count,),
    }
    for name, shape in shapes.items():
        value = np.asarray(getattr(action, name))
        if value.shape != shape:
            raise ValueError(f"`{name}` must have shape {shape}, got {value.shape}")
        if not np.all(np.isfinite(value)):
            raise ValueError(f"`{name}` must be finite, got {value.tolist()}")


def one_step_whatif(
    plant: Plant,
    change: PlantAction | Mapping[str, float | Sequence[float] | np.ndarray],
    blade_power_w: np.ndarray | None = None,
    wet_bulb_k: float | None = None,
    *,
    steps: int = 1,
    baseline: PlantAction | None = None,
    outputs: Sequence[str] = WHATIF_OUTPUTS,
) -> dict:
    """Predict the plant `steps` control steps ahead under `change` vs holding `baseline`, then restore the plant.

    `change` is a full PlantAction or a delta mapping added to `baseline` (default: the setpoints the plant
    holds now). Load and wet bulb are held at `blade_power_w` / `wet_bulb_k` (default: the plant's last
    inputs). Returns ``{"horizon_steps", "horizon_s", "action", "baseline_action", "baseline", "predicted",
    "delta"}``; the last three map each output name to an array at the end of the horizon (step-mean
    outputs such as powers are means over the final step).
    """
    if not 1 <= steps <= MAX_WHATIF_STEPS:
        raise ValueError(f"`steps` must be in [1, {MAX_WHATIF_STEPS}], got {steps}")
    unknown = [name for name in outputs if name not in plant.out]
    if unknown:
        raise ValueError(f"unknown output(s) {unknown}; valid: {', '.join(plant.out)}")
    base = baseline.copy() if baseline is not None else current_action(plant)
    candidate = change.copy() if isinstance(change, PlantAction) else apply_delta(base, change)
    _check_action(plant, base)
    _check_action(plant, candidate)
    power = np.array(plant.inp["blade_power_w"] if blade_power_w is None else blade_power_w, dtype=float)
    if power.shape != plant.inp["blade_power_w"].shape or not np.all(np.isfinite(power)):
        raise ValueError(f"`blade_power_w` must be {plant.inp['blade_power_w'].shape} finite watts")
    wet_bulb = float(plant.inp["wet_bulb_k"] if wet_bulb_k is None else wet_bulb_k)
    if not np.isfinite(wet_bulb):
        raise ValueError(f"`wet_bulb_k` must be finite, got {wet_bulb_k}")

    results = {}
    with RestoredPlant(plant) as start:
        for label, action in (("baseline", base), ("predicted", candidate)):
            plant.restore_state(start)
            for _ in range(steps):
                out = plant.step(power, wet_bulb, action)
            results[label] = {name: np.array(out[name], dtype=float) for name in outputs}
    return {
        "horizon_steps": steps,
        "horizon_s": steps * plant.step_s,
        "action": _action_dict(candidate),
        "baseline_action": _action_dict(base),
        "baseline": results["baseline"],
        "predicted": results["predicted"],
        "delta": {name: results["predicted"][name] - results["baseline"][name] for name in outputs},
    }


def _action_dict(action: PlantAction) -> dict[str, np.ndarray]:
    return dict(zip(ACTION_FIELDS, (np.array(a, dtype=float) for a in action.astuple())))


class RestoredPlant:
    """Saves the FMU state (its inputs with it) and the step count; puts both back on exit (every tool that runs the
    live twin ahead: the what-ifs here and `whatif_controller`)."""

    def __init__(self, plant: Plant):
        self.plant = plant

    def __enter__(self):
        p = self.plant
        self.state = p.save_state()
        self.n_steps_done = p.n_steps_done
        return self.state

    def __exit__(self, *exc) -> None:
        p = self.plant
        try:
            p.restore_state(self.state)
        finally:
            p.free_state(self.state)
        p.n_steps_done = self.n_steps_done

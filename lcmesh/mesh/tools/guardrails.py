"""Guardrails: the limits every action passes before it reaches the plant.

A proposal with the wrong shape or a non-finite number is *rejected* (the Sensor then holds the
last safe action or falls back to G36). Anything else is *clamped*, and every clamp is reported
with the field, the index, the proposed and applied values and the reason, so the audit trail
says exactly what changed. Order: range limits, then rate limits against the previous applied
action, then the tower approach (the leaving water can not be colder than the wet bulb plus the
minimum approach, so that one wins over the rate limit), then the valve split (fractions in
[v_min, 1] summing to 1).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from lcmesh.twin.plant import PlantAction
from lcmesh.twin.system import PSI_TO_PA, SystemDescription

_K = 273.15


class GuardrailLimits(BaseModel):
    """Setpoint ranges, per-step rate limits and the tower's minimum approach (SI units)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    supply_temp_min_k: float = Field(18.0 + _K, ge=273.15, le=373.15)
    supply_temp_max_k: float = Field(40.0 + _K, ge=273.15, le=373.15)
    dp_min_pa: float = Field(25.0 * PSI_TO_PA, gt=0)
    dp_max_pa: float = Field(38.0 * PSI_TO_PA, gt=0)
    valve_fraction_min: float = Field(0.05, ge=0, lt=1, description="v_min of every branch valve")
    lw_min_k: float = Field(10.0 + _K, ge=273.15, le=373.15)
    lw_max_k: float = Field(45.0 + _K, ge=273.15, le=373.15)
    min_approach_k: float = Field(2.8, ge=0, le=20, description="leaving water >= wet bulb + this")
    supply_temp_rate_k: float = Field(2.0, gt=0, description="largest supply setpoint change per step")
    dp_rate_pa: float = Field(5.0 * PSI_TO_PA, gt=0, description="largest dp setpoint change per step")
    lw_rate_k: float = Field(2.0, gt=0, description="largest leaving-water setpoint change per step")
    valve_rate: float = Field(0.5, gt=0, le=1, description="largest valve fraction change per step")

    @model_validator(mode="after")
    def _ranges(self) -> "GuardrailLimits":
        for low, high in (("supply_temp_min_k", "supply_temp_max_k"), ("dp_min_pa", "dp_max_pa"),
                          ("lw_min_k", "lw_max_k")):  # fmt: skip
            if getattr(self, low) >= getattr(self, high):
                raise ValueError(f"`{low}` ({getattr(self, low)}) must be < `{high}` ({getattr(self, high)})")
        return self

    def check_system(self, system: SystemDescription) -> None:
        """Raise ValueError if the limits can not be met on `system` (v_min times branches above 1)."""
        branches = system.cabinets.branches
        if self.valve_fraction_min * branches > 1.0 + 1e-12:
            raise ValueError(
                f"`valve_fraction_min` = {self.valve_fraction_min} times {branches} branches exceeds 1; "
                f"it must be <= {1.0 / branches:.4f} for {system.name}"
            )


class Clamp(BaseModel):
    """One value the guardrails changed, and why."""

    model_config = ConfigDict(extra="forbid")

    field: str
    index: list[int] = Field([], description="0-based array index into `field` (the UI's API shows it from 1)")
    proposed: float
    applied: float
    reason: str


@dataclass
class GuardrailResult:
    """The action to apply (None when rejected), its clamps, and the rejection reason if any."""

    action: PlantAction | None
    clamps: list[Clamp] = field(default_factory=list)
    rejected: str | None = None


def expected_shapes(system: SystemDescription) -> dict[str, tuple[int, ...]]:
    C, B, N = system.cabinets.count, system.cabinets.branches, system.towers.count
    return {"supply_temp_setpoint_k": (C,), "dp_setpoint_pa": (C,), "valve_fractions": (C, B), "lw_setpoint_k": (N,)}


def check_action(action: PlantAction, system: SystemDescription) -> str | None:
    """Why `action` can not be applied at all (wrong shape, non-finite), or None."""
    for (name, shape), value in zip(expected_shapes(system).items(), action.astuple()):
        array = np.asarray(value, dtype=float)
        if array.shape != shape:
            return f"`{name}` must have shape {shape}, got {array.shape}"
        if not np.isfinite(array).all():  # the index is looked for only when there is one to say
            return f"`{name}` holds a non-finite value at flat index {int(np.flatnonzero(~np.isfinite(array))[0])}"
    return None


def apply_guardrails(
    proposed: PlantAction,
    previous: PlantAction,
    wet_bulb_k: float,
    limits: GuardrailLimits,
    system: SystemDescription,
) -> GuardrailResult:
    """Clamp `proposed` into `limits` relative to `previous`; reject it if it is malformed."""
    problem = check_action(proposed, system)
    if problem is not None:
        return GuardrailResult(None, rejected=problem)
    clamps: list[Clamp] = []
    supply = _limit(proposed.supply_temp_setpoint_k, previous.supply_temp_setpoint_k, "supply_temp_setpoint_k",
                    limits.supply_temp_min_k, limits.supply_temp_max_k, limits.supply_temp_rate_k, clamps)  # fmt: skip
    dp = _limit(proposed.dp_setpoint_pa, previous.dp_setpoint_pa, "dp_setpoint_pa",
                limits.dp_min_pa, limits.dp_max_pa, limits.dp_rate_pa, clamps)  # fmt: skip
    lw = _limit(proposed.lw_setpoint_k, previous.lw_setpoint_k, "lw_setpoint_k",
                limits.lw_min_k, limits.lw_max_k, limits.lw_rate_k, clamps)  # fmt: skip
    lw_floor = float(wet_bulb_k) + limits.min_approach_k
    low = lw < lw_floor
    why = f"below wet bulb {wet_bulb_k:.2f} K + minimum approach {limits.min_approach_k} K"
    for i in np.flatnonzero(low):
        clamps.append(Clamp(field="lw_setpoint_k", index=[int(i)], proposed=float(lw[i]), applied=lw_floor,
                            reason=why))  # fmt: skip
    lw = np.where(low, lw_floor, lw)
    valves = _limit_valves(np.asarray(proposed.valve_fractions, dtype=float),
                           np.asarray(previous.valve_fractions, dtype=float), limits, clamps)  # fmt: skip
    return GuardrailResult(PlantAction(supply, dp, valves, lw), clamps)


def _limit(value, previous, name: str, low: float, high: float, rate: float, clamps: list[Clamp]) -> np.ndarray:
    # ufuncs rather than np.clip and np.array_equal: at every step of every run, on arrays of a few values, the
    # wrappers' Python cost was most of the guardrails' (bench twin: the guarded loop against the bare one)
    proposed = np.asarray(value, dtype=float)
    ranged = np.minimum(np.maximum(proposed, low), high)
    prev = np.asarray(previous, dtype=float)
    limited = np.minimum(np.maximum(ranged, prev - rate), prev + rate)
    if (limited == proposed).all():
        return limited  # nothing clamped (the common case, at every step of every run)
    for i in np.flatnonzero(ranged != proposed):
        clamps.append(Clamp(field=name, index=[int(i)], proposed=float(proposed[i]), applied=float(limited[i]),
                            reason=f"outside [{low:.6g}, {high:.6g}]"))  # fmt: skip
    for i in np.flatnonzero((limited != ranged) & (ranged == proposed)):
        why = f"change from {prev[i]:.6g} exceeds the rate limit {rate:.6g} per step"
        clamps.append(Clamp(field=name, index=[int(i)], proposed=float(proposed[i]), applied=float(limited[i]),
                            reason=why))  # fmt: skip
    return limited


def _limit_valves(proposed: np.ndarray, previous: np.ndarray, limits: GuardrailLimits, clamps: list[Clamp]):
    v_min, rate = limits.valve_fraction_min, limits.valve_rate
    if (np.abs(proposed - previous) <= rate).all() and proposed.min() >= v_min \
            and (np.abs(proposed.sum(axis=1) - 1.0) <= 1e-10).all():
        # within the rate limit and a valid split already: the projection would move no value by 1e-9, the
        # threshold below, so the split passes bit for bit, as it would through the full path (the common case)
        return proposed.copy()
    limited = np.minimum(np.maximum(proposed, previous - rate), previous + rate)
    projected = project_valve_splits(limited, v_min)
    changed = np.abs(projected - proposed) > 1e-9
    if not changed.any():
        return proposed.copy()  # a valid split passes bit for bit (the projection may round its last digit)
    for i, j in zip(*np.nonzero(changed)):
        if abs(limited[i, j] - proposed[i, j]) > 1e-12:
            reason = f"change from {previous[i, j]:.4f} exceeds the rate limit {rate} per step"
        elif proposed[i, j] < v_min:
            reason = f"below v_min = {v_min}"
        else:
            reason = f"cabinet {i + 1} split renormalized to fractions in [{v_min}, 1] summing to 1"
        clamps.append(Clamp(field="valve_fractions", index=[int(i), int(j)], proposed=float(proposed[i, j]),
                            applied=float(projected[i, j]), reason=reason))  # fmt: skip
    return projected


def project_valve_splits(rows: np.ndarray, v_min: float) -> np.ndarray:
    """:func:`project_valve_split` on every row of (C, B) at once (the guardrails run it at every step; a
    frontier-full plant has 25 cabinets, and a loop over them cost a run 3x its speed)."""
    x = np.maximum(np.asarray(rows, dtype=float), 0.0).reshape(-1, np.shape(rows)[-1])
    n = x.shape[1]
    x[x.sum(axis=1) <= 0.0] = 1.0 / n  # an all-zero or negative row: the equal split
    pinned = np.zeros(x.shape, dtype=bool)
    for _ in range(n):
        free = ~pinned
        room = 1.0 - v_min * pinned.sum(axis=1)
        free_sum = np.where(free, x, 0.0).sum(axis=1)
        spread = room / np.maximum(free.sum(axis=1), 1)
        scaled = x * (room / np.where(free_sum > 0.0, free_sum, 1.0))[:, None]
        x = np.where(free, np.where((free_sum > 0.0)[:, None], scaled, spread[:, None]), v_min)
        newly = free & (x < v_min)
        if not newly.any():
            break
        pinned |= newly
    return x.reshape(np.shape(rows))


def project_valve_split(fractions: np.ndarray, v_min: float) -> np.ndarray:
    """Fractions >= v_min summing to 1, as close to `fractions` as the clamp-and-rescale allows.

    Values below v_min are raised to it; the rest are rescaled to fill what is left, repeated
    until none falls below. An all-zero or negative row becomes the equal split.
    """
    x = np.maximum(np.asarray(fractions, dtype=float), 0.0)
    n = x.size
    if x.sum() <= 0.0:
        return np.full(n, 1.0 / n)
    pinned = np.zeros(n, dtype=bool)
    for _ in range(n):
        free = ~pinned
        room = 1.0 - v_min * pinned.sum()
        free_sum = x[free].sum()
        if free_sum <= 0.0:
            x[free] = room / free.sum()
        else:
            x[free] *= room / free_sum
        x[pinned] = v_min
        newly = free & (x < v_min)
        if not newly.any():
            break
        pinned |= newly
    return x

"""What the learned policies see and do: per-cabinet and per-tower rows, and their decoding.

Every learned controller (PPO, trees, the LLM) reads the same rows, built from an
:class:`~lcmesh.twin.controllers.base.Observation` only, so a policy runs wherever a controller runs
(twin, envs, mesh). Rows are per cabinet and per tower (LC-Opt's state decomposition, sec. 4.1);
their width depends on B (branches) and m (cells) only, so a policy trained on lcopt-5 runs on any
C and N with the same B and m. :class:`FeatureLayout` names every column; a policy file carries its
layout and is refused on a system whose layout differs, with one opt-in exception: ``pool_cells``
runs a policy trained for m cells per tower on towers of another cell count by area-averaging the
cells' fan powers onto m virtual cells (:func:`cell_pooling`; the mean fan loading is preserved, the
per-cell staging detail is not). The branch count B is never adapted.

Cabinet row (4B + 3): branch mean temperatures, branch hottest-blade temperatures, branch powers of
the coming step (per unit of the design branch load), branch power shares, the CDU's measured supply
temperature, the HTW supply temperature, the wet bulb.
Tower row (m + 6): its cells' fan powers (per unit of nominal), its leaving-water temperature, the
mean leaving-water temperature of all towers, the HTW return temperature, the wet bulb, its present
approach setpoint (leaving-water setpoint minus wet bulb), the plant's hottest blade.

Cabinet action (2 + B, in [-1, 1] before decoding): supply setpoint over 20..40 degC, dp setpoint
over 25..38 psi, B valve weights (mapped to [0, 1] and normalized to sum to 1; the multi-head policy
emits the split directly). Tower action: one of the nine ``APPROACH_LEVELS_K``; the leaving-water
setpoint is the wet bulb plus that approach (LC-Opt's discrete setpoint delta over the wet bulb).
A first design added steps to the previous setpoint; its argmax policy drifted to one end of the
range and stayed there, so the choice is absolute now.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from lcmesh.twin.controllers.base import Observation
from lcmesh.twin.plant import PlantAction
from lcmesh.twin.system import PSI_TO_PA, SystemDescription

K = 273.15
SUPPLY_RANGE_K = (K + 20.0, K + 40.0)
DP_RANGE_PA = (25.0 * PSI_TO_PA, 38.0 * PSI_TO_PA)
APPROACH_LEVELS_K = (1.5, 2.0, 2.5, 3.0, 3.5, 4.0, 5.0, 6.5, 8.0)
APPROACH_START_K = 10.0 / 1.8  # the static rule's wet bulb + 10 degF
VALVE_FLOOR = 0.02  # smallest valve fraction a decoded split keeps (no branch is ever shut)

_T_CENTER_K, _T_SCALE_K = K + 35.0, 5.0
_WB_CENTER_K, _WB_SCALE_K = K + 20.0, 10.0


@dataclass(frozen=True)
class FeatureLayout:
    """Column names of the cabinet and tower rows; a policy is valid only for an equal layout."""

    branches: int
    cells: int
    version: int = 1

    @property
    def cabinet_columns(self) -> tuple[str, ...]:
        b = range(self.branches)
        return (
            *(f"branch_temp[{j}]" for j in b), *(f"branch_max_temp[{j}]" for j in b),
            *(f"branch_power[{j}]" for j in b), *(f"branch_share[{j}]" for j in b),
            "supply_temp", "htw_supply_temp", "wet_bulb",
        )  # fmt: skip

    @property
    def tower_columns(self) -> tuple[str, ...]:
        return (
            *(f"cell_fan_power[{j}]" for j in range(self.cells)),
            "leaving_temp", "mean_leaving_temp", "htw_return_temp", "wet_bulb", "approach_setpoint", "max_blade_temp",
        )  # fmt: skip

    @property
    def cabinet_action_columns(self) -> tuple[str, ...]:
        return ("supply_temp_setpoint", "dp_setpoint", *(f"valve[{j}]" for j in range(self.branches)))

    def to_json(self) -> dict:
        return asdict(self)

    @classmethod
    def for_system(cls, system: SystemDescription) -> "FeatureLayout":
        return cls(branches=system.cabinets.branches, cells=system.towers.cells)

    def check(self, system: SystemDescription, what: str, pool_cells: bool = False) -> None:
        """Refuse a policy whose rows do not fit ``system`` (clear message, never a silent misfit).

        With ``pool_cells`` a differing cell count is accepted (the builder pools the cells).
        """
        other = FeatureLayout.for_system(system)
        if other == self:
            return
        cells_only = other.branches == self.branches and other.version == self.version
        if cells_only and pool_cells:
            return
        hint = " Retrain or distill for this system."
        if cells_only:
            hint += f" Or pass pool_cells (CLI --pool-cells) to pool its {other.cells} cells into {self.cells}."
        raise LayoutMismatch(
            f"{what} was trained for B={self.branches} branches and m={self.cells} cells per tower "
            f"(feature layout v{self.version}); system {system.name!r} has B={other.branches}, m={other.cells} "
            f"(layout v{other.version}).{hint}",
            cells_only=cells_only,
        )


class LayoutMismatch(ValueError):
    """A policy's feature layout does not fit the system; ``cells_only`` when only m differs."""

    def __init__(self, message: str, cells_only: bool = False):
        super().__init__(message)
        self.cells_only = cells_only


def cell_pooling(m_from: int, m_to: int) -> np.ndarray:
    """(m_to, m_from) area-averaging weights: cell j of m_from covers [j, j+1)/m_from of the tower."""
    edges_from = np.linspace(0.0, 1.0, m_from + 1)
    edges_to = np.linspace(0.0, 1.0, m_to + 1)
    w = np.zeros((m_to, m_from))
    for i in range(m_to):
        for j in range(m_from):
            overlap = min(edges_to[i + 1], edges_from[j + 1]) - max(edges_to[i], edges_from[j])
            w[i, j] = max(overlap, 0.0) * m_to
    return w


class FeatureBuilder:
    """Builds cabinet rows (C, 4B+3) and tower rows (N, m+6) from observations, into reused buffers."""

    def __init__(self, system: SystemDescription, layout: FeatureLayout | None = None):
        """``layout``: the policy's, when it pools another cell count (see :meth:`FeatureLayout.check`)."""
        cab, tw = system.cabinets, system.towers
        self.C, self.B, self.G = cab.count, cab.branches, cab.blade_groups_per_branch
        self.layout = layout if layout is not None else FeatureLayout.for_system(system)
        self.N, self.m, self.system_cells = tw.count, self.layout.cells, tw.cells
        self.pool = cell_pooling(tw.cells, self.m) if tw.cells != self.m else None
        self.design_branch_w = cab.design_heat_w / self.B
        self.fan_nominal_w = tw.cell.fan_power_nominal_w
        self.cabinet = np.zeros((self.C, len(self.layout.cabinet_columns)), dtype=np.float32)
        self.tower = np.zeros((self.N, len(self.layout.tower_columns)), dtype=np.float32)

    @property
    def pooling_note(self) -> str:
        """What a controller adds to its version when it pools cells (empty when it does not)."""
        return f" (cells pooled {self.system_cells}->{self.m})" if self.pool is not None else ""

    def cabinet_rows(self, obs: Observation) -> np.ndarray:
        C, B = self.C, self.B
        out, x = obs.out, self.cabinet
        x[:, 0:B] = (out["branch_temp_k"].reshape(C, B) - _T_CENTER_K) / _T_SCALE_K
        x[:, B : 2 * B] = (out["branch_max_temp_k"].reshape(C, B) - _T_CENTER_K) / _T_SCALE_K
        power = np.asarray(obs.blade_power_w).reshape(C, B, self.G).sum(axis=2)
        x[:, 2 * B : 3 * B] = power / self.design_branch_w - 1.0
        x[:, 3 * B : 4 * B] = power / np.maximum(power.sum(axis=1, keepdims=True), 1.0)
        x[:, 4 * B] = (out["supply_temp_k"] - _T_CENTER_K) / _T_SCALE_K
        x[:, 4 * B + 1] = (float(np.mean(out["htw_supply_temp_k"])) - _T_CENTER_K) / _T_SCALE_K
        x[:, 4 * B + 2] = (obs.wet_bulb_k - _WB_CENTER_K) / _WB_SCALE_K
        return x

    def tower_rows(self, obs: Observation) -> np.ndarray:
        N, m = self.N, self.m
        out, x = obs.out, self.tower
        leaving = out["ct_leaving_temp_k"].reshape(N)
        fans = out["cell_fan_power_w"].reshape(N, self.system_cells) / self.fan_nominal_w
        x[:, 0:m] = fans if self.pool is None else fans @ self.pool.T
        x[:, m] = (leaving - _T_CENTER_K) / _T_SCALE_K
        x[:, m + 1] = (leaving.mean() - _T_CENTER_K) / _T_SCALE_K
        x[:, m + 2] = (float(np.mean(out["htw_return_temp_k"])) - _T_CENTER_K) / _T_SCALE_K
        x[:, m + 3] = (obs.wet_bulb_k - _WB_CENTER_K) / _WB_SCALE_K
        x[:, m + 4] = (out["applied_lw_setpoint_k"].reshape(N) - obs.wet_bulb_k - APPROACH_START_K) / 2.0
        x[:, m + 5] = (float(out["blade_temp_k"].max()) - _T_CENTER_K) / _T_SCALE_K
        return x


def decode_cabinet(u: np.ndarray, target: PlantAction, valves_given: bool = False) -> None:
    """Write (C, 2+B) policy outputs in [-1, 1] (valves already a split if ``valves_given``) into ``target``."""
    u = np.clip(u, -1.0, 1.0) if not valves_given else u
    lo, hi = SUPPLY_RANGE_K
    target.supply_temp_setpoint_k[:] = lo + (np.clip(u[:, 0], -1, 1) + 1.0) * 0.5 * (hi - lo)
    lo, hi = DP_RANGE_PA
    target.dp_setpoint_pa[:] = lo + (np.clip(u[:, 1], -1, 1) + 1.0) * 0.5 * (hi - lo)
    if u.shape[1] > 2:
        w = u[:, 2:] if valves_given else (u[:, 2:] + 1.0) * 0.5
        target.valve_fractions[:] = normalize_split(w)


def normalize_split(weights: np.ndarray) -> np.ndarray:
    """Valve weights (C, B) >= 0 to fractions that sum to 1, each at least ``VALVE_FLOOR``."""
    w = np.maximum(np.nan_to_num(np.asarray(weights, dtype=np.float64), nan=0.0), 0.0)
    total = w.sum(axis=1, keepdims=True)
    w = np.where(total > 1e-9, w / np.maximum(total, 1e-9), 1.0 / w.shape[1])
    B = w.shape[1]
    return VALVE_FLOOR + (1.0 - B * VALVE_FLOOR) * w


def encode_cabinet(action: PlantAction) -> np.ndarray:
    """The inverse of :func:`decode_cabinet` for the first two columns, valves as fractions: (C, 2+B)."""
    lo, hi = SUPPLY_RANGE_K
    s = 2.0 * (action.supply_temp_setpoint_k - lo) / (hi - lo) - 1.0
    lo, hi = DP_RANGE_PA
    d = 2.0 * (action.dp_setpoint_pa - lo) / (hi - lo) - 1.0
    return np.column_stack([s, d, action.valve_fractions])


@dataclass(frozen=True)
class HoldBand:
    """How far a learned policy's target must move from the applied setpoint before the setpoint moves."""

    supply_k: float = 1.0
    dp_psi: float = 1.0
    lw_k: float = 0.5

    def apply(self, action: PlantAction, out) -> PlantAction:
        """Keep each CDU's supply and dp and each tower's leaving-water setpoint where the plant applies it, unless
        the target leaves the band around it (in place; returns ``action``). Valves are not held.

        A deadband, as building controls put on their setpoints: a policy's output wanders with its inputs by a
        fraction of a kelvin at every step, and moving the plant for that buys nothing. The reference is the
        plant's applied setpoint (``out``), so the hold is the same in the twin, the benches and the mesh.
        """
        for name, key, band in (("supply_temp_setpoint_k", "applied_supply_setpoint_k", self.supply_k),
                                ("dp_setpoint_pa", "applied_dp_setpoint_pa", self.dp_psi * PSI_TO_PA),
                                ("lw_setpoint_k", "applied_lw_setpoint_k", self.lw_k)):  # fmt: skip
            target, applied = getattr(action, name), np.asarray(out[key], dtype=float).reshape(-1)
            if applied.shape == target.shape and np.all(applied > 0.0):  # the plant has applied something
                np.copyto(target, applied, where=np.abs(target - applied) <= band)
        return action


DEFAULT_HOLD = HoldBand()
"""The learned controllers' hold band (``hold=None`` turns it off: the policy's raw output)."""


class TowerSetpoints:
    """Turns each tower's discrete choice into its leaving-water setpoint (wet bulb + approach level)."""

    def __init__(self, system: SystemDescription):
        self.N = system.towers.count
        self.min_approach_k = max(system.towers.cell.approach_min_k, APPROACH_LEVELS_K[0])
        self.approach_k = np.full(self.N, APPROACH_START_K)

    def reset(self) -> None:
        self.approach_k[:] = APPROACH_START_K

    def apply(self, choice: np.ndarray, wet_bulb_k: float, target: PlantAction) -> None:
        index = np.clip(np.asarray(choice, dtype=np.int64), 0, len(APPROACH_LEVELS_K) - 1)
        np.maximum(np.asarray(APPROACH_LEVELS_K)[index], self.min_approach_k, out=self.approach_k)
        target.lw_setpoint_k[:] = wet_bulb_k + self.approach_k

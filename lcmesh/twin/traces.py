"""Exogenous inputs of the twin: IT heat load per blade group and outside wet bulb.

A trace is a per-cabinet load (W, ``(n_steps, C)``) and a wet bulb (K, ``(n_steps,)``)
on the system's step grid, plus a seeded *skew model* that spreads each cabinet's load
over its B branches and G blade groups per branch. See docs/traces.md for the full
description and a plot.

Sources (``load_trace(spec, system)``):

- ``"frontier-2024-04-07"``: one day of the 25 Frontier CDUs at ORNL (data/ATTRIBUTION.md),
  evaluation only. The file has 5,761 rows at 0, 15, ..., 86,400 s; the last row is the end
  point of the day, so the trace has 5,760 steps and step ``k`` holds row ``k``.
- ``"synthetic:SEED"``: a seeded job-based workload and diurnal weather (24 h, or ``hours``).
- a path to a CSV with the shipped day's columns (``time``, ``power[1]``..``power[K]``,
  ``OA Wetbulb Temp``); rows need not be 15 s apart: values are linearly interpolated onto
  the system's ``step_s`` when the spacing differs.

Mapping of CSV columns to cabinets: cabinet ``i`` takes column ``power[(i mod K) + 1]``
(K = 25 for the shipped day) scaled by ``design_heat_w / 650e3`` (650 kW is the day's mean
CDU load, so the day's mean per cabinet equals ``design_heat_w``). Cabinets ``i >= K`` reuse
a column circularly shifted in time by a seeded 1/24 to 23/24 of the trace length. Wet bulb:
the CSV's deg C + 273.15 + ``wet_bulb_offset_k`` (LC-Opt uses +15 K; default 0).

Skew (all seeded from ``system.load_skew_seed``; the branch schedule also from the seed of a
synthetic trace): each cabinet has a base branch pattern (for B = 3 about 0.03/0.16/0.81,
shares in geometric progression with ratio ``_SHARE_RATIO`` between largest and smallest,
lognormal jitter, random order). Its assignment to branches rotates by one branch every
``period`` seconds (30 to 90 min, per cabinet, random phase); each rotation blends over the
last ``_TRANSITION_S`` seconds of the period with a smoothstep, so shares never jump. Within a
branch, blade groups take static lognormal (sigma 0.3) shares normalized to sum to 1.
"""

from __future__ import annotations

import csv
import difflib
import functools
import math
import re
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import Literal

import numpy as np

from lcmesh.twin.system import SystemDescription

TRAIN_SEEDS = range(0, 1000)
EVAL_SEEDS = range(1000, 2000)
FRONTIER_DAY = "frontier-2024-04-07"

FRONTIER_MEAN_CDU_LOAD_W = 650e3
WET_BULB_RANGE_C = (-40.0, 50.0)
KELVIN_OFFSET = 273.15

_DATA_PACKAGE = "lcmesh.twin.data"
_TIME_COL = "time"
_WET_BULB_COL = "OA Wetbulb Temp"
_POWER_COL = re.compile(r"^power\[(\d+)\]$")

_SHARE_RATIO = 25.0  # largest / smallest branch share of a base pattern (B = 3: about 0.03/0.16/0.81)
_SHARE_JITTER_SIGMA = 0.1
_ROTATION_PERIOD_S = (1800.0, 5400.0)
_TRANSITION_S = 300.0
_GROUP_SHARE_SIGMA = 0.3  # the LC-Opt scenario's blade-group spread (chosen, not measured)
# The data scenarios' blade-group spread: the median over the Frontier day of the standard deviation of
# log(CDU load / mean CDU load) across its 25 columns (tests/twin/test_traces.py recomputes it).
_DATA_GROUP_SHARE_SIGMA = 0.094
# SeedSequence stream tags, so the draws of one purpose never shift those of another.
_BRANCH_STREAM, _GROUP_STREAM, _COLUMN_SHIFT_STREAM, _PROFILE_STREAM = 1, 2, 3, 4

# Climatic design conditions of Knoxville McGhee Tyson Airport, TN (WMO 723260), 11 miles from ORNL: the annual
# evaporation design wet bulb by percentile and the daily wet-bulb range, as read from ASHRAE Handbook-
# Fundamentals (2009); not verified against the source in this workplace (docs/traces.md, "Design days").
KNOXVILLE_EVAP_WB_C = {0.4: 24.6, 1.0: 24.0, 2.0: 23.4}
KNOXVILLE_WB_RANGE_K = 3.9


class TraceError(ValueError):
    """A trace that cannot be loaded; the message names the file, column or row."""


@dataclass(frozen=True, eq=False)
class LoadSkew:
    """Seeded split of cabinet load over branches (rotating) and blade groups (static)."""

    base_shares: np.ndarray  # (C, B), rows sum to 1
    period_s: np.ndarray  # (C,) rotation period
    phase_s: np.ndarray  # (C,) time offset of the rotation
    group_shares: np.ndarray  # (C*B, G), rows sum to 1
    transition_s: float = _TRANSITION_S

    def __post_init__(self) -> None:
        n_cab, n_branches = self.base_shares.shape
        object.__setattr__(self, "_branch_index", np.arange(n_branches))
        object.__setattr__(self, "_cabinet_index", np.arange(n_cab)[:, None])
        object.__setattr__(self, "_transition_start", 1.0 - self.transition_s / self.period_s)

    def branch_shares(self, t_s: float | np.ndarray) -> np.ndarray:
        """Shares (…, C, B) of each cabinet's load per branch at time(s) ``t_s``."""
        t = np.asarray(t_s, dtype=np.float64)[..., None]
        u = (t + self.phase_s) / self.period_s
        rotation = np.floor(u)
        frac = u - rotation
        w = np.clip((frac - self._transition_start) * (self.period_s / self.transition_s), 0.0, 1.0)
        w = (w * w * (3.0 - 2.0 * w))[..., None]
        n_branches = self.base_shares.shape[1]
        idx = (self._branch_index + rotation.astype(np.int64)[..., None]) % n_branches
        now = self.base_shares[self._cabinet_index, idx]
        nxt = self.base_shares[self._cabinet_index, (idx + 1) % n_branches]
        return now + w * (nxt - now)


@dataclass(frozen=True, eq=False)
class DataSkew:
    """Branch shares taken from data: one (C, B) row of shares per trace step, plus static group shares."""

    shares: np.ndarray  # (n_steps, C, B), rows sum to 1; step k holds time k * step_s
    step_s: float
    group_shares: np.ndarray  # (C*B, G), rows sum to 1

    @property
    def base_shares(self) -> np.ndarray:
        """The shares at time 0, (C, B): the shape of the split (the same field as `LoadSkew`'s)."""
        return self.shares[0]

    def branch_shares(self, t_s: float | np.ndarray) -> np.ndarray:
        """Shares (…, C, B) at time(s) ``t_s``: the row of the step that holds that time (held past the end)."""
        rows = np.floor(np.asarray(t_s, dtype=np.float64) / self.step_s + 1e-9).astype(np.int64)
        return self.shares[np.clip(rows, 0, self.shares.shape[0] - 1)]


@dataclass(frozen=True, eq=False)
class Trace:
    """Per-cabinet IT load and wet bulb on the system's step grid, plus the load skew."""

    name: str
    step_s: float
    cabinet_load_w: np.ndarray  # (n_steps, C)
    wet_bulb_k: np.ndarray  # (n_steps,)
    branches: int
    blade_groups_per_branch: int
    skew: LoadSkew | DataSkew
    scenario: str = "frontier"
    start_s: float = 0.0  # time of step 0 on the skew schedule (non-zero for slices)
    _n_blade_groups: int = field(init=False, repr=False)

    def __post_init__(self) -> None:
        n, c = self.cabinet_load_w.shape
        if self.wet_bulb_k.shape != (n,):
            raise TraceError(f"`wet_bulb_k` must have shape ({n},), got {self.wet_bulb_k.shape}")
        expected = (c * self.branches, self.blade_groups_per_branch)
        if self.skew.base_shares.shape != (c, self.branches) or self.skew.group_shares.shape != expected:
            raise TraceError(f"skew shapes do not match C={c}, B={self.branches}, G={self.blade_groups_per_branch}")
        object.__setattr__(self, "_n_blade_groups", expected[0] * expected[1])

    @property
    def n_steps(self) -> int:
        return self.cabinet_load_w.shape[0]

    @property
    def n_cabinets(self) -> int:
        return self.cabinet_load_w.shape[1]

    def _check_step(self, step: int) -> None:
        if not 0 <= step < self.cabinet_load_w.shape[0]:
            raise IndexError(f"`step` must be in [0, {self.n_steps}), got {step}")

    def branch_shares(self, steps: int | np.ndarray) -> np.ndarray:
        """Branch shares of each cabinet's load, (C, B) for one step or (n, C, B) for an array."""
        return self.skew.branch_shares(self.start_s + self.step_s * np.asarray(steps, dtype=np.float64))

    def branch_power_w(self, step: int) -> np.ndarray:
        """(C, B) W per branch at ``step``: the sum over the branch's blade groups."""
        self._check_step(step)
        return self.cabinet_load_w[step][:, None] * self.skew.branch_shares(self.start_s + self.step_s * step)

    def blade_power_w(self, step: int, out: np.ndarray | None = None) -> np.ndarray:
        """(C*B*G,) W per blade group at ``step``; index = (cabinet*B + branch)*G + group."""
        branch = self.branch_power_w(step).reshape(-1, 1)
        if out is None:
            out = np.empty(self._n_blade_groups)
        elif out.shape != (self._n_blade_groups,) or out.dtype != np.float64 or not out.flags.c_contiguous:
            raise ValueError(f"`out` must be a contiguous float64 array of shape ({self._n_blade_groups},)")
        np.multiply(branch, self.skew.group_shares, out=out.reshape(self.skew.group_shares.shape))
        return out

    def slice(self, start_step: int, n_steps: int) -> Trace:
        """The window of ``n_steps`` steps from ``start_step``; the skew schedule continues."""
        if n_steps < 1 or start_step < 0 or start_step + n_steps > self.n_steps:
            raise TraceError(
                f"slice [{start_step}, {start_step + n_steps}) of {self.name!r} must lie in [0, {self.n_steps})"
                " and hold at least one step"
            )
        window = slice(start_step, start_step + n_steps)
        return replace(
            self,
            name=f"{self.name}[{start_step}:{start_step + n_steps}]",
            cabinet_load_w=self.cabinet_load_w[window],
            wet_bulb_k=self.wet_bulb_k[window],
            start_s=self.start_s + self.step_s * start_step,
        )


def trace_split(kind: Literal["train", "eval"]) -> list[str]:
    """Trace specs of a split: training uses TRAIN_SEEDS only; evaluation the Frontier day and EVAL_SEEDS."""
    if kind == "train":
        return [f"synthetic:{s}" for s in TRAIN_SEEDS]
    if kind == "eval":
        return [FRONTIER_DAY] + [f"synthetic:{s}" for s in EVAL_SEEDS]
    raise ValueError(f"`kind` must be 'train' or 'eval', got {kind!r}")


@dataclass(frozen=True)
class Scenario:
    """How a trace's data becomes the twin's inputs: weather, load scale and the spread over branches.

    ``cabinet_mean_w``: the mean cabinet load the trace is scaled to (default: the system's ``design_heat_w``).
    ``branch_spread`` "data": each branch follows the time profile of another CDU column of the trace
    (docs/traces.md); "lcopt": LC-Opt's seeded 25:1 rotating pattern. ``design_day``: replace the
    trace's wet bulb by the design-day profile of that name (`DESIGN_DAYS`).
    """

    name: str
    description: str
    branch_spread: Literal["data", "lcopt"] = "data"
    wet_bulb_offset_k: float = 0.0
    cabinet_mean_w: float | None = None  # scale the loads to this mean per cabinet instead of `design_heat_w`
    design_day: str | None = None


@dataclass(frozen=True)
class DesignDay:
    """A design day's wet bulb: its peak and its daily range, shaped by ASHRAE's hourly fractions."""

    name: str
    peak_wet_bulb_c: float
    daily_range_k: float

    def wet_bulb_c(self, time_s: np.ndarray) -> np.ndarray:
        """Wet bulb (deg C) at ``time_s`` (s from midnight, local solar time), interpolated between hours."""
        hours = np.asarray(time_s, dtype=np.float64) / 3600.0
        # the fractions are for the hour ending at 1..24; hour 24 is also hour 0 of the next day
        knots_h = np.arange(0.0, 25.0)
        fractions = np.concatenate(([_DAILY_RANGE_FRACTION[-1]], _DAILY_RANGE_FRACTION))
        frac = np.interp(hours % 24.0, knots_h, fractions)
        return self.peak_wet_bulb_c - frac * self.daily_range_k


# ASHRAE Handbook-Fundamentals (2009, ch. 14, table 6; unchanged since): the fraction of the daily
# range below the peak, for the hours ending 01:00 .. 24:00. 0 at 14-15 h, 1 at 05 h.
_DAILY_RANGE_FRACTION = np.array([
    0.88, 0.92, 0.95, 0.98, 1.00, 0.98, 0.91, 0.74, 0.55, 0.38, 0.23, 0.13,
    0.05, 0.00, 0.00, 0.06, 0.14, 0.24, 0.39, 0.50, 0.59, 0.68, 0.75, 0.82,
])  # fmt: skip
_DAILY_RANGE_FRACTION.setflags(write=False)

DESIGN_DAYS = {
    f"knoxville-{pct:g}": DesignDay(f"knoxville-{pct:g}", wet_bulb_c, KNOXVILLE_WB_RANGE_K)
    for pct, wet_bulb_c in KNOXVILLE_EVAP_WB_C.items()
}

LCOPT_LOAD_W = 225e3  # the mean cabinet load LC-Opt-scale runs use (docs/twin.md, "The LC-Opt scenario")
DEFAULT_SCENARIO = "frontier"
SCENARIOS = {
    s.name: s
    for s in (
        Scenario("frontier", "the trace as recorded: real CDU loads, real wet bulb, branch spread from the data"),
        Scenario(
            "design-day",
            "the trace's loads under the 0.4 % evaporation design wet bulb of Knoxville, TN, with its daily range",
            design_day="knoxville-0.4",
        ),
        Scenario(
            "lcopt",
            "LC-Opt's hardening, for comparison with its Table 3: wet bulb +15 K, a 25:1 rotating branch skew,"
            f" loads scaled to a {LCOPT_LOAD_W / 1e3:.0f} kW mean per cabinet",
            branch_spread="lcopt",
            wet_bulb_offset_k=15.0,
            cabinet_mean_w=LCOPT_LOAD_W,
        ),
    )
}


def scenario_with_offset(name: str, wet_bulb_offset_k: float) -> Scenario:
    """The named scenario with its wet-bulb offset replaced (training configs that record the offset themselves)."""
    return replace(scenario_named(name), wet_bulb_offset_k=wet_bulb_offset_k)


def scenario_named(name: str | Scenario) -> Scenario:
    """The named scenario; an unknown name gets the known ones and the closest match."""
    if isinstance(name, Scenario):
        return name
    if name in SCENARIOS:
        return SCENARIOS[name]
    close = difflib.get_close_matches(str(name), list(SCENARIOS), n=1)
    hint = f"; did you mean {close[0]!r}?" if close else ""
    raise TraceError(f"unknown scenario {name!r}{hint} (known: {', '.join(SCENARIOS)})")


def load_trace(
    spec: str,
    system: SystemDescription,
    *,
    scenario: str | Scenario = DEFAULT_SCENARIO,
    wet_bulb_offset_k: float = 0.0,
    hours: float | None = None,
) -> Trace:
    """Load ``"frontier-2024-04-07"``, ``"synthetic:SEED"`` or a CSV path for ``system`` under ``scenario``.

    ``wet_bulb_offset_k`` is added on top of the scenario's own offset.
    """
    scen = scenario_named(scenario)
    if hours is not None and not (hours > 0 and math.isfinite(hours)):
        raise TraceError(f"`hours` must be a positive number, got {hours}")
    if not math.isfinite(wet_bulb_offset_k):
        raise TraceError(f"`wet_bulb_offset_k` must be a finite number of kelvin, got {wet_bulb_offset_k}")
    spec = str(spec)
    trace_seed: int | None = None
    cab = system.cabinets
    mean_w = cab.design_heat_w if scen.cabinet_mean_w is None else scen.cabinet_mean_w
    if spec.startswith("synthetic:"):
        trace_seed = _parse_seed(spec)
        n_steps = _hours_to_steps(24.0 if hours is None else hours, system.step_s)
        load_w, wet_bulb_c = _synthetic(trace_seed, system, n_steps, mean_w)
        # the branches' profiles: the shipped day's CDU columns, drawn by seed (data spread)
        profiles = _synthetic_profiles(trace_seed, system, n_steps) if scen.branch_spread == "data" else None
        name = f"synthetic:{trace_seed}"
    else:
        if spec == FRONTIER_DAY:
            time_s, power_w, wet_bulb_c = _read_shipped_day()
        else:
            time_s, power_w, wet_bulb_c = _read_csv(_user_path(spec))
        power_w, wet_bulb_c = _resample(time_s, power_w, wet_bulb_c, system.step_s, spec)
        if hours is not None:
            n_steps = _hours_to_steps(hours, system.step_s)
            if n_steps > len(wet_bulb_c):
                held_h = len(wet_bulb_c) * system.step_s / 3600
                raise TraceError(f"trace {spec!r} holds {held_h:.2f} h, asked for {hours} h")
            power_w, wet_bulb_c = power_w[:n_steps], wet_bulb_c[:n_steps]
        profiles = _column_profiles(power_w, system) if scen.branch_spread == "data" else None
        power_w = _columns_to_cabinets(power_w, system)
        load_w, name = power_w * (mean_w / FRONTIER_MEAN_CDU_LOAD_W), spec
    if scen.design_day is not None:
        wet_bulb_c = DESIGN_DAYS[scen.design_day].wet_bulb_c(system.step_s * np.arange(len(wet_bulb_c)))
    wet_bulb_k = wet_bulb_c + KELVIN_OFFSET + scen.wet_bulb_offset_k + wet_bulb_offset_k
    for a in (load_w, wet_bulb_k):
        a.setflags(write=False)
    if profiles is None:
        skew: LoadSkew | DataSkew = _make_skew(system, trace_seed)
    else:
        skew = DataSkew(shares=_shares_from_profiles(profiles, cab.branches), step_s=system.step_s,
                        group_shares=_group_shares(system, _DATA_GROUP_SHARE_SIGMA))  # fmt: skip
    return Trace(
        name=name,
        step_s=system.step_s,
        cabinet_load_w=load_w,
        wet_bulb_k=wet_bulb_k,
        branches=cab.branches,
        blade_groups_per_branch=cab.blade_groups_per_branch,
        skew=skew,
        scenario=scen.name,
    )


def _parse_seed(spec: str) -> int:
    text = spec.removeprefix("synthetic:")
    if not text.isdigit():
        raise TraceError(f"trace {spec!r}: the seed after 'synthetic:' must be an integer >= 0, got {text!r}")
    return int(text)


def _hours_to_steps(hours: float, step_s: float) -> int:
    n_steps = round(hours * 3600.0 / step_s)
    if n_steps < 1:
        raise TraceError(f"`hours` = {hours} is shorter than one {step_s} s step")
    return n_steps


def _user_path(spec: str) -> Path:
    path = Path(spec)
    if path.is_file():
        return path
    if path.suffix.lower() == ".csv" or path.parent != Path("."):
        raise TraceError(f"trace file not found: {path}")
    close = difflib.get_close_matches(spec, [FRONTIER_DAY, "synthetic:0"], n=1)
    hint = f"; did you mean {close[0]!r}?" if close else ""
    raise TraceError(f"unknown trace {spec!r}{hint} (known: {FRONTIER_DAY!r}, 'synthetic:SEED', or a CSV path)")


@functools.lru_cache(maxsize=1)
def _read_shipped_day() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    resource = resources.files(_DATA_PACKAGE).joinpath(f"{FRONTIER_DAY}.csv")
    with resources.as_file(resource) as path:
        arrays = _read_csv(path)
    for a in arrays:
        a.setflags(write=False)
    return arrays


def _read_csv(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Parse and validate a trace CSV: (time_s (n,), power_w (n, K), wet_bulb_c (n,))."""
    if not path.is_file():
        raise TraceError(f"trace file not found: {path}")
    with path.open(newline="") as f:
        rows = [row for row in csv.reader(f) if row]
    if not rows:
        raise TraceError(f"{path}: empty file; expected a header with `time`, `power[1]`.., `{_WET_BULB_COL}`")
    header = [h.strip() for h in rows[0]]
    col_of = {name: j for j, name in enumerate(header)}
    power_idx = sorted(int(m.group(1)) for h in header if (m := _POWER_COL.match(h)))
    missing = [c for c in (_TIME_COL, _WET_BULB_COL) if c not in col_of]
    if not power_idx:
        missing.append("power[1] (at least one power[k] column)")
    else:
        missing += [f"power[{k}]" for k in range(1, power_idx[-1] + 1) if k not in power_idx]
    if missing:
        raise TraceError(f"{path}: missing column(s) {', '.join(missing)}; header is {header}")
    data = rows[1:]
    if len(data) < 2:
        raise TraceError(f"{path}: needs at least 2 data rows (start and end time), got {len(data)}")
    for i, row in enumerate(data):
        if len(row) != len(header):
            raise TraceError(f"{path}, line {i + 2}: {len(row)} fields, the header has {len(header)}")
    names = [_TIME_COL, *(f"power[{k}]" for k in power_idx), _WET_BULB_COL]
    table = np.column_stack([_column(path, data, name, col_of[name]) for name in names])
    time_s, power_w, wet_bulb_c = table[:, 0], table[:, 1:-1], table[:, -1]
    _check_values(path, time_s, power_w, wet_bulb_c, names)
    return time_s, power_w, wet_bulb_c


def _column(path: Path, data: list[list[str]], name: str, j: int) -> np.ndarray:
    cells = [row[j] for row in data]
    try:
        values = np.array(cells, dtype=np.float64)
        if np.isfinite(values).all():
            return values
    except ValueError:
        pass
    for i, cell in enumerate(cells):  # only on error: find the first bad cell
        try:
            ok = math.isfinite(float(cell))
        except ValueError:
            ok = False
        if not ok:
            raise TraceError(f"{path}, line {i + 2}, column {name!r}: {cell!r} is not a finite number")
    raise AssertionError("unreachable: a cell failed to convert but every cell converts")


def _check_values(
    path: Path, time_s: np.ndarray, power_w: np.ndarray, wet_bulb_c: np.ndarray, names: list[str]
) -> None:
    dt = np.diff(time_s)
    if (bad := np.flatnonzero(dt <= 0)).size:
        i = bad[0] + 1
        raise TraceError(f"{path}, line {i + 2}: `time` {time_s[i]} is not after {time_s[i - 1]}; time must increase")
    if (bad := np.flatnonzero(np.abs(dt - dt[0]) > 1e-6 * dt[0])).size:
        i = bad[0] + 1
        raise TraceError(
            f"{path}, line {i + 2}: time step {dt[i - 1]} s differs from the first step {dt[0]} s;"
            " rows must be evenly spaced"
        )
    if (bad := np.argwhere(power_w < 0)).size:
        i, k = bad[0]
        raise TraceError(f"{path}, line {i + 2}, column {names[k + 1]!r}: power {power_w[i, k]} W must be >= 0")
    lo, hi = WET_BULB_RANGE_C
    if (bad := np.flatnonzero((wet_bulb_c < lo) | (wet_bulb_c > hi))).size:
        i = bad[0]
        raise TraceError(
            f"{path}, line {i + 2}, column {_WET_BULB_COL!r}: {wet_bulb_c[i]} deg C is outside [{lo}, {hi}] deg C"
        )


def _resample(
    time_s: np.ndarray, power_w: np.ndarray, wet_bulb_c: np.ndarray, step_s: float, spec: str
) -> tuple[np.ndarray, np.ndarray]:
    """Values at the start of each step; the last row is the trace's end point."""
    if abs((time_s[1] - time_s[0]) - step_s) <= 1e-6 * step_s:
        return power_w[:-1], wet_bulb_c[:-1]
    n_steps = math.floor((time_s[-1] - time_s[0]) / step_s + 1e-9)
    if n_steps < 1:
        raise TraceError(f"trace {spec!r} lasts {time_s[-1] - time_s[0]} s, shorter than one {step_s} s step")
    t = time_s[0] + step_s * np.arange(n_steps)
    power = np.column_stack([np.interp(t, time_s, col) for col in power_w.T])
    return power, np.interp(t, time_s, wet_bulb_c)


def _columns_to_cabinets(power_w: np.ndarray, system: SystemDescription) -> np.ndarray:
    """Cabinet i takes column i mod K; cabinets i >= K get a seeded circular time shift."""
    n_steps, n_cols = power_w.shape
    n_cab = system.n_cabinets
    cabinets = power_w[:, np.arange(n_cab) % n_cols]
    if n_cab > n_cols and n_steps > 1:
        rng = _stream(system.load_skew_seed, _COLUMN_SHIFT_STREAM)
        lo = max(1, n_steps // 24)
        shifts = rng.integers(lo, max(lo + 1, n_steps - lo), size=n_cab - n_cols)
        for i, shift in zip(range(n_cols, n_cab), shifts, strict=True):
            cabinets[:, i] = np.roll(cabinets[:, i], shift)
    return cabinets


def _stream(*entropy: int) -> np.random.Generator:
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence(list(entropy))))


def _make_skew(system: SystemDescription, trace_seed: int | None) -> LoadSkew:
    cab = system.cabinets
    n_cab, n_br = cab.count, cab.branches
    entropy = [system.load_skew_seed, _BRANCH_STREAM] + ([] if trace_seed is None else [trace_seed])
    rng = _stream(*entropy)
    geometric = _SHARE_RATIO ** np.linspace(0.0, 1.0, n_br)
    base = geometric * rng.lognormal(0.0, _SHARE_JITTER_SIGMA, size=(n_cab, n_br))
    base = rng.permuted(base / base.sum(axis=1, keepdims=True), axis=1)
    period_s = rng.uniform(*_ROTATION_PERIOD_S, size=n_cab)
    phase_s = rng.uniform(0.0, 1.0, size=n_cab) * period_s
    groups = _group_shares(system, _GROUP_SHARE_SIGMA)
    for a in (base, period_s, phase_s):
        a.setflags(write=False)
    return LoadSkew(base_shares=base, period_s=period_s, phase_s=phase_s, group_shares=groups)


def _group_shares(system: SystemDescription, sigma: float) -> np.ndarray:
    """Static lognormal shares of each branch's load over its blade groups, (C*B, G), rows sum to 1."""
    cab = system.cabinets
    rng = _stream(system.load_skew_seed, _GROUP_STREAM)
    groups = rng.lognormal(0.0, sigma, size=(cab.count * cab.branches, cab.blade_groups_per_branch))
    groups /= groups.sum(axis=1, keepdims=True)
    groups.setflags(write=False)
    return groups


def _column_profiles(power_w: np.ndarray, system: SystemDescription) -> np.ndarray:
    """(n, C*B) load profiles for the branches: branch j of cabinet i follows column (i*B + j) mod K."""
    n_cols = power_w.shape[1]
    return power_w[:, np.arange(system.n_branches) % n_cols]


def _synthetic_profiles(seed: int, system: SystemDescription, n_steps: int) -> np.ndarray:
    """(n, C*B) branch profiles for a synthetic trace: the shipped day's CDU columns, drawn by seed.

    The spread between branches is the data's: every branch takes a seeded column, all from the same
    seeded time of day (the columns move together, so one shift for all keeps their co-movement).
    """
    time_s, power_w, wet_bulb_c = _read_shipped_day()
    day, _ = _resample(time_s, power_w, wet_bulb_c, system.step_s, FRONTIER_DAY)
    rng = _stream(seed, _PROFILE_STREAM)
    cols = rng.integers(0, day.shape[1], size=system.n_branches)
    rows = (np.arange(n_steps) + rng.integers(0, day.shape[0])) % day.shape[0]
    return day[rows[:, None], cols[None, :]]


def _shares_from_profiles(profiles: np.ndarray, n_branches: int) -> np.ndarray:
    """Each cabinet's branch shares at every step: its B profiles normalized to sum to 1 (equal if all 0)."""
    n = profiles.shape[0]
    grouped = profiles.reshape(n, -1, n_branches)
    total = grouped.sum(axis=2, keepdims=True)
    shares = np.divide(grouped, total, out=np.full_like(grouped, 1.0 / n_branches), where=total > 0)
    shares.setflags(write=False)
    return shares


# Synthetic workload: fractions of design_heat_w, times in seconds.
_JOB_RATE_PER_H = 1.2
_JOB_WIDE_PROB = 0.5  # jobs spanning 80-100 % of the cabinets: the site moves together
_JOB_DURATION_MEDIAN_S, _JOB_DURATION_SIGMA = 3600.0, 0.8
_JOB_DURATION_RANGE_S = (600.0, 8 * 3600.0)
_JOB_LEVEL = (0.55, 0.9)
_IDLE_LEVEL = (0.10, 0.20)
_BURST_RATE_PER_H, _BURST_DURATION_S, _BURST_LEVEL = 0.5, (60.0, 300.0), (1.0, 1.1)
_LOAD_CLIP = (0.05, 1.15)
# design_heat_w is the *mean* cabinet load; the Frontier day spans 0.09-1.98x of its mean, so the
# fractions above (of a cabinet's peak) are stretched to cover the same range as the evaluation day.
_PEAK_OVER_MEAN = 1.75
_WARMUP_S = 6 * 3600.0  # jobs start before t = 0 so the trace does not open empty


def _synthetic(seed: int, system: SystemDescription, n_steps: int, mean_w: float) -> tuple[np.ndarray, np.ndarray]:
    """Seeded job-based cabinet loads (W, about `mean_w` on average) and diurnal wet bulb (deg C)."""
    rng = np.random.Generator(np.random.PCG64(seed))
    load, wet_bulb_c = _synthetic_series(rng, system.n_cabinets, system.step_s, n_steps)
    return load * mean_w, wet_bulb_c


def _synthetic_series(
    rng: np.random.Generator, n_cab: int, step_s: float, n_steps: int
) -> tuple[np.ndarray, np.ndarray]:
    """Job-based loads in units of the mean load, (n_steps, n_cab), and diurnal wet bulb (deg C)."""
    duration_s = n_steps * step_s
    load = np.broadcast_to(rng.uniform(*_IDLE_LEVEL, size=n_cab), (n_steps, n_cab)).copy()

    def steps(t0: float, t1: float) -> slice:
        return slice(max(0, math.ceil(t0 / step_s)), max(0, min(n_steps, math.ceil(t1 / step_s))))

    t = -_WARMUP_S
    while (t := t + rng.exponential(3600.0 / _JOB_RATE_PER_H)) < duration_s:
        length = rng.lognormal(math.log(_JOB_DURATION_MEDIAN_S), _JOB_DURATION_SIGMA)
        length = float(np.clip(length, *_JOB_DURATION_RANGE_S))
        frac = rng.uniform(0.8, 1.0) if rng.random() < _JOB_WIDE_PROB else rng.uniform(0.05, 0.5)
        cabs = rng.choice(n_cab, size=max(1, round(frac * n_cab)), replace=False)
        window = steps(t, t + length)
        # a job takes its level of the headroom left, so overlapping jobs saturate below 1
        load[window, cabs] += rng.uniform(*_JOB_LEVEL) * (1.0 - load[window, cabs])
    t = 0.0
    while (t := t + rng.exponential(3600.0 / _BURST_RATE_PER_H)) < duration_s:
        window = steps(t, t + rng.uniform(*_BURST_DURATION_S))
        cabs = rng.choice(n_cab, size=max(1, round(rng.uniform(0.3, 1.0) * n_cab)), replace=False)
        load[window, cabs] = np.maximum(load[window, cabs], rng.uniform(*_BURST_LEVEL))
    load *= 1.0 + 0.02 * rng.standard_normal(load.shape)
    load_w = np.clip(load, *_LOAD_CLIP) * _PEAK_OVER_MEAN

    hour = np.arange(n_steps) * (step_s / 3600.0)
    mean_c, amplitude_k, coldest_h = rng.uniform(2.0, 20.0), rng.uniform(2.0, 5.0), rng.uniform(5.0, 7.0)
    diurnal = mean_c - amplitude_k * np.cos(2.0 * np.pi * (hour - coldest_h) / 24.0)
    phi = math.exp(-step_s / 7200.0)  # weather noise with a 2 h correlation time, 0.7 K std
    shocks = rng.standard_normal(n_steps) * 0.7 * math.sqrt(1.0 - phi * phi)
    noise = np.empty(n_steps)
    noise[0] = rng.standard_normal() * 0.7
    for k in range(1, n_steps):
        noise[k] = phi * noise[k - 1] + shocks[k]
    return load_w, diurnal + noise

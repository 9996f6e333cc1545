"""The episode driver shared by every env: one Plant, one Trace, a clock and the episode's end.

Differences from LC-Opt, on purpose: LC-Opt never advanced time through its load and weather
(every episode replayed the FMU's initial conditions) and never ended an episode (``done`` was
always False). Here each episode starts at a random row of the trace (seeded through
``reset(seed=...)``), time advances one trace row per step (``time_s = (start + k) * step_s``
after ``k`` steps), episodes are truncated after ``episode_steps`` steps or at the end of the
trace, and terminated on thermal runaway (a blade group above ``runaway_temp_k``).

A step at row ``r`` applies the trace's load and wet bulb of row ``r`` during the step; the
observation after it is at time ``(r + 1) * step_s``. The inputs of the *coming* step are
prepared before the agent acts (``blade_power_w``, ``wet_bulb_k``), so the default policy sees
what any LC-Opt controller sees: the plant outputs plus the coming step's exogenous inputs.
"""

from __future__ import annotations

import math
import operator
from dataclasses import dataclass
from typing import Any, NamedTuple

import gymnasium as gym
import numpy as np

from lcmesh.twin.controllers import Observation
from lcmesh.twin.controllers.static import StaticController
from lcmesh.twin.plant import Plant, PlantAction
from lcmesh.twin.system import load_system
from lcmesh.twin.traces import KELVIN_OFFSET, load_trace, scenario_with_offset

_CHUNK_ROWS = 256  # trace rows whose branch loads are computed in one vectorized call
KPI_BAND_K = (KELVIN_OFFSET + 20.0, KELVIN_OFFSET + 40.0)  # the paper's blade-group operating band
PHYSICAL_TEMP_BOUNDS_K = (173.15, 473.15)  # observation-space bounds; far outside any state we simulate


class Clamp(NamedTuple):
    """One action entry outside its range: what was asked and what was applied instead."""

    agent: str  # "cabinet_2", "tower_0"
    field: str  # "supply_temp_setpoint_k", "valve_fraction[1]", "lw_setpoint_index"
    requested: float
    applied: float

    def __str__(self) -> str:
        return f"{self.agent}.{self.field}: requested {self.requested:g}, applied {self.applied:g}"


@dataclass(frozen=True)
class EpisodeConfig:
    """What every lc-mesh env is built from; the defaults reproduce LC-Opt's setting (the ``lcopt`` scenario on
    lcopt-5-paper, the plant the shipped policies were trained on; docs/twin.md)."""

    system: str = "lcopt-5-paper"
    """Reference system name (``lcopt-5``) or a path to a system-description JSON."""
    trace: str = "synthetic:0"
    """Load and weather: ``"synthetic:SEED"``, ``"frontier-2024-04-07"`` or a CSV path."""
    scenario: str = "lcopt"
    """How the trace drives the plant (``lcmesh.twin.traces.SCENARIOS``): ``lcopt`` is LC-Opt's 25:1 branch skew
    and 225 kW loads; ``frontier`` and ``design-day`` are the real loads."""
    wet_bulb_offset_k: float | None = 15.0
    """Replaces the scenario's wet-bulb offset (+15 K is the LC-Opt paper's hardening); None keeps the scenario's."""
    trace_hours: float | None = None
    """Use only the first hours of the trace (None: all of it, 24 h for synthetic traces)."""
    episode_steps: int | None = 200
    """Steps before truncation (LC-Opt: 200); None runs to the end of the trace."""
    warmup_steps: int = 20
    """Default-policy steps at the start row's inputs before the first observation (20 = 5 min)."""
    runaway_temp_k: float = KELVIN_OFFSET + 85.0
    """The episode terminates when any blade group is hotter than this."""
    random_start: bool = True
    """Draw the start row uniformly so the episode fits in the trace (else row 0).
    With ``episode_steps=None`` every episode starts at row 0."""
    spin_up_hours: float = 1.0
    """Run at the first trace row's inputs once at construction; that state is what reset restores."""

    def __post_init__(self) -> None:
        if self.episode_steps is not None and self.episode_steps < 1:
            raise ValueError(f"`episode_steps` must be >= 1 or None, got {self.episode_steps}")
        if self.warmup_steps < 0:
            raise ValueError(f"`warmup_steps` must be >= 0, got {self.warmup_steps}")
        if not (math.isfinite(self.runaway_temp_k) and self.runaway_temp_k > 0):
            raise ValueError(f"`runaway_temp_k` must be a positive number of kelvin, got {self.runaway_temp_k}")
        if not (math.isfinite(self.spin_up_hours) and self.spin_up_hours >= 0):
            raise ValueError(f"`spin_up_hours` must be >= 0, got {self.spin_up_hours}")
        if self.wet_bulb_offset_k is not None and not math.isfinite(self.wet_bulb_offset_k):
            raise ValueError(f"`wet_bulb_offset_k` must be a finite number of kelvin, got {self.wet_bulb_offset_k}")


class TwinEnv(gym.Env):
    """What the single-agent envs share: reset through the episode driver, close it.

    Subclasses set ``self.driver`` (see :func:`open_episode`) and define ``_observe()``.
    """

    driver: "EpisodeDriver"

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        start_row = options.get("start_row") if options else None
        self.driver.reset(self.np_random, start_row)
        return self._observe(), {"time_s": self.driver.time_s, "start_row": self.driver.start_row}

    def _observe(self) -> np.ndarray:
        raise NotImplementedError

    def close(self) -> None:
        self.driver.close()


def open_episode(
    env_name: str, config: EpisodeConfig | None, render_mode: str | None, overrides: dict[str, Any]
) -> tuple[EpisodeConfig, "EpisodeDriver"]:
    """The shared start of every env's constructor: refuse render modes, merge config, start the driver."""
    if render_mode is not None:
        raise ValueError(f"{env_name} has no render modes, got render_mode={render_mode!r}")
    merged = make_config(config, overrides)
    return merged, EpisodeDriver(merged)


def make_config(config: EpisodeConfig | None, overrides: dict[str, Any]) -> EpisodeConfig:
    """``config`` (or the defaults) with keyword overrides; unknown names say what is valid."""
    base = config or EpisodeConfig()
    if not overrides:
        return base
    known = EpisodeConfig.__dataclass_fields__
    unknown = sorted(set(overrides) - set(known))
    if unknown:
        raise TypeError(f"unknown env option(s) {unknown}; valid: {', '.join(known)}")
    fields = {name: getattr(base, name) for name in known}
    return EpisodeConfig(**{**fields, **overrides})


class EpisodeDriver:
    """Steps the plant along the trace for one env; owns the default policy for uncontrolled parts."""

    def __init__(self, config: EpisodeConfig):
        self.config = config
        self.system = load_system(config.system)
        self.plant = Plant(self.system)
        self.trace = load_trace(
            config.trace,
            self.system,
            scenario=(
                config.scenario
                if config.wet_bulb_offset_k is None
                else scenario_with_offset(config.scenario, config.wet_bulb_offset_k)
            ),
            hours=config.trace_hours,
        )
        self.default_policy = StaticController(self.system)
        self.step_s = self.system.step_s
        self.n_rows = self.trace.n_steps
        self.blade_power_w = np.empty(self.system.n_blade_groups)
        """Blade-group load (W) of the coming step; overwritten every step."""
        self.wet_bulb_k = 0.0
        """Wet bulb (K) of the coming step."""
        self.start_row = 0
        self.steps_done = 0
        self.time_s = 0.0
        self._group_shares = self.trace.skew.group_shares
        self._blade_2d = self.blade_power_w.reshape(self._group_shares.shape)
        self._chunk_start = -1
        self._chunk_branch_w = np.empty((0, self.system.n_branches))
        self._blade_temp_k = self.plant.out["blade_temp_k"]
        self._runaway_k = config.runaway_temp_k
        self._last_row = self.n_rows - 1
        self._spin_up()

    # --- inputs ----------------------------------------------------------
    def _load_inputs(self, row: int) -> None:
        """Fill ``blade_power_w`` and ``wet_bulb_k`` with trace row ``row``."""
        offset = row - self._chunk_start
        if not 0 <= offset < self._chunk_branch_w.shape[0]:
            self._load_chunk(row)
            offset = 0
        np.multiply(self._chunk_branch_w[offset][:, None], self._group_shares, out=self._blade_2d)
        self.wet_bulb_k = float(self.trace.wet_bulb_k[row])

    def _load_chunk(self, row: int) -> None:
        rows = np.arange(row, min(row + _CHUNK_ROWS, self.n_rows))
        loads = self.trace.cabinet_load_w[rows[0] : rows[-1] + 1]
        branch = loads[:, :, None] * self.trace.branch_shares(rows)
        self._chunk_branch_w = branch.reshape(len(rows), -1)
        self._chunk_start = row

    def observation(self) -> Observation:
        """What a controller sees before the coming step."""
        return Observation(self.plant.out, self.wet_bulb_k, self.blade_power_w, self.time_s)

    def default_action(self) -> PlantAction:
        """The default policy's setpoints for the coming step (do not modify the arrays)."""
        return self.default_policy.act(self.observation())

    # --- episode -----------------------------------------------------------
    def _spin_up(self) -> None:
        self._load_inputs(0)
        self.default_policy.reset()
        action = self.default_action()
        self.plant.spin_up(self.blade_power_w, self.wet_bulb_k, action, hours=self.config.spin_up_hours)

    def reset(self, np_random: np.random.Generator, start_row: int | None = None) -> dict[str, np.ndarray]:
        """Restore the spun-up state, pick the start row, warm up at its inputs; return the plant outputs."""
        episode_steps = self.config.episode_steps
        if start_row is None:
            if self.config.random_start and episode_steps is not None:
                start_row = int(np_random.integers(0, max(0, self.n_rows - episode_steps) + 1))
            else:
                start_row = 0
        elif not 0 <= (start_row := operator.index(start_row)) < self.n_rows:
            raise ValueError(f"`start_row` must be in [0, {self.n_rows}) for {self.trace.name!r}, got {start_row}")
        self.start_row = start_row
        self.steps_done = 0
        self.time_s = start_row * self.step_s
        self.plant.reset()
        self.default_policy.reset()
        self._load_inputs(start_row)
        for _ in range(self.config.warmup_steps):
            self.plant.step(self.blade_power_w, self.wet_bulb_k, self.default_action())
        return self.plant.out

    def step(self, action: PlantAction) -> tuple[dict[str, np.ndarray], bool, bool]:
        """Advance one step with ``action``; return (plant outputs, terminated, truncated)."""
        out = self.plant.step(self.blade_power_w, self.wet_bulb_k, action)
        self.steps_done += 1
        row = self.start_row + self.steps_done
        self.time_s = row * self.step_s
        episode_steps = self.config.episode_steps
        truncated = row > self._last_row or (episode_steps is not None and self.steps_done >= episode_steps)
        if row <= self._last_row:
            self._load_inputs(row)
        terminated = bool(self._blade_temp_k.max() > self._runaway_k)
        return out, terminated, truncated

    def in_band_fraction(self) -> float:
        """KPI sample: the fraction of blade groups within 20..40 degC now."""
        t = self._blade_temp_k
        lo, hi = KPI_BAND_K
        return int(np.count_nonzero((t >= lo) & (t <= hi))) / t.size

    def close(self) -> None:
        self.plant.close()

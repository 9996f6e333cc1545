"""A plant that is not the detector's model: the maintenance benchmark's mismatch scenario.

The fault detector models the plant with the system description's parameters (the toolbox). A real
plant differs from its description, drifts, and carries loads nobody planned. One draw of
:class:`PlantMismatch` (seeded, per run) gives the simulated plant, while the detector keeps the
nominal description (docs/maintenance.md, "Model mismatch"):

| what | amount | how the twin gets it |
|---|---|---|
| CDU HX UA | x (0.80-0.90 or 1.10-1.20) per cabinet | ``deviation_hx_ua_factor`` |
| CDU pump curve head | x (0.80-0.90 or 1.10-1.20) per cabinet | ``deviation_pump_head_factor`` |
| tower approach fit | x (0.80-0.90 or 1.10-1.20) per tower | ``deviation_ct_approach_factor`` |
| HX fouling | UA falls 2-5 % per day (linear) per cabinet | the UA factor, every step |
| supply sensor | offset +-0.2 K, drift +-0.1-0.3 K/day per cabinet | ``fault_sensor_bias_k`` (its loop follows) |
| return sensor | offset +-0.2 K, drift +-0.1-0.3 K/day per cabinet | added to what the detector reads |
| load transients | ~1 per 2 h per cabinet: IT power x 0.4-0.7 or 1.3-1.6, 10-60 min | the twin's blade power |

The supply sensor is the one the CDU's valve loop reads, so its offset goes through the twin's sensor
input (the plant controls to the wrong temperature, as a real one would); an injected sensor-bias
fault adds to it. The return sensor is read only by the detector.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from lcmesh.twin.plant import Plant
from lcmesh.twin.system import SystemDescription

DAY_S = 86400.0


@dataclass(frozen=True)
class MismatchSpec:
    """The amounts of one mismatch scenario (ranges are drawn uniformly; signs at random)."""

    parameter_error: tuple[float, float] = (0.10, 0.20)  # |factor - 1| on UA, pump head, tower fit
    fouling_per_day: tuple[float, float] = (0.02, 0.05)  # UA lost per day
    sensor_offset_k: float = 0.2  # calibration offset at the start, uniform in +-this
    sensor_drift_k_per_day: tuple[float, float] = (0.1, 0.3)
    load_steps_per_hour: float = 0.5  # per cabinet, Poisson
    load_drop: tuple[float, float] = (0.4, 0.7)  # IT power factor of a job ending
    load_rise: tuple[float, float] = (1.3, 1.6)  # ... of a job starting
    load_step_minutes: tuple[float, float] = (10.0, 60.0)


@dataclass(frozen=True)
class LoadStep:
    cabinet: int  # zero-based
    start_step: int
    end_step: int  # exclusive
    factor: float


@dataclass(frozen=True)
class PlantMismatch:
    """One seeded draw of how the simulated plant differs from the detector's model (see the module docstring)."""

    hx_ua_factor: np.ndarray  # (C,) at the start of the run
    pump_head_factor: np.ndarray  # (C,)
    ct_approach_factor: np.ndarray  # (N,)
    fouling_per_day: np.ndarray  # (C,) fraction of UA lost per day
    supply_offset_k: np.ndarray  # (C,) at the start
    supply_drift_k_per_day: np.ndarray  # (C,)
    return_offset_k: np.ndarray  # (C,)
    return_drift_k_per_day: np.ndarray  # (C,)
    load_steps: tuple[LoadStep, ...]
    step_s: float

    @classmethod
    def draw(cls, system: SystemDescription, n_steps: int, rng: np.random.Generator,
             spec: MismatchSpec = MismatchSpec()) -> "PlantMismatch":  # fmt: skip
        """A random plant within `spec` for a run of `n_steps` steps."""
        C, N = system.cabinets.count, system.towers.count

        def factor(n: int) -> np.ndarray:
            return 1.0 + rng.choice([-1.0, 1.0], n) * rng.uniform(*spec.parameter_error, n)

        def signed(low_high: tuple[float, float], n: int) -> np.ndarray:
            return rng.choice([-1.0, 1.0], n) * rng.uniform(*low_high, n)

        steps, per_step = [], spec.load_steps_per_hour * system.step_s / 3600.0
        for i in range(C):
            for start in np.flatnonzero(rng.random(n_steps) < per_step):
                minutes = rng.uniform(*spec.load_step_minutes)
                size = rng.uniform(*(spec.load_drop if rng.random() < 0.5 else spec.load_rise))
                end = min(int(start + minutes * 60.0 / system.step_s), n_steps)
                steps.append(LoadStep(i, int(start), end, float(size)))
        return cls(
            hx_ua_factor=factor(C), pump_head_factor=factor(C), ct_approach_factor=factor(N),
            fouling_per_day=rng.uniform(*spec.fouling_per_day, C),
            supply_offset_k=rng.uniform(-spec.sensor_offset_k, spec.sensor_offset_k, C),
            supply_drift_k_per_day=signed(spec.sensor_drift_k_per_day, C),
            return_offset_k=rng.uniform(-spec.sensor_offset_k, spec.sensor_offset_k, C),
            return_drift_k_per_day=signed(spec.sensor_drift_k_per_day, C),
            load_steps=tuple(steps), step_s=system.step_s,
        )  # fmt: skip

    def ua_factor(self, step: int) -> np.ndarray:
        """(C,) the HX UA factor at `step`: the drawn error, less the fouling so far."""
        return self.hx_ua_factor * (1.0 - self.fouling_per_day * step * self.step_s / DAY_S)

    def supply_sensor_error_k(self, step: int) -> np.ndarray:
        return self.supply_offset_k + self.supply_drift_k_per_day * step * self.step_s / DAY_S

    def return_sensor_error_k(self, step: int) -> np.ndarray:
        return self.return_offset_k + self.return_drift_k_per_day * step * self.step_s / DAY_S

    def apply(self, plant: Plant, step: int, sensor_bias_k: np.ndarray | float = 0.0) -> None:
        """Set the plant's deviations and supply-sensor error for `step` (plus an injected `sensor_bias_k`)."""
        plant.set_deviations(hx_ua_factor=self.ua_factor(step), pump_head_factor=self.pump_head_factor,
                             ct_approach_factor=self.ct_approach_factor)  # fmt: skip
        plant.set_faults(sensor_bias_k=self.supply_sensor_error_k(step) + sensor_bias_k)

    def scale_load(self, step: int, blade_power_w: np.ndarray, groups_per_cabinet: int) -> np.ndarray:
        """`blade_power_w` (in place) with the load steps active at `step`."""
        for s in self.load_steps:
            if s.start_step <= step < s.end_step:
                blade_power_w[s.cabinet * groups_per_cabinet : (s.cabinet + 1) * groups_per_cabinet] *= s.factor
        return blade_power_w

    def measured(self, out: dict[str, np.ndarray], step: int) -> dict[str, np.ndarray]:
        """What the detector reads (in place): the return sensors' error added."""
        out["return_temp_k"] = out["return_temp_k"] + self.return_sensor_error_k(step)
        return out

    def summary(self) -> dict:
        """The drawn amounts, JSON-ready (the load steps counted)."""
        d = {k: np.round(v, 4).tolist() for k, v in asdict(self).items() if isinstance(v, np.ndarray)}
        return {**d, "load_steps": len(self.load_steps)}

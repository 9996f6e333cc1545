"""``lcmesh bench maintenance``: detection rate, delay and false alarms of the fault detector on simulated days.

Each run is lcopt-5 under the G36 controller on one day (the Frontier day and seeded synthetic days from the
evaluation split, all in the default "frontier" scenario: real CDU loads and the day's own wet bulb). A
fault of one kind is injected at a random step (1 h to 20 h into the day), location and size; the detector
sees the plant outputs through a seeded sensor-noise model. A second twin without the fault runs in lockstep
from the injection step (same inputs, a copy of the controller) to find when the fault first *shows*: a
valve stuck where the healthy valve would be anyway, or a spare cell taken out while the tower does not need
it, changes nothing until the operating point moves. "Shows" means: pump speed or flow differ (pump), the
measured supply differs (sensor bias), the true supply temperature differs by more than the valve loop's own
deadband (stuck valve), a cell's fan power or heat differs by more than 1 % of nominal (cell out). Delays
are reported from injection and from that moment.

Every run is made on the matched plant (the twin is the detector's model) and, with the same injections
and noise, on a mismatched plant (:mod:`lcmesh.bench.mismatch`: parameters 10-20 % off, fouling, sensor
drift, load steps) that the detector models with the nominal description; ``nominal_detector`` adds the
detector without baseline learning on those plants.

False alarms are fault findings (the four fault kinds) raised on fault-free days and before injection
in fault runs, per simulated fault-free day. Overtemperature and trend findings describe real
conditions, not faults: they are counted on the fault-free days, with the share of trend warnings that
an overtemperature at the same cabinet follows within the horizon (precision) and the share of
overtemperatures a trend warning preceded (recall).
"""

from __future__ import annotations

import copy
import statistics
import time
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass

import numpy as np

from lcmesh.bench.machine import machine_info
from lcmesh.bench.mismatch import MismatchSpec, PlantMismatch
from lcmesh.mesh.tools.maintenance import FAULT_KINDS, DetectorConfig, FaultDetector, ValveExercise
from lcmesh.twin.controllers import Observation, make_controller
from lcmesh.twin.fmu_runner import FmuState
from lcmesh.twin.plant import Plant
from lcmesh.twin.system import SystemDescription, load_system
from lcmesh.twin.traces import DEFAULT_SCENARIO, EVAL_SEEDS, FRONTIER_DAY, Trace, load_trace, scenario_named

TARGETS = {"detection_rate": 0.90, "median_delay_min": 10.0, "false_alarms_per_day": 1.0}
_NOISELESS = ("cells_active", "stored_energy_j", "stored_energy_change_j", "energy_in_j", "energy_rejected_j",
              "energy_recovered_j")  # fmt: skip


@dataclass(frozen=True)
class SensorNoise:
    """Gaussian measurement noise (1 sigma) on what the detector reads; setpoints and staging are exact."""

    temp_k: float = 0.05
    flow_rel: float = 0.005
    pressure_rel: float = 0.005
    power_rel: float = 0.01
    power_abs_w: float = 100.0
    speed: float = 0.002
    valve: float = 0.003

    def scaled(self, factor: float) -> "SensorNoise":
        return SensorNoise(**{k: v * factor for k, v in asdict(self).items()})

    def apply(self, out: Mapping[str, np.ndarray], rng: np.random.Generator) -> dict[str, np.ndarray]:
        """A noisy copy of the plant outputs."""
        noisy = {}
        for name, value in out.items():
            v = np.array(value, dtype=float)
            if name.startswith("applied_") or name in _NOISELESS:
                pass
            elif name.endswith("_k"):
                v += rng.normal(0.0, self.temp_k, v.shape)
            elif name.endswith("_kg_s"):
                v *= 1.0 + rng.normal(0.0, self.flow_rel, v.shape)
            elif name.endswith("_pa"):
                v *= 1.0 + rng.normal(0.0, self.pressure_rel, v.shape)
            elif name.endswith("_w"):
                v = v * (1.0 + rng.normal(0.0, self.power_rel, v.shape)) + rng.normal(0.0, self.power_abs_w, v.shape)
            elif name in ("pump_speed", "fan_speed"):
                v += rng.normal(0.0, self.speed, v.shape)
            elif name == "primary_valve":
                v += rng.normal(0.0, self.valve, v.shape)
            noisy[name] = v
        return noisy


@dataclass(frozen=True)
class Injection:
    """One injected fault: kind, zero-based index, size and the step it starts."""

    kind: str
    index: int  # cabinet, or tower * cells + cell for cell_out
    magnitude: float  # head loss, bias K, or 1
    step: int

    def location(self, system: SystemDescription) -> str:
        """Where the detector reports it: numbered from 1, ``cabinet_3``, ``tower_1/cell_2``."""
        if self.kind == "cell_out":
            tower, cell = divmod(self.index, system.towers.cells)
            return f"tower_{tower + 1}/cell_{cell + 1}"
        return f"cabinet_{self.index + 1}"

    def faults(self, system: SystemDescription) -> dict[str, np.ndarray]:
        C, N, m = system.cabinets.count, system.towers.count, system.towers.cells
        size = N * m if self.kind == "cell_out" else C
        value = np.zeros(size)
        value[self.index] = self.magnitude
        name = {"sensor_bias": "sensor_bias_k"}.get(self.kind, self.kind)
        return {name: value.reshape(N, m) if self.kind == "cell_out" else value}


def sample_injection(kind: str, system: SystemDescription, n_steps: int, rng: np.random.Generator) -> Injection:
    """A random fault of `kind`: pump head loss 15-60 %, sensor bias +-0.5-2 K, between 1 h and 20 h."""
    step_h = 3600.0 / system.step_s
    step = int(rng.integers(int(1 * step_h), min(int(20 * step_h), n_steps - 1)))
    if kind == "cell_out":
        return Injection(kind, int(rng.integers(system.n_cells)), 1.0, step)
    index = int(rng.integers(system.cabinets.count))
    magnitude = {
        "pump_degradation": float(rng.uniform(0.15, 0.60)),
        "sensor_bias": float(rng.choice([-1.0, 1.0]) * rng.uniform(0.5, 2.0)),
        "valve_stuck": 1.0,
    }[kind]
    return Injection(kind, index, magnitude, step)


def _manifested(kind: str, faulty: Mapping[str, np.ndarray], healthy: Mapping[str, np.ndarray], system) -> bool:
    """Has the fault changed what the plant does (vs the healthy twin)? See the module docstring."""

    def differs(name: str, tolerance: float) -> bool:
        return bool(np.any(np.abs(np.asarray(faulty[name]) - np.asarray(healthy[name])) > tolerance))

    if kind == "pump_degradation":
        return differs("pump_speed", 0.005) or differs("secondary_flow_kg_s", 0.1)
    if kind == "valve_stuck":  # the supply it controls has left the loop's own deadband vs the healthy plant
        return differs("supply_temp_k", system.cabinets.cdu.temp_deadband_k)
    if kind == "sensor_bias":
        return differs("supply_temp_measured_k", 0.05)
    fan_w, heat_w = system.towers.cell.fan_power_nominal_w, system.towers.cell.design_heat_w
    return differs("cell_fan_power_w", 0.01 * fan_w) or differs("cell_heat_w", 0.01 * heat_w)


def run_day(
    plant: Plant,
    healthy: Plant,
    trace: Trace,
    injection: Injection | None,
    noise: SensorNoise,
    seed: int,
    config: DetectorConfig | None = None,
    start: FmuState | None = None,
    valve_exercise_s: float = 0.0,
    mismatch: PlantMismatch | None = None,
) -> dict:
    """One day under G36 with an optional fault; stops early once the fault is found and has shown.

    `start` is the state to spin up from (the FMU's initial state), so a run does not depend on the one before.
    `valve_exercise_s` > 0 strokes each primary valve that often (:class:`ValveExercise`). `mismatch`: the
    plant (and its healthy copy) differs from the description the detector models (:mod:`lcmesh.bench.mismatch`).
    """
    system = plant.system
    if start is not None:
        plant.restore_state(start)
    controller = make_controller("g36", system)
    detector = FaultDetector(system, config)
    rng = np.random.default_rng(seed)
    power = np.zeros(system.n_blade_groups)
    first = Observation(plant.out, float(trace.wet_bulb_k[0]), trace.blade_power_w(0, out=power), 0.0)
    plant.set_faults(pump_degradation=0, valve_stuck=0, cell_out=0, sensor_bias_k=0)
    groups = system.cabinets.branches * system.cabinets.blade_groups_per_branch
    if mismatch is not None:
        mismatch.apply(plant, 0)
        mismatch.scale_load(0, power, groups)
    plant.spin_up(power, first.wet_bulb_k, controller.act(first), hours=1.0)
    out = plant.reset()
    controller.reset()
    location = injection.location(system) if injection else None
    record = dict(trace=trace.name, injection=asdict(injection) if injection else None, location=location,
                  false_alarms=[], other_findings=[], misattributed=[], detected_step=None,
                  manifest_step=None)  # fmt: skip
    twin_ctrl, healthy_out, twin_exercise = None, None, None
    exercise = ValveExercise(system, period_s=valve_exercise_s)
    k = 0
    for k in range(trace.n_steps):
        wet_bulb = float(trace.wet_bulb_k[k])
        trace.blade_power_w(k, out=power)
        if mismatch is not None:
            mismatch.scale_load(k, power, groups)
        if injection is not None and k == injection.step:
            state = plant.save_state()
            copied = healthy.runner.deserialize_state(plant.runner.serialize_state(state))
            healthy.restore_state(copied)
            healthy.free_state(copied)
            plant.free_state(state)
            twin_ctrl, healthy_out, twin_exercise = copy.deepcopy(controller), healthy.out, copy.deepcopy(exercise)
            plant.set_faults(**injection.faults(system))
        if mismatch is not None:  # after the injection: its faults would overwrite the mismatch's sensor error
            mismatch.apply(plant, k, _injected_bias(injection, k, system))
        action = controller.act(Observation(out, wet_bulb, power, k * trace.step_s))
        action, _ = exercise.stroked(k, action, out)
        out = plant.step(power, wet_bulb, action)
        if twin_ctrl is not None and record["manifest_step"] is None:
            if mismatch is not None:
                mismatch.apply(healthy, k)
            healthy_action = twin_ctrl.act(Observation(healthy_out, wet_bulb, power, k * trace.step_s))
            healthy_action, _ = twin_exercise.stroked(k, healthy_action, healthy_out)
            healthy_out = healthy.step(power, wet_bulb, healthy_action)
            if _manifested(injection.kind, out, healthy_out, system):
                record["manifest_step"] = k
        measured = noise.apply(out, rng)
        if mismatch is not None:
            mismatch.measured(measured, k)
        detector.update((k + 1) * trace.step_s, measured, wet_bulb, action)
        for f in detector.last_raised:
            entry = (k, f.kind, f.location)
            if f.kind not in FAULT_KINDS:
                record["other_findings"].append(entry)
            elif injection is None or k < injection.step:
                record["false_alarms"].append(entry)
            elif f.kind == injection.kind and f.location == location and record["detected_step"] is None:
                record["detected_step"] = k
            elif record["detected_step"] is None:
                record["misattributed"].append(entry)
        if record["detected_step"] is not None and record["manifest_step"] is not None:
            break
    record["steps_run"] = k + 1
    record["fault_free_steps"] = injection.step if injection else k + 1
    return record


def _injected_bias(injection: Injection | None, step: int, system: SystemDescription) -> np.ndarray | float:
    """The injected supply-sensor bias at `step` (0 before injection or for other kinds)."""
    if injection is None or injection.kind != "sensor_bias" or step < injection.step:
        return 0.0
    return injection.faults(system)["sensor_bias_k"]


def _delay_stats(minutes: list[float]) -> dict:
    if not minutes:
        return {"median_min": None, "p90_min": None}
    return {"median_min": statistics.median(minutes), "p90_min": float(np.percentile(minutes, 90))}


def _trend_quality(clean_runs: list[dict], horizon_steps: int) -> dict:
    """Precision and recall of trend warnings as predictors of an overtemperature at the same cabinet."""
    hits = n_trend = preceded = n_hot = 0
    for r in clean_runs:
        trends = [(k, loc) for k, kind, loc in r["other_findings"] if kind == "trend"]
        hots = [(k, loc) for k, kind, loc in r["other_findings"] if kind == "overtemperature" and k > 10]
        n_trend, n_hot = n_trend + len(trends), n_hot + len(hots)
        hits += sum(any(loc2 == loc and k < k2 <= k + horizon_steps for k2, loc2 in hots) for k, loc in trends)
        preceded += sum(any(loc2 == loc and k - horizon_steps <= k2 < k for k2, loc2 in trends) for k, loc in hots)
    return {"trend_precision": hits / n_trend if n_trend else None,
            "trend_recall": preceded / n_hot if n_hot else None}  # fmt: skip


def summarize(runs: list[dict], step_s: float) -> dict:
    """Per fault kind: detection rate and delays; overall: false alarms per fault-free day."""
    per_kind = {}
    for kind in FAULT_KINDS:
        mine = [r for r in runs if r["injection"] and r["injection"]["kind"] == kind]
        if not mine:
            continue
        detected = [r for r in mine if r["detected_step"] is not None]
        shown = [r for r in mine if r["manifest_step"] is not None]
        from_injection = [(r["detected_step"] - r["injection"]["step"] + 1) * step_s / 60 for r in detected]
        from_manifest = [max(r["detected_step"] - r["manifest_step"], 0) * step_s / 60 + step_s / 60
                         for r in detected if r["manifest_step"] is not None]  # fmt: skip
        per_kind[kind] = {
            "injected": len(mine),
            "detected": len(detected),
            "detection_rate": len(detected) / len(mine),
            "manifested": len(shown),
            "detection_rate_manifested": (
                sum(r["detected_step"] is not None for r in shown) / len(shown) if shown else None
            ),
            "delay_from_injection": _delay_stats(from_injection),
            "delay_from_manifestation": _delay_stats(from_manifest),
            "misattributed_findings": sum(len(r["misattributed"]) for r in mine),
        }
    fault_free_days = sum(r["fault_free_steps"] for r in runs) * step_s / 86400.0
    false_alarms = [fa for r in runs for fa in r["false_alarms"]]
    by_kind = {kind: sum(1 for fa in false_alarms if fa[1] == kind) for kind in FAULT_KINDS}
    clean = [r for r in runs if r["injection"] is None]
    clean_days = sum(r["fault_free_steps"] for r in clean) * step_s / 86400.0
    others = {kind: sum(1 for r in clean for f in r["other_findings"] if f[1] == kind)
              for kind in ("overtemperature", "trend")}  # fmt: skip
    others.update(_trend_quality(clean, horizon_steps=int(DetectorConfig().trend_horizon_s / step_s) + 40))
    return {
        "per_kind": per_kind,
        "false_alarms": {
            "fault_free_days": fault_free_days,
            "count": len(false_alarms),
            "per_day": len(false_alarms) / fault_free_days if fault_free_days else None,
            "by_kind": by_kind,
            "examples": false_alarms[:10],
        },
        "condition_findings_on_fault_free_days": {"days": clean_days, **others},
    }


SCENARIOS = {
    "matched": "the plant is the detector's model",
    "mismatched": "the plant differs from the model (lcmesh.bench.mismatch); the detector learns its baselines",
    "mismatched_nominal_detector": "the same plants; the detector takes the model's zero as the baseline",
}
NOMINAL_DETECTOR = DetectorConfig(baseline_learn_s=0.0, baseline_tau_s=0.0)  # the model taken as the plant
_MISMATCH_SEED = 20251121


def run_bench_maintenance(
    quick: bool = False,
    seeds: int | None = None,
    noise_scale: float = 1.0,
    on_run: Callable[[int, int], None] | None = None,
    valve_exercise_s: float = 600.0,
    mismatch: bool = True,
    nominal_detector: bool = False,
    held_out: bool = False,
) -> dict:
    """The whole benchmark: fault-free days plus `seeds` injections per (day, fault kind), on the matched plant
    and (`mismatch`) on plants that differ from the detector's model; `nominal_detector` adds the detector
    without baseline learning on those plants. The same injections and noise seeds in every scenario.
    `held_out`: synthetic days, injections and plants not used while the detector was tuned (the next four
    evaluation days, other seeds; the Frontier day is the only one there is)."""
    system = load_system("lcopt-5")
    n_synthetic = 1 if quick else 4
    seeds = seeds if seeds is not None else (1 if quick else 3)
    first = n_synthetic if held_out else 0
    synthetic = list(EVAL_SEEDS)[first : first + n_synthetic]
    days = [FRONTIER_DAY, *(f"synthetic:{s}" for s in synthetic)]
    noise = SensorNoise().scaled(noise_scale)
    traces = {spec: load_trace(spec, system, scenario=DEFAULT_SCENARIO) for spec in days}
    rng = np.random.default_rng(20240407 + held_out)
    mismatch_seed = _MISMATCH_SEED + held_out
    plan = []  # (trace, injection, noise seed, mismatch)
    for spec in days:
        for kind in (None, *(k for k in FAULT_KINDS for _ in range(seeds))):
            trace = traces[spec]
            injection = sample_injection(kind, system, trace.n_steps, rng) if kind else None
            drawn = PlantMismatch.draw(system, trace.n_steps, np.random.default_rng([mismatch_seed, len(plan)]))
            plan.append((trace, injection, int(rng.integers(2**31)), drawn))
    scenarios = ["matched"] + ["mismatched"] * mismatch + ["mismatched_nominal_detector"] * nominal_detector
    results, done = {}, 0
    with Plant(system) as plant, Plant(system, instance_name="healthy") as healthy:
        initial = plant.save_state()
        for name in scenarios:
            runs, t0 = [], time.perf_counter()
            config = NOMINAL_DETECTOR if name == "mismatched_nominal_detector" else None
            for trace, injection, seed, drawn in plan:
                runs.append(run_day(plant, healthy, trace, injection, noise, seed=seed, config=config, start=initial,
                                    valve_exercise_s=valve_exercise_s,
                                    mismatch=drawn if name != "matched" else None))  # fmt: skip
                if name != "matched":
                    runs[-1]["mismatch"] = drawn.summary()
                done += 1
                if on_run is not None:
                    on_run(done, len(plan) * len(scenarios))
            results[name] = _scenario(runs, system.step_s, time.perf_counter() - t0, config or DetectorConfig())
    matched = results.pop("matched")
    return {
        "machine": machine_info(),
        "system": system.name,
        "controller": "g36",
        "days": days,
        "trace_scenario": DEFAULT_SCENARIO,
        "injections_per_day_and_kind": seeds,
        "held_out": held_out,
        "valve_exercise_s": valve_exercise_s,
        "noise": asdict(noise),
        **matched,
        "targets": TARGETS,
        "mismatch_amounts": asdict(MismatchSpec()),
        **results,
        "wall_s": matched["wall_s"] + sum(r["wall_s"] for r in results.values()),
        "simulated_days": matched["simulated_days"] + sum(r["simulated_days"] for r in results.values()),
    }


def _scenario(runs: list[dict], step_s: float, wall_s: float, config: DetectorConfig) -> dict:
    """One scenario's summary, its verdict against the targets and its runs."""
    summary = summarize(runs, step_s)
    fa = summary["false_alarms"]["per_day"]
    meets = {
        kind: {
            "detection_rate": r["detection_rate"] >= TARGETS["detection_rate"],
            "median_delay": (r["delay_from_injection"]["median_min"] or float("inf")) <= TARGETS["median_delay_min"],
        }
        for kind, r in summary["per_kind"].items()
    }
    return {
        "detector_config": config.model_dump(),
        **summary,
        "meets_targets": {**meets, "false_alarms": fa is not None and fa <= TARGETS["false_alarms_per_day"]},
        "wall_s": wall_s,
        "simulated_days": sum(r["steps_run"] for r in runs) * step_s / 86400.0,
        "runs": runs,
    }


def render_maintenance(r: dict) -> str:
    """The BENCHMARKS.md section: per fault kind and plant, then false alarms per plant."""
    m = r["machine"]

    def fmt(x, spec=".1f"):
        return "n/a" if x is None else format(x, spec)

    scenarios = {"matched": r, **{name: r[name] for name in SCENARIOS if name != "matched" and name in r}}
    label = {"matched": "matched", "mismatched": "mismatched",
             "mismatched_nominal_detector": "mismatched, no baseline learning"}  # fmt: skip
    lines = [
        "## Maintenance fault detector (`lcmesh bench maintenance --json runs/bench/maintenance.json "
        "--markdown BENCHMARKS.md`)",
        "",
        f"Machine: {m['cpu']}, {m['logical_cpus']} logical CPUs; Python {m['python']}; commit {m['commit']}; "
        f"{m['date']}. {r['system']} under {r['controller']}; days: {', '.join(r['days'])}"
        + (f" (scenario {r['trace_scenario']}, {scenario_named(r['trace_scenario']).description})"
           if r.get("trace_scenario") else "")
        + "; "
        + ("held out (days, injections and plants not used while tuning the detector); " if r.get("held_out") else "")
        + f"{r['injections_per_day_and_kind']} injection(s) per day and fault kind at random times (1-20 h), "
        f"locations and sizes; sensor noise on every reading (docs/maintenance.md); "
        + (f"each primary valve stroked every {r['valve_exercise_s']:g} s (supply setpoint 1.5 K off the measured supply for 1 min, "
           "`ValveExercise`). " if r.get("valve_exercise_s") else "no valve exercise (passive detection). ")
        + ("Matched: the plant is the detector's model. Mismatched: each run's plant differs from it (UA, pump "
           "curve head and tower approach fit each x 0.8-0.9 or 1.1-1.2, UA fouling 2-5 %/day, supply and "
           "return sensors +-0.2 K off drifting 0.1-0.3 K/day, load steps x 0.4-0.7 or 1.3-1.6 for 10-60 min "
           "about every 2 h per cabinet; docs/maintenance.md), the same injections. "
           if len(scenarios) > 1 else "")
        + f"{r['simulated_days']:.1f} simulated days in {r['wall_s']:.0f} s.",
        "",
        "| fault | plant | detected | rate | median / p90 delay from injection (min) | rate once it shows | "
        "median / p90 delay once it shows (min) | misattributed |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for kind in r["per_kind"]:
        for name, sc in scenarios.items():
            k = sc["per_kind"][kind]
            di, dm = k["delay_from_injection"], k["delay_from_manifestation"]
            lines.append(
                f"| {kind} | {label[name]} | {k['detected']}/{k['injected']} | {k['detection_rate']:.0%} | "
                f"{fmt(di['median_min'])} / {fmt(di['p90_min'])} | {fmt(k['detection_rate_manifested'], '.0%')} "
                f"({k['manifested']} showed) | {fmt(dm['median_min'])} / {fmt(dm['p90_min'])} | "
                f"{k['misattributed_findings']} |"
            )
    lines.append("")
    for name, sc in scenarios.items():
        fa = sc["false_alarms"]
        lines.append(
            f"False alarms, {label[name]}: {fa['count']} in {fa['fault_free_days']:.1f} fault-free simulated days = "
            f"**{fmt(fa['per_day'], '.2f')} per day**; by kind: "
            + ", ".join(f"{k} {v}" for k, v in fa["by_kind"].items()) + "."
        )
    cond = r["condition_findings_on_fault_free_days"]
    lines += [
        "",
        f"Condition findings on the {cond['days']:.0f} matched fault-free days (real conditions, not faults): "
        f"overtemperature {cond['overtemperature']}, trend {cond['trend']} (an overtemperature followed "
        f"{fmt(cond['trend_precision'], '.0%')} of trend warnings within the horizon; "
        f"{fmt(cond['trend_recall'], '.0%')} of overtemperatures had one before them).",
        f"Targets: detection >= {r['targets']['detection_rate']:.0%} per kind, median delay <= "
        f"{r['targets']['median_delay_min']:.0f} min, <= {r['targets']['false_alarms_per_day']:.0f} false alarm "
        "per day.",
    ]
    return "\n".join(lines)

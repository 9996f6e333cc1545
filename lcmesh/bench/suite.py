"""``lcmesh bench suite``: every controller on a held-out suite of days, with regret against a reference (issue 13).

The days are declared here and nowhere else. Training uses ``TRAIN_SEEDS`` (0-999, lcmesh/twin/traces.py);
the test and validation days come from the Frontier day and ``EVAL_SEEDS`` (1000-1999), and
`assert_disjoint` proves no test day is a validation or training day, and that the tree distiller's default
seeds (``lcmesh distill tree``: training, held-out and reward traces) run none of them.

How the synthetic days were picked (once, deterministically; loads and wet bulbs of lcopt-5 under
``frontier``). Over seeds 1000-1040 the mean load is 1.05 +- 0.14 x design (design = the system's
``design_heat_w`` per cabinet) and the mean wet bulb 9.4 +- 4.9 C. *Mild* days: for each of the six targets
(load z = -1, +1) x (wet bulb z = -1, 0, +1), the seed nearest in z-space, first seed on ties. *Hot* days
run under ``design-day`` (Knoxville's 0.4 % design wet bulb, 20.7-24.6 C, mean 22.5 C, replaces the
trace's), so only the workload differs: for load z = -1.5, -0.5, +0.5, +1.5 the nearest seed not yet
taken. *Validation* days: seeds 1990-1993, outside the scanned range, so the test picks never depend on them.

====================  ============  ===========  ====================  ==================
label                 trace         scenario     mean load / design    mean wet bulb (C)
====================  ============  ===========  ====================  ==================
frontier              Frontier day  frontier     1.00                  7.8
frontier-hot          Frontier day  design-day   1.00                  22.5
mild-1010             1010          frontier     0.94 (low)            4.7 (cool)
mild-1037             1037          frontier     0.83 (low)            9.4 (middle)
mild-1005             1005          frontier     0.89 (low)            15.5 (warm)
mild-1039             1039          frontier     1.21 (high)           4.1 (cool)
mild-1009             1009          frontier     1.17 (high)           8.5 (middle)
mild-1019             1019          frontier     1.18 (high)           15.1 (warm)
hot-1003              1003          design-day   0.85                  22.5
hot-1016              1016          design-day   0.97                  22.5
hot-1011              1011          design-day   1.12                  22.5
hot-1033              1033          design-day   1.26                  22.5
val-mild-1990         1990          frontier     0.84                  8.9
val-mild-1991         1991          frontier     0.91                  14.9
val-hot-1992          1992          design-day   1.14                  22.5
val-hot-1993          1993          design-day   1.29                  22.5
====================  ============  ===========  ====================  ==================

Per controller and day: D_blade, tower fan, pump and cooling (fans + pumps) energy, cooling PUE, actuator
travel (summed |change| of the applied setpoints over the day and over all cabinets, branches or towers),
blade max and wall time; mean and sample std over the days; *regret* against the reference controller per
day: D_blade points below it and cooling kWh above it (positive = worse than the reference).
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lcmesh.bench.engine import (
    EngineSettings, Outcome, Unit, cache_lines, cache_summary, controller_version, run_units, twin_version,
)  # fmt: skip
from lcmesh.bench.machine import machine_info
from lcmesh.distill.tree_config import TreeDistillConfig
from lcmesh.twin.controllers import NEEDS_PLANT, Controller, make_controller
from lcmesh.twin.controllers.guarded import MESH_GUARDRAILS
from lcmesh.twin.kpi import cooling_energies_kwh
from lcmesh.twin.plant import Plant
from lcmesh.twin.run import run_twin, save_figure
from lcmesh.twin.system import PSI_TO_PA, SystemDescription, load_system
from lcmesh.twin.traces import FRONTIER_DAY, Trace, load_trace, trace_split

_K = 273.15
Progress = Callable[[str, int, int], None]


@dataclass(frozen=True)
class Day:
    """One day of the suite: a trace spec, the scenario it runs under and a short label for tables and the CLI."""

    trace: str
    scenario: str
    label: str


def _synthetic(seed: int, scenario: str, prefix: str) -> Day:
    return Day(f"synthetic:{seed}", scenario, f"{prefix}-{seed}")


MILD_SEEDS = (1010, 1037, 1005, 1039, 1009, 1019)
HOT_SEEDS = (1003, 1016, 1011, 1033)
TEST_DAYS: tuple[Day, ...] = (
    Day(FRONTIER_DAY, "frontier", "frontier"),
    Day(FRONTIER_DAY, "design-day", "frontier-hot"),
    *(_synthetic(s, "frontier", "mild") for s in MILD_SEEDS),
    *(_synthetic(s, "design-day", "hot") for s in HOT_SEEDS),
)
VALIDATION_DAYS: tuple[Day, ...] = (
    _synthetic(1990, "frontier", "val-mild"),
    _synthetic(1991, "frontier", "val-mild"),
    _synthetic(1992, "design-day", "val-hot"),
    _synthetic(1993, "design-day", "val-hot"),
)

GUARDRAILS_ON = "the mesh's guardrails (GuardrailLimits defaults, apply_guardrails) on every action"
GUARDRAILS_OFF_TEXT = "no guardrails (the paper's setting; the mesh would clamp these actions)"
FIGURES = ("d_blade_pct", "tower_fan_kwh", "pump_kwh", "cooling_kwh", "pue_cooling", "blade_max_c", "clamped_pct", "wall_s")
TRAVEL = ("supply_temp_setpoint_k", "dp_setpoint_pa", "valve_fraction", "lw_setpoint_k")
REGRET = ("d_blade_pts", "cooling_kwh")
SUITE_HEADER = (
    "| controller | D_blade % | hottest blade C | tower fans kWh | pumps kWh | cooling kWh | cooling PUE | "
    "supply travel K | dp travel psi | valve travel | tower LW travel K | clamped steps % | regret D_blade pts | "
    "regret cooling kWh |"
)


def held_out_days_in(traces: Iterable[str]) -> list[Day]:
    """The test and validation days that run one of `traces`, under any scenario (the loads are the trace's)."""
    traces = set(traces)
    return [d for d in TEST_DAYS + VALIDATION_DAYS if d.trace in traces]


def held_out_seeds() -> list[int]:
    """The synthetic seeds of the test and validation days: no training or tuning run may use them."""
    return sorted({int(d.trace.removeprefix("synthetic:")) for d in TEST_DAYS + VALIDATION_DAYS
                   if d.trace.startswith("synthetic:")})  # fmt: skip


def assert_disjoint() -> None:
    """Raise if a test day is also a validation day, a training trace, outside the evaluation split, or a trace
    the tree distiller runs by default."""
    test = {d.trace for d in TEST_DAYS}
    validation = {d.trace for d in VALIDATION_DAYS}
    if shared := test & validation:
        raise AssertionError(f"test days also used for validation: {sorted(shared)}")
    if leaked := (test | validation) & set(trace_split("train")):
        raise AssertionError(f"held-out days that are training traces: {sorted(leaked)}")
    if outside := (test | validation) - set(trace_split("eval")):
        raise AssertionError(f"held-out days outside the evaluation split (Frontier day, EVAL_SEEDS): {sorted(outside)}")
    labels = [d.label for d in TEST_DAYS + VALIDATION_DAYS]
    if len(set(labels)) != len(labels):
        raise AssertionError(f"day labels must be unique, got {labels}")
    try:
        TreeDistillConfig()  # refuses seeds that run a held-out day
    except ValueError as exc:
        raise AssertionError(f"the tree distiller's defaults: {exc}") from None


def days_named(labels: Iterable[str], pool: tuple[Day, ...] = TEST_DAYS) -> tuple[Day, ...]:
    """The days of ``pool`` with these labels, in the order given; an unknown label gets the closest known one."""
    by_label = {d.label: d for d in pool}
    days = []
    for label in labels:
        if label not in by_label:
            close = difflib.get_close_matches(label, by_label, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ValueError(f"unknown day {label!r}{hint} (known: {', '.join(by_label)})")
        days.append(by_label[label])
    return tuple(days)


def load_day(day: Day, system: SystemDescription, hours: float | None = None) -> Trace:
    """The day's trace for ``system`` under the day's scenario (the first ``hours`` when given)."""
    return load_trace(day.trace, system, scenario=day.scenario, hours=hours)


def run_day(
    system: SystemDescription, trace: Trace, controller: Controller, score_from: int = 0, guardrails=MESH_GUARDRAILS
) -> dict:
    """``controller`` on a fresh plant over ``trace``: the suite's figures for that day (from step ``score_from``,
    the steps before it a warm-up by the same controller), behind ``guardrails`` (the mesh's; None: bare)."""
    with Plant(system) as plant:
        run = run_twin(plant, trace, controller, score_from=score_from, guardrails=guardrails)
    kpi, hours = run.kpi, run.sim_seconds / 3600.0
    fan_kwh, pump_kwh = cooling_energies_kwh(kpi, hours)
    return {
        "d_blade_pct": kpi["d_blade_pct"],
        "tower_fan_kwh": fan_kwh,
        "pump_kwh": pump_kwh,
        "cooling_kwh": fan_kwh + pump_kwh,
        "it_kwh": kpi["it_power_kw_avg"] * hours,
        "pue_cooling": kpi["pue_cooling"],
        "travel": {k: kpi["actuator_travel"][k] for k in TRAVEL},
        "blade_max_c": kpi["blade_temp_max_c"],
        "wall_s": run.wall_seconds,
        "heat_recovered_kwh": kpi["heat_recovered_kw_avg"] * hours,
        "clamped_pct": float(run.guardrails.get("clamped_steps_pct", 0.0)),
        "guardrails": run.guardrails,
    }


def run_suite(
    controllers: list[str],
    system_name: str = "lcopt-5",
    days: tuple[Day, ...] = TEST_DAYS,
    hours: float = 24.0,
    reference: str = "lookahead",
    progress: Progress | None = None,
    guardrails: bool = True,
    engine: EngineSettings | None = None,
) -> dict:
    """Each controller on each day; per-day figures, mean and std over the days, regret against ``reference``.

    Every controller runs behind the mesh's guardrails unless ``guardrails`` is False (the paper's setting).
    A controller that fails to build or to run is reported with its error, not raised. The (controller, day)
    units run on ``engine`` (lcmesh/bench/engine.py: Ray, cached); the table is the serial run's, row for row.
    """
    plan = suite_plan(controllers, system_name, days, hours, guardrails)
    return suite_result(plan, run_units(plan.units, engine, progress), reference)


@dataclass
class SuitePlan:
    """A suite's units and what assembles them: the controllers, the days, the errors found before running."""

    controllers: list[str]
    system_name: str
    days: tuple[Day, ...]
    hours: float
    guardrails: bool
    facts: list[dict]
    build_errors: dict[str, str]
    units: list[Unit]


def suite_plan(controllers: list[str], system_name: str, days: tuple[Day, ...], hours: float,
               guardrails: bool) -> SuitePlan:  # fmt: skip
    """One unit per (controller, day); each controller is built once here for its version (code and artifacts)."""
    if not controllers:
        raise ValueError("`controllers` must name at least one controller, got none")
    if not days:
        raise ValueError("`days` must hold at least one day, got none")
    system = load_system(system_name)
    build_errors, units = {}, []
    for name in controllers:
        try:
            units += day_units(name, system_name, days, hours, guardrails)
        except Exception as exc:  # noqa: BLE001 - a controller that cannot be built is a result of the benchmark
            build_errors[name] = f"build failed: {type(exc).__name__}: {exc}"
    facts = [_day_facts(d, load_day(d, system, hours)) for d in days]
    return SuitePlan(list(controllers), system_name, tuple(days), hours, guardrails, facts, build_errors, units)


def built_version(controller: str, system: SystemDescription, options: dict | None = None) -> str:
    """``controller`` built once with ``options``, for its version (code and artifact files: a cache key), then
    closed; one that cannot be built raises here, before anything runs."""
    built = make_controller(controller, system, **(options or {}))
    try:
        return controller_version(built)
    finally:
        getattr(built, "close", lambda: None)()


def day_units(controller: str, system_name: str, days: Iterable[Day], hours: float | None, guardrails: bool = True,
              options: dict | None = None, tag: str | None = None,
              windows: dict[str, tuple[int, int, int]] | None = None) -> list[Unit]:  # fmt: skip
    """One unit per day of ``controller`` (built with ``options``, JSON-able keywords; see `built_version`).
    ``windows``: per day label, the (start, warm-up, scored) steps of a slice of the day (see `suite_day`)."""
    system = load_system(system_name)
    version = built_version(controller, system, options)
    # a system file is named by its absolute path: a Ray worker's working directory need not be ours
    system_ref = str(Path(system_name).resolve()) if system_name.endswith(".json") else system_name
    versions = (twin_version(), version, system.model_dump_json())
    return [Unit("lcmesh.bench.suite:suite_day",
                 {"system": system_ref, "trace": day.trace, "scenario": day.scenario, "hours": hours,
                  "controller": controller, "guardrails": guardrails, "options": options or {},
                  "window": (windows or {}).get(day.label)},
                 label=f"{system.name}: {tag or controller} on {day.label}",
                 num_cpus=unit_cpus(controller, options), versions=versions,
                 cost=10.0 if controller in NEEDS_PLANT else 1.0)  # one that simulates the plant itself: the longest
            for day in days]  # fmt: skip


def unit_cpus(controller: str, options: dict | None = None) -> float:
    """The CPUs a day of ``controller`` needs: one for the twin, the llama.cpp threads for the LLM controller (its
    ``threads`` option, else its settings'; 0, llama.cpp's default here, is one)."""
    if controller != "llm":
        return 1.0
    threads = (options or {}).get("threads")
    if threads is None:
        from lcmesh.llm.controller import LlmControllerSettings

        threads = LlmControllerSettings().control_threads
    return float(max(1, threads))


def suite_day(system: str, trace: str, scenario: str, hours: float | None, controller: str, guardrails: bool,
              options: dict | None = None, window: Sequence[int] | None = None) -> dict:
    """One unit of the benches: ``controller`` (built fresh with ``options``: no carry-over between days) on one day,
    or with ``window`` = (start, warm-up, scored steps) on the scored steps from ``start``, after a warm-up by the
    same controller. A controller that counts who decided (the LLM's) adds its counters as ``controller_stats``."""
    desc = load_system(system)
    day = load_trace(trace, desc, scenario=scenario, hours=hours)
    score_from = 0
    if window is not None:
        start, warm, steps = (int(v) for v in window)
        day, score_from = day.slice(start - warm, warm + steps), warm
    built = make_controller(controller, desc, **(options or {}))
    try:
        result = run_day(desc, day, built, score_from=score_from, guardrails=MESH_GUARDRAILS if guardrails else None)
        if callable(getattr(built, "stats_snapshot", None)):
            result["controller_stats"] = built.stats_snapshot()
        return result
    finally:
        getattr(built, "close", lambda: None)()


def suite_result(plan: SuitePlan, outcomes: list[Outcome], reference: str) -> dict:
    """The suite's table from its units' outcomes (in the plan's order): a controller with a failed day is an error."""
    by_controller: dict[str, list[Outcome]] = {}
    for o in outcomes:
        by_controller.setdefault(o.unit.kwargs["controller"], []).append(o)
    per_controller: dict[str, dict] = {}
    for name in plan.controllers:
        if name in plan.build_errors:
            per_controller[name] = {"error": plan.build_errors[name], "days": {}}
            continue
        entry: dict = {"error": None, "days": {}, "cached_days": 0}
        for day, o in zip(plan.days, by_controller[name]):
            if o.error is not None:
                entry = {"error": f"run on {day.label} failed: {o.error}", "days": {}}
                break
            entry["days"][day.label] = o.result
            entry["cached_days"] += int(o.cached)
        if entry["error"] is None:
            entry["mean"], entry["std"] = _mean_std(list(entry["days"].values()))
        per_controller[name] = entry
    result = {
        "machine": machine_info(),
        "system": plan.system_name,
        "hours": plan.hours,
        "reference": reference,
        "guardrails": GUARDRAILS_ON if plan.guardrails else GUARDRAILS_OFF_TEXT,
        "days": plan.facts,
        "controllers": per_controller,
        "cache": cache_summary(outcomes),
    }
    result["regret_note"] = _add_regret(per_controller, reference)
    return result


def _day_facts(day: Day, trace: Trace) -> dict:
    return {
        "label": day.label,
        "trace": day.trace,
        "scenario": day.scenario,
        "mean_load_kw": float(trace.cabinet_load_w.sum(axis=1).mean() / 1e3),
        "mean_wet_bulb_c": float(trace.wet_bulb_k.mean() - _K),
    }


def _mean_std(rows: list[dict]) -> tuple[dict, dict]:
    """Mean and sample std (0 for one day) of every figure over the days; travel is a nested dict."""
    mean, std = {}, {}
    for key in FIGURES:
        mean[key], std[key] = _stats([r[key] for r in rows])
    mean["travel"], std["travel"] = {}, {}
    for key in TRAVEL:
        mean["travel"][key], std["travel"][key] = _stats([r["travel"][key] for r in rows])
    return mean, std


def _stats(values: list[float]) -> tuple[float, float]:
    """Mean and sample std (n - 1; 0 for a single value)."""
    a = np.asarray(values, dtype=np.float64)
    return float(a.mean()), (float(a.std(ddof=1)) if a.size > 1 else 0.0)


def _add_regret(per_controller: dict[str, dict], reference: str) -> str | None:
    """Regret of every working controller against ``reference``, in place; a note when it cannot be computed."""
    if reference not in per_controller:
        return f"no regret: the reference {reference!r} is not among the controllers"
    ref = per_controller[reference]
    if ref["error"] is not None:
        return f"no regret: the reference {reference!r} failed ({ref['error']})"
    for entry in per_controller.values():
        if entry["error"] is not None:
            continue
        days = {
            label: {"d_blade_pts": ref["days"][label]["d_blade_pct"] - r["d_blade_pct"],
                    "cooling_kwh": r["cooling_kwh"] - ref["days"][label]["cooling_kwh"]}
            for label, r in entry["days"].items()
        }  # fmt: skip
        stats = {k: _stats([r[k] for r in days.values()]) for k in REGRET}
        entry["regret"] = {
            "days": days,
            "mean": {k: mean for k, (mean, _) in stats.items()},
            "std": {k: std for k, (_, std) in stats.items()},
        }
    return None


def _pm(mean: float, std: float, digits: int) -> str:
    return f"{mean:.{digits}f} ± {std:.{digits}f}"


def render_suite(r: dict) -> str:
    """The BENCHMARKS.md section: mean ± std per controller, a per-day table, the days, the machine."""
    m, hours = r["machine"], r["hours"]
    working = {n: e for n, e in r["controllers"].items() if e["error"] is None}
    lines = [
        "## Control suite: held-out days (`lcmesh bench suite --json runs/bench/suite.json --markdown BENCHMARKS.md`)",
        "",
        (
            f"{r['system']}, {len(r['days'])} days of {hours:g} h (below), none used for training or validation "
            f"(lcmesh/bench/suite.py). Energies in kWh over {hours:g} h; travel = summed |change| of the applied "
            "setpoints over the day and over all cabinets, branches or towers; mean ± sample std over the days. "
            f"Regret against `{r['reference']}`: D_blade points below it, cooling kWh above it (positive = worse)."
        ),
        "",
        f"Guardrails: {r.get('guardrails', GUARDRAILS_OFF_TEXT)}; clamped steps = share of decisions the guardrails "
        "changed. Hottest blade: the day's hottest blade group, mean ± std over the days (band top 40 C).",
        "",
        SUITE_HEADER,
        "|---" * 14 + "|",
    ]
    for name, e in working.items():
        mu, sd = e["mean"], e["std"]
        mt, st = mu["travel"], sd["travel"]
        regret = e.get("regret")
        regret_cells = (
            f"{_pm(regret['mean']['d_blade_pts'], regret['std']['d_blade_pts'], 2)} | "
            f"{_pm(regret['mean']['cooling_kwh'], regret['std']['cooling_kwh'], 0)}"
            if regret else " | "
        )  # fmt: skip
        lines.append(
            f"| {name} | {_pm(mu['d_blade_pct'], sd['d_blade_pct'], 2)} | {_pm(mu['blade_max_c'], sd['blade_max_c'], 1)} | "
            f"{_pm(mu['tower_fan_kwh'], sd['tower_fan_kwh'], 0)} | "
            f"{_pm(mu['pump_kwh'], sd['pump_kwh'], 0)} | {_pm(mu['cooling_kwh'], sd['cooling_kwh'], 0)} | "
            f"{_pm(mu['pue_cooling'], sd['pue_cooling'], 4)} | {_pm(mt['supply_temp_setpoint_k'], st['supply_temp_setpoint_k'], 1)} | "
            f"{_pm(mt['dp_setpoint_pa'] / PSI_TO_PA, st['dp_setpoint_pa'] / PSI_TO_PA, 1)} | "
            f"{_pm(mt['valve_fraction'], st['valve_fraction'], 2)} | {_pm(mt['lw_setpoint_k'], st['lw_setpoint_k'], 1)} | "
            f"{mu.get('clamped_pct', 0.0):.1f} | {regret_cells} |"
        )
    for name, e in r["controllers"].items():
        if e["error"] is not None:
            lines.append(f"| {name} | not run: {e['error'].replace('|', '/')} |" + " |" * 12)
    if r.get("regret_note"):
        lines += ["", f"Regret: {r['regret_note']}."]
    if working:
        lines += ["", "### Per day: D_blade % / cooling kWh / hottest blade C / supply travel K", "",
                  "| day | " + " | ".join(working) + " |", "|---" * (len(working) + 1) + "|"]  # fmt: skip
        for d in r["days"]:
            cells = [_day_cell(e["days"][d["label"]]) for e in working.values()]
            lines.append(f"| {d['label']} | " + " | ".join(cells) + " |")
        checks = deploy_checks(r)
        if checks:
            lines += ["", "### Deployable control (issue 23): the targets, measured", "",
                      "| controller | target | measured | met |", "|---|---|---|---|"]  # fmt: skip
            lines += [f"| {c['controller']} | {c['target']} | {c['measured']} | {'yes' if c['met'] else '**no**'} |"
                      for c in checks]  # fmt: skip
    if "plot" in r:
        lines += ["", f"![D_blade against cooling energy, per controller]({r['plot']})"]
    if "plot_days" in r:
        lines += ["", f"![D_blade, cooling energy and hottest blade per controller and day]({r['plot_days']})"]
    lines += ["", "### Days", "", "| label | trace | scenario | mean IT load kW | mean wet bulb C |"]
    lines.append("|---" * 5 + "|")
    for d in r["days"]:
        lines.append(f"| {d['label']} | {d['trace']} | {d['scenario']} | {d['mean_load_kw']:,.0f} | "
                     f"{d['mean_wet_bulb_c']:.1f} |")  # fmt: skip
    walls = [f"{n} {e['mean']['wall_s']:.2f} s" for n, e in working.items()]
    machine = (
        f"Machine: {m['cpu']}, {m['logical_cpus']} logical CPUs; Python {m['python']}, numpy {m['numpy']}; "
        f"commit {m['commit']}; {m['date']}. Mean wall time of a day's loop: {', '.join(walls) or 'none'}."
    )
    lines += ["", machine]
    lines += cache_lines(r.get("cache", {}))
    return "\n".join(lines)


LCOPT_HRU_EFFECT = ("LC-Opt Section 7.3 (case 7, N=2, m=2, C=5, B=3): the HRU cuts the average cooling-tower "
                    "power by about 21 % (10.2 kW, over 17 h)")


def run_hru(controllers: list[str], days: tuple[Day, ...] = TEST_DAYS, hours: float = 24.0,
            progress: Progress | None = None, guardrails: bool = True, engine: EngineSettings | None = None) -> dict:
    """Each controller on ``days`` on lcopt-5 without and with the heat-recovery unit (lcopt-5-hru): both systems'
    units in one submission, so the engine keeps every CPU busy."""
    plans = {system: suite_plan(controllers, system, days, hours, guardrails) for system in ("lcopt-5", "lcopt-5-hru")}
    outcomes = run_units([u for p in plans.values() for u in p.units], engine, progress)
    runs, start = {}, 0
    for system, plan in plans.items():
        runs[system] = suite_result(plan, outcomes[start:start + len(plan.units)], reference="none")
        start += len(plan.units)
    rows = {}
    for name in controllers:
        off, on = runs["lcopt-5"]["controllers"][name], runs["lcopt-5-hru"]["controllers"][name]
        if off["error"] is not None or on["error"] is not None:
            rows[name] = {"error": off["error"] or on["error"]}
            continue
        rows[name] = {"error": None, **{f"{k}_{tag}": e["mean"][k] for tag, e in (("off", off), ("on", on))
                                        for k in ("tower_fan_kwh", "pump_kwh", "cooling_kwh", "d_blade_pct")},
                      "heat_recovered_kwh": float(np.mean([d["heat_recovered_kwh"] for d in on["days"].values()])),
                      "fan_cut_pct": _cut(off["mean"]["tower_fan_kwh"], on["mean"]["tower_fan_kwh"]),
                      "cooling_cut_pct": _cut(off["mean"]["cooling_kwh"], on["mean"]["cooling_kwh"])}  # fmt: skip
    return {"machine": machine_info(), "hours": hours, "days": [d.label for d in days], "rows": rows,
            "guardrails": GUARDRAILS_ON if guardrails else GUARDRAILS_OFF_TEXT, "published": LCOPT_HRU_EFFECT,
            "runs": runs, "cache": cache_summary(outcomes)}  # fmt: skip


def _cut(before: float, after: float) -> float:
    return 100.0 * (before - after) / before if before else 0.0


def render_hru(r: dict) -> str:
    """The BENCHMARKS.md section: per controller, tower fans, cooling energy and D_blade without and with the HRU."""
    lines = [
        "## Heat recovery on the suite (`lcmesh bench suite --hru --json runs/bench/hru.json --markdown BENCHMARKS.md`)",
        "",
        f"lcopt-5 without and with the heat-recovery unit (lcopt-5-hru: UA 150 kW/K to a 20 C district loop at 20 kg/s), "
        f"{len(r['days'])} test days of {r['hours']:g} h, means over the days; guardrails: {r['guardrails']}. "
        f"Published: {r['published']}.",
        "",
        "| controller | tower fans kWh (no HRU / HRU) | fan cut % | cooling kWh (no HRU / HRU) | cooling cut % | "
        "D_blade % (no HRU / HRU) | heat recovered kWh |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, row in r["rows"].items():
        if row["error"] is not None:
            lines.append(f"| {name} | not run: {row['error'].replace('|', '/')} | | | | | |")
            continue
        lines.append(
            f"| {name} | {row['tower_fan_kwh_off']:,.0f} / {row['tower_fan_kwh_on']:,.0f} | {row['fan_cut_pct']:.1f} | "
            f"{row['cooling_kwh_off']:,.0f} / {row['cooling_kwh_on']:,.0f} | {row['cooling_cut_pct']:.1f} | "
            f"{row['d_blade_pct_off']:.2f} / {row['d_blade_pct_on']:.2f} | {row['heat_recovered_kwh']:,.0f} |"
        )  # fmt: skip
    m = r["machine"]
    lines += ["", f"Machine: {m['cpu']}, {m['logical_cpus']} logical CPUs; commit {m['commit']}; {m['date']}."]
    lines += cache_lines(r.get("cache", {}))
    return "\n".join(lines)


def _day_cell(day: dict) -> str:
    return (f"{day['d_blade_pct']:.2f} / {day['cooling_kwh']:.0f} / {day['blade_max_c']:.1f} / "
            f"{day['travel']['supply_temp_setpoint_k']:,.0f}")  # fmt: skip


def deploy_checks(r: dict, learned: tuple[str, ...] = ("ppo", "readable", "tree", "llm")) -> list[dict]:
    """Issue 23's targets on this result, for each learned controller that ran: value, target, met or not.

    Against G36 and the strong rule (``rule``) per day; the look-ahead's energy against every controller at equal
    or better D_blade. Empty when G36 did not run.
    """
    ok = {n: e for n, e in r["controllers"].items() if e["error"] is None}
    if "g36" not in ok:
        return []
    g36 = ok["g36"]
    labels = [d["label"] for d in r["days"]]
    checks = []

    def add(name: str, target: str, measured: str, met: bool) -> None:
        checks.append({"controller": name, "target": target, "measured": measured, "met": bool(met)})

    for name in (n for n in learned if n in ok):
        e = ok[name]
        loss = max(g36["days"][d]["d_blade_pct"] - e["days"][d]["d_blade_pct"] for d in labels)
        worst = max(labels, key=lambda d: g36["days"][d]["d_blade_pct"] - e["days"][d]["d_blade_pct"])
        bound = 1.0 if name != "readable" else 0.2
        verdict = "no day lost" if loss <= 0 else f"largest loss {loss:.2f} points ({worst})"
        add(name, f"no day lost to G36 by more than {bound:g} point(s)",
            f"{verdict}; G36 minus {name} at most {loss:+.2f} points", loss <= bound)  # fmt: skip
        if name in ("ppo", "llm"):
            mean, g_mean = e["mean"]["d_blade_pct"], g36["mean"]["d_blade_pct"]
            rule = ok.get("rule", {}).get("mean", {}).get("d_blade_pct", float("nan"))
            add(name, "mean D_blade above G36's and the strong rule's", f"{mean:.2f} vs {g_mean:.2f} / {rule:.2f}",
                mean > g_mean and mean > rule)  # fmt: skip
            if "rule" in ok:
                ratio = e["mean"]["cooling_kwh"] / ok["rule"]["mean"]["cooling_kwh"]
                add(name, "cooling energy <= 0.8x the strong rule's", f"{ratio:.2f}x", ratio <= 0.8)
            ratios = [e["days"][d]["travel"]["supply_temp_setpoint_k"]
                      / max(g36["days"][d]["travel"]["supply_temp_setpoint_k"], 1e-9) for d in labels]  # fmt: skip
            add(name, "supply travel <= 3x G36's, every day", f"{min(ratios):.1f}x to {max(ratios):.1f}x",
                max(ratios) <= 3.0)  # fmt: skip
            hot = [e["days"][d]["blade_max_c"] - g36["days"][d]["blade_max_c"] for d in labels]
            add(name, "hottest blade <= G36's + 1 K, every day", f"{min(hot):+.1f} to {max(hot):+.1f} K",
                max(hot) <= 1.0)  # fmt: skip
    if "lookahead" in ok:
        la = ok["lookahead"]
        beaten = [f"{n} on {d}" for n, e in ok.items() if n != "lookahead" for d in labels
                  if e["days"][d]["d_blade_pct"] >= la["days"][d]["d_blade_pct"]
                  and e["days"][d]["cooling_kwh"] < la["days"][d]["cooling_kwh"]]  # fmt: skip
        add("lookahead", "no controller uses less cooling energy at equal or better D_blade, any day",
            f"{len(beaten)} beat it" + (f": {', '.join(beaten[:6])}" if beaten else ""), not beaten)  # fmt: skip
    return checks


def plot_pareto(r: dict, path: str | Path) -> Path:
    """D_blade against cooling energy: each controller's mean with std bars, and its days as faint points."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 5.5))
    working = [(n, e) for n, e in r["controllers"].items() if e["error"] is None]
    for i, (name, e) in enumerate(working):
        days, colour = list(e["days"].values()), f"C{i % 10}"
        ax.scatter([d["cooling_kwh"] for d in days], [d["d_blade_pct"] for d in days], s=14, color=colour, alpha=0.3)
        mu, sd = e["mean"], e["std"]
        # D_blade cannot pass 100 %: the std bar is cut there rather than drawn into the impossible
        yerr = [[sd["d_blade_pct"]], [min(sd["d_blade_pct"], 100.0 - mu["d_blade_pct"])]]
        ax.errorbar(mu["cooling_kwh"], mu["d_blade_pct"], xerr=sd["cooling_kwh"], yerr=yerr,
                    fmt="o", ms=9, capsize=4, color=colour, label=name)  # fmt: skip
    per = "day" if math.isclose(r["hours"], 24.0) else f"{r['hours']:g} h"
    ax.set_xlabel(f"cooling energy, tower fans + pumps (kWh per {per}); better: up and left")
    ax.set_ylabel("D_blade (% of blade-group steps in 20-40 C)")
    ax.set_title(f"{r['system']}: {len(r['days'])} held-out days; mean ± std (cut at 100 %) per controller, faint: days",
                 fontsize=11)  # fmt: skip
    ax.set_ylim(top=101.0)
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=9)
    return save_figure(fig, path, dpi=110)


def plot_days(r: dict, path: str | Path) -> Path:
    """D_blade, cooling energy and the hottest blade per controller and day: three panels of grouped bars."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    working = [(n, e) for n, e in r["controllers"].items() if e["error"] is None]
    labels = [d["label"] for d in r["days"]]
    panels = (("d_blade_pct", "D_blade % (higher is better)"), ("cooling_kwh", "cooling kWh (fans + pumps)"),
              ("blade_max_c", "hottest blade C (band top 40 C)"))  # fmt: skip
    fig, axes = plt.subplots(3, 1, figsize=(max(8.0, 0.9 * len(labels) + 3), 9), sharex=True)
    x = np.arange(len(labels))
    width = 0.8 / max(len(working), 1)
    for ax, (key, title) in zip(axes, panels):
        for i, (name, e) in enumerate(working):
            ax.bar(x + (i - (len(working) - 1) / 2) * width, [e["days"][d][key] for d in labels], width,
                   color=f"C{i % 10}", label=name)  # fmt: skip
        ax.set_ylabel(title, fontsize=9)
        ax.grid(axis="y", alpha=0.3)
    axes[0].set_ylim(bottom=max(0.0, min((e["days"][d]["d_blade_pct"] for _, e in working for d in labels),
                                         default=0.0) - 5.0), top=101.0)  # fmt: skip
    hottest = [e["days"][d]["blade_max_c"] for _, e in working for d in labels]
    axes[2].set_ylim(bottom=min(hottest, default=20.0) - 3.0, top=max(max(hottest, default=40.0), 40.0) + 1.0)
    axes[2].axhline(40.0, color="k", lw=0.8, ls="--")
    axes[-1].set_xticks(x, labels, rotation=30, ha="right", fontsize=8)
    if working:
        axes[0].legend(loc="lower center", bbox_to_anchor=(0.5, 1.0), fontsize=8, ncols=min(len(working), 8),
                       frameon=False)  # fmt: skip
    fig.suptitle(f"{r['system']}: per controller and held-out day", fontsize=11)
    return save_figure(fig, path, dpi=100)

"""``lcmesh bench ablation``: the ablation cases retrained on the real-load plant, every seed on the held-out suite.

Each PPO case of LC-Opt's Table 3 (2-7) was trained on lcopt-5 under the ``frontier`` and ``design-day``
scenarios with one schedule (160k environment steps) at seeds 0-2 and selected on the validation days
(``lcmesh/artifacts/ppo/frontier/case{C}-seed{S}``; the commands are in docs/controllers.md). This bench
runs every seed on every test day of ``lcmesh.bench.suite`` and reports, per case, the mean and sample
std *over seeds* of each seed's suite mean, the worst seed, and each seed's worst day against G36 on the
same day. The baselines (G36, the strong rule; the look-ahead ceiling when asked) run once per day.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np

from lcmesh.bench.engine import EngineSettings, cache_lines, cache_summary, run_units
from lcmesh.bench.machine import machine_info
from lcmesh.bench.suite import GUARDRAILS_ON, TEST_DAYS, Day, day_units

ABLATION_DIR = Path(__file__).resolve().parent.parent / "artifacts" / "ppo" / "frontier"
FIGURES = ("d_blade_pct", "cooling_kwh", "tower_fan_kwh", "pump_kwh")
CASE_TITLES = {
    2: "CT RL + BG baseline",
    3: "CT baseline + BG RL, no valve control",
    4: "CT baseline + BG RL, with valve control",
    5: "Multi-agent RL, decentralized action",
    6: "Multi-agent RL, centralized action",
    7: "Multi-agent RL, centralized action + multi-head",
}
_NAME = re.compile(r"^case(\d+)-seed(\d+)\.json$")
Progress = Callable[[str, int, int], None]


def ablation_policies(folder: Path = ABLATION_DIR) -> dict[int, list[tuple[int, Path]]]:
    """Case -> [(seed, policy path without extension)], from ``case{C}-seed{S}.json`` files in ``folder``."""
    found: dict[int, list[tuple[int, Path]]] = {}
    for path in sorted(Path(folder).glob("case*-seed*.json")):
        m = _NAME.match(path.name)
        if m:
            found.setdefault(int(m.group(1)), []).append((int(m.group(2)), path.with_suffix("")))
    if not found:
        raise FileNotFoundError(f"no case{{C}}-seed{{S}}.json policies in {folder}")
    return {case: sorted(runs) for case, runs in sorted(found.items())}


def _validation_score(policy: Path) -> float | None:
    """The checkpoint-selection score of a policy (D_blade - 0.02/kW x fans and pumps), from its manifest."""
    meta = json.loads(policy.with_suffix(".json").read_text())
    val = (meta.get("manifest", {}).get("metrics") or {}).get("validation") or {}
    if "d_blade_pct" not in val:
        return None
    return val["d_blade_pct"] - 0.02 * (val.get("ct_power_kw_avg", 0.0) + val.get("pump_power_kw_avg", 0.0))


def run_ablation(
    folder: Path = ABLATION_DIR,
    system_name: str = "lcopt-5",
    days: tuple[Day, ...] = TEST_DAYS,
    hours: float = 24.0,
    baselines: tuple[str, ...] = ("g36", "rule"),
    progress: Progress | None = None,
    engine: EngineSettings | None = None,
) -> dict:
    """Every seed of every case and each baseline on every day, behind the mesh's guardrails; per-case mean and std
    over the seeds. The (policy or baseline, day) units run on ``engine`` (Ray by default, cached)."""
    if not days:
        raise ValueError("`days` must hold at least one day, got none")
    policies = ablation_policies(folder)
    runs = [(name, None, name) for name in baselines]
    runs += [(f"case {case} seed {seed}", str(path.resolve()), "ppo") for case, seeds in policies.items()
             for seed, path in seeds]  # fmt: skip
    units = [u for tag, policy, name in runs
             for u in day_units(name, system_name, days, hours, options={"policy": policy} if policy else None, tag=tag)]
    outcomes = run_units(units, engine, progress)
    each = iter(outcomes)
    rows: dict[str, dict[str, dict]] = {}
    for tag, _, _ in runs:
        rows[tag] = {}
        for day in days:
            o = next(each)
            if o.error is not None:
                raise RuntimeError(f"{tag} on {day.label} failed: {o.error}")
            rows[tag][day.label] = o.result
    base = {name: rows[name] for name in baselines}
    cases = {}
    for case, seeds_paths in policies.items():
        seeds = [_seed_summary(seed, path, rows[f"case {case} seed {seed}"], base.get("g36"))
                 for seed, path in seeds_paths]  # fmt: skip
        cases[case] = {"title": CASE_TITLES.get(case, f"case {case}"), "seeds": seeds, **_over_seeds(seeds)}
    return {
        "machine": machine_info(),
        "system": system_name,
        "hours": hours,
        "days": [d.label for d in days],
        "folder": str(folder),
        "guardrails": GUARDRAILS_ON,
        "baselines": {name: {"days": r, "mean": _day_means(r)} for name, r in base.items()},
        "cases": cases,
        "cache": cache_summary(outcomes),
    }


def _day_means(rows: dict[str, dict]) -> dict[str, float]:
    means = {k: float(np.mean([r[k] for r in rows.values()])) for k in FIGURES}
    means["supply_travel_k"] = float(np.mean([r["travel"]["supply_temp_setpoint_k"] for r in rows.values()]))
    means["blade_max_c_worst"] = float(np.max([r["blade_max_c"] for r in rows.values()]))
    return means


def _seed_summary(seed: int, path: Path, rows: dict[str, dict], g36: dict[str, dict] | None) -> dict:
    summary = {"seed": seed, "policy": path.name, "validation_score": _validation_score(path), "days": rows,
               "mean": _day_means(rows)}  # fmt: skip
    if g36 is not None:
        gaps = {label: r["d_blade_pct"] - g36[label]["d_blade_pct"] for label, r in rows.items()}
        worst = min(gaps, key=gaps.get)
        summary["worst_day_vs_g36"] = {"day": worst, "points": gaps[worst]}
    return summary


def _over_seeds(seeds: list[dict]) -> dict:
    """Mean and sample std over seeds of each seed's suite mean; the worst seed's D_blade."""
    mean, std = {}, {}
    for key in (*FIGURES, "supply_travel_k", "blade_max_c_worst"):
        a = np.array([s["mean"][key] for s in seeds], dtype=float)
        mean[key], std[key] = float(a.mean()), float(a.std(ddof=1)) if a.size > 1 else 0.0
    worst = min(seeds, key=lambda s: s["mean"]["d_blade_pct"])
    return {"mean": mean, "std": std, "worst_seed": {"seed": worst["seed"], "d_blade_pct": worst["mean"]["d_blade_pct"]}}


def render_ablation(r: dict) -> str:
    """The BENCHMARKS.md section: one row per case (mean +- std over seeds), the baselines' rows, per-seed detail."""
    m = r["machine"]
    lines = [
        "## Ablation on the real-load plant, seeds on the held-out suite "
        "(`lcmesh bench ablation --json runs/bench/ablation.json --markdown BENCHMARKS.md`)",
        "",
        f"{r['system']}, {len(r['days'])} held-out test days of {r['hours']:g} h (lcmesh/bench/suite.py), the policies in "
        f"`{Path(r['folder']).name}/` (one schedule: 160k steps; seeds selected on the validation days only). "
        "Per seed: the mean over the days; per case: mean +- sample std over the seeds. Energies in kWh per run of each day. "
        f"Guardrails: {r.get('guardrails', 'not recorded')}. Hottest blade: the hottest blade group of any day; "
        "supply travel: summed |change| of the applied supply setpoints per day, over the five CDUs.",
        "",
        "| case | control | seeds | D_blade % | cooling kWh | tower fans kWh | pumps kWh | hottest blade C | "
        "supply travel K/day | worst seed D_blade % | worst day vs G36, pts (per seed) |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, b in r["baselines"].items():
        bm = b["mean"]
        lines.append(f"| {name} | baseline | - | {bm['d_blade_pct']:.2f} | {bm['cooling_kwh']:.0f} | "
                     f"{bm['tower_fan_kwh']:.0f} | {bm['pump_kwh']:.0f} | {bm.get('blade_max_c_worst', float('nan')):.1f} | "
                     f"{bm.get('supply_travel_k', float('nan')):,.0f} | | |")  # fmt: skip
    for case, c in r["cases"].items():
        mn, sd = c["mean"], c["std"]
        worst_days = ", ".join(f"{s['worst_day_vs_g36']['points']:+.1f}" for s in c["seeds"] if "worst_day_vs_g36" in s)
        lines.append(
            f"| {case} | {c['title']} | {len(c['seeds'])} | {mn['d_blade_pct']:.2f} +- {sd['d_blade_pct']:.2f} | "
            f"{mn['cooling_kwh']:.0f} +- {sd['cooling_kwh']:.0f} | {mn['tower_fan_kwh']:.0f} +- {sd['tower_fan_kwh']:.0f} | "
            f"{mn['pump_kwh']:.0f} +- {sd['pump_kwh']:.0f} | {mn.get('blade_max_c_worst', float('nan')):.1f} | "
            f"{mn.get('supply_travel_k', float('nan')):,.0f} | {c['worst_seed']['d_blade_pct']:.2f} (seed "
            f"{c['worst_seed']['seed']}) | {worst_days} |"
        )
    lines += ["", "Per seed: validation score (selection; D_blade - 0.02/kW x fans and pumps) / test D_blade % / "
              "cooling kWh per day", "", "| case | " + " | ".join(f"seed {s['seed']}" for s in _any_seeds(r)) + " |",
              "|---|" + "---|" * len(_any_seeds(r))]  # fmt: skip
    for case, c in r["cases"].items():
        cells = []
        for s in c["seeds"]:
            val = "-" if s["validation_score"] is None else f"{s['validation_score']:.2f}"
            cells.append(f"{val} / {s['mean']['d_blade_pct']:.2f} / {s['mean']['cooling_kwh']:.0f}")
        lines.append(f"| {case} | " + " | ".join(cells) + " |")
    lines += ["", f"Machine: {m.get('cpu', '?')}, {m.get('logical_cpus', '?')} logical CPUs; commit {m.get('commit', '?')}; "
              f"{m.get('date', '?')}."]  # fmt: skip
    lines += cache_lines(r.get("cache", {}))
    return "\n".join(lines) + "\n"


def _any_seeds(r: dict) -> list[dict]:
    return max((c["seeds"] for c in r["cases"].values()), key=len)

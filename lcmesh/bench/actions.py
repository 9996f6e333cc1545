"""``lcmesh bench actions``: does each plant action reach its setpoint, and does it move the KPIs? (issue 12)

Two measurements per scenario, on the Frontier day (lcopt-5 unless told):

- *Tracking*: the static rule and G36 run closed loop; the share of (cabinet, step) whose CDU supply is
  within 0.5 K of its applied setpoint and whose cabinet dp is within 0.5 psi of its setpoint, the share
  of (tower, step) whose leaving water is within 0.5 K of its setpoint, and the median miss (measured -
  setpoint) so a reader sees which way the misses go. A setpoint that is never reached means the plant
  or the scenario is wrong, not the controller.
- *Sweep*: the static rule's values held, one action varied at a time:

  =============================  ===============================  ======================
  action                         values                           tracked setpoint
  =============================  ===============================  ======================
  CDU supply setpoint            20, 24, 28, 32, 36 C             supply
  cabinet dp setpoint            25, 28, 31, 34, 38 psi           dp
  tower approach to wet bulb     2.5, 4, 5.56, 8, 12 K            tower leaving water
  branch valve split             equal, proportional, inverse     (none: applied as sent)
  =============================  ===============================  ======================

  "proportional" splits each cabinet's flow by its branches' IT power; "inverse" by 1 / power, a
  deliberately wrong split. An action *matters* when its sweep moves D_blade by >= 0.5 points, the
  cooling energy (tower fans + pumps) by >= 2 % (max over min), or the hottest blade group by >= 1 K
  (thermal margin a compliance count alone does not show).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from lcmesh.bench.machine import machine_info
from lcmesh.twin.controllers import Controller, Observation, make_controller
from lcmesh.twin.controllers.static import APPROACH_10F_K
from lcmesh.twin.kpi import cooling_energies_kwh
from lcmesh.twin.plant import Plant, PlantAction
from lcmesh.twin.run import run_twin, save_figure
from lcmesh.twin.system import PSI_TO_PA, SystemDescription, load_system
from lcmesh.twin.traces import FRONTIER_DAY, SCENARIOS, Trace, load_trace

_K = 273.15
SUPPLY_TOLERANCE_K = 0.5
DP_TOLERANCE_PSI = 0.5
LW_TOLERANCE_K = 0.5
MATTERS_D_BLADE_PTS = 0.5
MATTERS_ENERGY_PCT = 2.0
MATTERS_BLADE_MAX_K = 1.0
PAPER_SYSTEM = "lcopt-5-paper"  # where the lcopt scenario belongs (docs/twin.md)

HELD = {"supply_c": 28.0, "dp_psi": 27.5, "approach_k": APPROACH_10F_K, "valves": "equal"}
SWEEPS: dict[str, tuple] = {
    "supply_c": (20.0, 24.0, 28.0, 32.0, 36.0),
    "dp_psi": (25.0, 28.0, 31.0, 34.0, 38.0),
    "approach_k": (2.5, 4.0, APPROACH_10F_K, 8.0, 12.0),
    "valves": ("equal", "proportional", "inverse"),
}
ACTION_LABELS = {
    "supply_c": "CDU supply setpoint (C)",
    "dp_psi": "cabinet dp setpoint (psi)",
    "approach_k": "tower approach to wet bulb (K)",
    "valves": "branch valve split",
}
TRACKED_BY = {"supply_c": "supply_tracked", "dp_psi": "dp_tracked", "approach_k": "tower_tracked", "valves": None}
CONTROLLERS = ("static", "g36")

Progress = Callable[[str, int, int], None]


class HeldSetpoints:
    """Fixed CDU supply and dp setpoints, tower leaving water = wet bulb + approach, and a valve split rule."""

    version = "1"

    def __init__(self, system: SystemDescription, supply_c: float, dp_psi: float, approach_k: float, valves: str):
        if valves not in SWEEPS["valves"]:
            raise ValueError(f"`valves` must be one of {SWEEPS['valves']}, got {valves!r}")
        C, B, N = system.cabinets.count, system.cabinets.branches, system.towers.count
        self.name = f"held(supply {supply_c:g} C, dp {dp_psi:g} psi, approach {approach_k:.2f} K, {valves} valves)"
        self.approach_k, self.valves = approach_k, valves
        self._shape = (C, B, system.cabinets.blade_groups_per_branch)
        self._action = PlantAction(
            np.full(C, supply_c + _K), np.full(C, dp_psi * PSI_TO_PA), np.full((C, B), 1.0 / B), np.zeros(N)
        )

    def reset(self) -> None:
        pass

    def act(self, obs: Observation) -> PlantAction:
        self._action.lw_setpoint_k[:] = obs.wet_bulb_k + self.approach_k
        if self.valves != "equal":
            # a branch's power is the sum of its blade groups; 1 W keeps an idle branch finite under "inverse"
            branch_w = np.maximum(obs.blade_power_w.reshape(self._shape).sum(axis=2), 1.0)
            weight = branch_w if self.valves == "proportional" else 1.0 / branch_w
            self._action.valve_fractions[:] = weight / weight.sum(axis=1, keepdims=True)
        return self._action


class _Misses:
    """Per-step misses (measured - applied setpoint) of the supply, dp and tower leaving water."""

    def __init__(self, plant: Plant, n_steps: int):
        C, N = plant.system.cabinets.count, plant.system.towers.count
        self._out = plant.out
        self.supply_k, self.dp_psi, self.lw_k = np.zeros((n_steps, C)), np.zeros((n_steps, C)), np.zeros((n_steps, N))

    def __call__(self, k: int) -> None:
        out = self._out
        self.supply_k[k] = out["supply_temp_k"] - out["applied_supply_setpoint_k"]
        self.dp_psi[k] = (out["cabinet_dp_pa"] - out["applied_dp_setpoint_pa"]) / PSI_TO_PA
        self.lw_k[k] = out["ct_leaving_temp_k"] - out["applied_lw_setpoint_k"]

    def summary(self) -> dict:
        return {
            "supply_tracked": float(np.mean(np.abs(self.supply_k) <= SUPPLY_TOLERANCE_K)),
            "dp_tracked": float(np.mean(np.abs(self.dp_psi) <= DP_TOLERANCE_PSI)),
            "tower_tracked": float(np.mean(np.abs(self.lw_k) <= LW_TOLERANCE_K)),
            "supply_median_miss_k": float(np.median(self.supply_k)),
            "dp_median_miss_psi": float(np.median(self.dp_psi)),
            "tower_median_miss_k": float(np.median(self.lw_k)),
        }


def _run(plant: Plant, trace: Trace, controller: Controller) -> dict:
    """One closed-loop run: setpoint tracking, D_blade, blade max, cooling PUE and energies."""
    misses = _Misses(plant, trace.n_steps)
    kpi = run_twin(plant, trace, controller, on_step=misses).kpi
    hours = trace.n_steps * trace.step_s / 3600.0
    fan_kwh, pump_kwh = cooling_energies_kwh(kpi, hours)
    return {
        **misses.summary(),
        "d_blade_pct": kpi["d_blade_pct"],
        "blade_max_c": kpi["blade_temp_max_c"],
        "pue_cooling": kpi["pue_cooling"],
        "fan_kwh": fan_kwh,
        "pump_kwh": pump_kwh,
        "cooling_kwh": fan_kwh + pump_kwh,
    }


def tracking(system_name: str = "lcopt-5", scenario: str = "frontier", controller: str | Controller = "static",
             hours: float = 24.0) -> dict:  # fmt: skip
    """Setpoint tracking and KPIs of `controller` (a registered name or an instance) on the Frontier day."""
    system = load_system(system_name)
    trace = load_trace(FRONTIER_DAY, system, scenario=scenario, hours=hours)
    ctrl = make_controller(controller, system) if isinstance(controller, str) else controller
    with Plant(system) as plant:
        return {"controller": ctrl.name, **_run(plant, trace, ctrl)}


def sweep(system_name: str = "lcopt-5", scenario: str = "frontier", hours: float = 24.0,
          on_point: Callable[[str], None] | None = None) -> dict:  # fmt: skip
    """Each action varied over its range with the others held at the static rule's values, and its verdict."""
    system = load_system(system_name)
    trace = load_trace(FRONTIER_DAY, system, scenario=scenario, hours=hours)
    done: dict[tuple, dict] = {}  # the held point recurs in three sweeps: run it once
    actions = {}
    with Plant(system) as plant:
        for action, values in SWEEPS.items():
            points = []
            for value in values:
                setting = {**HELD, action: value}
                key = tuple(setting.values())
                if key not in done:
                    done[key] = _run(plant, trace, HeldSetpoints(system, **setting))
                tracked = TRACKED_BY[action]
                points.append({"value": value, **done[key], "tracked_share": done[key][tracked] if tracked else None})
                if on_point is not None:
                    on_point(f"{scenario}: {ACTION_LABELS[action]} {_value(value)}")
            actions[action] = {"label": ACTION_LABELS[action], "points": points, **_verdict(points)}
    held = {**HELD, "approach_k": round(HELD["approach_k"], 2)}
    return {"system": system_name, "scenario": scenario, "hours": hours, "held": held, "actions": actions}


def _verdict(points: list[dict]) -> dict:
    d_blade = [p["d_blade_pct"] for p in points]
    energy = [p["cooling_kwh"] for p in points]
    blade_max = [p["blade_max_c"] for p in points]
    d_blade_spread = max(d_blade) - min(d_blade)
    energy_spread = 100.0 * (max(energy) / min(energy) - 1.0) if min(energy) > 0 else float("inf")
    blade_max_spread = max(blade_max) - min(blade_max)
    matters = (
        d_blade_spread >= MATTERS_D_BLADE_PTS
        or energy_spread >= MATTERS_ENERGY_PCT
        or blade_max_spread >= MATTERS_BLADE_MAX_K
    )
    return {"d_blade_spread_pts": d_blade_spread, "energy_spread_pct": energy_spread,
            "blade_max_spread_k": blade_max_spread, "matters": matters}  # fmt: skip


def run_bench_actions(systems: tuple[str, ...] = ("lcopt-5",), scenarios: tuple[str, ...] = tuple(SCENARIOS),
                      hours: float = 24.0, progress: Progress | None = None, plot_dir: Path | None = None) -> dict:  # fmt: skip
    """Tracking under the static rule and G36, and the sweeps, for each system and scenario.

    The ``lcopt`` scenario also runs on lcopt-5-paper, the plant it was set for (its loads are scaled to 225 kW
    per cabinet, so on the real-scale plants the towers are oversized and the tower action hardly acts).
    """
    pairs = [(system_name, scenario) for system_name in systems for scenario in scenarios]
    if "lcopt" in scenarios and PAPER_SYSTEM not in systems:
        pairs.append((PAPER_SYSTEM, "lcopt"))
    total = len(pairs) * (len(CONTROLLERS) + sum(map(len, SWEEPS.values())))
    runs = 0

    def one_more(stage: str) -> None:
        nonlocal runs
        runs += 1
        if progress is not None:
            progress(stage, runs, total)

    result: dict = {"machine": machine_info(), "trace": FRONTIER_DAY, "hours": hours, "systems": {}}
    for system_name, scenario in pairs:
        rows = {}
        for controller in CONTROLLERS:
            rows[controller] = tracking(system_name, scenario, controller, hours)
            one_more(f"{system_name} {scenario}: tracking under {controller}")
        per_scenario = result["systems"].setdefault(system_name, {})
        per_scenario[scenario] = {"tracking": rows, "sweep": sweep(system_name, scenario, hours, one_more)}
    if plot_dir is not None:
        result["plot"] = str(plot_actions(result, plot_dir))
    return result


def plot_actions(result: dict, plot_dir: Path) -> Path:
    """D_blade (top) and cooling energy (bottom) against each action's value, lines per scenario."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(SWEEPS), figsize=(4 * len(SWEEPS), 6.5), sharex="col")
    for system_name, per_scenario in result["systems"].items():
        for scenario, r in per_scenario.items():
            label = scenario if len(result["systems"]) == 1 else f"{system_name} {scenario}"
            for col, (action, a) in enumerate(r["sweep"]["actions"].items()):
                values = [p["value"] for p in a["points"]]
                x = np.arange(len(values)) if action == "valves" else np.array(values)
                axes[0, col].plot(x, [p["d_blade_pct"] for p in a["points"]], marker="o", label=label)
                axes[1, col].plot(x, [p["cooling_kwh"] for p in a["points"]], marker="o", label=label)
                if action == "valves":
                    axes[1, col].set_xticks(x, values)
    for col, action in enumerate(SWEEPS):
        axes[0, col].set_title(ACTION_LABELS[action], fontsize=10)
        axes[1, col].set_xlabel(ACTION_LABELS[action], fontsize=9)
    axes[0, 0].set_ylabel("D_blade (%)")
    axes[1, 0].set_ylabel(f"tower fans + pumps (kWh over {result['hours']:g} h)")
    axes[0, 0].legend(fontsize=8)
    where = f"{', '.join(result['systems'])}, {result['trace']}, {result['hours']:g} h"
    fig.suptitle(f"Each action varied alone, the others at the static rule's values ({where})")
    return save_figure(fig, Path(plot_dir) / "actions.png", dpi=90)


TRACKING_HEADER = (
    "| scenario | controller | supply tracked % | supply miss K | dp tracked % | tower tracked % | tower miss K | "
    "D_blade % | cooling PUE | tower fans kWh | pumps kWh |"
)
SWEEP_HEADER = (
    "| action | value | D_blade % | blade max C | cooling PUE | tower fans kWh | pumps kWh | its setpoint tracked % |"
)


def _pct(share: float | None) -> str:
    return "" if share is None else f"{100.0 * share:.1f}"


def _value(v: float | str) -> str:
    return v if isinstance(v, str) else f"{round(v, 2):g}"


def render_actions(r: dict, level: int = 2) -> str:
    """The markdown section: a tracking table, a sweep table per scenario, a verdict per action, the plot."""
    h = "#" * level
    title = f"{h} Plant and scenarios: setpoint tracking and each action's effect (issue 12)"
    if level == 2:
        title += " (`lcmesh bench actions --json runs/bench/actions.json --markdown BENCHMARKS.md`)"
    m = r["machine"]
    about = (
        f"Machine: {m['cpu']}, {m['logical_cpus']} logical CPUs; commit {m['commit']}; {m['date']}. "
        f"Trace: {r['trace']}, {r['hours']:g} h. Tracked: |measured - applied setpoint| <= {SUPPLY_TOLERANCE_K} K "
        f"(supply, tower leaving water) or {DP_TOLERANCE_PSI} psi (dp), share of (cabinet, step) or (tower, step); "
        "miss = median (measured - setpoint)."
    )
    lines = [title, "", about, ""]
    for system_name, per_scenario in r["systems"].items():
        lines += [f"{h}# Setpoint tracking ({system_name})", "", TRACKING_HEADER, "|---" * 11 + "|"]
        for scenario, s in per_scenario.items():
            for controller, t in s["tracking"].items():
                lines.append(
                    f"| {scenario} | {controller} | {_pct(t['supply_tracked'])} | {t['supply_median_miss_k']:+.2f} | "
                    f"{_pct(t['dp_tracked'])} | {_pct(t['tower_tracked'])} | {t['tower_median_miss_k']:+.2f} | "
                    f"{t['d_blade_pct']:.2f} | {t['pue_cooling']:.4f} | {t['fan_kwh']:.0f} | {t['pump_kwh']:.0f} |"
                )
        for scenario, s in per_scenario.items():
            sw = s["sweep"]
            held = sw["held"]
            held_text = (
                f"Held: supply {held['supply_c']:g} C, dp {held['dp_psi']:g} psi, approach {held['approach_k']:g} K, "
                f"{held['valves']} valves; one action varied at a time."
            )
            lines += ["", f"{h}# Each action's effect: {scenario} ({system_name})", "", held_text, "",
                      SWEEP_HEADER, "|---" * 8 + "|"]  # fmt: skip
            for a in sw["actions"].values():
                for p in a["points"]:
                    lines.append(
                        f"| {a['label']} | {_value(p['value'])} | {p['d_blade_pct']:.2f} | {p['blade_max_c']:.1f} | "
                        f"{p['pue_cooling']:.4f} | {p['fan_kwh']:.0f} | {p['pump_kwh']:.0f} | "
                        f"{_pct(p['tracked_share']) or 'n/a'} |"
                    )
            lines.append("")
            for a in sw["actions"].values():
                verdict = "matters" if a["matters"] else "does NOT matter"
                lines.append(f"- {a['label']}: {verdict} (D_blade moves {a['d_blade_spread_pts']:.2f} points, "
                             f"cooling energy {a['energy_spread_pct']:.1f} %, hottest blade "
                             f"{a['blade_max_spread_k']:.1f} K)")  # fmt: skip
    if "plot" in r:
        lines += ["", f"![actions]({r['plot']})"]
    return "\n".join(lines)

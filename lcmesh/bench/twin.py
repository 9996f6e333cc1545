"""``lcmesh bench twin``: env steps/s on lcopt-5, a 24 h day of frontier-full, raw fmi2 vs fmpy's list API.

Everything is measured in one process pinned to one core; each figure is the median of repeats.
"""

from __future__ import annotations

import os
import statistics
import time

import numpy as np

from lcmesh.bench.machine import machine_info
from lcmesh.twin.controllers.static import StaticController
from lcmesh.twin.plant import Plant
from lcmesh.twin.controllers.guarded import MESH_GUARDRAILS
from lcmesh.twin.run import run_twin
from lcmesh.twin.system import load_system
from lcmesh.twin.traces import FRONTIER_DAY, load_trace


def pin_to_one_core() -> int | None:
    """Run on a single CPU so 'steps/s on one core' means what it says."""
    try:
        cpu = min(os.sched_getaffinity(0))
        os.sched_setaffinity(0, {cpu})
        return cpu
    except (AttributeError, OSError):
        return None


def plant_loop_steps_per_second(system_name: str = "lcopt-5", n_steps: int = 5760, repeats: int = 3) -> dict:
    """The twin's closed loop (trace inputs + static rule + one FMU step + KPIs, no env wrapper), behind the mesh's
    guardrails as every run is, and bare; the two alternate within each repeat so a busy moment hits both alike."""
    system = load_system(system_name)
    trace = load_trace(FRONTIER_DAY, system)
    rates: dict[str, list[float]] = {"guarded": [], "bare": []}
    with Plant(system) as plant:
        for _ in range(repeats):
            for kind, limits in (("guarded", MESH_GUARDRAILS), ("bare", None)):
                result = run_twin(plant, trace, StaticController(system), n_steps=n_steps, spinup_hours=0.25,
                                  guardrails=limits)  # fmt: skip
                rates[kind].append(result.kpi["steps"] / result.wall_seconds)
    guarded, bare = statistics.median(rates["guarded"]), statistics.median(rates["bare"])
    return {"steps_per_s": guarded, "repeats": rates["guarded"], "bare_steps_per_s": bare, "bare_repeats": rates["bare"],
            "guard_slowdown": bare / guarded}  # fmt: skip


def list_api_comparison(system_name: str = "lcopt-5", n_steps: int = 3000, repeats: int = 3) -> dict:
    """The same step loop through raw fmi2 calls with numpy buffers vs fmpy's list-based setReal/getReal."""
    system = load_system(system_name)
    trace = load_trace(FRONTIER_DAY, system)
    raw, listed = [], []
    with Plant(system) as plant:
        runner = plant.runner
        in_vrs = [int(v) for v in plant._inputs.vrs]
        out_vrs = [int(v) for v in plant._outputs.vrs]
        action = plant.default_action()
        power = np.zeros(system.n_blade_groups)
        start = plant.save_state()
        for _ in range(repeats):
            plant.restore_state(start)
            t0 = time.perf_counter()
            for k in range(n_steps):
                plant.step(trace.blade_power_w(k, out=power), trace.wet_bulb_k[k], action)
            raw.append(n_steps / (time.perf_counter() - t0))

            plant.restore_state(start)
            values = plant._inputs.values  # same input values each step as the raw loop writes
            t0 = time.perf_counter()
            for k in range(n_steps):
                trace.blade_power_w(k, out=power)
                plant.inp["blade_power_w"][:] = power
                plant.inp["wet_bulb_k"][...] = trace.wet_bulb_k[k]
                runner.set_real_list(in_vrs, values.tolist())
                runner.do_step_list(plant.step_s)
                runner.get_real_list(out_vrs)
            listed.append(n_steps / (time.perf_counter() - t0))
        plant.free_state(start)
    raw_rate, list_rate = statistics.median(raw), statistics.median(listed)
    return {
        "system": system_name,
        "raw_fmi2_steps_per_s": raw_rate,
        "fmpy_list_steps_per_s": list_rate,
        "speedup": raw_rate / list_rate,
        "reals_set_per_step": len(in_vrs),
        "reals_read_per_step": len(out_vrs),
    }


def frontier_day(repeats: int = 3) -> dict:
    """Wall time of a 24 h day (5,760 steps) of frontier-full with the static rule."""
    system = load_system("frontier-full")
    trace = load_trace(FRONTIER_DAY, system)
    walls, kpi = [], None
    with Plant(system) as plant:
        for _ in range(repeats):
            result = run_twin(plant, trace, StaticController(system), spinup_hours=0.25, record_every=20)
            walls.append(result.wall_seconds)
            kpi = result.kpi
    wall = statistics.median(walls)
    return {
        "system": "frontier-full",
        "blade_groups": system.n_blade_groups,
        "steps": trace.n_steps,
        "wall_s": wall,
        "wall_s_repeats": walls,
        "realtime_factor": trace.n_steps * trace.step_s / wall,
        "d_blade_pct_static": kpi["d_blade_pct"],
        "energy_balance_error_pct": kpi["energy_balance_error_pct"],
    }


def run_bench_twin(quick: bool = False) -> dict:
    """Every twin figure, in one run on one core."""
    from lcmesh.twin.envs.bench import env_steps_per_second

    cpu = pin_to_one_core()
    n_env = 5000 if quick else 20000
    envs = {
        kind: env_steps_per_second(system="lcopt-5", n_steps=n_env, env=kind)
        for kind in ("cabinet", "tower", "parallel")
    }
    return {
        "machine": {**machine_info(), "pinned_cpu": cpu},
        "env_lcopt5": envs,
        "plant_loop_lcopt5": plant_loop_steps_per_second(n_steps=2000 if quick else 5760),
        "fmi2_raw_vs_list": list_api_comparison(n_steps=1000 if quick else 3000),
        "fmi2_raw_vs_list_frontier": list_api_comparison("frontier-full", n_steps=50 if quick else 200),
        "frontier_full_day": frontier_day(repeats=1 if quick else 3),
        "targets": {"env_lcopt5_steps_per_s": 5000, "frontier_full_day_wall_s": 20.0, "guard_slowdown": 2.0},
    }

"""Experience data from a teacher controller, with VIPER importance weights (LC-Opt Appendix A).

``collect_experience`` rolls the deterministic teacher on the twin over one or more traces and
records, per step: the raw plant quantities a prompt or an operator would cite (``obs``; its
branch_power_w is the coming step's load, the one the teacher decided on), the
feature rows the learned policies read (``cabinet_rows``, ``tower_rows``), the teacher's action,
and the VIPER weight of every cabinet and tower decision,
``l(s) = log pi*(a*|s) - min_a log pi*(a|s)``, when the teacher can compute it (``PpoController``
can; a baseline teacher gets uniform weights). ``resample`` draws a weighted dataset D' from it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from lcmesh.twin.controllers.base import Controller, Observation
from lcmesh.twin.controllers.guarded import MESH_GUARDRAILS, guard, spinup_action
from lcmesh.twin.plant import Plant
from lcmesh.twin.system import SystemDescription
from lcmesh.twin.traces import load_trace, scenario_with_offset

OBS_KEYS = ("branch_temp_k", "branch_max_temp_k", "branch_power_w", "supply_temp_k", "secondary_flow_kg_s",
            "cabinet_dp_pa", "return_temp_k", "ct_leaving_temp_k", "cell_fan_power_w", "htw_supply_temp_k",
            "htw_return_temp_k", "applied_lw_setpoint_k")  # fmt: skip
ACTION_KEYS = ("supply_temp_setpoint_k", "dp_setpoint_pa", "valve_fractions", "lw_setpoint_k")


@dataclass
class Experience:
    """Per-step arrays (leading axis T): ``obs[k]`` plant outputs, ``actions[k]`` teacher setpoints."""

    system_name: str
    teacher: str
    traces: list[str]
    obs: dict[str, np.ndarray]
    actions: dict[str, np.ndarray]
    wet_bulb_k: np.ndarray  # (T,)
    cabinet_rows: np.ndarray  # (T, C, Fc)
    tower_rows: np.ndarray  # (T, N, Ft)
    cabinet_weights: np.ndarray  # (T, C) VIPER l(s), >= 0
    tower_weights: np.ndarray  # (T, N)
    meta: dict = field(default_factory=dict)

    @property
    def n_steps(self) -> int:
        return int(self.wet_bulb_k.shape[0])

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        arrays = {f"obs.{k}": v for k, v in self.obs.items()} | {f"action.{k}": v for k, v in self.actions.items()}
        import json

        np.savez_compressed(
            path, wet_bulb_k=self.wet_bulb_k, cabinet_rows=self.cabinet_rows, tower_rows=self.tower_rows,
            cabinet_weights=self.cabinet_weights, tower_weights=self.tower_weights,
            header=np.array(json.dumps({"system": self.system_name, "teacher": self.teacher, "traces": self.traces,
                                        "meta": self.meta})), **arrays,
        )  # fmt: skip
        return path

    @classmethod
    def load(cls, path: str | Path) -> "Experience":
        import json

        with np.load(Path(path), allow_pickle=False) as z:
            header = json.loads(str(z["header"]))
            return cls(
                system_name=header["system"], teacher=header["teacher"], traces=header["traces"],
                obs={k[4:]: z[k] for k in z.files if k.startswith("obs.")},
                actions={k[7:]: z[k] for k in z.files if k.startswith("action.")},
                wet_bulb_k=z["wet_bulb_k"], cabinet_rows=z["cabinet_rows"], tower_rows=z["tower_rows"],
                cabinet_weights=z["cabinet_weights"], tower_weights=z["tower_weights"], meta=header.get("meta", {}),
            )  # fmt: skip


def collect_experience(
    teacher: Controller,
    system: SystemDescription,
    traces: list[str] | str,
    n_steps: int | None = None,
    *,
    wet_bulb_offset_k: float = 15.0,
    spinup_hours: float = 1.0,
    on_step: Callable[[int], None] | None = None,
    guardrails=MESH_GUARDRAILS,
    window_hours: float | None = None,
) -> Experience:
    """Roll ``teacher`` over each trace (``n_steps`` each, default all) and record what it saw and did.

    A trace ``SPEC@SCENARIO`` runs under that scenario; a bare spec under ``lcopt`` with ``wet_bulb_offset_k``.
    The teacher runs behind ``guardrails`` (the mesh's by default; None: bare), so the states recorded are those
    the mesh would visit and the actions recorded are those it would apply.

    ``window_hours``: roll only each trace's busiest window of that length (highest mean load,
    ``lcmesh.bench.llm.busiest_window``), after a warm-up of ``WARMUP_STEPS`` by the same controller (recorded
    too); ``n_steps`` is then ignored. The hours a plant is hardest to hold, which uniform draws over whole days
    hardly contain.
    """
    from lcmesh.distill.features import FeatureBuilder

    teacher = guard(teacher, system, guardrails)

    traces = [traces] if isinstance(traces, str) else list(traces)
    features = FeatureBuilder(system)
    rec: dict[str, list] = {k: [] for k in ("wb", "cab", "tow", "wc", "wt")}
    obs_rec: dict[str, list] = {k: [] for k in OBS_KEYS}
    act_rec: dict[str, list] = {k: [] for k in ACTION_KEYS}
    C, N = system.cabinets.count, system.towers.count
    done = 0
    with Plant(system) as plant:
        for spec in traces:
            name, _, scenario = spec.partition("@")
            trace = load_trace(name, system, scenario=scenario or scenario_with_offset("lcopt", wet_bulb_offset_k))
            if window_hours is not None:
                trace = _busiest(trace, window_hours)
            steps = trace.n_steps if n_steps is None or window_hours is not None else min(n_steps, trace.n_steps)
            power = np.zeros(system.n_blade_groups)
            teacher.reset()
            first = Observation(plant.out, float(trace.wet_bulb_k[0]), trace.blade_power_w(0, out=power), 0.0)
            plant.spin_up(power, first.wet_bulb_k, spinup_action(teacher, first), hours=spinup_hours)
            out = plant.reset()
            teacher.reset()
            for k in range(steps):
                obs = Observation(out, float(trace.wet_bulb_k[k]), trace.blade_power_w(k, out=power), k * trace.step_s)
                rec["cab"].append(features.cabinet_rows(obs).copy())
                rec["tow"].append(features.tower_rows(obs).copy())
                for key in OBS_KEYS:
                    obs_rec[key].append(np.array(out[key], dtype=np.float32))
                obs_rec["branch_power_w"][-1] = power.reshape(C, system.cabinets.branches, -1).sum(axis=2).astype(np.float32)
                weights = teacher.viper_weights(obs) if hasattr(teacher, "viper_weights") else {}
                action = teacher.act(obs)
                rec["wc"].append(weights.get("cabinet", np.ones(C)))
                rec["wt"].append(weights.get("tower", np.ones(N)))
                rec["wb"].append(obs.wet_bulb_k)
                for key, value in zip(ACTION_KEYS, action.astuple()):
                    act_rec[key].append(np.array(value, dtype=np.float32))
                out = plant.step(power, obs.wet_bulb_k, action)
                done += 1
                if on_step is not None:
                    on_step(done)
    return Experience(
        system_name=system.name, teacher=f"{getattr(teacher, 'name', '?')}:{getattr(teacher, 'version', '?')}",
        traces=traces, obs={k: np.stack(v) for k, v in obs_rec.items()},
        actions={k: np.stack(v) for k, v in act_rec.items()}, wet_bulb_k=np.asarray(rec["wb"]),
        cabinet_rows=np.stack(rec["cab"]), tower_rows=np.stack(rec["tow"]),
        cabinet_weights=np.maximum(np.stack(rec["wc"]), 0.0), tower_weights=np.maximum(np.stack(rec["wt"]), 0.0),
    )  # fmt: skip


def _busiest(trace, hours: float):
    """The trace's busiest ``hours`` with the benchmark's warm-up before them."""
    from lcmesh.bench.llm import WARMUP_STEPS, busiest_window

    if hours <= 0:
        raise ValueError(f"`window_hours` must be > 0, got {hours}")
    steps = min(max(round(hours * 3600.0 / trace.step_s), 1), trace.n_steps)
    start = busiest_window(trace, steps)
    warm = min(WARMUP_STEPS, start)
    return trace.slice(start - warm, warm + steps)


def resample(exp: Experience, n: int, rng: np.random.Generator, agent: str = "cabinet", uniform: bool = False) -> np.ndarray:
    """Draw ``n`` (t, row) index pairs with probability proportional to the VIPER weight (D -> D')."""
    w = (exp.cabinet_weights if agent == "cabinet" else exp.tower_weights).astype(np.float64)
    flat = np.ones(w.size) if uniform else w.reshape(-1)
    total = flat.sum()
    p = flat / total if total > 0 else np.full(flat.size, 1.0 / flat.size)
    idx = rng.choice(flat.size, size=n, replace=True, p=p)
    return np.column_stack(np.unravel_index(idx, w.shape))

"""The LLM controller: each cabinet's CDU setpoints and valve split and each tower's approach, answered by the LLM.

Each decision asks SmolLM2-135M with the distilled control adapter (``lcmesh/artifacts/llm-control``,
``lcmesh distill llm-control``) one short prompt per cabinet and per tower, in the compact protocol
of ``lcmesh.llm.control_format``, decoded under its grammar on the llama.cpp runtime
(``lcmesh.llm.llama_backend``): the answer is valid by construction. Its targets go through the
same hold band as every learned controller's (``lcmesh.distill.features.DEFAULT_HOLD``), then, in
the twin as in the mesh, through the mesh's guardrails.

Who decided is always counted and said (``stats_snapshot``, ``decided_by``): the LLM decides every
``period_steps``-th step and its answers hold in between. A cabinet or tower it did not answer (the
decision's time budget ran out before its turn, or the runtime failed) takes the fallback
controller's action for that step, counted with the reason. The fallback (the shipped PPO policy,
the adapter's teacher, else G36) runs every step so its state stays current.

Outside the mesh there is no deadline (``decision_budget_s = None``): the LLM answers every decision
it is asked for. In the mesh the Control agent calls :meth:`pace` with the wall seconds of a plant
step; the period then adapts so that a decision takes at most ``PACE_SHARE`` of the time between
decisions (the period in force is reported), and each decision's budget is that time.
"""

from __future__ import annotations

import logging
import math
import time
from collections import Counter, deque

import numpy as np
from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict

from lcmesh.distill.features import DEFAULT_HOLD, HoldBand
from lcmesh.llm.budget import Clock
from lcmesh.llm.control_format import (
    CABINET_HEAD,
    TOWER_FIELDS,
    TOWER_HEAD,
    cabinet_decision,
    cabinet_fields,
    cabinet_rest,
    tower_decision,
    tower_rest,
)  # fmt: skip
from lcmesh.llm.io_format import CabinetDecision, TowerDecision, cabinet_views, tower_views
from lcmesh.twin.controllers.base import Controller, Observation
from lcmesh.twin.plant import PlantAction
from lcmesh.twin.system import SystemDescription

log = logging.getLogger("lcmesh.llm.controller")
PACE_SHARE = 0.8  # in the mesh a decision may take this share of the wall time between decisions
# a decision's time varies (the explainer and the other agents share the cores): the period is paced on the slowest
# of the recent decisions with this margin. Paced on the latest or mean latency alone, a live demo at 60x gave 0.91 s
# decisions a 1.0 s budget, and the fallback answered 44 % of the cabinets and towers (deadline)
PACE_MARGIN = 1.2
PACE_WINDOW = 16  # recent decisions the pace looks at
MAX_PERIOD_STEPS = 240  # one hour of 15 s steps: slower than this, the LLM is not controlling the plant


class LlmControllerSettings(BaseSettings):
    """Knobs of the LLM controller (``LCMESH_LLM_CONTROL_PERIOD_STEPS=4`` etc.)."""

    model_config = SettingsConfigDict(env_prefix="LCMESH_LLM_", extra="ignore")

    control_period_steps: int = Field(4, ge=1, description="the LLM decides every N plant steps (at least, in the "
                                      "mesh: the period adapts to the LLM's speed), held in between")
    fallback: str = Field("auto", description="controller for what the LLM did not answer: auto (ppo, else g36)")
    control_adapter: str = Field("default", description="the control LoRA adapter: default (packaged), a folder, none")
    control_threads: int = Field(1, ge=0, description="llama.cpp threads for control (0: its default); one leaves "
                                 "the other core to the plant and the agents")


def make_fallback(name: str, system: SystemDescription) -> Controller:
    """The fallback controller; ``auto`` tries the default PPO policy (the shipped LLM's teacher) and settles for G36."""
    from lcmesh.twin.controllers import make_controller

    if name != "auto":
        return make_controller(name, system)
    try:
        return make_controller("ppo", system)
    except Exception as exc:  # no trained policy shipped, or not for this system
        log.info("fallback 'ppo' unavailable (%s); using 'g36'", exc)
        return make_controller("g36", system)


def make_control_backend(adapter: str = "default", threads: int = 1):
    """The llama.cpp runtime with the control adapter (converted to a GGUF LoRA on first use)."""
    from lcmesh.llm.gguf_lora import runtime_files
    from lcmesh.llm.llama_backend import LlamaCppBackend

    gguf, lora, adapter_id = runtime_files(adapter, "control")
    if gguf is None and lora is None and adapter != "none":
        raise FileNotFoundError("no control adapter is packaged (lcmesh/artifacts/llm-control); run "
                                "`lcmesh distill llm-control` or pass adapter='none' for the bare model")  # fmt: skip
    return LlamaCppBackend(gguf, lora=lora, threads=threads, adapter_id=adapter_id)


class LlmController:
    """Setpoints from an LLM, cabinet by cabinet and tower by tower, with a counted fallback and a paced period."""

    name = "llm"

    def __init__(
        self,
        system: SystemDescription,
        *,
        backend=None,
        fallback: str | Controller | None = None,
        period_steps: int | None = None,
        decision_budget_s: float | None = None,
        hold: HoldBand | None = DEFAULT_HOLD,
        clock: Clock | None = None,
        adapter: str | None = None,
        threads: int | None = None,
    ):
        """``backend``: anything with ``decide(prompts, fields, deadline)`` and a ``clock`` (default: llama.cpp with
        the control adapter ``adapter`` on ``threads`` threads, the settings' when None). ``decision_budget_s``: None
        (no deadline) outside the mesh."""
        cfg = LlmControllerSettings()
        self.system = system
        self.base_period = period_steps if period_steps is not None else cfg.control_period_steps
        if self.base_period < 1:
            raise ValueError(f"`period_steps` must be >= 1, got {self.base_period}")
        if decision_budget_s is not None and decision_budget_s <= 0:
            raise ValueError(f"`decision_budget_s` must be > 0 or None, got {decision_budget_s}")
        self.period_steps = self.base_period
        self.decision_budget_s = decision_budget_s
        self._owns_backend = backend is None
        self.backend = backend if backend is not None else make_control_backend(
            adapter if adapter is not None else cfg.control_adapter,
            threads if threads is not None else cfg.control_threads)
        self.clock = clock or getattr(self.backend, "clock", time.monotonic)
        fb = fallback if fallback is not None else cfg.fallback
        self.fallback = make_fallback(fb, system) if isinstance(fb, str) else fb
        self.hold = hold
        self.version = f"{self.backend.model_id}|fallback={self.fallback.name}"
        # what a result depends on (the benches' cache keys, lcmesh/bench/engine.py): model, adapter, the fallback's
        self.artifact_files = (*(p for p in (getattr(self.backend, "gguf", None), getattr(self.backend, "lora", None))
                                 if p is not None), *getattr(self.fallback, "artifact_files", ()))  # fmt: skip
        C, B, N = system.cabinets.count, system.cabinets.branches, system.towers.count
        self._fields = cabinet_fields(B)
        self._action = PlantAction(np.zeros(C), np.zeros(C), np.full((C, B), 1.0 / B), np.zeros(N))
        self._min_approach_k = system.towers.cell.approach_min_k
        self._fan_nominal_w = system.towers.cell.fan_power_nominal_w
        self.reset()

    def reset(self) -> None:
        self.fallback.reset()
        self._step = 0
        self._held: list[CabinetDecision | None] = [None] * self.system.cabinets.count
        self._held_towers: list[TowerDecision | None] = [None] * self.system.towers.count
        self.stats = {
            "decisions": 0, "cabinet_decisions": 0, "llm_cabinet_actions": 0, "tower_decisions": 0,
            "llm_tower_actions": 0, "fallbacks": 0, "fallback_reasons": Counter(), "fallbacks_by_kind": Counter(),
            "latency_s_last": 0.0, "latency_s_total": 0.0, "latency_s_max": 0.0, "forward_passes": 0,
            "steps": 0, "steps_llm": 0,
        }  # fmt: skip
        self.last_answers: list[str] = []
        self._recent: deque[float] = deque(maxlen=PACE_WINDOW)

    def close(self) -> None:
        """Free the runtime this controller loaded itself (one it was given stays its owner's)."""
        if self._owns_backend and callable(getattr(self.backend, "close", None)):
            self.backend.close()

    # --- pacing (the mesh) ----------------------------------------------------------------------------------
    def pace(self, step_wall_s: float) -> int:
        """Adapt the period to a plant step of ``step_wall_s`` wall seconds: a decision (the slowest of the recent ones,
        the latest or the mean, with ``PACE_MARGIN``) takes at most ``PACE_SHARE`` of the time between decisions; never below the configured period. Sets
        the decision budget to that time; returns the period."""
        if not step_wall_s > 0:
            raise ValueError(f"`step_wall_s` must be > 0, got {step_wall_s}")
        s = self.stats
        latency = PACE_MARGIN * max(s["latency_s_last"], s["latency_s_total"] / max(s["decisions"], 1),
                                    max(self._recent, default=0.0))  # fmt: skip
        needed = math.ceil(latency / (PACE_SHARE * step_wall_s)) if latency > 0 else 1
        self.period_steps = int(min(max(self.base_period, needed), MAX_PERIOD_STEPS))
        self.decision_budget_s = self.period_steps * step_wall_s * PACE_SHARE
        return self.period_steps

    # --- control ----------------------------------------------------------------------------------------------
    def act(self, obs: Observation) -> PlantAction:
        base = self.fallback.act(obs)
        action = self._action
        for dst, src in zip(action.astuple(), base.astuple()):
            dst[...] = src
        if self._step % self.period_steps == 0:
            self._decide(obs)
        self._step += 1
        s = self.stats
        s["steps"] += 1
        all_llm = True
        for c, decision in enumerate(self._held):
            if decision is None:
                all_llm = False
                continue
            action.supply_temp_setpoint_k[c] = decision.supply_temp_setpoint_k
            action.dp_setpoint_pa[c] = decision.dp_setpoint_pa
            action.valve_fractions[c] = decision.valve_fractions
        for t, tower in enumerate(self._held_towers):
            if tower is None:
                all_llm = False
                continue
            action.lw_setpoint_k[t] = obs.wet_bulb_k + max(tower.approach_k, self._min_approach_k)
        s["steps_llm"] += int(all_llm)
        if self.hold is not None:
            self.hold.apply(action, obs.out)
        return action

    def _decide(self, obs: Observation) -> None:
        """One decision: every cabinet's and tower's prompt answered in turn within the budget (if any)."""
        C, B, N = self.system.cabinets.count, self.system.cabinets.branches, self.system.towers.count
        branch_power_w = np.asarray(obs.blade_power_w).reshape(C, B, -1).sum(axis=2)
        cabs = cabinet_views(obs.out, branch_power_w, obs.wet_bulb_k)
        towers = tower_views(obs.out, obs.wet_bulb_k, self._fan_nominal_w)
        prompts = [(CABINET_HEAD, cabinet_rest(v)) for v in cabs] + [(TOWER_HEAD, tower_rest(v)) for v in towers]
        fields = [self._fields] * C + [TOWER_FIELDS] * N
        t0 = self.clock()
        deadline = None if self.decision_budget_s is None else t0 + self.decision_budget_s
        try:
            choices = self.backend.decide(prompts, fields, deadline)
            if len(choices) != C + N:
                raise RuntimeError(f"runtime returned {len(choices)} answers for {C} cabinets and {N} towers")
            failure = None
        except Exception as exc:  # a failed runtime must not stop control: everything falls back, counted
            log.warning("LLM runtime failed (%s: %s); all cabinets and towers fall back", type(exc).__name__, exc)
            choices, failure = [None] * (C + N), "runtime_error"
        latency = self.clock() - t0
        s = self.stats
        s["decisions"] += 1
        s["latency_s_last"] = latency
        s["latency_s_total"] += latency
        s["latency_s_max"] = max(s["latency_s_max"], latency)
        self._recent.append(latency)
        self.last_answers = []
        for i, choice in enumerate(choices):
            kind = "cabinet" if i < C else "tower"
            s[f"{kind}_decisions"] += 1
            if choice is None:
                reason = failure or "deadline"
                s["fallbacks"] += 1
                s["fallback_reasons"][reason] += 1
                s["fallbacks_by_kind"][kind] += 1
                self.last_answers.append("")
                decision = None
            else:
                s[f"llm_{kind}_actions"] += 1
                s["forward_passes"] += choice.passes
                self.last_answers.append(" ".join(choice.values))
                decision = cabinet_decision(choice.values) if kind == "cabinet" else tower_decision(choice.values)
            if kind == "cabinet":
                self._held[i] = decision
            else:
                self._held_towers[i - C] = decision

    # --- reporting ----------------------------------------------------------------------------------------------
    def stats_snapshot(self) -> dict:
        """Counters for the mesh, the run JSON and the benchmarks (JSON-ready)."""
        s = self.stats
        n = s["cabinet_decisions"] + s["tower_decisions"]
        llm = s["llm_cabinet_actions"] + s["llm_tower_actions"]
        return {
            **{k: v for k, v in s.items() if k not in ("fallback_reasons", "fallbacks_by_kind")},
            "fallback_reasons": dict(s["fallback_reasons"]),
            "fallbacks_by_kind": dict(s["fallbacks_by_kind"]),
            "llm_share": llm / n if n else None,
            "fallback_rate": s["fallbacks"] / n if n else None,
            "latency_s_mean": s["latency_s_total"] / max(s["decisions"], 1),
            "period_steps": self.period_steps,
            "base_period_steps": self.base_period,
            "decision_budget_s": self.decision_budget_s,
            "fallback_controller": self.fallback.name,
            "runtime": getattr(self.backend, "runtime", type(self.backend).__name__),
            "model_id": self.backend.model_id,
        }

    def decided_by(self) -> dict:
        """Who decided, for every surface: the LLM's share of cabinet and tower answers and why the rest fell back."""
        snap = self.stats_snapshot()
        return {"controller": "llm", "llm_share": snap["llm_share"],
                "llm_answers": snap["llm_cabinet_actions"] + snap["llm_tower_actions"],
                "answers": snap["cabinet_decisions"] + snap["tower_decisions"],
                "fallback": snap["fallback_controller"], "fallback_reasons": snap["fallback_reasons"],
                "period_steps": snap["period_steps"], "latency_s_mean": snap["latency_s_mean"],
                "summary": decided_by_line(snap)}  # fmt: skip


def decided_by_line(snap: dict) -> str:
    """One sentence: who decided, how often the fallback served and why, at which period."""
    n = snap["cabinet_decisions"] + snap["tower_decisions"]
    if n == 0:
        return "the LLM has not decided yet"
    llm = snap["llm_cabinet_actions"] + snap["llm_tower_actions"]
    text = (f"the LLM made {llm:,} of {n:,} cabinet and tower decisions ({100.0 * llm / n:.1f} %), "
            f"every {snap['period_steps']} plant steps")
    if snap["fallbacks"]:
        reasons = ", ".join(f"{k} {v:,}" for k, v in sorted(snap["fallback_reasons"].items()))
        text += f"; {snap['fallback_controller']} served the other {snap['fallbacks']:,} ({reasons})"
    return text


"""The LLM controller: every cabinet's CDU head and every tower's approach decided by one batched generate call.

The cabinets and the towers are the batch (LC-Opt's centralized action: one shared policy applied to
each cabinet, one to each tower). Each answer is parsed strictly (``lcmesh.llm.io_format``); a
cabinet or tower whose answer is unparsable or out of bounds, or all of them when the backend fails,
take the fallback controller's action for that cabinet or tower, and the reason is counted in
``stats`` (per kind in ``fallbacks_by_kind``). The fallback (the system's default ``"ppo"`` policy
when it loads, else ``"g36"``) runs every step, so its state stays current, and serves only rejected
answers. With ``period_steps = k`` the LLM decides every k-th step and its CDU setpoints and tower
approaches are held in between (the leaving-water setpoint follows the wet bulb at the held approach;
fallback cabinets and towers follow the fallback live). The decision's time
budget bounds the whole backend call, its first forward pass included (``lcmesh.llm.budget``): a
batch that cannot finish in time is not started, and every cabinet falls back as ``timeout``.
The action goes to the plant (or, in the mesh, to the Sensor agent's guardrails) like any other.
"""

from __future__ import annotations

import logging
import time
from collections import Counter

import numpy as np
from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict

from lcmesh.llm.base import LlmBackend, LlmBackendSettings, make_backend
from lcmesh.llm.budget import Clock
from lcmesh.llm.io_format import (
    ANSWER_STOP, CabinetDecision, TowerDecision, cabinet_views, controller_messages, parse_cabinet_answer,
    parse_tower_answer, tower_messages, tower_views,
)  # fmt: skip
from lcmesh.twin.controllers.base import Controller, Observation
from lcmesh.twin.plant import PlantAction
from lcmesh.twin.system import SystemDescription

log = logging.getLogger("lcmesh.llm.controller")


class LlmControllerSettings(BaseSettings):
    """Knobs of the LLM controller (``LCMESH_LLM_CONTROL_PERIOD_STEPS=4`` etc.)."""

    model_config = SettingsConfigDict(env_prefix="LCMESH_LLM_", extra="ignore")

    control_period_steps: int = Field(4, ge=1, description="the LLM decides every N plant steps, held in between")
    fallback: str = Field("auto", description="controller for rejected answers: auto (ppo, else g36)")
    max_new_tokens: int = Field(64, ge=8, le=512, description="answer budget per cabinet")
    decision_budget_s: float = Field(10.0, gt=0, description="wall-time budget of one batched decision")


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


class LlmController:
    """CDU setpoints and valve splits from an LLM, batched over cabinets, with a counted per-cabinet fallback."""

    name = "llm"

    def __init__(
        self,
        system: SystemDescription,
        *,
        backend: LlmBackend | None = None,
        backend_settings: LlmBackendSettings | None = None,
        fallback: str | Controller | None = None,
        period_steps: int | None = None,
        max_new_tokens: int | None = None,
        decision_budget_s: float | None = None,
        clock: Clock | None = None,
    ):
        """``clock`` times the decisions; by default the backend's, so one injected clock drives both."""
        cfg = LlmControllerSettings()
        self.system = system
        self.period_steps = period_steps if period_steps is not None else cfg.control_period_steps
        if self.period_steps < 1:
            raise ValueError(f"`period_steps` must be >= 1, got {self.period_steps}")
        self.max_new_tokens = max_new_tokens if max_new_tokens is not None else cfg.max_new_tokens
        self.decision_budget_s = decision_budget_s if decision_budget_s is not None else cfg.decision_budget_s
        if self.decision_budget_s <= 0:
            raise ValueError(f"`decision_budget_s` must be > 0, got {self.decision_budget_s}")
        self.backend = backend if backend is not None else make_backend(backend_settings)
        self.clock = clock or getattr(self.backend, "clock", time.monotonic)
        fb = fallback if fallback is not None else cfg.fallback
        self.fallback = make_fallback(fb, system) if isinstance(fb, str) else fb
        self.version = f"{self.backend.model_id}|fallback={self.fallback.name}"
        C, B, N = system.cabinets.count, system.cabinets.branches, system.towers.count
        self._action = PlantAction(np.zeros(C), np.zeros(C), np.full((C, B), 1.0 / B), np.zeros(N))
        self._held: list[CabinetDecision | None] = [None] * C
        self._held_towers: list[TowerDecision | None] = [None] * N
        self._min_approach_k = system.towers.cell.approach_min_k
        self._fan_nominal_w = system.towers.cell.fan_power_nominal_w
        self.reset()

    def reset(self) -> None:
        self.fallback.reset()
        self._step = 0
        self._held = [None] * self.system.cabinets.count
        self._held_towers = [None] * self.system.towers.count
        self.stats = {
            "decisions": 0, "cabinet_decisions": 0, "llm_cabinet_actions": 0, "tower_decisions": 0,
            "llm_tower_actions": 0, "fallbacks": 0, "fallback_reasons": Counter(),
            "fallbacks_by_kind": Counter(), "latency_s_last": 0.0, "latency_s_total": 0.0, "new_tokens_total": 0,
        }  # fmt: skip
        self.last_answers: list[str] = []
        self.last_failures: list[str | None] = []

    def act(self, obs: Observation) -> PlantAction:
        base = self.fallback.act(obs)
        action = self._action
        for dst, src in zip(action.astuple(), base.astuple()):
            dst[...] = src
        if self._step % self.period_steps == 0:
            self._held, self._held_towers = self.decide(obs)
        self._step += 1
        for c, decision in enumerate(self._held):
            if decision is not None:
                action.supply_temp_setpoint_k[c] = decision.supply_temp_setpoint_k
                action.dp_setpoint_pa[c] = decision.dp_setpoint_pa
                action.valve_fractions[c] = decision.valve_fractions
        for t, tower in enumerate(self._held_towers):
            if tower is not None:
                action.lw_setpoint_k[t] = obs.wet_bulb_k + max(tower.approach_k, self._min_approach_k)
        return action

    def decide(self, obs: Observation) -> tuple[list[CabinetDecision | None], list[TowerDecision | None]]:
        """One batched LLM call over all cabinets and towers; None where an answer was rejected (counted)."""
        C, B, N = self.system.cabinets.count, self.system.cabinets.branches, self.system.towers.count
        branch_power_w = np.asarray(obs.blade_power_w).reshape(C, B, -1).sum(axis=2)
        conversations = [controller_messages(v) for v in cabinet_views(obs.out, branch_power_w, obs.wet_bulb_k)]
        conversations += [tower_messages(v) for v in tower_views(obs.out, obs.wet_bulb_k, self._fan_nominal_w)]
        t0 = self.clock()
        try:
            generations = self.backend.chat(conversations, max_new_tokens=self.max_new_tokens, stop=[ANSWER_STOP],
                                            time_budget_s=self.decision_budget_s)  # fmt: skip
            answers = [(g.text, _failure(g), g.new_tokens) for g in generations]
            if len(answers) != C + N:
                raise RuntimeError(f"backend returned {len(answers)} answers for {C} cabinets and {N} towers")
        except Exception as exc:  # a dead endpoint must not stop control: every cabinet and tower falls back
            log.warning("LLM backend failed (%s: %s); all cabinets and towers fall back", type(exc).__name__, exc)
            answers = [("", f"{type(exc).__name__}: {exc}", 0)] * (C + N)
        latency = self.clock() - t0
        s = self.stats
        s["decisions"] += 1
        s["latency_s_last"] = latency
        s["latency_s_total"] += latency
        decisions: list = []
        self.last_answers, self.last_failures = [a[0] for a in answers], []
        for i, (text, error, n_tokens) in enumerate(answers):
            kind = "cabinet" if i < C else "tower"
            s[f"{kind}_decisions"] += 1
            s["new_tokens_total"] += n_tokens
            if error is not None:
                parsed = None
            else:
                parsed = parse_cabinet_answer(text, B) if kind == "cabinet" else parse_tower_answer(text)
            if isinstance(parsed, (CabinetDecision, TowerDecision)):
                s[f"llm_{kind}_actions"] += 1
                decisions.append(parsed)
                self.last_failures.append(None)
                continue
            reason = ("timeout" if error == "timeout" else "backend") if parsed is None else parsed.reason
            s["fallbacks"] += 1
            s["fallback_reasons"][reason] += 1
            s["fallbacks_by_kind"][kind] += 1
            self.last_failures.append(error if parsed is None else parsed.detail)
            decisions.append(None)
        return decisions[:C], decisions[C:]

    def stats_snapshot(self) -> dict:
        """Counters for the mesh and the benchmark (JSON-ready)."""
        s = self.stats
        n = max(s["cabinet_decisions"] + s["tower_decisions"], 1)
        return {
            **{k: v for k, v in s.items() if k not in ("fallback_reasons", "fallbacks_by_kind")},
            "fallback_reasons": dict(s["fallback_reasons"]),
            "fallbacks_by_kind": dict(s["fallbacks_by_kind"]),
            "fallback_rate": s["fallbacks"] / n,
            "latency_s_mean": s["latency_s_total"] / max(s["decisions"], 1),
            "period_steps": self.period_steps,
            "fallback_controller": self.fallback.name,
        }


def _failure(gen) -> str | None:
    """Why a generation cannot be parsed at all; None when it has an answer (one can end just as time runs out)."""
    if gen.failure == "timeout" and gen.text.rstrip().endswith(ANSWER_STOP):
        return None
    return gen.failure

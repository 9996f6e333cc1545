"""The LLM controller: every cabinet's CDU head decided by one batched generate call.

The cabinets are the batch (LC-Opt's centralized action: one shared policy applied to each cabinet).
Each answer is parsed strictly (``lcmesh.llm.io_format``); a cabinet whose answer is unparsable or
out of bounds, or all cabinets when the backend fails, take the fallback controller's action for
that cabinet, and the reason is counted in ``stats``. The fallback (``"ppo"`` when a trained policy
loads, else ``"g36"``) runs every step, so its state stays current; it also sets the cooling towers,
which the LLM does not decide. With ``period_steps = k`` the LLM decides every k-th step and its
CDU setpoints are held in between (fallback cabinets follow the fallback live). The decision's time
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
from lcmesh.llm.io_format import ANSWER_STOP, CabinetDecision, cabinet_views, controller_messages, parse_cabinet_answer
from lcmesh.twin.controllers.base import Controller, Observation
from lcmesh.twin.plant import PlantAction
from lcmesh.twin.system import SystemDescription

log = logging.getLogger("lcmesh.llm.controller")


class LlmControllerSettings(BaseSettings):
    """Knobs of the LLM controller (``LCMESH_LLM_CONTROL_PERIOD_STEPS=4`` etc.)."""

    model_config = SettingsConfigDict(env_prefix="LCMESH_LLM_", extra="ignore")

    control_period_steps: int = Field(4, ge=1, description="the LLM decides every N plant steps, held in between")
    fallback: str = Field("auto", description="controller for failed cabinets and the towers: auto (ppo, else g36)")
    max_new_tokens: int = Field(64, ge=8, le=512, description="answer budget per cabinet")
    decision_budget_s: float = Field(10.0, gt=0, description="wall-time budget of one batched decision")


def make_fallback(name: str, system: SystemDescription) -> Controller:
    """The fallback controller; ``auto`` tries the trained PPO policy and settles for G36."""
    from lcmesh.twin.controllers import make_controller

    if name != "auto":
        return make_controller(name, system)
    from lcmesh.distill.policy import PAPER_POLICY  # the teacher the shipped LLM was distilled from

    try:
        return make_controller("ppo", system, policy=str(PAPER_POLICY))
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
        self.reset()

    def reset(self) -> None:
        self.fallback.reset()
        self._step = 0
        self._held = [None] * self.system.cabinets.count
        self.stats = {
            "decisions": 0, "cabinet_decisions": 0, "llm_cabinet_actions": 0, "fallbacks": 0,
            "fallback_reasons": Counter(), "latency_s_last": 0.0, "latency_s_total": 0.0, "new_tokens_total": 0,
        }  # fmt: skip
        self.last_answers: list[str] = []
        self.last_failures: list[str | None] = []

    def act(self, obs: Observation) -> PlantAction:
        base = self.fallback.act(obs)
        action = self._action
        for dst, src in zip(action.astuple(), base.astuple()):
            dst[...] = src
        if self._step % self.period_steps == 0:
            self._held = self.decide(obs)
        self._step += 1
        for c, decision in enumerate(self._held):
            if decision is not None:
                action.supply_temp_setpoint_k[c] = decision.supply_temp_setpoint_k
                action.dp_setpoint_pa[c] = decision.dp_setpoint_pa
                action.valve_fractions[c] = decision.valve_fractions
        return action

    def decide(self, obs: Observation) -> list[CabinetDecision | None]:
        """One batched LLM call over all cabinets; None where the answer was rejected (counted)."""
        C, B = self.system.cabinets.count, self.system.cabinets.branches
        branch_power_w = np.asarray(obs.blade_power_w).reshape(C, B, -1).sum(axis=2)
        conversations = [controller_messages(v) for v in cabinet_views(obs.out, branch_power_w, obs.wet_bulb_k)]
        t0 = self.clock()
        try:
            generations = self.backend.chat(conversations, max_new_tokens=self.max_new_tokens, stop=[ANSWER_STOP],
                                            time_budget_s=self.decision_budget_s)  # fmt: skip
            answers = [(g.text, _failure(g), g.new_tokens) for g in generations]
            if len(answers) != C:
                raise RuntimeError(f"backend returned {len(answers)} answers for {C} cabinets")
        except Exception as exc:  # a dead endpoint must not stop control: every cabinet falls back
            log.warning("LLM backend failed (%s: %s); all cabinets fall back", type(exc).__name__, exc)
            answers = [("", f"{type(exc).__name__}: {exc}", 0)] * C
        latency = self.clock() - t0
        s = self.stats
        s["decisions"] += 1
        s["latency_s_last"] = latency
        s["latency_s_total"] += latency
        decisions: list[CabinetDecision | None] = []
        self.last_answers, self.last_failures = [a[0] for a in answers], []
        for text, error, n_tokens in answers:
            s["cabinet_decisions"] += 1
            s["new_tokens_total"] += n_tokens
            parsed = parse_cabinet_answer(text, B) if error is None else None
            if isinstance(parsed, CabinetDecision):
                s["llm_cabinet_actions"] += 1
                decisions.append(parsed)
                self.last_failures.append(None)
                continue
            reason = ("timeout" if error == "timeout" else "backend") if parsed is None else parsed.reason
            s["fallbacks"] += 1
            s["fallback_reasons"][reason] += 1
            self.last_failures.append(error if parsed is None else parsed.detail)
            decisions.append(None)
        return decisions

    def stats_snapshot(self) -> dict:
        """Counters for the mesh and the benchmark (JSON-ready)."""
        s = self.stats
        n = max(s["cabinet_decisions"], 1)
        return {
            **{k: v for k, v in s.items() if k != "fallback_reasons"},
            "fallback_reasons": dict(s["fallback_reasons"]),
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

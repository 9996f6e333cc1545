"""The Control agent: runs the configured policy on each plant state and publishes proposals.

A proposal carries a decision id, the controller's name and version, the action, and the key
facts behind it (hottest branch, setpoints and their changes: cheap, so they ride on the
critical path). Right after publishing it computes the full grounding facts (the toolbox's
``cabinet_decision_facts`` for the cabinet with the hottest branch, or the controller's own
``explain_facts``) and the deterministic text, and publishes that explanation, under the same
decision id, on ``explain/{decision_id}`` (the Sensor records it in history). With ``explainer = "llm"`` every decision
still gets that rendering, and the newest rendered decision goes on to the local LLM (a thread of its
own, at ``explain_level``: short, the rendering and the LLM's WHAT IF section; or detailed) with the
toolbox's what-if facts; the judge checks its text, which is published over the rendering, under the
same decision id, only where it adds a verified what-if claim the rendering lacks. Otherwise the
rendering stays and the reason is counted (``explained_by`` in the stats).

By default the decision runs in the bus callback (no thread hand-off: lowest latency). For a policy
slower than a control period (the LLM), ``inline = false`` moves it to a worker thread with a
one-item mailbox (stale states are skipped, not queued) and, while a decision is in progress, the
controller's last action is re-sent for each new step, so the Sensor never falls back for want of it.
The LLM controller always runs so (``_worker_mode``), and is paced: before each step the agent tells it
the wall seconds of a plant step, and its decision period adapts (lcmesh/llm/controller.py); what it
decided and what fell back rides in the agent's stats (``decided_by``), which the UI shows.

The controller follows the Configuration agent's ``controller``; one that can not load (not
trained yet, unknown, a third-party ``module:Class`` not listed in ``controller_plugins``, or one
that needs the plant and the trace, like ``lookahead``) is replaced by G36 with a warning event.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Collection

import numpy as np

from lcmesh.llm.explainer import TARGET_S
from lcmesh.mesh import keys
from lcmesh.mesh.agents.base import Agent, LatestSlot
from lcmesh.mesh.messages import (
    ActionModel, AppliedAction, Explanation, FactModel, MeshConfig, PlantState, Proposal, new_id,
    plant_state_to_observation, utc_now,
)  # fmt: skip
from lcmesh.mesh.tools.explain import render_explanation
from lcmesh.mesh.tools.facts import Fact, cabinet_decision_facts
from lcmesh.twin.controllers import Controller, ControllerError, Observation, make_controller, mesh_refusal
from lcmesh.twin.plant import PlantAction
from lcmesh.twin.system import SystemDescription, load_system

log = logging.getLogger("lcmesh.mesh.agents.control")
FALLBACK_CONTROLLER = "g36"
_K = 273.15


def build_controller(
    name: str, system: SystemDescription, allowed_plugins: Collection[str] = ()
) -> tuple[Controller, str | None]:
    """`name`'s controller, or G36 and a note saying why `name` could not be used.

    A third-party ``module:Class`` is imported only when `allowed_plugins` (the settings'
    ``allowed_controller_plugins``) lists it. A learned policy trained for another cell count per tower
    runs with its cells pooled (noted).
    """
    from lcmesh.distill.features import LayoutMismatch

    try:
        problem = mesh_refusal(name, allowed_plugins)
        if problem is not None:
            raise ControllerError(f"`controller` {problem}")
        try:
            return make_controller(name, system), None
        except LayoutMismatch as exc:
            if not exc.cells_only:
                raise
            ctrl = make_controller(name, system, pool_cells=True)
            return ctrl, f"controller {name!r} runs with tower cells pooled: {ctrl.version}"
    except Exception as exc:  # unknown name, module not written yet, no trained artifact
        why = f"{type(exc).__name__}: {exc}"
        note = f"controller {name!r} is not available ({why}); using {FALLBACK_CONTROLLER!r}"
        return make_controller(FALLBACK_CONTROLLER, system), note


def decision_facts(
    controller: Controller, system: SystemDescription, obs: Observation, action: PlantAction,
    previous: PlantAction | None,
) -> list[FactModel]:  # fmt: skip
    """The full grounding facts of a decision: the controller's own, else the toolbox's for the hottest cabinet."""
    own = getattr(controller, "explain_facts", None)
    if callable(own):
        facts = own(obs, action)
        items = facts.items() if isinstance(facts, dict) else None
        if items is not None:
            return [FactModel(name=str(k), value=_plain(v)) for k, v in items]
        return [FactModel.model_validate(_fact_dict(f)) for f in facts]
    cabinet = int(np.argmax(obs.out["branch_temp_k"].max(axis=1)))
    facts = cabinet_decision_facts(system, obs.out, action, previous, obs.wet_bulb_k, cabinet)
    return [FactModel.model_validate(_fact_dict(f)) for f in facts]


def explanation_text(facts: list[FactModel]) -> str:
    """The deterministic short explanation (toolbox renderer), or the facts' sentences joined."""
    try:
        return render_explanation([Fact.model_validate(f.model_dump()) for f in facts], "short")
    except (ValueError, KeyError, TypeError):  # facts not of the toolbox's kind (a controller's own)
        return "; ".join(f.text for f in facts if f.text) or ", ".join(f"{f.name} = {f.value}" for f in facts)


def key_facts(obs: Observation, action: PlantAction, previous: PlantAction | None) -> list[FactModel]:
    """The few numbers a proposal carries (cheap, on the critical path): where it is hottest, what changed."""
    branch = obs.out["branch_temp_k"]
    cabinet, j = (int(i) for i in np.unravel_index(np.argmax(branch), branch.shape))
    supply_c = float(action.supply_temp_setpoint_k[cabinet]) - _K
    lw_c = float(np.mean(action.lw_setpoint_k)) - _K
    facts = [
        FactModel(name="hottest_branch", value=f"cabinet {cabinet + 1} branch {j + 1}", kind="label",
                  text=f"the hottest branch is branch {j + 1} of cabinet {cabinet + 1}"),
        FactModel(name="hottest_branch_temp", value=round(float(branch[cabinet, j]) - _K, 2), unit="degC",
                  kind="observation", text=f"it runs at {float(branch[cabinet, j]) - _K:.1f} °C"),
        FactModel(name="max_blade_temp", value=round(float(obs.out["blade_temp_k"].max()) - _K, 2), unit="degC",
                  kind="observation"),
        FactModel(name="supply_setpoint", value=round(supply_c, 2), unit="degC", kind="action",
                  text=f"cabinet {cabinet + 1} supply setpoint {supply_c:.1f} °C"),
        FactModel(name="tower_lw_setpoint", value=round(lw_c, 2), unit="degC", kind="action"),
        FactModel(name="wet_bulb", value=round(obs.wet_bulb_k - _K, 2), unit="degC", kind="observation"),
    ]  # fmt: skip
    if previous is not None:
        supply_change = supply_c - (float(previous.supply_temp_setpoint_k[cabinet]) - _K)
        lw_change = lw_c - (float(np.mean(previous.lw_setpoint_k)) - _K)
        facts += [FactModel(name="supply_setpoint_change", value=round(supply_change, 3), unit="K", kind="change"),
                  FactModel(name="tower_lw_change", value=round(lw_change, 3), unit="K", kind="change")]  # fmt: skip
    return facts


def _fact_dict(fact) -> dict:
    data = fact.model_dump() if hasattr(fact, "model_dump") else dict(fact)
    data["value"] = _plain(data.get("value"))
    return data


def _plain(value):
    if isinstance(value, (np.generic,)):
        return value.item()
    return value if isinstance(value, (int, float, str, bool)) or value is None else str(value)


def _worker_mode(controller: str) -> bool:
    """Controllers slower than a control period decide in the worker thread whatever ``inline`` says."""
    return controller == "llm"


class ControlAgent(Agent):
    role = "control"

    def __init__(self, settings, agent_id: str | None = None):
        super().__init__(settings, agent_id)
        self.cfg = settings.control
        self.system: SystemDescription | None = None
        self.controller: Controller | None = None
        self.controller_note: str | None = None
        self._wanted: str | None = None
        self._decide_lock = threading.Lock()
        self._states = LatestSlot()
        self._explain_jobs = LatestSlot()
        self._llm_jobs = LatestSlot()  # rendered decisions the LLM may add its text to: the newest one
        self._previous: PlantAction | None = None
        self._run_id: str | None = None
        self._last_state_id: str | None = None
        self._applied = threading.Event()
        self._applied_step = -1
        self._last_proposal: Proposal | None = None
        self.tally = {"decisions": 0, "repeats": 0, "bad_states": 0, "explanations": 0, "llm_texts": 0,
                      "llm_fallbacks": 0, "llm_texts_in_target": 0, "llm_explain_s_max": 0.0,
                      "llm_fallback_reasons": {}}  # fmt: skip
        self._llm_explainer = None
        self._llm_thread: threading.Thread | None = None

    def on_start(self) -> None:
        self.system = load_system(self.settings.system)
        self.watch_config(self._on_config)
        self._use_controller(self.config.controller)
        self.subscribe(keys.applied(self.site, self.cfg.loop), AppliedAction, self._on_applied)
        self.subscribe(keys.plant_state(self.site), PlantState, self._on_state, latest=True)
        self.spawn("decide", self._decide_loop)
        if self.cfg.explain:
            self.spawn("explain", self._explain_loop)
            if self.cfg.explainer == "llm":
                self._llm_thread = self.spawn("explain-llm", self._llm_explain_loop)

    def on_stop(self) -> None:
        """An LLM explanation in progress outlives the base class's 5 s join (its budget is 9.7 s): wait for it, or
        the model's threads meet interpreter shutdown mid-generation (the process aborts)."""
        if self._llm_thread is not None:
            self._llm_thread.join(timeout=30.0)

    def details(self) -> dict:
        c = self.controller
        report = getattr(c, "decided_by", None)
        return {"controller": getattr(c, "name", None), "controller_version": getattr(c, "version", None),
                "wanted": self.config.controller, "note": self.controller_note,
                **{k: dict(v) if isinstance(v, dict) else v for k, v in self.tally.items()},  # a copy: the explain
                # thread adds to the reasons while the stats are sent
                "skipped_states": self._states.replaced, "skipped_explanations": self._explain_jobs.replaced,
                "not_asked_of_the_llm": self._llm_jobs.replaced,
                **({"decided_by": report()} if callable(report) else {}),
                **({"explained_by": self.explained_by()} if self.cfg.explain and self.cfg.explainer == "llm" else {}),
                "busy_with": self.busy_with()}  # fmt: skip

    def busy_with(self) -> list[str]:
        """The local LLM's work in this agent, for the Agent Monitor to name beside a high CPU share."""
        work = []
        if getattr(self.controller, "name", None) == "llm":
            every = getattr(self.controller, "period_steps", None)
            work.append(f"the local LLM is the controller{f', deciding every {every} plant steps' if every else ''}")
        if self.cfg.explain and self.cfg.explainer == "llm":
            work.append(f"the local LLM writes {self.cfg.explain_level} explanations on a thread of its own: "
                        "LCMESH_CONTROL__EXPLAINER=renderer frees the core")  # fmt: skip
        return work

    def explained_by(self) -> dict:
        """Who wrote the published explanations with the LLM explaining: its share, the renderer's reasons, in a line."""
        t, level = self.tally, self.cfg.explain_level
        n = t["llm_texts"] + t["llm_fallbacks"]
        reasons = dict(t["llm_fallback_reasons"])
        part = "its WHAT IF after the rendering" if level == "short" else "the whole text"
        summary = (f"the LLM wrote {part} in {t['llm_texts']} of the {n} {level} explanations it was asked for "
                   f"({t['llm_texts_in_target']} within {TARGET_S[level]:g} s; it is asked for the newest "
                   f"decision when free, the others keep the rendering)"
                   + (f"; the rendering stood in for {t['llm_fallbacks']}: "
                      + ", ".join(f"{k} {v}" for k, v in sorted(reasons.items(), key=lambda kv: -kv[1]))
                      if t["llm_fallbacks"] else ""))  # fmt: skip
        return {"level": level, "decisions": t["decisions"], "explanations": n, "llm_texts": t["llm_texts"],
                "llm_texts_in_target": t["llm_texts_in_target"], "target_s": TARGET_S[level],
                "llm_explain_s_max": t["llm_explain_s_max"], "fallback_reasons": reasons, "summary": summary}  # fmt: skip

    def _on_config(self, old: MeshConfig, new: MeshConfig) -> None:
        if new.controller != old.controller and self.controller is not None:
            self._wanted = new.controller  # built before the next decision

    def _on_applied(self, applied: AppliedAction) -> None:
        self._previous = applied.action.to_action()
        self._applied_step = applied.step
        self._applied.set()

    def _use_controller(self, name: str) -> None:
        self.controller, self.controller_note = build_controller(
            name, self.system, self.settings.allowed_controller_plugins
        )
        if hasattr(self.controller, "base_period"):  # the LLM: its configured period (paced up from there)
            self.controller.base_period = self.controller.period_steps = self.config.llm.control_period_steps
        self.controller.reset()
        if self.controller_note:
            log.warning("%s", self.controller_note)
            self.emit_event("warning", self.controller_note)
        else:
            log.info("controller %s version %s", self.controller.name, self.controller.version)

    def _on_state(self, state: PlantState) -> None:
        """Decide in the bus callback (``inline``), or hand the state to the worker (a slow controller: the LLM)."""
        if self.cfg.inline and not _worker_mode(self.config.controller):
            self._decide(state)
        else:
            self._on_state_async(state)

    def _on_state_async(self, state: PlantState) -> None:
        """Worker mode: while a slow decision runs, the controller's last action is re-sent for each new step."""
        last = self._last_proposal
        if self._decide_lock.locked() and last is not None and last.step < state.step:
            repeat = last.model_copy(update={
                "id": new_id(), "sent_at": utc_now(), "step": state.step, "state_id": state.id,
                "facts": [FactModel(name="repeats_decision", value=last.decision_id, kind="label",
                                    text=f"the decision of step {last.step} holds while the next one is computed")],
            })  # fmt: skip
            self.bus.publish(keys.proposal(self.site, self.cfg.loop), repeat)
            self.tally["repeats"] += 1
        self._states.put(state)

    def _decide_loop(self) -> None:
        while not self.stopping:
            state = self._states.take(timeout_s=0.2)
            if state is not None:
                self._decide(state)

    def _decide(self, state: PlantState) -> None:
        """Decode, act, publish the proposal; hand the explanation to its own thread."""
        with self._decide_lock:
            if state.id == self._last_state_id:
                return
            t0 = time.perf_counter()
            if self._wanted is not None:
                wanted, self._wanted = self._wanted, None
                self._use_controller(wanted)
            try:
                obs = plant_state_to_observation(state, self.system)
            except ValueError as exc:
                self.tally["bad_states"] += 1
                log.warning("dropped plant state %s: %s", state.id, exc)
                return
            self._last_state_id = state.id
            if state.run_id != self._run_id:
                self._run_id = state.run_id
                self.controller.reset()
            ctrl, previous = self.controller, self._previous
            pace = getattr(ctrl, "pace", None)
            if callable(pace):  # a slow policy (the LLM) decides every k steps, k adapted to the mesh's speed
                pace(state.period_s)
            action = ctrl.act(obs)
            proposal = Proposal(
                source=self.agent_id, loop=self.cfg.loop, step=state.step, state_id=state.id, controller=ctrl.name,
                controller_version=str(ctrl.version), action=ActionModel.from_action(action),
                facts=key_facts(obs, action, previous), compute_ms=(time.perf_counter() - t0) * 1e3,
            )  # fmt: skip
            self._applied.clear()
            self._last_proposal = proposal
            self.bus.publish(keys.proposal(self.site, self.cfg.loop), proposal)
            self.tally["decisions"] += 1
            if self.cfg.explain:
                self._explain_jobs.put((state, obs, action.copy(), previous, proposal.decision_id, ctrl))

    def _llm_explanation(
        self, state, obs, action, previous, decision_id: str, ctrl
    ) -> tuple[Explanation | None, float, str]:
        """The local LLM's explanation (``explain_level``) of the hottest cabinet's decision where it adds a verified
        what-if claim the rendering lacks; the rendering where it fails the judge or adds none (said in
        ``why_renderer``). Short: the rendering and the LLM's WHAT IF section (docs/llm.md). Returns the message to
        publish (None where the rendering stands), the seconds it took and why the rendering stood in."""
        from lcmesh.llm.explainer import make_explainer

        if self._llm_explainer is None:
            self._llm_explainer = make_explainer(self.system, short_only=self.cfg.explain_level == "short")
        level = self.cfg.explain_level
        cabinet = int(np.argmax(obs.out["branch_temp_k"].max(axis=1)))
        t0 = time.perf_counter()  # the whole explanation: facts, rendering, LLM, judge
        r = self._llm_explainer.explain(obs.out, action, previous, obs.wet_bulb_k, cabinet, level,
                                        record_id=decision_id)  # fmt: skip
        seconds = time.perf_counter() - t0
        text, why = r.text, r.fallback_reason or ""
        if r.source == "llm" and not r.whatif_claims:  # it passed the judge, but says nothing the rendering lacks
            text, why = r.rendered, "no verified claim the rendering lacks"
        if r.source != "llm" or why:
            return None, seconds, why
        return Explanation(source=self.agent_id, decision_id=decision_id, step=state.step, controller=ctrl.name,
                           level=level, text=text, written_by="llm", llm_part=r.llm_part,
                           facts=[FactModel.model_validate(_fact_dict(f)) for f in r.facts]), seconds, why  # fmt: skip

    def _count_llm_explanation(self, by_llm: bool, seconds: float, why: str) -> None:
        """Count an LLM explanation once it is published (or the rendering stood in): what ``explained_by`` says."""
        self.tally["llm_texts" if by_llm else "llm_fallbacks"] += 1
        self.tally["llm_texts_in_target"] += by_llm and seconds <= TARGET_S[self.cfg.explain_level]
        self.tally["llm_explain_s_max"] = round(max(self.tally["llm_explain_s_max"], seconds), 3)
        if why:
            reasons = self.tally["llm_fallback_reasons"]
            reasons[why] = reasons.get(why, 0) + 1

    def _explain_loop(self) -> None:
        """Full facts and the rendering for each decision, once the Sensor applied its step (off the critical path);
        with the LLM explaining, the newest rendered decision goes on to it."""
        while not self.stopping:
            job = self._explain_jobs.take(timeout_s=0.2)
            if job is None:
                continue
            state, obs, action, previous, decision_id, ctrl = job
            if self._applied_step < state.step:
                self._applied.wait(timeout=0.5 * state.period_s)
            try:
                facts = decision_facts(ctrl, self.system, obs, action, previous)
                explanation = Explanation(source=self.agent_id, decision_id=decision_id, step=state.step,
                                          controller=ctrl.name, text=explanation_text(facts), facts=facts)  # fmt: skip
            except Exception as exc:  # a facts bug must not stop the explanations of later decisions
                log.exception("explaining decision %s failed", decision_id)
                self._on_handler_error("explain", exc)
                continue
            self._publish_explanation(explanation)
            if self._llm_thread is not None and not callable(getattr(ctrl, "explain_facts", None)):
                self._llm_jobs.put(job)

    def _llm_explain_loop(self) -> None:
        """The LLM's text for the newest rendered decision, published over the rendering where it earns it (a verified
        what-if claim the rendering lacks); else the rendering stays, and the reason is counted."""
        while not self.stopping:
            job = self._llm_jobs.take(timeout_s=0.2)
            if job is None:
                continue
            try:
                explanation, seconds, why = self._llm_explanation(*job)
            except Exception as exc:  # a failing LLM leaves the rendering; it never stops the explanations
                log.exception("the LLM's explanation of decision %s failed", job[4])
                self._on_handler_error("explain-llm", exc)
                continue
            if explanation is not None:
                self._publish_explanation(explanation)
            self._count_llm_explanation(explanation is not None, seconds, why)

    def _publish_explanation(self, explanation: Explanation) -> None:
        """On ``explain/{decision_id}``; the Sensor records it in history."""
        self.bus.publish(keys.explain(self.site, explanation.decision_id), explanation, block=True)
        self.tally["explanations"] += 1

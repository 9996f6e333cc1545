"""The Sensor agent: owns the twin, publishes plant state, applies actions after the guardrails.

Each control period (one 15 s plant step, ``15 / speed_factor`` wall seconds) it publishes the
plant state, waits up to ``deadline_fraction`` of the period for a proposal for that step, passes
the proposal (or the operator's manual action) through the guardrails, applies it and steps the
twin. Without a usable proposal it holds the last safe action for ``hold_periods`` periods, then
falls back to G36, which it runs in shadow every step so it is warm. With ``valve_exercise_s`` set
in the config, the applied action also carries the scheduled primary-valve strokes (recorded as
clamps with their reason; the last safe action stays the unstroked one). The step's applied action,
the next plant state and an FMU checkpoint go to history in one transaction before the applied
action is published; the rows the other agents publish it records too (``recorder.py``: the Sensor is
the only writer of history). A proposal counts only if it names the step and the id of the state this
Sensor published for it; only the control role can publish proposals at all (the router's access
control, docs/mesh.md, Security).

It also hosts the toolbox queryables (``tools/{name}/{role}``, serialized with stepping by the twin's
lock, each limited to ``tools_rate_per_s`` queries a second per asking role after a burst of
``tools_burst``; the what-ifs together to ``whatif_max_running`` at once and
``whatif_plant_minutes_per_min`` plant minutes a wall minute) and the
commands ``cmd/{agent_id}/inject_fault`` and ``cmd/{agent_id}/status``.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, field

from lcmesh.mesh import keys
from lcmesh.mesh.agents.base import Agent
from lcmesh.mesh.agents.recorder import HistoryRecorder
from lcmesh.mesh.agents.twin_host import TwinHost
from lcmesh.mesh.bus import QueryError
from lcmesh.mesh.history import HistoryWriter
from lcmesh.mesh.messages import (
    ActionModel, AppliedAction, CommandReply, FaultRequest, MeshConfig, PlantState, Proposal, utc_now,
)  # fmt: skip
from lcmesh.mesh.ratelimit import TokenBuckets, WorkBudget
from lcmesh.mesh.tools import registry
from lcmesh.mesh.tools.guardrails import Clamp, apply_guardrails
from lcmesh.mesh.tools.maintenance import ValveExercise
from lcmesh.twin.controllers.g36 import G36Controller
from lcmesh.twin.plant import PlantAction

log = logging.getLogger("lcmesh.mesh.agents.sensor")
LARGE_STATE_VALUES = 5_000
LARGE_PAYLOAD_EVERY = 40


class SensorAgent(Agent):
    role = "sensor"
    clock = time.monotonic  # of the tools' rate limits (a test sets its own)

    def __init__(self, settings, agent_id: str | None = None):
        super().__init__(settings, agent_id)
        self.cfg = settings.sensor
        self.twin: TwinHost | None = None
        self.fallback: G36Controller | None = None
        self.last_safe: PlantAction | None = None
        self._window_lock = threading.Lock()
        self._window: _StepWindow | None = None
        self._misses = 0
        self.tally = {"steps": 0, "proposals_applied": 0, "held": 0, "g36_fallback": 0, "rejected": 0,
                      "late_periods": 0, "stale_proposals": 0, "duplicate_proposals": 0, "foreign_proposals": 0,
                      "valve_strokes": 0}  # fmt: skip
        self._exercise: ValveExercise | None = None
        self._exercise_period = 0.0
        self.whatif_budget: WorkBudget | None = None  # the what-ifs' runs and plant minutes, for every asker
        self.recorder: HistoryRecorder | None = None

    # --- lifecycle ------------------------------------------------------------------------------
    def on_start(self) -> None:
        s = self.settings
        self.history = HistoryWriter(s.history_file, retention=s.history)  # the mesh's only writer of it
        self.recorder = HistoryRecorder(self.history)
        self.recorder.start(self)  # first: its own events of the start are recorded too
        self.twin = TwinHost(s.system, s.trace, s.scenario, s.wet_bulb_offset_k, instance_name=self.agent_id)
        self.fallback = G36Controller(self.twin.system)
        self._begin_or_resume()
        if self.stopping:  # told to stop during the spin-up: nothing to serve
            return
        self.watch_config(self._on_config)
        self.subscribe(keys.proposal(self.site, self.cfg.loop), Proposal, self._on_proposal)
        self.serve(keys.cmd(self.site, self.agent_id, "inject_fault"), self._inject_fault)
        self.serve(keys.cmd(self.site, self.agent_id, "status"), self._status)
        self._declare_tools()
        self.spawn("loop", self._loop)

    def on_stop(self) -> None:
        if self.twin is not None:  # the run stays open: the next Sensor resumes it (`lcmesh demo` ends it)
            self.twin.close()
            self.twin = None

    def _begin_or_resume(self) -> None:
        twin = self.twin
        checkpoint = self.history.resumable(twin.system_hash, twin.trace.name) if self.cfg.resume else None
        if checkpoint is not None:
            try:
                self.last_safe = twin.resume(checkpoint)
            except Exception as exc:  # e.g. a checkpoint from another build of the FMU
                log.exception("could not resume run %s", checkpoint.run_id)
                self.emit_event("warning", f"could not resume run {checkpoint.run_id} at step {checkpoint.step} "
                                f"({type(exc).__name__}: {exc}); starting a new run")  # fmt: skip
                self.history.end_run(checkpoint.run_id)
                twin.plant.reset()
            else:
                self.emit_event("started", f"resumed run {twin.run_id} at step {twin.step}")
                return
        first = self.fallback.act(twin.observation()).copy()
        if not twin.begin(first, self.cfg.spinup_hours, stop=self.stop_event):
            log.info("stopped during the twin's spin-up; no run begun")
            return
        self.fallback.reset()
        self.last_safe = first
        self.history.start_run(twin.run_id, twin.system.name, twin.system_hash, twin.trace.name)
        state = twin.state_message(self.agent_id, self.period_s)
        self.history.record_step(None, state, payload=True, checkpoint=twin.checkpoint(first))
        self.emit_event("started", f"new run {twin.run_id} of {twin.system.name} on {twin.trace.name}")

    @property
    def period_s(self) -> float:
        return self.twin.system.step_s / self.config.speed_factor

    def details(self) -> dict:
        twin = self.twin
        return {"step": twin.step if twin else None, "run_id": twin.run_id if twin else None,
                "speed_factor": self.config.speed_factor, "period_s": self.period_s if twin else None,
                "history_rows_recorded": self.recorder.tally if self.recorder else None, **self.tally}  # fmt: skip

    # --- bus callbacks ----------------------------------------------------------------------------
    def _on_config(self, old: MeshConfig, new: MeshConfig) -> None:
        try:
            new.guardrails.check_system(self.twin.system)
        except ValueError as exc:  # the Configuration agent validates too; keep the old limits if not
            log.error("ignoring guardrails of config version %s: %s", self.config_doc.version, exc)
            self.config = new.model_copy(update={"guardrails": old.guardrails})

    def _on_proposal(self, proposal: Proposal) -> None:
        """The first proposal for the open step is decided right here, in the bus callback (no thread hand-off)."""
        with self._window_lock:
            window = self._window
            if window is None or proposal.step != window.state.step:
                self.tally["stale_proposals"] += 1
                return
            if proposal.state_id != window.state.id:  # not decided on the state this Sensor published
                self.tally["foreign_proposals"] += 1
                return
            if window.claimed:
                self.tally["duplicate_proposals"] += 1
                return
            window.claimed = True
        try:
            window.applied = self._decide(window, proposal)
        finally:
            window.done.set()

    def _inject_fault(self, payload: bytes | None) -> CommandReply:
        if not payload:
            raise QueryError('send a FaultRequest JSON, e.g. {"kind": "pump_degradation", "cabinet": 2, "value": 0.5} '
                             "(cabinets, towers and cells numbered from 1)")
        request = FaultRequest.model_validate_json(payload)
        faults = self.twin.inject_fault(request)
        log.info("fault injected: %s", request.model_dump_json())
        self.emit_event("warning", f"twin fault injected at step {self.twin.step}: {request.model_dump_json()}")
        return CommandReply(ok=True, detail=f"{request.kind} applied at step {self.twin.step}", data=faults)

    def _status(self, _payload: bytes | None) -> CommandReply:
        return CommandReply(ok=True, data=self.details())

    # --- toolbox queryables --------------------------------------------------------------------------
    def _declare_tools(self) -> None:
        """Serve the twin's toolbox tools (physics and what-ifs) on ``tools/{name}/{role}``: a token bucket per tool
        and asking role, and one what-if budget for all (checked before a what-if waits for the twin's lock)."""
        cfg = self.cfg
        budget = WorkBudget(cfg.whatif_max_running, cfg.whatif_plant_minutes_per_min, clock=self.clock,
                            setting="LCMESH_SENSOR__WHATIF_PLANT_MINUTES_PER_MIN")  # fmt: skip
        self.whatif_budget = budget
        # invoke holds the twin's lock around each call: a step does not rewrite the outputs a tool reads meanwhile
        context = registry.ToolContext(system=self.twin.system, plant=self.twin.plant, lock=self.twin.lock,
                                       latest_out=self.twin.plant.out, budget=budget)  # fmt: skip
        limit = TokenBuckets(cfg.tools_rate_per_s, cfg.tools_burst, clock=self.clock)
        for name in registry.served_tools(data=False):

            def answer(payload: bytes | None, name=name):
                result = registry.invoke(name, payload or b"{}", context)
                if not result.ok:
                    raise QueryError(result.error)
                return result

            self.serve(keys.tool_served(self.site, name), answer, limit=limit)

    # --- the control loop -------------------------------------------------------------------------------
    def _loop(self) -> None:
        twin = self.twin
        state = twin.state_message(self.agent_id, self.period_s)
        next_tick = time.monotonic()
        while not self.stopping:
            delay = next_tick - time.monotonic()
            if delay > 0 and self.wait(delay):
                break
            period = self.period_s
            late_s = max(0.0, time.monotonic() - next_tick)
            if late_s > 0.5 * period:
                self.tally["late_periods"] += 1
            state = self._one_step(state, period, late_s)
            next_tick = max(next_tick + period, time.monotonic() - period)

    def _one_step(self, state: PlantState, period: float, late_s: float) -> PlantState:
        twin = self.twin
        shadow = self.fallback.act(twin.observation())  # every step, so G36 is warm when it is needed
        window = _StepWindow(state, shadow, late_s)
        state.sent_at, state.period_s = utc_now(), period
        with self._window_lock:
            self._window = window
        window.published = time.perf_counter()
        self.bus.publish(keys.plant_state(self.site), state, latest=True)
        window.done.wait(max(0.0, window.published + self.cfg.deadline_fraction * period - time.perf_counter()))
        with self._window_lock:
            self._window, claimed = None, window.claimed
        if claimed:
            window.done.wait()  # a proposal arrived at the deadline: its decision is finishing
        applied = window.applied or self._decide(window, None)
        twin.advance(applied.action.to_action())
        next_state = twin.state_message(self.agent_id, period)
        checkpoint = twin.checkpoint(self.last_safe) if next_state.step % self.cfg.checkpoint_every_steps == 0 else None
        payload = self._full_payload(next_state.step)
        self.history.record_step(applied, next_state, payload=payload, checkpoint=checkpoint)
        self.bus.publish(keys.applied(self.site, self.cfg.loop), applied, block=True)
        self.history.maintain()  # retention, after the step is out
        self.tally["steps"] += 1
        return next_state

    def _decide(self, window: "_StepWindow", proposal: Proposal | None) -> AppliedAction:
        """Guardrails on the proposal (or manual action); hold or G36 (the window's shadow) when none is usable."""
        twin, cfg, config, state = self.twin, self.cfg, self.config, window.state
        system, limits, wet_bulb_k = twin.system, config.guardrails, state.wet_bulb_k
        source, version, decision_id, reason, rejected, latency = "", "", None, None, None, None
        result = None
        if config.mode == "manual" and config.manual_action is not None:
            candidate, source = config.manual_action.to_action(), "manual"
            version = f"config-v{self.config_doc.version}" if self.config_doc else "settings"
        elif proposal is not None:
            candidate, source, version = proposal.action.to_action(), proposal.controller, proposal.controller_version
            decision_id = proposal.decision_id
        else:
            candidate, reason = None, f"no proposal within {cfg.deadline_fraction * state.period_s * 1e3:.0f} ms"
        if candidate is not None:
            result = apply_guardrails(candidate, self.last_safe, wet_bulb_k, limits, system)
            if result.rejected is not None:
                rejected = f"{source} proposal rejected: {result.rejected}"
                reason, result = rejected, None
                self.tally["rejected"] += 1
        fallback = result is None
        if fallback:
            self._misses += 1
            if self._misses <= cfg.hold_periods:
                result = apply_guardrails(self.last_safe, self.last_safe, wet_bulb_k, limits, system)
                source, version, decision_id = "hold", "1", None
                self.tally["held"] += 1
            else:
                result = apply_guardrails(window.shadow, self.last_safe, wet_bulb_k, limits, system)
                source, version, decision_id = self.fallback.name, self.fallback.version, None
                self.tally["g36_fallback"] += 1
        else:
            self._misses = 0
            if proposal is not None and config.mode != "manual":
                latency = (time.perf_counter() - window.published) * 1e3
                self.tally["proposals_applied"] += 1
        self.last_safe = result.action.copy()
        action, clamps = self._exercise_valves(state.step, result.action, result.clamps)
        return AppliedAction(
            source=self.agent_id, run_id=twin.run_id, loop=cfg.loop, step=state.step, time_s=state.time_s,
            decision_id=decision_id, source_controller=source, source_version=version,
            action=ActionModel.from_action(action), clamps=clamps, fallback=fallback,
            fallback_reason=reason if fallback else None, rejected_reason=rejected, latency_ms=latency,
            late_ms=window.late_s * 1e3,
        )  # fmt: skip

    def _exercise_valves(self, step: int, action: PlantAction, clamps: list) -> tuple[PlantAction, list]:
        """The action with this step's valve strokes (``valve_exercise_s``), each recorded as a clamp."""
        period = self.config.valve_exercise_s
        if period <= 0:
            return action, clamps
        if self._exercise is None or self._exercise_period != period:
            self._exercise = ValveExercise(self.twin.system, period_s=max(period, 4 * self.twin.system.step_s))
            self._exercise_period = period
        stroked, cabinets = self._exercise.stroked(step, action, self.twin.plant.out)
        if not cabinets:
            return action, clamps
        self.tally["valve_strokes"] += len(cabinets)
        extra = [Clamp(field="supply_temp_setpoint_k", index=[c], proposed=float(action.supply_temp_setpoint_k[c]),
                       applied=float(stroked.supply_temp_setpoint_k[c]), reason="valve exercise (maintenance stroke test)")
                 for c in cabinets]  # fmt: skip
        return stroked, [*clamps, *extra]

    def _full_payload(self, step: int) -> bool:
        every = self.cfg.payload_every_steps
        if every is None:
            n_values = sum(v.size for v in self.twin.plant.out.values()) + self.twin.system.n_blade_groups
            every = LARGE_PAYLOAD_EVERY if n_values > LARGE_STATE_VALUES else 1
        return step % every == 0


@dataclass
class _StepWindow:
    """One step's wait for a proposal; whoever claims it (bus callback or deadline) decides the step."""

    state: PlantState
    shadow: PlantAction
    late_s: float
    published: float = 0.0
    claimed: bool = False
    applied: AppliedAction | None = None
    done: threading.Event = field(default_factory=threading.Event)

"""The Maintenance agent: the toolbox's fault detector on every plant state, alerts on the bus.

It feeds each state (and the action applied in the step that led to it) to
``lcmesh.mesh.tools.maintenance.FaultDetector`` and turns its active findings into alerts: one
``raised`` when a (kind, location) finding starts or gets more severe, one ``cleared`` when it
has been absent for ``clear_after_updates`` updates. The Sensor records the alerts in history. A
restarted agent reloads the alerts still active in history (read-only), so it neither repeats nor forgets them.
If the detector module is not installed yet, the agent retries the import every few seconds.
"""

from __future__ import annotations

import importlib
import logging
import math
import threading
import time

from lcmesh.mesh import keys
from lcmesh.mesh.agents.base import Agent, LatestSlot
from lcmesh.mesh.history import HistoryReader
from lcmesh.mesh.messages import Alert, AppliedAction, PlantState, new_id, plant_state_to_observation
from lcmesh.twin.plant import PlantAction
from lcmesh.twin.system import load_system

log = logging.getLogger("lcmesh.mesh.agents.maintenance")
SEVERITY_RANK = {"info": 0, "warning": 1, "critical": 2}
RESTORED_GRACE_UPDATES = 30  # a reloaded alert waits this long for the fresh detector to see it again


class _Active:
    def __init__(self, alert_id: str, severity: str, missing: int = 0):
        self.alert_id, self.severity, self.missing = alert_id, severity, missing


class MaintenanceAgent(Agent):
    role = "maintenance"

    def __init__(self, settings, agent_id: str | None = None):
        super().__init__(settings, agent_id)
        self.cfg = settings.maintenance
        self.system = None
        self.detector = None
        self._next_import = 0.0
        self._slot = LatestSlot()
        self._step_done = threading.Event()
        self._applied: dict[int, PlantAction] = {}
        self._run_id: str | None = None
        self.active: dict[tuple[str, str], _Active] = {}
        self.tally = {"updates": 0, "raised": 0, "cleared": 0, "bad_states": 0}

    def on_start(self) -> None:
        self.system = load_system(self.settings.system)
        self._restore_active_alerts()
        self._load_detector()
        self.subscribe(keys.applied_all(self.site), AppliedAction, self._on_applied)
        self.subscribe(keys.plant_state(self.site), PlantState, self._slot.put, latest=True)
        self.spawn("watch", self._loop)

    def _restore_active_alerts(self) -> None:
        """The alerts still raised in history (read-only: the Sensor records the alerts this agent publishes)."""
        if not self.settings.history_file.exists():
            return
        reader = HistoryReader(self.settings.history_file)
        try:
            rows = reader.alerts(active_only=True, limit=10_000)
        finally:
            reader.close()
        for row in rows:
            self.active[(row["kind"], row["location"])] = _Active(row["alert_id"], row["severity"],
                                                                   -RESTORED_GRACE_UPDATES)  # fmt: skip

    def details(self) -> dict:
        return {"detector": self.detector is not None, "active_alerts": len(self.active), **self.tally}

    def _load_detector(self) -> None:
        if self.detector is not None or time.monotonic() < self._next_import:
            return
        self._next_import = time.monotonic() + self.cfg.detector_poll_s
        try:
            module = importlib.import_module("lcmesh.mesh.tools.maintenance")
        except ImportError as exc:
            log.warning("fault detector not available yet (%s); retrying every %.0f s", exc, self.cfg.detector_poll_s)
            return
        self.detector = module.FaultDetector(self.system)

    def _on_applied(self, applied: AppliedAction) -> None:
        self._applied[applied.step] = applied.action.to_action()
        for step in [s for s in self._applied if s < applied.step - 4]:
            del self._applied[step]
        self._step_done.set()

    def _loop(self) -> None:
        while not self.stopping:
            state = self._slot.take(timeout_s=0.5)
            self._load_detector()
            if state is not None and self.detector is not None:
                # the control loop has the cores first: wait until this step's action is applied
                self._step_done.clear()
                if state.step not in self._applied:
                    self._step_done.wait(timeout=state.period_s)
                try:
                    self._update(state)
                except Exception as exc:  # a detector bug must not take the agent down with it
                    log.exception("detector update failed at step %s", state.step)
                    self._on_handler_error("detector", exc)

    def _update(self, state: PlantState) -> None:
        try:
            obs = plant_state_to_observation(state, self.system)
        except ValueError as exc:
            self.tally["bad_states"] += 1
            log.warning("dropped plant state %s: %s", state.id, exc)
            return
        if state.run_id != self._run_id:
            if self._run_id is not None:
                self.detector.reset()
            self._run_id = state.run_id
        findings = self.detector.update(state.time_s, obs.out, obs.wet_bulb_k, self._applied.get(state.step - 1))
        self.tally["updates"] += 1
        seen = set()
        for finding in findings:
            key = (finding.kind, finding.location)
            seen.add(key)
            known = self.active.get(key)
            if known is None or SEVERITY_RANK[finding.severity] > SEVERITY_RANK.get(known.severity, 0):
                alert_id = known.alert_id if known else new_id()
                self.active[key] = _Active(alert_id, finding.severity)
                self._send(self._alert(alert_id, "raised", finding, state))
            else:
                known.missing = 0
        for key in [k for k in self.active if k not in seen]:
            known = self.active[key]
            known.missing += 1
            if known.missing >= self.cfg.clear_after_updates:
                del self.active[key]
                kind, location = key
                self._send(Alert(source=self.agent_id, alert_id=known.alert_id, state="cleared", kind=kind,
                                 severity="info", location=location, message=f"{kind} at {location} cleared",
                                 step=state.step, time_s=state.time_s))  # fmt: skip

    def _alert(self, alert_id: str, state_word: str, finding, state: PlantState) -> Alert:
        return Alert(
            source=self.agent_id, alert_id=alert_id, state=state_word, kind=finding.kind, severity=finding.severity,
            location=finding.location, message=finding.message, evidence=dict(finding.evidence),
            prescription=finding.prescription, predicted_failure_s=_finite(finding.predicted_failure_s),
            step=state.step, time_s=state.time_s,
        )  # fmt: skip

    def _send(self, alert: Alert) -> None:
        self.bus.publish(keys.alerts(self.site), alert, block=True)
        self.tally["raised" if alert.state == "raised" else "cleared"] += 1
        log.info("alert %s: %s %s %s", alert.state, alert.kind, alert.location, alert.message)


def _finite(value: float | None) -> float | None:
    return value if value is not None and math.isfinite(value) else None

"""The recorded site the chat benchmark replays: a real twin run written to a real history file.

``record_site`` plays the mesh's producers in one process, in the order the bus would give them, and
writes what each writes to history through ``HistoryWriter``:

- Sensor: the twin (``TwinHost``, the Sensor's own host), the guardrails, each step's applied action,
  the next plant state with its payload and the FMU checkpoint, in one transaction;
- Control: the configured controller on each plant state (``build_controller``), the explanation of each
  decision from the toolbox facts and renderer (``decision_facts``, ``explanation_text``);
- Configuration: version 1 (G36, from the settings), then a switch to `controller` partway through;
- Maintenance: the ``FaultDetector`` on every state, raised and cleared alerts as the agent makes them,
  after a twin fault (default: pump degradation on cabinet 3) is injected partway through.

Every id comes from the seed and every timestamp from the site clock (the trace's day at `start_hour`, plus
plant time), so a recording is the same twice; only the wall-clock columns history stamps itself
(``runs.started_at``, ``checkpoints.saved_at``) differ. The run is left open, as a live mesh leaves it.

``open_site`` reads a recording back with the ``PlantData`` shape the chat tools read
(``lcmesh.mesh.tools.plant_data``); ``site_plant`` is a real plant restored from the last checkpoint, for
what-ifs; ``ensure_site`` records once per parameter set into a cache folder and reuses it.
"""

from __future__ import annotations

import hashlib
import inspect
import json
import random
import shutil
import sqlite3
import tempfile
import time
from dataclasses import dataclass, field
from datetime import datetime, timedelta, timezone
from importlib.metadata import version as package_version
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict

from lcmesh.mesh.agents.control import build_controller, decision_facts, explanation_text
from lcmesh.mesh.agents.twin_host import TwinHost
from lcmesh.mesh.history import Checkpoint, HistoryReader, HistoryWriter
from lcmesh.mesh.messages import (
    ActionModel, AgentEvent, Alert, AppliedAction, ConfigDoc, Explanation, FaultRequest, MeshConfig, PlantState,
    plant_state_to_observation,
)  # fmt: skip
from lcmesh.mesh.settings import MaintenanceConfig, SensorConfig
from lcmesh.mesh.tools.guardrails import Clamp, apply_guardrails
from lcmesh.mesh.tools.maintenance import FaultDetector, Finding
from lcmesh.mesh.tools.plant_data import NotReady
from lcmesh.twin.fmu_build import build_hash
from lcmesh.twin.plant import Plant, PlantAction
from lcmesh.twin.system import load_system
from lcmesh.twin.traces import FRONTIER_DAY

SITE_FORMAT = 1  # bump when what a recording holds changes: cached sites of the old format are recorded again
SITE_DAY = datetime(2024, 4, 7, tzinfo=timezone.utc)  # the site clock's day (the Frontier day's) for every trace
FIRST_CONTROLLER = "g36"  # configuration version 1, as LCMESH_* settings would seed it
DEFAULT_FAULT = FaultRequest(kind="pump_degradation", cabinet=3, value=0.5)  # cabinets count from 1
AGENT_ROLES = ("configuration", "control", "maintenance", "monitor", "orchestration", "sensor", "ui")
HISTORY_FILE = "site.sqlite"
SWITCHED_BY = "ui/shift-lead"  # the Configuration agent's `changed_by`: the bus role, then who the UI vouches for
SWITCH_REASON = "commissioning done: hand the loop from G36 to the {controller} policy"
_SPEED_FACTOR = MeshConfig().speed_factor  # the mesh's default: a period is step_s / speed_factor wall seconds


class SiteManifest(BaseModel):
    """What a recording holds: its parameters, the run, when things happened, and row counts."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    format: int
    package_version: str
    key: str  # site_key: the parameters, the package version, the format, the FMU build, the code
    system: str
    system_hash: str
    trace: str  # the trace spec (a day)
    trace_name: str  # the trace as recorded: the day sliced from `start_hour`
    start_step: int  # the trace row of plant step 0
    scenario: str
    start_hour: float
    step_s: float
    controller: str  # asked for
    controller_acting: str  # what ran after the switch (G36 when `controller` could not be built)
    controller_version: str
    controller_note: str | None = None
    seed: int
    minutes: float
    steps: int
    run_id: str
    site_start: datetime  # the site clock at step 0
    site_end: datetime  # ... at the last step
    switch_step: int
    fault: dict[str, Any] | None  # the FaultRequest injected, as the Sensor's inject_fault command takes it
    fault_step: int | None
    fault_at: datetime | None
    config_versions: list[dict[str, Any]]
    alerts: list[dict[str, Any]]  # every alert row: alert_id, state, kind, severity, location, step
    counts: dict[str, int]
    record_wall_s: float


# --- recording -----------------------------------------------------------------------------------------
def record_site(
    path: str | Path,
    *,
    system: str = "lcopt-5",
    minutes: float = 120,
    controller: str = "tree",
    scenario: str = "frontier",
    trace: str = FRONTIER_DAY,
    start_hour: float = 10.0,
    seed: int = 0,
    fault: FaultRequest | None = DEFAULT_FAULT,
    fault_at_min: float | None = None,
    switch_at_min: float | None = None,
    explain_every: int = 1,
) -> SiteManifest:
    """Run the twin for `minutes` of plant time as the mesh would, into a new history file at `path`.

    The configuration starts at G36 and switches to `controller` at `switch_at_min` (default: a quarter
    of the run); `fault` is injected at `fault_at_min` (default: half way; None: no fault). Every
    `explain_every`-th decision gets an explanation. Writes the manifest next to `path` and returns it.
    """
    params = _params(system=system, minutes=minutes, controller=controller, scenario=scenario, trace=trace,
                     start_hour=start_hour, seed=seed, fault=fault, fault_at_min=fault_at_min,
                     switch_at_min=switch_at_min, explain_every=explain_every)  # fmt: skip
    path = Path(path)
    if path.exists():
        raise FileExistsError(f"{path} exists; record a site into a new file (or use ensure_site to reuse one)")
    t0 = time.perf_counter()
    run = _SiteRun(path, params)
    try:
        run.record()
    except BaseException:
        run.close()
        for leftover in (path, path.with_name(path.name + "-wal"), path.with_name(path.name + "-shm")):
            leftover.unlink(missing_ok=True)  # half a site is no site: a retry records into the same path
        raise
    run.close()
    manifest = run.manifest(record_wall_s=time.perf_counter() - t0)
    manifest_path(path).write_text(manifest.model_dump_json(indent=2))
    return manifest


def manifest_path(path: str | Path) -> Path:
    """Where the manifest of the history file `path` lives: ``site.sqlite`` -> ``site.manifest.json``."""
    path = Path(path)
    return path.with_name(path.stem + ".manifest.json")


def load_manifest(path: str | Path) -> SiteManifest:
    """The manifest of the history file `path`."""
    where = manifest_path(path)
    if not where.exists():
        raise FileNotFoundError(f"no site manifest at {where}; record the site with record_site or ensure_site")
    return SiteManifest.model_validate_json(where.read_text())


def _params(**kw) -> dict[str, Any]:
    """The recording parameters checked, with derived defaults filled in (the switch and fault steps)."""
    step_s = load_system(kw["system"]).step_s
    steps = kw["minutes"] * 60.0 / step_s
    if not (steps >= 8 and steps == int(steps)):
        raise ValueError(f"`minutes` must be a whole number of {step_s:g} s steps, at least 8, got {kw['minutes']}")
    if not 0.0 <= kw["start_hour"] < 24.0:
        raise ValueError(f"`start_hour` must be in [0, 24), got {kw['start_hour']}")
    if kw["explain_every"] < 1:
        raise ValueError(f"`explain_every` must be >= 1, got {kw['explain_every']}")
    if kw["fault"] is not None:
        kw["fault"] = FaultRequest.model_validate(kw["fault"])  # a dict from a config file is fine too
    minutes = kw["minutes"]
    for name, default in (("switch_at_min", minutes / 4), ("fault_at_min", minutes / 2)):
        kw[name] = default if kw[name] is None else kw[name]
        if not 0.0 <= kw[name] < minutes:
            raise ValueError(f"`{name}` must be in [0, {minutes}) minutes (the run), got {kw[name]}")
    kw["steps"], kw["step_s"] = int(steps), step_s
    return kw


def site_key(params: dict[str, Any]) -> str:
    """The cache key: a hash of the parameters, the package version, the site format, the FMU build and the code.

    The code (every module and tree artifact of the package) is in it because the version stays put while
    the project changes under it: a recording is cheap, a stale one answers questions with yesterday's numbers.
    """
    plain = {k: (v.model_dump() if isinstance(v, BaseModel) else v) for k, v in params.items()}
    plain.update(package=package_version("lc-mesh"), format=SITE_FORMAT, code=_code_fingerprint(),
                 fmu=build_hash(load_system(params["system"])))  # fmt: skip
    return hashlib.sha256(json.dumps(plain, sort_keys=True, default=str).encode()).hexdigest()


def _code_fingerprint() -> str:
    """A hash of the package's Python modules and distilled trees (what a recording runs)."""
    root = Path(__file__).resolve().parents[1]
    digest = hashlib.sha256()
    for path in sorted([*root.rglob("*.py"), *(root / "artifacts" / "trees").glob("*.json")]):
        digest.update(path.relative_to(root).as_posix().encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()


class _Ids:
    """Ids drawn from the seed (uuid4-sized hex), so two recordings with one seed are the same file."""

    def __init__(self, seed: int):
        self._rng = random.Random(f"lcmesh-chat-site:{seed}")

    def __call__(self) -> str:
        return f"{self._rng.getrandbits(128):032x}"


@dataclass
class _Tally:
    plant_states: int = 0
    actions: int = 0
    explanations: int = 0
    alerts_raised: int = 0
    alerts_cleared: int = 0
    config_changes: int = 0
    agent_events: int = 0
    clamped_actions: int = 0
    held_actions: int = 0


@dataclass
class _Active:
    alert_id: str
    severity: str
    missing: int = 0


@dataclass
class _SiteRun:
    """One recording: the twin, the controller, the detector and the writer, stepped together."""

    path: Path
    params: dict[str, Any]
    tally: _Tally = field(default_factory=_Tally)

    def __post_init__(self) -> None:
        p = self.params
        self.ids = _Ids(p["seed"])
        self.twin = TwinHost(p["system"], p["trace"], p["scenario"], 0.0, instance_name="site-sensor")
        self.start_step = _slice_from(self.twin, p["start_hour"])
        self.system = self.twin.system
        self.period_s = self.system.step_s / _SPEED_FACTOR
        self.start = SITE_DAY + timedelta(hours=p["start_hour"])
        self.writer = HistoryWriter(self.path)
        self.detector = FaultDetector(self.system)
        self.clear_after = MaintenanceConfig().clear_after_updates
        self.active: dict[tuple[str, str], _Active] = {}
        self.alerts: list[dict[str, Any]] = []
        self.config_versions: list[dict[str, Any]] = []
        self.controller, self.controller_note = build_controller(FIRST_CONTROLLER, self.system)
        self.last_safe: PlantAction | None = None
        self.fault_step = round(p["fault_at_min"] * 60.0 / self.system.step_s) if p["fault"] else None
        self.switch_step = round(p["switch_at_min"] * 60.0 / self.system.step_s)

    def clock(self, step: int) -> datetime:
        """The site clock at plant step `step`."""
        return self.start + timedelta(seconds=step * self.system.step_s)

    def close(self) -> None:
        self.writer.close()
        self.twin.close()

    # --- the run -------------------------------------------------------------------------------------
    def record(self) -> None:
        """Configuration v1, the agents' start, step 0 (as the Sensor begins a run), then every step."""
        self._configure(1, FIRST_CONTROLLER, "settings", "initial configuration from LCMESH_* settings",
                        {"*": [None, "initial"]}, step=0)  # fmt: skip
        for role in AGENT_ROLES:
            self._event("started", role, f"{role} agent started", step=0)
        state = self._begin()
        for step in range(self.params["steps"]):
            if step == self.switch_step:
                self._switch_controller(step)
            if step == self.fault_step:
                self._inject_fault(step)
            state = self._one_step(state)

    def _begin(self) -> PlantState:
        """Spin up under G36's first action and write step 0 with its checkpoint, as the Sensor does."""
        twin = self.twin
        first = self.controller.act(twin.observation()).copy()
        twin.begin(first, SensorConfig().spinup_hours)
        self.controller.reset()
        twin.run_id = self.ids()
        self.last_safe = first
        self.writer.start_run(twin.run_id, self.system.name, twin.system_hash, twin.trace.name)
        self._event("started", "sensor", f"new run {twin.run_id} of {self.system.name} on {twin.trace.name}", step=0)
        state = self._state()
        self.writer.record_step(None, state, payload=True, checkpoint=twin.checkpoint(first))
        self._watch(state, None)
        return state

    def _one_step(self, state: PlantState) -> PlantState:
        """Decide, guard, apply and step; record the action, the next state, the checkpoint; explain; watch."""
        obs = plant_state_to_observation(state, self.system)
        previous = self.last_safe.copy() if state.step > 0 else None  # the Control agent has seen no action yet
        proposed = self.controller.act(obs).copy()
        decision_id = self.ids()
        applied = self._guard(state, proposed, decision_id)
        self.twin.advance(applied.action.to_action())
        next_state = self._state()
        self.writer.record_step(applied, next_state, payload=True, checkpoint=self.twin.checkpoint(self.last_safe))
        self.tally.actions += 1
        if state.step % self.params["explain_every"] == 0:
            self._explain(state, obs, proposed, previous, decision_id)
        self._watch(next_state, applied)
        return next_state

    def _state(self) -> PlantState:
        """The Sensor's plant state message of the current step, with a seeded id and the site clock."""
        state = self.twin.state_message("sensor", self.period_s)
        state.id, state.sent_at = self.ids(), self.clock(state.step)
        self.tally.plant_states += 1
        return state

    def _guard(self, state: PlantState, proposed: PlantAction, decision_id: str) -> AppliedAction:
        """The Sensor's guardrails on the proposal; a rejected one holds the last safe action."""
        limits = MeshConfig().guardrails
        result = apply_guardrails(proposed, self.last_safe, state.wet_bulb_k, limits, self.system)
        ctrl = self.controller
        source, version, rejected = ctrl.name, str(ctrl.version), None
        if result.rejected is not None:
            rejected = f"{ctrl.name} proposal rejected: {result.rejected}"
            result = apply_guardrails(self.last_safe, self.last_safe, state.wet_bulb_k, limits, self.system)
            source, version, decision_id = "hold", "1", None
            self.tally.held_actions += 1
        self.tally.clamped_actions += bool(result.clamps)
        self.last_safe = result.action.copy()
        return AppliedAction(
            id=self.ids(), sent_at=self.clock(state.step), source="sensor", run_id=state.run_id, step=state.step,
            time_s=state.time_s, decision_id=decision_id, source_controller=source, source_version=version,
            action=ActionModel.from_action(result.action), clamps=result.clamps, fallback=rejected is not None,
            fallback_reason=rejected, rejected_reason=rejected,
        )  # fmt: skip

    def _explain(self, state: PlantState, obs, proposed: PlantAction, previous: PlantAction | None,
                 decision_id: str) -> None:  # fmt: skip
        """The Control agent's explanation of a decision: toolbox facts, the deterministic renderer."""
        facts = decision_facts(self.controller, self.system, obs, proposed, previous)
        self.writer.add_explanation(Explanation(
            id=self.ids(), sent_at=self.clock(state.step), source="control", decision_id=decision_id,
            step=state.step, controller=self.controller.name, text=explanation_text(facts), facts=facts,
        ))  # fmt: skip
        self.tally.explanations += 1

    # --- configuration, faults, events -------------------------------------------------------------
    def _switch_controller(self, step: int) -> None:
        """Configuration version 2 names `controller`; the Control agent builds it before its next decision."""
        wanted = self.params["controller"]
        self._configure(2, wanted, SWITCHED_BY, SWITCH_REASON.format(controller=wanted),
                        {"controller": [FIRST_CONTROLLER, wanted]}, step=step)  # fmt: skip
        self.controller, self.controller_note = build_controller(wanted, self.system)
        self.controller.reset()
        if self.controller_note:
            self._event("warning", "control", self.controller_note, step=step)

    def _configure(self, version: int, controller: str, by: str, reason: str, changes: dict, *, step: int) -> None:
        doc = ConfigDoc(id=self.ids(), sent_at=self.clock(step), source="configuration", version=version,
                        config=MeshConfig(controller=controller), changed_by=by, reason=reason)  # fmt: skip
        self.writer.add_config_change(doc, changes)
        self.tally.config_changes += 1
        self.config_versions.append({"version": version, "controller": controller, "changed_by": by,
                                     "reason": reason, "step": step, "at": doc.sent_at.isoformat()})  # fmt: skip

    def _inject_fault(self, step: int) -> None:
        """The Sensor's ``inject_fault`` command: the fault acts from this step's advance on."""
        request: FaultRequest = self.params["fault"]
        self.twin.inject_fault(request)
        self._event("warning", "sensor", f"twin fault injected at step {step}: {request.model_dump_json()}", step=step)

    def _event(self, kind: str, role: str, detail: str, *, step: int) -> None:
        self.writer.add_event(AgentEvent(id=self.ids(), sent_at=self.clock(step), source="orchestration", kind=kind,
                                         role=role, agent_id=role, detail=detail))  # fmt: skip
        self.tally.agent_events += 1

    # --- maintenance -----------------------------------------------------------------------------------
    def _watch(self, state: PlantState, applied: AppliedAction | None) -> None:
        """The Maintenance agent's update: raise new or worse findings, clear ones absent long enough."""
        obs = plant_state_to_observation(state, self.system)
        action = applied.action.to_action() if applied is not None else None
        findings = self.detector.update(state.time_s, obs.out, obs.wet_bulb_k, action)
        rank = {"info": 0, "warning": 1, "critical": 2}
        seen = set()
        for finding in findings:
            key = (finding.kind, finding.location)
            seen.add(key)
            known = self.active.get(key)
            if known is None or rank[finding.severity] > rank[known.severity]:
                alert_id = known.alert_id if known else self.ids()
                self.active[key] = _Active(alert_id, finding.severity)
                self._alert(_raised(alert_id, finding, state, self.ids(), self.clock(state.step)))
            else:
                known.missing = 0
        for key in [k for k in self.active if k not in seen]:
            known = self.active[key]
            known.missing += 1
            if known.missing >= self.clear_after:
                del self.active[key]
                kind, location = key
                self._alert(Alert(id=self.ids(), sent_at=self.clock(state.step), source="maintenance",
                                  alert_id=known.alert_id, state="cleared", kind=kind, severity="info",
                                  location=location, message=f"{kind} at {location} cleared", step=state.step,
                                  time_s=state.time_s))  # fmt: skip

    def _alert(self, alert: Alert) -> None:
        self.writer.add_alert(alert)
        self.alerts.append({"alert_id": alert.alert_id, "state": alert.state, "kind": alert.kind,
                            "severity": alert.severity, "location": alert.location, "step": alert.step})  # fmt: skip
        if alert.state == "raised":
            self.tally.alerts_raised += 1
        else:
            self.tally.alerts_cleared += 1

    # --- the manifest ------------------------------------------------------------------------------------
    def manifest(self, record_wall_s: float) -> SiteManifest:
        p, twin = self.params, self.twin
        counts = vars(self.tally) | {"alerts": self.tally.alerts_raised + self.tally.alerts_cleared}
        return SiteManifest(
            format=SITE_FORMAT, package_version=package_version("lc-mesh"), key=site_key(p), system=p["system"],
            system_hash=twin.system_hash, trace=p["trace"], trace_name=twin.trace.name, start_step=self.start_step,
            scenario=p["scenario"], start_hour=p["start_hour"],
            step_s=self.system.step_s, controller=p["controller"], controller_acting=self.controller.name,
            controller_version=str(self.controller.version), controller_note=self.controller_note, seed=p["seed"],
            minutes=p["minutes"], steps=p["steps"], run_id=twin.run_id, site_start=self.clock(0),
            site_end=self.clock(p["steps"]), switch_step=self.switch_step,
            fault=p["fault"].model_dump() if p["fault"] else None, fault_step=self.fault_step,
            fault_at=self.clock(self.fault_step) if self.fault_step is not None else None,
            config_versions=self.config_versions, alerts=self.alerts, counts=counts,
            record_wall_s=round(record_wall_s, 3),
        )  # fmt: skip


def _raised(alert_id: str, finding: Finding, state: PlantState, message_id: str, at: datetime) -> Alert:
    """The Maintenance agent's raised alert for `finding` (non-finite predictions dropped, as JSON has none)."""
    eta = finding.predicted_failure_s
    return Alert(
        id=message_id, sent_at=at, source="maintenance", alert_id=alert_id, state="raised", kind=finding.kind,
        severity=finding.severity, location=finding.location, message=finding.message,
        evidence=dict(finding.evidence), prescription=finding.prescription,
        predicted_failure_s=eta if eta is not None and np.isfinite(eta) else None, step=state.step,
        time_s=state.time_s,
    )  # fmt: skip


# --- the cache ------------------------------------------------------------------------------------------------
def ensure_site(cache_dir: str | Path, **kw) -> Path:
    """The history file of a site recorded with `kw` (record_site's keywords): recorded once, then reused.

    The folder is named by the system, the length and ``site_key``; a recording goes to a temporary
    folder first and is renamed into place whole, so a reader never sees half a site.
    """
    bound = inspect.signature(record_site).bind("-", **kw)
    bound.apply_defaults()
    params = _params(**{k: v for k, v in bound.arguments.items() if k != "path"})
    cache_dir = Path(cache_dir)
    folder = cache_dir / f"{params['system']}-{params['minutes']:g}min-{site_key(params)[:16]}"
    path = folder / HISTORY_FILE
    if manifest_path(path).exists():
        return path
    cache_dir.mkdir(parents=True, exist_ok=True)
    scratch = Path(tempfile.mkdtemp(prefix=f".{folder.name}-", dir=cache_dir))
    try:
        record_site(scratch / HISTORY_FILE, **kw)
        scratch.rename(folder)
    except OSError:
        if not manifest_path(path).exists():  # not a concurrent recording of the same site that won the rename
            raise
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    return path


# --- reading a site back ------------------------------------------------------------------------------------
class SiteData:
    """A recorded site with the ``PlantData`` shape: what the chat tools read, from the file instead of the mesh."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.manifest = load_manifest(self.path)
        self.system = load_system(self.manifest.system)
        self._reader = HistoryReader(self.path)
        self._latest: PlantState | None = None

    def latest_state(self) -> PlantState:
        """The last recorded plant state (with its payload)."""
        if self._latest is None:
            self._latest = self._reader.latest_state(self.manifest.run_id)
        if self._latest is None:
            raise NotReady(f"the site {self.path} holds no plant state with a payload")
        return self._latest

    def history(self) -> HistoryReader:
        return self._reader

    def config(self) -> ConfigDoc | None:
        """The latest recorded configuration version, as the Configuration agent published it."""
        rows = self._reader.config_changes(limit=1)
        if not rows:
            return None
        row = rows[0]
        return ConfigDoc(source="configuration", sent_at=row["created_at"], version=row["version"],
                         config=MeshConfig.model_validate(row["config"]), changed_by=row["changed_by"],
                         reason=row["reason"])  # fmt: skip

    def applied(self) -> AppliedAction | None:
        """The last recorded applied action, as the Sensor published it."""
        rows = self._reader.decisions(limit=1, run_id=self.manifest.run_id)
        if not rows:
            return None
        row = rows[0]
        return AppliedAction(
            source="sensor", sent_at=row["applied_at"], run_id=row["run_id"], step=row["step"], time_s=row["time_s"],
            decision_id=row["decision_id"], source_controller=row["source_controller"],
            source_version=row["source_version"], action=ActionModel.model_validate(row["action"]),
            clamps=[Clamp.model_validate(c) for c in row["clamps"]], fallback=row["fallback"],
            fallback_reason=row["fallback_reason"], rejected_reason=row["rejected_reason"],
            latency_ms=row["latency_ms"], late_ms=row["late_ms"],
        )  # fmt: skip

    def agents(self) -> list[dict]:
        """The seven agents alive since the site started, in the UI's agents-view shape (no live stats)."""
        since = self.manifest.site_start.isoformat()
        return [{"agent_id": role, "role": role, "alive": True, "since": since, "pid": None, "uptime_s": None,
                 "cpu_pct": None, "rss_bytes": None, "msgs_in": 0, "msgs_out": 0, "invalid": 0, "handler_errors": 0,
                 "latency_ms_p99": None, "stats_age_s": None, "advice": []} for role in AGENT_ROLES]  # fmt: skip

    def close(self) -> None:
        self._reader.close()

    def __enter__(self) -> SiteData:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def open_site(path: str | Path) -> SiteData:
    """The recorded site at `path` (its history file), read-only."""
    return SiteData(path)


def site_plant(path: str | Path, instance_name: str = "site-whatif") -> Plant:
    """A real plant where the site's Sensor left it: restored from the last checkpoint, last inputs in place.

    As on the live Sensor's plant, ``plant.out`` is the latest state's outputs and ``plant.inp`` holds the
    last step's load, wet bulb and applied setpoints, so a what-if (``whatif.one_step_whatif``) runs as live.
    """
    manifest = load_manifest(path)
    twin = TwinHost(manifest.system, manifest.trace, manifest.scenario, 0.0, instance_name=instance_name)
    twin.resume(_checkpoint(Path(path), manifest.run_id))  # the checkpoint's FMU state holds the last inputs
    return twin.plant


def _slice_from(twin: TwinHost, start_hour: float) -> int:
    """Start `twin`'s trace at `start_hour` of its day (the rest of the day follows); the row of step 0."""
    start_step = round(start_hour * 3600.0 / twin.system.step_s)
    twin.trace = twin.trace.slice(start_step, twin.trace.n_steps - start_step)
    return start_step


def _checkpoint(path: Path, run_id: str) -> Checkpoint:
    """The run's checkpoint, read-only (``HistoryWriter.resumable`` would open the shared file for writing)."""
    conn = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        row = conn.execute("SELECT run_id, step, fmu_state, sensor_state FROM checkpoints WHERE run_id = ?",
                           (run_id,)).fetchone()  # fmt: skip
    finally:
        conn.close()
    if row is None:
        raise NotReady(f"the site {path} holds no checkpoint of run {run_id}")
    return Checkpoint(row[0], row[1], bytes(row[2]), row[3])


__all__ = [
    "DEFAULT_FAULT", "SiteData", "SiteManifest", "ensure_site", "load_manifest", "manifest_path", "open_site",
    "record_site", "site_key", "site_plant",
]  # fmt: skip

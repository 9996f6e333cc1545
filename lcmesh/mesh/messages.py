"""Messages on the bus: pydantic v2 models, JSON on the wire, SI units inside.

Every message carries ``schema_version``, ``id``, ``sent_at`` (UTC) and ``source`` (the sending
agent's id). Arrays travel as flat JSON lists; their shapes are derived from the system
description (``plant_state_to_observation``), so a message never carries what both ends know.
Non-finite numbers are refused at the edge (``allow_inf_nan=False``).
"""

from __future__ import annotations

import math
import uuid
from datetime import datetime, timezone
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from lcmesh.mesh.settings import NAME_PATTERN, check_valve_exercise_s
from lcmesh.mesh.tools.guardrails import Clamp, GuardrailLimits
from lcmesh.twin.controllers.base import Observation
from lcmesh.twin.plant import PlantAction
from lcmesh.twin.system import SystemDescription

SCHEMA_VERSION = 1


def utc_now() -> datetime:
    return datetime.now(timezone.utc)


def check_finite(value: Any, where: str = "") -> None:
    """ValueError naming the first NaN or infinite number in parsed JSON (``json.loads`` lets them in)."""
    if isinstance(value, float) and not math.isfinite(value):
        raise ValueError(f"`{where or 'value'}` must be a finite number, got {value!r}")
    if isinstance(value, dict):
        for key, item in value.items():
            check_finite(item, f"{where}.{key}" if where else str(key))
    elif isinstance(value, (list, tuple)):
        for i, item in enumerate(value):
            check_finite(item, f"{where}[{i}]")


def new_id() -> str:
    return uuid.uuid4().hex


class Message(BaseModel):
    """The envelope every bus message shares."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    schema_version: Literal[1] = SCHEMA_VERSION
    id: str = Field(default_factory=new_id, min_length=1, max_length=64)
    sent_at: datetime = Field(default_factory=utc_now)
    source: str = Field(pattern=NAME_PATTERN)


class _Part(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


# --- plant state and actions ------------------------------------------------------------------
class PlantState(Message):
    """The twin after `step` steps, and the exogenous inputs of the coming step."""

    system: str
    run_id: str
    step: int = Field(ge=0)
    time_s: float
    wet_bulb_k: float = Field(gt=150, lt=400)
    blade_power_w: list[float]
    outputs: dict[str, list[float]]
    faults_active: bool = False
    period_s: float = Field(gt=0, description="wall seconds per control period at the current speed factor")
    scenario: str = Field("frontier", max_length=64, description="how the trace drives the plant (docs/traces.md, "
                          "Scenarios): whether `wet_bulb_k` is the recorded one or a design day's")
    wet_bulb_offset_k: float = Field(0.0, ge=-100, le=100, description="K added to the trace's wet bulb (the "
                                     "scenario's and LCMESH_WET_BULB_OFFSET_K); `wet_bulb_k` includes it")


class ActionModel(_Part):
    """A PlantAction on the wire: per-cabinet setpoints, valve split (C x B), tower setpoints."""

    supply_temp_setpoint_k: list[float]
    dp_setpoint_pa: list[float]
    valve_fractions: list[list[float]]
    lw_setpoint_k: list[float]

    @classmethod
    def from_action(cls, action: PlantAction) -> "ActionModel":
        return cls(
            supply_temp_setpoint_k=np.asarray(action.supply_temp_setpoint_k, dtype=float).tolist(),
            dp_setpoint_pa=np.asarray(action.dp_setpoint_pa, dtype=float).tolist(),
            valve_fractions=np.asarray(action.valve_fractions, dtype=float).tolist(),
            lw_setpoint_k=np.asarray(action.lw_setpoint_k, dtype=float).tolist(),
        )

    def to_action(self) -> PlantAction:
        """As numpy arrays; ragged valve rows become an object-free (C, 0) array the guardrails reject."""
        rows = self.valve_fractions
        ragged = len({len(r) for r in rows}) > 1
        valves = np.zeros((len(rows), 0)) if ragged else np.asarray(rows, dtype=float).reshape(len(rows), -1)
        return PlantAction(
            np.asarray(self.supply_temp_setpoint_k, dtype=float),
            np.asarray(self.dp_setpoint_pa, dtype=float),
            valves,
            np.asarray(self.lw_setpoint_k, dtype=float),
        )


class FactModel(_Part):
    """A grounding fact behind a decision: a named number (or word) with its unit and a sentence."""

    name: str
    value: float | str | bool | None = None
    unit: str = ""
    text: str = ""
    kind: str = ""


class Proposal(Message):
    """A controller's action for one plant step."""

    decision_id: str = Field(default_factory=new_id)
    loop: str = Field("plant", pattern=NAME_PATTERN)
    step: int = Field(ge=0)
    state_id: str
    controller: str
    controller_version: str
    action: ActionModel
    facts: list[FactModel] = []
    compute_ms: float = Field(0.0, ge=0)


class AppliedAction(Message):
    """What the Sensor applied to the plant for `step`, with its source and audit trail."""

    run_id: str
    loop: str = "plant"
    step: int = Field(ge=0)
    time_s: float
    decision_id: str | None = None
    source_controller: str
    source_version: str
    action: ActionModel
    clamps: list[Clamp] = []
    fallback: bool = False
    fallback_reason: str | None = None
    rejected_reason: str | None = None
    latency_ms: float | None = Field(None, description="plant-state publish to applied action, when a proposal made it")
    late_ms: float = Field(0.0, ge=0, description="how far this period started behind its schedule")


class Explanation(Message):
    """Why a decision was taken: its grounding facts and a plain-language text."""

    decision_id: str
    step: int = Field(ge=0)
    controller: str
    level: str = "facts"
    text: str
    facts: list[FactModel] = []
    written_by: Literal["renderer", "llm"] = Field("renderer", description="who wrote the text: the toolbox's "
                                                   "renderer, or the LLM (its text passed the judge)")
    why_renderer: str = Field("", max_length=200, description="with the LLM explaining: why the rendering was "
                              "published (the judge's reason, a timeout, or no verified claim the rendering lacks)")
    llm_part: Literal["", "whole", "what-if"] = Field("", description="with the LLM's text: 'whole' (it wrote all of "
                                                      "it) or 'what-if' (the rendering, then its WHAT IF section)")


# --- maintenance, monitor, events ---------------------------------------------------------------
class Alert(Message):
    """A maintenance finding starting (``raised``) or ending (``cleared``)."""

    alert_id: str
    state: Literal["raised", "cleared"]
    kind: str
    severity: Literal["info", "warning", "critical"] = "warning"
    location: str = ""
    message: str = ""
    evidence: dict[str, Any] = {}
    prescription: str = ""
    predicted_failure_s: float | None = None
    step: int | None = None
    time_s: float | None = None


class AgentStats(Message):
    """One agent's own view of itself, published every few hundred ms."""

    role: str
    agent_id: str
    pid: int
    host: str
    uptime_s: float
    cpu_pct: float
    rss_bytes: int
    threads: int
    msgs_in: dict[str, int] = {}
    msgs_out: dict[str, int] = {}
    invalid: dict[str, int] = {}
    rate_limited: dict[str, int] = {}  # queries answered "rate limited", per queryable
    handler_errors: int = 0
    latency_ms_p50: float | None = None
    latency_ms_p99: float | None = None
    details: dict[str, Any] = {}


class AgentHealth(_Part):
    agent_id: str
    role: str
    alive: bool
    since: datetime | None = None
    pid: int | None = None
    msgs_in_per_s: float = 0.0
    msgs_out_per_s: float = 0.0
    invalid_total: int = 0
    handler_errors: int = 0
    latency_ms_p50: float | None = None
    latency_ms_p99: float | None = None
    cpu_pct: float | None = None
    rss_bytes: int | None = None
    stats_age_s: float | None = None


class Recommendation(_Part):
    severity: Literal["info", "warning", "critical"]
    agent_id: str | None = None
    text: str


class MonitorReport(Message):
    agents: list[AgentHealth]
    recommendations: list[Recommendation] = []
    fallback_steps_last_minute: int = 0


EventKind = Literal[
    "started", "stopped", "died", "hung", "restarted", "exception", "warning", "skipped", "gave_up", "adopted"
]


class AgentEvent(Message):
    """Something that happened to an agent; the UI lists these."""

    kind: EventKind
    role: str
    agent_id: str
    detail: str = ""
    pid: int | None = None


RECENT_EVENTS = 100  # events an agent keeps for the history's writer to fetch after it (re)starts


class RecentEvents(Message):
    """An agent's latest events, served on ``events/{role}/recent``: what the history's writer (the Sensor)
    fetches when it starts, so events sent while it was down still reach history."""

    events: list[AgentEvent] = Field(default_factory=list, max_length=RECENT_EVENTS)


# --- configuration ---------------------------------------------------------------------------------
class LlmSettings(_Part):
    """Settings of the LLM controller and explainer (used by the LLM issue)."""

    model: str = "smollm2-135m-instruct"
    temperature: float = Field(0.0, ge=0, le=2)
    max_new_tokens: int = Field(256, ge=1, le=4096)
    control_period_steps: int = Field(4, ge=1, description="the LLM controller decides every N plant steps")
    explain: bool = True


class MeshConfig(_Part):
    """What operators change at run time (held, versioned and audited by the Configuration agent)."""

    controller: str = "tree"
    mode: Literal["auto", "manual"] = "auto"
    manual_action: ActionModel | None = None
    speed_factor: float = Field(60.0, gt=0, le=100_000)
    valve_exercise_s: float = Field(0.0, ge=0, le=86_400, description="stroke each CDU primary valve this often, "
                                    "plant seconds (0: off; lets Maintenance find a valve stuck where it would stay)")
    guardrails: GuardrailLimits = GuardrailLimits()
    llm: LlmSettings = LlmSettings()

    _valve_exercise = field_validator("valve_exercise_s")(check_valve_exercise_s)


CONFIG_SECTIONS = ("all", "controller", "mode", "speed_factor", "guardrails", "llm")


class ConfigDoc(Message):
    """One version of the mesh configuration."""

    version: int = Field(ge=1)
    config: MeshConfig
    changed_by: str = ""
    reason: str = ""
    signature: str = Field("", max_length=200, description="the Configuration agent's Ed25519 signature of the "
                           "version and config, base64 (security.config_signed_bytes); agents adopt only a valid one")
    changes: dict[str, Any] = Field(default_factory=dict, description="what this version changed, "
                                    "{dotted field: [old, new]} (history's config_changes row records it)")


class ConfigUpdate(_Part):
    """A change request: a partial MeshConfig (nested dicts merge), who asks and why."""

    changes: dict[str, Any]
    by: str = Field(min_length=1, max_length=64)
    reason: str = ""
    expected_version: int | None = Field(None, description="refuse if the current version differs")

    @field_validator("changes")
    @classmethod
    def _finite(cls, value: dict[str, Any]) -> dict[str, Any]:  # `Any` is not checked by allow_inf_nan
        check_finite(value, "changes")
        return value


# --- commands --------------------------------------------------------------------------------------
FaultKind = Literal["pump_degradation", "valve_stuck", "cell_out", "sensor_bias", "clear"]


class FaultRequest(_Part):
    """Inject a twin fault: pump degradation / valve stuck / sensor bias per cabinet, cell out per tower cell.

    A person writes these, so cabinets, towers and cells count from 1, as alerts name them (``cabinet_2``).
    """

    kind: FaultKind
    cabinet: int | None = Field(None, ge=1, description="1-based")
    tower: int | None = Field(None, ge=1, description="1-based")
    cell: int | None = Field(None, ge=1, description="1-based, within the tower")
    value: float = Field(1.0, description="degradation 0..0.95, bias in K, 1/0 for stuck and out")


class CommandReply(_Part):
    ok: bool
    detail: str = ""
    data: dict[str, Any] = {}


# --- conversions ------------------------------------------------------------------------------------
_SHAPES: dict[int, tuple[SystemDescription, dict[str, tuple[int, ...]]]] = {}


def output_shapes(system: SystemDescription) -> dict[str, tuple[int, ...]]:
    """Shapes of the output blocks of `system`'s generated FMU (cached per description object)."""
    cached = _SHAPES.get(id(system))
    if cached is None or cached[0] is not system:
        from lcmesh.twin.fmu_layout import build_layout

        cached = (system, {b.name: tuple(b.shape) for b in build_layout(system).blocks})
        _SHAPES[id(system)] = cached
    return cached[1]


def plant_state_from_outputs(
    out: dict[str, np.ndarray], *, source: str, system: SystemDescription, run_id: str, step: int,
    time_s: float, wet_bulb_k: float, blade_power_w: np.ndarray, period_s: float, faults_active: bool = False,
    scenario: str = "frontier", wet_bulb_offset_k: float = 0.0,
) -> PlantState:  # fmt: skip
    """The PlantState message for plant outputs `out` (``Plant.out``) and the coming step's inputs."""
    return PlantState.model_construct(
        schema_version=SCHEMA_VERSION, id=new_id(), sent_at=utc_now(), source=source, system=system.name,
        run_id=run_id, step=step, time_s=float(time_s), wet_bulb_k=float(wet_bulb_k),
        blade_power_w=np.asarray(blade_power_w, dtype=float).tolist(),
        outputs={name: np.asarray(value, dtype=float).ravel().tolist() for name, value in out.items()},
        faults_active=faults_active, period_s=float(period_s), scenario=scenario,
        wet_bulb_offset_k=float(wet_bulb_offset_k),
    )  # fmt: skip


def plant_state_to_observation(msg: PlantState, system: SystemDescription) -> Observation:
    """A controller Observation from a PlantState; a block of the wrong size raises ValueError naming it."""
    if msg.system != system.name:
        raise ValueError(f"plant state is for system {msg.system!r}, this agent runs {system.name!r}")
    shapes = output_shapes(system)
    out: dict[str, np.ndarray] = {}
    for name, values in msg.outputs.items():
        shape = shapes.get(name)
        if shape is None:
            raise ValueError(f"`outputs.{name}` is not an output block of {system.name}")
        array = np.asarray(values, dtype=float)
        size = int(np.prod(shape)) if shape else 1
        if array.size != size:
            raise ValueError(f"`outputs.{name}` must hold {size} values for shape {shape}, got {array.size}")
        out[name] = array.reshape(shape)
    power = np.asarray(msg.blade_power_w, dtype=float)
    if power.size != system.n_blade_groups:
        raise ValueError(f"`blade_power_w` must hold {system.n_blade_groups} values, got {power.size}")
    return Observation(out=out, wet_bulb_k=msg.wet_bulb_k, blade_power_w=power, time_s=msg.time_s)


def observation_to_plant_state(
    obs: Observation, system: SystemDescription, *, source: str, run_id: str, step: int, period_s: float
) -> PlantState:
    """The reverse of `plant_state_to_observation`."""
    return plant_state_from_outputs(
        dict(obs.out), source=source, system=system, run_id=run_id, step=step, time_s=obs.time_s,
        wet_bulb_k=obs.wet_bulb_k, blade_power_w=obs.blade_power_w, period_s=period_s,
    )  # fmt: skip

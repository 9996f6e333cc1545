"""Request and response bodies of the REST API (pydantic; they make the OpenAPI document).

Units at this edge are the operator's: °C, kW, psi, fractions; cabinets, branches and towers
count from 1. Inside the mesh everything stays SI.
"""

from __future__ import annotations

import typing
from typing import Annotated, Any, Literal

from pydantic import (
    AwareDatetime, BaseModel, BeforeValidator, ConfigDict, Field, create_model, field_validator, model_validator,
)  # fmt: skip

from lcmesh.assistant.facts import ChatFact
from lcmesh.mesh.messages import MeshConfig
from lcmesh.twin.controllers import NEEDS_PLANT, PLUGIN_PATTERN, REGISTRY, is_plugin, mesh_refusal


def _integer(value: object) -> object:
    """JSON Schema's integer: 3 and 3.0, not 3.5, "3" or true (strict pydantic refuses 3.0, lax accepts "3")."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (isinstance(value, float)
                                                                         and not value.is_integer()):  # fmt: skip
        raise ValueError("must be an integer")
    return int(value)


def json_int(*constraints: Any) -> Any:
    """An integer as JSON Schema has it, with `constraints` (``Field(ge=1)``; before the validator, so the schema shows
    them)."""
    return Annotated[(int, *constraints, BeforeValidator(_integer))]


class _In(BaseModel):
    """A request body: unknown fields, non-finite numbers and loose types (``true`` for 1) refused."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True)


# --- errors ---------------------------------------------------------------------------------------
class FieldError(BaseModel):
    loc: list[str]
    msg: str
    type: str


class ErrorAnswer(BaseModel):
    """Every error: `detail` names the field and says what would be valid; 422s from validation add `errors`."""

    detail: str
    errors: list[FieldError] | None = Field(None, description="422 from request validation: one item per problem")


def _header(description: str) -> dict:
    return {"description": description, "schema": {"type": "string"}}


ERRORS: dict[int, dict[str, Any]] = {
    400: {"description": "the body is not valid JSON text (UTF-8)"},
    401: {"description": "missing or wrong bearer token", "headers": {"WWW-Authenticate": _header("Bearer")}},
    404: {"description": "no such cabinet, tower or run; `detail` gives the valid range"},
    409: {"description": "`expected_version` (or a chat proposal's `proposal.config_version`) is not the current "
               "version"},
    410: {"description": "a chat proposal older than LCMESH_UI_PROPOSAL_MAX_AGE_S: ask the chat again"},
    413: {"description": "the request body is larger than 256 KiB"},
    422: {"description": "invalid input; `detail` names the field and says what would be valid"},
    429: {"description": "too many questions, or a tool over its rate limit or the what-if budget; retry after "
               "`Retry-After` seconds",
          "headers": {"Retry-After": _header("seconds to wait")}},
    503: {"description": "the mesh is not ready; `detail` says why",
          "headers": {"Retry-After": _header("seconds to wait")}},
}  # fmt: skip


def errors(*codes: int) -> dict[int | str, dict[str, Any]]:
    """OpenAPI `responses` for the error `codes` of a route, all with the ErrorAnswer body."""
    return {code: {"model": ErrorAnswer, **ERRORS[code]} for code in codes}


# --- reads ----------------------------------------------------------------------------------------
class Health(BaseModel):
    status: Literal["ok", "degraded", "starting"] = Field(
        description="ok; degraded: it answers, but something is missing or old (`reasons`), e.g. the Sensor is "
        "down; starting: no plant state or history yet"
    )
    ready: bool = Field(description="the data endpoints can answer (a plant state and the history file are there)")
    reasons: list[str]
    sensor_alive: bool = Field(description="the Sensor agent's liveliness token is present")
    agent_id: str
    site: str
    system: str
    uptime_s: float
    plant_step: int | None
    plant_state_age_s: float | None
    history: bool
    config_version: int | None
    live_clients: int
    chat_phraser: str = Field(description="template, or llm:<model> once the LLM backend is loaded")


class CabinetView(BaseModel):
    cabinet: int
    blade_temps_c: list[float]
    blade_temp_max_c: float
    branch_temps_c: list[float]
    branch_power_kw: list[float]
    valve_fractions: list[float]
    supply_temp_c: float = Field(description="the twin's coolant supply temperature")
    supply_temp_measured_c: float = Field(description="the supply as the CDU's sensor reads it (what its valve "
                                          "loop holds at `supply_setpoint_c`; a sensor bias shows here)")
    supply_setpoint_c: float
    return_temp_c: float
    secondary_flow_kg_s: float
    dp_psi: float
    dp_setpoint_psi: float
    pump_power_kw: float
    cdu_heat_kw: float


class TowerView(BaseModel):
    tower: int
    leaving_temp_c: float
    leaving_setpoint_c: float
    entering_temp_c: float
    approach_k: float
    fan_speed: float
    cells_active: float
    fan_power_kw: float
    pump_power_kw: float


class StateView(BaseModel):
    """The latest plant state in operator units."""

    system: str
    run_id: str
    step: int
    time_s: float
    sent_at: str
    period_s: float
    faults_active: bool
    wet_bulb_c: float = Field(description="the wet bulb the plant runs on, any scenario offset included")
    scenario: str = Field(description="how the trace drives the plant: frontier, design-day, lcopt (docs/traces.md)")
    wet_bulb_offset_k: float = Field(description="K added to the trace's wet bulb (the scenario's plus "
                                     "LCMESH_WET_BULB_OFFSET_K)")
    wet_bulb_note: str | None = Field(description="where the wet bulb comes from when it is not the recorded one, "
                                      "e.g. 'recorded + 15 K, scenario lcopt'; null when it is")
    totals: dict[str, float | None] = Field(
        description="plant totals in kW, °C and %, and `cooling_pue`: (IT + tower fans + pumps) / IT, null with no "
        "IT load"
    )
    cabinets: list[CabinetView]
    towers: list[TowerView]
    controller: dict[str, Any] | None = Field(
        description="who decided the last applied action; for a controller that falls back (the LLM) `decided_by` "
        "gives the LLM's share of decisions, the fallback's reasons and the decision period in force; with the LLM "
        "explaining, `explained_by` gives its share of the published explanations and why the rendering stood in")


class HistoryAnswer(BaseModel):
    run_id: str | None
    fields: list[str]
    units: dict[str, str]
    start_step: int = Field(description="first step of the range asked (every bound given applies)")
    end_step: int | None = Field(description="last step of the range asked; null: up to the newest")
    every: int
    rows: list[dict[str, float | int | None]]


class AgentView(BaseModel):
    agent_id: str
    role: str
    alive: bool
    since: str | None
    pid: int | None
    uptime_s: float | None
    cpu_pct: float | None
    rss_bytes: int | None
    msgs_in: int
    msgs_out: int
    invalid: int
    handler_errors: int
    latency_ms_p99: float | None
    stats_age_s: float | None
    advice: list[str]


class AgentsAnswer(BaseModel):
    agents: list[AgentView]
    recommendations: list[dict[str, Any]]
    fallback_steps_last_minute: int | None


class ActionView(BaseModel):
    """An applied action in operator units."""

    supply_temp_setpoint_c: list[float]
    dp_setpoint_psi: list[float]
    valve_fractions: list[list[float]]
    lw_setpoint_c: list[float]


class DecisionRow(BaseModel):
    model_config = ConfigDict(extra="allow")

    step: int
    time_s: float
    decision_id: str | None
    source_controller: str
    source_version: str
    fallback: bool
    fallback_reason: str | None
    rejected_reason: str | None
    clamps: list[dict[str, Any]] = Field(description="what the guardrails changed: `field`, `index` (counted from "
                                         "1: [cabinet], [cabinet, branch] or [tower]), `proposed`, `applied` (SI), "
                                         "`reason`")
    latency_ms: float | None
    action: ActionView
    changes: list[str] | None = Field(description="what this action changed from the decision before, as the page "
                                      "shows it ('cabinet 3 branch 2 valve 0.31 → 0.36'); [] nothing visible; "
                                      "null: no earlier decision known")
    explanation: str | None
    explanation_written_by: Literal["renderer", "llm"] | None = Field(
        None, description="who wrote the explanation's text: the toolbox's renderer, or the LLM (it passed the judge)")
    explanation_why_renderer: str | None = Field(None, description="with the LLM explaining: why the rendering was "
                                                 "published instead of its text")
    explanation_llm_part: str | None = Field(None, description="with the LLM's text: 'whole', or 'what-if' (the "
                                             "rendering, then the LLM's WHAT IF section)")


class DecisionsAnswer(BaseModel):
    source: Literal["history", "memory"] = Field(description="history: the SQLite file; memory: what the UI saw")
    decisions: list[DecisionRow]


class AlertRow(BaseModel):
    model_config = ConfigDict(extra="allow")

    alert_id: str
    state: Literal["raised", "cleared"]
    kind: str
    severity: Literal["info", "warning", "critical"]
    location: str
    message: str
    evidence: dict[str, Any]
    prescription: str
    predicted_failure_s: float | None
    step: int | None
    time_s: float | None
    source: str


class AlertsAnswer(BaseModel):
    source: Literal["history", "memory"]
    alerts: list[AlertRow]


def _strict_copy(model: type[BaseModel], *, partial: bool) -> type[BaseModel]:
    """`model` with strict types and, if `partial`, nothing required (nested sections alike): what may merge into it.

    A section (a field whose type is a model) is partial too, since nested dicts merge; a field that
    is a model or null (``manual_action``) is replaced whole, so its copy keeps every field required.
    Rules between fields stay with the model itself (the Configuration agent checks the merged document).
    """
    fields: dict[str, Any] = {}
    for name, info in model.model_fields.items():
        annotation, metadata = info.annotation, info.metadata
        args = typing.get_args(annotation)
        if annotation is int:
            annotation, metadata = json_int(*info.metadata), []
        elif isinstance(annotation, type) and issubclass(annotation, BaseModel):
            annotation = _strict_copy(annotation, partial=partial)
        elif type(None) in args and any(isinstance(a, type) and issubclass(a, BaseModel) for a in args):
            annotation = typing.Union[tuple(_strict_copy(a, partial=False) if isinstance(a, type) and
                                            issubclass(a, BaseModel) else a for a in args)]  # fmt: skip
        typed = Annotated[(annotation, *metadata)] if metadata else annotation
        default = Field(None, description=info.description) if partial else Field(description=info.description)
        fields[name] = (typed, default)
    return create_model(f"{model.__name__}{'Change' if partial else 'Whole'}", __doc__=model.__doc__,
                        __config__=_In.model_config, **fields)  # fmt: skip


MeshConfigChange = _strict_copy(MeshConfig, partial=True)


class ConfigChange(_In):
    """A partial configuration (nested dicts merge), why, and optionally the version it was based on."""

    changes: MeshConfigChange = Field(  # type: ignore[valid-type]
        description="a partial configuration, e.g. {\"guardrails\": {\"supply_temp_max_k\": 310.15}}"
    )
    reason: str = Field("", max_length=500)
    expected_version: json_int(Field(ge=1, le=2**53)) | None = Field(  # type: ignore[valid-type]
        None, description="refuse (409) if the configuration moved on"
    )


def _at_least_one(*fields: str) -> dict:
    """JSON Schema: at least one of `fields` present and not null (what the model validator checks)."""
    return {"anyOf": [{"required": [f], "properties": {f: {"not": {"type": "null"}}}} for f in fields]}


MODE_FIELDS = ("controller", "mode")
MESH_CONTROLLERS = tuple(sorted(set(REGISTRY) - NEEDS_PLANT))


def controller_schema() -> dict:
    """JSON Schema of a controller name in the mesh: a registered one it runs, or a 'package.module:Class'."""
    registered = {"type": "string", "enum": list(MESH_CONTROLLERS)}
    return {"anyOf": [registered, {"type": "string", "pattern": PLUGIN_PATTERN}]}


class ModeRequest(_In):
    """Switch the controller and/or auto / manual mode."""

    model_config = ConfigDict(json_schema_extra=_at_least_one(*MODE_FIELDS))

    controller: str | None = Field(
        None, description="a registered controller the mesh runs, or a third-party 'package.module:Class' listed in "
        "LCMESH_CONTROLLER_PLUGINS (the Configuration agent checks the list)",
        json_schema_extra={"anyOf": [*controller_schema()["anyOf"], {"type": "null"}]},
    )  # fmt: skip
    mode: Literal["auto", "manual"] | None = Field(None, description="manual holds the current action unless "
                                                   "setpoints are sent to /api/control/setpoints")  # fmt: skip
    reason: str = Field("", max_length=500)
    proposal: ProposalStamp | None = Field(None, description="set by a chat proposal: refused once it has aged")

    @field_validator("controller", mode="before")
    @classmethod
    def _known(cls, value: object) -> object:
        if isinstance(value, str):  # a plugin's allow-list is the Configuration agent's to check (422 from there)
            problem = mesh_refusal(value, allowed_plugins=(value,) if is_plugin(value) else ())
            if problem is not None:
                raise ValueError(problem)
        return value

    @model_validator(mode="after")
    def _something(self) -> "ModeRequest":
        if self.controller is None and self.mode is None:
            raise ValueError("give `controller`, `mode` or both")
        return self


# Wide bounds that catch typos (and keep non-finite numbers out); the guardrails clamp further to the configured
# limits. The OpenAPI document adds this site's counts (a list holds one value per cabinet, tower or branch).
TEMP_C_MAX, PSI_MAX = 80.0, 100.0
TempC = Annotated[float, Field(ge=0, le=TEMP_C_MAX)]
Psi = Annotated[float, Field(ge=0, le=PSI_MAX)]
Fraction = Annotated[float, Field(ge=0, le=1)]
SETPOINT_FIELDS = ("supply_temp_setpoint_c", "dp_setpoint_psi", "lw_setpoint_c", "valve_fractions")


class ProposalStamp(_In):
    """Where a chat proposal's body came from: the configuration version it was made on, and when (UTC).

    Confirming it after the configuration moved on is refused (409), after ``LCMESH_UI_PROPOSAL_MAX_AGE_S``
    (5 min) too (410): its per-cabinet setpoints were read from the plant at `made_at`.
    """

    config_version: json_int(Field(ge=1, le=2**53)) | None = Field(  # type: ignore[valid-type]
        None, description="the configuration version the proposal was made on (none: no configuration yet)"
    )
    made_at: AwareDatetime = Field(strict=False, description="when the chat made it, ISO 8601 with a time zone")

    @field_validator("made_at", mode="before")
    @classmethod
    def _iso_text(cls, value: Any) -> Any:
        """The schema's date-time is a text: a number (pydantic would read Unix seconds) is refused (422)."""
        if not isinstance(value, str):
            raise ValueError(f"`made_at` must be ISO 8601 text with a time zone (2026-11-27T10:00:00+00:00), "
                             f"got {type(value).__name__}")
        return value


class SetpointsRequest(_In):
    """Manual setpoints in operator units; a scalar applies to every selected cabinet (or tower)."""

    model_config = ConfigDict(json_schema_extra=_at_least_one(*SETPOINT_FIELDS))

    supply_temp_setpoint_c: TempC | list[TempC] | None = Field(None, description="°C, one for the selected "
                                                               "cabinets or one per cabinet")  # fmt: skip
    dp_setpoint_psi: Psi | list[Psi] | None = Field(None, description="psi, one or one per cabinet")
    lw_setpoint_c: TempC | list[TempC] | None = Field(None, description="°C, one for every tower or one per tower")
    valve_fractions: list[Fraction] | list[list[Fraction]] | None = Field(
        None, description="one split (a fraction per branch) for the selected cabinets, or one row per cabinet; the "
        "guardrails raise fractions below v_min and rescale each row to sum to 1 (reported in `clamps_expected`)"
    )
    cabinets: list[json_int(Field(ge=1))] | None = Field(  # type: ignore[valid-type]
        None, description="1-based cabinets a scalar or single split applies to (default: all)"
    )
    reason: str = Field("", max_length=500)
    proposal: ProposalStamp | None = Field(None, description="set by a chat proposal: refused once it has aged")

    @model_validator(mode="after")
    def _something(self) -> "SetpointsRequest":
        if all(getattr(self, f) is None for f in SETPOINT_FIELDS):
            raise ValueError(f"give at least one of {', '.join(f'`{f}`' for f in SETPOINT_FIELDS)}")
        return self


class ControlAnswer(BaseModel):
    ok: bool
    config_version: int
    controller: str
    mode: str
    manual_action: dict[str, Any] | None = None
    clamps_expected: list[dict[str, Any]] = Field([], description="the clamps the guardrails will apply, as "
                                                  "/api/decisions lists them (`index` counted from 1)")
    detail: str = ""


class ChatQuestion(_In):
    message: str = Field(min_length=1, description="the operator's question (plain text; never executed; at most "
                         "LCMESH_UI_CHAT_MAX_CHARS characters)")  # fmt: skip
    session: str | None = Field(None, min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_-]+$",
                                description="a chat session id of the client's choosing: a follow-up (\"and cabinet "
                                "2?\", \"why?\") reads the previous question of the same session; sessions hold the "
                                "last question only and expire (LCMESH_UI_CHAT_SESSION_S)")  # fmt: skip


class ChatToolCall(BaseModel):
    tool: str = Field(description="a tool of the registry served on tools/* (see docs/ui.md, The assistant)")
    args: dict[str, Any]


class ChatProblem(BaseModel):
    kind: str = Field(description="ungrounded_number (a number no fact holds, or given for the wrong entity or "
                                  "quantity), wrong_ranking or wrong_direction: the flag names of every check "
                                  "(lcmesh.mesh.tools.claims.FLAG_KINDS)")
    span: str
    detail: str


class ChatAnswer(BaseModel):
    answer: str
    facts: list[ChatFact]
    intent: str = Field(description="the first tool called, or 'refuse' when no tool answers the question")
    proposed_command: dict[str, Any] | None = None
    phrased_by: str
    phrasing_note: str | None = None
    grounded: bool = Field(description="true only for an answer written from tool results that passed the semantic "
                           "guard; refusals and tool errors are never grounded")
    elapsed_ms: float
    plan: list[ChatToolCall] = []
    planned_by: str = Field("rules", description="llm, openai or rules (the regex fallback)")
    plan_note: str | None = None
    refused: bool = False
    declined: bool = Field(False, description="the question asks for something the results do not give (energy, not "
                           "power; a gap, not a value; blade groups, not cabinets; where or when ...): the answer "
                           "says so and offers what it found as what it can give instead; never grounded")
    missing: list[str] = Field([], description="what the question asks for that the results do not give")
    problems: list[ChatProblem] = []
    lang: str = "en"
    query: dict[str, Any] | None = Field(None, description="the typed reading of the question the calls follow from "
                                         "(asks, lang, follow_up; lcmesh/assistant/query.py), follow-ups resolved")
    session: str | None = None
    follow_up: bool = Field(False, description="the question was read as continuing the session's previous one")
    detail: list[dict[str, str]] = Field([], description="longer texts the answer leads with the start of (a "
                                         "decision's whole reasoning): {title, text}, shown one click away")

"""Request and response bodies of the REST API (pydantic; they make the OpenAPI document).

Units at this edge are the operator's: °C, kW, psi, fractions; cabinets, branches and towers
count from 1. Inside the mesh everything stays SI.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from lcmesh.mesh.agents.ui.facts import ChatFact


class _In(BaseModel):
    model_config = ConfigDict(extra="forbid")


class Health(BaseModel):
    status: Literal["ok", "degraded", "starting"]
    ready: bool
    reasons: list[str]
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
    supply_temp_c: float
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
    wet_bulb_c: float
    totals: dict[str, float]
    cabinets: list[CabinetView]
    towers: list[TowerView]
    controller: dict[str, Any] | None


class HistoryAnswer(BaseModel):
    run_id: str | None
    fields: list[str]
    units: dict[str, str]
    every: int
    rows: list[dict[str, float | int | None]]


class ConfigChange(_In):
    """A partial configuration (nested dicts merge), why, and optionally the version it was based on."""

    changes: dict[str, Any] = Field(description="e.g. {\"guardrails\": {\"supply_temp_max_k\": 310.15}}")
    reason: str = Field("", max_length=500)
    expected_version: int | None = Field(None, ge=1, description="refuse (409) if the configuration moved on")


class ModeRequest(_In):
    """Switch the controller and/or auto / manual mode."""

    controller: str | None = Field(None, min_length=1, max_length=64, description="g36, tree, ppo, static, llm")
    mode: Literal["auto", "manual"] | None = Field(None, description="manual holds the current action unless "
                                                   "setpoints are sent to /api/control/setpoints")  # fmt: skip
    reason: str = Field("", max_length=500)

    @model_validator(mode="after")
    def _something(self) -> "ModeRequest":
        if self.controller is None and self.mode is None:
            raise ValueError("give `controller`, `mode` or both")
        return self


PerCabinet = float | list[float]


class SetpointsRequest(_In):
    """Manual setpoints in operator units; a scalar applies to every selected cabinet (or tower)."""

    supply_temp_setpoint_c: PerCabinet | None = None
    dp_setpoint_psi: PerCabinet | None = None
    lw_setpoint_c: PerCabinet | None = None
    valve_fractions: list[float] | list[list[float]] | None = Field(
        None, description="one split for the selected cabinets, or one row per cabinet; each row sums to 1"
    )
    cabinets: list[int] | None = Field(None, description="1-based cabinets a scalar or single split applies to")
    reason: str = Field("", max_length=500)

    @model_validator(mode="after")
    def _something(self) -> "SetpointsRequest":
        if all(v is None for v in (self.supply_temp_setpoint_c, self.dp_setpoint_psi, self.lw_setpoint_c,
                                   self.valve_fractions)):  # fmt: skip
            raise ValueError("give at least one of `supply_temp_setpoint_c`, `dp_setpoint_psi`, `lw_setpoint_c`, "
                             "`valve_fractions`")  # fmt: skip
        return self


class ControlAnswer(BaseModel):
    ok: bool
    config_version: int
    controller: str
    mode: str
    manual_action: dict[str, Any] | None = None
    clamps_expected: list[dict[str, Any]] = []
    detail: str = ""


class ChatQuestion(_In):
    message: str = Field(min_length=1, description="the operator's question (plain text; never executed)")


class ChatAnswer(BaseModel):
    answer: str
    facts: list[ChatFact]
    intent: str
    proposed_command: dict[str, Any] | None = None
    phrased_by: str
    phrasing_note: str | None = None
    grounded: bool
    elapsed_ms: float

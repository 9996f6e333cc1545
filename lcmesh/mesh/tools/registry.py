"""The toolbox as named tools with pydantic requests and responses (hosted as ``lcmesh/{site}/tools/{name}``).

``invoke(name, payload, context)`` validates the payload, calls the tool and returns a `ToolResult`: either
``ok`` with the response as JSON-ready data, or an error that names the field and what would be valid. It
never raises for bad input, so a bus callback can answer every query. Non-finite numbers (NaN, Infinity)
are refused wherever they sit in a request. A what-if (a tool with `plant_minutes`) runs only within the
context's `budget` (``ratelimit.WorkBudget``), checked before it waits for the twin's lock; over it, the
result carries `retry_after_s`. Equations: docs/toolbox.md.
"""

from __future__ import annotations

import contextlib
import difflib
import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from lcmesh.mesh.messages import check_finite
from lcmesh.mesh.ratelimit import RateLimited, WorkBudget
from lcmesh.mesh.tools import operations, plant_data, stats, thermo
from lcmesh.twin.system import SystemDescription

if TYPE_CHECKING:  # the twin (and fmpy) load only where a tool runs it
    from lcmesh.twin.plant import Plant


@dataclass
class ToolContext:
    """What a tool may use: the system, optionally the live twin (and the lock guarding it), the latest outputs."""

    system: SystemDescription
    plant: Plant | None = None
    lock: Any = None  # a threading.RLock held around every call (the twin's, on the Sensor); tools take it again
    latest_out: Mapping[str, np.ndarray] | None = None
    data: Any = None  # a plant_data.PlantData (state, history, config): the operator's tools read it
    budget: WorkBudget | None = None  # what-ifs at once and plant minutes per wall minute, for every asker together



class ToolError(ValueError):
    """A well-formed request this context cannot answer (no plant, an index out of range, ...)."""


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


@dataclass(frozen=True)
class ToolSpec:
    """A named tool: its request and response models, the function that answers, and for a what-if the plant
    minutes a request costs on the twin (`plant_minutes`, spent from ``ToolContext.budget``)."""

    name: str
    description: str
    request_model: type[BaseModel]
    response_model: type[BaseModel]
    call: Callable[[Any, ToolContext], BaseModel] = field(repr=False)
    plant_minutes: Callable[[Any, SystemDescription], float] | None = field(default=None, repr=False)


class ToolResult(BaseModel):
    """The answer to one tool query, as it goes on the wire."""

    ok: bool
    tool: str
    result: dict[str, Any] | None = None
    error: str | None = None
    not_ready: bool = False  # the data the tool needs has not arrived yet (retry later), not a bad request
    retry_after_s: float | None = None  # over the what-if budget: nothing ran; ask again after this long


# --- heat_balance -----------------------------------------------------------------------------------
class HeatBalanceRequest(_Model):
    """Q = m_dot c_p dT from a flow and a temperature difference, or a cabinet's CDU balance from the latest outputs."""

    mass_flow_kg_s: float | None = Field(None, ge=0, le=1e5)
    delta_t_k: float | None = Field(None, ge=-200, le=200)
    cp_j_kg_k: float = Field(thermo.CP_WATER_J_KG_K, gt=0, le=1e5)
    cabinet: int | None = Field(None, ge=0, description="zero-based; uses the latest plant outputs")

    @model_validator(mode="after")
    def _one_mode(self) -> "HeatBalanceRequest":
        explicit = self.mass_flow_kg_s is not None or self.delta_t_k is not None
        if explicit == (self.cabinet is not None):
            raise ValueError("give either `mass_flow_kg_s` and `delta_t_k`, or `cabinet`")
        if explicit and (self.mass_flow_kg_s is None or self.delta_t_k is None):
            raise ValueError("`mass_flow_kg_s` and `delta_t_k` go together; give both")
        return self


class HeatBalanceResponse(_Model):
    heat_w: float
    equation: str
    cdu_heat_w: float | None = None
    branch_heat_w: float | None = None
    residual_w: float | None = None
    residual_pct: float | None = None
    implied_supply_temp_k: float | None = None
    supply_residual_k: float | None = None


def _heat_balance(req: HeatBalanceRequest, ctx: ToolContext) -> HeatBalanceResponse:
    if req.cabinet is None:
        q = float(thermo.heat_flow_w(req.mass_flow_kg_s, req.delta_t_k, req.cp_j_kg_k))
        return HeatBalanceResponse(heat_w=q, equation=f"Q = m_dot c_p dT = {req.mass_flow_kg_s:g} kg/s x "
                                   f"{req.cp_j_kg_k:g} J/(kg K) x {req.delta_t_k:g} K = {q:,.0f} W")  # fmt: skip
    out = _latest(ctx)
    _check_index("cabinet", req.cabinet, ctx.system.cabinets.count)
    b = thermo.cdu_heat_balance(out, req.cabinet, ctx.system)
    return HeatBalanceResponse(
        heat_w=b.cdu_heat_w, equation="residual = sum_j P_j (1 + a P_j / P_unit) - Q_cdu (steady state)",
        cdu_heat_w=b.cdu_heat_w, branch_heat_w=b.branch_heat_w, residual_w=b.residual_w,
        residual_pct=_finite(b.residual_pct), implied_supply_temp_k=b.implied_supply_temp_k,
        supply_residual_k=b.supply_residual_k,
    )  # fmt: skip


# --- hx_effectiveness ---------------------------------------------------------------------------------
class HxEffectivenessRequest(_Model):
    """Counter-flow effectiveness from the four terminal temperatures, or from NTU and the capacity ratio."""

    hot_in_k: float | None = Field(None, gt=0, lt=1000)
    hot_out_k: float | None = Field(None, gt=0, lt=1000)
    cold_in_k: float | None = Field(None, gt=0, lt=1000)
    cold_out_k: float | None = Field(None, gt=0, lt=1000)
    ntu: float | None = Field(None, ge=0, le=1000)
    capacity_ratio: float | None = Field(None, ge=0, le=1)

    @model_validator(mode="after")
    def _one_mode(self) -> "HxEffectivenessRequest":
        temps = [self.hot_in_k, self.hot_out_k, self.cold_in_k, self.cold_out_k]
        by_temps = all(t is not None for t in temps)
        by_ntu = self.ntu is not None and self.capacity_ratio is not None
        if by_temps == by_ntu:
            raise ValueError("give either all four of `hot_in_k`, `hot_out_k`, `cold_in_k`, `cold_out_k`, "
                             "or `ntu` and `capacity_ratio`")  # fmt: skip
        if by_temps and self.hot_in_k <= self.cold_in_k:
            raise ValueError(f"`hot_in_k` ({self.hot_in_k}) must be above `cold_in_k` ({self.cold_in_k})")
        return self


class HxEffectivenessResponse(_Model):
    effectiveness: float
    method: Literal["temperatures", "ntu"]
    equation: str


def _hx_effectiveness(req: HxEffectivenessRequest, ctx: ToolContext) -> HxEffectivenessResponse:
    if req.ntu is not None:
        eps = float(thermo.counterflow_effectiveness(req.ntu, req.capacity_ratio))
        return HxEffectivenessResponse(effectiveness=eps, method="ntu",
                                       equation="eps = (1 - e) / (1 - Cr e), e = exp(-NTU (1 - Cr))")  # fmt: skip
    eps = float(thermo.effectiveness_from_temperatures_k(req.hot_in_k, req.hot_out_k, req.cold_in_k, req.cold_out_k))
    return HxEffectivenessResponse(effectiveness=eps, method="temperatures",
                                   equation="eps = max(dT_hot, dT_cold) / (T_hot,in - T_cold,in)")  # fmt: skip


# --- approach -------------------------------------------------------------------------------------------
class ApproachRequest(_Model):
    """Tower approach (and range) from temperatures, or a tower's from the latest outputs."""

    leaving_water_k: float | None = Field(None, gt=200, lt=400)
    wet_bulb_k: float | None = Field(None, gt=200, lt=400)
    entering_water_k: float | None = Field(None, gt=200, lt=400)
    tower: int | None = Field(None, ge=0, description="zero-based; uses the latest plant outputs")

    @model_validator(mode="after")
    def _one_mode(self) -> "ApproachRequest":
        explicit = self.leaving_water_k is not None and self.wet_bulb_k is not None
        if explicit == (self.tower is not None):
            raise ValueError("give either `leaving_water_k` and `wet_bulb_k`, or `tower`")
        return self


class ApproachResponse(_Model):
    approach_k: float
    range_k: float | None = None
    leaving_water_k: float
    equation: str = "approach = T_leaving_water - T_wet_bulb; range = T_entering_water - T_leaving_water"


def _approach(req: ApproachRequest, ctx: ToolContext) -> ApproachResponse:
    if req.tower is None:
        rng = None if req.entering_water_k is None else float(thermo.range_k(req.entering_water_k, req.leaving_water_k))
        return ApproachResponse(approach_k=float(thermo.approach_k(req.leaving_water_k, req.wet_bulb_k)),
                                range_k=rng, leaving_water_k=req.leaving_water_k)  # fmt: skip
    out = _latest(ctx)
    _check_index("tower", req.tower, ctx.system.towers.count)
    lw = float(out["ct_leaving_temp_k"][req.tower])
    return ApproachResponse(approach_k=float(out["approach_k"][req.tower]), leaving_water_k=lw,
                            range_k=float(thermo.range_k(out["ct_entering_temp_k"][req.tower], lw)))  # fmt: skip


# --- affinity -------------------------------------------------------------------------------------------
class AffinityRequest(_Model):
    """Scale a pump or fan operating point to another speed (same impeller, same system curve)."""

    machine: Literal["pump", "fan"]
    speed_from: float = Field(gt=0, le=2, description="fraction of nominal speed")
    speed_to: float = Field(ge=0, le=2)
    flow: float = Field(ge=0, description="any flow unit (kg/s, m^3/s); returned in the same unit")
    head: float = Field(0.0, ge=0, description="pump head (m or Pa) or fan pressure (Pa)")
    power_w: float = Field(0.0, ge=0)


class AffinityResponse(_Model):
    speed_ratio: float
    flow: float
    head: float
    power_w: float
    equation: str = "Q2 = Q1 (n2/n1), H2 = H1 (n2/n1)^2, P2 = P1 (n2/n1)^3"


def _affinity(req: AffinityRequest, ctx: ToolContext) -> AffinityResponse:
    law = thermo.pump_affinity if req.machine == "pump" else thermo.fan_affinity
    p = law(req.speed_from, req.speed_to, req.flow, req.head, req.power_w)
    return AffinityResponse(speed_ratio=req.speed_to / req.speed_from, flow=p.flow, head=p.head, power_w=p.power_w)


# --- tower_power ----------------------------------------------------------------------------------------
class TowerPowerRequest(_Model):
    """Fan power one tower needs to reject a heat load at an approach (the twin's tower model)."""

    heat_w: float = Field(ge=0, le=1e9)
    approach_k: float = Field(gt=0, le=40)
    wet_bulb_k: float = Field(gt=223.15, lt=323.15)
    cells_active: int | None = Field(None, ge=1, description="default: every cell of a tower")


class TowerPowerResponse(_Model):
    fan_speed: float
    fan_power_w: float
    reachable: bool
    approach_at_full_speed_k: float
    heat_per_cell_w: float
    cells_active: int
    equation: str = "air = beta Q_cell / (Q_design (T_app - alpha)); P = cells P_nom air^3"


def _tower_power(req: TowerPowerRequest, ctx: ToolContext) -> TowerPowerResponse:
    cells = req.cells_active or ctx.system.towers.cells
    if cells > ctx.system.towers.cells:
        raise ToolError(f"`cells_active` must be <= {ctx.system.towers.cells} (cells per tower), got {cells}")
    est = thermo.tower_fan_power_w(ctx.system, req.heat_w, req.approach_k, req.wet_bulb_k, cells)
    return TowerPowerResponse(fan_speed=est.fan_speed, fan_power_w=est.fan_power_w, reachable=est.reachable,
                              approach_at_full_speed_k=est.approach_at_full_speed_k,
                              heat_per_cell_w=est.heat_per_cell_w, cells_active=cells)  # fmt: skip


# --- confidence_interval --------------------------------------------------------------------------------
class ConfidenceIntervalRequest(_Model):
    """Interval of the mean (t or bootstrap) or the central range of history samples."""

    samples: list[float] = Field(min_length=2, max_length=200_000)
    confidence: float = Field(0.95, gt=0.5, lt=1.0)
    method: Literal["t", "bootstrap", "percentile"] = "t"


class ConfidenceIntervalResponse(_Model):
    estimate: float
    low: float
    high: float
    confidence: float
    n: int
    method: str


def _confidence_interval(req: ConfidenceIntervalRequest, ctx: ToolContext) -> ConfidenceIntervalResponse:
    fn = {"t": stats.mean_confidence_interval, "bootstrap": stats.bootstrap_interval,
          "percentile": stats.percentile_range}[req.method]  # fmt: skip
    iv = fn(req.samples, req.confidence)
    return ConfidenceIntervalResponse(estimate=iv.estimate, low=iv.low, high=iv.high, confidence=iv.confidence,
                                      n=iv.n, method=iv.method)  # fmt: skip


# --- whatif ---------------------------------------------------------------------------------------------
class WhatIfRequest(_Model):
    """Setpoint changes to try on the live twin for `steps` control steps (load and weather held)."""

    supply_temp_setpoint_delta_k: float = Field(0.0, ge=-20, le=20)
    dp_setpoint_delta_pa: float = Field(0.0, ge=-200_000, le=200_000)
    lw_setpoint_delta_k: float = Field(0.0, ge=-20, le=20)
    valve_fractions: list[list[float]] | None = Field(None, description="full C x B split to try (rows sum to 1)")
    cabinets: list[int] | None = Field(None, description="zero-based; the setpoint deltas apply to these (default all)")
    steps: int = Field(4, ge=1, le=240, description="15 s steps to look ahead (4 = 1 min)")


class WhatIfResponse(_Model):
    horizon_steps: int
    horizon_s: float
    action: dict[str, list]
    baseline: dict[str, Any]
    predicted: dict[str, Any]
    delta: dict[str, Any]


def _whatif(req: WhatIfRequest, ctx: ToolContext) -> WhatIfResponse:
    from lcmesh.mesh.tools import whatif

    if ctx.plant is None:
        raise ToolError("`whatif` needs the live twin, and this context has none; ask the agent that runs the plant")
    s = ctx.system
    C, B = s.cabinets.count, s.cabinets.branches
    cabinets = list(range(C)) if req.cabinets is None else req.cabinets
    for n, i in enumerate(cabinets):
        _check_index(f"cabinets[{n}]", i, C)
    mask = np.zeros(C)
    mask[cabinets] = 1.0
    delta: dict[str, Any] = {"supply_temp_setpoint_k": req.supply_temp_setpoint_delta_k * mask,
                             "dp_setpoint_pa": req.dp_setpoint_delta_pa * mask,
                             "lw_setpoint_k": req.lw_setpoint_delta_k}  # fmt: skip
    with ctx.lock if ctx.lock is not None else contextlib.nullcontext():
        base = whatif.current_action(ctx.plant)
        if req.valve_fractions is not None:
            split = np.asarray(req.valve_fractions, dtype=float)
            if split.shape != (C, B) or np.any(split < 0) or not np.allclose(split.sum(axis=1), 1.0, atol=1e-6):
                raise ToolError(f"`valve_fractions` must be {C} rows of {B} fractions >= 0 summing to 1, "
                                f"got shape {split.shape}")  # fmt: skip
            delta["valve_fractions"] = split - base.valve_fractions
        r = whatif.one_step_whatif(ctx.plant, delta, steps=req.steps, baseline=base)

    def js(d: dict) -> dict:
        return {k: np.asarray(v).tolist() for k, v in d.items()}

    return WhatIfResponse(horizon_steps=r["horizon_steps"], horizon_s=r["horizon_s"], action=js(r["action"]),
                          baseline=js(r["baseline"]), predicted=js(r["predicted"]), delta=js(r["delta"]))  # fmt: skip


# --- registry and invocation -----------------------------------------------------------------------------
def _horizon_min(minutes: float, system: SystemDescription) -> float:
    """The plant minutes a look-ahead of `minutes` runs: whole steps, as the what-if tools round them."""
    from lcmesh.mesh.tools.whatif import MAX_WHATIF_STEPS

    steps = min(MAX_WHATIF_STEPS, max(1, round(minutes * 60.0 / system.step_s)))
    return steps * system.step_s / 60.0


# what a what-if request costs on the twin, spent from ToolContext.budget
PLANT_MINUTES: dict[str, Callable[[Any, SystemDescription], float]] = {
    "whatif": lambda req, system: req.steps * system.step_s / 60.0,
    "whatif_setpoint": lambda req, system: _horizon_min(req.minutes, system),
    "whatif_controller": lambda req, system: 2 * _horizon_min(req.minutes, system),  # two courses
}

TOOLS: dict[str, ToolSpec] = {
    spec.name: spec
    for spec in (
        ToolSpec("heat_balance", "Heat carried by a coolant stream (Q = m_dot c_p dT) or a cabinet's CDU heat "
                 "balance residual", HeatBalanceRequest, HeatBalanceResponse, _heat_balance),
        ToolSpec("hx_effectiveness", "Counter-flow heat-exchanger effectiveness from temperatures or NTU",
                 HxEffectivenessRequest, HxEffectivenessResponse, _hx_effectiveness),
        ToolSpec("approach", "Cooling-tower approach and range", ApproachRequest, ApproachResponse, _approach),
        ToolSpec("affinity", "Pump or fan affinity laws: flow ~ n, head ~ n^2, power ~ n^3",
                 AffinityRequest, AffinityResponse, _affinity),
        ToolSpec("tower_power", "Tower fan speed and power to reject a heat load at an approach",
                 TowerPowerRequest, TowerPowerResponse, _tower_power),
        ToolSpec("confidence_interval", "Confidence interval (t, bootstrap) or central range of samples",
                 ConfidenceIntervalRequest, ConfidenceIntervalResponse, _confidence_interval),
        ToolSpec("whatif", "Predicted plant outputs after a setpoint change vs holding the current setpoints, on "
                 "the live twin (restored afterwards)", WhatIfRequest, WhatIfResponse, _whatif,
                 PLANT_MINUTES["whatif"]),
    )
}  # fmt: skip
TOOLS.update({name: ToolSpec(name, description, request, response, call, PLANT_MINUTES.get(name))
              for name, description, request, response, call in (*plant_data.DATA_TOOLS, *operations.OPERATION_TOOLS)
              })  # fmt: skip


DATA_TOOLS = tuple(name for name, *_ in (*plant_data.DATA_TOOLS, *operations.OPERATION_TOOLS)
                   if name not in plant_data.PLANT_TOOLS)  # fmt: skip


def served_tools(*, data: bool) -> list[str]:
    """The tools a host serves on the bus: the twin's host the physics and what-if tools, the UI the data tools."""
    return [name for name in TOOLS if (name in DATA_TOOLS) == data]


def invoke(name: str, payload: Mapping[str, Any] | str | bytes | None, context: ToolContext) -> ToolResult:
    """Validate `payload` for tool `name`, call it, and wrap the answer or a clear error; never raises on input."""
    spec = TOOLS.get(name)
    if spec is None:
        close = difflib.get_close_matches(name, TOOLS, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        return ToolResult(ok=False, tool=name, error=f"unknown tool {name!r}{hint} (known: {', '.join(TOOLS)})")
    try:
        if isinstance(payload, (str, bytes)):
            payload = json.loads(payload or "{}")
        if payload is not None and not isinstance(payload, Mapping):  # `[]` or `0` are not "no arguments"
            return ToolResult(ok=False, tool=name, error=f"the request must be a JSON object of {name}'s arguments "
                              f"(or empty for the defaults), got {type(payload).__name__}")
        check_finite(payload)
        request = spec.request_model.model_validate(payload or {})
    except json.JSONDecodeError as exc:
        return ToolResult(ok=False, tool=name, error=f"the request is not valid JSON: {exc}")
    except ValidationError as exc:
        return ToolResult(ok=False, tool=name, error=format_validation_error(exc, spec.request_model))
    except ValueError as exc:
        return ToolResult(ok=False, tool=name, error=f"invalid {spec.request_model.__name__}: {exc}")
    try:
        budget = context.budget if spec.plant_minutes is not None else None
        with (budget.run(spec.plant_minutes(request, context.system)) if budget else contextlib.nullcontext(),
              context.lock if context.lock is not None else contextlib.nullcontext()):  # fmt: skip
            response = spec.call(request, context)
    except RateLimited as exc:
        return ToolResult(ok=False, tool=name, error=str(exc), retry_after_s=exc.retry_after_s)
    except (ToolError, ValueError) as exc:
        return ToolResult(ok=False, tool=name, error=str(exc))
    except (plant_data.NotReady, FileNotFoundError) as exc:
        return ToolResult(ok=False, tool=name, error=str(exc), not_ready=True)
    return ToolResult(ok=True, tool=name, result=response.model_dump(mode="json", exclude_none=True))


def catalog() -> list[dict[str, Any]]:
    """Every tool with its description and JSON schemas (for the bus, the UI and LLM prompts)."""
    return [{"name": s.name, "description": s.description, "request": s.request_model.model_json_schema(),
             "response": s.response_model.model_json_schema()} for s in TOOLS.values()]  # fmt: skip


def format_validation_error(exc: ValidationError, model: type[BaseModel]) -> str:
    """One line per problem: "`field`: message (got value)"; unknown fields suggest the closest known one."""
    lines = []
    for err in exc.errors():
        loc = ".".join(f"[{p}]" if isinstance(p, int) else str(p) for p in err["loc"]).replace(".[", "[")
        msg = err["msg"].removeprefix("Value error, ")
        if err["type"] == "extra_forbidden":
            close = difflib.get_close_matches(str(err["loc"][-1]), model.model_fields, n=1)
            msg += f"; did you mean {close[0]!r}?" if close else f"; valid fields: {', '.join(model.model_fields)}"
        elif "input" in err and err["type"] not in ("missing", "model_type") and not isinstance(err["input"], dict):
            msg += f" (got {err['input']!r})"
        lines.append(f"`{loc}`: {msg}" if loc else msg)
    return f"invalid {model.__name__}: " + "; ".join(lines)


def _latest(ctx: ToolContext) -> Mapping[str, np.ndarray]:
    if ctx.latest_out is None:
        raise ToolError("no plant outputs yet in this context; give explicit values instead of an index")
    return ctx.latest_out


def _check_index(name: str, value: int, count: int) -> None:
    if not 0 <= value < count:
        raise ToolError(f"`{name}` must be in [0, {count - 1}] (zero-based), got {value}")


def _finite(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None

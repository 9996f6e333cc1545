"""Read endpoints: health, state, history, agents, decisions, alerts, config, metrics and the page."""

from __future__ import annotations

import difflib
import math
import re
import time
from typing import Annotated

from fastapi import APIRouter, HTTPException, Query, Request
from fastapi.responses import FileResponse, JSONResponse, Response
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

from lcmesh.assistant.sources import NotReady
from lcmesh.mesh.agents.ui.schemas import (
    AgentsAnswer, AlertsAnswer, CabinetView, DecisionsAnswer, Health, HistoryAnswer, StateView, TowerView, errors,
)  # fmt: skip
from lcmesh.mesh.agents.ui.views import action_changes, action_view, c, clamp_view, kw
from lcmesh.mesh.history import STATE_FIELDS
from lcmesh.mesh.messages import ActionModel, ConfigDoc

router = APIRouter()
DEFAULT_WINDOW_S = 3600.0
# Bounds of plant time and steps a query may name: far beyond any run (1e9 s is 31 years, 1e9 steps of 15 s 475
# years) and far inside SQLite's 64-bit integers, so every number that passes is one the database can compare.
MAX_PLANT_S = 1e9
MAX_STEP = 1_000_000_000


def _ctx(request: Request):
    return request.app.state.ctx


@router.get("/", include_in_schema=False)
async def page(request: Request) -> FileResponse:
    """The web page (its CSP and frame headers come from ``app.SecurityHeaders``, as on every answer)."""
    from lcmesh.mesh.agents.ui.app import STATIC_DIR

    return FileResponse(STATIC_DIR / "index.html")


@router.get("/api/health", response_model=Health, tags=["read"])
def health(request: Request) -> Health:
    """Liveness and readiness: always 200 while the UI runs; `status` degraded while the Sensor is down.

    `ready` says whether the data endpoints can answer; `reasons` what is missing or old.
    """
    ctx = _ctx(request)
    reasons = []
    state = ctx.store.state
    if state is None:
        reasons.append("no plant state received yet (Sensor agent not running?)")
    sensors = [a for a in ctx.store.agents_view() if a["role"] == "sensor"]
    sensor_alive = any(a["alive"] for a in sensors)
    if not sensor_alive:
        reasons.append("the Sensor agent is down: its liveliness token is gone" if sensors else
                       "no Sensor agent seen on the bus (no liveliness token)")  # fmt: skip
    try:
        ctx.history()
        history = True
    except (NotReady, FileNotFoundError):
        history = False
        reasons.append("history file not there yet")
    doc = ctx.config_doc()
    if doc is None:
        reasons.append("no configuration seen yet (Configuration agent not running?)")
    age = ctx.store.state_age_s()
    if age is not None and state is not None and age > max(10.0, 20 * state.period_s):
        reasons.append(f"the latest plant state is {age:.0f} s old")
    ready = state is not None and history
    status = "ok" if not reasons else "degraded" if ready else "starting"
    return Health(status=status, ready=ready, reasons=reasons, sensor_alive=sensor_alive, agent_id=ctx.agent_id,
                  site=ctx.settings.site, system=ctx.system.name, uptime_s=round(time.monotonic() - ctx.started_at, 3),
                  plant_step=state.step if state else None, plant_state_age_s=None if age is None else round(age, 3),
                  history=history, config_version=doc.version if doc else None, live_clients=ctx.hub.clients,
                  chat_phraser=ctx.chat.phraser.name)  # fmt: skip


@router.get("/api/state", tags=["read"], response_class=Response,
            responses={200: {"model": StateView, "description": "the latest plant state"}, **errors(503)})  # fmt: skip
async def state(request: Request) -> Response:
    """The latest plant state in °C, kW, psi (prepared once per state, so this is cheap)."""
    data = request.app.state.ctx.store.view_json
    if data is None:
        raise NotReady("no plant state has arrived yet from the Sensor agent (is it running?)")
    return Response(data, media_type="application/json")


def _view(request: Request) -> dict:
    view = _ctx(request).store.view
    if view is None:
        raise NotReady("no plant state has arrived yet from the Sensor agent (is it running?)")
    return view


@router.get("/api/state/cabinets/{cabinet}", response_model=CabinetView, tags=["read"],
            responses=errors(404, 422, 503))
def cabinet_state(request: Request, cabinet: int) -> dict:
    """One cabinet (numbered from 1) of the latest state."""
    view = _view(request)
    n = len(view["cabinets"])
    if not 1 <= cabinet <= n:
        raise HTTPException(404, f"cabinet {cabinet} does not exist; {view['system']} has cabinets 1..{n}")
    return view["cabinets"][cabinet - 1]


@router.get("/api/state/towers/{tower}", response_model=TowerView, tags=["read"],
            responses=errors(404, 422, 503))
def tower_state(request: Request, tower: int) -> dict:
    """One cooling tower (numbered from 1) of the latest state."""
    view = _view(request)
    n = len(view["towers"])
    if not 1 <= tower <= n:
        raise HTTPException(404, f"tower {tower} does not exist; {view['system']} has towers 1..{n}")
    return view["towers"][tower - 1]


def _ui_name(field: str) -> str:
    """History column to API field name: ``_k`` -> ``_c`` (°C), ``_w`` -> ``_kw``."""
    return field[:-2] + "_c" if field.endswith("_k") else field[:-2] + "_kw" if field.endswith("_w") else field


UI_FIELDS = {_ui_name(f): f for f in STATE_FIELDS}
UNITS = {name: "degC" if name.endswith("_c") else "kW" if name.endswith("_kw") else "%" for name in UI_FIELDS}


def _convert(field: str, value: float | None) -> float | None:
    if value is None:
        return None
    return c(value) if field.endswith("_k") else kw(value) if field.endswith("_w") else round(float(value), 3)


def _names_pattern(names) -> str:
    one = "(?:" + "|".join(re.escape(n) for n in names) + ")"
    return f"^(?:{one}(?:,{one})*)?$"


FIELDS_PATTERN = _names_pattern([*UI_FIELDS, *STATE_FIELDS])
Step = Annotated[int | None, Query(ge=0, le=MAX_STEP)]


@router.get("/api/history", response_model=HistoryAnswer, tags=["read"], responses=errors(404, 422, 503))
def history(
    request: Request,
    fields: Annotated[str | None, Query(description=f"comma-separated without spaces, default all: "
                                                    f"{', '.join(UI_FIELDS)}",
                                        json_schema_extra={"pattern": FIELDS_PATTERN})] = None,
    last_s: Annotated[float | None, Query(gt=0, le=MAX_PLANT_S, allow_inf_nan=False,
                                          description="plant seconds before the newest state (default 3600 when "
                                                      "no other bound is given)")] = None,
    start_s: Annotated[float | None, Query(ge=0, le=MAX_PLANT_S, allow_inf_nan=False,
                                           description="plant time from (s into the run)")] = None,
    end_s: Annotated[float | None, Query(ge=0, le=MAX_PLANT_S, allow_inf_nan=False,
                                         description="plant time to (s into the run)")] = None,
    start_step: Step = None,
    end_step: Step = None,
    max_points: Annotated[int, Query(ge=2, le=200_000, description="rows at most; longer ranges are decimated")] = 1000,
    run_id: Annotated[str | None, Query(max_length=64, description="default: the newest run")] = None,
) -> dict:
    """Plant summaries over a range in °C, kW and %: step, time_s and the selected fields.

    Every bound given applies (`last_s`, `start_s`/`end_s`, `start_step`/`end_step` narrow the same
    range); an empty range answers no rows.
    """
    ctx = _ctx(request)
    selected = _fields(fields)
    reader = ctx.history()
    runs = {r["run_id"] for r in reader.runs()}
    if run_id is not None and run_id not in runs:
        raise HTTPException(404, f"run {run_id!r} is not in the history; known runs: {', '.join(sorted(runs)) or 'none'}")
    run = run_id or reader.latest_run_id()
    if run is None:
        raise NotReady("the history holds no run yet")
    step_s = ctx.system.step_s
    first, last = start_step or 0, end_step
    if start_s is not None:
        first = max(first, math.ceil(start_s / step_s))
    if end_s is not None:
        last = _min(last, math.floor(end_s / step_s))
    if last_s is not None or all(v is None for v in (start_s, end_s, start_step, end_step)):
        newest = _newest_step(ctx, reader, run)
        first, last = max(first, newest - int(round((last_s or DEFAULT_WINDOW_S) / step_s))), _min(last, newest)
    columns = [UI_FIELDS[name] for name in selected]
    rows, every = [], 1
    if last is None or last >= first:
        span = (last if last is not None else _newest_step(ctx, reader, run)) - first + 1
        points = min(max_points, ctx.ui.history_max_points)
        every = max(1, math.ceil(span / points))
        rows = reader.states(start_step=first, end_step=last, fields=columns, run_id=run, every=every, limit=points)
    return {"run_id": run, "fields": selected, "units": {name: UNITS[name] for name in selected}, "start_step": first,
            "end_step": last, "every": every,
            "rows": [{"step": r["step"], "time_s": r["time_s"],
                      **{name: _convert(col, r[col]) for name, col in zip(selected, columns)}} for r in rows]}  # fmt: skip


def _min(a: int | None, b: int) -> int:
    return b if a is None else min(a, b)


def _fields(text: str | None) -> list[str]:
    """API field names from a comma list (history column names are accepted too); exactly FIELDS_PATTERN."""
    if not text:
        return list(UI_FIELDS)
    out = []
    for name in text.split(","):
        name = _ui_name(name) if name in STATE_FIELDS else name
        if name not in UI_FIELDS:
            close = difflib.get_close_matches(name.strip(), UI_FIELDS, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise HTTPException(422, f"`fields`: unknown field {name[:60]!r}{hint}; a comma list without spaces of "
                                     f"{', '.join(UI_FIELDS)}")  # fmt: skip
        if name not in out:
            out.append(name)
    return out


def _newest_step(ctx, reader, run: str) -> int:
    state = ctx.store.state
    if state is not None and state.run_id == run:
        return state.step
    latest = reader.latest_state(run)
    return latest.step if latest is not None else 0


@router.get("/api/agents", response_model=AgentsAnswer, tags=["read"])
def agents(request: Request) -> dict:
    """Every agent seen on the bus: liveliness, CPU, memory, message counts, and the Agent Monitor's advice."""
    ctx = _ctx(request)
    report = ctx.store.monitor
    return {"agents": ctx.store.agents_view(),
            "recommendations": [r.model_dump() for r in report.recommendations] if report else [],
            "fallback_steps_last_minute": report.fallback_steps_last_minute if report else None}  # fmt: skip


def _decision_rows(rows: list[dict], limit: int) -> list[dict]:
    """History rows (newest first) in operator units, each with what it changed from the row after it (the one
    before in time; null for the oldest when no earlier row was read) and its clamps counted from 1."""
    actions = [action_view(ActionModel.model_validate(row["action"])) for row in rows]
    out = []
    for k, row in enumerate(rows[:limit]):
        changes = action_changes(actions[k + 1], actions[k]) if k + 1 < len(rows) else None
        clamps = [clamp_view(cl) for cl in row["clamps"]]
        out.append({**row, "action": actions[k], "changes": changes, "clamps": clamps})
    return out


@router.get("/api/decisions", response_model=DecisionsAnswer, tags=["read"], responses=errors(422))
def decisions(request: Request, limit: Annotated[int, Query(ge=1, le=1000)] = 50, since_step: Step = None) -> dict:
    """Applied actions newest first: source controller and version, what each changed from the one before, clamps
    (`index` counted from 1), fallback, explanation."""
    ctx = _ctx(request)
    try:
        reader = ctx.history()
    except NotReady:
        rows = ctx.store.recent_decisions(limit)
        return {"source": "memory", "decisions": [r for r in rows if since_step is None or r["step"] >= since_step]}
    return {"source": "history", "decisions": _decision_rows(reader.decisions(limit + 1, since_step), limit)}


@router.get("/api/alerts", response_model=AlertsAnswer, tags=["read"], responses=errors(422))
def alerts(request: Request, active: bool = False, limit: Annotated[int, Query(ge=1, le=1000)] = 100) -> dict:
    """Maintenance alerts newest first (`active=true`: raised and not cleared)."""
    ctx = _ctx(request)
    try:
        reader = ctx.history()
    except NotReady:
        items = ctx.store.active_alerts() if active else list(ctx.store.alerts.values())
        return {"source": "memory", "alerts": [a.model_dump(mode="json") for a in items][:limit]}
    return {"source": "history", "alerts": reader.alerts(active_only=active, limit=limit)}


@router.get("/api/config", tags=["read"], response_class=JSONResponse,
            responses={200: {"model": ConfigDoc, "description": "the current configuration"}, **errors(503)})  # fmt: skip
def get_config(request: Request) -> JSONResponse:
    """The current configuration document (version, controller, mode, guardrails in SI, LLM settings)."""
    ctx = _ctx(request)
    doc = ctx.config_doc() or ctx.require_gateway().config()
    return JSONResponse(doc.model_dump(mode="json"))


@router.get("/metrics", tags=["read"], response_class=Response,
            responses={200: {"description": "Prometheus text exposition format 0.0.4",
                             "content": {"text/plain": {"schema": {"type": "string"}}}}})  # fmt: skip
def metrics(request: Request) -> Response:
    """Prometheus text exposition."""
    return Response(generate_latest(request.app.state.registry), media_type=CONTENT_TYPE_LATEST)

"""Authenticated writes: configuration changes, controller / mode switch, manual setpoints.

The token is checked twice: by ``guards.WriteAuth`` before the body is read (it finds these routes
by their ``require_token`` dependency), and by that dependency, which also puts the bearer scheme
in the OpenAPI document.

All three go to the Configuration agent's ``config/all`` queryable as a ``ConfigUpdate``; it
validates (pydantic, the controller registry, the guardrails against the plant), versions,
persists and publishes. The Sensor applies the result through the guardrails, which clamp and
report; ``/api/control/setpoints`` previews those clamps in its answer.
"""

from __future__ import annotations

from typing import Annotated

import numpy as np
from fastapi import APIRouter, Depends, HTTPException, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from lcmesh.assistant.sources import NotReady
from lcmesh.mesh.agents.ui.schemas import (
    PSI_MAX, TEMP_C_MAX, ConfigChange, ControlAnswer, ModeRequest, ProposalStamp, SetpointsRequest, errors,
)  # fmt: skip
from lcmesh.mesh.agents.ui.security import token_matches
from lcmesh.mesh.agents.ui.views import c, clamp_view, psi
from lcmesh.mesh.messages import ActionModel, ConfigDoc
from lcmesh.mesh.tools.guardrails import apply_guardrails
from lcmesh.twin.plant import PlantAction
from lcmesh.twin.system import PSI_TO_PA

router = APIRouter()
bearer = HTTPBearer(auto_error=False, description="the API token (LCMESH_API_TOKEN or LCMESH_API_TOKEN_FILE)")
AUTH = errors(400, 401, 413, 422, 503)
CONFIRM = errors(409, 410)  # a chat proposal confirmed on another config version, or too late
K0 = 273.15


def require_token(request: Request, credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)]) -> str:
    """The caller's address if it sent the API token; 401 otherwise."""
    header = f"Bearer {credentials.credentials}" if credentials else None
    if not token_matches(request.app.state.ctx.token.value, header):
        raise HTTPException(401, "this endpoint needs `Authorization: Bearer <token>` with the API token",
                            headers={"WWW-Authenticate": "Bearer"})  # fmt: skip
    return request.client.host if request.client else "unknown"


Caller = Annotated[str, Depends(require_token)]


def _by(caller: str) -> str:
    return f"api@{caller}"[:64]


@router.put("/api/config", response_model=ConfigDoc, tags=["write"], responses={**AUTH, **errors(409)})
def put_config(request: Request, body: ConfigChange, caller: Caller) -> dict:
    """Change the configuration (a partial document; nested sections merge). Returns the new version."""
    changes = body.changes.model_dump(exclude_unset=True)  # what was sent, typed: the rest merges from the current
    gateway = request.app.state.ctx.require_gateway()
    doc = gateway.update_config(changes, _by(caller), body.reason, body.expected_version)
    return doc.model_dump(mode="json")


def check_proposal(ctx, stamp: ProposalStamp | None) -> int | None:
    """The config version a confirmed chat proposal needs (None: not a proposal, or made before any config).

    410 when it is older than ``LCMESH_UI_PROPOSAL_MAX_AGE_S``; 409 when the configuration moved on since it
    was made (the Configuration agent checks the version again when it applies the change).
    """
    if stamp is None:
        return None
    age_s = (ctx.clock() - stamp.made_at).total_seconds()
    limit_s = ctx.ui.proposal_max_age_s
    if age_s > limit_s:
        raise HTTPException(410, f"`proposal.made_at`: this chat proposal was made {age_s:.0f} s ago, at "
                                 f"{stamp.made_at.isoformat()}; proposals expire after {limit_s:g} s "
                                 "(LCMESH_UI_PROPOSAL_MAX_AGE_S) since the plant has moved on: ask the chat "
                                 "again")  # fmt: skip
    if age_s < -60:
        raise HTTPException(422, f"`proposal.made_at` is {-age_s:.0f} s in the future ({stamp.made_at.isoformat()}); "
                                 "send the proposal as the chat made it")  # fmt: skip
    doc = ctx.config_doc()
    if stamp.config_version is not None and doc is not None and doc.version != stamp.config_version:
        raise HTTPException(409, f"`proposal.config_version`: the configuration changed since this chat "
                                 f"proposal (version {stamp.config_version} then, {doc.version} now): ask the chat "
                                 "again")  # fmt: skip
    return stamp.config_version


def _answer(doc, detail: str, clamps: list | None = None) -> ControlAnswer:
    manual = doc.config.manual_action
    view = None
    if manual is not None:
        view = {"supply_temp_setpoint_c": [c(v) for v in manual.supply_temp_setpoint_k],
                "dp_setpoint_psi": [psi(v) for v in manual.dp_setpoint_pa],
                "valve_fractions": [[round(v, 4) for v in row] for row in manual.valve_fractions],
                "lw_setpoint_c": [c(v) for v in manual.lw_setpoint_k]}  # fmt: skip
    return ControlAnswer(ok=True, config_version=doc.version, controller=doc.config.controller, mode=doc.config.mode,
                         manual_action=view, clamps_expected=clamps or [], detail=detail)  # fmt: skip


@router.post("/api/control/mode", response_model=ControlAnswer, tags=["write"], responses={**AUTH, **CONFIRM})
def control_mode(request: Request, body: ModeRequest, caller: Caller) -> ControlAnswer:
    """Switch the controller and/or auto / manual; manual without setpoints holds the action applied now."""
    ctx = request.app.state.ctx
    expected_version = check_proposal(ctx, body.proposal)
    changes: dict = {}
    if body.controller is not None:
        changes["controller"] = body.controller
    if body.mode is not None:
        changes["mode"] = body.mode
        if body.mode == "manual":
            applied = ctx.store.latest_applied()
            if applied is None:
                raise NotReady("no applied action yet to hold; send setpoints to /api/control/setpoints instead")
            changes["manual_action"] = applied.action.model_dump()
    doc = ctx.require_gateway().update_config(changes, _by(caller), body.reason or "controller switch from the API",
                                              expected_version)  # fmt: skip
    return _answer(doc, f"controller {doc.config.controller}, mode {doc.config.mode}")


def _per_item(name: str, value, count: int, selected: list[int], current: np.ndarray, convert) -> np.ndarray:
    out = current.copy()
    if isinstance(value, list):
        if len(value) != count:
            raise HTTPException(422, f"`{name}` must hold {count} values (one per item) or one number, got {len(value)}")
        return np.asarray([convert(v) for v in value], dtype=float)
    out[selected] = convert(value)
    return out


def _valves(value: list, selected: list[int], current: np.ndarray) -> np.ndarray:
    """One split for the selected cabinets or a row per cabinet; the guardrails make each row sum to 1 (reported)."""
    C, B = current.shape
    if value and isinstance(value[0], list):
        if len(value) != C or any(len(row) != B for row in value):
            raise HTTPException(422, f"`valve_fractions` must be {B} fractions or {C} rows of {B}, got "
                                     f"{len(value)} rows of {sorted({len(row) for row in value})}")  # fmt: skip
        return np.asarray(value, dtype=float)
    if len(value) != B:
        raise HTTPException(422, f"`valve_fractions` must hold {B} fractions (one per branch), got {len(value)}")
    out = current.copy()
    out[selected] = np.asarray(value, dtype=float)
    return out


@router.post("/api/control/setpoints", response_model=ControlAnswer, tags=["write"],
             responses={**AUTH, **CONFIRM, **errors(404)})
def control_setpoints(request: Request, body: SetpointsRequest, caller: Caller) -> ControlAnswer:
    """Manual setpoints (°C, psi, fractions) on top of the action applied now; switches to manual mode.

    The guardrails still apply at the Sensor: values outside the limits are clamped there and the
    clamps recorded with every step; `clamps_expected` previews them against the current limits.
    """
    ctx = request.app.state.ctx
    expected_version = check_proposal(ctx, body.proposal)
    system = ctx.system
    applied = ctx.store.latest_applied()
    state = ctx.store.state
    if applied is None or state is None:
        raise NotReady("no applied action yet: the current setpoints are not known")
    C, N = system.cabinets.count, system.towers.count
    cabinets = body.cabinets or list(range(1, C + 1))
    wrong = [i for i in cabinets if not 1 <= i <= C]
    if wrong:
        raise HTTPException(404, f"cabinet(s) {wrong} do not exist; {system.name} has cabinets 1..{C}")
    selected = [i - 1 for i in cabinets]
    base = applied.action.to_action()
    to_k = lambda v: float(v) + K0  # noqa: E731
    candidate = PlantAction(
        _per_item("supply_temp_setpoint_c", body.supply_temp_setpoint_c, C, selected, base.supply_temp_setpoint_k, to_k)
        if body.supply_temp_setpoint_c is not None else base.supply_temp_setpoint_k.copy(),
        _per_item("dp_setpoint_psi", body.dp_setpoint_psi, C, selected, base.dp_setpoint_pa,
                  lambda v: float(v) * PSI_TO_PA) if body.dp_setpoint_psi is not None else base.dp_setpoint_pa.copy(),
        _valves(body.valve_fractions, selected, base.valve_fractions)
        if body.valve_fractions is not None else base.valve_fractions.copy(),
        _per_item("lw_setpoint_c", body.lw_setpoint_c, N, list(range(N)), base.lw_setpoint_k, to_k)
        if body.lw_setpoint_c is not None else base.lw_setpoint_k.copy(),
    )  # fmt: skip
    for name, values, low, high in (("supply_temp_setpoint_c", candidate.supply_temp_setpoint_k, K0, K0 + TEMP_C_MAX),
                                    ("dp_setpoint_psi", candidate.dp_setpoint_pa, 0.0, PSI_MAX * PSI_TO_PA),
                                    ("lw_setpoint_c", candidate.lw_setpoint_k, K0, K0 + TEMP_C_MAX)):  # fmt: skip
        if not np.all(np.isfinite(values)) or np.any(values < low) or np.any(values > high):
            unit_low, unit_high = (0.0, TEMP_C_MAX) if name.endswith("_c") else (0.0, PSI_MAX)
            raise HTTPException(422, f"`{name}` must be within [{unit_low:g}, {unit_high:g}] (the guardrails clamp "
                                     "further to the configured limits)")  # fmt: skip
    limits = (ctx.config_doc().config.guardrails if ctx.config_doc() else None)
    clamps = []
    if limits is not None:
        preview = apply_guardrails(candidate, base, state.wet_bulb_k, limits, system)
        clamps = [clamp_view(cl.model_dump()) for cl in preview.clamps]
    changes = {"mode": "manual", "manual_action": ActionModel.from_action(candidate).model_dump()}
    doc = ctx.require_gateway().update_config(changes, _by(caller), body.reason or "manual setpoints from the API",
                                              expected_version)  # fmt: skip
    detail = "manual setpoints set" + (f"; the guardrails will clamp {len(clamps)} value(s)" if clamps else "")
    return _answer(doc, detail, clamps)

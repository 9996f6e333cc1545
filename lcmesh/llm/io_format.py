"""The controller's text protocol: one cabinet's or tower's observation as a prompt, its action as strict JSON.

The prompt (``lcmesh/prompts/controller_action.md``) shows what the distilled policies see (the
cabinet rows of ``lcmesh.distill.features``) in display units: per branch its mean and hottest
temperature, its coming-step power and power share; the CDU's measured supply, the hot-water supply
and the wet bulb. The answer is one JSON object, ``{"supply_c": 27.35, "dp_psi": 31.2, "valves":
[0.4, 0.33, 0.27]}``, parsed strictly: any other text, a missing or extra key, a non-finite number,
a setpoint outside 20-40 degC / 25-38 psi, a negative valve, the wrong count or a split not summing
to 1 within ``VALVE_SUM_TOLERANCE`` is rejected with a reason (the controller then falls back).

A cooling tower gets its own prompt (``controller_tower.md``: its cells' fan power, its and all towers'
leaving water, the hot-water return, the wet bulb, its present approach, the hottest blade) and answers
``{"approach_k": 4.0}``, the leaving-water setpoint over the wet bulb, within ``APPROACH_RANGE_K`` (the
learned policies' nine levels span it); the setpoint is the wet bulb plus that approach, never below the
tower's minimum approach.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources
from string import Template

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from lcmesh.twin.system import PSI_TO_PA

K0 = 273.15
SUPPLY_RANGE_C = (20.0, 40.0)
DP_RANGE_PSI = (25.0, 38.0)
VALVE_SUM_TOLERANCE = 0.05
ANSWER_STOP = "}"
APPROACH_RANGE_K = (1.5, 8.0)  # lcmesh.distill.features.APPROACH_LEVELS_K, first and last
REASONS = ("empty", "not_json", "schema", "out_of_bounds", "valves_count", "valves_negative", "valves_sum", "backend",
           "timeout")  # fmt: skip


@dataclass(frozen=True)
class CabinetView:
    """What the controller prompt shows of one cabinet, display units (degC, kW, %)."""

    branch_temp_c: tuple[float, ...]
    branch_max_temp_c: tuple[float, ...]
    branch_power_kw: tuple[float, ...]
    supply_c: float
    htw_supply_c: float
    wet_bulb_c: float


@dataclass(frozen=True)
class TowerView:
    """What the tower prompt shows of one cooling tower, display units (degC, K, % of nominal fan power)."""

    tower: int  # 1-based, as the prompt says it
    fan_pct: tuple[float, ...]
    leaving_c: float
    mean_leaving_c: float
    htw_return_c: float
    wet_bulb_c: float
    approach_k: float
    hottest_c: float


@dataclass(frozen=True)
class TowerDecision:
    """A parsed, in-bounds tower answer: the approach over the wet bulb, K."""

    approach_k: float


@dataclass(frozen=True)
class CabinetDecision:
    """A parsed, in-bounds answer in SI units; ``valves`` normalized to sum to exactly 1."""

    supply_temp_setpoint_k: float
    dp_setpoint_pa: float
    valve_fractions: tuple[float, ...]


@dataclass(frozen=True)
class ParseFailure:
    """Why an answer was rejected: ``reason`` is one of ``REASONS``, ``detail`` names the field."""

    reason: str
    detail: str


class _TowerAnswer(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)

    approach_k: float = Field(ge=APPROACH_RANGE_K[0], le=APPROACH_RANGE_K[1])


class _Answer(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)

    supply_c: float = Field(ge=SUPPLY_RANGE_C[0], le=SUPPLY_RANGE_C[1])
    dp_psi: float = Field(ge=DP_RANGE_PSI[0], le=DP_RANGE_PSI[1])
    valves: list[float]


def cabinet_views(
    out: Mapping[str, np.ndarray], branch_power_w: np.ndarray, wet_bulb_k: float
) -> list[CabinetView]:
    """Views of all cabinets from plant outputs (``Plant.out`` or an experience step) and the (C, B) loads."""
    temp = np.asarray(out["branch_temp_k"], dtype=float) - K0
    hottest = np.asarray(out["branch_max_temp_k"], dtype=float) - K0
    power = np.asarray(branch_power_w, dtype=float).reshape(temp.shape) / 1e3
    supply = np.asarray(out["supply_temp_k"], dtype=float).reshape(-1) - K0
    htw = float(np.mean(out["htw_supply_temp_k"])) - K0
    wb = float(wet_bulb_k) - K0
    return [
        CabinetView(tuple(temp[c].tolist()), tuple(hottest[c].tolist()), tuple(power[c].tolist()),
                    float(supply[c]), htw, wb)  # fmt: skip
        for c in range(temp.shape[0])
    ]


def tower_views(out: Mapping[str, np.ndarray], wet_bulb_k: float, fan_nominal_w: float) -> list[TowerView]:
    """Views of all towers from plant outputs (``Plant.out`` or an experience step)."""
    leaving = np.asarray(out["ct_leaving_temp_k"], dtype=float).reshape(-1) - K0
    n = leaving.size
    fans = 100.0 * np.asarray(out["cell_fan_power_w"], dtype=float).reshape(n, -1) / fan_nominal_w
    approach = np.asarray(out["applied_lw_setpoint_k"], dtype=float).reshape(n) - wet_bulb_k
    hottest = float(np.max(out["branch_max_temp_k"])) - K0
    ret = float(np.mean(out["htw_return_temp_k"])) - K0
    return [TowerView(t + 1, tuple(fans[t].tolist()), float(leaving[t]), float(leaving.mean()), ret,
                      float(wet_bulb_k) - K0, float(approach[t]), hottest) for t in range(n)]  # fmt: skip


def tower_messages(view: TowerView) -> list[dict[str, str]]:
    """Chat messages asking for one tower's approach."""
    system, user = load_template("controller_tower")
    values = {"tower": str(view.tower), "fans": "/".join(f"{f:.0f}" for f in view.fan_pct),
              "leaving_c": f"{view.leaving_c:.1f}", "mean_leaving_c": f"{view.mean_leaving_c:.1f}",
              "htw_return_c": f"{view.htw_return_c:.1f}", "wet_bulb_c": f"{view.wet_bulb_c:.1f}",
              "approach_k": f"{view.approach_k:.1f}", "hottest_c": f"{view.hottest_c:.1f}"}  # fmt: skip
    return [
        {"role": "system", "content": Template(system).substitute(values)},
        {"role": "user", "content": Template(user).substitute(values)},
    ]


def tower_answer_text(approach_k: float) -> str:
    """The training target / expected answer for a tower's approach."""
    return f'{{"approach_k":{approach_k:.1f}}}'


def parse_tower_answer(text: str) -> TowerDecision | ParseFailure:
    """Strictly parse one tower answer; a failure says why (never raises)."""
    data = _json_object(text)
    if isinstance(data, ParseFailure):
        return data
    try:
        answer = _TowerAnswer.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        if err["type"] in ("greater_than_equal", "less_than_equal"):
            lo, hi = APPROACH_RANGE_K
            return ParseFailure("out_of_bounds", f"`approach_k` must be in {lo}..{hi}, got {err['input']}")
        field = ".".join(str(p) for p in err["loc"]) or "answer"
        return ParseFailure("schema", f"`{field}`: {err['msg']}")
    return TowerDecision(answer.approach_k)


@lru_cache(maxsize=None)
def load_template(name: str) -> tuple[str, ...]:
    """A packaged prompt: (system, user) when it has both parts, else (body,), comment lines dropped."""
    text = resources.files("lcmesh.prompts").joinpath(f"{name}.md").read_text(encoding="utf-8")
    body = "\n".join(line for line in text.splitlines() if not line.startswith("<!-- ") or "-->" not in line[-4:])
    if "<!-- system -->" in text:
        system, user = text.split("<!-- system -->", 1)[1].split("<!-- user -->", 1)
        return system.strip(), user.strip()
    return (body.strip(),)


def controller_messages(view: CabinetView) -> list[dict[str, str]]:
    """Chat messages asking for one cabinet's CDU action."""
    system, user = load_template("controller_action")
    (branch_line,) = load_template("controller_branch")
    total = sum(view.branch_power_kw)
    n = len(view.branch_power_kw)
    lines = []
    for j, (t, tmax, p) in enumerate(zip(view.branch_temp_c, view.branch_max_temp_c, view.branch_power_kw)):
        temp = f"{t:.1f}" if abs(tmax - t) < 0.05 else f"{t:.1f}/{tmax:.1f}"  # one blade group: mean = hottest
        share = p / total if total > 0 else 1.0 / n
        row = {"branch": j + 1, "temp_c": temp, "power_kw": f"{p:.1f}", "share": f"{share:.2f}"}
        lines.append(Template(branch_line).substitute(row))
    values = {"branches": "\n".join(lines), "wet_bulb_c": f"{view.wet_bulb_c:.1f}", "supply_c": f"{view.supply_c:.1f}",
              "htw_supply_c": f"{view.htw_supply_c:.1f}", "n_branches": str(n), "cabinet_kw": f"{total:.1f}",
              "hottest_c": f"{max(view.branch_max_temp_c):.1f}"}  # fmt: skip
    return [
        {"role": "system", "content": Template(system).substitute(values)},
        {"role": "user", "content": Template(user).substitute(values)},
    ]


def answer_text(supply_temp_setpoint_k: float, dp_setpoint_pa: float, valve_fractions) -> str:
    """The training target / expected answer for an action, compact JSON at the precision the model writes."""
    valves = ",".join(f"{v:.2f}" for v in np.asarray(valve_fractions, dtype=float))
    return (f'{{"supply_c":{supply_temp_setpoint_k - K0:.1f},"dp_psi":{dp_setpoint_pa / PSI_TO_PA:.1f},'
            f'"valves":[{valves}]}}')  # fmt: skip


def _reject_constant(name: str):
    raise ValueError(f"non-finite number {name}")


def _json_object(text: str) -> dict | ParseFailure:
    """The answer as one JSON object (no NaN or Infinity), or why it is not one."""
    body = (text or "").strip()
    if not body:
        return ParseFailure("empty", "the answer is empty")
    try:
        data = json.loads(body, parse_constant=_reject_constant)
    except ValueError as exc:
        return ParseFailure("not_json", f"the answer is not one JSON object ({exc}): {body[:80]!r}")
    if not isinstance(data, dict):
        return ParseFailure("not_json", f"the answer must be a JSON object, got {type(data).__name__}")
    return data


def parse_cabinet_answer(text: str, n_branches: int) -> CabinetDecision | ParseFailure:
    """Strictly parse one answer; a failure says why (never raises)."""
    data = _json_object(text)
    if isinstance(data, ParseFailure):
        return data
    try:
        answer = _Answer.model_validate(data)
    except ValidationError as exc:
        return _classify(exc)
    valves = answer.valves
    if len(valves) != n_branches:
        return ParseFailure("valves_count", f"`valves` must hold {n_branches} fractions, got {len(valves)}")
    if any(not math.isfinite(v) or v < 0 for v in valves):
        return ParseFailure("valves_negative", f"`valves` must all be >= 0, got {valves}")
    total = sum(valves)
    if abs(total - 1.0) > VALVE_SUM_TOLERANCE:
        return ParseFailure("valves_sum", f"`valves` must sum to 1 (+-{VALVE_SUM_TOLERANCE}), got {total:.3f}")
    return CabinetDecision(answer.supply_c + K0, answer.dp_psi * PSI_TO_PA, tuple(v / total for v in valves))


def _classify(exc: ValidationError) -> ParseFailure:
    err = exc.errors()[0]
    field = ".".join(str(p) for p in err["loc"]) or "answer"
    if err["type"] in ("greater_than_equal", "less_than_equal"):
        bounds = {"supply_c": SUPPLY_RANGE_C, "dp_psi": DP_RANGE_PSI}.get(field, ("?", "?"))
        return ParseFailure("out_of_bounds", f"`{field}` must be in {bounds[0]}..{bounds[1]}, got {err['input']}")
    return ParseFailure("schema", f"`{field}`: {err['msg']}")

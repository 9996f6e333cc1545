"""Explain-eval input records: validation, normalization and the pool of grounded values.

A record (DESIGN.md, CLI) is ``{"id", "observation", "action", "explanation", "facts"?}`` plus the
optional ``previous_action`` (same shape as ``action``), ``level`` (short | detailed | very_detailed)
and ``index_base`` (0 or 1). Values are read with the unit their key ends in (``_k``, ``_c``, ``_w``,
``_kw``, ``_kg_s``, ``_pa``, ``_psi``, ``_pct`` ...; ``valve_fractions`` and ``*_share`` are fractions),
facts with their ``unit`` field, so records from any system can be scored.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from lcmesh.mesh.tools.claims import Fact
from lcmesh.mesh.tools.facts import COP_REFERENCE, STABILITY_FULL_MARGIN_K

K0 = 273.15
PSI_TO_PA = 6894.757
BAND_K = (293.15, 313.15)  # the 20-40 degC blade band (LC-Opt Section 6)


class Bounds(BaseModel):
    """Physical ranges an action must respect (``out_of_bounds`` otherwise)."""

    model_config = ConfigDict(extra="forbid")

    supply_setpoint_c: tuple[float, float] = (18.0, 40.0)
    dp_psi: tuple[float, float] = (25.0, 38.0)
    flow_kg_s: tuple[float, float] = (0.0, 500.0)
    lw_setpoint_c: tuple[float, float] = (0.0, 40.0)
    valve_sum_tol: float = Field(default=0.01, ge=0)


class EvalConfig(BaseModel):
    """Tolerances and bounds of the evaluator (``--config FILE.json`` overrides any field)."""

    model_config = ConfigDict(extra="forbid")

    rel_tol: float = Field(default=0.01, ge=0, le=0.5, description="relative tolerance (power, flow, pressure ...)")
    temp_tol_k: float = Field(default=0.1, ge=0, le=5, description="absolute tolerance on temperatures, K")
    rank_temp_tol_k: float = Field(default=0.02, ge=0, le=5, description="temperatures closer than this tie in a "
                                   "ranking ('hottest'), K: it compares the data's own values, not printed ones")
    fraction_tol: float = Field(default=0.005, ge=0, le=0.2, description="absolute tolerance on fractions")
    hold_band: dict[str, float] = {"supply": 0.05, "dp": 0.05 * PSI_TO_PA, "flow": 0.05, "tower": 0.05, "valve": 0.005}
    bounds: Bounds = Bounds()


class RawRecord(BaseModel):
    """One input line, as validated at the edge."""

    model_config = ConfigDict(extra="allow")

    id: str
    observation: dict[str, Any] = {}
    action: dict[str, Any]
    explanation: str
    facts: list[dict[str, Any]] | dict[str, Any] | None = None
    previous_action: dict[str, Any] | None = None
    level: Literal["short", "detailed", "very_detailed"] | None = None
    index_base: Literal[0, 1] | None = None

    @field_validator("id", mode="before")
    @classmethod
    def _id_as_text(cls, v: Any) -> Any:
        return str(v) if isinstance(v, int) else v


def validation_message(exc: ValidationError) -> str:
    """``field: problem`` lines for an invalid record."""
    parts = []
    for err in exc.errors():
        loc = ".".join(str(p) for p in err["loc"]) or "(record)"
        parts.append(f"`{loc}`: {err['msg']}")
    return "; ".join(parts)


def pool_fact(quantity: str, value: float, name: str, branch: int | None = None) -> Fact:
    """A value of the record's pool: ``branch`` is the 0-based position of the branch it belongs to."""
    return Fact(name, value, quantity, entity=None if branch is None else f"branch {branch + 1}", branch=branch)


@dataclass
class Record:
    """A validated record in SI units, with what the checks need."""

    id: str
    text: str
    level: str | None
    index_base: int | None
    temps_k: np.ndarray | None  # per branch
    powers_w: np.ndarray | None  # per branch
    valves: np.ndarray | None
    supply_k: float | None = None
    dp_pa: float | None = None
    flow_kg_s: float | None = None
    lw_k: float | None = None
    ct_category: str | None = None
    wet_bulb_k: float | None = None
    changes: dict[str, float] = field(default_factory=dict)  # dimension -> action minus previous
    valve_changes: np.ndarray | None = None
    observed: dict[str, float] = field(default_factory=dict)  # measured flow/dp/supply for direction refs
    pool: list[Fact] = field(default_factory=list)

    @property
    def n_branches(self) -> int:
        for arr in (self.valves, self.temps_k, self.powers_w):
            if arr is not None:
                return int(arr.size)
        return 0


def build_record(raw: RawRecord) -> Record:
    """Normalize a validated record: per-branch arrays, SI values, changes and the value pool."""
    obs, act, prev = raw.observation, raw.action, raw.previous_action or {}
    valves = _array(act.get("valve_fractions", act.get("valves")))
    temps = _array(_first(obs, "blade_temp_k", "branch_temp_k"))
    if temps is None and (c := _array(_first(obs, "blade_temp_c", "branch_temp_c"))) is not None:
        temps = c + K0
    powers = _array(_first(obs, "blade_power_w", "branch_power_w"))
    if powers is None and (kw := _array(_first(obs, "blade_power_kw", "branch_power_kw"))) is not None:
        powers = kw * 1e3
    n = valves.size if valves is not None else None
    rec = Record(
        id=raw.id, text=raw.explanation, level=raw.level, index_base=raw.index_base,
        temps_k=_per_branch(temps, n, np.mean), powers_w=_per_branch(powers, n, np.sum), valves=valves,
    )  # fmt: skip
    rec.supply_k = _temperature_k(act, "supply_temp_setpoint")
    rec.dp_pa = _pressure_pa(act, "dp")
    rec.flow_kg_s = _number(act.get("flow_kg_s"))
    rec.lw_k, rec.ct_category = _tower(act.get("ct_action"), act)
    rec.wet_bulb_k = _temperature_k(obs, "wet_bulb")
    if prev:
        before = {"supply": _temperature_k(prev, "supply_temp_setpoint"), "dp": _pressure_pa(prev, "dp"),
                  "flow": _number(prev.get("flow_kg_s")), "tower": _tower(prev.get("ct_action"), prev)[0]}  # fmt: skip
        now = {"supply": rec.supply_k, "dp": rec.dp_pa, "flow": rec.flow_kg_s, "tower": rec.lw_k}
        rec.changes = {k: now[k] - before[k] for k in now if now[k] is not None and before[k] is not None}
        pv = _array(prev.get("valve_fractions", prev.get("valves")))
        if pv is not None and valves is not None and pv.size == valves.size:
            rec.valve_changes = valves - pv
    rec.observed = {k: v for k, v in (("flow", _number(obs.get("flow_kg_s"))), ("dp", _pressure_pa(obs, "dp")),
                                      ("supply", _temperature_k(obs, "supply_temp"))) if v is not None}  # fmt: skip
    _changes_from_facts(rec, raw.facts)
    rec.pool = _pool(rec, raw)
    return rec


def _first(d: dict, *keys: str) -> Any:
    for k in keys:
        if k in d:
            return d[k]
    return None


def _number(v: Any) -> float | None:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return None
    return float(v) if math.isfinite(v) else None


def _array(v: Any) -> np.ndarray | None:
    if not isinstance(v, (list, tuple)) or not v:
        return None
    vals = [_number(x) for x in v]
    if any(x is None for x in vals):
        vals = [x for x in vals if x is not None]  # partial lists: keep what is numeric
        if not vals:
            return None
    return np.array(vals, dtype=float)


def _per_branch(values: np.ndarray | None, n_branches: int | None, reduce) -> np.ndarray | None:
    """Blade-group lists of G groups per branch become per-branch values (mean temperature, summed power)."""
    if values is None or n_branches is None or values.size == n_branches or values.size % n_branches:
        return values
    return reduce(values.reshape(n_branches, -1), axis=1)


def _temperature_k(d: dict, stem: str) -> float | None:
    if (v := _number(d.get(f"{stem}_k"))) is not None:
        return v
    if (v := _number(d.get(f"{stem}_c"))) is not None:
        return v + K0
    return None


def _pressure_pa(d: dict, stem: str) -> float | None:
    for suffix, scale in (("_pa", 1.0), ("_kpa", 1e3), ("_psi", PSI_TO_PA), ("_setpoint_pa", 1.0)):
        if (v := _number(d.get(stem + suffix))) is not None:
            return v * scale
    return None


def _tower(ct: Any, act: dict) -> tuple[float | None, str | None]:
    """(leaving-water setpoint K, category) from ``ct_action``: a number (deg C, or K above 100), an int
    category, a string category, a list (mean), or a dict with lw_setpoint_c/_k and/or category."""
    if ct is None:
        ct = {k: v for k, v in act.items() if k.startswith(("lw_setpoint", "ct_lw"))} or None
    if ct is None:
        return None, None
    if isinstance(ct, str):
        return None, ct
    if isinstance(ct, int) and not isinstance(ct, bool):
        return None, str(ct)
    if isinstance(ct, (list, tuple)):
        arr = _array(list(ct))
        ct = float(arr.mean()) if arr is not None else None
    if isinstance(ct, float):
        return (ct if ct > 100 else ct + K0), None
    if isinstance(ct, dict):
        lw = _first(ct, "lw_setpoint_k", "lw_setpoint_c", "ct_lw_setpoint_k", "ct_lw_setpoint_c")
        if isinstance(lw, (list, tuple)):
            arr = _array(list(lw))
            lw = float(arr.mean()) if arr is not None else None
        lw = _number(lw)
        if lw is not None and any(k.endswith("_c") for k in ct if "lw" in k):
            lw += K0
        cat = ct.get("category")
        return lw, (None if cat is None else str(cat))
    return None, None


_FACT_CHANGES = {"supply_setpoint_change": "supply", "dp_setpoint_change": "dp", "flow_change": "flow",
                 "tower_lw_change": "tower"}  # fmt: skip


def _changes_from_facts(rec: Record, facts: Any) -> None:
    """Our facts carry the change of each setpoint; use them when no previous action is given."""
    for f in _fact_items(facts):
        dim = _FACT_CHANGES.get(str(f.get("name")))
        value = _number(f.get("value"))
        if dim and value is not None and dim not in rec.changes:
            scale = PSI_TO_PA if f.get("unit") == "psi" else 1.0
            rec.changes[dim] = value * scale


def _fact_items(facts: Any) -> list[dict]:
    if isinstance(facts, dict):
        return [{"name": k, "value": v, "unit": ""} for k, v in facts.items()]
    return [f for f in facts or [] if isinstance(f, dict)]


# --- the pool of grounded values -------------------------------------------------------------

_SUFFIX = [  # key ending -> (quantity, scale, offset)
    ("_kg_s", "flow", 1.0, 0.0), ("_l_s", "flow", 0.997, 0.0), ("_kpa", "pressure", 1e3, 0.0),
    ("_psi", "pressure", PSI_TO_PA, 0.0), ("_pa", "pressure", 1.0, 0.0), ("_bar", "pressure", 1e5, 0.0),
    ("_kw", "power", 1e3, 0.0), ("_mw", "power", 1e6, 0.0), ("_w", "power", 1.0, 0.0),
    ("_pct", "percent", 1.0, 0.0), ("_percent", "percent", 1.0, 0.0), ("_c", "temp_abs", 1.0, K0),
    ("_f", "temp_abs", 1 / 1.8, K0 - 32 / 1.8), ("_k", "temp", 1.0, 0.0), ("fractions", "fraction", 1.0, 0.0),
    ("_fraction", "fraction", 1.0, 0.0), ("_share", "fraction", 1.0, 0.0), ("_shares", "fraction", 1.0, 0.0),
    ("_j", "energy", 1.0, 0.0), ("_s", None, 0, 0), ("_h", None, 0, 0),
]  # fmt: skip
_FACT_UNITS = {
    "degc": ("temp_abs", 1.0, K0), "°c": ("temp_abs", 1.0, K0), "c": ("temp_abs", 1.0, K0), "k": ("temp", 1.0, 0.0),
    "degf": ("temp_abs", 1 / 1.8, K0 - 32 / 1.8), "w": ("power", 1.0, 0.0), "kw": ("power", 1e3, 0.0),
    "mw": ("power", 1e6, 0.0), "kg/s": ("flow", 1.0, 0.0), "psi": ("pressure", PSI_TO_PA, 0.0),
    "pa": ("pressure", 1.0, 0.0), "kpa": ("pressure", 1e3, 0.0), "fraction": ("fraction", 1.0, 0.0),
    "%": ("percent", 1.0, 0.0), "j/(kg k)": ("specific_heat", 1.0, 0.0), "": ("unitless", 1.0, 0.0),
}  # fmt: skip
# Definitions a fact's text cites (the band, the scores' scales): grounded by definition, not by the data.
CONSTANTS = [
    ("temp_abs", BAND_K[0], "20 °C band edge"), ("temp_abs", BAND_K[1], "40 °C band edge"),
    ("temp_delta", STABILITY_FULL_MARGIN_K, "stability score's full band margin"),
    ("unitless", COP_REFERENCE, "efficiency score's reference COP"),
    ("fraction", 0.0, "zero"), ("fraction", 1.0, "one"), ("percent", 100.0, "100 %"),
    ("unitless", 0.0, "zero"), ("unitless", 1.0, "one"), ("specific_heat", 4186.0, "c_p of water"),
]  # fmt: skip
_BRANCH_NAME = re.compile(r"branch_(\d+)_")


def _pool(rec: Record, raw: RawRecord) -> list[Fact]:
    pool = [pool_fact(q, v, label) for q, v, label in CONSTANTS]
    n = rec.n_branches
    for section, data in (("observation", raw.observation), ("action", raw.action),
                          ("previous_action", raw.previous_action or {})):  # fmt: skip
        skip = _PER_BRANCH_KEYS if section != "previous_action" else set()
        _walk({k: v for k, v in data.items() if not (k in skip and isinstance(v, list) and len(v) == n)}, section, pool)
    if rec.lw_k is not None:
        pool.append(pool_fact("temp_abs", rec.lw_k, "tower leaving-water setpoint"))
    for j in range(rec.n_branches):  # per-branch values, tagged for attribution checks
        for arr, q in ((rec.temps_k, "temp_abs"), (rec.powers_w, "power"), (rec.valves, "fraction")):
            if arr is not None and j < arr.size:
                pool.append(pool_fact(q, float(arr[j]), f"branch {j + 1}", j))
    if rec.powers_w is not None and rec.powers_w.sum() > 0:
        total = float(rec.powers_w.sum())
        pool.append(pool_fact("power", total, "total branch power"))
        pool += [pool_fact("fraction", float(p / total), f"power share of branch {j + 1}", j)
                 for j, p in enumerate(rec.powers_w)]  # fmt: skip
    for dim, change in rec.changes.items():
        q = {"supply": "temp_delta", "tower": "temp_delta", "dp": "pressure", "flow": "flow"}[dim]
        pool.append(pool_fact(q, abs(change), f"{dim} change"))
    prev_valves = _array((raw.previous_action or {}).get("valve_fractions", (raw.previous_action or {}).get("valves")))
    if prev_valves is not None and prev_valves.size == n:  # "closed from 0.25 to 0.20" is said of the branch
        pool += [pool_fact("fraction", float(v), f"previous valve fraction of branch {j + 1}", j)
                 for j, v in enumerate(prev_valves)]  # fmt: skip
    if rec.valve_changes is not None:
        pool += [pool_fact("fraction", abs(float(d)), f"valve change of branch {j + 1}", j)
                 for j, d in enumerate(rec.valve_changes)]  # fmt: skip
    if rec.lw_k is not None and rec.wet_bulb_k is not None:
        pool.append(pool_fact("temp_delta", abs(rec.lw_k - rec.wet_bulb_k), "approach of the leaving-water setpoint"))
    for f in _fact_items(raw.facts):
        value = _number(f.get("value"))
        if value is None:
            continue
        unit = str(f.get("unit", "")).strip().lower()
        q, scale, offset = _FACT_UNITS.get(unit, ("unitless", 1.0, 0.0))
        m = _BRANCH_NAME.match(str(f.get("name", "")))
        entity = int(m.group(1)) - 1 if m else None  # our fact names count branches from 1
        _add(pool, q, value * scale + offset, f"fact {f.get('name')}", entity)
        if q == "unitless" and 0.0 <= value <= 1.0:
            pool.append(pool_fact("fraction", value, f"fact {f.get('name')}"))
    _mark_aliases(pool)
    for e in pool:
        e.topic = next((name for name, pattern in TOPICS if pattern.search(e.name)), None)
    return pool


# pool labels (record keys, fact names) -> the topic a text names them by; checked by grounding.py
TOPICS = [("wet_bulb", re.compile(r"wet_bulb")),
          ("lw_setpoint", re.compile(r"lw_setpoint|leaving-water setpoint")),
          ("supply_setpoint", re.compile(r"supply_temp_setpoint|supply_setpoint(?!_change|_direction)"))]  # fmt: skip


_PER_BRANCH_KEYS = {"blade_temp_k", "branch_temp_k", "blade_temp_c", "branch_temp_c", "blade_power_w", "branch_power_w",
                    "blade_power_kw", "branch_power_kw", "valve_fractions", "valves"}  # fmt: skip


_ALIAS_TOL = {"power": 1.0, "pressure": 1.0, "fraction": 1e-4}  # our facts round to 3-4 decimals


def _mark_aliases(pool: list[Fact]) -> None:
    """A value without a branch that equals a branch's value (``hottest_branch_temp``) is that branch's alias."""
    owned = [(e.quantity, e.value, e.branch) for e in pool if e.branch is not None]
    for e in pool:
        if e.branch is None:
            for q, v, j in owned:
                if q == e.quantity and abs(v - e.value) <= _ALIAS_TOL.get(q, 1e-3):
                    e.alias = j
                    break


def _walk(data: Any, path: str, pool: list[Fact]) -> None:
    if isinstance(data, dict):
        for k, v in data.items():
            _walk(v, f"{path}.{k}", pool)
        return
    values = data if isinstance(data, (list, tuple)) else [data]
    key = path.rsplit(".", 1)[-1].lower()
    quantity, scale, offset = "unitless", 1.0, 0.0
    for suffix, q, s, o in _SUFFIX:
        if key.endswith(suffix):
            quantity, scale, offset = q, s, o
            break
    if quantity is None:
        return
    for i, v in enumerate(values):
        if isinstance(v, (dict, list)):
            _walk(v, f"{path}[{i}]", pool)
        elif (x := _number(v)) is not None:
            _add(pool, quantity, x * scale + offset, f"{path}[{i}]" if len(values) > 1 else path)
            if quantity == "unitless" and 0.0 <= x <= 1.0:
                pool.append(pool_fact("fraction", x, path))


def _add(pool: list[Fact], quantity: str, value: float, label: str, entity: int | None = None) -> None:
    if quantity == "temp":  # K: an absolute temperature above 150 K, else a difference
        quantity = "temp_abs" if value > 150 else "temp_delta"
    if quantity != "temp_abs":
        value = abs(value)  # text states magnitudes; directions are checked separately
    pool.append(pool_fact(quantity, value, label, entity))

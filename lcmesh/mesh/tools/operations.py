"""The operator's questions the state-now tools do not answer: energy over a window, setpoint tracking, where and
when a peak happened, top-N at any level, another controller on a copy of the twin, the weather on the towers.

All numbered from 1, in display units (degC, K, kW, kWh, %). ``energy_used`` integrates the history's plant-wide
power columns over plant time (trapezoids); ``peak`` reads the per-entity outputs of the stored plant states;
``whatif_controller`` runs two controllers from the live state on the twin (the FMU state is saved and restored,
so the plant goes on exactly as before); ``weather_effect`` adds the tower model's fan power at one kelvin more wet
bulb (``thermo.tower_fan_power_w``). Definitions: docs/ui.md.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, Field

from lcmesh.mesh.tools import thermo
from lcmesh.mesh.tools.plant_data import (
    K0, QUANTITIES, EntityValue, NotReady, QuantityKey, ToolInputError, _data, _Model, _outputs, check_number,
    entity_values,
)  # fmt: skip

# --- energy_used ---------------------------------------------------------------------------------------------------
EnergyWhat = Literal["cooling", "pumps", "tower_fans", "it", "heat_rejected"]
_ENERGY_COLUMNS: dict[str, tuple[tuple[str, ...], str]] = {
    "cooling": (("ct_fan_power_w", "pump_power_w"), "cooling (tower fans and pumps)"),
    "pumps": (("pump_power_w",), "pumps"),
    "tower_fans": (("ct_fan_power_w",), "tower fans"),
    "it": (("it_power_w",), "IT load"),
    "heat_rejected": (("heat_rejected_w",), "heat rejected by the towers"),
}
MAX_SAMPLES = 2000  # history rows read per question: a week at 15 s is 40,320, read every k-th


class EnergyUsedRequest(_Model):
    """Energy (kWh) over the last `minutes`, integrated from the history's power columns."""

    what: EnergyWhat = "cooling"
    minutes: float = Field(60.0, gt=0, le=7 * 24 * 60)


class EnergyUsedResponse(_Model):
    what: str
    label: str
    kwh: float
    mean_kw: float
    minutes_asked: float
    minutes_covered: float
    samples: int
    from_step: int
    to_step: int


def _window(minutes: float, step_s: float, most: int) -> tuple[int, int]:
    """(steps back, read every k-th) for a window of `minutes`, at most about `most` rows read."""
    back = max(1, int(round(minutes * 60.0 / step_s)))
    return back, max(1, math.ceil((back + 1) / most))


def _window_rows(data: Any, minutes: float, fields: tuple[str, ...]) -> list[dict]:
    state = data.latest_state()
    back, every = _window(minutes, data.system.step_s, MAX_SAMPLES)
    rows = data.history().states(start_step=max(0, state.step - back), end_step=state.step, fields=fields,
                                 run_id=state.run_id, every=every, limit=back + 2)  # fmt: skip
    rows = [r for r in rows if all(r[f] is not None for f in fields)]
    if len(rows) < 2:
        raise NotReady("history holds fewer than two plant states of this run yet")
    return rows


def energy_used(req: EnergyUsedRequest, ctx: Any) -> EnergyUsedResponse:
    columns, label = _ENERGY_COLUMNS[req.what]
    rows = _window_rows(_data(ctx), req.minutes, columns)
    t = np.asarray([r["time_s"] for r in rows], dtype=float)
    p = np.asarray([sum(r[c] for c in columns) for r in rows], dtype=float)
    joules = float(np.sum((p[1:] + p[:-1]) / 2.0 * np.diff(t)))
    covered = float(t[-1] - t[0])
    return EnergyUsedResponse(what=req.what, label=label, kwh=joules / 3.6e6, mean_kw=joules / covered / 1e3,
                              minutes_asked=req.minutes, minutes_covered=covered / 60.0, samples=len(rows),
                              from_step=rows[0]["step"], to_step=rows[-1]["step"])  # fmt: skip


# --- tracking_gap -------------------------------------------------------------------------------------------------
class TrackingGapRequest(_Model):
    """How far each CDU's measured supply is from its supply setpoint (`level` cabinet), or each tower's leaving
    water from its leaving-water setpoint (`level` tower), now."""

    level: Literal["cabinet", "tower"] = "cabinet"
    cabinet: int | None = Field(None, ge=1, le=10_000, description="numbered from 1")
    tower: int | None = Field(None, ge=1, le=10_000, description="numbered from 1")


class Gap(_Model):
    entity: str
    setpoint_c: float
    measured_c: float
    gap_k: float = Field(description="measured minus setpoint")


class TrackingGapResponse(_Model):
    level: str
    what: str
    step: int
    gaps: list[Gap]
    largest: str = Field(description="the entity farthest from its setpoint (either side)")
    largest_gap_k: float


def tracking_gap(req: TrackingGapRequest, ctx: Any) -> TrackingGapResponse:
    data = _data(ctx)
    system, state = data.system, data.latest_state()
    level = "tower" if req.tower is not None else "cabinet" if req.cabinet is not None else req.level
    if level == "cabinet":
        check_number("cabinet", req.cabinet, system.cabinets.count)
        measured, setpoint = _outputs(state, "supply_temp_measured_k"), _outputs(state, "applied_supply_setpoint_k")
        names, what, pick = [f"cabinet {c + 1}" for c in range(measured.size)], "CDU supply vs its setpoint", req.cabinet
    else:
        check_number("tower", req.tower, system.towers.count)
        measured, setpoint = _outputs(state, "ct_leaving_temp_k"), _outputs(state, "applied_lw_setpoint_k")
        names, what, pick = [f"tower {t + 1}" for t in range(measured.size)], "leaving water vs its setpoint", req.tower
    gaps = [Gap(entity=n, setpoint_c=float(s - K0), measured_c=float(m - K0), gap_k=float(m - s))
            for n, m, s in zip(names, measured, setpoint)]  # fmt: skip
    if pick is not None:
        gaps = [gaps[pick - 1]]
    largest = max(gaps, key=lambda g: abs(g.gap_k))
    return TrackingGapResponse(level=level, what=what, step=state.step, gaps=gaps, largest=largest.entity,
                               largest_gap_k=largest.gap_k)  # fmt: skip


# --- peak -----------------------------------------------------------------------------------------------------------
class PeakRequest(_Model):
    """Where and when a quantity was highest (or lowest) over the last `minutes`, per entity, from history."""

    quantity: QuantityKey = "blade_temp"
    minutes: float = Field(60.0, gt=0, le=7 * 24 * 60)
    extreme: Literal["max", "min"] = "max"


class PeakResponse(_Model):
    quantity: str
    label: str
    unit: str
    extreme: str
    value: float
    entity: str = Field(description="where: the branch, cabinet or tower (\"plant\" for a plant-wide quantity)")
    step: int
    at: str = Field(description="when: the plant state's time (UTC, ISO 8601)")
    minutes_ago: float
    minutes_asked: float
    minutes_covered: float
    samples: int


MAX_PEAK_STATES = 480  # plant states read per question (their full payloads); a longer window is sampled


def peak(req: PeakRequest, ctx: Any) -> PeakResponse:
    data = _data(ctx)
    system, now = data.system, data.latest_state()
    q = QUANTITIES[req.quantity]
    back, every = _window(req.minutes, system.step_s, MAX_PEAK_STATES)
    states = data.history().payload_states(start_step=max(0, now.step - back), end_step=now.step, run_id=now.run_id,
                                           every=every, limit=MAX_PEAK_STATES + 2)  # fmt: skip
    if len(states) < 2:
        raise NotReady("history holds fewer than two stored plant states of this run yet")
    best: tuple[float, EntityValue, Any] | None = None
    sign = 1.0 if req.extreme == "max" else -1.0
    for state in states:
        for v in entity_values(q, state, system):
            if v.value is not None and np.isfinite(v.value) and (best is None or sign * v.value > sign * best[0]):
                best = (v.value, v, state)
    if best is None:
        raise ToolInputError(f"history holds no {q.label} values in that window")
    value, where, state = best
    return PeakResponse(quantity=q.key, label=q.label, unit=q.unit, extreme=req.extreme, value=value,
                        entity=where.entity, step=state.step, at=state.sent_at.isoformat(timespec="seconds"),
                        minutes_ago=(now.time_s - state.time_s) / 60.0, minutes_asked=req.minutes,
                        minutes_covered=(states[-1].time_s - states[0].time_s) / 60.0, samples=len(states))  # fmt: skip


# --- weather_effect -----------------------------------------------------------------------------------------------
class WeatherRequest(_Model):
    """How the weather drives the towers: the wet bulb now and over the last `minutes`, each tower's approach,
    leaving water, fan speed and power, and the fan power one more kelvin of wet bulb would cost."""

    minutes: float = Field(60.0, gt=0, le=7 * 24 * 60)


class TowerWeather(_Model):
    entity: str
    approach_k: float
    leaving_water_c: float
    fan_speed_pct: float
    fan_power_kw: float


class WeatherResponse(_Model):
    step: int
    wet_bulb_c: float
    wet_bulb_change_k: float = Field(description="over the window: last minus first")
    fan_power_kw: float
    fan_power_change_kw: float = Field(description="over the window: last minus first")
    minutes_covered: float
    towers: list[TowerWeather]
    fan_kw_per_k_wet_bulb: float | None = Field(
        description="tower-model estimate: extra fan power to hold today's leaving water at one kelvin more wet bulb "
                    "(None where a tower could not hold it even at full speed)")  # fmt: skip


def weather_effect(req: WeatherRequest, ctx: Any) -> WeatherResponse:
    data = _data(ctx)
    system, state = data.system, data.latest_state()
    rows = _window_rows(data, req.minutes, ("wet_bulb_k", "ct_fan_power_w"))
    N = system.towers.count
    approach, leaving = _outputs(state, "approach_k"), _outputs(state, "ct_leaving_temp_k")
    speed = _outputs(state, "fan_speed")
    fan_w = _outputs(state, "cell_fan_power_w").reshape(N, -1).sum(axis=1)
    heat_w = _outputs(state, "cell_heat_w").reshape(N, -1).sum(axis=1)
    cells = _outputs(state, "cells_active")
    towers = [TowerWeather(entity=f"tower {t + 1}", approach_k=float(approach[t]), leaving_water_c=float(leaving[t] - K0),
                           fan_speed_pct=float(speed[t] * 100.0), fan_power_kw=float(fan_w[t] / 1e3))
              for t in range(N)]  # fmt: skip
    wb = float(state.wet_bulb_k)
    extra = 0.0
    for t in range(N):
        n = max(1, int(round(cells[t])))
        now = thermo.tower_fan_power_w(system, heat_w[t], float(approach[t]), wb, n)
        hotter = thermo.tower_fan_power_w(system, heat_w[t], float(approach[t]) - 1.0, wb + 1.0, n)
        if not (now.reachable and hotter.reachable):
            extra = math.nan
            break
        extra += hotter.fan_power_w - now.fan_power_w
    return WeatherResponse(step=state.step, wet_bulb_c=wb - K0,
                           wet_bulb_change_k=float(rows[-1]["wet_bulb_k"] - rows[0]["wet_bulb_k"]),
                           fan_power_kw=float(fan_w.sum() / 1e3),
                           fan_power_change_kw=float(rows[-1]["ct_fan_power_w"] - rows[0]["ct_fan_power_w"]) / 1e3,
                           minutes_covered=(rows[-1]["time_s"] - rows[0]["time_s"]) / 60.0, towers=towers,
                           fan_kw_per_k_wet_bulb=None if math.isnan(extra) else extra / 1e3)  # fmt: skip


# --- whatif_controller ----------------------------------------------------------------------------------------------
class WhatIfControllerRequest(_Model):
    """Another controller against the current one over the next `minutes`, both from the live state on the twin."""

    controller: str = Field(min_length=1, max_length=80, description="the controller to try: g36, rule, static ...")
    minutes: float = Field(15.0, gt=0, le=60)
    current: str | None = Field(None, max_length=80, description="the controller running now (filled by the mesh)")


class Course(_Model):
    controller: str
    cooling_kwh: float = Field(description="tower fans and pumps over the horizon")
    tower_fans_kwh: float
    pumps_kwh: float
    hottest_blade_c: float = Field(description="the hottest blade group at any step of the horizon")
    in_band_pct: float = Field(description="mean share of blade groups inside 20-40 degC over the horizon")
    note: str | None = None


class WhatIfControllerResponse(_Model):
    minutes: float
    current: Course
    alternative: Course
    cooling_kwh_saved: float = Field(description="current minus alternative: > 0 when the alternative uses less")


_CONTROLLERS: dict[tuple[str, str], tuple[Any, str | None]] = {}  # (system hash, name) -> built controller, note


def _controller(name: str, system: Any) -> tuple[Any, str | None]:
    from lcmesh.mesh.agents.control import build_controller
    from lcmesh.twin.controllers.guarded import MESH_GUARDRAILS, guard

    key = (system.content_hash(), name)
    if key not in _CONTROLLERS:
        ctrl, note = build_controller(name, system)
        _CONTROLLERS[key] = (guard(ctrl, system, MESH_GUARDRAILS), note)
    return _CONTROLLERS[key]


def _course(plant: Any, name: str, steps: int, start: Any) -> Course:
    from lcmesh.twin.controllers import Observation

    plant.restore_state(start)
    ctrl, note = _controller(name, plant.system)
    ctrl.reset()
    power = np.array(plant.inp["blade_power_w"], dtype=float)
    wet_bulb = float(plant.inp["wet_bulb_k"])
    out = {k: np.array(v) for k, v in plant.out.items()}
    fans = pumps = 0.0
    hottest, band = -math.inf, []
    for k in range(steps):
        out = plant.step(power, wet_bulb, ctrl.act(Observation(out, wet_bulb, power, k * plant.step_s)))
        fans += float(np.sum(out["ct_fan_power_w"])) * plant.step_s
        pumps += float(np.sum(out["pump_power_w"])) * plant.step_s
        temps = np.asarray(out["blade_temp_k"], dtype=float) - K0
        hottest = max(hottest, float(temps.max()))
        band.append(float(np.mean((temps > 20.0) & (temps < 40.0)) * 100.0))
    return Course(controller=name, cooling_kwh=(fans + pumps) / 3.6e6, tower_fans_kwh=fans / 3.6e6,
                  pumps_kwh=pumps / 3.6e6, hottest_blade_c=hottest, in_band_pct=float(np.mean(band)), note=note)


def whatif_controller(req: WhatIfControllerRequest, ctx: Any) -> WhatIfControllerResponse:
    """Both controllers from the same saved state, same load and weather held; the plant restored afterwards."""
    from lcmesh.mesh.tools.whatif import MAX_WHATIF_STEPS, RestoredPlant

    plant = getattr(ctx, "plant", None)
    if plant is None:
        raise ToolInputError("this host has no live twin; the Sensor agent serves what-ifs")
    current = req.current
    data = getattr(ctx, "data", None)
    if current is None and data is not None:
        doc = data.config()
        current = doc.config.controller if doc is not None else None
    if current is None:
        raise ToolInputError("the controller running now is not known; give `current`")
    steps = int(min(MAX_WHATIF_STEPS, max(1, round(req.minutes * 60.0 / plant.step_s))))
    with ctx.lock if getattr(ctx, "lock", None) is not None else contextlib.nullcontext():
        with RestoredPlant(plant) as start:
            now = _course(plant, current, steps, start)
            other = _course(plant, req.controller, steps, start)
    return WhatIfControllerResponse(minutes=steps * plant.step_s / 60.0, current=now, alternative=other,
                                    cooling_kwh_saved=now.cooling_kwh - other.cooling_kwh)  # fmt: skip


# --- the tool table (registered in registry.TOOLS) ----------------------------------------------------------------
OPERATION_TOOLS: list[tuple[str, str, type[BaseModel], type[BaseModel], Callable]] = [
    ("energy_used", "Energy in kWh over the last minutes (cooling, pumps, tower fans, IT, heat rejected), integrated "
     "from history", EnergyUsedRequest, EnergyUsedResponse, energy_used),
    ("tracking_gap", "How far each CDU's supply is from its setpoint, or each tower's leaving water from its "
     "setpoint, now", TrackingGapRequest, TrackingGapResponse, tracking_gap),
    ("peak", "Where and when a quantity peaked (or bottomed) over the last minutes", PeakRequest, PeakResponse, peak),
    ("weather_effect", "How the weather drives the towers: wet bulb, approach, leaving water, fans, and the fan "
     "power of one more kelvin of wet bulb", WeatherRequest, WeatherResponse, weather_effect),
    ("whatif_controller", "Another controller (G36, rule ...) against the current one over the next minutes, on the "
     "live twin", WhatIfControllerRequest, WhatIfControllerResponse, whatif_controller),
]  # fmt: skip

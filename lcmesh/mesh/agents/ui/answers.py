"""Chat answers about the plant as it is and as it was: state, rankings, history, alerts, agents, controller.

Each function retrieves facts (the latest plant state the UI holds, history rows, alerts, agents)
and writes a deterministic answer citing only them. Decisions, what-ifs and commands live in
``actions.py``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from lcmesh.mesh.agents.ui.facts import ChatFact, FactBook, fact
from lcmesh.mesh.agents.ui.intents import QUANTITIES, Intent
from lcmesh.mesh.history import HistoryReader
from lcmesh.mesh.messages import ConfigDoc, PlantState
from lcmesh.twin.system import PSI_TO_PA, SystemDescription

K0 = 273.15
BAND_C = (20.0, 40.0)
CONVERT: dict[str, Callable[[float], float]] = {
    "c": lambda v: v - K0, "kw": lambda v: v / 1e3, "psi": lambda v: v / PSI_TO_PA, "pct": lambda v: v * 100.0,
    "raw": lambda v: v,
}  # fmt: skip
REDUCE: dict[str, Callable[[np.ndarray], float]] = {"max": np.max, "min": np.min, "mean": np.mean, "sum": np.sum}


class NotReady(RuntimeError):
    """The data an answer needs is not there yet (no plant state, no history file)."""


@dataclass
class Answer:
    """A chat answer before phrasing: its text, the facts it cites, and a command to confirm, if any."""

    intent: str
    text: str
    facts: list[ChatFact]
    proposed_command: dict[str, Any] | None = None


@dataclass
class ChatSources:
    """Where answers get their facts (the UI agent fills it; tests may build one from the same parts)."""

    system: SystemDescription
    state: Callable[[], PlantState | None]
    history: Callable[[], HistoryReader]
    config: Callable[[], ConfigDoc | None]
    agents: Callable[[], list[dict]]
    gateway: Any = None  # MeshGateway: toolbox queries (what-if)
    applied: Callable[[], Any] = lambda: None

    def latest_state(self) -> PlantState:
        state = self.state()
        if state is None:
            raise NotReady("no plant state has arrived yet from the Sensor agent (is it running?)")
        return state


# --- values out of a plant state, with references that find them again --------------------------------
def state_value(state: PlantState, block: str, convert: str, *, index: int | None = None, reduce: str | None = None,
                over: list[int] | None = None) -> float:  # fmt: skip
    """One output value (`index`) or a reduction (`reduce` over `over`, default all), converted."""
    raw = np.asarray([state.wet_bulb_k] if block == "wet_bulb_k" else state.outputs[block], dtype=float)
    if index is not None:
        return round(CONVERT[convert](float(raw[index])), 4)
    picked = raw if over is None else raw[over]
    return round(CONVERT[convert](float(REDUCE[reduce or "mean"](picked))), 4)


def state_fact(state: PlantState, name: str, block: str, convert: str, unit: str, text: str, *,
               index: int | None = None, reduce: str | None = None, over: list[int] | None = None) -> ChatFact:  # fmt: skip
    """A fact read from `state`; with both `index` and `reduce` it claims block[index] is the reduction over `over`."""
    value = state_value(state, block, convert, index=index, reduce=None if index is not None else reduce, over=over)
    ref = {"run_id": state.run_id, "step": state.step, "block": block, "convert": convert}
    if index is not None:
        ref["index"] = index
    if reduce is not None:
        ref["reduce"] = reduce
        if over is not None:
            ref["over"] = over
    return fact(name, value, unit, text, "state", **ref)


def index_fact(state: PlantState, name: str, what: str, block: str, index: int, per: int) -> ChatFact:
    """The 1-based cabinet / branch / tower number owning flat `index` of `block` (`per` entries each)."""
    number = index // per + 1
    return fact(name, number, "", f"{what} {number}", "state", run_id=state.run_id, step=state.step, block=block,
                index=index, per=per)  # fmt: skip


def system_fact(name: str, value: int | float, unit: str, text: str, attribute: str) -> ChatFact:
    return fact(name, value, unit, text, "system", attribute=attribute)


def question_fact(name: str, value: float | int | str, unit: str, text: str, words: str) -> ChatFact:
    return fact(name, value, unit, text, "question", words=words)


def plant_time_fact(state: PlantState) -> ChatFact:
    hours = round(state.time_s / 3600.0, 4)
    return fact("plant_time", hours, "h", f"plant time {hours:.1f} h into the run", "state", run_id=state.run_id,
                step=state.step, field="time_s", scale=1 / 3600.0)  # fmt: skip


def step_fact(state: PlantState, name: str = "step") -> ChatFact:
    return fact(name, state.step, "", f"plant step {state.step}", "state", run_id=state.run_id, step=state.step,
                field="step")  # fmt: skip


def out_of_range(book: FactBook, what: str, asked: int, count: int, words: str) -> str:
    """The answer to a question about a cabinet / branch / tower that does not exist."""
    book.add(question_fact(f"asked_{what}", asked, "", f"the question names {what} {asked}", words))
    book.add(system_fact(f"{what}_count", count, "", f"the plant has {count} of them", "branches" if what == "branch"
                         else f"{what}s"))  # fmt: skip
    book.add(system_fact(f"first_{what}", 1, "", f"{what}s are numbered from 1", "numbering"))
    plural = "branches" if what == "branch" else f"{what}s"
    return book.say(f"There is no {what} {{asked_{what}}}: this plant has {plural} {{first_{what}}} to "
                    f"{{{what}_count}}.")  # fmt: skip


def check_indices(intent: Intent, system: SystemDescription, book: FactBook) -> str | None:
    """An answer if the question names a cabinet, branch or tower that does not exist, else None."""
    for what, asked, count in (("cabinet", intent.cabinet, system.cabinets.count),
                               ("branch", intent.branch, system.cabinets.branches),
                               ("tower", intent.tower, system.towers.count)):  # fmt: skip
        if asked is not None and not 1 <= asked <= count:
            return out_of_range(book, what, asked, count, f"{what} {asked}")
    return None


# --- per-quantity layout: (block, convert, unit, plant-level reduction, per-cabinet or per-tower) ------------
def _groups(system: SystemDescription, per: str) -> tuple[int, int]:
    """(count, entries per item) of blade_temp_k per cabinet or cell_fan_power_w per tower."""
    if per == "cabinet":
        return system.cabinets.count, system.n_blade_groups // system.cabinets.count
    return system.towers.count, system.towers.cells


CABINET_BLOCKS = {
    "supply_temp": ("supply_temp_k", "c", "mean"), "supply_setpoint": ("applied_supply_setpoint_k", "c", "mean"),
    "return_temp": ("return_temp_k", "c", "mean"), "dp": ("cabinet_dp_pa", "psi", "mean"),
    "flow": ("secondary_flow_kg_s", "raw", "sum"), "it_cooling": ("cdu_heat_w", "kw", "sum"),
}  # fmt: skip
TOWER_BLOCKS = {"leaving_water": ("ct_leaving_temp_k", "c", "mean"), "lw_setpoint": ("applied_lw_setpoint_k", "c", "mean")}
PLANT_SCALARS = {
    "pump_power": ("pump_power_w", "kw"), "tower_power": ("ct_fan_power_w", "kw"), "it_power": ("it_power_w", "kw"),
    "heat_rejected": ("heat_rejected_w", "kw"), "wet_bulb": ("wet_bulb_k", "c"), "it_cooling": ("it_cooling_w", "kw"),
}  # fmt: skip


def overview(state: PlantState, system: SystemDescription, book: FactBook, applied) -> str:
    """A one-paragraph status: hottest blade group, compliance, powers, weather, controller."""
    n_cab, per = _groups(system, "cabinet")
    temps = np.asarray(state.outputs["blade_temp_k"])
    hot = int(np.argmax(temps))
    book.add(step_fact(state))
    book.add(plant_time_fact(state))
    book.add(state_fact(state, "hottest_blade", "blade_temp_k", "c", "degC", "hottest blade group", index=hot,
                        reduce="max"))  # fmt: skip
    book.add(index_fact(state, "hottest_cabinet", "cabinet", "blade_temp_k", hot, per))
    _in_band(state, book)
    for key, name, label in (("it_power", "it_power", "IT power"), ("tower_power", "tower_fan_power", "tower fans"),
                             ("pump_power", "pump_power", "pumps"), ("wet_bulb", "wet_bulb", "wet bulb")):  # fmt: skip
        block, conv = PLANT_SCALARS[key]
        book.add(state_fact(state, name, block, conv, QUANTITIES[key].unit, label, index=0))
    text = book.say("At step {step} ({plant_time} into the run) the hottest blade group is in cabinet {hottest_cabinet} "
                    "at {hottest_blade}; {in_band} of blade groups are inside the {band_low} to {band_high} band. "
                    "IT power {it_power}, tower fans {tower_fan_power}, pumps {pump_power}, wet bulb {wet_bulb}.")
    if applied is not None:
        book.add(fact("controller", applied.source_controller, "", f"the last action came from "
                      f"{applied.source_controller}", "decision", run_id=applied.run_id, step=applied.step,
                      path=["source_controller"]))  # fmt: skip
        text += book.say(" The last action came from {controller}.")
    return text


def _in_band(state: PlantState, book: FactBook) -> None:
    temps_c = np.asarray(state.outputs["blade_temp_k"], dtype=float) - K0
    pct = round(float(np.mean((temps_c > BAND_C[0]) & (temps_c < BAND_C[1])) * 100.0), 4)
    book.add(fact("in_band", pct, "%", "share of blade groups inside the band", "state", run_id=state.run_id,
                  step=state.step, block="blade_temp_k", band_c=list(BAND_C), reduce="in_band_pct"))  # fmt: skip
    book.add(system_fact("band_low", BAND_C[0], "degC", "compliance band low edge", "blade_band_low_c"))
    book.add(system_fact("band_high", BAND_C[1], "degC", "compliance band high edge", "blade_band_high_c"))


def answer_state(intent: Intent, src: ChatSources) -> Answer:
    """The current value of a quantity, for a cabinet or tower when one is named."""
    book = FactBook()
    problem = check_indices(intent, src.system, book)
    if problem:
        return Answer("state", problem, book.listed())
    state = src.latest_state()
    q = intent.quantity
    if q is None or (q == "blade_temp" and intent.cabinet is None):
        return Answer("state", overview(state, src.system, book, src.applied()), book.listed())
    return Answer("state", _quantity_text(q, intent, state, src.system, book), book.listed())


def _quantity_text(q: str, intent: Intent, state: PlantState, system: SystemDescription, book: FactBook) -> str:
    label, unit = QUANTITIES[q].label, QUANTITIES[q].unit
    book.add(step_fact(state))
    c, t = intent.cabinet, intent.tower
    n_cab, per = _groups(system, "cabinet")
    B = system.cabinets.branches
    if q == "blade_temp":
        if c is None:
            return overview(state, system, book, None)
        over = list(range((c - 1) * per, c * per))
        temps = np.asarray(state.outputs["blade_temp_k"])[over]
        book.add(question_fact("cabinet", c, "", f"cabinet {c}", f"cabinet {c}"))
        book.add(state_fact(state, "cabinet_blade_max", "blade_temp_k", "c", unit, "hottest blade group of the cabinet",
                            index=over[int(np.argmax(temps))], reduce="max", over=over))  # fmt: skip
        book.add(state_fact(state, "cabinet_blade_mean", "blade_temp_k", "c", unit, "mean blade temperature",
                            reduce="mean", over=over))  # fmt: skip
        return book.say("At step {step} cabinet {cabinet}'s hottest blade group is at {cabinet_blade_max}; "
                        "its blade groups average {cabinet_blade_mean}.")
    if q == "in_band":
        _in_band(state, book)
        return book.say("At step {step}, {in_band} of blade groups are inside the {band_low} to {band_high} band.")
    if q == "valve":
        if c is not None:
            cab = c
            book.add(question_fact("cabinet", c, "", f"cabinet {c}", f"cabinet {c}"))
        else:
            hot = int(np.argmax(np.asarray(state.outputs["blade_temp_k"])))
            cab = book.add(index_fact(state, "cabinet", "cabinet", "blade_temp_k", hot, per)).value
        parts = []
        for j in range(B):
            book.add(system_fact(f"branch_{j + 1}", j + 1, "", f"branch {j + 1}", "branch_number"))
            book.add(state_fact(state, f"valve_{j + 1}", "applied_valve_fraction", "raw", "fraction",
                                f"branch {j + 1} valve fraction", index=(cab - 1) * B + j))  # fmt: skip
            parts.append(f"branch {{branch_{j + 1}}} {{valve_{j + 1}}}")
        lead = "" if c else "Cabinet {cabinet} has the hottest blade group. "
        return book.say(lead + "At step {step} cabinet {cabinet}'s valve split is " + ", ".join(parts) + ".")
    if q in CABINET_BLOCKS and not (q == "it_cooling" and c is None):
        block, conv, reduce = CABINET_BLOCKS[q]
        if c is not None:
            book.add(question_fact("cabinet", c, "", f"cabinet {c}", f"cabinet {c}"))
            book.add(state_fact(state, "value", block, conv, unit, f"{label} of cabinet {c}", index=c - 1))
            return book.say(f"At step {{step}} cabinet {{cabinet}}'s {label} is {{value}}.")
        return _spread(state, book, block, conv, unit, label, reduce, n_cab, "cabinet")
    if q in TOWER_BLOCKS:
        block, conv, reduce = TOWER_BLOCKS[q]
        if t is not None:
            book.add(question_fact("tower", t, "", f"tower {t}", f"tower {t}"))
            book.add(state_fact(state, "value", block, conv, unit, f"{label} of tower {t}", index=t - 1))
            return book.say(f"At step {{step}} tower {{tower}}'s {label.removeprefix('tower ')} is {{value}}.")
        return _spread(state, book, block, conv, unit, label, reduce, system.towers.count, "tower")
    if q == "tower_power" and t is not None:
        m = system.towers.cells
        book.add(question_fact("tower", t, "", f"tower {t}", f"tower {t}"))
        book.add(state_fact(state, "value", "cell_fan_power_w", "kw", unit, f"fan power of tower {t}", reduce="sum",
                            over=list(range((t - 1) * m, t * m))))  # fmt: skip
        return book.say("At step {step} tower {tower}'s fans draw {value}.")
    if q == "pump_power" and c is not None:
        book.add(question_fact("cabinet", c, "", f"cabinet {c}", f"cabinet {c}"))
        book.add(state_fact(state, "value", "cdu_pump_power_w", "kw", unit, f"CDU pump power of cabinet {c}",
                            index=c - 1))  # fmt: skip
        return book.say("At step {step} cabinet {cabinet}'s CDU pump draws {value}.")
    if q == "it_power" and c is not None:
        book.add(question_fact("cabinet", c, "", f"cabinet {c}", f"cabinet {c}"))
        book.add(state_fact(state, "value", "branch_power_w", "kw", unit, f"IT power of cabinet {c}", reduce="sum",
                            over=list(range((c - 1) * B, c * B))))  # fmt: skip
        return book.say("At step {step} cabinet {cabinet} draws {value} of IT power.")
    if q == "cooling_power":
        book.add(state_fact(state, "fans", "ct_fan_power_w", "kw", unit, "tower fan power", index=0))
        book.add(state_fact(state, "pumps", "pump_power_w", "kw", unit, "pump power", index=0))
        total = round(book["fans"].value + book["pumps"].value, 4)
        book.add(fact("value", total, unit, "tower fans plus pumps", "state", run_id=state.run_id, step=state.step,
                      sum_of=["ct_fan_power_w", "pump_power_w"], convert="kw"))  # fmt: skip
        return book.say("At step {step} cooling takes {value}: tower fans {fans} and pumps {pumps}.")
    block, conv = PLANT_SCALARS[q]
    book.add(state_fact(state, "value", block, conv, unit, label, index=0))
    return book.say(f"At step {{step}} the {label} is {{value}}.")


def _spread(state, book: FactBook, block: str, conv: str, unit: str, label: str, reduce: str, count: int,
            what: str) -> str:  # fmt: skip
    values = np.asarray(state.outputs[block], dtype=float)
    hi, lo = int(np.argmax(values)), int(np.argmin(values))
    book.add(state_fact(state, "overall", block, conv, unit, f"{label}, {reduce} over {what}s", reduce=reduce))
    word = "total" if reduce == "sum" else "mean"
    if book.add(state_fact(state, "high", block, conv, unit, f"highest {label}", index=hi, reduce="max")).display == \
            book.add(state_fact(state, "low", block, conv, unit, f"lowest {label}", index=lo, reduce="min")).display:
        return book.say(f"At step {{step}} the {label} is {{overall}} ({word} over {what}s); every {what} reads "
                        "{high}.")  # fmt: skip
    book.add(index_fact(state, f"high_{what}", what, block, hi, 1))
    book.add(index_fact(state, f"low_{what}", what, block, lo, 1))
    return book.say(f"At step {{step}} the {label} is {{overall}} ({word} over {what}s), from {{low}} in {what} "
                    f"{{low_{what}}} to {{high}} in {what} {{high_{what}}}.")


def answer_rank(intent: Intent, src: ChatSources) -> Answer:
    """Which cabinet (or tower) is highest or lowest in a quantity; blade temperature by default."""
    book = FactBook()
    problem = check_indices(intent, src.system, book)
    if problem:
        return Answer("rank", problem, book.listed())
    state = src.latest_state()
    q = intent.quantity or "blade_temp"
    book.add(step_fact(state))
    if q != "blade_temp":
        return Answer("rank", _quantity_text(q, intent, state, src.system, book), book.listed())
    n_cab, per = _groups(src.system, "cabinet")
    temps = np.asarray(state.outputs["blade_temp_k"], dtype=float).reshape(n_cab, per)
    peaks = temps.max(axis=1)
    order = np.argsort(peaks)
    first, second = (int(order[0]), int(order[1])) if intent.low else (int(order[-1]), int(order[-2]))
    for name, cab in (("first", first), ("second", second)):
        over = list(range(cab * per, (cab + 1) * per))
        index = cab * per + int(np.argmax(temps[cab]))
        book.add(index_fact(state, f"{name}_cabinet", "cabinet", "blade_temp_k", index, per))
        book.add(state_fact(state, f"{name}_peak", "blade_temp_k", "c", "degC", f"hottest blade group of cabinet "
                            f"{cab + 1}", index=index, reduce="max", over=over))  # fmt: skip
    branch_per = per // src.system.cabinets.branches
    hot_index = first * per + int(np.argmax(temps[first]))
    book.add(fact("first_branch", (hot_index % per) // branch_per + 1, "", "branch holding that blade group", "state",
                  run_id=state.run_id, step=state.step, block="blade_temp_k", index=hot_index, per=branch_per,
                  modulo=src.system.cabinets.branches))  # fmt: skip
    book.add(state_fact(state, "plant_mean", "blade_temp_k", "c", "degC", "mean blade temperature", reduce="mean"))
    if intent.low:
        text = book.say("At step {step} cabinet {first_cabinet} runs coolest: its hottest blade group (branch "
                        "{first_branch}) is at {first_peak}. Next is cabinet {second_cabinet} at {second_peak}; "
                        "blade groups average {plant_mean}.")
    else:
        text = book.say("At step {step} cabinet {first_cabinet} runs hottest: its hottest blade group (branch "
                        "{first_branch}) is at {first_peak}. Next is cabinet {second_cabinet} at {second_peak}; "
                        "blade groups average {plant_mean}.")
    return Answer("rank", text, book.listed())


# --- history ------------------------------------------------------------------------------------------
def _history_convert(field_name: str) -> tuple[str, str]:
    if field_name.endswith("_k"):
        return "c", "degC"
    if field_name.endswith("_w"):
        return "kw", "kW"
    return "raw", "%"


def answer_compare(intent: Intent, src: ChatSources) -> Answer:
    """A quantity now against a time ago (one hour unless the question says), with the window's range."""
    book = FactBook()
    state = src.latest_state()
    q = QUANTITIES[intent.quantity or "blade_temp"]
    if q.history_field is None:
        fields = ", ".join(x.label for x in QUANTITIES.values() if x.history_field)
        return Answer("compare", f"History keeps plant-wide summaries only; I can compare: {fields}.", [])
    history = src.history()
    window_s = intent.window_s or 3600.0
    step_s = src.system.step_s
    back = max(1, int(round(window_s / step_s)))
    rows = history.states(start_step=max(0, state.step - back), end_step=state.step, fields=(q.history_field,),
                          run_id=state.run_id, limit=back + 2)  # fmt: skip
    rows = [r for r in rows if r[q.history_field] is not None]
    if len(rows) < 2:
        raise NotReady("history holds fewer than two plant states of this run yet")
    conv, unit = _history_convert(q.history_field)
    now, then = rows[-1], rows[0]

    def hist(name: str, row: dict, text: str) -> ChatFact:
        value = round(CONVERT[conv](float(row[q.history_field])), 4)
        return book.add(fact(name, value, unit, text, "history", run_id=state.run_id, step=row["step"],
                             field=q.history_field, convert=conv))  # fmt: skip

    hist("now", now, f"{q.label} at step {now['step']}")
    hist("then", then, f"{q.label} at step {then['step']}")
    minutes = round((now["time_s"] - then["time_s"]) / 60.0, 4)
    book.add(fact("window", minutes, "min", "time between the two samples (plant time)", "history", run_id=state.run_id,
                  steps=[then["step"], now["step"]], field="time_s", scale=1 / 60.0))  # fmt: skip
    change = round(book["now"].value - book["then"].value, 4)
    book.add(fact("change", change, "K" if unit == "degC" else unit, "now minus then", "history", derived="now - then"),
             unsigned=True)  # fmt: skip
    values = [CONVERT[conv](float(r[q.history_field])) for r in rows]
    for stat, fn in (("low", min), ("high", max)):
        book.add(fact(f"window_{stat}", round(fn(values), 4), unit, f"{stat}est {q.label} in the window", "history",
                      run_id=state.run_id, start_step=then["step"], end_step=now["step"], field=q.history_field,
                      stat="min" if stat == "low" else "max", convert=conv))  # fmt: skip
    trend = "up" if change > 0 else "down" if change < 0 else "unchanged"
    short = ""
    if (now["time_s"] - then["time_s"]) < window_s - step_s:
        book.add(question_fact("asked_window", intent.window_text or "one hour", "", "the window asked for",
                               intent.window_text or "one hour"))  # fmt: skip
        short = book.say(" History of this run only reaches back {window}, not {asked_window}.")
    if trend == "unchanged":
        text = book.say(f"The {q.label} is {{now}} now, the same as {{window}} earlier ({{then}}).")
    else:
        text = book.say(f"The {q.label} is {{now}} now against {{then}} {{window}} earlier: {trend} {{change}}. "
                        "Over that window it ranged from {window_low} to {window_high}.")
    return Answer("compare", text + short, book.listed())


# --- alerts, agents, controller, help -------------------------------------------------------------------
def answer_alerts(intent: Intent, src: ChatSources) -> Answer:
    book = FactBook()
    rows = src.history().alerts(active_only=True, limit=20)
    book.add(fact("active_alerts", len(rows), "", "alerts raised and not cleared", "alert", active_only=True))
    if not rows:
        return Answer("alerts", book.say("No alerts are active: {active_alerts} raised and not cleared."),
                      book.listed())
    parts = []
    for k, row in enumerate(rows[:5]):
        summary = f"{row['severity']} {row['kind']} at {row['location'] or 'the plant'}: {row['message'].rstrip('.')}"
        book.add(fact(f"alert_{k + 1}", summary, "", "an active alert", "alert", alert_id=row["alert_id"]))
        parts.append(f"{{alert_{k + 1}}}")
    text = book.say("{active_alerts} alert(s) active. " + "; ".join(parts) + ".")
    prescriptions = [r["prescription"] for r in rows[:5] if r.get("prescription")]
    if prescriptions:
        book.add(fact("advice", prescriptions[0], "", "the newest alert's prescription", "alert",
                      alert_id=rows[0]["alert_id"]))  # fmt: skip
        text += book.say(" Suggested: {advice}")
    return Answer("alerts", text, book.listed())


def answer_agents(intent: Intent, src: ChatSources) -> Answer:
    book = FactBook()
    agents = src.agents()
    alive = [a for a in agents if a["alive"]]
    down = [a["agent_id"] for a in agents if not a["alive"]]
    book.add(fact("alive", len(alive), "", "agents with a live token", "agents", field="alive"))
    book.add(fact("known", len(agents), "", "agents seen on the bus", "agents", field="count"))
    text = book.say("{alive} of {known} agents are alive.")
    if down:
        book.add(fact("down", ", ".join(down), "", "agents whose token is gone", "agents", field="down"))
        text += book.say(" Down: {down}.")
    advice = [x for a in agents for x in a.get("advice", [])]
    if advice:
        book.add(fact("advice", advice[0], "", "the Agent Monitor's first recommendation", "agents", field="advice"))
        text += book.say(" Monitor: {advice}")
    return Answer("agents", text, book.listed())


def answer_controller(intent: Intent, src: ChatSources) -> Answer:
    book = FactBook()
    doc = src.config()
    applied = src.applied()
    parts = []
    if doc is not None:
        book.add(fact("configured", doc.config.controller, "", "configured controller", "config", version=doc.version,
                      path=["controller"]))  # fmt: skip
        book.add(fact("mode", doc.config.mode, "", "auto or manual", "config", version=doc.version, path=["mode"]))
        book.add(fact("version", doc.version, "", "configuration version", "config", version=doc.version,
                      path=["version"]))  # fmt: skip
        parts.append("The configured controller is {configured} in {mode} mode (configuration version {version}).")
    if applied is not None:
        book.add(fact("acting", applied.source_controller, "", "controller of the last applied action", "decision",
                      run_id=applied.run_id, step=applied.step, path=["source_controller"]))  # fmt: skip
        book.add(fact("acting_step", applied.step, "", "step of the last applied action", "decision",
                      run_id=applied.run_id, step=applied.step, path=["step"]))  # fmt: skip
        parts.append("The last applied action (step {acting_step}) came from {acting}.")
        if applied.fallback and applied.fallback_reason:
            book.add(fact("reason", applied.fallback_reason, "", "why it was a fallback", "decision",
                          run_id=applied.run_id, step=applied.step, path=["fallback_reason"]))  # fmt: skip
            parts.append("It was a fallback: {reason}.")
    if not parts:
        raise NotReady("neither the configuration nor an applied action is known yet")
    return Answer("controller", book.say(" ".join(parts)), book.listed())


HELP = ("I answer from the plant's live state, its history, the decisions and the toolbox. Try: "
        "\"which cabinet runs hottest?\", \"tower power now vs an hour ago\", \"why did cabinet N open branch M?\", "
        "\"what if I raise the supply setpoint by N K?\", \"any alerts?\", \"are all agents up?\", "
        "\"which controller is running?\". I never change the plant: a request to change it comes back as a "
        "proposed command that an operator confirms through the authenticated control API.")


def answer_help(intent: Intent, src: ChatSources) -> Answer:
    return Answer("help", HELP, [])


"""Rebuild the explain-eval outside corpus (docs/explanations.md, "The outside corpus").

    .venv/bin/python docs/scripts/make_explain_corpus.py              # records + styles + mutations -> corpus.jsonl
    .venv/bin/python docs/scripts/make_explain_corpus.py --llm        # also (re)generate the SmolLM2 texts (slow)

Deterministic (seed 14): the twin runs are deterministic, every random choice draws from a
``random.Random`` seeded by the seed and the record's key. Writes
``lcmesh/mesh/tools/explain_eval/corpus/corpus.jsonl``; reads the hand-written texts (``hand.jsonl``)
and the cached SmolLM2 outputs (``llm.jsonl``, labelled by hand) from the same folder.

How it works:

- **records**: G36 and the load-proportional rule controller on lcopt-5 over the Frontier day in three
  scenarios (frontier, design-day, lcopt), a decision every 45 min for 12 h, one cabinet per decision
  (rotating): real ``explain-twin`` records (observation, action, previous action, facts).
- **split**: by decision, so no record is in both parts: the decisions are shuffled (seeded) and half go
  to ``dev``, half to ``test``. Some phrasings (verbs, ranking words, unit spellings) are drawn only for
  test records, so the test part holds wording the judge was never tuned on.
- **correct texts**: each record is written in 3 of 6 styles by writers that read a *view* of the
  record (its values in display units). Every number a writer prints goes through ``Num``, which asserts
  that the printed figure converts back (pint) to the record's value within half a unit in its last
  digit; directions come from the facts' changes with the renderer's dead bands; rankings from argmax.
- **planted errors**: a mutation changes one item of the view (a value, a unit, a direction, a ranking,
  a dimension, a physical effect) and the same writer, with the same random draws, writes the text
  again: the label is known by construction, and the mutated text must differ from the correct one.
"""

from __future__ import annotations

import argparse
import copy
import json
import random
import re
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import pint

ROOT = Path(__file__).resolve().parents[2]
CORPUS = ROOT / "lcmesh" / "mesh" / "tools" / "explain_eval" / "corpus"
SEED = 14
ERROR_FLAG = {
    "value_swap": "ungrounded_number", "value_off": "ungrounded_number", "constant_as_measure": "ungrounded_number",
    "wrong_unit": "ungrounded_number", "ranking_inverted": "wrong_ranking", "direction_inverted": "wrong_direction",
    "dimension_dropped": "missing_action_dimension", "wrong_cause": "physics",
}  # fmt: skip
STYLES = ("paper_prose", "log_line", "bullets", "kv_table", "mixed_units", "varied_verbs")
UREG = pint.UnitRegistry()
RHO_WATER = 0.997  # kg/L at the loop's ~25 degC, as the judge reads L/s

# --- records from real twin runs ---------------------------------------------------------------------

RUNS = (("rule", "frontier"), ("g36", "lcopt"), ("rule", "design-day"), ("g36", "frontier"), ("rule", "lcopt"))


def twin_records() -> list[dict]:
    """One explain-twin record per decision (every 45 min over 12 h, one rotating cabinet), per run."""
    from lcmesh.mesh.tools.explain_eval.pipeline import twin_explanation_records
    from lcmesh.twin.controllers import make_controller
    from lcmesh.twin.plant import Plant
    from lcmesh.twin.system import load_system
    from lcmesh.twin.traces import FRONTIER_DAY, load_trace

    system = load_system("lcopt-5")
    out = []
    for r, (controller, scenario) in enumerate(RUNS):
        trace = load_trace(FRONTIER_DAY, system, scenario=scenario)
        with Plant(system) as plant:
            for rec in twin_explanation_records(plant, trace, make_controller(controller, system), n_steps=2880,
                                                every_steps=180, levels=("short",)):  # fmt: skip
                step = int(re.search(r"step(\d+)", rec["id"]).group(1))
                cabinet = int(re.search(r"cabinet(\d+)", rec["id"]).group(1))
                if step == 0 or (step // 180 + r) % 5 != cabinet - 1:
                    continue
                key = f"{controller}-{scenario}-step{step}-cabinet{cabinet}"
                out.append({"record_key": key, "observation": rec["observation"], "action": rec["action"],
                            "previous_action": rec["previous_action"], "facts": rec["facts"]})  # fmt: skip
    return out


def split_of(records: list[dict]) -> dict[str, str]:
    keys = sorted(r["record_key"] for r in records)
    random.Random(SEED).shuffle(keys)
    return {k: ("dev" if i < len(keys) // 2 else "test") for i, k in enumerate(keys)}


# --- the view: what a writer believes -------------------------------------------------------------


@dataclass
class View:
    """A record's values in display units (temperatures degC, power kW, flow kg/s, dp psi, fractions)."""

    cabinet: int
    temps: list[float]
    powers: list[float]
    shares: list[float]
    valves: list[float]
    valve_dirs: list[str]
    supply_sp: float
    supply_dir: str
    supply_change: float
    supply_meas: float
    dp_sp: float
    dp_dir: str
    dp_change: float
    flow: float
    lw_sp: float
    lw_dir: str
    lw_change: float
    wet_bulb: float
    approach: float
    tower_water: float
    fan_kw: float
    cdu_heat: float
    pump_kw: float
    cop: float
    cab_power: float
    hottest: int
    coolest: int
    most_loaded: int
    least_loaded: int
    widest: int
    narrowest: int
    # what a mutation changed
    mislabel: dict[str, str] = field(default_factory=dict)  # item -> wrong unit written
    dropped: str | None = None  # "valve:j", "supply", "dp", "tower"
    wrong_effect: bool = False
    raw: dict = field(default_factory=dict)  # the record's own values (for the Num check), same units

    @property
    def n(self) -> int:
        return len(self.valves)

    def valves_equal(self) -> bool:
        return max(self.valves) - min(self.valves) < 0.01


def _dir(change: float, band: float) -> str:
    return "up" if change > band else "down" if change < -band else "hold"


def make_view(rec: dict) -> View:
    f = {x["name"]: x["value"] for x in rec["facts"]}
    n = len(rec["action"]["valve_fractions"])
    temps = [f[f"branch_{j + 1}_temp"] for j in range(n)]
    powers = [f[f"branch_{j + 1}_power"] for j in range(n)]
    valves = list(rec["action"]["valve_fractions"])
    prev = rec["previous_action"]["valve_fractions"]
    v = View(
        cabinet=int(f["cabinet"]), temps=temps, powers=powers,
        shares=[f[f"branch_{j + 1}_power_share"] for j in range(n)],
        valves=valves, valve_dirs=[_dir(a - b, 0.005) for a, b in zip(valves, prev)],
        supply_sp=f["supply_setpoint"], supply_change=f["supply_setpoint_change"],
        supply_dir=_dir(f["supply_setpoint_change"], 0.05), supply_meas=f["supply_temp"],
        dp_sp=f["dp_setpoint"], dp_change=f["dp_setpoint_change"], dp_dir=_dir(f["dp_setpoint_change"], 0.05),
        flow=f["secondary_flow"], lw_sp=f["tower_lw_setpoint"], lw_change=f["tower_lw_change"],
        lw_dir=_dir(f["tower_lw_change"], 0.05), wet_bulb=f["wet_bulb"], approach=f["tower_approach_setpoint"],
        tower_water=f["tower_leaving_temp"], fan_kw=f["tower_fan_power"], cdu_heat=f["cdu_heat"],
        pump_kw=f["cdu_pump_power"], cop=f["cooling_cop"], cab_power=f["cabinet_power"],
        hottest=max(range(n), key=lambda j: temps[j]), coolest=min(range(n), key=lambda j: temps[j]),
        most_loaded=max(range(n), key=lambda j: powers[j]), least_loaded=min(range(n), key=lambda j: powers[j]),
        widest=max(range(n), key=lambda j: valves[j]), narrowest=min(range(n), key=lambda j: valves[j]),
    )  # fmt: skip
    v.raw = copy.deepcopy({k: getattr(v, k) for k in _VALUE_FIELDS})
    return v


_VALUE_FIELDS = ("temps", "powers", "shares", "valves", "supply_sp", "supply_change", "supply_meas", "dp_sp",
                 "dp_change", "flow", "lw_sp", "lw_change", "wet_bulb", "approach", "tower_water", "fan_kw",
                 "cdu_heat", "pump_kw", "cop", "cab_power")  # fmt: skip


# --- printing numbers, checked --------------------------------------------------------------------

_PINT_UNITS = {"degC": UREG.degC, "degF": UREG.degF, "K": UREG.kelvin, "kW": UREG.kW, "W": UREG.W, "MW": UREG.MW,
               "psi": UREG.psi, "kPa": UREG.kPa, "bar": UREG.bar, "kg/s": UREG.kg / UREG.s}  # fmt: skip
_SHOWN = {"degC": "°C", "degF": "°F", "K": "K", "kW": "kW", "W": "W", "MW": "MW", "psi": "psi", "kPa": "kPa",
          "bar": "bar", "kg/s": "kg/s", "gpm": "gpm", "L/s": "L/s", "%": "%", "": ""}  # fmt: skip


class Num:
    """Prints values; in a correct text (``check``) each printed figure must convert back to the record's value
    within half a unit in its last digit (the corpus's verification of correct texts)."""

    def __init__(self, view: View, check: bool):
        self.v, self.check = view, check
        self.printed: list[list[str]] = []  # [figure, unit as written, unit meant]

    def __call__(self, item: str, value: float, unit: str, decimals: int, shown: str | None = None,
                 delta: bool = False, space: str = " ") -> str:  # fmt: skip
        """``value`` in the view's unit for ``item`` (degC, kW, kg/s, psi, fraction); printed in ``unit``."""
        x = _convert(value, item, unit, delta)
        text = f"{x:.{decimals}f}"
        label = self.v.mislabel.get(item, shown if shown is not None else _SHOWN[unit])
        if self.check:
            truth = _convert(_raw_value(self.v, item), item, unit, delta)
            assert abs(float(text) - truth) <= 0.5 * 10**-decimals + 1e-9, (item, text, truth, unit)
        self.printed.append([text, label, unit])
        return text + (space + label if label else "")


def _base_unit(item: str) -> str:
    if item.startswith(("temp", "supply", "lw", "wet", "tower_water")):
        return "degC"
    if item.startswith(("power", "cab_power", "fan", "cdu_heat", "pump")):
        return "kW"
    return {"flow": "kg/s", "dp_sp": "psi"}.get(item.split(":")[0], "")


def _convert(value: float, item: str, unit: str, delta: bool) -> float:
    base = _base_unit(item)
    if unit in ("", "%") or base == "" or unit == base:
        return value * 100 if unit == "%" else value
    if unit == "gpm":
        return value / RHO_WATER * 15.850323
    if unit == "L/s":
        return value / RHO_WATER
    if delta:  # a temperature difference: K and degC alike, degF 1.8 times
        return value * 1.8 if unit == "degF" else value
    return UREG.Quantity(value, _PINT_UNITS[base]).to(_PINT_UNITS[unit]).magnitude


def _raw_value(v: View, item: str) -> float:
    name, _, j = item.partition(":")
    val = v.raw[{"temp": "temps", "power": "powers", "share": "shares", "valve": "valves"}.get(name, name)]
    return val[int(j)] if j else val


# --- words ------------------------------------------------------------------------------------------

# (shared, test-only): test records may draw wording the judge never saw on dev
VERBS = {
    "up": (["raised", "increased", "nudged up", "bumped up", "lifted", "stepped up", "pushed up"],
           ["edged up", "notched up", "ratcheted up"]),
    "down": (["lowered", "trimmed", "eased", "cut", "reduced", "backed off", "pulled down", "dropped"],
             ["dialed back", "walked down", "shaved"]),
    "hold": (["held", "kept", "left unchanged", "held steady", "parked"], ["pinned", "left alone"]),
}  # fmt: skip
HOT = (["runs hottest", "is the hottest branch", "is the warmest"], ["is the most thermally stressed", "peaks highest"])
LOADED = (["carries the most load", "is the most loaded", "draws the most power"], ["does the heaviest work"])
WIDE = (["gets the largest valve fraction", "is opened the most", "gets the most flow"],
        ["the split is tilted toward", "the allocation emphasizes"])  # fmt: skip


def pick(rng: random.Random, pools: tuple[list[str], list[str]], test: bool) -> str:
    words = pools[0] + (pools[1] if test else [])
    return rng.choice(words)


def verb(rng: random.Random, pol: str, test: bool) -> str:
    return pick(rng, VERBS[pol], test)


def effect_sentence(v: View, rng: random.Random) -> str | None:
    """A physics statement about the action that moved (correct, or inverted when ``v.wrong_effect``)."""
    options = []
    if v.supply_dir != "hold":
        up = v.supply_dir == "up"
        right, wrong = (("saves tower fan power", "lets the blades run a little warmer"),
                        ("makes the tower fans work harder", "cools the blades")) if up else (
                       ("cools the blades", "makes the tower fans work harder"),
                       ("warms the blades", "saves tower fan power"))  # fmt: skip
        adj = "higher" if up else "lower"
        k = rng.randrange(2)
        options.append(f"The {adj} supply setpoint {(wrong if v.wrong_effect else right)[k]}.")
    if v.lw_dir != "hold":
        up = v.lw_dir == "up"
        right = "saves fan power" if up else "makes the fans work harder"
        wrong = "makes the fans work harder" if up else "saves fan power"
        adj = "higher" if up else "lower"
        options.append(f"A {adj} leaving-water setpoint {wrong if v.wrong_effect else right}.")
    for j, pol in enumerate(v.valve_dirs):
        if pol == "up":
            effect = "warms" if v.wrong_effect else "cools"
            options.append(f"Opening branch {j + 1}'s valve further {effect} its blades.")
        elif pol == "down":
            effect = "cools its blades" if v.wrong_effect else "lets its blades run a little warmer"
            options.append(f"Closing branch {j + 1}'s valve {effect}.")
    if not options:
        return None
    return rng.choice(options)


# --- the six writers ------------------------------------------------------------------------------


def b(j: int) -> int:
    return j + 1


def _valve_clause(v: View, num: Num, j: int, rng: random.Random, test: bool, unit: str = "") -> str:
    val = num(f"valve:{j}", v.valves[j], unit, 0 if unit == "%" else 2)
    pol = v.valve_dirs[j]
    return f"{verb(rng, pol, test)} at {val}" if pol == "hold" else f"{verb(rng, pol, test)} to {val}"


def write_paper_prose(v: View, num: Num, rng: random.Random, test: bool) -> str:
    parts = [f"For Cabinet {v.cabinet}, the agent's action distributes the coolant across the {v.n} blade groups."]
    valves = [f"Blade Group {b(j)}'s valve is {_valve_clause(v, num, j, rng, test)}" for j in range(v.n)
              if v.dropped != f"valve:{j}"]  # fmt: skip
    parts.append("; ".join(valves) + ".")
    h, m = v.hottest, v.most_loaded
    parts.append(f"Blade Group {b(h)} {pick(rng, HOT, test)} at {num(f'temp:{h}', v.temps[h], 'degC', 1)}, and "
                 f"Blade Group {b(m)} {pick(rng, LOADED, test)}, {num(f'power:{m}', v.powers[m], 'kW', 1)} of the "
                 f"cabinet's {num('cab_power', v.cab_power, 'kW', 1)}.")  # fmt: skip
    if v.dropped != "supply":
        parts.append(_supply_sentence(v, num, rng, test, "The CDU supply temperature setpoint"))
    if v.dropped != "dp":
        parts.append(_dp_sentence(v, num, rng, test, "The pump differential-pressure setpoint"))
    if v.dropped != "tower":
        parts.append(_tower_sentence(v, num, rng, test, "The cooling tower's leaving-water setpoint"))
    if (e := effect_sentence(v, rng)) is not None:
        parts.append(e)
    parts.append("Overall, the action balances thermal safety against cooling energy.")
    return " ".join(parts)


def _supply_sentence(v: View, num: Num, rng, test, subject: str, tu: str = "degC") -> str:
    sp = num("supply_sp", v.supply_sp, tu, 1)
    if v.supply_dir == "hold":
        return f"{subject} was {verb(rng, 'hold', test)} at {sp}."
    return (f"{subject} was {verb(rng, v.supply_dir, test)} by "
            f"{num('supply_change', abs(v.supply_change), 'degF' if tu == 'degF' else 'K', 1, delta=True)} to {sp}.")


def _dp_sentence(v: View, num: Num, rng, test, subject: str, pu: str = "psi", fu: str = "kg/s") -> str:
    dec = {"psi": 1, "kPa": 0, "bar": 2}[pu]
    sp = num("dp_sp", v.dp_sp, pu, dec)
    flow = num("flow", v.flow, fu, 1 if fu == "gpm" else 2)
    how = f"{verb(rng, 'hold', test)} at {sp}" if v.dp_dir == "hold" else f"{verb(rng, v.dp_dir, test)} to {sp}"
    return f"{subject} was {how}, driving {flow} of secondary flow."


def _tower_sentence(v: View, num: Num, rng, test, subject: str, tu: str = "degC") -> str:
    sp = num("lw_sp", v.lw_sp, tu, 1)
    wb = num("wet_bulb", v.wet_bulb, tu, 1)
    how = f"{verb(rng, 'hold', test)} at {sp}" if v.lw_dir == "hold" else f"{verb(rng, v.lw_dir, test)} to {sp}"
    return f"{subject} was {how}, against a {wb} wet bulb."


def write_log_line(v: View, num: Num, rng: random.Random, test: bool) -> str:
    arrows = rng.choice([{"up": "up", "down": "dn", "hold": "hold"}, {"up": "↑", "down": "↓", "hold": "="},
                         {"up": "raised", "down": "lowered", "hold": "held"}])  # fmt: skip
    sep = rng.choice([" | ", "; ", "  "])
    items = [f"cab{v.cabinet}"]
    valves = " ".join(f"b{b(j)}={num(f'valve:{j}', v.valves[j], '', 2)}({arrows[v.valve_dirs[j]]})"
                      for j in range(v.n) if v.dropped != f"valve:{j}")  # fmt: skip
    items.append(f"valves {valves}")
    if v.dropped != "supply":
        items.append(f"supply_sp {arrows[v.supply_dir]} {num('supply_sp', v.supply_sp, 'degC', 1, space='')}")
    if v.dropped != "dp":
        items.append(f"dp_sp {arrows[v.dp_dir]} {num('dp_sp', v.dp_sp, 'psi', 1, space='')}")
    if v.dropped != "tower":
        items.append(f"lwt_sp {arrows[v.lw_dir]} {num('lw_sp', v.lw_sp, 'degC', 1, space='')}")
    h = v.hottest
    items.append(f"hottest b{b(h)} {num(f'temp:{h}', v.temps[h], 'degC', 1, space='')}")
    items.append(f"flow {num('flow', v.flow, 'kg/s', 2, space='')}")
    return sep.join(items)


def write_bullets(v: View, num: Num, rng: random.Random, test: bool) -> str:
    lines = [f"Cabinet {v.cabinet} decision:"]
    for j in range(v.n):
        if v.dropped == f"valve:{j}":
            continue
        lines.append(f"- Branch {b(j)} valve: {_valve_clause(v, num, j, rng, test)} "
                     f"({num(f'share:{j}', v.shares[j], '%', 0)} of the load, "
                     f"{num(f'temp:{j}', v.temps[j], 'degC', 1)})")
    if v.dropped != "supply":
        lines.append("- " + _supply_sentence(v, num, rng, test, "Supply setpoint").rstrip("."))
    if v.dropped != "dp":
        lines.append("- " + _dp_sentence(v, num, rng, test, "Differential-pressure setpoint").rstrip("."))
    if v.dropped != "tower":
        lines.append("- " + _tower_sentence(v, num, rng, test, "Tower leaving-water setpoint").rstrip("."))
    h = v.hottest
    lines.append(f"- Branch {b(h)} {pick(rng, HOT, test)}; branch {b(v.most_loaded)} {pick(rng, LOADED, test)}")
    if (e := effect_sentence(v, rng)) is not None:
        lines.append("- " + e.rstrip("."))
    return "\n".join(lines)


def write_kv_table(v: View, num: Num, rng: random.Random, test: bool) -> str:
    words = {"up": "raised", "down": "lowered", "hold": "held"}
    if rng.random() < 0.5:  # a markdown table
        rows = ["| item | value | change |", "|---|---|---|"]
        rows += [f"| branch {b(j)} valve | {num(f'valve:{j}', v.valves[j], '', 2)} | {words[v.valve_dirs[j]]} |"
                 for j in range(v.n) if v.dropped != f"valve:{j}"]  # fmt: skip
        if v.dropped != "supply":
            rows.append(f"| supply setpoint | {num('supply_sp', v.supply_sp, 'degC', 1)} | {words[v.supply_dir]} |")
        if v.dropped != "dp":
            rows.append(f"| dp setpoint | {num('dp_sp', v.dp_sp, 'psi', 1)} | {words[v.dp_dir]} |")
        if v.dropped != "tower":
            rows.append(f"| leaving-water setpoint | {num('lw_sp', v.lw_sp, 'degC', 1)} | {words[v.lw_dir]} |")
        hot = num(f"temp:{v.hottest}", v.temps[v.hottest], "degC", 1)
        rows.append(f"| hottest branch | branch {b(v.hottest)} ({hot}) | |")
        rows.append(f"| secondary flow | {num('flow', v.flow, 'kg/s', 2)} | |")
        return f"Cabinet {v.cabinet}\n\n" + "\n".join(rows)
    lines = [f"cabinet: {v.cabinet}"]
    lines += [f"branch_{b(j)}_valve: {num(f'valve:{j}', v.valves[j], '', 2)} ({words[v.valve_dirs[j]]})"
              for j in range(v.n) if v.dropped != f"valve:{j}"]  # fmt: skip
    if v.dropped != "supply":
        lines.append(f"supply_setpoint: {num('supply_sp', v.supply_sp, 'degC', 1)} ({words[v.supply_dir]})")
    if v.dropped != "dp":
        lines.append(f"dp_setpoint: {num('dp_sp', v.dp_sp, 'psi', 1)} ({words[v.dp_dir]})")
    if v.dropped != "tower":
        lines.append(f"tower_lw_setpoint: {num('lw_sp', v.lw_sp, 'degC', 1)} ({words[v.lw_dir]})")
    lines.append(f"hottest_branch: {b(v.hottest)} at {num(f'temp:{v.hottest}', v.temps[v.hottest], 'degC', 1)}")
    loaded = num(f"power:{v.most_loaded}", v.powers[v.most_loaded], "kW", 1)
    lines.append(f"most_loaded_branch: {b(v.most_loaded)} at {loaded}")
    lines.append(f"wet_bulb: {num('wet_bulb', v.wet_bulb, 'degC', 1)}")
    return "\n".join(lines)


def write_mixed_units(v: View, num: Num, rng: random.Random, test: bool) -> str:
    tu = rng.choice(["degF", "K"])
    pu = rng.choice(["kPa", "bar"])
    fu = rng.choice(["gpm", "L/s"])
    tdec = 1
    parts = [f"Cabinet {v.cabinet}:"]
    vals = [f"branch {b(j)} {_valve_clause(v, num, j, rng, test, unit='%')}" for j in range(v.n)
            if v.dropped != f"valve:{j}"]  # fmt: skip
    parts.append("valve shares " + ", ".join(vals) + ".")
    h = v.hottest
    parts.append(f"Branch {b(h)} {pick(rng, HOT, test)} at {num(f'temp:{h}', v.temps[h], tu, tdec)} with "
                 f"{num(f'share:{h}', v.shares[h], '%', 0)} of the load.")  # fmt: skip
    if v.dropped != "supply":
        parts.append(_supply_sentence(v, num, rng, test, "The supply setpoint", tu=tu))
    if v.dropped != "dp":
        parts.append(_dp_sentence(v, num, rng, test, "The dp setpoint", pu=pu, fu=fu))
    if v.dropped != "tower":
        parts.append(_tower_sentence(v, num, rng, test, "The leaving-water setpoint", tu=tu))
    if (e := effect_sentence(v, rng)) is not None:
        parts.append(e)
    return " ".join(parts)


def write_varied_verbs(v: View, num: Num, rng: random.Random, test: bool) -> str:
    parts = [f"Cabinet {v.cabinet}."]
    for j in range(v.n):
        if v.dropped == f"valve:{j}":
            continue
        parts.append(f"The valve on branch {b(j)} was {_valve_clause(v, num, j, rng, test)}.")
    if v.dropped != "supply":
        parts.append(_supply_sentence(v, num, rng, test, "The supply setpoint"))
    if v.dropped != "dp":
        parts.append(_dp_sentence(v, num, rng, test, "The dp setpoint"))
    if v.dropped != "tower":
        parts.append(_tower_sentence(v, num, rng, test, "The tower setpoint"))
    if not v.valves_equal():
        w = pick(rng, WIDE, test)
        if w.startswith("the "):
            parts.append(f"With these fractions {w} branch {b(v.widest)}.")
        else:
            parts.append(f"Branch {b(v.widest)} {w}.")
    parts.append(f"Branch {b(v.hottest)} {pick(rng, HOT, test)} at "
                 f"{num(f'temp:{v.hottest}', v.temps[v.hottest], 'degC', 1)}.")  # fmt: skip
    if (e := effect_sentence(v, rng)) is not None:
        parts.append(e)
    return " ".join(parts)


WRITERS = {"paper_prose": write_paper_prose, "log_line": write_log_line, "bullets": write_bullets,
           "kv_table": write_kv_table, "mixed_units": write_mixed_units,
           "varied_verbs": write_varied_verbs}  # fmt: skip


# --- mutations ----------------------------------------------------------------------------------------


def mutate(v: View, kind: str, rng: random.Random, style: str) -> tuple[View, str] | None:
    """A copy of the view with one planted error of ``kind`` and its description, or None if not applicable."""
    m = copy.deepcopy(v)
    n = v.n
    if kind == "value_swap":
        options = []
        for a, c in ((v.hottest, v.coolest), (v.coolest, v.hottest)):
            if abs(v.temps[a] - v.temps[c]) > 0.3:
                options.append(("temp", a, c))
        if abs(v.supply_sp - v.lw_sp) > 0.3:
            options.append(("supply_sp", "lw_sp", None))
        if abs(v.temps[v.hottest] - v.supply_sp) > 0.3:
            options.append(("temp_from_supply", v.hottest, None))
        if abs(v.lw_sp - v.wet_bulb) > 0.3:
            options.append(("wet_bulb", "lw_sp", None))
        if not options:
            return None
        what = rng.choice(options)
        if what[0] == "temp":
            m.temps[what[1]] = v.temps[what[2]]
            return m, f"branch {what[1] + 1}'s temperature given as branch {what[2] + 1}'s"
        if what[0] == "temp_from_supply":
            m.temps[what[1]] = v.supply_sp
            return m, f"the supply setpoint given as branch {what[1] + 1}'s temperature"
        setattr(m, what[0], getattr(v, what[1]))
        return m, f"{what[1]} given as {what[0]}"
    if kind == "value_off":
        item = rng.choice(["flow", "temp", "lw_sp", "supply_sp", "power"] if style != "mixed_units" else
                          ["temp", "lw_sp", "supply_sp", "flow"])  # fmt: skip
        u = rng.uniform(0.01, 0.10) * rng.choice([-1, 1])
        if item == "temp":
            j = v.hottest
            new = v.temps[j] * (1 + u)
            if abs(round(new, 1) - round(v.temps[j], 1)) < 0.25:
                new = v.temps[j] + (0.3 if u > 0 else -0.3)
            m.temps[j] = new
            return m, f"branch {j + 1}'s temperature off by {100 * (new / v.temps[j] - 1):+.1f} %"
        if item == "power":
            j = v.most_loaded
            m.powers[j] = v.powers[j] * (1 + u)
            if abs(m.powers[j] - v.powers[j]) < 0.25:
                return None
            return m, f"branch {j + 1}'s power off by {100 * u:+.1f} %"
        old = getattr(v, item)
        new = old * (1 + u)
        step = 0.03 if item == "flow" else 0.25
        if abs(new - old) < step:
            new = old + (step if u > 0 else -step) * 1.2
        setattr(m, item, new)
        return m, f"{item} off by {100 * (new / old - 1):+.1f} %"
    if kind == "constant_as_measure":
        j = v.hottest
        const = 40.0 if abs(v.temps[j] - 40.0) > 0.5 else 20.0
        m.temps[j] = const
        return m, f"the {const:.0f} °C band limit quoted as branch {j + 1}'s temperature"
    if kind == "wrong_unit":
        if style == "log_line":
            return None
        # not the flow in mixed units: L/s written as kg/s is 0.3 % off, no error
        with_flow = style not in ("kv_table", "mixed_units")
        item = rng.choice(["supply_sp", "dp_sp", "lw_sp"] + (["flow"] if with_flow else []))
        if style == "mixed_units":
            wrong = {"supply_sp": "°C", "lw_sp": "°C", "dp_sp": "psi", "flow": "kg/s"}[item]
        else:
            wrong = {"supply_sp": rng.choice(["K", "°F"]), "lw_sp": rng.choice(["K", "°F"]),
                     "dp_sp": rng.choice(["kPa", "bar"]), "flow": rng.choice(["gpm", "L/min"])}[item]  # fmt: skip
        m.mislabel[item] = wrong
        return m, f"{item} written with unit {wrong}"
    if kind == "ranking_inverted":
        options = []
        if abs(v.temps[v.hottest] - v.temps[v.coolest]) > 0.3:
            options.append("hottest")
        if v.powers[v.most_loaded] > 1.1 * v.powers[v.least_loaded] and style in ("paper_prose", "bullets", "kv_table"):
            options.append("most_loaded")
        if v.valves[v.widest] - v.valves[v.narrowest] > 0.03 and style == "varied_verbs":
            options.append("widest")
        if not options:
            return None
        what = rng.choice(options)
        other = {"hottest": "coolest", "most_loaded": "least_loaded", "widest": "narrowest"}[what]
        setattr(m, what, getattr(v, other))
        return m, f"branch {getattr(v, other) + 1} (the {other.replace('_', ' ')}) named the {what.replace('_', ' ')}"
    if kind == "direction_inverted":
        dims = [d for d, pol in (("supply", v.supply_dir), ("dp", v.dp_dir), ("tower", v.lw_dir)) if pol != "hold"]
        dims += [f"valve:{j}" for j in range(n) if v.valve_dirs[j] != "hold"]
        if not dims:
            dims = ["supply", "tower"] + [f"valve:{j}" for j in range(n)]
        d = rng.choice(dims)
        flip = {"up": "down", "down": "up", "hold": rng.choice(["up", "down"])}
        if d.startswith("valve:"):
            j = int(d[6:])
            m.valve_dirs[j] = flip[v.valve_dirs[j]]
            return m, f"branch {j + 1}'s valve said {m.valve_dirs[j]}, went {v.valve_dirs[j]}"
        attr = {"supply": "supply_dir", "dp": "dp_dir", "tower": "lw_dir"}[d]
        setattr(m, attr, flip[getattr(v, attr)])
        if getattr(v, attr) == "hold":  # a held setpoint said to move: state a change of 0.1-0.5 K
            change = {"supply": "supply_change", "tower": "lw_change"}.get(d)
            if change is not None:
                setattr(m, change, 0.0)
        return m, f"the {d} setpoint said {getattr(m, attr)}, went {getattr(v, attr)}"
    if kind == "dimension_dropped":
        m.dropped = rng.choice([f"valve:{j}" for j in range(n)] + ["supply", "dp", "tower"])
        return m, f"the {m.dropped} dimension left out"
    if kind == "wrong_cause":
        if style not in ("paper_prose", "bullets", "varied_verbs", "mixed_units") or effect_sentence(v, rng) is None:
            return None
        m.wrong_effect = True
        return m, "a physical effect inverted"
    raise ValueError(kind)


# --- assembling ---------------------------------------------------------------------------------------


def record_fields(rec: dict) -> dict:
    return {k: rec[k] for k in ("observation", "action", "previous_action", "facts")}


def build(records: list[dict]) -> list[dict]:
    split = split_of(records)
    kinds = list(ERROR_FLAG)
    items = []
    used = dict.fromkeys(kinds, 0)
    for r_i, rec in enumerate(sorted(records, key=lambda r: r["record_key"])):
        key = rec["record_key"]
        test = split[key] == "test"
        view = make_view(rec)
        styles = [STYLES[(r_i + s) % len(STYLES)] for s in (0, 2, 4)]
        for s_i, style in enumerate(styles):
            seed = zlib.crc32(f"{SEED}/{key}/{style}".encode())
            num = Num(view, check=True)
            text = WRITERS[style](view, num, random.Random(seed), test)
            base = {"record_key": key, "split": split[key], "style": style, "source": "generated"}
            items.append(base | {"id": f"{key}/{style}/correct", "explanation": text, "correct": True,
                                 "error": None, "expected_flags": [], "numbers": num.printed,
                                 "verified": "generated from the record's values; every printed number checked "
                                             "against the record within half a unit in its last digit"})  # fmt: skip
            n_mut = 2 if s_i < 2 else 1
            done = 0
            for kind in sorted(kinds, key=lambda x: (used[x], kinds.index(x))):  # the least used kinds first
                if done == n_mut:
                    break
                mrng = random.Random(seed ^ 0x5EED)
                got = mutate(view, kind, mrng, style)
                if got is None:
                    continue
                mview, what = got
                mtext = WRITERS[style](mview, Num(mview, check=False), random.Random(seed), test)
                if mtext == text:
                    continue
                items.append(base | {"id": f"{key}/{style}/{kind}", "explanation": mtext, "correct": False,
                                     "error": kind, "error_detail": what, "expected_flags": [ERROR_FLAG[kind]],
                                     "verified": "mutation of the correct text: label by construction"})  # fmt: skip
                done += 1
                used[kind] += 1
    return items


def attach_external(items: list[dict], records: dict[str, dict], split: dict[str, str], name: str) -> None:
    path = CORPUS / name
    if not path.is_file():
        return
    for line in path.read_text().splitlines():
        if not line.strip():
            continue
        h = json.loads(line)
        if "expected_flags" not in h:
            raise SystemExit(f"{name}: {h['id']} has no hand label (`expected_flags`)")
        if h["record_key"] not in records:
            raise SystemExit(f"{name}: {h['id']} names unknown record {h['record_key']}")
        items.append({"id": h["id"], "record_key": h["record_key"], "split": split[h["record_key"]],
                      "style": h["style"], "source": h.get("source", name.split(".")[0]),
                      "explanation": h["explanation"], "correct": not h["expected_flags"],
                      "error": h.get("error"), "expected_flags": sorted(h["expected_flags"]),
                      "verified": h.get("verified", "hand-labelled")} | (
                      {"prompt": h["prompt"]} if "prompt" in h else {}))  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--llm", action="store_true", help="regenerate llm_raw.jsonl with the base SmolLM2 (slow)")
    ap.add_argument("--records-only", action="store_true", help="print the records' views and stop")
    args = ap.parse_args()
    CORPUS.mkdir(parents=True, exist_ok=True)
    records = twin_records()
    by_key = {r["record_key"]: r for r in records}
    split = split_of(records)
    if args.records_only:
        for r in records:
            v = make_view(r)
            print(split[r["record_key"]], r["record_key"], json.dumps({k: getattr(v, k) for k in _VALUE_FIELDS} | {
                "dirs": [v.valve_dirs, v.supply_dir, v.dp_dir, v.lw_dir]}, default=lambda x: round(x, 3)))
        return
    if args.llm:
        from llm_texts import generate  # docs/scripts/llm_texts.py

        generate(records, split, CORPUS / "llm_raw.jsonl")  # labelled by hand into llm.jsonl
    items = build(records)
    attach_external(items, by_key, split, "hand.jsonl")
    attach_external(items, by_key, split, "llm.jsonl")
    with (CORPUS / "records.jsonl").open("w") as fh:
        for r in sorted(records, key=lambda r: r["record_key"]):
            fh.write(json.dumps({"record_key": r["record_key"], "split": split[r["record_key"]]} | record_fields(r))
                     + "\n")
    with (CORPUS / "corpus.jsonl").open("w") as fh:
        for it in items:
            fh.write(json.dumps(it, ensure_ascii=False) + "\n")
    counts: dict[str, int] = {}
    for it in items:
        for key in (f"split:{it['split']}", f"style:{it['style']}", f"error:{it['error']}", f"source:{it['source']}"):
            counts[key] = counts.get(key, 0) + 1
    print(f"{len(records)} records, {len(items)} texts")
    for key in sorted(counts):
        print(f"  {key}: {counts[key]}")


if __name__ == "__main__":
    main()

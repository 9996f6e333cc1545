"""The assistant's answers, written from tool results only, in the operator's language.

``write(tool, result, args, book, index, lang)`` turns one tool's result into sentences: every
number it prints is a ``ChatFact`` (value, unit, the entity it belongs to and its quantity), placed
through a digit-free template, so the text can only cite what the tool returned. The semantic guard
then checks that each number sits next to the right entity and quantity and that rankings and
directions agree.

The fixed words come from the catalog in ``language.py`` (English, Spanish, German, French):
phrases, quantity labels, entity names ("branch 2 of cabinet 3" is "rama 2 del gabinete 3",
"Zweig 2 von Schrank 3", "branche 2 de l'armoire 3"). A fact's ``entity`` stays the canonical
English name in every language; units stay symbols and decimals print with ".". Quoted text (an
alert, an explanation, a tool's refusal) is cited as the mesh wrote it, in English.
"""

from __future__ import annotations

import re

from collections.abc import Callable
from typing import Any

from lcmesh.assistant.facts import FactBook, fact, format_value
from lcmesh.assistant.language import ENTITY_FORMS, FOLDS, SUPERLATIVES, phrase, quantity_label
from lcmesh.mesh.tools.plant_data import QUANTITIES

TOOL_SOURCE = "tool"


class Writer:
    """Adds the facts of one answer with unique names and returns template fragments that cite them."""

    def __init__(self, book: FactBook, tool: str, step: int | None = None, lang: str = "en"):
        self.book, self.tool, self.lang, self._n = book, tool, lang, 0
        self.where = {} if step is None else {"step": step}  # the plant step the tool read, for re-checking

    def value(self, value: float | int | str, unit: str, text: str, *, entity: str | None = None,
              quantity: str | None = None, unsigned: bool = False, **ref: Any) -> str:  # fmt: skip
        """A placeholder for `value` (rounded as displayed), bound to `entity` and `quantity`."""
        self._n += 1
        name = f"{self.tool}_{self._n}"
        if isinstance(value, float):
            value = round(value, 4)
        self.book.add(fact(name, value, unit, text, TOOL_SOURCE, entity=entity, quantity=quantity,
                           tool=self.tool, **self.where, **ref), unsigned=unsigned)  # fmt: skip
        return "{" + name + "}"

    def quote(self, text: str, what: str, **ref: Any) -> str:
        """Text cited verbatim (an alert, an explanation), in quotes: the guard reads it as a quote, not a claim."""
        return "“" + self.value(text, "", what, quantity="quote", **ref) + "”"

    def entity(self, name: str) -> str:
        """An entity's name ("branch 2 of cabinet 3") in the answer's language, each of its numbers a fact."""
        return self.entity_forms(name)["bare"]

    def entity_forms(self, name: str) -> dict[str, str]:
        """The name bare, with its article ("the"), after "of" and after "in", citing one set of number facts."""
        words = name.split()
        segments = [s.rpartition(" ") for s in name.split(" of ")]
        forms = ENTITY_FORMS[self.lang]
        if not all(kind in forms and number.isdigit() for kind, _, number in segments):
            out = []  # a name the catalog does not know: its words as they are
            for k, word in enumerate(words):
                out.append(self.value(int(word), "", f"{words[k - 1]} number", entity=name, quantity="number")
                           if word.isdigit() else word)  # fmt: skip
            bare = " ".join(out)
            return {"bare": bare, "the": bare, "of": f"of {bare}", "in": f"in {bare}"}
        numbers = [self.value(int(number), "", f"{kind.split()[-1]} number", entity=name, quantity="number")
                   for kind, _, number in segments]  # fmt: skip
        outer = "".join(f" {forms[kind][2]} {n}" for (kind, _, _), n in zip(segments[1:], numbers[1:]))
        inner = forms[segments[0][0]]
        return {form: f"{inner[i]} {numbers[0]}{outer}" for i, form in enumerate(("bare", "the", "of", "in"))}

    def entity_slots(self, name: str, prefix: str = "entity") -> dict[str, str]:
        """Template slots for an entity: {entity}, {entity_the}, {entity_of}, {entity_in}."""
        forms = self.entity_forms(name)
        return {prefix: forms["bare"], f"{prefix}_the": forms["the"], f"{prefix}_of": forms["of"],
                f"{prefix}_in": forms["in"]}  # fmt: skip

    def t(self, key: str, **slots: str) -> str:
        """The catalog phrase `key` in the answer's language."""
        return phrase(self.lang, key, **slots)

    def label(self, quantity: str, english: str) -> dict[str, str]:
        """Slots {label} and {the_label} of a quantity, and its gender (for agreeing superlatives)."""
        label, the_label, gender = quantity_label(self.lang, quantity, english)
        return {"label": label, "the_label": the_label, "gender": gender}

    def say(self, template: str) -> str:
        return self.book.say(template)


def _label(quantity: str) -> str:
    return QUANTITIES[quantity].label if quantity in QUANTITIES else quantity.replace("_", " ")


def _fold_word(reduce: str) -> str:
    return FOLDS["en"][reduce][0]


# --- one writer per tool --------------------------------------------------------------------------------------
def _plant_state(w: Writer, r: dict, args: dict) -> str:
    q, unit, values = r["quantity"], r["unit"], r["values"]
    label = r["label"]
    names = w.label(q, label)
    if r["per"] == "plant":
        value = w.value(values[0]["value"], unit, label, entity="plant", quantity=q)
        return w.say(w.t("state.plant", value=value, **names))
    if len(values) == 1:
        v = values[0]
        slots = w.entity_slots(v["entity"])
        value = w.value(v["value"], unit, label, entity=v["entity"], quantity=q)
        return w.say(w.t("state.one", value=value, **slots, **names))
    items = ", ".join(w.t("item", entity=w.entity(v["entity"]),
                          value=w.value(v["value"], unit, label, entity=v["entity"], quantity=q))
                      for v in values[:15])  # fmt: skip
    word = _fold_word(r["plant_reduce"])
    fold = FOLDS[w.lang][r["plant_reduce"]][0]
    if r.get("selected") is not None and (args.get("cabinet") or args.get("tower")):
        scope = values[0]["entity"].split(" of ")[-1]
        slots = w.entity_slots(scope)
        value = w.value(r["selected"], unit, f"{word} {label}", entity=scope, quantity=q)
        return w.say(w.t("state.scope", value=value, fold=fold, items=items, **slots, **names))
    value = w.value(r["plant"], unit, f"{word} {label}", entity="plant", quantity=q)
    return w.say(w.t("state.all", value=value, fold=fold, items=items, **names))


def _overview(w: Writer, r: dict, args: dict) -> str:
    hot = r["hottest"]
    slots = w.entity_slots(hot["entity"])
    text = w.t("overview", **slots,
               value=w.value(hot["value"], "degC", "hottest blade group", entity=hot["entity"], quantity="blade_temp",
                             extreme="highest"),
               pct=w.value(r["in_band_pct"], "%", "share in band", entity="plant", quantity="in_band"),
               it=w.value(r["it_power_kw"], "kW", "IT power", entity="plant", quantity="it_power"),
               fans=w.value(r["tower_power_kw"], "kW", "tower fans", entity="plant", quantity="tower_power"),
               pumps=w.value(r["pump_power_kw"], "kW", "pumps", entity="plant", quantity="pump_power"),
               wb=w.value(r["wet_bulb_c"], "degC", "wet bulb", entity="plant", quantity="wet_bulb"))  # fmt: skip
    if r.get("pue") is not None:
        text += w.t("overview.pue", pue=w.value(r["pue"], "pue", "cooling PUE", entity="plant", quantity="pue"))
    text += "."
    if r.get("controller"):
        text += w.t("overview.controller", controller=w.value(r["controller"], "", "controller",
                                                              quantity="controller"))  # fmt: skip
    return w.say(text)


def _history_stat(w: Writer, r: dict, args: dict) -> str:
    q, unit, label = r["quantity"], r["unit"], r["label"]
    names = w.label(q, label)
    minutes = w.value(r["minutes_covered"], "min", "minutes of history covered", quantity="window")
    delta_unit = "K" if unit == "degC" else unit
    stat = r["stat"]
    if stat == "change":
        trend = "trend.up" if r["change"] > 0 else "trend.down" if r["change"] < 0 else "trend.flat"
        change = w.value(r["change"], delta_unit, f"change of the {label}", entity="plant", quantity=q,
                         unsigned=True, stat="change")  # fmt: skip
        text = w.t("history.change", minutes=minutes, trend=w.t(trend, change=change), **names,
                   first=w.value(r["first"], unit, f"{label} then", entity="plant", quantity=q, stat="first"),
                   last=w.value(r["last"], unit, f"{label} now", entity="plant", quantity=q, stat="last"))  # fmt: skip
    else:
        text = w.t("history.stat", minutes=minutes, word=w.t(f"stat.{stat}"), **names,
                   value=w.value(r[stat], unit, f"{stat} {label}", entity="plant", quantity=q, stat=stat),
                   min=w.value(r["min"], unit, f"min {label}", entity="plant", quantity=q, stat="min"),
                   max=w.value(r["max"], unit, f"max {label}", entity="plant", quantity=q, stat="max"),
                   last=w.value(r["last"], unit, f"{label} now", entity="plant", quantity=q, stat="last"))  # fmt: skip
    if r["minutes_covered"] < r["minutes_asked"] - 1:
        text += w.t("history.short", asked=w.value(r["minutes_asked"], "min", "window asked for", quantity="window"))
    return w.say(text)


def _rank(w: Writer, r: dict, args: dict) -> str:
    q, unit, label = r["quantity"], r["unit"], r["label"]
    names = w.label(q, label)
    ranked = r["ranked"]
    order = r["order"]
    first = ranked[0]
    slots = w.entity_slots(first["entity"])
    superlative = SUPERLATIVES[w.lang][order]
    text = w.t("rank.first", order=superlative.get(names["gender"], next(iter(superlative.values()))), **slots,
               **names, value=w.value(first["value"], unit, label, entity=first["entity"], quantity=q, rank=1,
                                      order=order))  # fmt: skip
    if len(ranked) > 1:
        items = ", ".join(w.t("item", entity=w.entity(v["entity"]),
                              value=w.value(v["value"], unit, label, entity=v["entity"], quantity=q, rank=k + 2,
                                            order=order))
                          for k, v in enumerate(ranked[1:]))  # fmt: skip
        text += w.t("rank.next", items=items)
    if r.get("plant") is not None:
        word = _fold_word(r["plant_reduce"])
        fold, fold_head = FOLDS[w.lang][r["plant_reduce"]]
        text += w.t("rank.plant", fold=fold, fold_head=fold_head,
                    count=w.value(r["count"], "", "entities ranked", quantity="count"),
                    value=w.value(r["plant"], unit, f"{word} {label}", entity="plant", quantity=q))  # fmt: skip
    return w.say(text)


def _compare(w: Writer, r: dict, args: dict) -> str:
    q, unit, label = r["quantity"], r["unit"], r["label"]

    def extreme(entity: str) -> dict:
        return {"extreme": "highest"} if entity == r["highest"] else {"extreme": "lowest"} if entity == r["lowest"] \
            else {}

    items = ", ".join(w.t("item", entity=w.entity(v["entity"]),
                          value=w.value(v["value"], unit, label, entity=v["entity"], quantity=q,
                                        **extreme(v["entity"])))
                      for v in r["values"])  # fmt: skip
    delta_unit = "K" if unit == "degC" else unit
    if format_value(r["difference"], delta_unit) == format_value(0.0, delta_unit):  # no "tower 1 is above tower 1"
        return w.say(w.t("compare.equal", items=items, **w.label(q, label)))
    highest = w.entity_slots(r["highest"], "highest")
    diff = w.value(r["difference"], delta_unit, "highest minus lowest", quantity=q, unsigned=True,
                   entity=f"{r['highest']} minus {r['lowest']}")  # fmt: skip
    lowest = w.entity_slots(r["lowest"], "lowest")
    highest_cap = highest["highest"][:1].upper() + highest["highest"][1:]
    return w.say(w.t("compare", items=items, diff=diff, highest_cap=highest_cap, **highest, **lowest,
                     **w.label(q, label)))  # fmt: skip


def _band_count(w: Writer, r: dict, args: dict) -> str:
    lo = w.value(r["low_c"], "degC", "band low edge", quantity="band_low")
    hi = w.value(r["high_c"], "degC", "band high edge", quantity="band_high")
    text = w.t("band", low=lo, high=hi,
               inside=w.value(r["inside"], "", "blade groups inside the band", quantity="inside"),
               total=w.value(r["total"], "", "blade groups", quantity="total"),
               pct=w.value(r["in_band_pct"], "%", "share inside", entity="plant", quantity="in_band"),
               above=w.value(r["above"], "", "blade groups above the band", quantity="above"),
               below=w.value(r["below"], "", "blade groups below the band", quantity="below"))  # fmt: skip
    if r["outside"]:
        items = ", ".join(w.t("band.item", entity=w.entity(v["entity"]),
                              value=w.value(v["value"], "degC", "blade temperature", entity=v["entity"],
                                            quantity="blade_temp"))
                          for v in r["outside"][:5])  # fmt: skip
        text += w.t("band.outside", items=items)
    return w.say(text)


def _energy_balance(w: Writer, r: dict, args: dict) -> str:
    def v(key: str, label: str, quantity: str, unit: str = "kW") -> str:
        return w.value(r[key], unit, label, entity="plant", quantity=quantity)

    text = w.t("energy", it=v("it_power_kw", "IT power", "it_power"),
               cdu=v("cdu_heat_kw", "heat removed at the CDUs", "cdu_heat"),
               rejected=v("heat_rejected_kw", "heat rejected", "heat_rejected"))  # fmt: skip
    if r.get("rejected_over_it_pct") is not None:
        text += w.t("energy.share", pct=v("rejected_over_it_pct", "heat rejected over IT load", "rejected_over_it",
                                          "%"))  # fmt: skip
    text += w.t("energy.cooling", cooling=v("cooling_power_kw", "cooling power", "cooling_power"),
                fans=v("tower_power_kw", "tower fans", "tower_power"),
                pumps=v("pump_power_kw", "pumps", "pump_power"))  # fmt: skip
    if r.get("pue") is not None:
        text += w.t("energy.pue", pue=v("pue", "cooling PUE", "pue", "pue"))
    return w.say(text + ".")


def _alerts(w: Writer, r: dict, args: dict) -> str:
    count = w.value(r["count"], "", "alerts", quantity="count")
    state = "active" if r["active_only"] else "recorded"
    if not r["alerts"]:
        return w.say(w.t(f"alerts.none.{state}", count=count))
    where, plant = w.t("alert.where"), w.t("alert.plant")
    items = "; ".join(w.quote(f"{a['severity']} {a['kind']} {where} {a['location'] or plant}: "
                              f"{a['message'].rstrip('.')}", "an alert", alert_id=a["alert_id"])
                      for a in r["alerts"][:5])  # fmt: skip
    text = w.t(f"alerts.{state}", count=count, items=items)
    advice = next((a["prescription"] for a in r["alerts"] if a.get("prescription")), None)
    if advice:
        text += w.t("alerts.advice", quote=w.quote(advice, "the newest alert's advice"))
    return w.say(text)


def _decision(w: Writer, r: dict, args: dict) -> str:
    if not r["found"]:
        return w.say(w.t("decision.none", count=w.value(r["searched_decisions"], "", "decisions searched",
                                                        quantity="count")))  # fmt: skip
    text = w.t("decision", id=w.value(r.get("decision_id") or "-", "", "decision id", quantity="decision_id"),
               step=w.value(r["step"], "", "plant step", quantity="step"),
               controller=w.value(r["controller"], "", "controller", quantity="controller"),
               fallback=w.t("decision.fallback") if r["fallback"] else "")  # fmt: skip
    if r["changes"]:
        parts = []
        for c in r["changes"]:
            entity = c["what"].split(" of ", 1)[1] if " of " in c["what"] else None
            trend = "raised" if c["after"] > c["before"] else "lowered"
            if c["action"] == "valve":
                trend = "opened" if c["after"] > c["before"] else "closed"
            head = c["what"].split(" of ", 1)[0] if w.lang == "en" else w.t(f"head.{c['action']}")
            slots = w.entity_slots(entity)
            parts.append(w.t("decision.change", trend=w.t(trend), head=head, **slots,
                             before=w.value(c["before"], c["unit"], f"{c['what']} before", entity=entity,
                                            quantity=c["action"]),
                             after=w.value(c["after"], c["unit"], f"{c['what']} after", entity=entity,
                                           quantity=c["action"])))  # fmt: skip
        text += w.t("decision.changes", items="; ".join(parts))
    else:
        text += w.t("decision.nothing")
    # the reason's first sentences only: the whole rendering goes beside the answer (the reply's `detail`, one click
    # away on the page), as a colleague leads with the reason and keeps the derivation for who asks
    if r.get("reasons") and r.get("reasons_source") == "rendered":  # the cabinet asked about, not the published one
        text += w.t("decision.reasons", entity=w.entity(r["reasons_for"]),
                    quote=w.quote(lead(r["reasons"]), f"the reasons for {r['reasons_for']}"))  # fmt: skip
    elif r.get("reasons"):  # plain sentences for a chat, never raw markdown
        text += w.t("decision.explanation", quote=w.quote(lead(r["reasons"]), "the published explanation"))
    return w.say(text)


LEAD_CHARS = 320  # a "why" answer quotes its reason up to about this long (two sentences, most often)
_SENTENCE_END = re.compile(r"(?<=[.!?])\s+(?=[A-ZÁÉÍÓÚÄÖÜ¿¡])")


def lead(text: str, sentences: int = 2, max_chars: int = LEAD_CHARS) -> str:
    """The first `sentences` sentences of `text` (at most `max_chars`, cut at a word with "…"); all of it if short."""
    text = " ".join(text.split())
    parts = _SENTENCE_END.split(text)
    out = " ".join(parts[:sentences])
    if len(out) > max_chars:
        out = out[:max_chars].rsplit(" ", 1)[0].rstrip(",;:") + " …"
    elif len(parts) > sentences:
        out += " …"
    return out


def _controller(w: Writer, r: dict, args: dict) -> str:
    parts = []
    if r.get("configured"):
        text = w.t("controller", controller=w.value(r["configured"], "", "controller", quantity="controller"))
        if r.get("mode"):
            text += w.t("controller.mode", mode=w.value(r["mode"], "", "mode", quantity="mode"))
        if r.get("since"):
            text += w.t("controller.since", since=w.value(r["since"], "", "when it was set", quantity="since"),
                        version=w.value(r["since_version"], "", "version", quantity="version"))  # fmt: skip
        parts.append(text + ".")
    if r.get("acting"):
        text = w.t("controller.acting", step=w.value(r["acting_step"], "", "plant step", quantity="step"),
                   controller=w.value(r["acting"], "", "acting controller", quantity="controller"))  # fmt: skip
        if r.get("fallback") and r.get("fallback_reason"):
            text += w.t("controller.fallback", quote=w.quote(r["fallback_reason"], "fallback reason"))
        parts.append(text + ".")
    return w.say(" ".join(parts))


def _agents(w: Writer, r: dict, args: dict) -> str:
    text = w.t("agents", alive=w.value(r["alive"], "", "agents alive", quantity="alive"),
               known=w.value(r["known"], "", "agents known", quantity="count"))  # fmt: skip
    if r["down"]:
        text += w.t("agents.down", down=w.value(", ".join(r["down"]), "", "agents down", quantity="down"))
    if r["advice"]:
        text += w.t("agents.advice", quote=w.quote(r["advice"][0], "monitor advice"))
    return w.say(text)


def _propose_change(w: Writer, r: dict, args: dict) -> str:
    if r.get("current") is None:
        text = w.t("propose.quote", quote=w.quote(r["summary"], "proposal"))
    else:
        unit = r["unit"]
        what = r["summary"].split(" from ")[0].removeprefix("set the ")
        entity = what.split(" of ", 1)[1] if " of " in what else "plant"
        head = what.split(" of ", 1)[0]
        key = {"supply": "supply_setpoint", "dp": "dp_setpoint", "lw": "lw_setpoint"}[args["setpoint"]]
        where = w.t("propose.where", **w.entity_slots(entity)) if entity != "plant" else ""
        text = w.t("propose.set", where=where, **w.label(key, head),
                   now=w.value(r["current"], unit, "setpoint now", entity=entity, quantity=key),
                   new=w.value(r["proposed"], unit, "setpoint proposed", entity=entity, quantity=key))  # fmt: skip
    if r.get("problem"):
        text += w.t("propose.problem", quote=w.quote(r["problem"], "why not"))
    return w.say(text + w.t("propose.confirm"))


def _whatif_setpoint(w: Writer, r: dict, args: dict) -> str:
    b, p = r["baseline"], r["predicted"]
    key = {"supply": "supply_setpoint", "dp": "dp_setpoint", "lw": "lw_setpoint"}[r["setpoint"]]
    si = r["change_si"]
    shown, unit = (si / 6894.757293168, "psi") if r["setpoint"] == "dp" else (si, "K")
    verb = w.t("whatif.raise" if si > 0 else "whatif.lower")
    scope = (w.t("whatif.scope.one", **w.entity_slots(f"cabinet {r['cabinets'][0]}")) if len(r["cabinets"]) == 1
             else w.t("whatif.scope.all"))  # fmt: skip

    def pair(key: str, label_: str, quantity: str, unit_: str) -> str:
        return w.t("whatif.pair",
                   predicted=w.value(p[key], unit_, f"{label_}, predicted", entity="plant", quantity=quantity,
                                     case="predicted"),
                   baseline=w.value(b[key], unit_, f"{label_}, holding", entity="plant", quantity=quantity,
                                    case="baseline"))  # fmt: skip

    minutes = w.value(r["minutes"], "min", "look-ahead horizon", quantity="window")
    change = w.value(abs(shown), unit, "change asked", quantity=r["setpoint"])
    return w.say(w.t("whatif", minutes=minutes, verb=verb, scope=scope, change=change, **w.label(key, _label(key)),
                     blade=pair("hottest_blade_c", "hottest blade group", "blade_temp", "degC"),
                     band=pair("in_band_pct", "share in band", "in_band", "%"),
                     fans=pair("tower_power_kw", "tower fans", "tower_power", "kW"),
                     pumps=pair("pump_power_kw", "pumps", "pump_power", "kW")))  # fmt: skip


def _energy_used(w: Writer, r: dict, args: dict) -> str:
    quantity = {"cooling": "cooling_power", "pumps": "pump_power", "tower_fans": "tower_power", "it": "it_power",
                "heat_rejected": "heat_rejected"}[r["what"]]  # fmt: skip
    text = w.t("energy_used", what=w.t(f"energy_used.what.{r['what']}"),
               minutes=w.value(r["minutes_covered"], "min", "minutes of history integrated", quantity="window"),
               kwh=w.value(r["kwh"], "kWh", f"{r['label']} energy", entity="plant", quantity=quantity, kind="energy"),
               mean=w.value(r["mean_kw"], "kW", f"{r['label']} mean power", entity="plant", quantity=quantity,
                            stat="mean"))  # fmt: skip
    if r["minutes_covered"] < r["minutes_asked"] - 1:
        text += w.t("history.short", asked=w.value(r["minutes_asked"], "min", "window asked for", quantity="window"))
    return w.say(text)


def _tracking_gap(w: Writer, r: dict, args: dict) -> str:
    quantity = "supply" if r["level"] == "cabinet" else "lw"
    items = []
    for g in r["gaps"]:
        e = g["entity"]
        items.append(w.t("gap.item", entity=w.entity(e),
                         measured=w.value(g["measured_c"], "degC", "measured", entity=e, quantity=quantity),
                         setpoint=w.value(g["setpoint_c"], "degC", "setpoint", entity=e, quantity=quantity),
                         gap=w.value(abs(g["gap_k"]), "K", "gap to the setpoint", entity=e, quantity=quantity,
                                     kind="gap", unsigned=True),
                         side=w.t("gap.above" if g["gap_k"] > 0 else "gap.below")))  # fmt: skip
    text = w.t(f"gap.{r['level']}", items="; ".join(items))
    if len(r["gaps"]) > 1:
        text += w.t("gap.largest", **w.entity_slots(r["largest"]))
    return w.say(text)


def _peak(w: Writer, r: dict, args: dict) -> str:
    q, unit, label = r["quantity"], r["unit"], r["label"]
    names = w.label(q, label)
    order = "highest" if r["extreme"] == "max" else "lowest"
    slots = {} if r["entity"] == "plant" else w.entity_slots(r["entity"])
    at = r["at"][11:19] + " UTC" if len(r["at"]) >= 19 else r["at"]
    text = w.t("peak.plant" if r["entity"] == "plant" else "peak", **slots, **names,
               minutes=w.value(r["minutes_covered"], "min", "minutes of history read"),
               word=w.t(f"stat.{r['extreme']}"),
               value=w.value(r["value"], unit, f"{r['extreme']} {label}", entity=r["entity"], quantity=q,
                             stat=r["extreme"], extreme=order),
               at=w.value(at, "", "when", quantity="time"),
               ago=w.value(r["minutes_ago"], "min", "how long ago"))  # fmt: skip
    if r["minutes_covered"] < r["minutes_asked"] - 1:
        text += w.t("history.short", asked=w.value(r["minutes_asked"], "min", "window asked for", quantity="window"))
    return w.say(text)


def _signed(w: Writer, value: float, unit: str, text: str, quantity: str, decimals: int = 1) -> str:
    if round(value, decimals) == 0:
        return w.t("trend.signed.flat")
    change = w.value(abs(value), unit, text, entity="plant", quantity=quantity, unsigned=True)
    return w.t("trend.signed.up" if value > 0 else "trend.signed.down", change=change)


def _weather_effect(w: Writer, r: dict, args: dict) -> str:
    items = "; ".join(w.t("weather.item", entity=w.entity(t["entity"]),
                          approach=w.value(t["approach_k"], "K", "approach", entity=t["entity"], quantity="approach"),
                          lw=w.value(t["leaving_water_c"], "degC", "leaving water", entity=t["entity"],
                                     quantity="leaving_water"),
                          speed=w.value(t["fan_speed_pct"], "%", "fan speed", entity=t["entity"], quantity="fan_speed"),
                          power=w.value(t["fan_power_kw"], "kW", "fan power", entity=t["entity"],
                                        quantity="tower_power"))
                      for t in r["towers"])  # fmt: skip
    text = w.t("weather", items=items,
               wb=w.value(r["wet_bulb_c"], "degC", "wet bulb", entity="plant", quantity="wet_bulb"),
               wb_change=_signed(w, r["wet_bulb_change_k"], "K", "wet-bulb change", "wet_bulb"),
               minutes=w.value(r["minutes_covered"], "min", "minutes of history read"),
               fans=w.value(r["fan_power_kw"], "kW", "tower fan power", entity="plant", quantity="tower_power"),
               fans_change=_signed(w, r["fan_power_change_kw"], "kW", "fan power change", "tower_power"))  # fmt: skip
    if r.get("fan_kw_per_k_wet_bulb") is not None:
        text += w.t("weather.per_k", per_k=w.value(r["fan_kw_per_k_wet_bulb"], "kW", "fan power per kelvin of wet "
                                                   "bulb", entity="plant", quantity="tower_power"))  # fmt: skip
    else:
        text += w.t("weather.per_k.none")
    return w.say(text)


def _whatif_controller(w: Writer, r: dict, args: dict) -> str:
    cur, alt = r["current"], r["alternative"]

    def course(c: dict, case: str) -> dict[str, str]:
        return {"kwh": w.value(c["cooling_kwh"], "kWh", f"cooling energy, {c['controller']}", entity="plant",
                               quantity="cooling_power", case=case, kind="energy"),
                "hot": w.value(c["hottest_blade_c"], "degC", f"hottest blade group, {c['controller']}",
                               entity="plant", quantity="blade_temp", case=case),
                "band": w.value(c["in_band_pct"], "%", f"share in band, {c['controller']}", entity="plant",
                                quantity="in_band", case=case)}  # fmt: skip

    now, other = course(cur, "current"), course(alt, "alternative")
    names = {"current": w.value(cur["controller"], "", "the controller now", quantity="controller"),
             "other": w.value(alt["controller"], "", "the controller tried", quantity="controller")}
    saved = w.value(abs(r["cooling_kwh_saved"]), "kWh", "cooling energy difference", entity="plant",
                    quantity="cooling_power", unsigned=True, kind="energy")  # fmt: skip
    verdict = w.t("whatif_ctrl.saves" if r["cooling_kwh_saved"] > 0 else "whatif_ctrl.costs", other=names["other"],
                  saved=saved)  # fmt: skip
    verdict = verdict[:1].upper() + verdict[1:]
    text = w.t("whatif_ctrl", minutes=w.value(r["minutes"], "min", "look-ahead horizon", quantity="window"),
               current=names["current"], other=names["other"], verdict=verdict,
               cur_kwh=now["kwh"], cur_hot=now["hot"], cur_band=now["band"],
               alt_kwh=other["kwh"], alt_hot=other["hot"], alt_band=other["band"])  # fmt: skip
    notes = [c["note"] for c in (cur, alt) if c.get("note")]
    if notes:
        text += w.t("whatif_ctrl.note", quote=w.quote(notes[0], "controller note"))
    return w.say(text)


WRITERS: dict[str, Callable[[Writer, dict, dict], str]] = {
    "plant_state": _plant_state, "overview": _overview, "history_stat": _history_stat, "rank": _rank,
    "compare": _compare, "band_count": _band_count, "energy_balance": _energy_balance, "alerts": _alerts,
    "decision": _decision, "controller": _controller, "agents": _agents, "propose_change": _propose_change,
    "whatif_setpoint": _whatif_setpoint, "energy_used": _energy_used, "tracking_gap": _tracking_gap, "peak": _peak,
    "weather_effect": _weather_effect, "whatif_controller": _whatif_controller,
}  # fmt: skip


def write(tool: str, result: dict, args: dict, book: FactBook, index: int = 0, lang: str = "en") -> str:
    """The sentences for one tool result in `lang` ("en", "es", "de", "fr"); every number cited through `book`."""
    text = WRITERS[tool](Writer(book, f"{tool}{index}", result.get("step"), lang), result, args)
    return text[:1].upper() + text[1:]


def refusal(lang: str = "en") -> str:
    """The honest answer to a question no tool answers: what the assistant cannot tell, and what it can."""
    return phrase(lang, "refusal") + phrase(lang, "can_do")


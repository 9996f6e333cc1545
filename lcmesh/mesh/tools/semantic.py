"""The semantic check: every number in a text bound to the right entity and quantity, rankings and directions right.

A text passes only if each number it states is a value the data holds *for the entity and the
quantity the sentence attaches it to*, each "hottest / lowest / highest" names the entity the data
ranks so, and each "raised / fell / opened" agrees with the sign of the change it describes. The
data is a list of ``Bound`` values (a value with its unit, entity and quantity) and ``Ranking``s;
the chat passes its tool results' facts, and the explanation judge can pass a decision's facts.

Reading is deliberately local: a number belongs to the nearest entity named before it in the
same clause (or right after it: "36.4 °C in cabinet 3"), and to the nearest quantity word before
it in the same sentence. Clauses end at ".", ";" and ","; sentences at "." and ";".
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

ENTITY_WORDS = {
    "cabinet": ("cabinet", "cabinets", "cdu", "rack", "gabinete", "armario", "schrank", "armoire"),
    "branch": ("branch", "branches", "rama", "zweig", "strang", "branche"),
    "tower": ("tower", "towers", "torre", "turm", "tour"),
}
_ENTITY_ALT = "|".join(w for words in ENTITY_WORDS.values() for w in words)
ENTITY = re.compile(rf"\b({_ENTITY_ALT})\s*#?\s*(\d+)(?:\s+(?:of|de|del|von|des|du)\s+(?:the\s+|l['’])?"
                    rf"({_ENTITY_ALT})\s*#?\s*(\d+))?", re.IGNORECASE)  # fmt: skip
NUMBER = re.compile(r"(?<![\w.])[-+]?\d+(?:\.\d+)?(?![\w.]*\d)")

# Words that name a quantity, longest first when matched; values are the quantity keys they may mean.
QUANTITY_WORDS: dict[str, tuple[str, ...]] = {
    "blade": ("blade_temp", "blade_temp_mean"), "hottest blade": ("blade_temp",),
    "supply setpoint": ("supply_setpoint", "supply"), "supply": ("supply_temp", "supply_setpoint", "supply"),
    "return": ("return_temp",), "dp setpoint": ("dp_setpoint", "dp"), "differential pressure": ("dp", "dp_setpoint"),
    "dp": ("dp", "dp_setpoint"), "flow": ("flow",), "valve": ("valve",), "pump speed": ("pump_speed",), "cdu pump speed": ("pump_speed",),
    "cdu pump": ("cdu_pump_power",), "pumps": ("pump_power", "cdu_pump_power"), "pump": ("pump_power", "cdu_pump_power"),
    "it power": ("it_power",), "it load": ("it_power",), "heat removed": ("cdu_heat",), "cdus move": ("cdu_heat",),
    "reject": ("heat_rejected", "rejected_over_it"), "leaving-water setpoint": ("lw_setpoint", "lw"),
    "leaving water": ("leaving_water", "lw_setpoint", "lw"), "approach": ("approach",), "fan speed": ("fan_speed",),
    "fans": ("tower_power",), "fan power": ("tower_power",), "cooling power": ("cooling_power",),
    "cooling takes": ("cooling_power",), "wet bulb": ("wet_bulb",), "wet-bulb": ("wet_bulb",),
    "hot-water supply": ("htw_supply_temp",), "hot-water return": ("htw_return_temp",),
    "in band": ("in_band",), "inside the": ("in_band", "inside", "total", "band_low", "band_high"),
    "pue": ("pue",), "leaving-water": ("leaving_water", "lw_setpoint", "lw"),
}  # fmt: skip
# The same keys in Spanish, German and French, as the writer's catalog (ui/language.py) and operators word them.
QUANTITY_WORDS.update({
    # es
    "impulsión": ("supply_temp", "supply_setpoint", "supply"), "consigna de impulsión": ("supply_setpoint", "supply"),
    "retorno": ("return_temp",), "presión diferencial": ("dp", "dp_setpoint"), "caudal": ("flow",),
    "válvula": ("valve",), "velocidad de la bomba": ("pump_speed",), "bomba": ("pump_power", "cdu_pump_power"),
    "potencia it": ("it_power",), "carga it": ("it_power",), "calor extraído": ("cdu_heat",), "extraen": ("cdu_heat",),
    "rechaz": ("heat_rejected", "rejected_over_it"), "agua de salida": ("leaving_water", "lw_setpoint", "lw"),
    "consigna de agua de salida": ("lw_setpoint", "lw"), "aproximación": ("approach",),
    "velocidad de ventilador": ("fan_speed",), "ventilador": ("tower_power",),
    "potencia de refrigeración": ("cooling_power",), "refrigeración consume": ("cooling_power",),
    "bulbo húmedo": ("wet_bulb",), "impulsión del agua caliente": ("htw_supply_temp",),
    "retorno del agua caliente": ("htw_return_temp",), "en banda": ("in_band",),
    "dentro de la banda": ("in_band", "inside", "total", "band_low", "band_high"),
    # de
    "vorlauf": ("supply_temp", "supply_setpoint", "supply"), "vorlaufsollwert": ("supply_setpoint", "supply"),
    "rücklauf": ("return_temp",), "differenzdruck": ("dp", "dp_setpoint"), "durchfluss": ("flow",),
    "ventil ": ("valve",), "ventilanteil": ("valve",), "pumpendrehzahl": ("pump_speed",), "it-leistung": ("it_power",),
    "it-last": ("it_power",),
    "abgeführte wärme": ("cdu_heat",), "cdus führen": ("cdu_heat",),
    "abgegebene wärme": ("heat_rejected", "rejected_over_it"), "türme geben": ("heat_rejected", "rejected_over_it"),
    "austrittswasser": ("leaving_water", "lw_setpoint", "lw"), "austrittswasser-sollwert": ("lw_setpoint", "lw"),
    "lüfterdrehzahl": ("fan_speed",), "lüfter": ("tower_power",), "kühlleistung": ("cooling_power",),
    "kühlung braucht": ("cooling_power",), "feuchtkugel": ("wet_bulb",), "warmwasser-vorlauf": ("htw_supply_temp",),
    "warmwasser-rücklauf": ("htw_return_temp",), "im band": ("in_band",),
    "innerhalb des": ("in_band", "inside", "total", "band_low", "band_high"),
    # fr
    "départ": ("supply_temp", "supply_setpoint", "supply"), "consigne de départ": ("supply_setpoint", "supply"),
    "retour": ("return_temp",), "pression différentielle": ("dp", "dp_setpoint"), "débit": ("flow",),
    "vanne": ("valve",), "vitesse de pompe": ("pump_speed",), "pompe": ("pump_power", "cdu_pump_power"),
    "puissance it": ("it_power",), "charge it": ("it_power",), "chaleur évacuée": ("cdu_heat",),
    "évacuent": ("cdu_heat",), "rejet": ("heat_rejected", "rejected_over_it"),
    "eau de sortie": ("leaving_water", "lw_setpoint", "lw"), "consigne d'eau de sortie": ("lw_setpoint", "lw"),
    "approche": ("approach",), "vitesse des ventilateur": ("fan_speed",), "ventilateur": ("tower_power",),
    "puissance de refroidissement": ("cooling_power",), "refroidissement consomme": ("cooling_power",),
    "bulbe humide": ("wet_bulb",), "départ d'eau chaude": ("htw_supply_temp",),
    "retour d'eau chaude": ("htw_return_temp",), "lames": ("blade_temp", "blade_temp_mean"),
    "dans la bande": ("in_band",),
    "à l'intérieur de la bande": ("in_band", "inside", "total", "band_low", "band_high"),
})  # fmt: skip
_QUANTITY = re.compile("|".join(re.escape(w) for w in sorted(QUANTITY_WORDS, key=len, reverse=True)), re.IGNORECASE)
HIGH_WORDS = ("hottest", "warmest", "highest", "most", "largest", "biggest", "maximum", "max", "peak")
LOW_WORDS = ("coolest", "coldest", "lowest", "least", "smallest", "minimum", "min")
# es/de/fr superlatives inflect and take several words: patterns ("más alta", "höchsten", "la plus élevée")
HIGH_FORMS = (r"más\s+(?:caliente|alt[oa]|elevad[oa])s?", r"máxim[oa]s?",
              r"(?:heißest|heissest|wärmst|höchst|größt)e[nrs]?", r"maximale[nrs]?",
              r"(?:le|la|les)\s+plus\s+(?:chaud|élevé|haut)e?s?")
LOW_FORMS = (r"más\s+(?:fr[ií][oa]|baj[oa])s?", r"mínim[oa]s?",
             r"(?:kältest|kühlst|niedrigst|tiefst|kleinst|geringst)e[nrs]?", r"minimale[nrs]?",
             r"(?:le|la|les)\s+plus\s+(?:froid|bas|faible)(?:e|se)?s?")
_HIGH = re.compile("|".join(HIGH_WORDS + HIGH_FORMS), re.IGNORECASE)
_SUPERLATIVE = re.compile(r"\b(" + "|".join(HIGH_WORDS + LOW_WORDS + HIGH_FORMS + LOW_FORMS) + r")\b",
                          re.IGNORECASE)  # fmt: skip
UP_WORDS = ("raised", "rose", "up", "increased", "higher", "opened", "bumped", "climbed", "warmer",
            "subió", "aumentó", "abrió", "subido", "aumentado", "abierto", "elevó",  # es
            "gestiegen", "erhöht", "erhöhte", "geöffnet", "angehoben", "stieg",  # de
            "augmenté", "relevé", "ouvert", "monté", "montée", "hausse")  # fr
DOWN_WORDS = ("lowered", "fell", "down", "decreased", "lower", "closed", "dropped", "trimmed", "eased", "cooler",
              "bajó", "disminuyó", "descendió", "cayó", "cerró", "bajado", "disminuido", "cerrado", "redujo",  # es
              "gesunken", "gesenkt", "senkte", "gefallen", "geschlossen", "abgesenkt", "sank", "fiel",  # de
              "baissé", "abaissé", "diminué", "fermé", "descendu", "descendue", "baisse")  # fr
_DIRECTION = re.compile(r"\b(" + "|".join(UP_WORDS + DOWN_WORDS) + r")\b", re.IGNORECASE)
_UNIT_THEN_OF = re.compile(r"\s*(?:°\s*[CF]|K|kW|psi|%|kg/s|bar|kPa|gpm)?\s*(?:in|of|for|at|en|von|de|du|del|im|bei"
                           r"|(?:en|dans|de)\s+(?:el|la|le|l['’]))\s*$", re.IGNORECASE)  # fmt: skip
_FROM_TO = re.compile(r"\b(?:from|de|desde|von|du)\s+(-?\d+(?:\.\d+)?)[^,;]*?\b(?:to|a|hasta|auf|bis|à)\s+"
                      r"(-?\d+(?:\.\d+)?)", re.IGNORECASE)  # fmt: skip


@dataclass(frozen=True)
class Bound:
    """A value the data holds: `shown` is how the text may write it (e.g. "36.4"); entity None = not tied to one."""

    shown: str
    entity: str | None = None
    quantity: str | None = None
    signed: float | None = None  # for a change: its signed value, to check the direction words against


@dataclass(frozen=True)
class Ranking:
    """The data's first entity for `order` ("highest" / "lowest") of a quantity."""

    quantity: str | None
    order: str
    entity: str


@dataclass(frozen=True)
class Problem:
    kind: str  # unbound_number, wrong_entity, wrong_quantity, wrong_rank, wrong_direction
    span: str
    detail: str


@dataclass
class _Clause:
    text: str
    start: int
    entities: list[tuple[int, int, str]] = field(default_factory=list)  # (start, end, canonical name)


def canonical_entity(kind_word: str, number: str, outer_word: str | None = None, outer: str | None = None) -> str:
    """"Cabinet 3" / "CDU 3" -> "cabinet 3"; "branch 2 of cabinet 3" stays nested."""
    def kind(word: str) -> str:
        return next(k for k, words in ENTITY_WORDS.items() if word.lower() in words)

    name = f"{kind(kind_word)} {int(number)}"
    if outer_word:
        name += f" of {kind(outer_word)} {int(outer)}"
    return name


def _clauses(text: str) -> list[_Clause]:
    out, start = [], 0
    for match in re.finditer(r"[;,]|\.(?!\d)|$", text):
        piece = text[start:match.start()]
        clause = _Clause(piece, start)
        for m in ENTITY.finditer(piece):
            clause.entities.append((m.start(), m.end(), canonical_entity(*m.groups())))
        out.append(clause)
        start = match.end()
    return out


def _sentence_start(text: str, pos: int) -> int:
    cut = max(text.rfind(". ", 0, pos), text.rfind("; ", 0, pos))
    return 0 if cut < 0 else cut + 2


def _quantity_before(text: str, pos: int) -> tuple[str, ...] | None:
    start = _sentence_start(text, pos)
    found = None
    for m in _QUANTITY.finditer(text, start, pos):
        found = QUANTITY_WORDS[m.group(0).lower()]
    return found


def _entity_for(clause: _Clause, offset: int, end: int) -> str | None:
    before = [e for e in clause.entities if e[1] <= offset]
    after = [e for e in clause.entities if e[0] >= end and e[0] - end <= 16]
    if after and _UNIT_THEN_OF.match(clause.text[end:after[0][0]]):
        return after[0][2]
    return before[-1][2] if before else None


def _is_entity_number(clause: _Clause, offset: int) -> bool:
    return any(s <= offset < e for s, e, _ in clause.entities)


def _same_entity(claimed: str, bound: str | None) -> bool:
    if bound is None or bound == "plant":
        return False
    return bound == claimed or bound.endswith(f"of {claimed}") or claimed.endswith(f"of {bound}")


def check_numbers(text: str, values: Sequence[Bound]) -> list[Problem]:
    """Each number stated must be a bound value of the entity and quantity the sentence attaches it to."""
    problems = []
    by_shown: dict[str, list[Bound]] = {}
    for v in values:
        by_shown.setdefault(_plain(v.shown), []).append(v)
    for clause in _clauses(text):
        for m in NUMBER.finditer(clause.text):
            if _is_entity_number(clause, m.start()):
                continue
            shown = _plain(m.group(0))
            candidates = by_shown.get(shown, [])
            span = clause.text.strip()
            if not candidates:
                problems.append(Problem("unbound_number", span, f"{m.group(0)} is not a value the data holds"))
                continue
            entity = _entity_for(clause, m.start(), m.end())
            if entity is not None and not any(_same_entity(entity, c.entity) or c.entity is None for c in candidates):
                holders = sorted({c.entity or "the plant" for c in candidates})
                problems.append(Problem("wrong_entity", span, f"{m.group(0)} belongs to {', '.join(holders)}, "
                                                              f"not {entity}"))  # fmt: skip
                continue
            quantity = _quantity_before(text, clause.start + m.start())
            if quantity and not any(c.quantity is None or c.quantity in quantity or c.quantity == "number"
                                    for c in candidates):  # fmt: skip
                held = sorted({c.quantity for c in candidates if c.quantity})
                problems.append(Problem("wrong_quantity", span, f"{m.group(0)} is the data's {', '.join(held)}, "
                                                                f"not {quantity[0]}"))  # fmt: skip
    return problems


def _plain(number: str) -> str:
    return number.lstrip("+").removeprefix("-") if number not in ("-0", "+0") else "0"


def check_rankings(text: str, rankings: Iterable[Ranking]) -> list[Problem]:
    """Every superlative next to an entity must name the entity the data ranks first that way."""
    firsts = {(r.order, r.entity) for r in rankings}
    opposite = {"highest": "lowest", "lowest": "highest"}
    problems = []
    for clause in _clauses(text):
        for m in _SUPERLATIVE.finditer(clause.text):
            order = "highest" if _HIGH.fullmatch(m.group(1)) else "lowest"
            if not clause.entities:
                continue
            entity = min(clause.entities, key=lambda e: abs(e[0] - m.start()))[2]
            names = {entity, entity.split(" of ")[-1]}
            known = sorted(e for o, e in firsts if o == order)
            wrong = (known and not names & set(known)) or any((opposite[order], n) in firsts for n in names)
            if wrong:
                truth = f"the data's {order} is {', '.join(known)}" if known else \
                    f"the data ranks {entity} {opposite[order]}"
                problems.append(Problem("wrong_rank", clause.text.strip(), f"{truth}, not {entity} {order}"))
    return problems


def check_directions(text: str, values: Sequence[Bound]) -> list[Problem]:
    """'from A to B' must go the way its verb says; 'up N' / 'down N' must match the change's sign."""
    problems = []
    signed = {_plain(v.shown): v.signed for v in values if v.signed is not None}
    for clause in _clauses(text):
        verbs = [m.group(1).lower() for m in _DIRECTION.finditer(clause.text)]
        if not verbs:
            continue
        up = verbs[-1] in UP_WORDS
        pair = _FROM_TO.search(clause.text)
        if pair:
            a, b = float(pair.group(1)), float(pair.group(2))
            if a != b and (b > a) != up:
                problems.append(Problem("wrong_direction", clause.text.strip(),
                                        f"'{verbs[-1]}' but {pair.group(1)} -> {pair.group(2)}"))  # fmt: skip
            continue
        for m in NUMBER.finditer(clause.text):
            value = signed.get(_plain(m.group(0)))
            if value is not None and value != 0 and (value > 0) != up:
                problems.append(Problem("wrong_direction", clause.text.strip(),
                                        f"'{verbs[-1]}' but the change is {value:+g}"))  # fmt: skip
    return problems


def check(text: str, values: Sequence[Bound], rankings: Iterable[Ranking] = ()) -> list[Problem]:
    """All problems of `text` against the data: numbers, entities, quantities, rankings, directions."""
    rankings = list(rankings)
    return check_numbers(text, values) + check_rankings(text, rankings) + check_directions(text, values)

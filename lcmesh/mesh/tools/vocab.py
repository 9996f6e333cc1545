"""The plant's words in English, Spanish, German and French, and which entity and quantity a number is said of.

Both checkers of numbers in text read these tables, so a word added here is read by both:

| table | words | chat guard (``semantic.py``) | explanation judge (``explain_eval/``) |
|---|---|---|---|
| ``ENTITY_WORDS`` | cabinet / CDU, branch, blade group, tower | ``ENTITY``, ``canonical_entity`` | branch mentions (a record's blade group j is its branch j), index and count words |
| ``QUANTITY_WORDS`` | supply, return, setpoint, valve, flow, dp, approach, wet bulb, fan and pump power ... -> fact keys | the quantity a number is said of | the action dimensions (``dimension``) and the readings grounding names |
| ``UNITS`` | °C, K, kW, kg/s, psi, %, por ciento / Prozent / pour cent ... | the unit between a number and "in cabinet 3" | every number's unit (``unit_at``) |
| ``DIRECTION_WORDS`` | up, down, held | up and down: ``check_directions`` | direction claims (English adds its grammar: ``EN_DIRECTIONS``) |
| ``SUPERLATIVES`` | highest / lowest, hottest / coolest, most loaded, most open | ``check_rankings`` | ranking claims |
| ``SPLIT_WORDS`` / ``OTHER_SHARES`` | "split equally", "more flow" / "34 % of the load" | | valve coverage and claims; which percentages are valve shares |
| ``FUNCTION_WORDS`` | and, or, not, if, would ... | | lists, negations, conditions and advice |

Binding: a number's unit is ``unit_at``'s for both. The guard says a number is of the entity named right
after it when only its unit and a preposition stand between ("36.4 °C in cabinet 3", "0.29 para la rama
1"), else of the nearest one named before it in its clause (``entity_of``), and of the quantity named
nearest before it in its sentence (``quantity_before``). The judge, which checks a number against one
decision's branches and readings, applies stricter distances (``explain_eval``: ``_branch_at``,
``grounding._topic_of``) to the same words: ``OF_BEFORE_ENTITY``, ``ARTICLE``, ``quantity_phrases``. Words
are matched without regard to case; quantity phrases anywhere in a word, so German compounds
("Kühlmitteldurchfluss") read as their last part.
"""

from __future__ import annotations

import re

LANGUAGES = ("en", "es", "de", "fr")
I = re.IGNORECASE


def alternation(*forms: str) -> str:
    """One non-capturing group of regex alternatives, the longest first (a longer phrase wins over its prefix)."""
    return "(?:" + "|".join(sorted(forms, key=len, reverse=True)) + ")"


def words(*forms: str) -> re.Pattern:
    """Whole words (or phrases), any of ``forms`` (regexes), case-insensitive."""
    return re.compile(r"\b" + alternation(*forms) + r"\b", I)


def _all(table: dict[str, tuple[str, ...]]) -> tuple[str, ...]:
    return tuple(w for lang in LANGUAGES for w in table.get(lang, ()))


# --- entities -------------------------------------------------------------------------------------------------------

# regex forms by kind and language; a blade group is an entity of its own in the chat (blade group g of branch b)
ENTITY_WORDS: dict[str, dict[str, tuple[str, ...]]] = {
    "cabinet": {"en": ("cabinets?", "cdus?", "racks?", "cabs?"), "es": ("gabinetes?", "armarios?"), "de": ("schr[aä]nke?",),
                "fr": ("armoires?",)},
    "branch": {"en": ("branch(?:es)?",), "es": ("ramas?",), "de": ("zweige?", "str[aä]nge?"), "fr": ("branches?",)},
    "blade group": {"en": (r"blade[\s-]groups?",), "es": (r"grupos?\s+de\s+blades",), "de": (r"blade-gruppen?",),
                    "fr": (r"groupes?\s+de\s+lames",)},
    "tower": {"en": ("towers?", "cts?"), "es": ("torres?",), "de": ("t[uü]rme?",), "fr": ("tours?",)},
}  # fmt: skip
_ENTITY_ALT = alternation(*(w for by_lang in ENTITY_WORDS.values() for w in _all(by_lang)))
_KINDS = {kind: re.compile(alternation(*_all(by_lang)), I) for kind, by_lang in ENTITY_WORDS.items()}
ARTICLE = r"(?:(?:the|la|el|le|der|dem|die|das)\s+|l['’])"
"""An article before an entity word ("the branch", "la rama", "der Zweig", "l'armoire"), with its space."""
_OF = rf"(?:of|de|del|von|des|du)\s+{ARTICLE}?"
# a number that is a value, not an entity's: "the hottest blade group 35.0 °C", "towers 48 kW", "valve 2 to 50 %"
NOT_A_VALUE = r"(?!\d)(?![.,]\d)(?!\s*(?:%|°|℃|K\b|[kM]?W\b|psi|kPa|kg|C\b))"
ENTITY = re.compile(rf"\b({_ENTITY_ALT})\s*#?\s*(\d+){NOT_A_VALUE}(?:\s+{_OF}({_ENTITY_ALT})\s*#?\s*(\d+){NOT_A_VALUE})?",
                    I)  # fmt: skip
"""An entity with its number, maybe inside another: groups (kind word, number, outer kind word, outer number)."""

# the words a record's branch goes by in an explanation: its branch, its blade group, its valve ("valve 2")
BRANCH_WORDS: dict[str, tuple[str, ...]] = {
    "en": ("branch(?:es)?", r"blade[\s-]groups?", "BGs?", "groups?", "valves?"),
    "es": ("ramas?", r"grupos?(?:\s+de\s+blades)?", "válvulas?"),
    "de": ("zweige?", "str[aä]nge?", r"(?:blade-)?gruppen?", "ventile?"),
    "fr": ("branches?", r"groupes?(?:\s+de\s+lames)?", "vannes?"),
}  # fmt: skip
# a share written as a fraction ("valves 1/3 each"): the split, not two numbers and not the valves 1 and 3
SHARE_FRACTION = re.compile(r"(?<![\d/])(?<!\d[.,])1/[2-9](?![\d/])(?![.,]\d)")

# ordinals and counts of branches in the four languages ("the third branch", "la tercera rama", "der dritte Zweig",
# "la troisième branche"; "all four branches", "las cuatro ramas", "alle vier Zweige", "les quatre branches")
ORDINAL_WORDS: dict[str, int] = {
    "first": 1, "second": 2, "third": 3, "fourth": 4, "fifth": 5, "sixth": 6, "seventh": 7, "eighth": 8,
    "primera": 1, "primer": 1, "primero": 1, "segunda": 2, "segundo": 2, "tercera": 3, "tercer": 3, "tercero": 3,
    "cuarta": 4, "cuarto": 4, "quinta": 5, "quinto": 5,
    "erste": 1, "ersten": 1, "erster": 1, "zweite": 2, "zweiten": 2, "zweiter": 2, "dritte": 3, "dritten": 3,
    "dritter": 3, "vierte": 4, "vierten": 4, "vierter": 4, "fünfte": 5, "fünften": 5,
    "premier": 1, "première": 1, "deuxième": 2, "seconde": 2, "troisième": 3, "quatrième": 4,
    "cinquième": 5,
}  # fmt: skip
COUNT_WORDS: dict[str, int] = {
    "two": 2, "three": 3, "four": 4, "five": 5, "six": 6, "seven": 7, "eight": 8,
    "dos": 2, "tres": 3, "cuatro": 4, "cinco": 5, "seis": 6,
    "zwei": 2, "drei": 3, "vier": 4, "fünf": 5, "sechs": 6,
    "deux": 2, "trois": 3, "quatre": 4, "cinq": 5,
}  # fmt: skip
# nouns a count or an index goes with ("3 branches", "rama 2") besides the entity words
COUNTED_NOUNS = ("cells?", "valves?", "pumps?", "agents?", "steps?", "nodes?", "decimals?", "digits?", "fans?",
                 "heads?", "loops?", "levels?", "sections?", "dimensions?", "actions?", "outputs?", "categories",
                 "válvulas?", "bombas?", "ventile?", "pumpen", "vannes?", "pompes?", "lames", "blades")  # fmt: skip


def entity_kind(word: str) -> str:
    """The kind ("cabinet", "branch", "blade group", "tower") of an entity word in any of the languages."""
    return next(kind for kind, pattern in _KINDS.items() if pattern.fullmatch(word.strip()))


def canonical_entity(kind_word: str, number: str, outer_word: str | None = None, outer: str | None = None) -> str:
    """"Cabinet 3" / "CDU 3" / "Schrank 3" -> "cabinet 3"; "branch 2 of cabinet 3" stays nested."""
    name = f"{entity_kind(kind_word)} {int(number)}"
    if outer_word:
        name += f" of {entity_kind(outer_word)} {int(outer)}"
    return name


# a preposition between a number (and its unit) and the entity it is said of: "36.4 °C in cabinet 3"
OF_BEFORE_ENTITY = re.compile(rf"\s*(?:in|of|for|at|en|von|de|du|del|im|bei|para|für|pour|dans|auf|sur|por)\s*{ARTICLE}?", I)


def entity_of(text: str, entities: list[tuple[int, int, str]], start: int, end: int) -> str | None:
    """The entity a number at [start, end) of ``text`` is said of, among ``entities`` (start, end, name) of its
    clause: the one right after it with only its unit and a preposition between ("36.4 °C in cabinet 3", "0.29
    para la rama 1"), else the nearest before it, else None."""
    before = [e for e in entities if e[1] <= start]
    after = [e for e in entities if e[0] >= end and e[0] - end <= 16]
    unit = unit_at(text, end)
    if after and OF_BEFORE_ENTITY.fullmatch(text, unit[1] if unit else end, after[0][0]):
        return after[0][2]
    return before[-1][2] if before else None


# --- units -----------------------------------------------------------------------------------------------------------

_SPACE = r"[\s\u00a0\u202f]*"


def _unit(pattern: str) -> re.Pattern:
    """A unit right after a number, after optional (also non-breaking) space or a hyphen ("30.9-C", LLMs write
    it); ``~`` in ``pattern`` stands for optional space."""
    return re.compile("(?:" + _SPACE + "|-)" + "(?:" + pattern.replace("~", _SPACE) + ")")


# (regex, normalized unit), tried in order right after the number
UNITS: list[tuple[re.Pattern, str]] = [
    (_unit(r"[°º]~C(?![a-zA-Z])|℃"), "degC"),
    (_unit(r"deg(?:rees?)?\.?~(?:C\b|Celsius\b)|degC\b|Celsius\b|C\b(?![-'’/])"), "degC"),
    (_unit(r"[°º]~F\b|℉|deg(?:rees?)?\.?~(?:F\b|Fahrenheit\b)|degF\b|F\b(?![-'’/])|grados?~Fahrenheit\b"), "degF"),
    # spoken and written out: "30 Grad", "18 grados", "20 degrés" (Celsius where nothing says otherwise)
    (_unit(r"(?:grados?|Grad|degrés?)\b(?!~(?:F\b|Fahrenheit))(?:~(?:C\b|Celsius\b))?"), "degC"),
    (_unit(r"K\b(?![-'’])|[Kk]elvins?\b"), "K"),
    (_unit(r"(?:kWh|MWh)\b"), "energy"),
    (_unit(r"MW\b|[Mm]egawatts?\b"), "MW"),
    (_unit(r"kW\b|KW\b|[Kk]ilowatts?\b|[Kk]ilovatios?\b"), "kW"),
    (_unit(r"W\b|[Ww]atts?\b"), "W"),
    (_unit(r"kg~/~s\b|kg~s(?:\^?-1|⁻¹)|kg per s(?:ec(?:ond)?)?\b"), "kg/s"),
    (_unit(r"[Ll]~/~s\b|lit(?:re|er)s? per second\b"), "L/s"),
    (_unit(r"kg~/~min\b|kg per min(?:ute)?\b"), "kg/min"),
    (_unit(r"kg~/~h(?:r|our)?\b|kg per hour\b"), "kg/h"),
    (_unit(r"lbs?~/~s\b"), "lb/s"),
    (_unit(r"lbs?~/~min\b"), "lb/min"),
    (_unit(r"m(?:3|³|\^3)~/~h(?:r|our)?\b|cubic met(?:re|er)s? per hour\b"), "m3/h"),
    (_unit(r"[Ll]~/~min\b|lpm\b|lit(?:re|er)s? per minute\b"), "L/min"),
    (_unit(r"gpm\b|GPM\b|gal(?:lons?)?~/~min\b|gallons? per minute\b"), "gpm"),
    (_unit(r"psid?\b|PSI\b"), "psi"),
    (_unit(r"kPa\b"), "kPa"),
    (_unit(r"mbar\b"), "mbar"),
    (_unit(r"MPa\b"), "MPa"),
    (_unit(r"Pa\b"), "Pa"),
    (_unit(r"bar\b"), "bar"),
    (_unit(r"percentage points?\b|pp\b"), "pp"),
    (_unit(r"%|percent\b|per~cent\b|por~ciento\b|[Pp]rozent\b|pour~cent\b"), "%"),
    (_unit(r"J~/~(?:\(~kg~[·*. ]?~K~\)|kg~/?~K\b)"), "J/(kg K)"),
    (_unit(r"[kMG]?J\b"), "energy"),
    (re.compile(r"(?:x\b|" + _SPACE + r"(?:times\b|-fold\b))"), "x"),
    (_unit(r"(?:ms|s|secs?|seconds?|min|mins|minutes?|h|hrs?|hours?|days?|weeks?)\b"), "time"),
]


def unit_at(text: str, pos: int) -> tuple[str, int] | None:
    """(normalized unit, end) of the unit written right after a number ending at ``pos``, or None."""
    for pattern, unit in UNITS:
        if m := pattern.match(text, pos):
            return unit, m.end()
    return None


# --- quantities ------------------------------------------------------------------------------------------------------

# Phrases (plain text, matched anywhere in a word) that name a quantity; values are the fact keys they may mean.
_ENERGY = ("cooling_power", "pump_power", "cdu_pump_power", "tower_power", "it_power")  # kWh of one of the powers
QUANTITY_WORDS: dict[str, tuple[str, ...]] = {
    # en
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
    "energy": _ENERGY,
    # es (the writer's catalog, ui/language.py, and how operators word it)
    "impulsión": ("supply_temp", "supply_setpoint", "supply"), "consigna de impulsión": ("supply_setpoint", "supply"),
    "consigna de temperatura de impulsión": ("supply_setpoint", "supply"),
    "retorno": ("return_temp",), "presión diferencial": ("dp", "dp_setpoint"), "caudal": ("flow",),
    "válvula": ("valve",), "velocidad de la bomba": ("pump_speed",), "bomba": ("pump_power", "cdu_pump_power"),
    "potencia it": ("it_power",), "carga it": ("it_power",), "calor extraído": ("cdu_heat",), "extraen": ("cdu_heat",),
    "rechaz": ("heat_rejected", "rejected_over_it"), "agua de salida": ("leaving_water", "lw_setpoint", "lw"),
    "consigna de agua de salida": ("lw_setpoint", "lw"), "consigna de la torre": ("lw_setpoint", "lw"),
    "aproximación": ("approach",), "velocidad de ventilador": ("fan_speed",), "ventilador": ("tower_power",),
    "potencia de refrigeración": ("cooling_power",), "refrigeración consume": ("cooling_power",),
    "bulbo húmedo": ("wet_bulb",), "impulsión del agua caliente": ("htw_supply_temp",),
    "retorno del agua caliente": ("htw_return_temp",), "en banda": ("in_band",),
    "dentro de la banda": ("in_band", "inside", "total", "band_low", "band_high"), "energía": _ENERGY,
    "diferencial de presión": ("dp", "dp_setpoint"), "salida de la torre": ("leaving_water", "lw_setpoint", "lw"),
    "suministro": ("supply_temp", "supply_setpoint", "supply"), "consigna de suministro": ("supply_setpoint", "supply"),
    "setpoint de suministro": ("supply_setpoint", "supply"),
    "consigna de salida": ("lw_setpoint", "lw"),
    "salida de torre": ("leaving_water", "lw_setpoint", "lw"),
    # de
    "vorlauf": ("supply_temp", "supply_setpoint", "supply"), "vorlaufsollwert": ("supply_setpoint", "supply"),
    "vorlauf-sollwert": ("supply_setpoint", "supply"), "vorlauftemperatur-sollwert": ("supply_setpoint", "supply"),
    "rücklauf": ("return_temp",), "differenzdruck": ("dp", "dp_setpoint"), "durchfluss": ("flow",),
    "ventil ": ("valve",), "ventilanteil": ("valve",), "pumpendrehzahl": ("pump_speed",), "it-leistung": ("it_power",),
    "it-last": ("it_power",),
    "abgeführte wärme": ("cdu_heat",), "cdus führen": ("cdu_heat",),
    "abgegebene wärme": ("heat_rejected", "rejected_over_it"), "türme geben": ("heat_rejected", "rejected_over_it"),
    "austrittswasser": ("leaving_water", "lw_setpoint", "lw"), "austrittswasser-sollwert": ("lw_setpoint", "lw"),
    "turmsollwert": ("lw_setpoint", "lw"), "turm-sollwert": ("lw_setpoint", "lw"),
    "lüfterdrehzahl": ("fan_speed",), "lüfter": ("tower_power",), "kühlleistung": ("cooling_power",),
    "kühlung braucht": ("cooling_power",), "feuchtkugel": ("wet_bulb",), "warmwasser-vorlauf": ("htw_supply_temp",),
    "warmwasser-rücklauf": ("htw_return_temp",), "im band": ("in_band",),
    "innerhalb des": ("in_band", "inside", "total", "band_low", "band_high"), "energie": _ENERGY,
    "vorlauf-soll": ("supply_setpoint", "supply"), "vorlaufsoll": ("supply_setpoint", "supply"),
    "vl-soll": ("supply_setpoint", "supply"), "kt-soll": ("lw_setpoint", "lw"), "kt-austritt": ("lw_setpoint", "lw"),
    "kühlturm-soll": ("lw_setpoint", "lw"),
    "austrittssollwert": ("lw_setpoint", "lw"), "turm-austritt": ("lw_setpoint", "lw"),
    "austritt-soll": ("lw_setpoint", "lw"),
    "turm-soll": ("lw_setpoint", "lw"), "turmsoll": ("lw_setpoint", "lw"), "kühlturm": ("leaving_water", "lw"),
    "turmaustritt": ("leaving_water", "lw_setpoint", "lw"), "austritt": ("leaving_water", "lw_setpoint", "lw"),
    # fr
    "départ": ("supply_temp", "supply_setpoint", "supply"), "consigne de départ": ("supply_setpoint", "supply"),
    "alimentation": ("supply_temp", "supply_setpoint", "supply"), "consigne d'alimentation": ("supply_setpoint", "supply"),
    "consigne de température de départ": ("supply_setpoint", "supply"),
    "retour": ("return_temp",), "pression différentielle": ("dp", "dp_setpoint"), "débit": ("flow",),
    "vanne": ("valve",), "vitesse de pompe": ("pump_speed",), "pompe": ("pump_power", "cdu_pump_power"),
    "puissance it": ("it_power",), "charge it": ("it_power",), "chaleur évacuée": ("cdu_heat",),
    "évacuent": ("cdu_heat",), "rejet": ("heat_rejected", "rejected_over_it"),
    "eau de sortie": ("leaving_water", "lw_setpoint", "lw"), "consigne d'eau de sortie": ("lw_setpoint", "lw"),
    "consigne de la tour": ("lw_setpoint", "lw"),
    "approche": ("approach",), "vitesse des ventilateur": ("fan_speed",), "ventilateur": ("tower_power",),
    "puissance de refroidissement": ("cooling_power",), "refroidissement consomme": ("cooling_power",),
    "bulbe humide": ("wet_bulb",), "départ d'eau chaude": ("htw_supply_temp",),
    "retour d'eau chaude": ("htw_return_temp",), "lames": ("blade_temp", "blade_temp_mean"),
    "dans la bande": ("in_band",),
    "à l'intérieur de la bande": ("in_band", "inside", "total", "band_low", "band_high"), "énergie": _ENERGY,
    "soufflage": ("supply_temp", "supply_setpoint", "supply"), "consigne de soufflage": ("supply_setpoint", "supply"),
    "eau sortie": ("leaving_water", "lw_setpoint", "lw"), "sortie de tour": ("leaving_water", "lw_setpoint", "lw"),
    "sortie tour": ("leaving_water", "lw_setpoint", "lw"), "consigne tour": ("lw_setpoint", "lw"),
    "consigne d'eau sortie": ("lw_setpoint", "lw"), "consigne de sortie": ("lw_setpoint", "lw"),
    "consigne depart": ("supply_setpoint", "supply"), "depart": ("supply_temp", "supply_setpoint", "supply"),
    "tour consigne sortie": ("lw_setpoint", "lw"),
    "consigne de sortie de tour": ("lw_setpoint", "lw"), "consigne départ": ("supply_setpoint", "supply"),
}  # fmt: skip
def fold_accents(text: str) -> str:
    """The text without accents, letter for letter ("impulsión" -> "impulsion"): keys in JSON and logs drop them."""
    import unicodedata

    return "".join(unicodedata.normalize("NFKD", ch)[0] if ch.isalpha() else ch for ch in text)


QUANTITY_WORDS.update({fold_accents(w): keys for w, keys in list(QUANTITY_WORDS.items()) if fold_accents(w) != w})
QUANTITY = re.compile("|".join(re.escape(w) for w in sorted(QUANTITY_WORDS, key=len, reverse=True)), I)


def sentence_start(text: str, pos: int) -> int:
    """Where the sentence holding ``pos`` starts: after the last ". " or "; " before it."""
    cut = max(text.rfind(". ", 0, pos), text.rfind("; ", 0, pos))
    return 0 if cut < 0 else cut + 2


def quantity_before(text: str, pos: int) -> tuple[str, ...] | None:
    """The fact keys of the quantity named nearest before ``pos`` in its sentence, or None."""
    found = None
    for m in QUANTITY.finditer(text, sentence_start(text, pos), pos):
        found = QUANTITY_WORDS[m.group(0).lower()]
    return found


# The judge's action dimensions as fact keys: a phrase names the dimension when its keys meet ``any``, and the
# setpoint itself (a direction word then claims the action moved) when its keys lie inside ``setpoint``.
DIMENSION_KEYS: dict[str, tuple[set[str], set[str]]] = {
    "supply": ({"supply_temp", "supply_setpoint", "supply"}, {"supply_setpoint", "supply"}),
    "flow": ({"flow", "pump_speed"}, {"flow", "pump_speed"}),
    "dp": ({"dp", "dp_setpoint"}, {"dp", "dp_setpoint"}),
    "tower": ({"leaving_water", "lw_setpoint", "lw"}, {"lw_setpoint", "lw"}),
    "valve": ({"valve"}, {"valve"}),
}
# English forms the phrases above do not spell out: "CDU supply temperature setpoint", "Δp", "LWT", "CT"
_TOWER_WATER = r"leaving[\s-]+water|\bLWT\b|(?:condenser|cold)[\s-]+water"  # the water the towers send back
_SUPPLY_SETPOINT = ((r"(?:supply|coolant|CDU|inlet)(?:[\s-]+(?:water|coolant|temperature|temp))*[\s-]*"
                     r"(?:set[\s-]?points?|targets?)"), r"\bT_?cdu\b", r"\bsupply[\s-]+setpoint")  # fmt: skip
EN_DIMENSION_FORMS: dict[str, tuple[str, ...]] = {
    "supply_setpoint": _SUPPLY_SETPOINT,
    "supply": (*_SUPPLY_SETPOINT, r"supply(?:[\s-]+(?:water|coolant))?[\s-]+temperature",
               r"coolant[\s-]+(?:supply[\s-]+)?temperature", r"\bsupply\b", r"\bcoolant\b",
               r"(?<![^\W_])VL(?![^\W_])", r"(?:(?<=\|\s)|(?<=,\s)|(?<=;\s)|^)SP\b", r"\bsup\.?\s+(?:sp|setpoint)\b", r"\b(?:sp|setpoint)\s+imp\b",
               r"\b(?:cons|csg)\.?\s+alim\w*", r"\balim\b", r"\bvorl\.", r"\bimp\.?\s+sp\b"),  # German shorthand (Vorlauf); a bare SP item
    "flow": (r"\bflow(?:[\s-]+rate)?\b", r"\bpump[\s-]+speed\b", r"\bQ_?cdu\b", r"\bmass flow\b"),
    "dp": (r"\bdp\b", r"Δ\s?p\b", r"\bdelta[\s-]?p\b", r"differential[\s-]+pressure", r"\bpressure\b", "pump head"),
    "tower": (r"cooling[\s-]+towers?", r"\btowers?\b", r"\bCTs?\b", _TOWER_WATER, r"\bKT\b"),
    # "the tower fans slowed down" is about the fans, not the leaving-water setpoint
    "tower_setpoint": (_TOWER_WATER, r"tower[\s-]+(?:\w+[\s-]+)?set[\s-]?point", r"\bCT\b", r"\bKT\b",
                       r"towers?(?![\s-]+(?:fans?|power|energy|draw|load|cells?)\b)"),
    "valve": (r"\bvalves?\b", r"\bvlvs?\b", r"\bvent(?=\s*[=:])", r"\bvent(?=\s+\d)", r"\bvent\.", r"\bválv\b", r"\bv(?=\s*[=:]\s*[\[(]?\d)", r"\breceiv\w*", r"\bfractions?\b", r"\bopenings?\b", r"\bsplit\b", r"\ballocat\w*", r"\bdistribut\w*",
              r"\bshare of (?:the )?flow\b", r"\bof (?:the )?(?:\w+ )?flow\b", r"\bflow share\b",
              r"\bof (?:the )?(?:\w+ )?coolant\b", r"\bopen\w*",
              r"\bclos\w*", r"\bthrottl\w*", r"\btilt\w*", r"\bemphasi[sz]\w*", r"\bfavou?r\w*"),
}  # fmt: skip
# es / de / fr valve and split words the quantity phrases do not hold
VALVE_WORDS = {
    "es": ("válvulas?", "fracci(?:ón|ones)", r"recib\w*", "aperturas?", "reparto", r"repart\w*", r"distribu\w*",
           r"(?:cuota|parte)\s+del\s+caudal", r"del\s+caudal", "abierta", "abierto", "abrió", "abre", "cerrada",
           "cerrado", "cerró", "cierra", r"estrangul\w*"),
    "de": ("ventile?", r"ventil(?!ator|ador)\w+", r"\w+ventile?\w*", "ventilanteile?", "erhält", "bekommt", r"anteile?", r"öffnung\w*", "aufteilung", r"verteil\w*",
           r"des\s+durchflusses", r"durchflussanteile?", "geöffnet", r"öffnet", "geschlossen", r"schließt",
           r"gedrosselt", r"drosselt"),
    "fr": ("vannes?", "fractions?", r"ouvertures?", "répartition", r"part\s+de\s+débit", r"reçoi\w*", r"répart\w*", r"distribu\w*", r"(?:part\s+)?du\s+débit",
           "ouverte?s?", "ouvre", "fermée?s?", "ferme", r"étrangl\w*"),
}  # fmt: skip
VALVE_WORDS = {lang: forms + tuple(fold_accents(f) for f in forms if fold_accents(f) != f)
               for lang, forms in VALVE_WORDS.items()}
# es / de / fr tower words that name its setpoint
TOWER_SETPOINT_WORDS = (r"consigna\s+de\s+(?:la\s+)?torre", r"turm-?sollwert", r"sollwert\s+des\s+turms",
                        r"consigne\s+de\s+(?:la\s+)?tour", r"consigne\s+d['’]eau\s+(?:sortant|de\s+sortie)")  # fmt: skip
_NOT_TOWER_FANS = (r"(?![\s-]+(?:de\s+(?:la\s+)?)?(?:fans?|ventilador\w*|lüfter\w*|ventilateur\w*|power|potencia|"
                   r"leistung|puissance|energ\w*))")
_TOWER_NAMES = tuple(w for lang in ("es", "de", "fr") for w in ENTITY_WORDS["tower"][lang])


def _phrase(phrase: str) -> str:
    """A phrase as a regex from a word start: spaces and hyphens interchangeable, a trailing space a word end."""
    core = re.escape(phrase.strip()).replace(r"\ ", r"[\s-]+").replace(r"\-", r"[\s-]?")
    return r"\b" + core + (r"\b" if phrase.endswith(" ") else "")


def quantity_phrases(keys: set[str], only: bool = False) -> tuple[str, ...]:
    """``QUANTITY_WORDS`` phrases (as regexes) that may name one of ``keys``; with ``only``, those that name
    nothing else."""
    return tuple(_phrase(p) for p, their in QUANTITY_WORDS.items() if (set(their) <= keys if only else set(their) & keys))


def dimension(name: str, setpoint: bool = False) -> re.Pattern:
    """The words of an action dimension ("supply", "flow", "dp", "tower", "valve") in the four languages; with
    ``setpoint``, only those naming the setpoint itself (supply and tower)."""
    any_keys, setpoint_keys = DIMENSION_KEYS[name]
    english = EN_DIMENSION_FORMS[f"{name}_setpoint" if setpoint else name]
    others = quantity_phrases(setpoint_keys, only=True) if setpoint else quantity_phrases(any_keys)
    if name == "valve":
        others += tuple(r"\b" + w + r"\b" for w in _all(VALVE_WORDS))
    if name == "tower":
        # the bare tower word names its setpoint too ("torre sube a 29,0 °C"), not its fans or power
        others += TOWER_SETPOINT_WORDS + tuple(r"\b" + w + r"\b" + (_NOT_TOWER_FANS if setpoint else "")
                                               for w in _TOWER_NAMES)
    return re.compile("|".join(english) + "|" + alternation(*others), I)  # English first, as it was tuned


# --- valve shares ---------------------------------------------------------------------------------------------------

# "41 % of the flow" is a valve share, "34 % of the load" is not
OTHER_SHARES = words(
    "load", "power", "heat", "work", "IT", "band", "capacity", r"utili[sz]ation", "demand",  # en
    "carga", "potencia", "calor", "banda", "capacidad", r"utilizaci[oó]n",  # es
    "last", "leistung", "wärme", "band(?:es)?", "kapazität", "auslastung",  # de
    "charge", "puissance", "chaleur", "bande", "capacité", "utilisation",  # fr
)
_SHARE_EN = r"\s+(?:\w+\s+)?(?:flow|coolant|share|fraction|opening)"
SPLIT_WORDS: dict[str, dict[str, tuple[str, ...]]] = {
    # the valves split equally
    "equal": {"en": (r"equal(?:ly)?", r"even(?:ly)?(?!\s+(?:though|if|so|more|less|as|when|with)\b)", r"uniform\w*",
                     "same (?:fraction|opening|share)", r"(?:one|a)[\s-]+third\s+each", r"one[\s-]+third", r"a\s+third", "⅓", r"identical\w*",
                     r"(?<![\d/])(?<!\d[.,])1/3(?![\d/])(?![.,]\d)", r"thirds"),
              "es": (r"por\s+igual", r"igual(?:es|mente)", r"uniforme\w*", r"equitativ\w*", r"parej[oa]s", r"un\s+tercio", r"tercios", r"tercera\s+parte", r"idéntic\w*"),
              "de": (r"gleich(?:mäßig|mässig|e[nrs]?)?", r"gleichmäßig\w*", r"(?:ein(?:em)?\s+)?drittel", r"gedrittelt", r"gleichverteil\w*", r"identisch\w*"),
              "fr": (r"égal(?:e|es|ement)?", r"uniforme\w*", r"à\s+parts\s+égales", r"un\s+tiers", r"tiers", r"identique\w*", r"équiréparti\w*")},
    "each": {"en": ("each", "every", "all", "everywhere", "across the board", r"[x×]\s?[2-9]", r"[2-9]\s?[x×]"),
             "es": ("cada", "todas", "todos"),
             "de": (r"jede[nrs]?", "alle", "je", "überall"), "fr": ("chaque", "chacune?", "toutes", "tous", "partout")},
    # "its valve ...": the branch the previous sentence was about
    "its": {"en": ("it", "its"), "es": ("su", "sus"), "de": (r"sein\w*", r"ihr\w*"), "fr": ("son", "sa", "ses")},
    # "more flow", "a larger share", "less coolant"
    "more": {"en": (r"(?:more|larger|bigger|greater|higher|extra)" + _SHARE_EN,),
             "es": (r"más\s+(?:\w+\s+)?(?:caudal|refrigerante|apertura)",
                    r"(?<!\bla\s)(?<!\bel\s)mayor\s+(?:cuota|parte|apertura)"),
             "de": (r"mehr\s+(?:\w+\s+)?(?:durchfluss|kühlmittel)", r"(?:größere[nrs]?|höhere[nrs]?)\s+(?:anteil|öffnung)"),
             "fr": (r"plus\s+de\s+(?:débit|fluide)", r"(?:une\s+)?plus\s+grande\s+(?:part|ouverture)")},
    "less": {"en": (r"(?:less|smaller|lower|reduced)" + _SHARE_EN,),
             "es": (r"menos\s+(?:\w+\s+)?(?:caudal|refrigerante|apertura)", r"menor\s+(?:cuota|parte|apertura)"),
             "de": (r"weniger\s+(?:\w+\s+)?(?:durchfluss|kühlmittel)", r"(?:kleinere[nrs]?|niedrigere[nrs]?)\s+(?:anteil|öffnung)"),
             "fr": (r"moins\s+de\s+(?:débit|fluide)", r"(?:une\s+)?plus\s+petite\s+(?:part|ouverture)")},
    # a valve claim made against the other branches ("more than the others") or the load ("above its load share")
    "than_others": {"en": ("than", "equal", r"even(?!\s+(?:though|if|so|when|as|more|less))(?=\s+\w)", "average",
                           "others?"),
                    "es": (r"que\s+(?:las|los)\s+(?:demás|otr[oa]s)", "media", "promedio"),
                    "de": ("als", r"durchschnitt\w*", r"andere[mns]?"),
                    "fr": (r"que\s+les\s+autres", "moyenne")},
    "than_load": {"en": (r"(?:load|power)\s+share", r"its share of (?:the )?(?:load|power)"),
                  "es": (r"cuota\s+de\s+carga",), "de": (r"lastanteil\w*",), "fr": (r"part\s+de\s+(?:la\s+)?charge",)},
}  # fmt: skip


def split_words(kind: str) -> re.Pattern:
    """One kind of ``SPLIT_WORDS`` in the four languages, as whole words."""
    return words(*_all(SPLIT_WORDS[kind]))


# --- directions ------------------------------------------------------------------------------------------------------

# Words that say a value went up, down or stayed, as plain words (whole words, case-insensitive). The chat reads
# up and down in all four languages; the judge reads es / de / fr from here and English through its grammar
# (EN_DIRECTIONS: which side of the verb the dimension is on, "held" and "kept" among its hold words).
DIRECTION_WORDS: dict[str, dict[str, tuple[str, ...]]] = {
    "up": {"en": ("raised", "rose", "up", "increased", "higher", "opened", "bumped", "climbed", "warmer"),
           "es": ("subió", "sube", "subido", "aumentó", "aumenta", "aumentado", "aumentada", "abrió", "abierto",
                  "abierta", "elevó", "elevado", "elevada", "incrementó", "incrementado", "incrementada"),
           "de": ("gestiegen", "steigt", "stieg", "erhöht", "erhöhte", "erhöhten", "geöffnet", "öffnet", "angehoben",
                  "angestiegen", "hob"),
           "fr": ("augmenté", "augmentée", "augmente", "relevé", "relevée", "relève", "ouvert", "ouverte", "ouvre",
                  "monté", "montée", "hausse", "rehaussé", "rehaussée")},
    "down": {"en": ("lowered", "fell", "down", "decreased", "lower", "closed", "dropped", "trimmed", "eased", "cooler"),
             "es": ("bajó", "bajado", "bajada", "disminuyó", "disminuye", "disminuido", "disminuida", "descendió",
                    "cayó", "cerró", "cierra", "cerrado", "cerrada", "redujo", "reduce", "reducido", "reducida"),
             "de": ("gesunken", "sinkt", "sank", "gesenkt", "senkt", "senkte", "gefallen", "fällt", "fiel",
                    "geschlossen", "schließt", "abgesenkt", "verringert", "reduziert", "gedrosselt", "drosselt"),
             "fr": ("baissé", "baissée", "baisse", "abaissé", "abaissée", "diminué", "diminuée", "diminue", "fermé",
                    "fermée", "ferme", "descendu", "descendue", "réduit", "réduite")},
    "hold": {"es": ("mantuvo", "mantiene", "mantenido", "mantenida", "sin cambios", "sin cambio", "no cambió", "constante",
                    "fijo", "fija"),
             "de": ("gehalten", "hält", "hielt", "beibehalten", "unverändert", "konstant", "blieb", "bleibt",
                    "nicht verändert", "nicht geändert"),
             "fr": ("maintenu", "maintenue", "inchangé", "inchangée", "conservé", "conservée", "constant",
                    "constante", "reste", "pas changé", "pas bougé")},
}  # fmt: skip
UP_WORDS = _all(DIRECTION_WORDS["up"])
DOWN_WORDS = _all(DIRECTION_WORDS["down"])
# comparisons that suggest a direction without claiming one ("more flow", "a lower setpoint")
COMPARISON_WORDS = ("more", "less", "larger", "smaller", "bigger", "greater", "higher", "lower", "extra", "reduced",
                    "más", "menos", "mayor", "menor", "mehr", "weniger", "höher", "niedriger", "größer", "kleiner",
                    "davantage", "moins", r"plus\s+(?:de|d['’])", "supérieure?", "inférieure?")  # fmt: skip
# "from A to B": the verb's direction must match A -> B
FROM_TO = re.compile(r"\b(?:from|de|desde|von|du)\s+(-?\d+(?:\.\d+)?)[^,;]*?\b(?:to|a|hasta|auf|bis|à)\s+"
                     r"(-?\d+(?:\.\d+)?)", I)  # fmt: skip

# English direction grammar, with the side the dimension is on: "after" (raises the setpoint), "before" (the
# setpoint rises), "both" (raised the setpoint / the setpoint is raised); es / de / fr words are "both"
_BEFORE_NOW = r"than\s+(?:before|previously|the\s+previous|last)"
# an object right after a verb: "drops the setpoint" is a claim about the setpoint, "the setpoint drops to" is not
_OBJECT_WORDS = (r"\s+(?:the|its|their|it|this|that|these|those|both|all|each|branch(?:es)?|blade|groups?|valves?"
                 r"|supply|dp|tower|cdu|coolant|LWT|B\d)\b")
_OBJECT, _NO_OBJECT = f"(?={_OBJECT_WORDS})", f"(?!{_OBJECT_WORDS})"
# phrasal verbs: "bumps up the setpoint", "brought down", "crept up"; verbs that go with up/down but do not move a
# setpoint (heats up, sets up, cools down, settles down) are left out
_NOT_PHRASAL_UP = (r"(?!(?:held|kept|heat(?:s|ed)?|warm(?:s|ed)?|pick(?:s|ed)?|back(?:s|ed)?|sets?|left|make?s?|made"
                   r"|end(?:s|ed)?|show(?:s|ed)?|sum(?:s|med)?|line(?:s|d)?|hold(?:s)?|keeps?|look(?:s|ed)?|use(?:s|d)?"
                   r"|add(?:s|ed)?|build(?:s)?|built|runs?|ran|catch(?:es)?|caught|follow(?:s|ed)?|speak(?:s)?|spoke"
                   r"|go(?:es)?|went|is|was|are|were|be|been)\b)")
_NOT_PHRASAL_DOWN = (r"(?!(?:cool(?:s|ed)?|calm(?:s|ed)?|settl(?:e|es|ed)|held|holds?|kept|keeps?|sets?|writ(?:e|es)"
                     r"|wrote|written|break(?:s)?|broke|broken|shut(?:s)?|note(?:s|d)?|look(?:s|ed)?|track(?:s|ed)?"
                     r"|go(?:es)?|went|is|was|are|were|be|been|count(?:s|ed)?)\b)")
_IRREGULAR_PAST = r"(?:brought|taken|took|wound|crept|dialled|dialed|cranked|ratcheted)"
EN_DIRECTIONS: list[tuple[str, str, tuple[str, ...]]] = [
    ("up", "after", ("rais(?:e|es|ing)", "increas(?:e|es|ing)", "boost(?:s|ing)?", "lift(?:s|ing)?", "widen(?:s|ing)?",
                     r"open(?:s|ing)?\s+(?:up|further|wider|more)", r"nudg(?:e|es|ing)\s+up", r"step(?:s|ping)?\s+up",
                     r"ups" + _OBJECT, r"hik(?:e|es|ing)", r"elevat(?:e|es|ing)", r"open(?:s|ing)?" + _OBJECT,
                     _NOT_PHRASAL_UP + r"[a-z]+(?:s|ing)\s+up" + _OBJECT)),
    ("up", "both", ("raised", "increased", "boosted", "lifted", "widened", r"opened\s+(?:up|further|wider|more)",
                    r"stepped\s+up", r"bumped(?:\s+up)?", r"nudged\s+up", r"pushed\s+up", "upped", "hiked", "elevated",
                    # "opened to 0.40", not "the most opened" or "opened the most" (a ranking)
                    (r"(?<!most\s)(?<!least\s)(?<!more\s)(?<!less\s)(?<!fully\s)opened"
                     r"(?!\s+(?:\w+\s+){0,2}(?:the\s+)?(?:most|least)\b)"),
                    r"adjust(?:s|ed|ing)?\s+upwards?", r"(?:moved|shifted|pushed|nudged)\s+higher",
                    _IRREGULAR_PAST + r"\s+up",
                    r"(?!(?:held|kept|heated|warmed|picked|backed|set|left)\b)[a-z]+ed\s+up")),
    ("up", "before", ("ris(?:e|es|ing)", "rose", r"goes\s+up", r"went\s+up", r"moves?\s+up", r"up\s+by", r"up\s+from",
                      r"higher\s+" + _BEFORE_NOW, r"climb(?:s|ed|ing)?", "grew", r"grows?", r"creep(?:s|ing)?\s+up",
                      r"tick(?:s|ing)?\s+up", r"edg(?:e|es|ing)\s+up", r"inch(?:es|ing)?\s+up")),
    ("down", "after", (r"lower(?:s|ing)?" + _OBJECT, "decreas(?:e|es|ing)", "reduc(?:e|es|ing)", "cut(?:s|ting)?",
                       r"step(?:s|ping)?\s+down", r"drop(?:s|ping)?" + _OBJECT, r"eas(?:e|es|ing)" + _OBJECT,
                       r"trim(?:s|ming)?", r"shav(?:e|es|ing)", r"slash(?:es|ing)?", r"lessen(?:s|ing)?",
                       _NOT_PHRASAL_DOWN + r"[a-z]+(?:s|ing)\s+(?:down|back)" + _OBJECT)),
    ("down", "both", ("lowered", "decreased", "reduced", "closed", "throttled", "narrowed", r"stepped\s+down",
                      r"cut\s+back", "clos(?:e|es|ing)", "throttl(?:e|es|ing)", "narrow(?:s|ing)?", "trimmed", "eased",
                      "cut", "dropped", r"backed\s+off", r"pulled\s+down", r"nudged\s+down", "shaved", "slashed",
                      "lessened",
                      r"adjust(?:s|ed|ing)?\s+downwards?", r"(?:moved|shifted|pushed|nudged)\s+lower",
                      _IRREGULAR_PAST + r"\s+(?:down|back)",
                      r"(?!(?:cooled|calmed|settled|held|kept|set)\b)[a-z]+ed\s+(?:down|back)")),
    ("down", "before", (r"drop(?:s|ping)?" + _NO_OBJECT, "falls?", "fell", r"goes\s+down", r"went\s+down",
                        r"moves?\s+down",
                        r"down\s+by", r"down\s+from", r"lower\s+" + _BEFORE_NOW, r"dip(?:s|ped|ping)?",
                        r"slip(?:s|ped|ping)?", r"eas(?:e|es|ing)" + _NO_OBJECT, r"creep(?:s|ing)?\s+down",
                        r"tick(?:s|ing)?\s+down", r"edg(?:e|es|ing)\s+down", r"inch(?:es|ing)?\s+down")),
    ("hold", "after", ("hold(?:s|ing)?", "keep(?:s|ing)?", "maintain(?:s|ing)?", r"leaves?(?!\s+water)",
                       r"pin(?:s|ning)?", r"freez(?:e|es|ing)")),
    ("hold", "both", ("held", "kept", "maintained", "unchanged", r"left\s+(?:at|unchanged|alone)", "fixed",
                      r"no\s+change", "parked", "pinned", "frozen", "untouched", "unaltered", "retained", "preserved")),
    ("hold", "before", ("steady", "constant", "stays?", "stayed", "remains?", "remained", r"(?:is|was)\s+not\s+changed",
                        r"did\s+not\s+change")),
]  # fmt: skip
# every inflection of the es / de / fr verbs of moving a setting (the words above are the forms the chat writes and
# tests one by one; these stems are what other writers use: "subieron", "la bajaron", "eleva", "runter", "remonte")
DIRECTION_STEMS: dict[str, tuple[str, ...]] = {  # finite forms and participles only: an infinitive ("subir la
    # consigna la enfriaría", "relever la Δp ferait") names a move without claiming it
    "up": (r"sub(?:e|en|ió|ieron|ida|ido|imos|iendo)", r"elev(?:a|an|ó|aron|ado|ada)", r"increment(?:a|an|ó|aron|ado|ada)",
           r"aument(?:a|an|ó|aron|ado|ada)", r"abr(?:e|en|ió|ieron|iendo)", r"erhöh(?:t|te|ten)", r"angehoben\w*",
           "hob", r"aufgemacht\w*", r"geöffnet\w*", r"öffne(?:t|te|ten)", r"relev(?:é|ée|és|ées|e|ent)", r"relève\w*",
           r"remont(?:e|ent|é|ée)", r"mont(?:e|ent|é|ée)", r"augment(?:e|ent|é|ée|és|ées)", r"rehauss(?:e|é|ée)",
           r"ouvr(?:e|ent)", r"ouvert\w*"),
    "down": (r"baj(?:an|ó|aron|ada|ado|amos|ando)", r"baja(?=\s+(?:a|de|hasta|un|una)\b)", r"reduc(?:e|en|ido|ida)", r"redujo|redujeron",
             r"disminu(?:ye|yen|yó|yeron|ido|ida)", r"desciende|descendió|descendieron", r"cerr(?:ó|aron|ada|ado|ando)",
             r"cierr(?:a|an)", r"gesenkt\w*", r"senk(?:t|te|ten)", r"abgesenkt\w*", "runter", r"zugemacht\w*",
             r"geschlossen\w*", r"schließt|schloss", r"gedrosselt\w*", r"drossel(?:t|te)", r"verringert\w*",
             r"baiss(?:e|ent|é|ée|és|ées)", r"abaiss(?:e|ent|é|ée)", r"diminu(?:e|ent|é|ée)", r"redescend\w*",
             r"ferm(?:e|ent|é|ée|és|ées)", r"réduit\w*"),
    "hold": (r"mantien\w+", r"mantuv\w+", r"mantenid[oa]s?", r"sigue|siguen", r"qued(?:a|an|ó|aron)", r"quiet[oa]s?",
             r"sin\s+cambios?", r"gehalten\w*", r"beibehalten\w*", r"unverändert\w*", r"bleib(?:t|en)", r"blieb\w*",
             r"konstant\w*", r"wie\s+(?:gehabt|vorher|zuvor)", r"maintenu\w*", r"inchangé\w*", r"rest(?:e|ent)",
             r"conserv(?:e|ent|é|ée|és|ées)", "stable", "pareil", r"ne\s+(?:change|bouge)\s+pas", r"igual(?:es)?"),
}  # fmt: skip
DIRECTIONS = EN_DIRECTIONS + [(pol, "both", tuple(w for lang in ("es", "de", "fr") for w in by_lang.get(lang, ()))
                               + DIRECTION_STEMS[pol]) for pol, by_lang in DIRECTION_WORDS.items()]  # fmt: skip
"""(polarity, side, forms) of every direction word the judge reads."""

# --- superlatives ----------------------------------------------------------------------------------------------------

# "highest" / "lowest" in general (the chat ranks any quantity), and of one kind (temperature, load, valve
# opening: the judge checks each against its own data); es / fr forms followed by "que" are comparatives
_VALVE_NOUN = r"\s+(?:valve\s+)?(?:valve|opening|fraction|share\s+of\s+(?:the\s+)?flow)"
_LOAD_NOUN = r"\s+(?:\w+\s+)?(?:load|power|heat|workload|utili[sz]ation|demand)"
_NOT_FROM = r"(?![^;]*\b(?:from|away)\b)"  # "the split tilts away from branch 3" is a change, not a ranking
_NO_QUE = r"(?!\s+que\b)"
SUPERLATIVES: dict[tuple[str, str], dict[str, tuple[str, ...]]] = {
    ("any", "highest"): {"en": ("highest", "most", "largest", "biggest", "maximum", "max", "peak"),
                         "es": (r"más\s+(?:alt[oa]|elevad[oa])s?" + _NO_QUE, r"máxim[oa]s?"),
                         "de": (r"(?:höchst|größt)e[nrs]?", r"maximale[nrs]?"),
                         "fr": (r"(?:le|la|les)\s+plus\s+(?:élevé|haut)e?s?" + _NO_QUE,)},
    ("any", "lowest"): {"en": ("lowest", "least", "smallest", "minimum", "min"),
                        "es": (r"más\s+baj[oa]s?" + _NO_QUE, r"mínim[oa]s?"),
                        "de": (r"(?:niedrigst|tiefst|kleinst|geringst)e[nrs]?", r"minimale[nrs]?"),
                        "fr": (r"(?:le|la|les)\s+plus\s+(?:bas|faible)(?:e|se)?s?" + _NO_QUE,)},
    ("temp", "highest"): {"en": ("hottest", "warmest", r"highest\s+(?:blade\s+|branch\s+)?temperature",
                                 r"most\s+thermally\s+stressed"),
                          "es": (r"más\s+(?:caliente|cálid[oa])s?" + _NO_QUE, r"temperatura\s+más\s+alta",
                                 r"(?:la|el)\s+caliente"),
                          "de": (r"(?:heißest|heissest|wärmst)e[nrs]?", r"höchste[nr]?\s+temperatur"),
                          "fr": (r"(?:le|la|les)\s+plus\s+chaude?s?" + _NO_QUE,
                                 r"température\s+la\s+plus\s+(?:élevée|haute)")},
    ("temp", "lowest"): {"en": ("coolest", "coldest", r"lowest\s+(?:blade\s+|branch\s+)?temperature"),
                         "es": (r"más\s+fr[ií][oa]s?" + _NO_QUE, r"temperatura\s+más\s+baja"),
                         "de": (r"(?:kältest|kühlst)e[nrs]?", r"niedrigste[nr]?\s+temperatur"),
                         "fr": (r"(?:le|la|les)\s+plus\s+froide?s?" + _NO_QUE, r"température\s+la\s+plus\s+basse")},
    ("load", "highest"): {"en": (r"most\s+(?:heavily\s+)?loaded", r"most\s+(?:of\s+the\s+)?(?:load|power|heat|work)",
                                 "heaviest", "(?:highest|largest|biggest|greatest)" + _LOAD_NOUN, "busiest",
                                 r"peak\s+load"),
                          "es": (r"más\s+cargad[oa]s?" + _NO_QUE, r"(?:la|el)\s+que\s+más\s+(?:carga|potencia|trabaja|tira)",
                                 r"más\s+carga\s+(?:lleva|tiene|soporta)", r"mayor\s+carga"),
                          "de": (r"am\s+stärksten\s+(?:belastet|ausgelastet)(?:e[nrs]?)?", r"(?:die\s+)?meiste\s+last",
                                 r"höchste[nr]?\s+last", r"meistbelastete[nrs]?", r"am\s+meisten\s+(?:last|belastet)"),
                          "fr": (r"(?:le|la|les)\s+plus\s+chargée?s?" + _NO_QUE,)},
    ("load", "lowest"): {"en": (r"least\s+(?:heavily\s+)?loaded", r"least\s+(?:of\s+the\s+)?(?:load|power|heat|work)",
                                "lightest", "(?:lowest|smallest)" + _LOAD_NOUN, "idlest"),
                         "es": (r"menos\s+cargad[oa]s?" + _NO_QUE, r"más\s+descargad[oa]s?",
                                r"(?:la|el)\s+que\s+menos\s+(?:carga|potencia|trabaja|tira)", r"menos\s+carga\s+(?:lleva|tiene)",
                                r"menor\s+carga"),
                         "de": (r"am\s+schwächsten\s+(?:belastet|ausgelastet)(?:e[nrs]?)?",
                                r"am\s+wenigsten\s+(?:belastet|ausgelastet|last)(?:e[nrs]?)?", r"geringste[nr]?\s+last",
                                r"wenigste[nr]?\s+last"),
                         "fr": (r"(?:le|la|les)\s+moins\s+chargée?s?" + _NO_QUE,)},
    ("valve", "highest"): {"en": ("(?:largest|biggest|highest|widest)" + _VALVE_NOUN, r"most\s+(?:open(?:ed)?|flow)",
                                  r"open(?:s|ed)?\s+(?:\w+\s+){0,3}the\s+most", "widest",
                                  # indirect: "the split tilts toward branch 3", "the allocation emphasizes branch 3"
                                  r"tilt(?:s|ed|ing)?\s+(?:\w+\s+)?toward(?:s)?" + _NOT_FROM,
                                  r"emphasi[sz](?:e|es|ed|ing)" + _NOT_FROM, r"favou?r(?:s|ed|ing)" + _NOT_FROM),
                           "es": (r"más\s+abiert[oa]s?" + _NO_QUE,),
                           "de": (r"am\s+weitesten\s+geöffnet(?:e[nrs]?)?",),
                           "fr": (r"(?:le|la|les)\s+plus\s+ouverte?s?" + _NO_QUE,)},
    ("valve", "lowest"): {"en": ("(?:smallest|lowest|narrowest)" + _VALVE_NOUN, r"least\s+(?:open(?:ed)?|flow)",
                                 r"most\s+closed"),
                          "es": (r"menos\s+abiert[oa]s?" + _NO_QUE,),
                          "de": (r"am\s+wenigsten\s+geöffnet(?:e[nrs]?)?",),
                          "fr": (r"(?:le|la|les)\s+moins\s+ouverte?s?" + _NO_QUE,)},
}  # fmt: skip
HIGHEST = tuple(w for (_, order), by_lang in SUPERLATIVES.items() if order == "highest" for w in _all(by_lang))
LOWEST = tuple(w for (_, order), by_lang in SUPERLATIVES.items() if order == "lowest" for w in _all(by_lang))
# "branch 1 is hotter / more loaded than branch 3", "Zweig 2 ist wärmer als Zweig 3", "la rama 2 lleva más carga que
# la rama 3", "la branche 1 est plus chaude que la branche 2"
COMPARATIVES: dict[tuple[str, str], tuple[str, ...]] = {
    ("temp", "gt"): ("hotter", "warmer", r"más\s+caliente", "wärmer", "heißer", r"plus\s+chaude?"),
    ("temp", "lt"): ("cooler", "colder", r"más\s+fr[ií][oa]", "kühler", "kälter", r"plus\s+froide?"),
    ("load", "gt"): (r"more\s+(?:heavily\s+)?loaded", r"(?:more|higher)\s+(?:load|power|heat)",
                     r"más\s+(?:carga|cargad[oa])", r"mehr\s+last", r"stärker\s+belastet",
                     r"plus\s+(?:de\s+)?charg(?:e|ée)"),
    ("load", "lt"): (r"less\s+(?:heavily\s+)?loaded", r"(?:less|lower)\s+(?:load|power|heat)",
                     r"menos\s+(?:carga|cargad[oa])", r"weniger\s+last", r"schwächer\s+belastet",
                     r"moins\s+(?:de\s+)?charg(?:e|ée)"),
}  # fmt: skip


def superlative_forms(kind: str, order: str) -> tuple[str, ...]:
    """The regex forms of one kind's superlative (``kind`` "temp", "load", "valve" or "any"; ``order`` "highest" or
    "lowest") in the four languages."""
    return _all(SUPERLATIVES[kind, order])


# --- function words --------------------------------------------------------------------------------------------------

FUNCTION_WORDS: dict[str, dict[str, tuple[str, ...]]] = {
    "and": {"en": ("and",), "es": ("y",), "de": ("und",), "fr": ("et",)},
    "or": {"en": ("or",), "es": ("o",), "de": ("oder",), "fr": ("ou",)},
    "not": {"en": ("not", "no", "never", "cannot", "without", "neither", "nor", r"instead\s+of", r"rather\s+than"),
            "es": ("no", "nunca", "ni", r"en\s+lugar\s+de"), "de": ("nicht", r"kein\w*", "nie", "weder", r"(?:an)?statt"),
            "fr": ("pas", "jamais", "ni", r"au\s+lieu\s+de", r"plutôt\s+que")},
    # a clause that starts so is a condition, not a claim about this action
    "if": {"en": ("if", "unless", "when", "whenever", "should", r"in\s+case", "otherwise"),
           "es": ("si", "cuando", r"a\s+menos\s+que"), "de": ("wenn", "falls", "sofern"),
           "fr": ("si", "quand", "lorsque", r"à\s+moins\s+que")},
    # modals and advice: not a claim about this action
    "would": {"en": ("would", "could", "should", "might", "may", "can", "consider", r"recommend\w*", r"suggest\w*",
                     "try", "aim", "plan", "ought", "prefer", "whether", "if", "unless", r"needs?\s+to", "worth"),
              "es": ("podría", "debería", "sería", "habría", "puede", r"recomend\w*", r"recomiend\w*", r"sugier\w*",
                     r"suger\w*", "si"),
              "de": ("würde", "könnte", "sollte", "kann", r"empfehl\w*", r"empfiehlt", "wenn", "falls"),
              "fr": ("pourrait", "devrait", "serait", "peut", r"recommand\w*", r"suggér\w*", "si")},
    # clause openers: "but", "while", "because" ...
    "but": {"en": ("but", "while", "whereas", "although", "though", "because", "since", "if", "unless", "when",
                   "whenever", "so that", "which", "otherwise"),
            "es": ("pero", "mientras", "aunque", "porque", "ya que", "si", "cuando"),
            "de": ("aber", "während", "obwohl", "weil", "wenn"),
            "fr": ("mais", "tandis que", "alors que", "bien que", "parce que", "car", "si", "quand")},
}  # fmt: skip


def function_words(kind: str) -> tuple[str, ...]:
    """One kind of function word ("and", "or", "not", "if", "would", "but") in the four languages."""
    return _all(FUNCTION_WORDS[kind])


# --- what a question asks for (the chat's question check, lcmesh/assistant/engine.py uncovered()) ----------------
# Words in a question that name something the answer must address; a plan that covers none of their concepts
# answers another question, and its answer is not marked grounded (the reply says what may be missing).
QUESTION_CONCEPTS: list[tuple[re.Pattern, frozenset[str]]] = [(re.compile(p, re.IGNORECASE), frozenset(c)) for p, c in (
    (r"\bpue\b", {"pue"}),
    (r"\bapproach|aproximaci[oó]n|ann[aä]herung|\bapproche", {"approach"}),
    (r"wet[- ]?bulb|bulbo h[uú]medo|feuchtkugel|bulbe humide", {"wet_bulb"}),
    (r"\bvalves?\b|v[aá]lvula|\bventil(e|s)?\b|\bventil(anteil|stellung)|\bvanne", {"valve"}),
    (r"\bdp\b|differential pressure|presi[oó]n|druck|pression", {"dp", "dp_setpoint"}),
    (r"\bflows?\b|caudal|durchfluss|d[ée]bit", {"flow"}),
    (r"\breturn\b|retorno|r[uü]cklauf|\bretour", {"return_temp", "htw_return_temp"}),
    (r"\balert|\balarm|\bfaults?\b|st[oö]rung|warnung|alerte|\bflag", {"alerts"}),
    (r"(?<!maintenance )\bagents?\b|(?<!en )(?<!in )\bservices?\b|agentes?\b|dienste", {"agents"}),
    (r"controller|\bpolicy\b|\bregler|controlador|contr[oô]leur", {"controller"}),
    (r"reject|rechaz|abgegeben|\brejet", {"heat_rejected"}),
    (r"leaving[- ]water|\blwt?\b|\bbasin\b", {"leaving_water", "lw_setpoint", "lw"}),
    (r"(?<!hot[- ])(?<!hot)\bwater\b", {"leaving_water", "lw_setpoint", "lw", "htw_supply_temp", "htw_return_temp"}),
    (r"\b(last|past|previous)\s+(\d+\s*)?(min|mins|minutes?|hours?|h|hrs?|days?)\b|\bago\b|\bhace\b|\bvor\s+\d"
     r"|\bil y a\b|[uú]ltima hora|[uú]ltimos \d+|letzten (stunde|\d+)|derni[eè]re heure|derni[eè]res \d+", {"history"}),
    (r"\bband\b|\bbanda\b|\bbande\b|compliance", {"in_band"}),
    (r"\bsu[p]{1,2}ly|impulsi[oó]n|vorlauf|\bd[ée]part\b", {"supply", "supply_temp", "supply_setpoint"}),
    (r"\b(towers?|torres?|t[uü]rme?|tours?|ct)\b(?!\s*#?\s*\d)", {"tower", "leaving_water", "lw_setpoint", "lw",
                                                                     "approach", "fan_speed", "tower_power",
                                                                     "heat_rejected"}),
    (r"hottest|\bhott[ets]{3}\b|warmest|coolest|coldest|\bhighest|\blowest|m[aá]s (caliente|fr[ií]o|alt[oa]|baj[oa])|hei(ß|ss)est"
     r"|k[aä]ltest|h[oö]chst|niedrigst|plus (chaud|froid|[ée]lev[ée]|bas)", {"ranking"}),
    (r"coolest|coldest|\blowest|\bleast\b|m[aá]s fr[ií]o|m[aá]s baj[oa]|k[aä]ltest|niedrigst|plus froid|plus bas",
     {"lowest"}),
    (r"\bmanual\b|\bmanuel\b|\bmanuell\b|\bauto(matic)?\s+mode|\bmodo\b|\bmodus\b", {"mode"}),
    (r"what (if|would happen)|\bsuppose\b|\bsimulat|qu[eé] pasar[ií]a|was w[aä]re|was passiert,? wenn"
     r"|que se passerait|\bet si\b", {"whatif"}),
    # the kind of quantity: energy (kWh over a window) is not power now
    (r"how much heat\b.*\b(last|past)\b|^(?!.*\bkw\b(?!h))(?=.*(\b(energ(y|[ií]a|ie)|[ée]nergie)\b(?!\s*(balance|efficiency|bilanz|bilan|-?effizienz))"
     r"|\bkwh\b|\bconsum|\bverbrauch|\bconsomm))", {"energy"}),  # "consuming now, in kW" asks power
    # "where" and "when" ask for a place and a time, not only a value
    (r"\bwhere\b|\bd[oó]nde\b|\bwo\b|\bwhich (cabinet|branch|tower|blade|cdu)|(?<!\w)où(?!\w)", {"where"}),
    (r"\bwhen\b|what time|\bcu[aá]ndo\b|qu[eé] hora|\bwann\b|wie viel uhr|\bquand\b|quelle heure", {"when"}),
    (r"(how many|\bcu[aá]nt[oa]s\b|wie viele|\bcombien de\b)(?!\s+(kwh|kw|mwh|degrees?|grados|grad|degr[ée]s|"
     r"minutes?|minutos|minuten|hours?|horas|stunden|heures|percent|por ciento|prozent|pour cent|psi|bar|k\b))",
     {"count"}),
    (r"\bpumps?\b|\bbombas?\b|\bpumpen?\b|\bpompes?\b", {"pumps", "pump_power", "cdu_pump_power", "pump_speed",
                                                         "cooling_power"}),
    (r"\bfans?\b|ventiladores?|l[uü]fter|ventilateurs?", {"fans", "tower_power", "fan_speed", "cooling_power"}),
    (r"\bweather\b|\bclima\b|\bwetter\b|\bm[ée]t[ée]o\b|(wet[- ]?bulb|bulbo|feuchtkugel|bulbe)\b.*\b(effect|affect|"
     r"impact|influen|efecto|afecta|wirkung|einfluss|auswirk|effet)|\b(effect|affect|impact|influen|efecto|afecta|"
     r"wirkung|einfluss|auswirk|effet)\w*\b.*(wet[- ]?bulb|bulbo|feuchtkugel|bulbe)", {"weather"}),
)]  # fmt: skip
# Two words together name what the answer must be: a setpoint-tracking gap, blade groups ranked (not cabinets).
PAIRED_CONCEPTS: list[tuple[re.Pattern, re.Pattern, frozenset[str]]] = [
    (re.compile(p, re.IGNORECASE), re.compile(q, re.IGNORECASE), frozenset(c)) for p, q, c in (
        (r"\bgaps?\b|deviat|\boff\b|\bfar\b|f[au]rthest|further|away from|differ|\btrack|abweich|[ée]cart|desviac|minus|"
         r"unterschied|distance|lejos|entfernt|loin",
         r"set[- ]?points?|consigna|sollwert|consigne", {"gap"}),
        (r"blade[- ]?groups|\bbranches\b|grupos de blades|\bramas\b|blade-gruppen|\bzweige\b|groupes de lames",
         r"hottest|warmest|coolest|coldest|highest|lowest|\btop\b|\blist\b|rank|m[aá]s (caliente|fr[ií])|"
         r"hei(ß|ss)est|k[aä]ltest|plus (chaud|froid)", {"branch_level"}),
    )]  # fmt: skip
SETPOINT_WORD = re.compile(r"set[- ]?points?|\bsp\b|consignas?|sollwerte?s?|consignes?", re.IGNORECASE)
# The aggregate a question asks of a window, and which way a ranking goes.
ASKED_STATS = {"mean": re.compile(r"\b(average|avg|mean|promedio|media|durchschnitt\w*|mittel\w*|moyenne)\b"
                                  r"(?![\s-]+(blade|temp))", I),
               "max": re.compile(r"\b(max(imum)?|peak(ed)?|highest|m[aá]xim[oa]|pico|spitze|h[oö]chst\w*|pic)\b", I),
               "min": re.compile(r"\b(minimum|lowest|m[ií]nim[oa]|niedrigst\w*|tiefst\w*)\b", I)}  # fmt: skip
HIGH_WORD = re.compile(r"\b(hottest|hott?est|warmest|highest|most|biggest|largest|fastest|m[aá]s (caliente|alt[oa])|"
                       r"hei(ß|ss)est\w*|h[oö]chst\w*|plus (chaud|[ée]lev[ée]))", I)  # fmt: skip
LOW_WORD = re.compile(r"\b(coolest|coldest|lowest|least|smallest|slowest|bottom|m[aá]s (fr[ií][oa]|baj[oa])|"
                      r"k[aä]ltest\w*|niedrigst\w*|plus (froid|bas))", I)  # fmt: skip
TRACKING_ERROR = re.compile(r"tracking error|regelabweichung|control (error|deviation)|error de (control|seguimiento)|"
                            r"[ée]cart de r[ée]gulation", I)  # fmt: skip
DOWN_ASKED = re.compile(r"\b(lower\w*|reduc\w*|decreas\w*|drop\w*|cut|bajar|baja|bajo|reducir|absenken|senken|senke|"
                        r"verringer\w*|baisser|abaisser|baisse|diminuer)\b|(?<![\w.])-\s*\d", I)  # fmt: skip
UP_ASKED = re.compile(r"\b(rais\w*|increas\w*|bump\w*|subir|sube|aumentar|anheben|erh[oö]h\w*|augmenter|augmente|"
                      r"relever)\b|(?<![\w.])\+\s*\d", I)  # fmt: skip
MEASURED_WORD = re.compile(r"(?<!not the )(?<!not )(?<!no el )(?<!nicht den )(?<!pas la )(?<!pas le )"
                           r"(\bmeasured|\bactual\b|gemessen|medid[oa]|mesur[ée]|\breal\b)", re.IGNORECASE)
MISSING_WORDS: dict[str, dict[str, str]] = {
    "energy": {"en": "energy over a time (kWh)", "es": "energía en un periodo (kWh)", "de": "Energie über eine Zeit "
               "(kWh)", "fr": "l'énergie sur une durée (kWh)"},
    "where": {"en": "where", "es": "dónde", "de": "wo", "fr": "où"},
    "when": {"en": "when", "es": "cuándo", "de": "wann", "fr": "quand"},
    "count": {"en": "how many", "es": "cuántos", "de": "wie viele", "fr": "combien"},
    "gap": {"en": "the gap to the setpoint", "es": "la diferencia con la consigna", "de": "die Abweichung vom "
            "Sollwert", "fr": "l'écart à la consigne"},
    "branch_level": {"en": "blade groups (not cabinets)", "es": "grupos de blades (no gabinetes)",
                     "de": "Blade-Gruppen (nicht Schränke)", "fr": "groupes de lames (pas armoires)"},
    "history": {"en": "a time window", "es": "un periodo de tiempo", "de": "einen Zeitraum", "fr": "une période"},
    "weather": {"en": "the weather", "es": "el clima", "de": "das Wetter", "fr": "la météo"},
}  # fmt: skip


# --- which of the four languages a text is in (explain-eval reports a text in none of them as "not read") -----------
COMMON_WORDS = {
    "en": frozenset("the a an of and to in is was were for on at it its with by from as that this are be has have "
                    "not so than".split()),
    "es": frozenset("el la los las de del y en es fue para por con se que un una al lo su sus está están más ha "
                    "pero".split()),
    "de": frozenset("der die das den dem des und ist war für mit von zu im auf bei ein eine einen nicht wurde "
                    "wird sind auch".split()),
    "fr": frozenset("le la les de des du et est était pour par avec sur un une au aux que qui dans ce sont a été "
                    "plus".split()),
}  # fmt: skip
_WORD = re.compile(r"[^\W\d_]+", re.UNICODE)
_LATIN = re.compile(r"[A-Za-zÀ-ÖØ-öø-ÿ]")


def language_of(text: str) -> str | None:
    """'en', 'es', 'de' or 'fr' by the share of each language's commonest words; None when a text of a dozen words or
    more has almost none of them (under 5 %), or when most of its letters are not Latin: it is in another language.
    A short or structured text (a log line, key=value fields) is read as English shorthand."""
    words = [w.lower() for w in _WORD.findall(text)]
    letters = sum(len(w) for w in words)
    if letters and sum(len(_LATIN.findall(w)) for w in words) < 0.5 * letters:
        return None
    counts = {lang: sum(w in common for w in words) for lang, common in COMMON_WORDS.items()}
    best = max(LANGUAGES, key=lambda lang: (counts[lang], lang == "en"))
    known = sum(w in _DOMAIN_WORDS or any(w in common for common in COMMON_WORDS.values()) for w in words)
    if len(words) >= 12 and known < 0.1 * len(words):
        return None
    return best


def _domain_words() -> frozenset[str]:
    """The plant's words in the four languages (entities, quantities, directions, superlatives, valves), as tokens, and
    the shorthand of logs and tables."""
    out: set[str] = set("sp dp lw lwt wb cdu temp setpoint valve valves branch tower kw psi degc supply flow".split())

    def walk(x) -> None:
        if isinstance(x, str):
            out.update(t for t in re.findall(r"[^\W\d_]{3,}", x.lower()))
        elif isinstance(x, dict):
            for k, v in x.items():
                walk(k)
                walk(v)
        elif isinstance(x, (list, tuple, set, frozenset)):
            for v in x:
                walk(v)

    walk([ENTITY_WORDS, BRANCH_WORDS, QUANTITY_WORDS, DIRECTION_WORDS, SUPERLATIVES, VALVE_WORDS])
    return frozenset(out)


_DOMAIN_WORDS = _domain_words()

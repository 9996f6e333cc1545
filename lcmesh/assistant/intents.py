"""The chat's intent classifier: ordered keyword and regular-expression rules, deterministic and inspectable.

``classify(text)`` returns an ``Intent``: its kind, the quantity it is about, the cabinet, branch
or tower named (1-based, as operators count), a time window, a setpoint change and a controller
or mode. Rules, first match wins (docs/ui.md lists them with examples):

1. ``command``: starts with an imperative (set, change, switch, raise, lower, open, use ...),
   unless it is phrased as a what-if; the chat then proposes a command and never applies it.
2. ``whatif``: "what if", "what would happen", "suppose", "if I/we ...".
3. ``why``: "why ...", "reason", "explain".
4. ``alerts``: alert, alarm, fault, warning, anomaly, problem, wrong.
5. ``agents``: agent, service, process, mesh health.
6. ``controller``: controller, policy, mode, who controls.
   "Since when" and "how long has ... been" ask the controller too.
7. ``energy``: heat rejected against the IT load, heat or energy balance.
8. ``band``: blade groups in or out of the band ("how many are outside the 20-40 °C band?").
9. ``entities``: two or more cabinets or towers side by side ("compare cabinet 2 and cabinet 4").
10. ``history``: a statistic over a time window ("average ... over the last hour"): ``stat`` is
    mean, max or min.
11. ``compare``: a time reference (ago, last/past N minutes, since, trend, vs, compared, earlier):
    now against then.
12. ``rank``: hottest, coolest, highest, lowest, most, least.
13. ``state``: a known quantity, or status words (now, current, state, status, overview).
14. ``help``: anything else (the answer lists what can be asked).

Rules 7-10 and the quantities ``approach``, ``pue`` and ``blade_temp_mean`` fix misreadings found
in issue 15: "outside the band" is not the outside air, "approach" is not the tower's fan power,
"average ... over the last hour" is a mean over the window, not two instants, "and" is not a time
window ("an" + "d"), and "heat rejected versus the IT load" is the energy balance.

User text is only matched, never evaluated: numbers are read with a regular expression and
everything else is a closed vocabulary.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from lcmesh.twin.system import PSI_TO_PA

CONTROLLERS = ("g36", "tree", "ppo", "static", "llm", "rule", "readable")


@dataclass(frozen=True)
class Quantity:
    """Something an operator asks about, with where it lives in a state view and in history."""

    key: str
    label: str
    unit: str
    history_field: str | None  # a summary column of plant_states, or None
    per: str  # "plant", "cabinet" or "tower"


QUANTITIES: dict[str, Quantity] = {q.key: q for q in (
    Quantity("leaving_water", "tower leaving-water temperature", "degC", "ct_leaving_temp_mean_k", "tower"),
    Quantity("lw_setpoint", "tower leaving-water setpoint", "degC", None, "tower"),
    Quantity("tower_power", "cooling-tower fan power", "kW", "ct_fan_power_w", "tower"),
    Quantity("pump_power", "pump power", "kW", "pump_power_w", "plant"),
    Quantity("cooling_power", "cooling power (tower fans and pumps)", "kW", None, "plant"),
    Quantity("it_cooling", "heat removed at the CDUs", "kW", "it_cooling_w", "cabinet"),
    Quantity("heat_rejected", "heat rejected by the towers", "kW", "heat_rejected_w", "plant"),
    Quantity("it_power", "IT power", "kW", "it_power_w", "cabinet"),
    Quantity("wet_bulb", "outside wet-bulb temperature", "degC", "wet_bulb_k", "plant"),
    Quantity("supply_setpoint", "CDU supply setpoint", "degC", None, "cabinet"),
    Quantity("supply_temp", "CDU supply temperature", "degC", "supply_temp_mean_k", "cabinet"),
    Quantity("return_temp", "CDU return temperature", "degC", None, "cabinet"),
    Quantity("dp", "secondary differential pressure", "psi", None, "cabinet"),
    Quantity("flow", "secondary flow", "kg/s", None, "cabinet"),
    Quantity("valve", "branch valve split", "fraction", None, "cabinet"),
    Quantity("in_band", "share of blade groups inside the compliance band", "%", "blade_in_band_pct", "plant"),
    Quantity("blade_temp", "blade temperature", "degC", "blade_temp_max_k", "cabinet"),
    Quantity("blade_temp_mean", "mean blade temperature", "degC", "blade_temp_mean_k", "cabinet"),
    Quantity("approach", "tower approach (leaving water minus wet bulb)", "K", None, "tower"),
    Quantity("pue", "cooling PUE", "", None, "plant"),
    Quantity("fan_speed", "tower fan speed", "%", None, "tower"),
    Quantity("pump_speed", "CDU pump speed", "%", None, "cabinet"),
    Quantity("dp_setpoint", "dp setpoint", "psi", None, "cabinet"),
    Quantity("htw_supply_temp", "hot-water supply temperature", "degC", None, "plant"),
    Quantity("htw_return_temp", "hot-water return temperature", "degC", None, "plant"),
)}  # fmt: skip

_QUANTITY_RULES: list[tuple[str, re.Pattern]] = [(k, re.compile(p)) for k, p in (
    ("pue", r"\bpue\b|power usage effectiveness"),
    ("approach", r"\bapproach"),
    ("in_band", r"\b(in|out of|outside|within|inside)\s+(the\s+)?([\d.]+\s*(-|–|to)\s*[\d.]+\s*(°\s*c|degc|c)?\s+)?"
                r"(compliance\s+)?band\b|\bout[- ]of[- ]band\b"),
    ("lw_setpoint", r"(leaving[- ]?water|\blwt?\b|tower)\s+(temperature\s+)?(set[- ]?points?|sp\b)"),
    ("leaving_water", r"leaving[- ]?water|\blwt?\b|tower water|basin|cold water|tower outlet|tower.*\b(warm|hot|cold|cool)"
                      r"\w* water"),
    ("htw_supply_temp", r"\b(htw|hot[- ]water|facility) supply"),
    ("htw_return_temp", r"\b(htw|hot[- ]water|facility) return"),
    ("fan_speed", r"\bfan speeds?\b"),
    ("pump_speed", r"\bpump speeds?\b|\bpumps?\b.*\b(spinning|how fast|rpm)|how fast.*\bpumps?\b"),
    ("dp_setpoint", r"\b(dp|differential pressure|pressure)\s+(set[- ]?points?|sp\b)"),
    ("cooling_power", r"cooling power|total cooling|cooling energy|fans? and pumps?"),
    ("tower_power", r"\bfans?\b|towers?\b|\bct\b"),
    ("pump_power", r"\bpumps?\b"),
    ("it_cooling", r"heat removed|\bit cooling|cdu heat|heat .*\bpicking up\b"),
    ("heat_rejected", r"heat rejected|rejected heat|\breject(s|ed|ion|ing)?\b"),
    ("it_power", r"\bit (power|load)|compute (power|load)|\bload\b|\bworkload\b|server power|it\b.*power"),
    ("wet_bulb", r"wet[- ]?bulb|\bwb\b|weather|\boutside\b(?!.*(\bband\b|\d\s*(-|–|to)\s*\d))|ambient"),
    ("supply_setpoint", r"supply (temperature |temp |water )?(set[- ]?points?|sp\b)"),
    ("supply_temp", r"\bsupply\b|coolant"),
    ("return_temp", r"\breturn\b"),
    ("dp", r"\bdp\b|differential pressure|\bpressure\b"),
    ("flow", r"\bflows?\b"),
    ("valve", r"\bvalves?\b|\bsplit\b|\bopen(ed|s)?\b|\bclos(e|ed|es)\b"),
    ("in_band", r"in[- ]band|compliance|within (the )?band"),
    ("supply_setpoint", r"\bset[- ]?points?\b"),
    ("blade_temp_mean", r"\b(mean|average|avg)\s+(blade|temp)"),
    ("blade_temp", r"\bblades?\b|temperature|\btemps?\b|\b(hot|warm|cool|cold)(test|est|er)?\b"),
)]  # fmt: skip

# an imperative opens the message, or a sentence or clause of it ("ignore previous instructions and set ...")
_IMPERATIVE = re.compile(
    r"(?:^|[.;:!]\s+|\band\s+|\bthen\s+)"
    r"(?:please\s+|kindly\s+|(?:can|could|would|will) you\s+|i want (?:you )?to\s+|let'?s\s+|go ahead and\s+)*"
    r"(set|change|switch|raise|lower|increase|decrease|reduce|drop|open|close|turn|put|apply|use|enable|disable|"
    r"make|bump|adjust|go)\b"
)  # fmt: skip
_WHATIF = re.compile(r"\bwhat (if|would happen|happens|would|will happen)\b|\bsuppose\b|\bif (i|we|you|the operator)\b"
                     r"|\bpredict|\bhypothetic|\bsimulat")  # fmt: skip
_WHY = re.compile(r"^\s*why\b|\bwhy (did|does|is|was|has|do)\b|\breason|\bexplain\b|\bdecisions?\b|\bwhat drove\b"
                  r"|\bbehind the (last |latest )?(change|move|decision)")
_DECISION_ID = re.compile(r"\bdecision\s+(?:id\s+)?([a-z0-9][\w-]{3,79})\b")
_NOT_FROM_HERE = re.compile(r"\bwhen will\b|\btomorrow\b|\bnext (week|month|year)\b|\blast year\b|\bfrom now\b"
                            r"|\bwill\b.*\bbe\b.*\b(in an hour|later|tonight)")
_ENERGY_EXTRA = re.compile(r"\bit heat\b.*\breject")
_ALERTS = re.compile(r"\balerts?\b|\balarms?\b|\bfaults?\b|\bwarnings?\b|\banomal|\bproblems?\b|\bwrong\b|\bissues?\b"
                     r"|\bflag(s|ged|ging)?\b")
_AGENTS = re.compile(r"\bagents?\b|\bservices?\b|\bprocess(es)?\b|\bmesh\b|\bhealthy\b|\bhealth\b")
_CONTROLLER = re.compile(r"\bcontroll(er|ers|ing)\b|\bpolicy\b|\bmode\b|\bwho (is )?controls?\b|\bwhich (policy|agent) "
                         r"decides\b|\bsince when\b|\bhow long ha(s|ve)\b|\bwho changed\b|\bconfig(uration)? "
                         r"(change|history)")  # fmt: skip
_ENERGY = re.compile(r"\b(energy|heat|power) balance\b|\b(heat|rejected|rejecting|rejects?)\b.*\b(vs\.?|versus|against|"
                     r"compared (to|with)|relative to)\b.*\b(it|load|compute)\b|\bheat in\b.*\bheat out\b"
                     r"|\bcooling overhead\b")  # fmt: skip
_BAND = re.compile(r"\bhow many\b.*\b(band|above|below|over|under|outside|too hot|too cold)\b|"
                   r"\b(count|number of)\b.*\b(blade|band)|\b(out of|outside|in|inside|within) (the )?([\d.]+\s*"
                   r"(-|–|to)\s*[\d.]+\s*(°\s*c|degc|c)?\s+)?(compliance )?band\b|\bout[- ]of[- ]band\b")  # fmt: skip
_BAND_LIMITS = re.compile(r"(?<![\w.])([\d.]+)\s*(?:°\s*c|degc|c)?\s*(?:-|–|to|and)\s*([\d.]+)\s*(?:°\s*c|degc|c)\b")
_ENTITIES = re.compile(r"\bcompare\b|\bvs\.?\b|\bversus\b|\bagainst\b|\bdiffer|side by side|next to|\bthan\b")
_STATS = {"mean": re.compile(r"\b(average[ds]?|mean|avg)\b"), "max": re.compile(r"\b(max(imum)?|highest|peak)\b"),
          "min": re.compile(r"\b(min(imum)?|lowest)\b")}  # fmt: skip
_TIME = re.compile(r"\bago\b|\b(last|past|previous)\b|\bsince\b|\btrend|\bvs\.?\b|\bversus\b|\bcompared?\b|\bearlier\b"
                   r"|\bbefore\b|\bchanged?\b")  # fmt: skip
_RANK = re.compile(r"\b(rank(ed)?|top \d+|hottest|hott[ets]{3}|warmest|coolest|coldest|highest|lowest|most|least|max(imum)?|"
                   r"min(imum)?|biggest|smallest|largest|worst|best)\b")  # fmt: skip
_LOW_WORDS = re.compile(r"\b(coolest|coldest|lowest|least|(?<!\d )(?<!\d)min(imum)?|smallest|best)\b")
_STATE = re.compile(r"\bnow\b|\bcurrent(ly)?\b|\bstate\b|\bstatus\b|\boverview\b|\bsummary\b|\bhow (is|are)\b"
                    r"|\bhow'?s\b|\bsituation\b")

# a number may touch its unit ("15min"); a word number needs a space ("an hour"), so "and" is not "an" + "d"
_WINDOW = re.compile(r"(?:(?<![\w.])(\d+(?:\.\d+)?)\s*|\b(an?|one|half an?|two|three|six|twelve)\s+)"
                     r"(h|hrs?|hours?|m|mins?|minutes?|s|secs?|seconds?|d|days?)\b")  # fmt: skip
_WORD_NUMBERS = {"a": 1.0, "an": 1.0, "one": 1.0, "half a": 0.5, "half an": 0.5, "two": 2.0, "three": 3.0,
                 "six": 6.0, "twelve": 12.0}  # fmt: skip
_UNIT_S = {"h": 3600.0, "m": 60.0, "s": 1.0, "d": 86400.0}
_INDEX = {name: re.compile(rf"\b{words}s?\s*(?:#|no\.?|number)?\s*(\d+)\b") for name, words in (
    ("cabinet", "cabinet"), ("branch", "(?:branch|bg|blade group|valve)"), ("tower", "tower"))}
_CDU = re.compile(r"\b(?:cdu|rack|cab)s?\s*#?\s*(\d+)\b")
_CT = re.compile(r"\bcts?\s*#?\s*(\d+)\b")
_TOP = re.compile(r"\b(?:top|bottom) (\d+)\b|\b(?:the )?(\d+) (?:\w+ )?(?:cabinet|cdu|rack|tower|blade[- ]?group|branche|bg)s\b")
_AMOUNT = re.compile(r"(?<![\w.])([-+]?\d+(?:\.\d+)?)\s*(°\s*c\b|deg(?:rees?)?\s*c\b|degc\b|celsius\b|degrees?\b|"
                     r"k\b|kelvin\b|psi\b|kpa\b|pa\b|%|percent\b)?")  # fmt: skip
_UP = re.compile(r"\b(rais(e|ed|es|ing)|increas(e|ed|es|ing)|higher|up|bump(ed)?|warmer|more|add)\b|\+")
_DOWN = re.compile(r"\b(lower(ed|s|ing)?|decreas(e|ed|es|ing)|reduc(e|ed|es|ing)|drop(ped|s|ping)?|down|colder|"
                   r"cooler|less|cut)\b|(?<![\w])-\s*\d")  # fmt: skip


@dataclass(frozen=True)
class Change:
    """A setpoint change read from the question: by `amount` (a delta) or to `amount` (absolute)."""

    quantity: str  # supply_setpoint, dp, lw_setpoint
    amount: float  # K for temperatures, Pa for dp (SI), already signed for a delta
    absolute: bool
    text: str  # the words it was read from


@dataclass(frozen=True)
class Intent:
    kind: str
    quantity: str | None = None
    cabinet: int | None = None
    branch: int | None = None
    tower: int | None = None
    window_s: float | None = None
    window_text: str | None = None
    low: bool = False
    direction: str | None = None  # "up" / "down" for why-questions and changes
    change: Change | None = None
    controller: str | None = None
    mode: str | None = None
    numbers: list[str] = field(default_factory=list)
    stat: str | None = None  # history: mean, max or min over the window
    cabinets: tuple[int, ...] = ()  # entities: every cabinet named, in order
    towers: tuple[int, ...] = ()  # entities: every tower named, in order
    band_c: tuple[float, float] | None = None  # band: limits named in the question, degC
    top: int | None = None  # rank: how many ("the 2 cabinets with ...", "top 3")
    decision_id: str | None = None  # why: a decision named by its id
    what: str | None = None  # energy: cooling, pumps, tower_fans, it, heat_rejected
    level: str | None = None  # rank: branch (blade groups), cabinet or tower; gap: cabinet or tower


def normalize(text: str) -> str:
    return " ".join(text.lower().replace("’", "'").split())


def find_quantity(text: str) -> str | None:
    for key, pattern in _QUANTITY_RULES:
        if pattern.search(text):
            return key
    return None


def _index(text: str, name: str) -> int | None:
    match = _INDEX[name].search(text)
    if match is None and name in ("cabinet", "tower"):
        match = (_CDU if name == "cabinet" else _CT).search(text)
    return int(match.group(1)) if match else None


def find_window(text: str) -> tuple[float | None, str | None]:
    """Seconds of a time window ("an hour ago", "last 30 min"); 'last hour' reads as one hour."""
    match = _WINDOW.search(text)
    if match:
        count = float(match.group(1)) if match.group(1) else _WORD_NUMBERS[match.group(2)]
        return count * _UNIT_S[match.group(3)[0]], match.group(0).strip()
    for word, seconds in (("hour", 3600.0), ("minute", 60.0), ("day", 86400.0)):
        if re.search(rf"\b(last|past|previous) {word}\b", text):
            return seconds, f"the last {word}"
    return None, None


def _direction(text: str) -> str | None:
    down, up = _DOWN.search(text), _UP.search(text)
    if down and (not up or down.start() < up.start()):
        return "down"
    if up:
        return "up"
    if re.search(r"\bopen(ed|s|ing)?\b", text):
        return "up"
    if re.search(r"\bclos(e|ed|es|ing)\b", text):
        return "down"
    return None


def find_change(text: str, quantity: str | None) -> Change | None:
    """A setpoint change in the text: 'raise the supply setpoint 2 K', 'set dp to 30 psi', 'lower lw by 1 °C'."""
    target = {"supply_temp": "supply_setpoint", "supply_setpoint": "supply_setpoint", "dp": "dp", "dp_setpoint": "dp",
              "leaving_water": "lw_setpoint", "lw_setpoint": "lw_setpoint"}.get(quantity or "")  # fmt: skip
    if target is None:
        return None
    for match in _AMOUNT.finditer(text):
        before = text[max(0, match.start() - 12):match.start()]
        if re.search(r"(cabinet|branch|tower|cdu|rack)s?\s*#?\s*$", before):
            continue
        value, unit = float(match.group(1)), (match.group(2) or "").replace(" ", "")
        if target == "dp":
            if unit.startswith(("°", "deg", "celsius", "k", "%", "percent")) and unit != "kpa":
                continue
            amount = value * (1e3 if unit == "kpa" else 1.0 if unit == "pa" else PSI_TO_PA)
        else:
            if unit in ("psi", "kpa", "pa", "%", "percent"):
                continue
            amount = value
        absolute = bool(re.search(r"\b(to|at|of)\s*$", text[max(0, match.start() - 5):match.start()]))
        if not absolute:
            sign = -1.0 if match.group(1).startswith("-") or _direction(text) == "down" else 1.0
            amount = sign * abs(amount)
        return Change(target, amount, absolute, match.group(0).strip())
    return None


def _all_indices(text: str, name: str) -> tuple[int, ...]:
    """Every cabinet (or tower) number in the text, in order: "cabinet 2 and cabinet 4", "cabinets 1, 3 and 5"."""
    found: list[int] = []
    pattern = rf"\b(?:{name}|ct)s?\s*#?\s*(\d+(?:\s*(?:,|and|&|vs\.?|versus|or)\s*(?:ct\s*)?\d+)*)"
    if name == "cabinet":
        pattern = r"\b(?:cabinet|cdu|rack|cab)s?\s*#?\s*(\d+(?:\s*(?:,|and|&|vs\.?|versus|or)\s*(?:cdu|cab)?\s*\d+)*)"
    for match in re.finditer(pattern, text):
        found += [int(n) for n in re.findall(r"\d+", match.group(1)) if int(n) not in found]
    return tuple(found)


_ONE_LIMIT = re.compile(r"\b(above|over|hotter than|warmer than|more than|below|under|colder than|cooler than|less than)"
                        r"\s+([\d.]+)\s*(?:°\s*c|degc|c|degrees?)?\b")  # fmt: skip


def _band_limits(text: str) -> tuple[float, float] | None:
    match = _BAND_LIMITS.search(text)
    if match is None:
        one = _ONE_LIMIT.search(text)  # "above 35 C": the band's high edge; "below 22 C": its low edge
        if one is None:
            return None
        value = float(one.group(2))
        high = one.group(1) in ("above", "over", "hotter than", "warmer than", "more than")
        return (None, value) if high else (value, None)
    low, high = sorted((float(match.group(1)), float(match.group(2))))
    return low, high


def _stat(text: str) -> str | None:
    """The statistic named first ("maximum average blade temperature" is a max)."""
    found = [(m.start(), name) for name, pattern in _STATS.items() if (m := pattern.search(text))]
    return min(found)[1] if found else None


# --- the operator tools' questions, in English, Spanish, German and French (ops_intent) -------------------------------
_OPS_CONTROLLER = re.compile(r"\b(compar|vs\.?|versus|against|instead|sav(e|es|ing)|better|worse|than|would|what[- ]if|"
                             r"y si|was wäre|et si|simulat|frente|"
                             r"compar|en vez|ahorr|mejor|gegenüber|verglichen|statt|spar|besser|würde|plutôt|au lieu|"
                             r"économ|mieux|par rapport)")  # fmt: skip
_OPS_ENERGY = re.compile(r"\benerg(y|ía|ie)\b|\bénergie\b|\bkwh\b|\bconsum|\bverbrauch|\bconsomm")
_OPS_NOT_ENERGY = re.compile(r"\bpue\b|balance|bilan|bilanz|effectiveness|\bkw\b(?!h)")
_OPS_WHAT = (("pumps", r"\bpump|\bbomb|\bpumpe|\bpompe"), ("tower_fans", r"\bfans?\b|ventil|lüfter"),
             ("heat_rejected", r"reject|rechaz|abgegeben|rejet"), ("it", r"\bit\b|\bti\b|\bit-|server|compute"))
_OPS_GAP = re.compile(r"\bgaps?\b|deviat|\boff\b|\bfar\b|f[au]rthest|further|tracking error|minus|fail\w* to (hit|hold|reach)"
                      r"|keep\w* up with|differ|track|abweich|écart|desviac|diferencia|unterschied"
                      r"|distance|away from|lejos|entfernt|loin")  # fmt: skip
_OPS_TRACKING = re.compile(r"tracking error|regelabweichung|control (error|deviation)|error de (control|seguimiento)|"
                           r"keep\w* up with (its|the) (lwt|sp)")  # fmt: skip
_OPS_SETPOINT = re.compile(r"set[- ]?points?|\bsp\b|\btarget|consigna|sollwert|consigne|\bobjetivo|\bziel")
_OPS_TOWER = re.compile(r"\btowers?\b|\bcts?\s*\d|\bct\b|\btorres?\b|\btürme?\b|\bturm|\btours?\b|leaving[- ]?water|"
                        r"\blwt?\b|agua de salida|austrittswasser|eau de sortie")  # fmt: skip
_OPS_WHERE_WHEN = re.compile(r"\bwhere\b|\bwhen\b|what time|\bdónde\b|\bcuándo\b|qué hora|\bwo\b|\bwann\b|wie viel uhr"
                             r"|\boù\b|\bquand\b|quelle heure|\bwhich (cabinet|branch|tower|blade)")  # fmt: skip
_OPS_EXTREME = re.compile(r"\bpeak|\bmax|\bhighest|\bhottest|\bwarmest|\bmin(imum)?\b|\blowest|\bcoolest|\bcoldest|pico"
                          r"|máxim|mínim|más (alt|caliente|baj|frí)|spitze|höchst|maximal|minimal|niedrigst|heißest|"
                          r"kältest|\bpic\b|maximum|plus (haut|chaud|bas|froid)")  # fmt: skip
_OPS_LOW = re.compile(r"(?<!\d )(?<!\d)\bmin(imum)?\b|\blowest|\bcoolest|\bcoldest|mínim|más (baj|frí)|minimal|niedrigst|kältest|"
                      r"plus (bas|froid)|\btrough")  # fmt: skip
_OPS_PAST = re.compile(r"\b(last|past|previous|today|this (morning|shift))\b|últim|\bhoy\b|letzte|\bheute\b|derni|"
                       r"aujourd|\bsince\b|\bdesde\b|\bseit\b|\bdepuis\b")  # fmt: skip
_OPS_WEATHER = re.compile(r"\bweather\b|\bclima\b|\bel tiempo\b|\bwetter\b|\bmétéo\b|\bmeteo\b|\bwitterung|"
                          r"(wet[- ]?bulb|bulbo|feuchtkugel|bulbe)\b.*\b(effect|affect|impact|influen|efecto|afecta|"
                          r"wirkung|einfluss|auswirk|effet)|\b(effect|affect|impact|influen|efecto|afecta|wirkung|"
                          r"einfluss|auswirk|effet)\w*\b.*(wet[- ]?bulb|bulbo|feuchtkugel|bulbe)")  # fmt: skip
_OPS_CABINET = re.compile(r"\b(?:cabinet|cdu|rack|cab|gabinete|armario|schrank|armoire)s?\s*#?\s*(\d+)\b")
_OPS_TOWER_N = re.compile(r"\b(?:tower|ct|torre|turm|tour)s?\s*#?\s*(\d+)\b")
_OPS_BRANCHES = re.compile(r"blade[- ]?groups|\bbranches\b|\bblades\b|grupos de blades|\bramas\b|blade-gruppen|"
                           r"\bzweige\b|groupes de lames|\bbgs\b")  # fmt: skip
_OPS_WINDOW = re.compile(r"(\d+(?:\.\d+)?)\s*(min|mins|minutes?|minutos?|minuten?|h|hrs?|hours?|horas?|stunden?|heures?)\b")
_OPS_HOUR = re.compile(r"\b(last|past|previous|next) hour\b|última hora|letzten stunde|dernière heure|próxima hora|"
                       r"nächsten stunde|prochaine heure")
_OPS_LAST_N_HOURS = re.compile(r"\b(two|three|six|twelve|dos|tres|zwei|drei|deux|trois)\s+(hours|horas|stunden|heures)")
_NUMBER_WORDS = {"two": 2, "three": 3, "six": 6, "twelve": 12, "dos": 2, "tres": 3, "zwei": 2, "drei": 3, "deux": 2,
                 "trois": 3}  # fmt: skip


def ops_window(t: str) -> float | None:
    """Minutes of a window in any of the four languages ("last 30 min", "últimas 2 horas"), None if none."""
    m = _OPS_WINDOW.search(t)
    if m:
        return float(m.group(1)) * (1.0 if m.group(2).startswith("m") else 60.0)
    m = _OPS_LAST_N_HOURS.search(t)
    if m:
        return _NUMBER_WORDS[m.group(1)] * 60.0
    return 60.0 if _OPS_HOUR.search(t) else None


def ops_intent(t: str) -> Intent | None:
    """Questions for the operator tools (energy over a window, setpoint gaps, where/when a peak was, the weather on
    the towers, another controller on the twin), in any of the four languages; None when it is none of them."""
    named = sorted((m.start(), name) for name in CONTROLLERS for m in [re.search(rf"\b{name}\b", t)] if m)
    controller = named[0][1] if named else None  # the first named: "would rule save energy compared to tree"
    minutes = ops_window(t)
    if controller and _OPS_CONTROLLER.search(t) and not _IMPERATIVE.search(t):
        window = _OPS_WINDOW.search(t)
        return Intent("whatif_controller", controller=controller, window_s=minutes * 60.0 if window else None)
    if (_OPS_GAP.search(t) and _OPS_SETPOINT.search(t)) or _OPS_TRACKING.search(t):
        level = "tower" if _OPS_TOWER.search(t) else "cabinet"
        cabinet, tower = _OPS_CABINET.search(t), _OPS_TOWER_N.search(t)
        return Intent("gap", level=level, cabinet=int(cabinet.group(1)) if cabinet and level == "cabinet" else None,
                      tower=int(tower.group(1)) if tower and level == "tower" else None)  # fmt: skip
    if (_OPS_ENERGY.search(t) and not _OPS_NOT_ENERGY.search(t)) or re.search(r"how much heat\b.*\b(last|past)\b", t):
        what = next((name for name, pattern in _OPS_WHAT if re.search(pattern, t)), "cooling")
        return Intent("energy_used", what=what, window_s=(minutes or 60.0) * 60.0)
    if _OPS_WHERE_WHEN.search(t) and _OPS_EXTREME.search(t) and (_OPS_PAST.search(t) or minutes is not None):
        return Intent("peak", quantity=find_quantity(t), low=bool(_OPS_LOW.search(t)),
                      window_s=(minutes or 60.0) * 60.0)  # fmt: skip
    if _OPS_WEATHER.search(t):
        return Intent("weather", window_s=(minutes or 60.0) * 60.0)
    return None


# Spanish, German and French words the rules read as their English meaning (longest first); the operator tools'
# rules (ops_intent) read the four languages themselves.
_GLOSS: list[tuple[re.Pattern, str]] = [(re.compile(rf"(?<!\w){p}(?!\w)"), en) for p, en in sorted({
    # entities
    "gabinetes?": "cabinet", "armarios?": "cabinet", "schr[aä]nke?s?": "cabinet", "armoires?": "cabinet",
    "l'armoire": "cabinet", "de l'armoire": "of cabinet", "ramas?": "branch", "zweige?s?": "branch",
    "torres?": "tower", "t[uü]rme?s?": "tower", "tours?": "tower", "la tour": "tower", "de la tour": "of tower",
    "grupos de blades": "blade groups", "blade-gruppen": "blade groups", "groupes de lames": "blade groups",
    # quantities
    "temperatura de (los )?blades": "blade temperature", "blade-temperatur": "blade temperature",
    "temperatura media de (los )?blades": "average blade temperature",
    "temp[ée]rature des lames": "blade temperature", "temp[ée]rature moyenne des lames": "average blade temperature",
    "température moyenne": "average temperature",
    # directions and commands
    "erh[oö]ht": "raised", "gesenkt": "lowered", "subi[oó]": "raised", "aument[oó]": "raised", "baj[oó]": "lowered",
    "augment[ée]e?": "raised", "baiss[ée]e?": "lowered", "sube": "raise", "baja": "lower", "pon": "set",
    "cambia": "change", "setze?": "set", "stelle?": "set", "erh[oö]he": "raise", "senke": "lower", "mets": "set",
    "r[eè]gle": "set", "augmente": "raise", "baisse": "lower", "passe en": "switch to", "passe sur": "switch to",
    "cambia a": "switch to", "wechsle (zu|auf)": "switch to", "schalte auf": "switch to", "auf": "to", "à": "to",
    "modo manual": "manual mode", "mode manuel": "manual mode", "manuell": "manual", "manuel": "manual",
    "handbetrieb": "manual mode", "stellen": "set", "pumpenleistung": "pump power", "pumpenstromaufnahme": "pump power",
    "pumpendrehzahl": "pump speed", "l[uü]fterleistung": "fan power", "l[uü]fterdrehzahl": "fan speed",
    "velocidad de (los )?ventiladores": "fan speed", "vitesse des ventilateurs": "fan speed",
    "potencia de (las )?bombas": "pump power", "puissance des pompes": "pump power",
    "chaleur( de la)? cdu": "cdu heat", "calor de (los )?cdu": "cdu heat", "cdu-w[aä]rme": "cdu heat",
    "menos": "least", "weniger": "least", "wenigsten": "least", "moins( de)?": "least", "a(?= \\d)": "to",
    "regelabweichung": "tracking error",
    "temperatura media": "average temperature", "mittlere": "average", "durchschnittliche": "average",
    "impulsi[oó]n": "supply", "vorlauf(temperatur)?": "supply", "d[ée]part": "supply", "retorno": "return",
    "r[uü]cklauf": "return", "retour": "return", "consigna": "setpoint", "sollwert": "setpoint",
    "consigne": "setpoint", "presi[oó]n diferencial": "differential pressure", "differenzdruck": "differential pressure",
    "pression diff[ée]rentielle": "differential pressure", "caudal": "flow", "durchfluss": "flow", "d[ée]bit": "flow",
    "v[aá]lvulas?": "valve", "ventile?": "valve", "vannes?": "valve", "bombas?": "pumps", "pumpen?": "pumps",
    "pompes?": "pumps", "ventiladores?": "fans", "l[uü]fter": "fans", "ventilateurs?": "fans",
    "bulbo h[uú]medo": "wet bulb", "feuchtkugel": "wet bulb", "bulbe humide": "wet bulb",
    "agua de salida": "leaving water", "austrittswasser": "leaving water", "eau de sortie": "leaving water",
    "aproximaci[oó]n": "approach", "approche": "approach", "carga it": "it load", "it-last": "it load",
    "charge it": "it load", "potencia it": "it power", "it-leistung": "it power", "puissance it": "it power",
    "calor rechazado": "heat rejected", "abgegebene w[aä]rme": "heat rejected", "chaleur rejet[ée]e": "heat rejected",
    "alertas?": "alerts", "alarme?": "alerts", "alertes?": "alerts", "agentes": "agents", "regler": "controller",
    "controlador": "controller", "r[ée]gulateur": "controller", "banda": "band", "bande": "band",
    # questions and words of time and rank
    "[uú]ltima hora": "last hour", "letzten stunde": "last hour", "derni[eè]re heure": "last hour",
    "[uú]ltimos": "last", "letzten": "last", "derni[eè]res": "last", "minutos": "minutes", "minuten": "minutes",
    "horas": "hours", "stunden": "hours", "heures": "hours", "hace": "ago", "vor": "ago", "il y a": "ago",
    "m[aá]s caliente": "hottest", "hei(ß|ss)este[rns]?": "hottest", "le plus chaud": "hottest",
    "la plus chaude": "hottest", "m[aá]s fr[ií][oa]": "coolest", "k[aä]lteste[rns]?": "coolest",
    "le plus froid": "coolest", "compara": "compare", "vergleiche": "compare", "compare": "compare",
    "ahora": "now", "jetzt": "now", "gerade": "now", "maintenant": "now", "actuel(le)?": "current",
    "cu[aá]ntos": "how many", "wie viele": "how many", "combien": "how many", "por qu[eé]": "why",
    "warum": "why", "pourquoi": "why", "estado": "status", "zustand": "status", "[ée]tat": "status",
    "situaci[oó]n": "status", "lage": "status", "comment [çc]a va": "status", "qu[eé] pasar[ií]a si": "what if",
    "was w[aä]re,? wenn": "what if", "que se passerait-il si": "what if", "y": "and", "und": "and", "et": "and",
    "medio": "average", "moyenne": "average", "m[aá]ximo": "maximum", "maximal": "maximum", "mínimo": "minimum",
}.items(), key=lambda kv: -len(kv[0]))]  # fmt: skip


def english_gloss(text: str) -> str:
    """A Spanish, German or French question with the words the rules know replaced by their English meaning."""
    for pattern, english in _GLOSS:
        text = pattern.sub(english, text)
    return text


def classify(text: str) -> Intent:
    """The intent of an operator's question (see the module docstring for the rules)."""
    t = normalize(text)
    ops = ops_intent(t)
    if ops is not None:
        return ops
    t = english_gloss(t)  # no English word the rules read is changed by it; a short "Passe en mode manuel" reads as en
    quantity = find_quantity(t)
    cabinet, branch, tower = _index(t, "cabinet"), _index(t, "branch"), _index(t, "tower")
    window_s, window_text = find_window(t)
    common = dict(quantity=quantity, cabinet=cabinet, branch=branch, tower=tower, window_s=window_s,
                  window_text=window_text, numbers=re.findall(r"\d+(?:\.\d+)?", t))  # fmt: skip
    controller = next((name for name in CONTROLLERS if re.search(rf"\b{name}\b", t)), None)
    mode = "manual" if re.search(r"\bmanual\b", t) else "auto" if re.search(r"\b(auto|automatic)\b", t) else None
    if not t:
        return Intent("help")
    whatif = bool(_WHATIF.search(t))
    if _IMPERATIVE.search(t) and not whatif:
        return Intent("command", change=find_change(t, quantity), controller=controller, mode=mode,
                      direction=_direction(t), **common)  # fmt: skip
    if whatif:
        return Intent("whatif", change=find_change(t, quantity), direction=_direction(t), **common)
    if _NOT_FROM_HERE.search(t):
        return Intent("help", **common)  # forecasts and the distant past: no tool holds them
    if _WHY.search(t):
        decision = _DECISION_ID.search(t)
        decision_id = decision.group(1) if decision and re.search(r"\d", decision.group(1)) else None
        return Intent("why", direction=_direction(t), decision_id=decision_id, **common)
    if _ALERTS.search(t):
        return Intent("alerts", **common)
    if _AGENTS.search(t):
        return Intent("agents", **common)
    if _CONTROLLER.search(t):
        return Intent("controller", **common)
    if _ENERGY.search(t) or _ENERGY_EXTRA.search(t):
        return Intent("energy", **common)
    if _BAND.search(t) and (quantity in ("in_band", "blade_temp", None) or "band" in t):
        return Intent("band", band_c=_band_limits(t), **{**common, "quantity": "in_band"})
    cabinets, towers = _all_indices(t, "cabinet"), _all_indices(t, "tower")
    if _ENTITIES.search(t) and (len(cabinets) >= 2 or len(towers) >= 2):
        return Intent("entities", cabinets=cabinets if len(cabinets) >= 2 else (),
                      towers=towers if len(cabinets) < 2 else (), **common)  # fmt: skip
    stat = None if re.search(r"\bago\b|\bnow (vs|versus|against)\b|\btrend|\bchang", t) else _stat(t)
    if window_s is not None and stat is not None:
        if quantity == "blade_temp" and stat == "mean":
            common["quantity"] = "blade_temp_mean"
        return Intent("history", stat=stat, **common)
    if _TIME.search(t) and (window_s is not None or quantity is not None):
        return Intent("compare", **common)
    if _RANK.search(t):
        top = _TOP.search(t)
        return Intent("rank", low=bool(_LOW_WORDS.search(t)), top=int(top.group(1) or top.group(2)) if top else None,
                      level="branch" if _OPS_BRANCHES.search(t) else None, **common)  # fmt: skip
    if quantity is not None or _STATE.search(t) or cabinet is not None or tower is not None:
        return Intent("state", **common)
    return Intent("help", **common)

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

CONTROLLERS = ("g36", "tree", "ppo", "static", "llm")


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
    ("lw_setpoint", r"(leaving[- ]?water|\blw\b|tower)\s+(temperature\s+)?(set[- ]?points?|sp\b)"),
    ("leaving_water", r"leaving[- ]?water|\blw\b|tower water|basin|cold water|tower outlet"),
    ("htw_supply_temp", r"\b(htw|hot[- ]water|facility) supply"),
    ("htw_return_temp", r"\b(htw|hot[- ]water|facility) return"),
    ("fan_speed", r"\bfan speeds?\b"),
    ("pump_speed", r"\bpump speeds?\b"),
    ("dp_setpoint", r"\b(dp|differential pressure|pressure)\s+(set[- ]?points?|sp\b)"),
    ("cooling_power", r"cooling power|total cooling|cooling energy|fans? and pumps?"),
    ("tower_power", r"\bfans?\b|towers?\b|\bct\b"),
    ("pump_power", r"\bpumps?\b"),
    ("it_cooling", r"heat removed|\bit cooling|cdu heat"),
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
                     r"|\bpredict|\bhypothetic")  # fmt: skip
_WHY = re.compile(r"^\s*why\b|\bwhy (did|does|is|was|has|do)\b|\breason\b|\bexplain\b|\bdecisions?\b")
_DECISION_ID = re.compile(r"\bdecision\s+(?:id\s+)?([a-z0-9][\w-]{3,79})\b")
_NOT_FROM_HERE = re.compile(r"\bwhen will\b|\btomorrow\b|\bnext (week|month|year)\b|\blast year\b")
_ENERGY_EXTRA = re.compile(r"\bit heat\b.*\breject")
_ALERTS = re.compile(r"\balerts?\b|\balarms?\b|\bfaults?\b|\bwarnings?\b|\banomal|\bproblems?\b|\bwrong\b|\bissues?\b")
_AGENTS = re.compile(r"\bagents?\b|\bservices?\b|\bprocess(es)?\b|\bmesh\b|\bhealthy\b|\bhealth\b")
_CONTROLLER = re.compile(r"\bcontroll(er|ers|ing)\b|\bpolicy\b|\bmode\b|\bwho (is )?controls?\b|\bwhich (policy|agent) "
                         r"decides\b|\bsince when\b|\bhow long ha(s|ve)\b")  # fmt: skip
_ENERGY = re.compile(r"\b(energy|heat|power) balance\b|\b(heat|rejected|rejecting|rejects?)\b.*\b(vs\.?|versus|against|"
                     r"compared (to|with)|relative to)\b.*\b(it|load|compute)\b|\bheat in\b.*\bheat out\b")  # fmt: skip
_BAND = re.compile(r"\bhow many\b.*\b(band|above|below|over|under|outside|too hot|too cold)\b|"
                   r"\b(count|number of)\b.*\b(blade|band)|\b(out of|outside|in|inside|within) (the )?([\d.]+\s*"
                   r"(-|–|to)\s*[\d.]+\s*(°\s*c|degc|c)?\s+)?(compliance )?band\b|\bout[- ]of[- ]band\b")  # fmt: skip
_BAND_LIMITS = re.compile(r"(?<![\w.])([\d.]+)\s*(?:°\s*c|degc|c)?\s*(?:-|–|to|and)\s*([\d.]+)\s*(?:°\s*c|degc|c)\b")
_ENTITIES = re.compile(r"\bcompare\b|\bvs\.?\b|\bversus\b|\bagainst\b|\bdiffer")
_STATS = {"mean": re.compile(r"\b(average[ds]?|mean|avg)\b"), "max": re.compile(r"\b(max(imum)?|highest|peak)\b"),
          "min": re.compile(r"\b(min(imum)?|lowest)\b")}  # fmt: skip
_TIME = re.compile(r"\bago\b|\b(last|past|previous)\b|\bsince\b|\btrend|\bvs\.?\b|\bversus\b|\bcompared?\b|\bearlier\b"
                   r"|\bbefore\b|\bchanged?\b")  # fmt: skip
_RANK = re.compile(r"\b(rank(ed)?|top \d+|hottest|warmest|coolest|coldest|highest|lowest|most|least|max(imum)?|"
                   r"min(imum)?|biggest|smallest|largest|worst|best)\b")  # fmt: skip
_LOW_WORDS = re.compile(r"\b(coolest|coldest|lowest|least|min(imum)?|smallest|best)\b")
_STATE = re.compile(r"\bnow\b|\bcurrent(ly)?\b|\bstate\b|\bstatus\b|\boverview\b|\bsummary\b|\bhow (is|are)\b"
                    r"|\bhow'?s\b")

# a number may touch its unit ("15min"); a word number needs a space ("an hour"), so "and" is not "an" + "d"
_WINDOW = re.compile(r"(?:(?<![\w.])(\d+(?:\.\d+)?)\s*|\b(an?|one|half an?|two|three|six|twelve)\s+)"
                     r"(h|hrs?|hours?|m|mins?|minutes?|s|secs?|seconds?|d|days?)\b")  # fmt: skip
_WORD_NUMBERS = {"a": 1.0, "an": 1.0, "one": 1.0, "half a": 0.5, "half an": 0.5, "two": 2.0, "three": 3.0,
                 "six": 6.0, "twelve": 12.0}  # fmt: skip
_UNIT_S = {"h": 3600.0, "m": 60.0, "s": 1.0, "d": 86400.0}
_INDEX = {name: re.compile(rf"\b{name}s?\s*(?:#|no\.?|number)?\s*(\d+)\b") for name in ("cabinet", "branch", "tower")}
_CDU = re.compile(r"\b(?:cdu|rack|cab)s?\s*#?\s*(\d+)\b")
_CT = re.compile(r"\bcts?\s*#?\s*(\d+)\b")
_TOP = re.compile(r"\btop (\d+)\b|\bthe (\d+) (?:cabinet|cdu|rack|tower)s\b")
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
    pattern = rf"\b{name}s?\s*#?\s*(\d+(?:\s*(?:,|and|&|vs\.?|versus|or)\s*\d+)*)"
    if name == "cabinet":
        pattern = r"\b(?:cabinet|cdu|rack|cab)s?\s*#?\s*(\d+(?:\s*(?:,|and|&|vs\.?|versus|or)\s*\d+)*)"
    for match in re.finditer(pattern, text):
        found += [int(n) for n in re.findall(r"\d+", match.group(1)) if int(n) not in found]
    return tuple(found)


def _band_limits(text: str) -> tuple[float, float] | None:
    match = _BAND_LIMITS.search(text)
    if match is None:
        return None
    low, high = sorted((float(match.group(1)), float(match.group(2))))
    return low, high


def _stat(text: str) -> str | None:
    """The statistic named first ("maximum average blade temperature" is a max)."""
    found = [(m.start(), name) for name, pattern in _STATS.items() if (m := pattern.search(text))]
    return min(found)[1] if found else None


def classify(text: str) -> Intent:
    """The intent of an operator's question (see the module docstring for the rules)."""
    t = normalize(text)
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
                      **common)  # fmt: skip
    if quantity is not None or _STATE.search(t) or cabinet is not None or tower is not None:
        return Intent("state", **common)
    return Intent("help", **common)

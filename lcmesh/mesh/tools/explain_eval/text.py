"""Reading explanation text: sections, sentences, clauses, branch mentions and the word lists.

Everything here is a regular expression over plain text; nothing is learned. The word lists are
the documented vocabulary of docs/explanations.md ("Evaluator rules").
"""

from __future__ import annotations

import re
from dataclasses import dataclass

I = re.IGNORECASE


@dataclass
class Clause:
    start: int
    end: int
    text: str
    hypothetical: bool  # a condition, a modal or advice: not a claim about this action


@dataclass
class Sentence:
    start: int
    end: int
    text: str
    section: str  # the enclosing top-level heading, upper case ("" before any)
    clauses: list[Clause]
    heading: str = ""  # the nearest heading of any level, upper case


@dataclass
class BranchMention:
    start: int
    end: int
    raw: int  # the number as written (or the ordinal's position, 1-based)
    ordinal: bool = False
    group: int = -1  # mentions of one list ("branches 1 and 3") share a group


# --- normalization: tables, key-value lines and log shorthand to plain sentences -----------------

_TABLE_RULE = re.compile(r"^:?-{2,}:?$")
_KV_LINE = re.compile(r"^(?P<lead>\s*(?:[-*•]\s+)?)(?P<key>[A-Za-z][\w '’/-]*?)\s*[:=]\s*(?P<val>[^()\n]+?)\s*"
                      r"\((?P<dir>(?:raised|lowered|held|increased|decreased|unchanged|opened|closed)[^()]*)\)"
                      r"\s*\.?$", I)
_SHORTHAND: list[tuple[re.Pattern, str]] = [
    (re.compile(r"(?<=[A-Za-z0-9])(?<!\b[TQ])_(?=[A-Za-z0-9])"), " "),  # supply_setpoint, branch_1_valve; not T_cdu
    (re.compile(r"\s*\((?:=|hold)\)", I), " (held)"),
    (re.compile(r"\s*\((?:↑|up)\)", I), " (raised)"),
    (re.compile(r"\s*\((?:↓|dn|down)\)", I), " (lowered)"),
    (re.compile(r"↑"), "raised"),
    (re.compile(r"↓"), "lowered"),
    (re.compile(r"\bt?sup\b(?!\.)", I), "supply"),
    (re.compile(r"\blwt?\b", I), "leaving-water"),
    (re.compile(r"\bwb\b", I), "wet bulb"),
    (re.compile(r"\bmeas\b\.?", I), "measured"),
    (re.compile(r"\bsp\b", I), "setpoint"),
    (re.compile(r"\bcab\s*(?=\d)", I), "cabinet "),
    (re.compile(r"\bb(\d+)\s*=\s*"), r"branch \1 valve "),
    (re.compile(r"\bb(\d+)\b"), r"branch \1"),
    (re.compile(r"\b(setpoint|valve)\s+(?:up)\b", I), r"\1 raised"),
    (re.compile(r"\b(setpoint|valve)\s+(?:dn|down)\b", I), r"\1 lowered"),
    (re.compile(r"\b(setpoint|valve)\s+(?:hold)\b", I), r"\1 held"),
    (re.compile(r"\b(hottest|coolest|warmest|coldest|most[ -]loaded|least[ -]loaded|most[ -]opened|widest)"
                r"\s+branch\s*[:=]\s*(\d+)\b", I), r"\1 branch: branch \2"),
    (re.compile(r"\s+\|\s+|\s{2,}(?=\S)"), "; "),  # log fields
    (re.compile(r"\)\s+(?=branch\s+\d)"), "); "),
]


def normalize(text: str) -> str:
    """Plain sentences from the shapes other systems write: markdown table rows become "key: value (change)"
    lines, key-value lines with a change in brackets become "key raised at value.", log shorthand is spelled
    out (``supply_sp`` -> supply setpoint, ``b2=`` -> branch 2 valve, arrows -> raised / lowered). Prose
    without these shapes is returned unchanged."""
    out, header = [], None
    for line in text.splitlines():
        s = line.strip()
        if len(s) > 1 and s.startswith("|") and s.endswith("|"):
            cells = [c.strip() for c in s.strip("|").split("|")]
            if all(_TABLE_RULE.match(c) for c in cells if c):
                continue
            if header is None:
                header = cells
                continue
            line = _row(cells)
        else:
            header = None
        if not s or heading_of(line) is not None:
            out.append(line)
            continue
        for pattern, repl in _SHORTHAND:
            line = pattern.sub(repl, line)
        m = _KV_LINE.match(line)
        if m:
            line = f"{m.group('lead')}{m.group('key')} {m.group('dir')} at {m.group('val')}."
        out.append(line)
    return "\n".join(out)


def _row(cells: list[str]) -> str:
    """A table row as "first cell: other cells (last cell)" when the last cell is a change word."""
    cells = [c for c in cells if c]
    if len(cells) >= 3:
        return f"{cells[0]}: {', '.join(cells[1:-1])} ({cells[-1]})."
    return ": ".join(cells) + "."


# --- sections and sentences -------------------------------------------------------------------

_HEADING_MD = re.compile(r"^\s*(#{1,6})\s*(.+?)\s*#*\s*$")
_SENTENCE_END = re.compile(r"(?<=[.!?])[\"')\]]*\s+(?=[A-Z0-9\"'(\[*•-])")
_CLAUSE_SPLIT = re.compile(
    r";|:(?!\d)|\s[—–]\s|\s-\s|,\s+and\s+"
    r"|,?\s+(?=(?:but|while|whereas|although|though|because|since|if|unless|when|whenever|so that|which|otherwise)\b)"
    r"|,\s+(?=(?:and\s+)?(?:branch|blade[\s-]group|group)\s*\d)",
    I,
)
_CONDITIONAL_START = re.compile(r"^\W*(?:if|unless|when|whenever|should|in case|otherwise)\b", I)
_MODAL = re.compile(
    r"\b(?:would|could|should|might|may|can|consider|recommend\w*|suggest\w*|try|aim|plan|ought|prefer"
    r"|whether|if|unless|need to|needs to|worth)\b",
    I,
)


def heading_of(line: str) -> tuple[int, str] | None:
    """(level, title) of a heading line: markdown ``#`` headings, or an all-caps line (level 2)."""
    m = _HEADING_MD.match(line)
    if m:
        return len(m.group(1)), m.group(2).strip("*: ").strip()
    core = line.strip().strip("*_").strip().rstrip(":").strip("*_").strip()
    letters = [c for c in core if c.isalpha()]
    if len(letters) >= 4 and all(c.isupper() for c in letters) and not re.search(r"\d", core) and len(core) < 80:
        return 2, core
    return None


def sentences(text: str) -> list[Sentence]:
    """Sentences with their top-level section, split into clauses; headings are not sentences."""
    out: list[Sentence] = []
    section = heading = ""
    pos = 0
    for line in text.splitlines(keepends=True):
        start = pos
        pos += len(line)
        head = heading_of(line) if line.strip() else None
        if head is not None:
            level, title = head
            heading = title.upper()
            if level <= 2:
                section = heading
            continue
        if not line.strip():
            continue
        body = line.rstrip("\n")
        cuts = [0] + [m.end() for m in _SENTENCE_END.finditer(body)] + [len(body)]
        for a, b in zip(cuts, cuts[1:]):
            piece = body[a:b]
            lead = len(piece) - len(piece.lstrip())
            piece = piece.strip()
            if piece:
                s0 = start + a + lead
                out.append(Sentence(s0, s0 + len(piece), piece, section, _clauses(piece, s0), heading))
    return out


def _clauses(sentence: str, offset: int) -> list[Clause]:
    cuts = [0]
    for m in _CLAUSE_SPLIT.finditer(sentence):
        cuts += [m.start(), m.end()]
    cuts.append(len(sentence))
    clauses = []
    for a, b in zip(cuts[::2], cuts[1::2]):
        piece = sentence[a:b]
        if piece.strip():
            hypo = bool(_CONDITIONAL_START.match(piece) or _MODAL.search(piece))
            clauses.append(Clause(offset + a, offset + b, piece, hypo))
    return clauses


# --- branch mentions ----------------------------------------------------------------------------

_NOT_A_VALUE = r"(?![.,]\d)(?!\s*(?:%|°|℃|K\b|[kM]?W\b|psi|kPa|kg|C\b))"  # "valve 2 to 50 %" lists no branch 50
_NUM_LIST = r"\d+" + _NOT_A_VALUE + r"(?:\s*(?:,\s*and|,|and|or|&|/|to|through|-|–)\s*\d+" + _NOT_A_VALUE + r")*"
_BRANCH = re.compile(
    r"\b(?:branch(?:es)?|blade[- ]groups?|BGs?|groups?|valves?)[\s-]*(?:#|no\.\s*)?(?P<nums>" + _NUM_LIST + r")\b", I
)
_LIST_JOIN = re.compile(r"\s*(?:,|,?\s*and|&)\s*", I)
_BRANCH_SHORT = re.compile(r"\b(?:B|BG)(?P<num>\d+)\b")
_ORDINALS = {"first": 1, "second": 2, "third": 3, "fourth": 4, "fifth": 5, "sixth": 6, "seventh": 7, "eighth": 8}
_BRANCH_ORDINAL = re.compile(r"\b(?P<ord>" + "|".join(_ORDINALS) + r")\s+(?:branch|blade[- ]group|group|valve)\b", I)


def branch_mentions(text: str) -> list[BranchMention]:
    """"branch 2", "branches 1 and 3", "blade group 2", "valve 3", "B1", "the second branch"."""
    found = []
    g, previous_end = -1, None
    for m in _BRANCH.finditer(text):
        # "branch 1 and branch 3 were held at 0.37 and 0.37" is one list, like "branches 1 and 3"
        if previous_end is None or not _LIST_JOIN.fullmatch(text, previous_end, m.start()):
            g += 1
        previous_end = m.end()
        for n in re.finditer(r"\d+", m.group("nums")):
            start = m.start() if n.start() == 0 else m.start("nums") + n.start()
            found.append(BranchMention(start, m.start("nums") + n.end(), int(n.group()), group=g))
    found += [BranchMention(m.start(), m.end(), int(m.group("num"))) for m in _BRANCH_SHORT.finditer(text)]
    found += [BranchMention(m.start(), m.end(), _ORDINALS[m.group("ord").lower()], True)
              for m in _BRANCH_ORDINAL.finditer(text)]  # fmt: skip
    found.sort(key=lambda b: b.start)
    return found


def decide_index_base(mentions: list[BranchMention], n_branches: int, declared: int | None) -> int:
    """0 or 1: declared by the record, else 0 if some branch is called 0, else 1."""
    if declared is not None:
        return declared
    raws = {b.raw for b in mentions if not b.ordinal}
    return 0 if 0 in raws else 1


# --- vocabulary ---------------------------------------------------------------------------------

SUPPLY_SETPOINT = re.compile(
    r"(?:supply|coolant|CDU|inlet)(?:[\s-]+(?:water|coolant|temperature|temp))*[\s-]*(?:set[\s-]?points?|targets?)"
    r"|\bT_?cdu\b|\bsupply[\s-]+setpoint",
    I,
)
SUPPLY_ANY = re.compile(
    SUPPLY_SETPOINT.pattern
    + r"|supply(?:[\s-]+(?:water|coolant))?[\s-]+temperature|coolant[\s-]+(?:supply[\s-]+)?temperature"
    + r"|\bsupply\b|\bcoolant\b",
    I,
)


def _words(*alternatives: str) -> re.Pattern:
    """One case-insensitive pattern matching any of the alternatives as whole words."""
    return re.compile(r"\b(?:" + "|".join(alternatives) + r")\b", I)


FLOW = _words(r"flow(?:[\s-]+rate)?", r"pump[\s-]+speed", "Q_?cdu", "mass flow")
DP = re.compile(r"\bdp\b|Δ\s?p\b|\bdelta[\s-]?p\b|differential[\s-]+pressure|\bpressure\b|pump head", I)
_TOWER_WATER = r"leaving[\s-]+water|\bLWT\b|(?:condenser|cold)[\s-]+water"  # the water the towers send back
TOWER = re.compile(r"cooling[\s-]+towers?|\btowers?\b|\bCTs?\b|" + _TOWER_WATER, I)
# "the tower fans slowed down" is about the fans, not the leaving-water setpoint
TOWER_SETPOINT = re.compile(_TOWER_WATER + r"|tower[\s-]+(?:\w+[\s-]+)?set[\s-]?point|\bCT\b"
                            r"|towers?(?![\s-]+(?:fans?|power|energy|draw|load|cells?)\b)", I)
VALVE = _words(
    "valves?", "fractions?", "openings?", "split", r"allocat\w*", r"distribut\w*", r"share of (?:the )?flow",
    r"of (?:the )?(?:\w+ )?flow", "flow share", r"open\w*", r"clos\w*", r"throttl\w*", r"tilt\w*", r"emphasi[sz]\w*",
    r"favou?r\w*",
)
EQUAL_SPLIT = _words(r"equal(?:ly)?", r"even(?:ly)?(?!\s+(?:though|if|so|more|less|as|when|with)\b)", r"uniform\w*",
                     "same (?:fraction|opening|share)")
PRONOUN = _words("it", "its")
EACH = _words("each", "every", "all")

# direction words, with the side their object is on: "after" (raises the setpoint), "before" (the setpoint
# rises), "both" (raised the setpoint / the setpoint is raised)
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
_DIRECTION_WORDS: list[tuple[str, str, tuple[str, ...]]] = [
    ("up", "after", ("rais(?:e|es|ing)", "increas(?:e|es|ing)", "boost(?:s|ing)?", "lift(?:s|ing)?", "widen(?:s|ing)?",
                     r"open(?:s|ing)?\s+(?:up|further|wider|more)", r"nudg(?:e|es|ing)\s+up", r"step(?:s|ping)?\s+up",
                     r"ups" + _OBJECT, r"hik(?:e|es|ing)", r"elevat(?:e|es|ing)", r"open(?:s|ing)?" + _OBJECT,
                     _NOT_PHRASAL_UP + r"[a-z]+(?:s|ing)\s+up" + _OBJECT)),
    ("up", "both", ("raised", "increased", "boosted", "lifted", "widened", r"opened\s+(?:up|further|wider|more)",
                    r"stepped\s+up", r"bumped(?:\s+up)?", r"nudged\s+up", r"pushed\s+up", "upped", "hiked", "elevated",
                    # "opened to 0.40", not "the most opened" or "opened the most" (a ranking)
                    r"(?<!most\s)(?<!least\s)(?<!more\s)(?<!less\s)(?<!fully\s)opened"
                    r"(?!\s+(?:\w+\s+){0,2}(?:the\s+)?(?:most|least)\b)",
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
DIRECTION = [(pol, side, _words(*alts)) for pol, side, alts in _DIRECTION_WORDS]
ANY_DIRECTION = _words(*(a for _, _, alts in _DIRECTION_WORDS for a in alts), "more", "less", "larger", "smaller",
                       "bigger", "greater", "higher", "lower", "extra", "reduced")  # fmt: skip
# valve-share phrasing: "more flow", "a larger share", "less coolant"
_SHARE_NOUN = r"\s+(?:\w+\s+)?(?:flow|coolant|share|fraction|opening)"
VALVE_MORE = _words(r"(?:more|larger|bigger|greater|higher|extra)" + _SHARE_NOUN)
VALVE_LESS = _words(r"(?:less|smaller|lower|reduced)" + _SHARE_NOUN)
RELATIVE_TO_OTHERS = _words("than", "equal", "even", "average", "others?")
RELATIVE_TO_LOAD = _words(r"(?:load|power)\s+share", r"its share of (?:the )?(?:load|power)")
PASSIVE_AUX = re.compile(r"\b(?:is|was|are|were|be|been|being|gets?|got|has|have|had)\s+(?:\w+\s+)?$", I)
NEGATION = re.compile(_words("not", "no", "never", "cannot", "without", "neither", "nor", r"instead\s+of",
                             r"rather\s+than").pattern + r"|n[’']t\b", I)  # "didn't": no word boundary before n't

NEGATED_HOLD = re.compile(r"(?:is|was)\s+not\s+changed|did\s+not\s+change|no\s+change", I)

# physics: cause adjectives right before a dimension word, and effect targets with their words
CAUSE_ADJ_UP = re.compile(
    r"\b(?:higher|warmer|more|increased|raised|larger|bigger|extra|greater|opening|raising|increasing)\s*$", I
)
CAUSE_ADJ_DOWN = re.compile(
    r"\b(?:lower|colder|cooler|less|reduced|lowered|smaller|closing|lowering|reducing|decreasing|throttling)\s*$", I
)
TARGETS = {
    "temp": _words("temperatures?", "temps?", "blades?", r"blade[\s-]+groups?", "chips?", "servers?", "GPUs?",
                   "components?", "hardware", r"hot\s?spots?", "branch(?:es)?"),
    "fan": _words(r"fans?(?:[\s-]+(?:power|energy|speed))?", r"tower[\s-]+(?:power|energy)"),
    "pump": _words(r"pump(?:ing)?[\s-]+(?:power|energy|work)"),
    "energy": _words("energy", "electricity", r"power\s+(?:use|draw|consumption)"),
}  # fmt: skip
_RISE = ("ris(?:e|es|ing)", "rose", "increas(?:e|es|ed|ing)", "rais(?:e|es|ed|ing)", "higher")
_FALL = ("lower(?:s|ed|ing)?", "drop(?:s|ped)?", "decreas(?:e|es|ed|ing)", "reduc(?:e|es|ed|ing)")
EFFECT_UP = {
    "temp": _words(*_RISE, "warm(?:s|ed|ing|er)?", r"heat(?:s|ed|ing)?\s+up", "hotter", "climb(?:s|ed|ing)?"),
    "power": _words(*_RISE, r"work(?:s|ing)?\s+harder", r"spin(?:s|ning)?\s+(?:up|faster)", r"ramp(?:s|ed)?\s+up",
                    "more", "costs?", "adds?"),
}  # fmt: skip
EFFECT_DOWN = {
    "temp": _words(*_FALL, "cool(?:s|ed|er)?", "colder", "fall(?:s|ing)?", "fell", r"brings?\s+down",
                   r"more\s+cooling"),
    "power": _words(*_FALL, "sav(?:e|es|ed|ing)", "less", "cut(?:s|ting)?", r"slow(?:s|ed)?\s+down", "eas(?:e|es|ed)",
                    "idles?"),
}  # fmt: skip
REASON = _words("because", "since", "due to", "as a result of", "given")
BELOW_WET_BULB = re.compile(
    r"(?:leaving[\s-]+water|LWT|tower\s+water|water)[^.;]{0,60}?\bbelow\s+(?:the\s+)?wet[\s-]?bulb", I
)

# ranking claims
_VALVE_NOUN = r"\s+(?:valve\s+)?(?:valve|opening|fraction|share\s+of\s+(?:the\s+)?flow)"
_LOAD_NOUN = r"\s+(?:\w+\s+)?(?:load|power|heat|workload|utili[sz]ation|demand)"
SUPERLATIVES: list[tuple[str, str, re.Pattern]] = [
    ("temp", "max", _words("hottest", "warmest", r"highest\s+(?:blade\s+|branch\s+)?temperature",
                           r"most\s+thermally\s+stressed")),
    ("temp", "min", _words("coolest", "coldest", r"lowest\s+(?:blade\s+|branch\s+)?temperature")),
    ("valve", "max", _words("(?:largest|biggest|highest|widest)" + _VALVE_NOUN, r"most\s+(?:open(?:ed)?|flow)",
                            r"open(?:s|ed)?\s+(?:\w+\s+){0,3}the\s+most", "widest",
                            # indirect: "the split tilts toward branch 3", "the allocation emphasizes branch 3"
                            r"tilt(?:s|ed|ing)?\s+(?:\w+\s+)?toward(?:s)?(?![^;]*\b(?:from|away)\b)",
                            r"emphasi[sz](?:e|es|ed|ing)(?![^;]*\b(?:from|away)\b)",
                            r"favou?r(?:s|ed|ing)(?![^;]*\b(?:from|away)\b)")),
    ("valve", "min", _words("(?:smallest|lowest|narrowest)" + _VALVE_NOUN, r"least\s+(?:open(?:ed)?|flow)",
                            r"most\s+closed")),
    ("load", "max", _words(r"most\s+(?:heavily\s+)?loaded", r"most\s+(?:of\s+the\s+)?(?:load|power|heat|work)",
                           "heaviest", "(?:highest|largest|biggest|greatest)" + _LOAD_NOUN, "busiest", r"peak\s+load")),
    ("load", "min", _words(r"least\s+(?:heavily\s+)?loaded", r"least\s+(?:of\s+the\s+)?(?:load|power|heat|work)",
                           "lightest", "(?:lowest|smallest)" + _LOAD_NOUN, "idlest")),
]  # fmt: skip
COMPARATIVES: list[tuple[str, str, re.Pattern]] = [
    ("temp", "gt", _words("hotter", "warmer")),
    ("temp", "lt", _words("cooler", "colder")),
    ("load", "gt", _words(r"more\s+(?:heavily\s+)?loaded", r"(?:more|higher)\s+(?:load|power|heat)")),
    ("load", "lt", _words(r"less\s+(?:heavily\s+)?loaded", r"(?:less|lower)\s+(?:load|power|heat)")),
]  # fmt: skip
THAN = _words("than")


def words_between(text: str, a: int, b: int) -> int:
    """Number of words strictly between positions a and b of ``text``."""
    lo, hi = (a, b) if a <= b else (b, a)
    return len(re.findall(r"[\w°%./-]+", text[lo:hi]))

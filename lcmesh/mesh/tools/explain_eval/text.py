"""Reading explanation text: sections, sentences, clauses, branch mentions and the patterns the checks use.

Everything here is a regular expression over plain text; nothing is learned. The words (in English,
Spanish, German and French) are ``lcmesh.mesh.tools.vocab``'s, which the chat's guard reads too; this
module compiles them into the patterns of docs/explanations.md ("Evaluator rules").
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass

from lcmesh.mesh.tools import vocab
from lcmesh.mesh.tools.vocab import function_words, words

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
_CHANGE_WORDS = r"(?:raised|lowered|held|increased|decreased|unchanged|opened|closed)"
_KV_LINE = re.compile(r"^(?P<lead>\s*(?:[-*•]\s+)?)(?P<key>[A-Za-z][\w '’/-]*?)\s*[:=]\s*(?P<val>[^()\n]+?)\s*"
                      r"\((?P<dir>" + _CHANGE_WORDS + r"[^()\d]*)\)\s*\.?$", I)  # not "(held, 10.0 K above wet bulb)"
# "dp setpoint: 41.5 psi, held": the change after a comma, as in a bullet list
_KV_COMMA_LINE = re.compile(r"^(?P<lead>\s*(?:[-*•]\s+)?)(?P<key>[A-Za-z][\w '’/-]*?)\s*:\s*(?P<val>[^(),\n]+?)\s*,\s*"
                            r"(?P<dir>" + _CHANGE_WORDS + r")\s*\.?$", I)
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
                r"(?:\s+branch)?\s*[:=]\s*(?:branch\s*)?(\d+)\b(?![.,]\d)", I), r"\1 branch: branch \2"),
    (re.compile(r"\s+\|\s+|\s{2,}(?=\S)"), "; "),  # log fields
    (re.compile(r"\)\s+(?=branch\s+\d)"), "); "),
]


# a comma between digits is a decimal comma ("31,69 °C", "0,33") unless three digits follow it ("1,000 kW": thousands)
# or it continues an index list ("ramas 1,2", "b1,2"); lc-mesh writes "." in every language, other writers do not
_DECIMAL_COMMA = re.compile(r"(?<![\w,.])(\d+),(?=(?:\d{1,2}|\d{4,})(?!\d|,\d))")
_INDEX_BEFORE = re.compile(r"\b(?:" + "|".join(w for lang in vocab.LANGUAGES for w in vocab.BRANCH_WORDS[lang])
                           + r")\s*$", I)
_KV_PAIR_GAP = re.compile(r"\s+(?=[A-Za-z][\w.-]*\s*=)")  # "valve1=0.33 valve1_change=held": one field each
_GENERIC_HEADERS = re.compile(r"^(?:value|now|current|new|valor|wert|valeur|actual)$", I)


# Spanish, German and French write the decimal comma whatever follows it ("0,333", "1.050,3 kW"): there a comma
# between digits is decimal and dots before a decimal comma group thousands
_DECIMAL_COMMA_ANY = re.compile(r"(?<![\w,.])(\d+),(?=\d+(?!\d|,\d))")
_THOUSAND_DOTS = re.compile(r"(?<![\w.,])\d{1,3}(?:\.\d{3})+(?=,\d)")
_LEADING_ZERO_COMMA = re.compile(r"(?<![\w,.])0,(?=\d+(?!\d|,\d))")  # "0,333" is no thousands group in any language


def _digits_end(text: str, pos: int) -> int:
    while pos < len(text) and text[pos].isdigit():
        pos += 1
    return pos


def _decimal_commas(text: str, language: str = "en") -> str:
    def repl(m: re.Match) -> str:
        if m.group(1) != "0" and _INDEX_BEFORE.search(text[max(0, m.start() - 20) : m.start()]) \
                and not vocab.unit_at(text, _digits_end(text, m.end())):
            return m.group()  # "ramas 1,2" lists branches; "ramas 31,1 °C" is a temperature
        return m.group(1) + "."

    if language in ("es", "de", "fr"):
        text = _THOUSAND_DOTS.sub(lambda m: m.group().replace(".", ""), text)
        return _DECIMAL_COMMA_ANY.sub(repl, text)
    return _DECIMAL_COMMA.sub(repl, _LEADING_ZERO_COMMA.sub("0.", text))


# a key's unit suffix, longest first: "kg_s" before "s", "kpa" before "pa"
_KEY_UNITS = sorted({"c": "°C", "f": "°F", "k": "K", "kw": "kW", "mw": "MW", "w": "W", "psi": "psi", "kpa": "kPa",
                     "pa": "Pa", "pct": "%", "kg_s": "kg/s"}.items(), key=lambda kv: -len(kv[0]))  # fmt: skip


def _key_unit(key: str) -> str | None:
    """The unit a JSON or CSV key ends in ("supply_sp_c" -> °C, "vorlauf_sollwert_f" -> °F), or None."""
    return next((unit for suffix, unit in _KEY_UNITS if key.lower().endswith("_" + suffix)), None)


def _with_key_unit(key: str, value):
    """A JSON value whose key ends in its unit ("supply_sp_c": 30.0, "vorlauf_sollwert_f": 86.0) keeps the unit."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (unit := _key_unit(key)) is None:
        return value
    return f"{value} {unit}"


def _flatten_json(text: str) -> str:
    """A JSON object in the text becomes one "key: values." line per object holding values (nested keys joined),
    so "valve_2": "0.25 -> 0.26 (opened)" and {"now": 0.29, "was": 0.31, "change": "closed"} read as sentences."""
    a, z = text.find("{"), text.rfind("}")
    if a < 0 or z < a:
        return text
    try:
        data = json.loads(text[a : z + 1])
    except ValueError:
        return text
    if not isinstance(data, dict):
        return text
    lines: list[str] = []

    def walk(obj: dict, path: list[str]) -> None:
        leaves = [(k, _with_key_unit(k, ", ".join(map(str, v)) if isinstance(v, list) else v)) for k, v in obj.items()
                  if not isinstance(v, dict) and not (isinstance(v, list) and any(isinstance(x, (dict, list)) for x in v))]
        change = [str(v) for k, v in leaves if _CHANGE_COLUMN.search(k)]
        cells = [str(v) if _GENERIC_HEADERS.match(k) else f"{k} {v}" for k, v in leaves
                 if not _CHANGE_COLUMN.search(k)]  # fmt: skip
        if path and cells:
            lines.append(f"{' '.join(path)}: {', '.join(cells)}{f' ({change[0]})' if change else ''}.")
        elif not path:
            lines.extend(f"{k}: {v}." for k, v in leaves)
        for k, v in obj.items():
            if isinstance(v, dict):
                walk(v, path + [k])
            elif isinstance(v, list):  # "ventile": [{"zweig": 1, "anteil": 0.338, "richtung": "geöffnet"}, ...]
                for item in v:
                    if isinstance(item, dict):
                        walk(item, path + [k])

    walk(data, [])
    head = text[:a].rstrip().rstrip("-> :=").rstrip()
    head = re.sub(r"```\w*\s*$", "", head).rstrip()
    tail = re.sub(r"^\s*```", "", text[z + 1 :])
    return "\n".join(x for x in (head + ("." if head and not head.endswith((".", ":")) else ""), *lines, tail) if x)


# "la branche la plus chaude est la 2", "la más cargada es la 3": the number after "es/est/ist la" names a branch
# when the sentence has named branches before it
_IS_THE_N = re.compile(r"\b(?:es|est|ist)\s+(?:la|el|le|der|die)\s+(?=\d+\b(?![.,]\d))"
                       r"|(?<![\w.,])(?:la|el|le|der|die|den|dem)\s+(?=[1-9]\b(?![.,]\d)(?!\s*(?:°|%|K\b|kW|psi|"
                       r"grad|grados|degr|kilo|°C|h\b|min)))", I)
_BRANCH_WORD = re.compile(r"\b(?:ramas?|zweige?s?|branches?|branch|str[aä]nge?s?|válvulas?|vannes?|ventile?|valves?)\b", I)


# "rama_a", "Zweig B", "branch C" as keys or labels: branches 1, 2, 3
_LETTER_BRANCH = re.compile(r"\b(ramas?|zweige?|branch(?:es)?|branches?)[\s_-]+([A-Ca-c])\b(?=\s*[:=,;)\]]|\s+\d|$)")


# the middle one of three branches: "the middle branch", "la rama central", "der mittlere Zweig", "la branche du milieu"
_MIDDLE_BRANCH = re.compile(r"\b(?:the\s+)?middle\s+branch|\brama\s+(?:central|del\s+medio)|\bmittlere[nrs]?\s+zweig\w*|"
                            r"\bbranche\s+(?:du\s+milieu|centrale)", I)  # fmt: skip
_NUMBER_NAMES = {"i": 1, "ii": 2, "iii": 3, "iv": 4, "uno": 1, "una": 1, "dos": 2, "tres": 3, "cuatro": 4, "eins": 1,
                 "zwei": 2, "drei": 3, "vier": 4, "un": 1, "une": 1, "deux": 2, "trois": 3, "quatre": 4, "one": 1,
                 "two": 2, "three": 3, "four": 4}  # fmt: skip
_NUMBER_NAME = r"(?:" + "|".join(sorted(_NUMBER_NAMES, key=len, reverse=True)) + r")"
# "Zweig II", "Zw. III", "rama dos", "ramas uno y dos", "branch two": a branch named by a roman numeral or a word
_NAMED_NUMBER = re.compile(r"\b((?:ramas?|zweige?|zw\.|str[aä]nge?|branch(?:es)?|branches?|vlv|ventile?)\s*)"
                           r"(" + _NUMBER_NAME + r"(?:\s*(?:-|,|/|y|und|et|and)\s*" + _NUMBER_NAME + r")*)\b"
                           r"(?!\s*(?:°|%|kW|psi))", I)


def _branch_number(m: re.Match) -> str:
    names = re.split(r"(\s*(?:-|,|/|y|und|et|and)\s*)", m.group(2))
    out = [str(_NUMBER_NAMES[p.lower()]) if p.lower() in _NUMBER_NAMES else p for p in names]
    return m.group(1) + "".join(out)


def _is_the_branch(line: str) -> str:
    out, last = [], 0
    for m in _IS_THE_N.finditer(line):
        start = max(line.rfind(". ", 0, m.start()), 0)
        if _BRANCH_WORD.search(line, start, m.start()):
            out += [line[last : m.end()], "branch "]
            last = m.end()
    return "".join(out) + line[last:]


def normalize(text: str, language: str = "en") -> str:
    """Plain sentences from the shapes other systems write: decimal commas become points, a JSON object one line
    per object holding values, markdown table rows "key: header value, ... (change)" lines, key-value lines with a
    change in brackets or after a comma "key raised at value.", a line of key=value fields one field at a time,
    log shorthand is spelled out (``supply_sp`` -> supply setpoint, ``b2=`` -> branch 2 valve, arrows -> raised /
    lowered). Prose without these shapes is returned unchanged."""
    out, header = [], None
    text = _flatten_json(_decimal_commas(text, language))
    lines = _csv_as_table(text.splitlines())
    bare = _bare_table_lines(lines)
    for k, line in enumerate(lines):
        s = line.strip()
        if k in bare:
            s = line = "| " + s + " |"
        if len(s) > 1 and s.startswith("|") and s.endswith("|"):
            cells = [c.strip() for c in s.strip("|").split("|")]
            if all(_TABLE_RULE.match(c) for c in cells if c):
                continue
            if header is None:
                header = cells
                continue
            line = _row(cells, header)
        else:
            header = None
        if not s or heading_of(line) is not None:
            out.append(line)
            continue
        line = _LETTER_BRANCH.sub(lambda m: f"{m.group(1)} {' abc'.index(m.group(2).lower())}", line)
        line = _MIDDLE_BRANCH.sub("branch 2", line)
        line = _is_the_branch(_NAMED_NUMBER.sub(_branch_number, line))
        if len(re.findall(r"[A-Za-z][\w.-]*\s*=", line)) >= 3:
            line = _KV_PAIR_GAP.sub("; ", line.strip())
        for pattern, repl in _SHORTHAND:
            line = pattern.sub(repl, line)
        m = _KV_LINE.match(line) or _KV_COMMA_LINE.match(line)
        if m:
            line = f"{m.group('lead')}{m.group('key')} {m.group('dir')} at {m.group('val')}."
        out.append(line)
    return "\n".join(out)


def _csv_as_table(lines: list[str]) -> list[str]:
    """CSV pasted as text (a header of names, then rows with as many "," or ";" separated fields) becomes a markdown
    table; a value whose header ends in a unit keeps it ("vorlauf_sw_c" -> °C)."""
    out, k = list(lines), 0
    while k < len(lines) - 1:
        head = lines[k].strip()
        sep = ";" if head.count(";") >= 2 else "," if head.count(",") >= 2 else None
        if sep is None or re.search(r"\d[.,]\d|\s{2,}", head) or not re.fullmatch(r"[\w\s%°/.-]+(?:" + sep + r"[\w\s%°/.-]+)+", head):
            k += 1
            continue
        names = [c.strip() for c in head.split(sep)]
        j = k + 1
        while j < len(lines) and lines[j].count(sep) == len(names) - 1 and lines[j].strip():
            j += 1
        if j - k < 2:
            k += 1
            continue
        out[k] = ""
        for r in range(k + 1, j):  # "armoire 2: branche 1, temp c 24.0 °C, vanne 0.333 (held), ..."
            cells = [c.strip() for c in lines[r].split(sep)]
            named: list[str] = []
            for name, cell in zip(names, cells):
                if named and _CHANGE_COLUMN.search(name):
                    named[-1] += f" ({cell})"  # "supply_dir": the change of the column before it
                else:
                    named.append(f"{name.replace('_', ' ')} {_cell_with_unit(name, cell)}")
            out[r] = f"{named[0]}: {', '.join(named[1:])}."
        k = j
    return out


_CHANGE_COLUMN = re.compile(r"(?:^|_)(?:dir|direction|change|status|estado|accion|acción|richtung|sens|änderung|cambio)$",
                            re.IGNORECASE)  # fmt: skip


def _cell_with_unit(name: str, cell: str) -> str:
    unit = _key_unit(name) if re.fullmatch(r"[-+]?\d+(?:\.\d+)?", cell) else None
    return cell if unit is None else f"{cell} {unit}"


def _bare_table_lines(lines: list[str]) -> set[int]:
    """Lines of a table written without its outer pipes ("Zweig | Temp. | Ventil" over "1 | 29,8 °C | 0,33"): two or
    more lines in a row with the same number (two or more) of cell separators."""
    counts = [s.count("|") if not s.strip().startswith("|") else -1 for s in lines]
    found: set[int] = set()
    k = 0
    while k < len(lines):
        j = k
        while j + 1 < len(lines) and counts[j + 1] == counts[k]:
            j += 1
        if counts[k] >= 2 and j > k:
            found.update(range(k, j + 1))
        k = j + 1
    return found


def _row(cells: list[str], header: list[str]) -> str:
    """A table row as "first cell: other cells (last cell)", each other cell named by its column's header ("Branch 1:
    blade temp 33.1 °C, valve 0.33 (held)"; "value", "now" ... name nothing); an index in the first cell takes the
    first header's name ("1" under "Branch"), a name takes it after it ("CDU supply" under "Setpoint")."""
    named = []
    for i, c in enumerate(cells):
        h = header[i] if i < len(header) else ""
        if not c or c in ("—", "-", "–"):
            continue
        if i == 0:
            if re.fullmatch(r"\d+", c) and h:
                c = f"{h} {c}"
            elif h and not _GENERIC_HEADERS.match(h) and h.lower().rstrip("s") not in c.lower():
                c = f"{c} {h.lower()}"
        elif h and not _GENERIC_HEADERS.match(h) and i < len(cells) - 1 and h.lower() not in c.lower():
            c = f"{h} {c}"
        named.append(c)
    if len(named) >= 3:
        return f"{named[0]}: {', '.join(named[1:-1])} ({named[-1]})."
    return ": ".join(named) + "."


# --- sections and sentences -------------------------------------------------------------------

_HEADING_MD = re.compile(r"^\s*(#{1,6})\s*(.+?)\s*#*\s*$")
# chat and log writers start sentences in lower case too ("dp held. torre sube a 29,0 °C"), but not after an
# abbreviation ("cons. 18,0 °C", "approx. 3 K", "z. B.")
_LOWER_SENTENCE_END = re.compile(r"(?<=[.!?])[\"')\]*_]*\s+(?=[a-zà-öø-ÿ])")
_ABBREVIATION = re.compile(r"(?:\b(?:cons|approx|aprox|env|ca|vs|etc|bzw|nr|no|resp|temp|max|min|avg|sp|br|arm|cab|zw|schr|gab|"
                           r"vorl|ét|csg|sup|imp|vent|änd|e\.g|i\.e|z\.\s?b|"
                           r"u\.\s?a|d\.\s?h|p\.\s?ej|c\.-à-d)\.)$", I)
_SENTENCE_END = re.compile(r"(?<=[.!?])[\"')\]*_]*\s+(?=[A-Z0-9ÁÉÍÓÚÑÄÖÜÀÂÇÈÊÎÔΔ\"'(\[*•¿¡-])")
_AND = vocab.alternation(*function_words("and"))
_BRANCH_WORDS = vocab.alternation(*(w for lang in vocab.LANGUAGES for w in vocab.BRANCH_WORDS[lang]))
_CLAUSE_SPLIT = re.compile(
    rf";|:(?!\d)|\s[—–]\s|\s-\s|,\s+{_AND}\s+"
    rf"|,?\s+(?={vocab.alternation(*function_words('but'))}\b)"
    rf"|,\s+(?=(?:{_AND}\s+)?{vocab.ARTICLE}?{_BRANCH_WORDS}\s*\d)",
    I,
)
_CONDITIONAL_START = re.compile(r"^\W*" + vocab.alternation(*function_words("if")) + r"\b", I)
# the conditional mood and general rules are no claims about this action: "la enfriaría", "ferait", "würde", "cuanto
# más baja es la consigna ...", "je höher ..."
_MODAL = re.compile(words(*function_words("would")).pattern + r"|\b\w+(?:ría|rían|rait|raient)\b"
                    r"|\b(?:würden?|könnte[n]?|sollte[n]?|wäre[n]?|cuanto|je\s+(?:mehr|höher|niedriger|weniger))\b", I)


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
        ends = [m.end() for pattern in (_SENTENCE_END, _LOWER_SENTENCE_END) for m in pattern.finditer(body)
                if not _ABBREVIATION.search(body[: m.start()].rstrip("\"')]"))]
        cuts = [0] + sorted(set(ends)) + [len(body)]
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
        if m.group().startswith(":") and len(re.findall(r"\w+", sentence[cuts[-1] if len(cuts) > 1 else 0 : m.start()])) <= 4:
            continue  # "torre: consigna bajada a 25,2 °C", "dp setpoint: raised to 27.5 psi": a label and what it says
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

_JOIN = vocab.alternation(r",\s*" + _AND, ",", _AND, *function_words("or"), "&", "/", "to", "through", "-", "–", "à",
                          "bis", "hasta", "al")  # fmt: skip
_ITEM_VALUE = r"(?:\s*\([^()]{1,20}\))?"  # "ramas 1 (0,324) y 2 (0,340)": each item with its value in brackets
_NUM_LIST = (r"\d+" + vocab.NOT_A_VALUE + r"(?:" + _ITEM_VALUE + r"\s*" + _JOIN + r"\s*\d+" + vocab.NOT_A_VALUE
             + r")*")  # fmt: skip
_BRANCH = re.compile(r"\b" + _BRANCH_WORDS + r"[\s-]*(?:#|no\.\s*)?(?P<nums>" + _NUM_LIST + r")\b", I)
_PERCENT_AFTER = re.compile(r"(?:\s*/\s*\d+)*\s*(?:%|por\s*ciento|prozent|pour\s*cent)", I)
# "V1=0,333", "V2 zu", "br. 3", "Br.2": a valve's or a branch's short name (a mention of that branch)
_VALVE_SHORT = re.compile(r"\b(?:V|R|Z|br\.?\s?|zw\.?\s?)(?P<num>[1-9])\b(?![.,]\d)", I)
_LIST_JOIN = re.compile(r"\s*(?:,|,?\s*" + _AND + r"|&|/|-)\s*" + vocab.ARTICLE + "?", I)
_BRANCH_SHORT = re.compile(r"\b(?:B|BG)(?P<num>\d+)\b")
_ORDINALS = vocab.ORDINAL_WORDS
_ORD = "|".join(sorted(_ORDINALS, key=len, reverse=True))
_ONE_BRANCH = vocab.alternation(r"branch", r"blade[- ]group", "group", "valve", "rama", "zweige?s?", "strang",
                                "branche", "vanne", "válvula", "ventil")
# "the third branch", "la tercera rama", "der dritte Zweig"; after a branch word in its sentence, an ordinal with its
# article alone ("deja la primera en 0,324", "la troisième, avec 2,7 kW") or before "es/est/ist" names a branch too
_BRANCH_ORDINAL = re.compile(r"\b(?P<ord>" + _ORD + r")\s+" + _ONE_BRANCH + r"\b"
                             r"|\b(?:la|el|le|der|die|das|the)\s+(?P<ord2>" + _ORD + r")\b(?!\s+\w*(?:stunde|hora|heure|"
                             r"hour|step|paso|schritt|pas|tiers|tercio|drittel|third|half|mitad|moitié|quart|cuarto|"
                             r"viertel|quarter))", I)  # fmt: skip


def _sentence_end(text: str, pos: int) -> int:
    end = text.find(". ", pos)
    return len(text) if end < 0 else end


def branch_mentions(text: str) -> list[BranchMention]:
    """"branch 2", "branches 1 and 3", "blade group 2", "valve 3", "B1", "the second branch"."""
    found = []
    g, previous_end = -1, None
    for m in _BRANCH.finditer(text):
        if vocab.SHARE_FRACTION.fullmatch(m.group("nums")) or _PERCENT_AFTER.match(text, m.end()):
            continue  # "valves 1/3" is a third each, "válvulas 33/33/33 %" shares: not valves 1 and 3
        # "branch 1 and branch 3 were held at 0.37 and 0.37" is one list, like "branches 1 and 3"
        if previous_end is None or not _LIST_JOIN.fullmatch(text, previous_end, m.start()):
            g += 1
        previous_end = m.end()
        for n in re.finditer(r"\([^()]*\)|\d+", m.group("nums")):
            if n.group().startswith("("):
                continue
            start = m.start() if n.start() == 0 else m.start("nums") + n.start()
            found.append(BranchMention(start, m.start("nums") + n.end(), int(n.group()), group=g))
    found += [BranchMention(m.start(), m.end(), int(m.group("num"))) for m in _BRANCH_SHORT.finditer(text)]
    found += [BranchMention(m.start(), m.end(), int(m.group("num"))) for m in _VALVE_SHORT.finditer(text)]
    for m in _BRANCH_ORDINAL.finditer(text):
        if m.group("ord"):
            found.append(BranchMention(m.start(), m.end(), _ORDINALS[m.group("ord").lower()], True))
        elif _BRANCH_WORD.search(text, max(m.start() - 200, 0), _sentence_end(text, m.end())):
            found.append(BranchMention(m.start("ord2"), m.end(), _ORDINALS[m.group("ord2").lower()], True))
    found.sort(key=lambda b: b.start)
    short = {id(b) for b in found if b.group < 0}  # "br1", "V2", "the third branch": no list of their own yet
    for a, b in zip(found, found[1:]):
        if id(a) in short and id(b) in short and _LIST_JOIN.fullmatch(text, a.end, b.start):
            if a.group < 0:
                g += 1
                a.group = g
            b.group = a.group
    return found


def decide_index_base(mentions: list[BranchMention], n_branches: int, declared: int | None) -> int:
    """0 or 1: declared by the record, else 0 if some branch is called 0, else 1."""
    if declared is not None:
        return declared
    raws = {b.raw for b in mentions if not b.ordinal}
    return 0 if 0 in raws else 1


# --- patterns (vocab.py's words in the four languages) ------------------------------------------

SUPPLY_SETPOINT = vocab.dimension("supply", setpoint=True)
SUPPLY_ANY = vocab.dimension("supply")
FLOW = vocab.dimension("flow")
DP = vocab.dimension("dp")
TOWER = vocab.dimension("tower")
TOWER_SETPOINT = vocab.dimension("tower", setpoint=True)
VALVE = vocab.dimension("valve")
EQUAL_SPLIT = vocab.split_words("equal")
PRONOUN = vocab.split_words("its")
EACH = vocab.split_words("each")
DIRECTION = [(pol, side, words(*forms)) for pol, side, forms in vocab.DIRECTIONS]
ANY_DIRECTION = words(*(f for _, _, forms in vocab.DIRECTIONS for f in forms), *vocab.COMPARISON_WORDS)
VALVE_MORE = vocab.split_words("more")
VALVE_LESS = vocab.split_words("less")
RELATIVE_TO_OTHERS = vocab.split_words("than_others")
RELATIVE_TO_LOAD = vocab.split_words("than_load")
PASSIVE_AUX = re.compile(r"\b(?:is|was|are|were|be|been|being|gets?|got|has|have|had)\s+(?:\w+\s+)?$", I)
NEGATION = re.compile(words(*function_words("not")).pattern + r"|n[’']t\b", I)  # "didn't": no word boundary before n't
NEGATED_HOLD = re.compile(r"(?:is|was)\s+not\s+changed|did\s+not\s+change|no\s+change|no\s+cambió"
                          r"|nicht\s+(?:verändert|geändert)|(?:n['’]a\s+)?pas\s+(?:changé|bougé)", I)  # fmt: skip

# physics: cause adjectives right before a dimension word, and effect targets with their words
# a verb or noun of moving a setting, in any form ("relever la Δp", "si bajáramos la impulsión", "eine Erhöhung des
# Sollwerts", "cette baisse de la consigne"), then an article
_ARTICLE_AFTER = r"(?:\s+(?:la|le|les|el|los|las|the|its|sa|son|su|die|der|den|des|das|dem|de|del|du|von|l['’]))*"
_MOVE_UP = (r"rais\w*|increas\w*|open\w*|rel[eè]v\w*|augment\w*|hausse|remont\w*|ouvr\w*|sub(?:ir|iera|iéramos|e|ió|ida|"
            r"iendo)|aument\w*|elev\w*|abr(?:ir|iera|iéramos|e|ió|iendo)|anheb\w*|anhebung|erhöh\w*|öffn\w*|hoch\w*")
_MOVE_DOWN = (r"lower(?:ing|ed|s)?|decreas\w*|reduc\w*|clos\w*|throttl\w*|baiss\w*|abaiss\w*|diminu\w*|ferm\w*|"
              r"réduir\w*|baj(?:ar|ara|áramos|amos|ó|ando|ada)|cerr\w*|disminu\w*|senk\w*|absenk\w*|schließ\w*|"
              r"drossel\w*|verringer\w*")
CAUSE_ADJ_UP = re.compile(
    r"\b(?:higher|warmer|more|increased|raised|larger|bigger|extra|greater|opening|raising|increasing"
    r"|más|mayor|mehr|höhere[nrs]?|plus\s+de|davantage\s+de|" + _MOVE_UP + r")" + _ARTICLE_AFTER + r"\s*$", I
)
CAUSE_ADJ_DOWN = re.compile(
    r"\b(?:lower|colder|cooler|less|reduced|lowered|smaller|closing|lowering|reducing|decreasing|throttling"
    r"|menos|menor|weniger|niedrigere[nrs]?|moins\s+de|" + _MOVE_DOWN + r")" + _ARTICLE_AFTER + r"\s*$", I
)
# the same after the dimension word: "un Δp plus élevé", "una consigna más alta", "une consigne de départ plus basse"
CAUSE_AFTER_UP = re.compile(r"^\s*(?:\w+\s+)?(?:anzuheben|zu\s+erhöhen|plus\s+(?:élevée?s?|haute?s?)|supérieure?s?|más\s+alt[oa]s?|"
                            r"higher|höher\w*|(?:this|so|that)\s+high|increase|rise|raise|bump|hike|aumento|subida|"
                            r"erhöhung|anhebung|hausse|augmentation)\b", I)
CAUSE_AFTER_DOWN = re.compile(r"^\s*(?:\w+\s+)?(?:abzusenken|zu\s+senken|(?:tan|muy|so|sehr|si|très)\s+(?:baj[oa]|niedrig\w*|basse?)|"
                              r"plus\s+basse?s?|inférieure?s?|más\s+baj[oa]s?|lower|"
                              r"niedriger\w*|tiefer\w*|decrease|drop|cut|reduction|bajada|descenso|reducción|"
                              r"absenkung|senkung|baisse|diminution)\b", I)
TARGETS = {
    "temp": words("temperatures?", "temps?", "blades?", r"blade[\s-]+groups?", "chips?", "servers?", "GPUs?",
                   "components?", "hardware", r"hot\s?spots?",
                   "placas", "temperaturas?", r"temperatur(?:en)?", "températures?", "lames",
                   r"supply\s+water", r"eau\s+de\s+(?:soufflage|départ)", r"agua\s+de\s+impulsión",
                   r"wasser\s+zur\s+cdu", r"water\s+to\s+the\s+cdus?", r"(?:agua|eau)\s+(?:hacia\s+|vers\s+)?(?:la|el)\s+cdu",
                   r"vorlauf(?:wasser|temperatur)"),
    # a branch itself warms or cools ("würde Zweig 2 noch wärmer machen", "la réchaufferait"): warm/cool words only
    "branch": words("ramas?", r"zweige?s?", "branches?", "branch", r"zw\.(?=\s*\d)", r"(?:la|le|lo)(?=\s+\w*(?:calent|enfri|réchauff|"
                    r"refroid))"),
    "fan": words(r"fans?(?:[\s-]+(?:power|energy|speed))?", r"tower[\s-]+(?:power|energy)",
                 r"(?:potencia\s+de\s+(?:los\s+)?)?ventiladores", r"lüfter(?:leistung)?",
                 r"(?:puissance\s+des\s+)?ventilateurs", r"ventilador(?:es)?", r"ventilator\w*", r"lüfter\w*"),
    "pump": words(r"pump(?:ing)?[\s-]+(?:power|energy|work)", r"potencia\s+de\s+(?:la\s+)?bomba",
                  r"pumpenleistung", r"puissance\s+de\s+(?:la\s+)?pompe", "pumps?", "bombas?", "pumpen?", "pompes?"),
    "energy": words("energy", "electricity", r"power\s+(?:use|draw|consumption)", "energía", "energie", "énergie",
                    "consumo", "verbrauch", "consommation"),
}  # fmt: skip
_RISE = ("ris(?:e|es|ing)", "rose", "increas(?:e|es|ed|ing)", "rais(?:e|es|ed|ing)", "higher",
         "aumenta", "sube", "steigt", "erhöht", "augmente", "monte")  # fmt: skip
_FALL = ("lower(?:s|ed|ing)?", "drop(?:s|ped)?", "decreas(?:e|es|ed|ing)", "reduc(?:e|es|ed|ing)",
         "reduce", "baja", "disminuye", "senkt", "sinkt", "réduit", "diminue", "baisse")  # fmt: skip
EFFECT_UP = {
    "temp": words(*_RISE, "warm(?:s|ed|ing|er)?", r"heat(?:s|ed|ing)?\s+up", "hotter", "climb(?:s|ed|ing)?",
                   r"calent\w*", r"erwärm\w*", r"réchauff\w*", "wärmer",
                   r"aufheiz\w*", r"heiz\w*", r"(?<!\bla\s)(?<!\bel\s)más\s+calientes?",
                   r"(?<!\bla\s)(?<!\ble\s)plus\s+chaude?s?"),
    "power": words(*_RISE, r"work(?:s|ing)?\s+harder", r"spin(?:s|ning)?\s+(?:up|faster)", r"ramp(?:s|ed)?\s+up",
                    "more", "costs?", "adds?", "cuesta", "kostet", "coûte", r"trabaj\w*\s+más", r"travaill\w*\s+plus",
                    r"mehr\s+arbeiten", r"cost\w*", r"coût\w*", r"kost\w*", r"consum\w*\s+más", r"más\s+consumo",
                    r"gast\w*\s+más", r"up"),
}  # fmt: skip
# an effect word reaches its target only within its own part of the sentence: "warms the supply water but reduces
# fan power" says nothing of the water going down
EFFECT_BREAK = re.compile(r"\b(?:but|pero|aber|mais|while|whereas|mientras|während|tandis|yet|sino|sondern)\b|[;,]", I)
EFFECT_DOWN = {
    "temp": words(*_FALL, "cool(?:s|ed|er)?", "colder", "fall(?:s|ing)?", "fell", r"brings?\s+down",
                   r"more\s+cooling", r"enfr[ií]\w*", r"kühl\w*", r"abkühl\w*", r"abgekühlt", r"refroidi\w*", "kälter",
                   r"(?<!\bla\s)(?<!\bel\s)más\s+fr[ií][oa]s?", r"(?<!\bla\s)(?<!\ble\s)plus\s+froide?s?"),
    "power": words(*_FALL, "sav(?:e|es|ed|ing)", "less", "cut(?:s|ting)?", r"slow(?:s|ed)?\s+down", "eas(?:e|es|ed)",
                    "idles?", "ahorra", "spart", "économise", r"trim\w*", r"relie\w*", r"ahorr\w*", r"spar\w*",
                    r"économis\w*", r"réduir\w*", r"reduc\w*", r"baisser\w*", r"entlast\w*", r"soulag\w*",
                    r"reducir\w*", r"verringer\w*", r"reduzier\w*", "down", r"gesenkt", r"gast\w*\s+menos",
                    r"(?:casi\s+)?parad[oa]s", "idle", r"à\s+l['’]arrêt", r"stehen\w*"),
}  # fmt: skip
EFFECT_UP["heat"] = words("warm(?:s|ed|ing|er)?", "hotter", r"calent\w*", r"erwärm\w*", r"réchauff\w*", "wärmer",
                          r"heat(?:s|ed|ing)?\s+up")
EFFECT_DOWN["heat"] = words("cool(?:s|ed|er)?", "colder", r"enfr[ií]\w*", r"kühl\w*", r"refroidi\w*", "kälter",
                            r"senkt\s+(?:dessen|seine|ihre|die)\s+temperatur")
REASON = words("because", "since", "due to", "as a result of", "given")
# water said to leave the tower colder than the wet bulb, however it is put: "below the wet bulb", "colder than the
# 18.8 °C wet bulb", "más fría que el bulbo húmedo", "kälter als die Feuchtkugel", "plus froide que le bulbe humide"
_WET_BULB = r"(?:wet[\s-]?bulb|bulbo\s+húmedo|feuchtkugel\w*|bulbe\s+humide)"
_BELOW = (r"(?:below|under|colder\s+than|cooler\s+than|lower\s+than|por\s+debajo\s+del?|más\s+fr[ií]a\s+que|"
          r"unter(?:halb)?|kälter\s+als|en\s+dessous\s+du|plus\s+froide\s+que)")
BELOW_WET_BULB = re.compile(
    r"(?:leaving[\s-]+water|LWT|tower\s+water|water|agua|wasser|eau)[^.;]{0,60}?\b" + _BELOW
    + r"\s+(?:(?:the|el|la|le|die|der)\s+)?(?:[-\d.]+\s*°\s*[CF]\s+)?" + _WET_BULB, I
)

# ranking claims
SUPERLATIVES: list[tuple[str, str, re.Pattern]] = [
    (kind, "max" if order == "highest" else "min", words(*vocab.superlative_forms(kind, order)))
    for kind, order in vocab.SUPERLATIVES if kind != "any"
]  # fmt: skip
COMPARATIVES: list[tuple[str, str, re.Pattern]] = [(kind, op, words(*forms))
                                                   for (kind, op), forms in vocab.COMPARATIVES.items()]  # fmt: skip
THAN = words("than", "als", "que", "qu'")
# what a rationale's direction word is said of when it stands between the setpoint and the word: "a higher
# leaving-water setpoint lets the tower fans ease off" says the fans ease off, not the setpoint
EFFECT_SUBJECT = words("fans?", "pumps?", "blades?", "chips?", "servers?", "GPUs?", "ventiladores", "bombas?", "lüfter",
                       "pumpen", "ventilateurs?", "pompes?")


def words_between(text: str, a: int, b: int) -> int:
    """Number of words strictly between positions a and b of ``text``."""
    lo, hi = (a, b) if a <= b else (b, a)
    return len(re.findall(r"[\w°%./-]+", text[lo:hi]))

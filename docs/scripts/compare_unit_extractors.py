"""Which quantity/unit reader should the judge use? Measured on the corpus's dev part only.

    .venv/bin/python docs/scripts/compare_unit_extractors.py

For every number a corpus writer printed in a correct dev text (``numbers``: figure, unit as written,
unit meant), check whether the reader finds that figure with that unit: the judge's own reader
(``numbers.extract_numbers``: regular expressions for the number and its role, units converted with
factors from pint) against quantulum3's ``parser.parse``. Prints accuracy per written unit and the time
per text (docs/explanations.md, "Libraries").
"""

from __future__ import annotations

import json
import time
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
CORPUS = ROOT / "lcmesh" / "mesh" / "tools" / "explain_eval" / "corpus" / "corpus.jsonl"
OURS = {"°C": "degC", "°F": "degF", "K": "K", "kW": "kW", "psi": "psi", "kPa": "kPa", "bar": "bar", "kg/s": "kg/s",
        "gpm": "gpm", "L/s": "L/s", "%": "%", "": ""}  # fmt: skip
QUANTULUM = {"°C": ("celsius",), "°F": ("fahrenheit",), "K": ("kelvin",), "kW": ("kilowatt",),
             "psi": ("pound-force per square inch", "psi"), "kPa": ("kilopascal",), "bar": ("bar",),
             "kg/s": ("kilogram per second",), "gpm": ("gallon per minute", "gallon per min"),
             "L/s": ("litre per second", "liter per second"), "%": ("percentage", "percent"),
             "": ("dimensionless",)}  # fmt: skip


def main() -> None:
    from quantulum3 import classifier, parser

    classifier.USE_CLF = False  # its pickled disambiguation model does not load with this scikit-learn

    from lcmesh.mesh.tools.explain_eval.numbers import extract_numbers
    from lcmesh.mesh.tools.explain_eval.text import normalize

    texts = [json.loads(line) for line in CORPUS.read_text().splitlines()]
    texts = [t for t in texts if t["split"] == "dev" and t["correct"] and t.get("numbers")]
    hits = {"regex+pint": defaultdict(lambda: [0, 0]), "quantulum3": defaultdict(lambda: [0, 0])}
    seconds = {"regex+pint": 0.0, "quantulum3": 0.0}
    for t in texts:
        text = normalize(t["explanation"])
        t0 = time.perf_counter()
        ours = {(m.text.lstrip("-−–+"), m.unit) for m in extract_numbers(text)}
        t1 = time.perf_counter()
        theirs = [(q, q.unit.name.lower()) for q in parser.parse(text)]
        t2 = time.perf_counter()
        seconds["regex+pint"] += t1 - t0
        seconds["quantulum3"] += t2 - t1
        for figure, written, _ in t["numbers"]:
            row = hits["regex+pint"][written]
            row[0] += 1
            row[1] += (figure, OURS.get(written, "?")) in ours
            row = hits["quantulum3"][written]
            row[0] += 1
            names = QUANTULUM.get(written, ())
            row[1] += any(abs(q.value - float(figure)) < 1e-9 and any(n in name for n in names) for q, name in theirs)
    print(f"{len(texts)} correct dev texts, {sum(len(t['numbers']) for t in texts)} printed numbers")
    for reader, table in hits.items():
        total = sum(r[0] for r in table.values())
        right = sum(r[1] for r in table.values())
        per = ", ".join(f"{u or 'bare'} {r[1]}/{r[0]}" for u, r in sorted(table.items()))
        ms = 1e3 * seconds[reader] / len(texts)
        print(f"{reader}: {right}/{total} = {right / total:.3f} ({ms:.2f} ms/text); {per}")


if __name__ == "__main__":
    main()

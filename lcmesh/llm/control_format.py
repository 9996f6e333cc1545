"""The LLM controller's compact protocol: one short prompt per cabinet or tower, an answer of a few decided digits.

A cabinet's prompt shows what the PPO teacher's cabinet row holds (per branch its mean and hottest
temperature and its coming-step power; the CDU's measured supply, the hot-water supply, the wet bulb),
at display precision; a tower's prompt what its tower row holds. Both are raw ChatML (SmolLM2's
format) with a short fixed head, the same for every cabinet (or tower), so a runtime that keeps the
head's KV cache reads only the numbers.

The answer is a fixed-width string of fields, each a set of allowed values:

    cabinet  ``S27.5 D31 V433``   supply 20.0-40.0 degC in 0.5 K, dp 25-38 psi, one weight 0-9 per branch
    tower    ``A3.5``             approach over the wet bulb, one of the learned policies' nine levels

Every digit is one token in SmolLM2's vocabulary, so the answer is decoded digit by digit, each digit
chosen among those that keep the text a prefix of an allowed value (a grammar in the form of a trie:
the answer parses by construction), and the characters that the grammar fixes (``.``, `` D``) are
fed with the digit before them at no extra forward pass. A cabinet costs 8 decided tokens, a tower 2.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from lcmesh.distill.features import APPROACH_LEVELS_K, normalize_split
from lcmesh.llm.io_format import K0, CabinetDecision, CabinetView, TowerDecision, TowerView
from lcmesh.twin.system import PSI_TO_PA

SUPPLY_VALUES = tuple(f"{20.0 + 0.5 * i:04.1f}" for i in range(41))  # "20.0" .. "40.0"
DP_VALUES = tuple(f"{p:02d}" for p in range(25, 39))  # "25" .. "38"
WEIGHT_VALUES = tuple(str(d) for d in range(10))
APPROACH_VALUES = tuple(f"{a:.1f}" for a in APPROACH_LEVELS_K)  # "1.5" .. "8.0"

CABINET_HEAD = "<|im_start|>system\nCDU setpoints<|im_end|>\n<|im_start|>user\n"
TOWER_HEAD = "<|im_start|>system\nTower approach<|im_end|>\n<|im_start|>user\n"
ASSISTANT = "<|im_end|>\n<|im_start|>assistant\n"


@dataclass(frozen=True)
class Field:
    """One answer field: the fixed text before it and its allowed values (all of one width)."""

    prefix: str
    values: tuple[str, ...]

    def __post_init__(self) -> None:
        if len({len(v) for v in self.values}) != 1:
            raise ValueError(f"field values must share one width, got {self.values}")


def cabinet_fields(n_branches: int) -> tuple[Field, ...]:
    """``S<supply> D<dp> V<w1><w2>...``."""
    return (Field("S", SUPPLY_VALUES), Field(" D", DP_VALUES),
            *(Field(" V" if b == 0 else "", WEIGHT_VALUES) for b in range(n_branches)))  # fmt: skip


TOWER_FIELDS = (Field("A", APPROACH_VALUES),)


def _c(x: float) -> str:
    return f"{x:.1f}"


def plant_line(wet_bulb_c: float, htw_c: float) -> str:
    """What every cabinet of one decision shares (read once: the next cabinet's prompt reuses its cache)."""
    return f"wb {_c(wet_bulb_c)} htw {_c(htw_c)}\n"


def cabinet_body(view: CabinetView) -> str:
    """The cabinet's own numbers: measured supply, then per branch its temperature (mean/hottest when they
    differ), and its coming-step power in kW."""
    rows = []
    for t, m, p in zip(view.branch_temp_c, view.branch_max_temp_c, view.branch_power_kw):
        temp = _c(t) if abs(m - t) < 0.05 else f"{_c(t)}/{_c(m)}"
        rows.append(f"{temp} {p:.0f}")
    return f"s {_c(view.supply_c)}\n" + "\n".join(rows)


def cabinet_rest(view: CabinetView) -> str:
    """What follows the cached head in a cabinet's prompt: the plant's line, its numbers, the assistant turn."""
    return plant_line(view.wet_bulb_c, view.htw_supply_c) + cabinet_body(view) + ASSISTANT


def tower_rest(view: TowerView) -> str:
    """What follows the cached head in a tower's prompt."""
    fans = "/".join(f"{f:.0f}" for f in view.fan_pct)
    body = (f"wb {_c(view.wet_bulb_c)} hot {_c(view.hottest_c)} ret {_c(view.htw_return_c)} mean {_c(view.mean_leaving_c)}\n"
            f"lw {_c(view.leaving_c)} app {_c(view.approach_k)} fans {fans}")
    return body + ASSISTANT


def cabinet_prompt(view: CabinetView) -> str:
    """The whole prompt for one cabinet."""
    return CABINET_HEAD + cabinet_rest(view)


def tower_prompt(view: TowerView) -> str:
    """The whole prompt for one tower."""
    return TOWER_HEAD + tower_rest(view)


def cabinet_answer(supply_k: float, dp_pa: float, valve_fractions: Sequence[float]) -> list[str]:
    """The field values (one per field) nearest a teacher's cabinet action."""
    supply = min(SUPPLY_VALUES, key=lambda v: abs(float(v) - (supply_k - K0)))
    dp = min(DP_VALUES, key=lambda v: abs(float(v) - dp_pa / PSI_TO_PA))
    f = np.asarray(valve_fractions, dtype=float)
    weights = np.clip(np.rint(9.0 * f / max(float(f.max()), 1e-9)), 0, 9).astype(int)  # the largest branch is 9
    return [supply, dp, *(str(w) for w in weights)]


def tower_answer(approach_k: float) -> list[str]:
    """The allowed approach nearest a teacher's (leaving-water setpoint minus wet bulb)."""
    return [min(APPROACH_VALUES, key=lambda v: abs(float(v) - approach_k))]


def answer_text(fields: Sequence[Field], values: Sequence[str]) -> str:
    return "".join(f.prefix + v for f, v in zip(fields, values))


def cabinet_decision(values: Sequence[str]) -> CabinetDecision:
    """Field values (grammar-valid by construction) to setpoints in SI units and a valve split."""
    supply, dp, *weights = values
    split = normalize_split(np.array([[float(w) for w in weights]]))[0]
    return CabinetDecision(float(supply) + K0, float(dp) * PSI_TO_PA, tuple(float(x) for x in split))


def tower_decision(values: Sequence[str]) -> TowerDecision:
    return TowerDecision(float(values[0]))


def allowed_next(values: Sequence[str], typed: str) -> list[str]:
    """The characters that may follow ``typed`` in a field with these values (the trie's children)."""
    return sorted({v[len(typed)] for v in values if v.startswith(typed) and len(v) > len(typed)})


def parse_values(fields: Sequence[Field], text: str) -> list[str] | None:
    """The field values of an answer text, or None when it does not follow the grammar."""
    values, pos = [], 0
    for f in fields:
        if not text.startswith(f.prefix, pos):
            return None
        pos += len(f.prefix)
        width = len(f.values[0])
        value = text[pos : pos + width]
        if value not in f.values:
            return None
        values.append(value)
        pos += width
    return values if pos == len(text.rstrip()) else None


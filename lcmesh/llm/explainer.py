"""LLM explanations of a cabinet decision, checked by the explanation evaluator, with a deterministic fallback.

The toolbox computes the decision's facts (``cabinet_decision_facts``) and, beside them, what the
renderer does not say (``decision_whatif_facts``: the hottest branch at the new and at the held supply
setpoint, the CDU pump at the new and the held dp and their difference in kW, the input furthest from
normal); the LLM writes the explanation from all of them (``lcmesh/prompts/controller_explain.md``:
compact ``name = value`` lines), and the judge grounds its numbers against all of them. A text's
*what-if claims* are the what-if facts it states, with their unit, that the rendering does not
(``whatif_claims``); they count only in a text the judge passes. At the detailed levels
(``WHATIF_LEVELS``) the LLM writes the whole text, WHAT IF section included. The whole short text and
that section do not fit the short budget on 2 cores: with a short-level backend (``short_backend_for``:
the ``explain-short`` adapter on llama.cpp, trained on the compact prompt of ``whatif_messages``) the
LLM writes only the WHAT IF section on the hottest branch, and it follows the rendering
(``llm_part = "what-if"``); without one a short text stops at the WHAT IF heading.
``lcmesh explain-eval``'s scorer checks the text; an explanation below the thresholds (numeric
grounding 0.98, coverage 1, direction consistency 0.95) or with missing sections is replaced by the
deterministic rendering, and the reason is counted. The distilled model was trained to write the
renderer's text, so the rendering is also passed as a draft: the backend verifies it in long runs
instead of decoding token by token (the text stays the model's own greedy output). The LLM gets a
time budget per level (2.85 s short, 9.7 s detailed: the rest of the 3 s / 10 s targets goes to the
facts, the checks and the rendering, about 10 ms). The budget bounds the whole backend call: the
decoder does not start a pass it expects to end after it, the first one included
(``lcmesh.llm.budget``); an unfinished or unstarted text counts as a ``timeout`` fallback.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass, field
from string import Template

import numpy as np

from lcmesh.llm.base import LlmBackend
from lcmesh.llm.budget import Clock
from lcmesh.llm.io_format import load_template
from lcmesh.mesh.tools.explain import explanation_record, render_explanation
from lcmesh.mesh.tools.explain_eval import LEVEL_SECTIONS, evaluate_record
from lcmesh.mesh.tools.claims import Claim, states
from lcmesh.mesh.tools.claims import Fact as CheckFact
from lcmesh.mesh.tools.explain_eval.numbers import read_numbers
from lcmesh.mesh.tools.facts import K0, Fact, cabinet_decision_facts, decision_whatif_facts
from lcmesh.twin.plant import PlantAction
from lcmesh.twin.system import SystemDescription

MAX_NEW_TOKENS = {"short": 1024, "detailed": 1536, "very_detailed": 2560}
# Levels whose texts may add the WHAT IF section: decoding it token by token takes 2-3 s on 2 cores, more than the
# short level's budget leaves after its one draft pass, so a short text stops at the section's heading.
WHATIF_LEVELS = ("detailed", "very_detailed")
WHATIF_HEADING = "## WHAT IF"
TIME_BUDGET_S = {"short": 2.85, "detailed": 9.7, "very_detailed": 20.0}  # the LLM's share; then the renderer
# the targets for a whole explanation (facts, rendering, LLM, judge), as the mesh and the benchmark count them
TARGET_S = {"short": 3.0, "detailed": 10.0}
# The short what-if: a short text has no time for the whole text and its WHAT IF section, so where a short-level
# backend is given (the ``explain-short`` adapter on llama.cpp) the LLM writes only that section, after the rendering,
# from a compact prompt (the decision's supply setpoint and the hottest branch's what-if facts, about 120 tokens)
SHORT_WHATIF_FACTS = ("cabinet", "supply_setpoint", "supply_setpoint_change")
SHORT_WHATIF_CLAIMS = ("hottest_branch_expected", "hottest_branch_if_held")
SHORT_WHATIF_TOKENS = 64  # the trained sentences end in 40-47 tokens; room, so none is cut short
LEVEL_WORDS = {"short": "short", "detailed": "detailed", "very_detailed": "very detailed"}


@dataclass(frozen=True)
class ExplainThresholds:
    """Minimum scores an LLM explanation needs to be used (else the deterministic text is)."""

    numeric_grounding: float = 0.98
    coverage: float = 1.0
    direction_consistency: float = 0.95


@dataclass
class ExplanationResult:
    """The text an operator sees, where it came from and how the LLM's own text scored."""

    text: str
    source: str  # "llm" | "renderer"
    level: str
    llm_scores: dict
    seconds: float
    new_tokens: int = 0
    fallback_reason: str | None = None
    flags: list = field(default_factory=list)
    whatif_claims: list[str] = field(default_factory=list)  # what-if facts the LLM's text states and the rendering lacks
    identical_to_rendering: bool = False
    facts: list[Fact] = field(default_factory=list)  # what the LLM was given and the judge grounded the text against
    llm_part: str = "whole"  # "whole": the LLM wrote the text; "what-if": the rendering, then the LLM's WHAT IF section
    rendered: str = ""  # the deterministic rendering of the same facts (the text when the renderer stands in)


# What a what-if fact's unit reads as in the judge's number interpretations: (quantity, value -> canonical SI)
_CANONICAL = {"degC": ("temp_abs", lambda v: v + K0), "K": ("temp_delta", abs), "kW": ("power", lambda v: abs(v) * 1e3)}
_CLAIM_TOL = {"temp_abs": 0.051, "temp_delta": 0.051, "power": 51.0}  # the facts' display precision (0.1 degC, kW)


def _check_fact(fact: Fact) -> CheckFact:
    """A toolbox fact as the checks read it: its value in SI, with its quantity."""
    quantity, to_si = _CANONICAL[fact.unit]
    return CheckFact(fact.name, to_si(float(fact.value)), quantity, fact.unit)


def _states(claims: list[Claim], fact: Fact) -> bool:
    """One of the number claims states the fact at the facts' display precision (or the number's own)."""
    target = _check_fact(fact)
    return states(claims, target.quantity, target.value, _CLAIM_TOL[target.quantity])


def unverified_whatif_numbers(text: str, facts: list[Fact]) -> list[str]:
    """Numbers with a unit in the text's WHAT IF section that state none of ``facts``: each what-if claim must hold on
    its own (a text-wide grounding share of 0.98 would let one wrong claim through in a long text)."""
    if WHATIF_HEADING not in text:
        return []
    section = text[text.index(WHATIF_HEADING) :]
    numeric = [f for f in facts if f.unit in _CANONICAL and isinstance(f.value, (int, float))]
    return [c.text for c in read_numbers(section) if c.unit and not any(_states([c], f) for f in numeric)]


def whatif_claims(text: str, whatif_facts: list[Fact], rendered: str) -> list[str]:
    """Names of the what-if facts ``text`` states with a unit (the input label with its value) and ``rendered`` does not."""
    said, base = read_numbers(text), read_numbers(rendered)
    by_name = {f.name: f for f in whatif_facts}
    claims = []
    for f in whatif_facts:
        if f.unit not in _CANONICAL or not isinstance(f.value, (int, float)):
            continue
        if f.name == "top_input_value" and str(by_name.get("top_input", f).value).lower() not in text.lower():
            continue
        if _states(said, f) and not _states(base, f):
            claims.append(f.name)
    return claims


def explain_messages(facts: list[Fact], level: str) -> list[dict[str, str]]:
    """Chat messages asking for an explanation of the decision behind ``facts`` at ``level``."""
    return _facts_messages(facts, LEVEL_WORDS[level], LEVEL_SECTIONS[level])


def _facts_messages(facts: list[Fact], level_words: str, headings) -> list[dict[str, str]]:
    system, user = load_template("controller_explain")
    cabinet = next((f.display for f in facts if f.name == "cabinet"), "?")
    values = {"level": level_words, "cabinet": cabinet, "headings": ", ".join(headings),
              "facts": "\n".join(f"{f.name} = {f.display}" for f in facts)}  # fmt: skip
    return [{"role": "system", "content": Template(system).substitute(values)},
            {"role": "user", "content": Template(user).substitute(values)}]  # fmt: skip


def short_whatif_facts(facts: list[Fact], whatif: list[Fact]) -> list[Fact]:
    """The compact prompt's facts: the decision's supply setpoint and the hottest branch's what-if estimates."""
    return [f for f in facts if f.name in SHORT_WHATIF_FACTS] + [f for f in whatif if f.name in SHORT_WHATIF_CLAIMS]


def whatif_messages(prompt_facts: list[Fact]) -> list[dict[str, str]]:
    """Chat messages asking for the WHAT IF section alone (the short level's LLM part) from the compact facts."""
    return _facts_messages(prompt_facts, "what if", ("WHAT IF",))


def short_backend_for(settings=None) -> LlmBackend | None:
    """llama.cpp with the short what-if adapter (``short_adapter``) for the short level; None where the backend is
    remote, llama.cpp is not installed or no such adapter is here (the short text is then the configured backend's)."""
    from lcmesh.llm.base import LlmBackendSettings
    from lcmesh.llm.gguf_lora import resolve_folder
    from lcmesh.llm.llama_backend import LlamaCppBackend, llama_available

    settings = settings or LlmBackendSettings()
    if settings.backend != "local" or not llama_available() or resolve_folder(settings.short_adapter,
                                                                               "explain-short") is None:  # fmt: skip
        return None
    short = settings.model_copy(update={"adapter": settings.short_adapter, "model": "smollm2-135m-instruct"})
    return LlamaCppBackend.from_settings(short, adapter_kind="explain-short")


def make_explainer(system: SystemDescription, settings=None, *, short_only: bool = False) -> LlmExplainer:
    """The explainer as the mesh runs it: the configured backend, and the short level's. ``short_only``: the configured
    backend is loaded only where no short-level one is here (a mesh explaining at the short level needs no other)."""
    from lcmesh.llm.base import make_backend

    short = short_backend_for(settings)
    return LlmExplainer(system, None if short_only and short is not None else make_backend(settings),
                        short_backend=short)  # fmt: skip


class LlmExplainer:
    """Explains cabinet decisions with an LLM backend; counts how often the renderer had to stand in."""

    def __init__(
        self,
        system: SystemDescription,
        backend: LlmBackend | None,
        *,
        thresholds: ExplainThresholds = ExplainThresholds(),
        use_draft: bool = True,
        whatif: bool = True,
        time_budget_s: dict[str, float] | None = None,
        clock: Clock | None = None,
        short_backend: LlmBackend | None = None,
    ):
        """``clock`` times the explanations; by default the backend's, so one injected clock drives both.
        ``whatif``: give the LLM the what-if facts too (the judge then grounds them). ``short_backend``: the short
        level's backend (``short_backend_for``: the ``explain-short`` adapter); with it a short text is the rendering
        and the LLM's WHAT IF section (``llm_part = "what-if"``)."""
        self.system, self.backend, self.thresholds, self.use_draft = system, backend, thresholds, use_draft
        self.short_backend = short_backend
        self.whatif = whatif
        self.clock = clock or getattr(backend, "clock", time.monotonic)
        self.time_budget_s = {**TIME_BUDGET_S, **(time_budget_s or {})}
        self.stats: Counter = Counter()

    def explain(
        self,
        out: Mapping[str, np.ndarray],
        action: PlantAction,
        previous_action: PlantAction | None,
        wet_bulb_k: float,
        cabinet: int,
        level: str = "short",
        record_id: str = "decision",
    ) -> ExplanationResult:
        """The explanation of ``cabinet``'s part of ``action`` (``out``: plant outputs it was decided on)."""
        if level not in MAX_NEW_TOKENS:
            raise ValueError(f"`level` must be one of {', '.join(MAX_NEW_TOKENS)}, got {level!r}")
        facts = cabinet_decision_facts(self.system, out, action, previous_action, wet_bulb_k, cabinet)
        rendered = render_explanation(facts, level)
        part = "what-if" if self.whatif and level == "short" and self.short_backend is not None else "whole"
        whatif = self.whatif and (level in WHATIF_LEVELS or part == "what-if")
        extra = decision_whatif_facts(self.system, out, action, previous_action, wet_bulb_k, cabinet) if whatif else []
        t0 = self.clock()
        try:
            if part == "what-if":
                text, gen = self._short_whatif(facts, extra, rendered)
            else:
                if self.backend is None:
                    raise RuntimeError(f"no backend for the {level} level (built for the short level only)")
                gen = self.backend.chat([explain_messages(facts + extra, level)], max_new_tokens=MAX_NEW_TOKENS[level],
                                        stop=() if whatif else (WHATIF_HEADING,),
                                        drafts=[rendered] if self.use_draft else None,
                                        time_budget_s=self.time_budget_s[level])[0]  # fmt: skip
                text = gen.text.removesuffix(WHATIF_HEADING).strip() + "\n"
            n_new, error = gen.new_tokens, gen.failure
            if error is None and part == "what-if" and text == rendered:
                error = "no_whatif"
        except Exception as exc:  # a failing backend degrades to the renderer, it never stops the agent
            text, error, n_new = "", f"{type(exc).__name__}: {exc}", 0
        seconds = self.clock() - t0
        record = explanation_record(out, action, facts + extra, text, cabinet=cabinet, record_id=record_id,
                                    previous_action=previous_action, wet_bulb_k=wet_bulb_k, level=level)  # fmt: skip
        item = evaluate_record(record)
        scores = {k: float(item[k]) for k in ("numeric_grounding", "coverage", "direction_consistency")}
        if error:
            reason = error if error in ("timeout", "no_whatif") else "backend"
        else:
            reason = self._failed_check(scores, item["flags"])
            if reason is None and unverified_whatif_numbers(text, facts + extra):
                reason = "whatif_unverified"
        self.stats["explanations"] += 1
        if reason is None:
            self.stats["llm"] += 1
            claims = whatif_claims(text, extra, rendered)
            same = text.strip() == rendered.strip()
            self.stats["llm_with_whatif_claim"] += bool(claims)
            self.stats["llm_identical_to_rendering"] += same
            return ExplanationResult(text, "llm", level, scores, seconds, n_new, None, item["flags"], claims, same,
                                     facts + extra, part, rendered)  # fmt: skip
        self.stats["renderer"] += 1
        self.stats[f"fallback_{reason}"] += 1
        return ExplanationResult(rendered, "renderer", level, scores, seconds, n_new, reason, item["flags"],
                                 facts=facts + extra, llm_part=part, rendered=rendered)  # fmt: skip

    def _short_whatif(self, facts: list[Fact], extra: list[Fact], rendered: str):
        """The rendering, then the WHAT IF section the short-level LLM writes from the compact prompt (the rendering
        alone when it writes none)."""
        gen = self.short_backend.chat([whatif_messages(short_whatif_facts(facts, extra))],
                                      max_new_tokens=SHORT_WHATIF_TOKENS,
                                      time_budget_s=self.time_budget_s["short"])[0]  # fmt: skip
        section = gen.text.strip()
        if not section.startswith(WHATIF_HEADING) or not section.removeprefix(WHATIF_HEADING).strip():
            return rendered, gen
        return f"{rendered.rstrip()}\n\n{section}\n", gen

    def _failed_check(self, scores: dict, flags: list[dict]) -> str | None:
        for key, minimum in vars(self.thresholds).items():
            if scores[key] < minimum:
                return key
        if any(f["kind"] == "missing_section" for f in flags):
            return "missing_section"
        return None

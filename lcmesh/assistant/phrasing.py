"""Who writes the chat answer's final text: the deterministic draft itself, or the LLM backend rephrasing it.

The template phraser returns the draft (written from tool results by ``writer.py``).
The LLM phraser (``LCMESH_UI_PHRASER=llm``; the backend is ``lcmesh.llm``'s, configured by
``LCMESH_LLM_*``) sends the question, the facts and the draft through
``lcmesh/prompts/chat_answer.md`` (the draft also goes as the backend's decoding draft). Its text
is kept only if every number in it is a fact and its numbers are the draft's, in the draft's
order (a small model can swap two facts' values and still cite only facts); else the draft is
used and the rejection counted. Either way the answer cites nothing but the facts.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from importlib import resources
from string import Template
from typing import Any, Protocol

from lcmesh.assistant.facts import ChatFact, numbers_in, ungrounded_numbers

log = logging.getLogger("lcmesh.assistant")
PROMPT = "chat_answer"
TIME_BUDGET_S = 4.0  # the LLM's share of the 5 s answer target; an unfinished text gives way to the draft
STOP = ("\n\nRewrite", "\nRewrite the", "\nOperator question", "\nQuestion type", "\nFacts:", "\nDraft answer")


@dataclass(frozen=True)
class Phrased:
    text: str
    by: str  # "template" or "llm:<model>"
    note: str | None = None


class Phraser(Protocol):
    name: str

    def phrase(self, question: str, intent: str, draft: str, facts: list[ChatFact]) -> Phrased: ...


class TemplatePhraser:
    """The deterministic draft, unchanged."""

    name = "template"

    def phrase(self, question: str, intent: str, draft: str, facts: list[ChatFact]) -> Phrased:
        return Phrased(draft, "template")


def load_chat_prompt() -> tuple[str, Template]:
    """(system text, user template) of ``lcmesh/prompts/chat_answer.md``."""
    text = resources.files("lcmesh.prompts").joinpath(f"{PROMPT}.md").read_text(encoding="utf-8")
    if "<!-- system -->" not in text or "<!-- user -->" not in text:
        raise ValueError(f"prompt {PROMPT}.md must hold a '<!-- system -->' and a '<!-- user -->' part")
    system, user = text.split("<!-- system -->", 1)[1].split("<!-- user -->", 1)
    return system.strip(), Template(user.strip())


def chat_messages(question: str, intent: str, draft: str, facts: list[ChatFact]) -> list[dict[str, str]]:
    """The chat messages asking an LLM to rephrase `draft` citing only `facts`."""
    system, user = load_chat_prompt()
    lines = "\n".join(f"- {f.name} = {f.display} ({f.text})" for f in facts) or "- (none)"
    return [{"role": "system", "content": system},
            {"role": "user", "content": user.substitute(question=question, intent=intent, facts=lines, draft=draft)}]  # fmt: skip


class LlmPhraser:
    """Rephrases drafts with an ``lcmesh.llm`` backend; falls back to the draft when the text is not grounded.

    The backend loads in a background thread (a local model takes seconds); until it is ready, and
    whenever it fails, answers are the template's.
    """

    def __init__(self, backend: Any = None, *, load: Callable[[], Any] | None = None, max_new_tokens: int = 160,
                 time_budget_s: float = TIME_BUDGET_S):  # fmt: skip
        self.backend, self.max_new_tokens, self.time_budget_s = backend, max_new_tokens, time_budget_s
        self.name = f"llm:{getattr(backend, 'model_id', 'loading')}"
        self.tally = {"phrased": 0, "rejected": 0, "errors": 0, "timeouts": 0}
        self.load_error: str | None = None
        self._lock = threading.Lock()  # one generation at a time on a CPU model
        self.ready = threading.Event()
        if backend is not None:
            self.ready.set()
        elif load is not None:
            threading.Thread(target=self._load, args=(load,), name="ui-llm-load", daemon=True).start()

    def _load(self, load: Callable[[], Any]) -> None:
        t0 = time.perf_counter()
        try:
            self.backend = load()
            self.name = f"llm:{getattr(self.backend, 'model_id', 'llm')}"
            log.info("chat LLM %s loaded in %.1f s", self.name, time.perf_counter() - t0)
        except Exception as exc:
            self.load_error = f"{type(exc).__name__}: {exc}"
            log.warning("chat LLM did not load (%s); phrasing with the template", self.load_error)
        finally:
            self.ready.set()

    def phrase(self, question: str, intent: str, draft: str, facts: list[ChatFact]) -> Phrased:
        if self.backend is None:
            note = f"LLM not usable: {self.load_error}" if self.load_error else "LLM still loading"
            return Phrased(draft, "template", note)
        messages = chat_messages(question, intent, draft, facts)
        budget = min(self.max_new_tokens, len(draft) // 3 + 32)  # a rephrasing is about as long as the draft
        try:
            with self._lock:
                gen = self.backend.chat([messages], max_new_tokens=budget, stop=STOP, drafts=[draft],
                                        time_budget_s=self.time_budget_s)[0]  # fmt: skip
            if gen.finish_reason == "timeout":
                self.tally["timeouts"] += 1
                return Phrased(draft, "template", f"LLM text unfinished after {self.time_budget_s:g} s")
            if gen.finish_reason == "error":
                raise RuntimeError(gen.error or "generation failed")
            text = cut_echo(gen.text)
        except Exception as exc:  # a backend failure must not lose the answer
            self.tally["errors"] += 1
            log.warning("LLM phrasing failed (%s: %s); using the template", type(exc).__name__, exc)
            return Phrased(draft, "template", f"LLM failed: {type(exc).__name__}")
        why = rejection(text, draft, facts)
        if why is not None:
            self.tally["rejected"] += 1
            return Phrased(draft, "template", f"LLM text rejected ({why})")
        self.tally["phrased"] += 1
        return Phrased(text, self.name)


def cut_echo(text: str) -> str:
    """The completion up to the first echo of the prompt's own headings."""
    cut = min((i for i in (text.find(s) for s in STOP) if i >= 0), default=len(text))
    return text[:cut].strip()


def rejection(text: str, draft: str, facts: list[ChatFact]) -> str | None:
    """Why an LLM text may not replace the draft, or None.

    Every number must be a fact, and the numbers must be the draft's, in the draft's order: a
    small model that swaps two facts' values (cabinet 5's peak printed as cabinet 2's) still
    cites only facts, so membership alone is not enough.
    """
    if not text:
        return "empty"
    bad = ungrounded_numbers(text, facts)
    if bad:
        return f"ungrounded numbers {bad[:5]}"
    if numbers_in(text) != numbers_in(draft):
        return "its numbers differ from the draft's (values or order)"
    return None


def make_phraser(kind: str, *, wait: bool = False, adapter: str | None = None) -> tuple[Phraser, str | None]:
    """The phraser `kind` asks for, or the template one and the reason the LLM is not used.

    ``llm`` takes the backend ``lcmesh.llm`` configures from ``LCMESH_LLM_*`` (local model or an
    OpenAI-compatible endpoint); it loads in the background unless `wait`. ``adapter`` replaces
    the local backend's LoRA adapter (the UI passes ``phraser_adapter``, 'none' by default).
    """
    if kind != "llm":
        return TemplatePhraser(), None
    try:
        from lcmesh.llm.base import LlmBackendSettings, make_backend

        settings = LlmBackendSettings()
        if adapter is not None and settings.backend == "local":
            settings = settings.model_copy(update={"adapter": adapter})
    except Exception as exc:  # the LLM package is absent or its settings are invalid
        reason = f"LLM backend not usable ({type(exc).__name__}: {exc}); phrasing with the template"
        log.warning("%s", reason)
        return TemplatePhraser(), reason
    phraser = LlmPhraser(load=lambda: make_backend(settings))
    if wait:
        phraser.ready.wait()
        if phraser.backend is None:
            return TemplatePhraser(), f"LLM backend not usable ({phraser.load_error}); phrasing with the template"
    return phraser, None

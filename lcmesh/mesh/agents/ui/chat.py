"""The grounded chat: classify the question, retrieve facts, write the answer, check its numbers.

``ChatEngine.ask(message)`` returns ``{"answer", "facts", "intent", "proposed_command",
"phrased_by", "grounded", "elapsed_ms"}``. The intent comes from a deterministic classifier
(``intents.py``); facts from the live state, history, decisions and the toolbox (``answers.py``,
``actions.py``); the text from a digit-free template over those facts, optionally rephrased by
the LLM backend (``phrasing.py``). Before it leaves, every number in the answer is checked
against the facts. A request to change the plant comes back as a proposed command: chat never
actuates.
"""

from __future__ import annotations

import logging
import time
from collections import Counter
from collections.abc import Callable
from typing import Any

from lcmesh.mesh.agents.ui import actions, answers
from lcmesh.mesh.agents.ui.answers import Answer, ChatSources, NotReady
from lcmesh.mesh.agents.ui.facts import ungrounded_numbers
from lcmesh.mesh.agents.ui.intents import Intent, classify
from lcmesh.mesh.agents.ui.phrasing import Phraser, TemplatePhraser

log = logging.getLogger("lcmesh.mesh.agents.ui")

HANDLERS: dict[str, Callable[[Intent, ChatSources], Answer]] = {
    "state": answers.answer_state, "rank": answers.answer_rank, "compare": answers.answer_compare,
    "alerts": answers.answer_alerts, "agents": answers.answer_agents, "controller": answers.answer_controller,
    "help": answers.answer_help, "why": actions.answer_why, "whatif": actions.answer_whatif,
    "command": actions.answer_command,
}  # fmt: skip


class ChatEngine:
    """Answers operator questions from facts; counts intents, latencies and ungrounded answers."""

    def __init__(self, sources: ChatSources, phraser: Phraser | None = None):
        self.sources = sources
        self.phraser = phraser or TemplatePhraser()
        self.intents: Counter = Counter()
        self.ungrounded = 0
        self.not_ready = 0
        self.latency_s: list[float] = []

    def ask(self, message: str) -> dict[str, Any]:
        """The answer to `message`; NotReady (HTTP 503) when the data it needs is not there yet."""
        t0 = time.perf_counter()
        intent = classify(message)
        self.intents[intent.kind] += 1
        try:
            answer = HANDLERS[intent.kind](intent, self.sources)
        except NotReady:
            self.not_ready += 1
            raise
        except FileNotFoundError as exc:  # no history file yet
            self.not_ready += 1
            raise NotReady(str(exc)) from None
        phrased = self.phraser.phrase(message, answer.intent, answer.text, answer.facts)
        bad = ungrounded_numbers(phrased.text, answer.facts)
        if bad:  # a template bug: say so rather than print an unsupported number
            self.ungrounded += 1
            log.error("chat answer to %r cites numbers no fact holds: %s", message, bad)
        elapsed = time.perf_counter() - t0
        self.latency_s.append(elapsed)
        del self.latency_s[:-1000]
        return {
            "answer": phrased.text,
            "facts": [f.model_dump() for f in answer.facts],
            "intent": answer.intent,
            "proposed_command": answer.proposed_command,
            "phrased_by": phrased.by,
            "phrasing_note": phrased.note,
            "grounded": not bad,
            "elapsed_ms": round(elapsed * 1e3, 2),
        }

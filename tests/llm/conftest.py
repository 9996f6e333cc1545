"""The local model, unpacked once per test session into the session cache (real weights, no hub), and test clocks."""

from __future__ import annotations

from contextlib import contextmanager

import pytest


@pytest.fixture(scope="session")
def local_model_dir():
    from lcmesh.llm.model_cache import resolve_model

    return resolve_model("smollm2-135m-instruct")


@pytest.fixture(scope="session")
def base_backend(local_model_dir):
    """SmolLM2-135M-Instruct without an adapter, in float32.

    These tests check decoding, budgets and fallbacks, which do not depend on the dtype; on a CPU without
    native bfloat16 (AVX2 only, as here) bfloat16 decodes 4-5x slower (a 7-prompt test: 28 s -> 6 s).
    The bfloat16 path the settings default to runs in test_planner.py, test_openai_compat.py and the mesh's
    LLM-explainer test."""
    from lcmesh.llm.hf.backend import HfBackend

    return HfBackend(local_model_dir, adapter=None, dtype="float32")


@pytest.fixture(scope="session")
def control_backend():
    """llama.cpp on the shipped GGUF with the packaged control adapter (as the LLM controller loads it)."""
    from lcmesh.llm.controller import make_control_backend

    backend = make_control_backend("default", threads=1)
    yield backend
    backend.close()


@pytest.fixture(scope="session")
def llama_base():
    """llama.cpp on the shipped GGUF, no adapter."""
    from lcmesh.llm.llama_backend import LlamaCppBackend

    backend = LlamaCppBackend(threads=1)
    yield backend
    backend.close()


def frozen_clock() -> float:
    """A clock on which no time passes: a budget never runs out, so only tokens and parsing decide."""
    return 0.0


class ForwardClock:
    """A clock that moves only when the model runs: each forward pass costs ``per_pass_s + per_token_s * tokens``.

    Budgets then depend on the passes a call makes, not on how busy the machine is.
    """

    def __init__(self, *, per_pass_s: float = 0.0, per_token_s: float = 0.0):
        self.per_pass_s, self.per_token_s = per_pass_s, per_token_s
        self.now, self.passes = 0.0, 0

    def __call__(self) -> float:
        return self.now

    @contextmanager
    def driving(self, model):
        """Advance this clock on every forward pass of ``model`` while inside."""
        handle = model.register_forward_pre_hook(self._tick, with_kwargs=True)
        try:
            yield self
        finally:
            handle.remove()

    def _tick(self, module, args, kwargs) -> None:
        ids = kwargs.get("input_ids")
        if ids is None:
            ids = args[0]
        self.now += self.per_pass_s + self.per_token_s * ids.numel()
        self.passes += 1

"""The local model, unpacked once per test session into the session cache (real weights, no hub)."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def local_model_dir():
    from lcmesh.llm.model_cache import resolve_model

    return resolve_model("smollm2-135m-instruct")


@pytest.fixture(scope="session")
def base_backend(local_model_dir):
    """SmolLM2-135M-Instruct without an adapter, bfloat16 (as the controller runs it)."""
    from lcmesh.llm.hf.backend import HfBackend

    return HfBackend(local_model_dir, adapter=None, dtype="bfloat16")

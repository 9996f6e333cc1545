"""GGUF -> plain safetensors folder (transformers reads the GGUF with the ``gguf`` package, de-quantized)."""

from __future__ import annotations

from pathlib import Path

from lcmesh.llm.model_cache import offline_env


def unpack_gguf(gguf: Path, target: Path) -> None:
    """Write config, weights (float32, as de-quantized) and tokenizer of ``gguf`` into ``target``."""
    offline_env()
    from transformers import AutoModelForCausalLM, AutoTokenizer
    from transformers.utils import logging as hf_logging

    hf_logging.disable_progress_bar()
    folder, name = str(gguf.parent), gguf.name
    tokenizer = AutoTokenizer.from_pretrained(folder, gguf_file=name)
    model = AutoModelForCausalLM.from_pretrained(folder, gguf_file=name)
    # the weights are plain tensors now; drop the GGUF quantizer so the folder is an ordinary checkpoint
    model.hf_quantizer = None
    if hasattr(model.config, "quantization_config"):
        del model.config.quantization_config
    model.config._name_or_path = gguf.stem
    model.save_pretrained(target)
    tokenizer.save_pretrained(target)


def gguf_load_seconds(gguf: Path) -> float:
    """Wall time to load the model straight from the GGUF (de-quantizing), for the cache benchmark."""
    import time

    offline_env()
    from transformers import AutoModelForCausalLM, AutoTokenizer

    t0 = time.perf_counter()
    AutoTokenizer.from_pretrained(str(gguf.parent), gguf_file=gguf.name)
    AutoModelForCausalLM.from_pretrained(str(gguf.parent), gguf_file=gguf.name)
    return time.perf_counter() - t0

"""GGUF -> plain safetensors folder (transformers reads the GGUF with the ``gguf`` package, de-quantized)."""

from __future__ import annotations

import functools
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from lcmesh.llm.model_cache import offline_env


def unpack_gguf(gguf: Path, target: Path) -> None:
    """Write config, weights (float32, as de-quantized) and tokenizer of ``gguf`` into ``target``."""
    offline_env()
    from transformers import AutoModelForCausalLM, AutoTokenizer
    from transformers.utils import logging as hf_logging

    hf_logging.disable_progress_bar()
    folder, name = str(gguf.parent), gguf.name
    with _parsed_once():
        tokenizer = AutoTokenizer.from_pretrained(folder, gguf_file=name)
        model = AutoModelForCausalLM.from_pretrained(folder, gguf_file=name)
    # the weights are plain tensors now; drop the GGUF quantizer so the folder is an ordinary checkpoint
    model.hf_quantizer = None
    if hasattr(model.config, "quantization_config"):
        del model.config.quantization_config
    model.config._name_or_path = gguf.stem
    model.save_pretrained(target)
    tokenizer.save_pretrained(target)


@contextmanager
def _parsed_once() -> Iterator[None]:
    """Within: transformers reads a GGUF once, not once per caller, and builds its tensor-name map once.

    Loading a tokenizer and a model from one GGUF parses the file three times (tokenizer, config, weights:
    about 10 s each on 2 cores, mostly the 49k-string vocabulary) and rebuilds gguf's name map for every
    module, around a 2.5 s de-quantization. The reader is read-only and the name map a pure function, so
    both are shared while the unpack runs (the folder written is byte for byte the same); then the
    originals are back.
    """
    import gguf  # transformers imports GGUFReader and get_tensor_name_map from the package at each call

    reader, name_map = gguf.GGUFReader, gguf.get_tensor_name_map
    gguf.GGUFReader = functools.lru_cache(maxsize=2)(reader)
    gguf.get_tensor_name_map = functools.lru_cache(maxsize=None)(name_map)
    try:
        yield
    finally:
        gguf.GGUFReader, gguf.get_tensor_name_map = reader, name_map


def gguf_load_seconds(gguf: Path) -> float:
    """Wall time to load the model straight from the GGUF (de-quantizing), for the cache benchmark."""
    import time

    offline_env()
    from transformers import AutoModelForCausalLM, AutoTokenizer

    t0 = time.perf_counter()
    AutoTokenizer.from_pretrained(str(gguf.parent), gguf_file=gguf.name)
    AutoModelForCausalLM.from_pretrained(str(gguf.parent), gguf_file=gguf.name)
    return time.perf_counter() - t0

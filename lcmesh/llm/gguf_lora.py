"""A peft LoRA folder as a GGUF LoRA adapter for llama.cpp, converted once into the model cache.

peft keeps ``lora_A`` (r x in) and ``lora_B`` (out x r) per projection in transformers' layout. llama.cpp's
GGUF stores the query and key projections with their rows permuted for its rotary kernel (the converter
that made the shipped file did that; ``transformers`` undoes it when it reads a GGUF), so ``lora_B`` of
those two gets the same row permutation; ``lora_A`` acts on the input side and stays. The scale is
llama.cpp's ``alpha / r``, as peft's. The conversion is checked against the transformers model with
the adapter merged (tests/llm/test_llama_runtime.py: same greedy answers, logits within tolerance).
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from pathlib import Path

import numpy as np

from lcmesh.llm.model_cache import models_dir

ARTIFACTS = Path(__file__).resolve().parents[1] / "artifacts"
PACKAGED = {"explain": ARTIFACTS / "llm", "control": ARTIFACTS / "llm-control", "planner": ARTIFACTS / "llm-planner"}
PROJECTIONS = {"q_proj": "attn_q", "k_proj": "attn_k", "v_proj": "attn_v", "o_proj": "attn_output",
               "gate_proj": "ffn_gate", "up_proj": "ffn_up", "down_proj": "ffn_down"}  # fmt: skip
N_HEAD, N_HEAD_KV = 9, 3  # SmolLM2-135M


def resolve_folder(spec: str | None, kind: str) -> Path | None:
    """``'default'`` -> the packaged adapter of ``kind`` if one was trained; ``'none'``/None -> none; else a folder."""
    if spec in (None, "", "none"):
        return None
    if spec == "default":
        folder = PACKAGED[kind]
        return folder if (folder / "adapter_config.json").is_file() else None
    folder = Path(spec).expanduser()
    if not (folder / "adapter_config.json").is_file():
        raise FileNotFoundError(f"`adapter` {spec!r} is not a LoRA adapter folder (no adapter_config.json)")
    return folder


def adapter_id(folder: Path | None) -> str:
    if folder is None:
        return "base"
    try:
        manifest = json.loads((folder / "manifest.json").read_text())
        return str(manifest.get("adapter_id", folder.name))
    except (OSError, json.JSONDecodeError):
        return folder.name


def lora_for(spec: str | None, kind: str) -> tuple[Path | None, str]:
    """The GGUF LoRA file for an adapter spec (converted on first use) and the adapter's id."""
    folder = resolve_folder(spec, kind)
    if folder is None:
        return None, "base"
    return cached_gguf(folder), adapter_id(folder)


def cached_gguf(folder: Path) -> Path:
    weights = folder / "adapter_model.safetensors"
    key = hashlib.sha256(weights.read_bytes() + (folder / "adapter_config.json").read_bytes()).hexdigest()[:12]
    target = models_dir() / f"lora-{folder.name}-{key}.gguf"
    if not target.is_file():
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}-", dir=target.parent)
        os.close(fd)
        try:
            convert(folder, Path(tmp))
            os.replace(tmp, target)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
    return target


def permute_rows(weight: np.ndarray, n_head: int) -> np.ndarray:
    """llama.cpp's rotary row order for a query/key projection's output rows (what its converter applies)."""
    out = weight.shape[0]
    return weight.reshape(n_head, 2, out // n_head // 2, *weight.shape[1:]).swapaxes(1, 2).reshape(weight.shape)


def convert(folder: Path, target: Path) -> Path:
    """Write ``folder``'s peft LoRA as a GGUF LoRA adapter at ``target``."""
    import gguf
    from safetensors.torch import load_file

    config = json.loads((folder / "adapter_config.json").read_text())
    if config.get("use_dora") or config.get("use_rslora"):
        raise ValueError(f"{folder}: DoRA and rsLoRA adapters have no GGUF LoRA form")
    tensors = {k: v.float().numpy() for k, v in load_file(str(folder / "adapter_model.safetensors")).items()}
    writer = gguf.GGUFWriter(str(target), "llama")
    writer.add_string("general.type", "adapter")
    writer.add_string("adapter.type", "lora")
    writer.add_float32("adapter.lora.alpha", float(config["lora_alpha"]))
    written = 0
    for key in sorted(tensors):
        if ".lora_A." not in key:
            continue
        a = tensors[key].astype(np.float32)
        b = tensors[key.replace(".lora_A.", ".lora_B.")].astype(np.float32)
        parts = key.split(".")
        layer = int(parts[parts.index("layers") + 1])
        proj = next(p for p in parts if p in PROJECTIONS)
        if proj == "q_proj":
            b = permute_rows(b, N_HEAD)
        elif proj == "k_proj":
            b = permute_rows(b, N_HEAD_KV)
        name = f"blk.{layer}.{PROJECTIONS[proj]}.weight"
        writer.add_tensor(f"{name}.lora_a", np.ascontiguousarray(a))
        writer.add_tensor(f"{name}.lora_b", np.ascontiguousarray(b))
        written += 1
    if not written:
        raise ValueError(f"{folder}: no LoRA tensors found")
    writer.write_header_to_file()
    writer.write_kv_data_to_file()
    writer.write_tensors_to_file()
    writer.close()
    return target

"""A peft LoRA folder for llama.cpp: a GGUF LoRA adapter, or the model merged and requantized; cached once.

Two forms, chosen by how the adapter was trained (its manifest's ``config.quant``):

- trained on the unpacked base (``quant`` none: the shipped Q4_1 GGUF de-quantized, which is what
  llama.cpp computes with): a GGUF LoRA over the shipped file (:func:`convert`), small and exact;
- trained as QLoRA on an nf4 image of the base (the planner and explainer adapters): its corrections
  belong to that image, and over Q4_1 they drift (the planner lost 13 points of plan accuracy on its
  dev split). The adapter is merged into the nf4 image, as the transformers backend does, and the
  result written as a whole GGUF with the changed projections in Q8_0 (:func:`merge_to_gguf`).

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

QUANT_DTYPES = ("bfloat16", "float32")  # the compute dtypes QLoRA training loads the base in (hf.backend.DTYPES)

ARTIFACTS = Path(__file__).resolve().parents[1] / "artifacts"
PACKAGED = {"explain": ARTIFACTS / "llm", "explain-short": ARTIFACTS / "llm-short", "control": ARTIFACTS / "llm-control",
            "planner": ARTIFACTS / "llm-planner"}  # fmt: skip
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


# The adapter's manifest, read without torch: the llama.cpp runtime (the mesh's agents) needs these fields too.
def read_adapter_manifest(adapter: Path) -> dict | None:
    """The ``manifest.json`` that ``lcmesh distill llm`` wrote beside an adapter; None if absent or unreadable."""
    try:
        manifest = json.loads((Path(adapter) / "manifest.json").read_text())
    except (OSError, json.JSONDecodeError):
        return None
    return manifest if isinstance(manifest, dict) else None


def adapter_id(folder: Path | None) -> str:
    """The manifest's ``adapter_id`` (the folder's name without one; 'base' for no adapter)."""
    if folder is None:
        return "base"
    return str((read_adapter_manifest(folder) or {}).get("adapter_id", folder.name))


def trained_quant(folder: Path) -> str:
    """How the base was quantized when the adapter was trained (its manifest's ``config.quant``; 'none' if unknown)."""
    config = (read_adapter_manifest(folder) or {}).get("config")
    return str(config.get("quant", "none")) if isinstance(config, dict) else "none"


def adapter_quant_dtype(adapter: Path) -> str:
    """The dtype the base's weights were in when bitsandbytes quantized them for ``adapter``'s training: the training's
    compute dtype (the manifest's ``metrics.train.compute_dtype``, else ``config.compute_dtype``; bfloat16, the old
    default, when neither says)."""
    manifest = read_adapter_manifest(adapter) or {}
    train = (manifest.get("metrics") or {}).get("train") or {}
    config = manifest.get("config") or {}
    for value in (train.get("compute_dtype"), config.get("compute_dtype")):
        if value in QUANT_DTYPES:
            return str(value)
    return "bfloat16"


def runtime_files(spec: str | None, kind: str) -> tuple[Path | None, Path | None, str]:
    """(model GGUF or None for the shipped one, LoRA GGUF or None, adapter id) for llama.cpp."""
    folder = resolve_folder(spec, kind)
    if folder is None:
        return None, None, "base"
    if trained_quant(folder) == "nf4":
        return merged_gguf(folder), None, adapter_id(folder)
    return None, cached_gguf(folder), adapter_id(folder)


def _key(folder: Path) -> str:
    weights = folder / "adapter_model.safetensors"
    return hashlib.sha256(weights.read_bytes() + (folder / "adapter_config.json").read_bytes()).hexdigest()[:12]


def _cached(target: Path, write) -> Path:
    """``target``, written by ``write(tmp_path)`` first if absent (atomic: a crash leaves no half file)."""
    if not target.is_file():
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}-", dir=target.parent)
        os.close(fd)
        try:
            write(Path(tmp))
            os.replace(tmp, target)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
    return target


def merged_gguf(folder: Path) -> Path:
    dtype = adapter_quant_dtype(folder)  # part of the name: the nf4 image depends on it
    name = f"merged-{folder.name}-{_key(folder)}{'' if dtype == 'bfloat16' else '-' + dtype}.gguf"
    return _cached(models_dir() / name, lambda tmp: merge_to_gguf(folder, tmp))


def merge_to_gguf(folder: Path, target: Path) -> Path:
    """The shipped model with ``folder``'s adapter merged (into the nf4 image when it was trained on one), as one
    GGUF: the shipped file's metadata, tokenizer and unchanged tensors, the merged projections in Q8_0."""
    import gguf
    import torch
    from peft import PeftModel
    from transformers import AutoModelForCausalLM

    from lcmesh.llm.hf.backend import nf4_roundtrip
    from lcmesh.llm.model_cache import resolve_model, shipped_gguf

    model = AutoModelForCausalLM.from_pretrained(resolve_model("smollm2-135m-instruct"), dtype=torch.float32)
    if trained_quant(folder) == "nf4":
        nf4_roundtrip(model, dtype=adapter_quant_dtype(folder))
    model = PeftModel.from_pretrained(model, str(folder)).merge_and_unload().eval()
    hf = {}
    for i, layer in enumerate(model.model.layers):
        for proj, name in PROJECTIONS.items():
            module = getattr(layer.self_attn if proj.endswith(("q_proj", "k_proj", "v_proj", "o_proj")) else layer.mlp,
                             proj)  # fmt: skip
            w = module.weight.detach().float().numpy()
            if proj == "q_proj":
                w = permute_rows(w, N_HEAD)
            elif proj == "k_proj":
                w = permute_rows(w, N_HEAD_KV)
            hf[f"blk.{i}.{name}.weight"] = w
    reader = gguf.GGUFReader(shipped_gguf())
    writer = gguf.GGUFWriter(str(target), "llama")
    for name, fld in reader.fields.items():
        if name.startswith("GGUF.") or name == "general.architecture":
            continue
        vtype = fld.types[0]
        sub = fld.types[-1] if vtype == gguf.GGUFValueType.ARRAY else None
        value = fld.contents()
        if name == "general.file_type":
            value = int(gguf.LlamaFileType.MOSTLY_Q8_0)
        writer.add_key_value(name, value, vtype, sub_type=sub)
    for t in reader.tensors:
        if t.name in hf:
            writer.add_tensor(t.name, gguf.quants.quantize(hf[t.name], gguf.GGMLQuantizationType.Q8_0),
                              raw_dtype=gguf.GGMLQuantizationType.Q8_0)  # fmt: skip
        else:
            writer.add_tensor(t.name, t.data, raw_dtype=t.tensor_type)  # quantized data comes as (rows, bytes)
    writer.write_header_to_file()
    writer.write_kv_data_to_file()
    writer.write_tensors_to_file()
    writer.close()
    return target


def cached_gguf(folder: Path) -> Path:
    return _cached(models_dir() / f"lora-{folder.name}-{_key(folder)}.gguf", lambda tmp: convert(folder, tmp))


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

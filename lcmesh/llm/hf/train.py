"""QLoRA (nf4 base via bitsandbytes) or plain LoRA fine-tuning of a causal LM on (messages, target) pairs.

The loss is the cross-entropy of the target tokens only; the language-model head runs on those
positions only (the 49k-word head over every prompt token would cost as much as the whole rest of a
135M model). Batches hold samples of similar length; order, LoRA init and data are seeded, so the
same seed on the same machine gives the same adapter. bitsandbytes' nf4 kernels run on CPU.
"""

from __future__ import annotations

import math
import random
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from lcmesh.llm.model_cache import offline_env, quiet_libraries

offline_env()
quiet_libraries()

import torch  # noqa: E402
from transformers import AutoModelForCausalLM, AutoTokenizer  # noqa: E402

from lcmesh.llm.hf.backend import DTYPES  # noqa: E402

LORA_TARGETS = ("q_proj", "k_proj", "v_proj", "o_proj", "gate_proj", "up_proj", "down_proj")


@dataclass
class LoraTrainConfig:
    """Fine-tuning hyper-parameters (validated on construction)."""

    quant: str = "nf4"  # nf4: QLoRA on a 4-bit base; none: plain LoRA on the full-precision base
    compute_dtype: str = "auto"  # matmul dtype of the frozen base (LoRA weights stay float32); auto: fast_compute_dtype
    r: int = 8
    alpha: int = 16
    dropout: float = 0.0
    target_modules: tuple[str, ...] = LORA_TARGETS
    epochs: float = 2.0
    lr: float = 2e-3
    batch_size: int = 8  # at most this many samples per step ...
    batch_tokens: int = 2048  # ... and at most this many tokens (padded), so long explanations fit in memory
    warmup_frac: float = 0.05
    max_len: int = 2048
    seed: int = 0
    threads: int = 0
    init_adapter: str = ""  # continue from this LoRA adapter folder instead of fresh LoRA weights

    def __post_init__(self) -> None:
        if self.quant not in ("nf4", "none"):
            raise ValueError(f"`quant` must be 'nf4' or 'none', got {self.quant!r}")
        if self.compute_dtype == "auto":
            self.compute_dtype = fast_compute_dtype()
        if self.compute_dtype not in DTYPES:
            raise ValueError(f"`compute_dtype` must be one of {', '.join(DTYPES)}, got {self.compute_dtype!r}")
        for name in ("r", "alpha", "batch_size", "batch_tokens", "max_len"):
            if getattr(self, name) < 1:
                raise ValueError(f"`{name}` must be >= 1, got {getattr(self, name)}")
        if not (self.epochs > 0 and self.lr > 0):
            raise ValueError(f"`epochs` and `lr` must be > 0, got {self.epochs}, {self.lr}")


@dataclass
class TrainResult:
    """What a run did: per-step losses, token throughput, time."""

    losses: list[float] = field(default_factory=list)
    steps: int = 0
    tokens: int = 0
    target_tokens: int = 0
    seconds: float = 0.0
    truncated: int = 0

    @property
    def tokens_per_s(self) -> float:
        return self.tokens / self.seconds if self.seconds > 0 else 0.0


def encode(tokenizer, messages: Sequence[dict], target: str, max_len: int) -> tuple[list[int], int] | None:
    """(ids, n_prompt) for prompt + target + end-of-turn; None when longer than ``max_len``."""
    text = tokenizer.apply_chat_template(list(messages), add_generation_prompt=True, tokenize=False)
    prompt = tokenizer(text, add_special_tokens=False)["input_ids"]
    answer = tokenizer(target, add_special_tokens=False)["input_ids"] + [tokenizer.eos_token_id]
    ids = prompt + answer
    return (ids, len(prompt)) if len(ids) <= max_len else None


def fast_compute_dtype(cpuinfo: str | None = None) -> str:
    """bfloat16 where the CPU multiplies it natively (AVX512-BF16 or AMX) or a GPU trains, else float32: on an
    AVX2-only CPU bfloat16 matmuls fall back to a scalar path (no QLoRA step of 8 samples ended in 5 min here, against
    12 s in float32; docs/llm.md)."""
    if torch.cuda.is_available():
        return "bfloat16"
    if cpuinfo is None:
        try:
            cpuinfo = Path("/proc/cpuinfo").read_text()
        except OSError:
            cpuinfo = ""
    flags = set(cpuinfo.split())
    return "bfloat16" if flags & {"avx512_bf16", "amx_bf16"} else "float32"


def load_for_training(model_dir: Path, cfg: LoraTrainConfig):
    """The base model (nf4-quantized for QLoRA) wrapped with fresh LoRA adapters (or ``cfg.init_adapter``'s)."""
    from peft import LoraConfig, PeftModel, get_peft_model, prepare_model_for_kbit_training

    dtype = DTYPES[cfg.compute_dtype]
    if cfg.quant == "nf4":
        from transformers import BitsAndBytesConfig

        quant = BitsAndBytesConfig(load_in_4bit=True, bnb_4bit_quant_type="nf4", bnb_4bit_compute_dtype=dtype)
        model = AutoModelForCausalLM.from_pretrained(model_dir, quantization_config=quant, dtype=dtype,
                                                     device_map=_device())  # fmt: skip
        model = prepare_model_for_kbit_training(model, use_gradient_checkpointing=False)
    else:
        model = AutoModelForCausalLM.from_pretrained(model_dir, dtype=dtype).to(_device())
    torch.manual_seed(cfg.seed)
    if cfg.init_adapter:
        model = PeftModel.from_pretrained(model, cfg.init_adapter, is_trainable=True)
    else:
        lora = LoraConfig(r=cfg.r, lora_alpha=cfg.alpha, lora_dropout=cfg.dropout,
                          target_modules=list(cfg.target_modules), task_type="CAUSAL_LM")  # fmt: skip
        model = get_peft_model(model, lora)
    for p in model.parameters():  # LoRA weights train in float32 whatever the base runs in
        if p.requires_grad:
            p.data = p.data.float()
    return model


def _device() -> str:
    return "cuda" if torch.cuda.is_available() else "cpu"


def train_lora(
    model_dir: Path,
    samples: Sequence[tuple[Sequence[dict], str]],
    cfg: LoraTrainConfig,
    on_step: Callable[[int, int, float], None] | None = None,
):
    """Fine-tune on ``(messages, target)`` pairs; returns (peft model, tokenizer, TrainResult)."""
    if cfg.threads > 0:
        torch.set_num_threads(cfg.threads)
    random.seed(cfg.seed)
    torch.manual_seed(cfg.seed)
    tokenizer = AutoTokenizer.from_pretrained(model_dir)
    encoded = [encode(tokenizer, m, t, cfg.max_len) for m, t in samples]
    result = TrainResult(truncated=sum(e is None for e in encoded))
    encoded = [e for e in encoded if e is not None]
    if not encoded:
        raise ValueError(f"no sample fits in `max_len` = {cfg.max_len} tokens")
    model = load_for_training(model_dir, cfg)
    model.train()
    rng = random.Random(cfg.seed)
    n_epochs = math.ceil(cfg.epochs)
    schedule = [b for e in range(n_epochs) for b in _batches(encoded, cfg.batch_size, cfg.batch_tokens, rng)]
    schedule = schedule[: max(1, round(len(schedule) * cfg.epochs / n_epochs))]
    params = [p for p in model.parameters() if p.requires_grad]
    opt = torch.optim.AdamW(params, lr=cfg.lr, weight_decay=0.0)
    warmup = max(1, int(cfg.warmup_frac * len(schedule)))

    def lr_at(i: int) -> float:  # linear warmup, cosine decay
        return cfg.lr * min(1.0, (i + 1) / warmup) * 0.5 * (1 + math.cos(math.pi * i / len(schedule)))

    body, head = model.get_base_model().model, model.get_base_model().lm_head
    device = next(params.__iter__()).device
    t0 = time.perf_counter()
    for i, batch in enumerate(schedule):
        for group in opt.param_groups:
            group["lr"] = lr_at(i)
        ids, mask, labels = _collate(batch, tokenizer.pad_token_id or tokenizer.eos_token_id, device)
        hidden = body(input_ids=ids, attention_mask=mask).last_hidden_state[:, :-1]
        target = labels[:, 1:]
        keep = target != -100
        logits = head(hidden[keep].to(head.weight.dtype)).float()
        loss = torch.nn.functional.cross_entropy(logits, target[keep])
        loss.backward()
        torch.nn.utils.clip_grad_norm_(params, 1.0)
        opt.step()
        opt.zero_grad(set_to_none=True)
        result.losses.append(float(loss.detach()))
        result.tokens += int(mask.sum())
        result.target_tokens += int(keep.sum())
        result.steps += 1
        if on_step is not None:
            on_step(i + 1, len(schedule), result.losses[-1])
    result.seconds = time.perf_counter() - t0
    model.eval()
    return model, tokenizer, result


def _batches(encoded: list[tuple[list[int], int]], batch_size: int, batch_tokens: int, rng: random.Random) -> list:
    """Shuffled batches of similar-length samples (sorted within windows), within both size limits."""
    order = list(range(len(encoded)))
    rng.shuffle(order)
    window = batch_size * 32
    batches: list[list] = []
    for start in range(0, len(order), window):
        current: list = []
        for k in sorted(order[start : start + window], key=lambda k: len(encoded[k][0])):
            width = len(encoded[k][0])  # sorted: the newest sample is the widest
            if current and (len(current) >= batch_size or (len(current) + 1) * width > batch_tokens):
                batches.append(current)
                current = []
            current.append(encoded[k])
        if current:
            batches.append(current)
    rng.shuffle(batches)
    return batches


def _collate(batch: list[tuple[list[int], int]], pad_id: int, device) -> tuple[torch.Tensor, ...]:
    width = max(len(ids) for ids, _ in batch)
    ids = torch.full((len(batch), width), pad_id, dtype=torch.long)
    mask = torch.zeros((len(batch), width), dtype=torch.long)
    labels = torch.full((len(batch), width), -100, dtype=torch.long)
    for row, (seq, n_prompt) in enumerate(batch):
        ids[row, : len(seq)] = torch.tensor(seq)
        mask[row, : len(seq)] = 1
        labels[row, n_prompt : len(seq)] = torch.tensor(seq[n_prompt:])
    return ids.to(device), mask.to(device), labels.to(device)


def step_log(path: Path, say: Callable[[str, int, int], None], label: str) -> Callable[[int, int, float], None]:
    """An ``on_step`` for ``train_lora`` that appends each step's loss to `path` (JSON lines) and reports it."""
    import json

    path.write_text("")
    t0 = time.perf_counter()

    def on_step(i: int, n: int, loss: float) -> None:
        with path.open("a") as log:
            log.write(json.dumps({"step": i, "of": n, "loss": round(loss, 5),
                                  "elapsed_s": round(time.perf_counter() - t0, 1)}) + "\n")  # fmt: skip
        say(f"{label} loss {loss:.3f}", i, n)

    return on_step


def save_adapter(model, out_dir: Path) -> Path:
    """Write ``adapter_config.json`` and the LoRA weights in bfloat16 (half the bytes, ample precision)."""
    from peft import get_peft_model_state_dict
    from safetensors.torch import save_file

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().to(torch.bfloat16).contiguous().cpu() for k, v in get_peft_model_state_dict(model).items()}
    save_file(state, str(out_dir / "adapter_model.safetensors"))
    config = model.peft_config["default"]
    config.base_model_name_or_path = None
    config.save_pretrained(str(out_dir))
    return out_dir / "adapter_model.safetensors"


def adapter_state(model) -> dict[str, torch.Tensor]:
    """The LoRA weights (for comparing runs)."""
    from peft import get_peft_model_state_dict

    return {k: v.detach().clone() for k, v in get_peft_model_state_dict(model).items()}

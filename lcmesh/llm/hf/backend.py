"""The local backend: a transformers causal LM (SmolLM2-135M-Instruct by default) on this machine's CPU or GPU.

Batches are decoded greedily in one ``generate`` call with left padding (the controller's cabinets).
A conversation that comes with a draft (the explainer passes the deterministic rendering) is decoded
draft-verified: the model scores a run of draft tokens in one forward pass and keeps the prefix it
would have produced itself plus its own next token, then looks the last tokens up in the draft (and
the prompt) again. The text is the model's greedy text; only the number of forward passes changes.
A LoRA adapter is merged into the weights at load, so inference pays nothing for it.
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from pathlib import Path

from lcmesh.llm.base import Conversation, Generation, LlmBackendSettings
from lcmesh.llm.model_cache import offline_env, quiet_libraries, resolve_model

offline_env()
quiet_libraries()

import numpy as np  # noqa: E402
import torch  # noqa: E402
from transformers import AutoModelForCausalLM, AutoTokenizer, StoppingCriteria, StoppingCriteriaList  # noqa: E402
from transformers.utils import logging as hf_logging  # noqa: E402

hf_logging.disable_progress_bar()
hf_logging.set_verbosity_error()

PACKAGED_ADAPTER = Path(__file__).resolve().parents[2] / "artifacts" / "llm"
DTYPES = {"bfloat16": torch.bfloat16, "float32": torch.float32}
LOOKUP_NGRAM = 3  # match the last up-to-3 generated tokens in the draft
LOOKUP_SPAN_FIRST = 4096  # draft tokens read with the prompt in the first pass (all of an explanation)
LOOKUP_SPAN_MAX = 512  # later passes: twice the last run while the model agrees, at most this ...
LOOKUP_SPAN_MIN = 16  # ... and after a miss, twice the agreed run, at least this


def resolve_adapter(spec: str | None) -> Path | None:
    """``'default'`` -> the packaged adapter if one was trained, ``'none'``/None -> base model, else a folder."""
    if spec in (None, "", "none"):
        return None
    if spec == "default":
        return PACKAGED_ADAPTER if (PACKAGED_ADAPTER / "adapter_config.json").is_file() else None
    path = Path(spec).expanduser()
    if not (path / "adapter_config.json").is_file():
        raise FileNotFoundError(f"`adapter` {spec!r} is not a LoRA adapter folder (no adapter_config.json)")
    return path


def read_adapter_manifest(adapter: Path) -> dict | None:
    """The ``manifest.json`` that ``lcmesh distill llm`` wrote beside an adapter; None if absent or unreadable."""
    try:
        manifest = json.loads((Path(adapter) / "manifest.json").read_text())
    except (OSError, json.JSONDecodeError):
        return None
    return manifest if isinstance(manifest, dict) else None


def adapter_base_quant(adapter: Path) -> str:
    """How the base was quantized when ``adapter`` was trained (its manifest's ``config.quant``; 'none' if unknown)."""
    config = (read_adapter_manifest(adapter) or {}).get("config")
    return str(config.get("quant", "none")) if isinstance(config, dict) else "none"


def nf4_roundtrip(model, blocksize: int = 64) -> int:
    """Give every decoder projection the weights of its nf4 image (bfloat16, quantized, dequantized); the count.

    A QLoRA adapter learned its corrections against the nf4 base; merged into the original weights it
    drifts (the distilled explanations lost their structure at a handful of tokens). Merged into this
    image, the model is the one that was trained, and it still runs at bfloat16 speed.
    """
    import bitsandbytes.functional as bnbf

    n = 0
    for layer in model.model.layers:
        for module in layer.modules():
            if isinstance(module, torch.nn.Linear):
                weight = module.weight.data.to(torch.bfloat16)
                packed, state = bnbf.quantize_4bit(weight, blocksize=blocksize, quant_type="nf4")
                module.weight.data = bnbf.dequantize_4bit(packed, state).to(module.weight.dtype)
                n += 1
    return n


class HfBackend:
    """Greedy chat completions from a local model folder, with an optional merged LoRA adapter."""

    name = "local"

    def __init__(self, model_dir: Path, *, adapter: Path | None = None, dtype: str = "bfloat16", threads: int = 0):
        if threads > 0:
            torch.set_num_threads(threads)
        t0 = time.perf_counter()
        self.model_dir, self.adapter = Path(model_dir), (Path(adapter) if adapter is not None else None)
        self.tokenizer = AutoTokenizer.from_pretrained(self.model_dir)
        self.tokenizer.padding_side = "left"
        if self.tokenizer.pad_token is None:
            self.tokenizer.pad_token = self.tokenizer.eos_token
        model = AutoModelForCausalLM.from_pretrained(self.model_dir, dtype=torch.float32)
        self.base_quant = adapter_base_quant(self.adapter) if self.adapter is not None else "none"
        if self.base_quant == "nf4":
            nf4_roundtrip(model)
        if adapter is not None:
            from peft import PeftModel

            model = PeftModel.from_pretrained(model, str(adapter)).merge_and_unload()
        self.model = model.to(DTYPES[dtype]).eval()
        self.load_seconds = time.perf_counter() - t0
        self.model_id = f"{_model_name(self.model_dir)}+{_adapter_name(self.adapter)}"
        self.last_forward_passes = 0

    @classmethod
    def from_settings(cls, settings: LlmBackendSettings) -> "HfBackend":
        return cls(
            resolve_model(settings.model), adapter=resolve_adapter(settings.adapter), dtype=settings.dtype,
            threads=settings.threads,
        )  # fmt: skip

    def prompt_ids(self, conversation: Conversation) -> list[int]:
        """Token ids of the chat-formatted conversation, ready for the assistant's answer."""
        text = self.tokenizer.apply_chat_template(list(conversation), add_generation_prompt=True, tokenize=False)
        return self.tokenizer(text, add_special_tokens=False)["input_ids"]

    @torch.inference_mode()
    def chat(
        self,
        conversations: Sequence[Conversation],
        *,
        max_new_tokens: int,
        stop: Sequence[str] = (),
        drafts: Sequence[str | None] | None = None,
        time_budget_s: float | None = None,
    ) -> list[Generation]:
        if not conversations:
            return []
        if drafts is not None and any(d for d in drafts):
            return [self._one_with_draft(c, d, max_new_tokens, stop, time_budget_s)
                    for c, d in zip(conversations, drafts)]  # fmt: skip
        return self._batch(conversations, max_new_tokens, stop, time_budget_s)

    def _batch(self, conversations: Sequence[Conversation], max_new_tokens: int, stop: Sequence[str],
               time_budget_s: float | None = None) -> list[Generation]:  # fmt: skip
        t0 = time.perf_counter()
        ids = [self.prompt_ids(c) for c in conversations]
        batch = self.tokenizer.pad({"input_ids": ids}, padding=True, return_tensors="pt")
        width = batch["input_ids"].shape[1]
        criteria = StoppingCriteriaList([_StopStrings(self.tokenizer, stop, width)]) if stop else None
        out = self.model.generate(
            **batch, max_new_tokens=max_new_tokens, do_sample=False, stopping_criteria=criteria,
            pad_token_id=self.tokenizer.pad_token_id, eos_token_id=self.tokenizer.eos_token_id,
            temperature=None, top_p=None, top_k=None, max_time=time_budget_s,
        )  # fmt: skip
        seconds = time.perf_counter() - t0
        self.last_forward_passes = out.shape[1] - width
        timed_out = time_budget_s is not None and seconds >= time_budget_s
        results = []
        for row, prompt in zip(out[:, width:].tolist(), ids):
            results.append(self._finish(row, len(prompt), max_new_tokens, stop, seconds, timed_out))
        return results

    def _finish(self, row: list[int], n_prompt: int, max_new_tokens: int, stop: Sequence[str], seconds: float,
                timed_out: bool = False):  # fmt: skip
        eos, pad = self.tokenizer.eos_token_id, self.tokenizer.pad_token_id
        if eos in row:
            row, ended = row[: row.index(eos)], True
        else:
            while row and row[-1] == pad:
                row = row[:-1]
            ended = False
        text = self.tokenizer.decode(row, skip_special_tokens=True)
        cut = _cut_at_stop(text, stop)
        if cut is not None:
            text, ended = cut, True
        if ended:
            reason = "stop"
        else:
            reason = "timeout" if timed_out else ("stop" if len(row) < max_new_tokens else "length")
        return Generation(text, n_prompt, len(row), seconds, reason)

    def _one_with_draft(self, conversation: Conversation, draft: str | None, max_new_tokens: int, stop: Sequence[str],
                        time_budget_s: float | None = None):  # fmt: skip
        t0 = time.perf_counter()
        prompt = self.prompt_ids(conversation)
        draft_ids = self.tokenizer(draft, add_special_tokens=False)["input_ids"] if draft else []
        deadline = None if time_budget_s is None else t0 + time_budget_s
        new, passes, timed_out = draft_verified_greedy(self.model, prompt, draft_ids, max_new_tokens,
                                                       self.tokenizer.eos_token_id, self._stop_check(stop),
                                                       deadline)  # fmt: skip
        self.last_forward_passes = passes
        seconds = time.perf_counter() - t0
        return self._finish(new, len(prompt), max_new_tokens, stop, seconds, timed_out)

    def _stop_check(self, stop: Sequence[str]):
        if not stop:
            return None
        return lambda ids: _cut_at_stop(self.tokenizer.decode(ids[-24:], skip_special_tokens=True), stop) is not None


def draft_verified_greedy(
    model, prompt: list[int], draft: list[int], max_new_tokens: int, eos: int, stopped=None,
    deadline: float | None = None,
):  # fmt: skip
    """Greedy decoding that verifies runs of ``draft`` (or prompt) tokens in one pass each.

    The first pass reads the prompt and the draft together, so a model that reproduces its draft
    needs one pass. Later runs double while the model agrees and shrink to twice the agreed length
    after a miss. ``deadline`` (a ``time.perf_counter()`` value) ends decoding early: a pass expected
    to end after it is not started. Returns (ids, forward passes, whether time ran out).
    """
    from transformers import DynamicCache

    cache = DynamicCache()
    generated: list[int] = []
    passes, sources, span, timings = 0, (draft, prompt), LOOKUP_SPAN_FIRST, []
    feed, out_of_time = list(prompt), False
    while len(generated) < max_new_tokens and not (generated and generated[-1] == eos):
        if stopped and generated and stopped(generated):
            break
        room = max_new_tokens - len(generated)
        if not generated:  # the first pass proposes the draft's opening
            proposal = draft[: min(span, room - 1)]
        else:
            proposal = _lookup(generated, sources, min(span, room - 1)) if room > 1 else []
        n = len(feed) + len(proposal)
        t0 = time.perf_counter()
        if passes and deadline is not None and t0 + _pass_seconds(timings, n) > deadline:
            out_of_time = True  # this pass would end after the deadline: stop now, not late
            break
        logits = model(input_ids=torch.tensor([feed + proposal]), past_key_values=cache, use_cache=True,
                       logits_to_keep=len(proposal) + 1).logits  # the vocabulary head on the verified positions only
        predicted = logits[0].argmax(-1).tolist()
        timings.append((n, time.perf_counter() - t0))
        passes += 1
        accepted = 0
        while accepted < len(proposal) and proposal[accepted] == predicted[accepted]:
            accepted += 1
        generated += proposal[:accepted] + [predicted[accepted]]
        cache.crop(len(prompt) + len(generated) - 1 - cache.get_seq_length())  # negative: drop rejected tokens
        feed = [generated[-1]]
        if proposal:
            full = accepted == len(proposal)
            span = min(LOOKUP_SPAN_MAX, 2 * span if full else max(LOOKUP_SPAN_MIN, 2 * accepted))
        if eos in generated:
            generated = generated[: generated.index(eos) + 1]
    return generated[:max_new_tokens], passes, out_of_time


def _pass_seconds(timings: list[tuple[int, float]], n: int) -> float:
    """The expected seconds of a forward pass over ``n`` new tokens: a line through the recent passes' timings."""
    recent = timings[-8:]
    sizes = {k for k, _ in recent}
    if len(sizes) < 2:  # one size seen: proportional to it
        k, seconds = recent[-1]
        return seconds * n / k
    slope, intercept = np.polyfit([k for k, _ in recent], [t for _, t in recent], 1)
    return max(0.0, float(intercept + slope * n))


def _lookup(generated: list[int], sources: Sequence[list[int]], span: int) -> list[int]:
    """The tokens following the latest occurrence of the generated tail in a source (longest tail first)."""
    if span <= 0:
        return []
    for n in range(min(LOOKUP_NGRAM, len(generated)), 0, -1):
        tail = generated[-n:]
        for source in sources:
            for start in range(len(source) - n, -1, -1):
                if source[start : start + n] == tail and start + n < len(source):
                    return source[start + n : start + n + span]
    return []


class _StopStrings(StoppingCriteria):
    """Per-row stop when the decoded new text contains a stop string (HF marks the row finished)."""

    def __init__(self, tokenizer, stop: Sequence[str], prompt_width: int):
        self.tokenizer, self.stop, self.width = tokenizer, tuple(stop), prompt_width

    def __call__(self, input_ids: torch.Tensor, scores, **kwargs) -> torch.Tensor:
        tails = self.tokenizer.batch_decode(input_ids[:, self.width :][:, -24:], skip_special_tokens=True)
        return torch.tensor([any(s in t for s in self.stop) for t in tails], dtype=torch.bool)


def _cut_at_stop(text: str, stop: Sequence[str]) -> str | None:
    hits = [text.index(s) + len(s) for s in stop if s in text]
    return text[: min(hits)] if hits else None


def _model_name(model_dir: Path) -> str:
    try:
        return json.loads((model_dir / "config.json").read_text()).get("_name_or_path") or model_dir.name
    except (OSError, json.JSONDecodeError):
        return model_dir.name


def _adapter_name(adapter: Path | None) -> str:
    if adapter is None:
        return "base"
    return str((read_adapter_manifest(adapter) or {}).get("adapter_id", adapter.name))

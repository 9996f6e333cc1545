"""The batched decoder (``lcmesh.llm.batch_decode``) against the sequential one, on the shipped model with the packaged
control adapter: the same answers for every cabinet and tower of lcopt-5, decision after decision along the Frontier
day (the cached prefixes reused, the plant line changed), in fewer llama.cpp passes."""

from __future__ import annotations

import numpy as np
import pytest

from lcmesh.llm.batch_decode import answer_steps, read_groups
from lcmesh.llm.choice import ChoiceDecoder
from lcmesh.llm.control_format import TOWER_FIELDS, cabinet_fields

DECISIONS = 3
PERIOD = 20  # plant steps between decisions: five minutes of the day, the wet bulb and the hot water move


class Recorder:
    """A runtime that keeps what the LLM controller asks and answers nothing (the fallback steers the plant)."""

    model_id = runtime = "recorder"

    def __init__(self):
        self.asked: list[tuple[list, list]] = []

    def decide(self, prompts, fields, deadline=None):
        self.asked.append((list(prompts), list(fields)))
        return [None] * len(prompts)


class StubScorer:
    """Seeded logits and one token per character: ``answer_steps`` must choose what ``ChoiceDecoder`` chooses."""

    def __init__(self, seed: int):
        self.rng = np.random.default_rng(seed)

    def tokenize(self, text: str) -> list[int]:
        return [ord(c) for c in text]

    def logits_after(self, ids) -> np.ndarray:
        return self.rng.normal(size=256).astype(np.float32)


@pytest.fixture(scope="module")
def decisions(lcopt5):
    """The (prompts, fields) of the LLM controller's first decisions along the Frontier day, as it builds them."""
    from lcmesh.llm.controller import LlmController
    from lcmesh.twin.controllers import Observation
    from lcmesh.twin.plant import Plant
    from lcmesh.twin.traces import FRONTIER_DAY, load_trace

    trace, recorder = load_trace(FRONTIER_DAY, lcopt5), Recorder()
    ctl = LlmController(lcopt5, backend=recorder, fallback="g36", period_steps=PERIOD, clock=lambda: 0.0)
    power = np.zeros(lcopt5.n_blade_groups)
    with Plant(lcopt5) as plant:
        out = plant.out
        for k in range(PERIOD * (DECISIONS - 1) + 1):
            wet_bulb = float(trace.wet_bulb_k[k])
            action = ctl.act(Observation(out, wet_bulb, trace.blade_power_w(k, out=power), 15.0 * k))
            out = plant.step(power, wet_bulb, action)
    return recorder.asked


class PassClock:
    """Counts llama.cpp's ``llama_decode`` calls, both paths' (the plant's forward passes); as a clock, each costs
    ``PASS_S``: budgets then depend on passes, not on how busy the machine is."""

    PASS_S = 1 / 64  # a power of two: sums of passes are exact, a deadline of n passes is met at the n-th

    def __init__(self, decode):
        self.decode, self.calls = decode, 0

    def __call__(self) -> float:
        return self.calls * self.PASS_S

    def counted(self, ctx, batch):
        self.calls += 1
        return self.decode(ctx, batch)


@pytest.fixture(scope="module")
def llama():
    """The LLM controller's runtime (one thread) on a :class:`PassClock`."""
    llama_cpp = pytest.importorskip("llama_cpp.llama_cpp")
    from lcmesh.llm.controller import make_control_backend

    backend, clock = make_control_backend("default", threads=1), PassClock(llama_cpp.llama_decode)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(llama_cpp, "llama_decode", clock.counted)
        yield backend.with_clock(clock), clock
    backend.close()


@pytest.fixture(scope="module")
def runs(llama, decisions):
    """Each decision answered one prompt after another, then batched: (answers, llama_decode calls, passes)."""
    backend, clock = llama
    out = []
    for prompts, fields in decisions:
        row = {}
        for mode, batched in (("sequential", False), ("batched", True)):
            before = clock.calls
            answers = backend.decide(prompts, fields, batched=batched)
            row[mode] = (answers, clock.calls - before, backend.last_forward_passes)
        out.append(row)
    return out


def test_the_decisions_are_the_controllers_and_their_plant_line_changes(decisions):
    assert len(decisions) == DECISIONS
    for prompts, fields in decisions:
        assert len(prompts) == 5 + 2 and list(fields) == [cabinet_fields(3)] * 5 + [TOWER_FIELDS] * 2
    plant_lines = {prompts[0][1].splitlines()[0] for prompts, _ in decisions}
    assert len(plant_lines) == DECISIONS  # each decision reads its prefix again from where the cached one parts


def test_batched_answers_are_the_sequential_ones_for_every_cabinet_and_tower(runs):
    for row in runs:
        sequential, batched = row["sequential"][0], row["batched"][0]
        assert all(c is not None for c in sequential)
        # values, decided positions and tokens fed, digit for digit
        assert batched == sequential, [(s.values, b.values) for s, b in zip(sequential, batched)]


def test_the_batch_makes_fewer_llama_decode_calls_than_the_sequential_passes(runs):
    for row in runs:
        (_, seq_calls, seq_passes), (_, batch_calls, batch_passes) = row["sequential"], row["batched"]
        assert seq_calls == seq_passes == sum(c.passes for c in row["sequential"][0])  # one call, one pass
        assert batch_calls <= batch_passes < seq_passes  # a call over runs of sequence ids is one ubatch per run


def test_a_batch_runs_when_its_latest_time_fits_the_deadline_else_one_prompt_after_another(llama, decisions, runs):
    backend, clock = llama
    prompts, fields = decisions[0]
    batch_s = runs[-1]["batched"][1] * PassClock.PASS_S  # the latest batch of this shape, on the pass clock
    assert backend.decide(prompts, fields, clock() + batch_s) == runs[0]["batched"][0]
    assert backend.last_forward_passes < runs[0]["sequential"][2]  # batched
    # ten passes: not the batch; a cabinet (8 passes at most) fits, a second does not, each tower (a pass) still does
    answers = backend.decide(prompts, fields, clock() + 10 * PassClock.PASS_S)
    assert answers[0] is not None and answers[1:5] == [None] * 4 and None not in answers[5:]
    assert backend.last_forward_passes == sum(c.passes for c in answers if c is not None)


def test_answer_steps_choose_what_the_sequential_decoder_chooses():
    fields = cabinet_fields(3)
    for seed in range(20):
        want = ChoiceDecoder(StubScorer(seed)).decode([1, 2, 3], fields)
        decoder, scorer = ChoiceDecoder(StubScorer(seed)), StubScorer(seed)
        steps, fed = answer_steps(decoder, fields), []
        try:
            tokens = next(steps)
            while True:
                fed += tokens
                tokens = steps.send(scorer.logits_after(fed).__getitem__)
        except StopIteration as done:
            assert done.value == want


def test_one_token_reads_go_alone_and_equal_reads_together():
    assert read_groups({3: [7], 0: [1, 2], 1: [4], 2: [5, 6], 4: [8, 9, 9]}) == [[1], [3], [0, 2], [4]]
    assert read_groups({}) == []

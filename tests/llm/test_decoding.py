"""Draft-verified decoding returns the model's own greedy text, in fewer forward passes when the draft is right."""

from __future__ import annotations

import pytest

from lcmesh.llm.hf.backend import HfBackend


@pytest.fixture(scope="module")
def fp32_backend(local_model_dir):
    return HfBackend(local_model_dir, adapter=None, dtype="float32")


CONV = [{"role": "user", "content": "In one sentence, why do cooling towers use fans?"}]


def test_draft_does_not_change_the_greedy_text(fp32_backend):
    (plain,) = fp32_backend.chat([CONV], max_new_tokens=40)
    plain_passes = fp32_backend.last_forward_passes
    (exact,) = fp32_backend.chat([CONV], max_new_tokens=40, drafts=[plain.text])
    exact_passes = fp32_backend.last_forward_passes
    (wrong,) = fp32_backend.chat([CONV], max_new_tokens=40, drafts=["Fans are loud and tall towers are blue."])
    assert exact.text == plain.text
    assert wrong.text == plain.text
    assert exact_passes <= 2 < plain_passes  # the prompt and the whole draft in one pass (+ its end, if retokenized)
    assert exact.new_tokens == plain.new_tokens

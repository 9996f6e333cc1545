"""The llama.cpp runtime against transformers on the same weights: template, tokens, LoRA, grammar, budgets."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lcmesh.llm.choice import ChoiceDecoder, HfScorer
from lcmesh.llm.control_format import (
    CABINET_HEAD,
    TOWER_FIELDS,
    TOWER_HEAD,
    allowed_next,
    answer_text,
    cabinet_answer,
    cabinet_decision,
    cabinet_fields,
    cabinet_prompt,
    parse_values,
    tower_prompt,
)  # fmt: skip
from lcmesh.llm.io_format import CabinetView, TowerView
from lcmesh.llm.llama_backend import chatml

VIEWS = [CabinetView((30.1, 31.2, 29.0), (30.1, 31.2, 29.0), (40.0, 45.0, 38.0), 27.2, 25.0, 18.3),
         CabinetView((36.4, 38.9, 33.0), (36.4, 38.9, 33.0), (62.0, 70.0, 55.0), 30.5, 29.1, 24.0)]  # fmt: skip


@pytest.fixture(scope="module")
def tokenizer(local_model_dir):
    from transformers import AutoTokenizer

    return AutoTokenizer.from_pretrained(local_model_dir)


def test_chatml_is_smollm2s_template_and_both_runtimes_tokenize_alike(tokenizer, llama_base):
    for conv in ([{"role": "user", "content": "What is a cooling tower?"}],
                 [{"role": "system", "content": "Plan tools."}, {"role": "user", "content": "hottest cabinet?"}]):
        text = chatml(conv)
        assert text == tokenizer.apply_chat_template(conv, add_generation_prompt=True, tokenize=False)
        assert llama_base.scorer.tokenize(text) == tokenizer(text, add_special_tokens=False)["input_ids"]


def test_the_gguf_lora_matches_the_adapter_merged_in_transformers(tokenizer, local_model_dir, control_backend):
    import torch
    from peft import PeftModel
    from transformers import AutoModelForCausalLM

    from lcmesh.llm.gguf_lora import PACKAGED

    model = AutoModelForCausalLM.from_pretrained(local_model_dir, dtype=torch.float32)
    merged = PeftModel.from_pretrained(model, str(PACKAGED["control"])).merge_and_unload().eval()
    hf, fields = ChoiceDecoder(HfScorer(merged, tokenizer)), cabinet_fields(3)
    exact = 0
    for view in VIEWS:
        prompt = cabinet_prompt(view)
        ids = hf.prompt_ids(CABINET_HEAD, prompt[len(CABINET_HEAD):])
        a, b = HfScorer(merged, tokenizer).logits_after(ids), control_backend.scorer.logits_after(ids)
        assert np.corrcoef(a, b)[0, 1] > 0.99  # llama.cpp quantizes activations; the adapter's effect is the same
        # the same answer, but where the two runtimes part on a close call of one decided digit (the last digit of a
        # field: 1 K or 0.5 K of supply, 1 psi, one valve weight)
        got, want = control_backend.decoder.decode(ids, fields).values, hf.decode(ids, fields).values
        assert all(abs(float(x) - float(y)) <= 1.0 + 1e-9 for x, y in zip(got, want)), (got, want)
        exact += got == want
    assert exact >= len(VIEWS) - 1  # a wrong conversion (rotary rows, scale) moves whole fields, on every view


def test_the_answer_grammar_only_admits_allowed_values():
    fields = cabinet_fields(3)
    assert allowed_next(fields[0].values, "") == ["2", "3", "4"]
    assert allowed_next(fields[0].values, "4") == ["0"] and allowed_next(fields[0].values, "40") == ["."]
    assert allowed_next(fields[1].values, "3") == [str(d) for d in range(9)]  # 30-38 psi
    values = cabinet_answer(300.15, 31 * 6894.757, [0.5, 0.3, 0.2])
    text = answer_text(fields, values)
    assert text == "S27.0 D31 V954" and parse_values(fields, text) == values  # weights: the largest branch is 9
    decision = cabinet_decision(values)
    assert decision.supply_temp_setpoint_k == pytest.approx(300.15) and sum(decision.valve_fractions) == pytest.approx(1)
    for bad in ("S41.0 D31 V953", "S27.0 D39 V953", "S27.0 D31 V95", "S27.3 D31 V953", "27.0 D31 V953"):
        assert parse_values(fields, bad) is None, bad


def test_decoding_under_the_grammar_always_yields_allowed_values(llama_base):
    """The base model knows nothing of the protocol; the grammar still makes every answer valid."""
    decoder = llama_base.decoder
    for view in VIEWS:
        prompt = cabinet_prompt(view)
        choice = decoder.decode(decoder.prompt_ids(CABINET_HEAD, prompt[len(CABINET_HEAD):]), cabinet_fields(3))
        assert parse_values(cabinet_fields(3), answer_text(cabinet_fields(3), choice.values)) == choice.values
        assert choice.passes in (6, 8)  # 40.0 is fixed after its 4: one decided digit instead of three
    tower = TowerView(1, (45.0, 40.0), 25.1, 25.3, 30.2, 18.2, 4.0, 35.2)
    prompt = tower_prompt(tower)
    choice = decoder.decode(decoder.prompt_ids(TOWER_HEAD, prompt[len(TOWER_HEAD):]), TOWER_FIELDS)
    assert choice.values[0] in TOWER_FIELDS[0].values and choice.passes in (1, 2)  # 1.5 is fixed after its 1


def test_a_plan_decoded_under_the_json_schema_parses(llama_base):
    from lcmesh.assistant.plan import PLANNER_TOOLS, plan_messages, plan_schema

    for question in ("which cabinet is the hottest?", "how much energy did the pumps use in the last 2 hours?"):
        gen = llama_base.chat([plan_messages(question)], max_new_tokens=64, json_schema=plan_schema())[0]
        data = json.loads(gen.text)  # the base model, no planner adapter: the grammar alone makes it JSON of the shape
        assert isinstance(data, list) and all(set(item) == {"tool", "args"} for item in data), gen.text
        for item in data:  # and each tool's own argument names, with values of their kind (no stray key, no 0th)
            fields = PLANNER_TOOLS[item["tool"]].model_fields
            assert set(item["args"]) <= set(fields), gen.text
            assert all(v >= 1 for k, v in item["args"].items() if k in ("cabinet", "branch", "tower")), gen.text


def test_chat_keeps_its_time_budget_on_a_test_clock(llama_base):
    ticks = iter(np.arange(0.0, 100.0, 0.25))  # every reading of the clock: a quarter second later
    view = llama_base.with_clock(lambda: float(next(ticks)))
    gen = view.chat([[{"role": "user", "content": "Count from one to fifty."}]], max_new_tokens=64, time_budget_s=2.0)[0]
    assert gen.finish_reason == "timeout" and 0 < gen.new_tokens < 64


def test_chat_keeps_stop_strings_in_the_text(llama_base):
    gen = llama_base.chat([[{"role": "user", "content": "Reply with the JSON {\"a\": 1} and nothing else."}]],
                          max_new_tokens=24, stop=["}"])[0]  # fmt: skip
    assert gen.finish_reason == "stop" and gen.text.endswith("}")


def test_a_stale_estimate_that_refuses_is_measured_again(llama_base):
    """A pass-cost estimate from a cold or busy moment (here: 10 ms a token) refuses a 3 s call over a long prompt
    while it is fresh; once older than REFRESH_S it is re-measured with a short pass that fits, and the call runs (the
    clock is a test clock: only the estimate decides)."""
    from lcmesh.llm.budget import REFRESH_S, PassCost

    now = [1000.0]

    def clock() -> float:
        now[0] += 1e-4
        return now[0]

    view = llama_base.with_clock(clock)
    view.pass_cost = PassCost(0.01, measured_at=now[0])
    facts = " ".join(f"cabinet {i} supply {20 + i % 7}.5 C, dp {25 + i % 5} psi;" for i in range(35))
    ask = [[{"role": "user", "content": f"{facts} Say hello."}]]  # about 530 tokens: 5.3 s at 10 ms a token
    fresh = view.chat(ask, max_new_tokens=4, time_budget_s=3.0)[0]
    assert fresh.finish_reason == "timeout" and fresh.new_tokens == 0
    now[0] += REFRESH_S + 1
    again = view.chat(ask, max_new_tokens=4, time_budget_s=3.0)[0]
    assert again.new_tokens > 0 and view.pass_cost.seconds_per_token < 0.01, again


def test_the_backend_measures_a_pass_when_it_loads(llama_base):
    assert llama_base.pass_cost.measured_at is not None  # calibrated at load, not the prior

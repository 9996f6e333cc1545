"""The chat planner: rules on the questions issue 15 found misread, the generator's data, the LLM and OpenAI ones."""

from __future__ import annotations

import json
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest

from lcmesh.distill.planner_data import CATEGORIES, canonical_calls, generate, typo
from lcmesh.llm.base import LlmBackendSettings
from lcmesh.assistant.understand import LlmReader
from lcmesh.assistant.plan import (
    PLANNER_ADAPTER, PLANNER_TOOLS, OpenAiPlanner, PlanError, RulePlanner, ToolCall, make_planner,
    openai_tools, parse_plan, plan_text, same_plan,
)  # fmt: skip
from tests.llm.conftest import ForwardClock, frozen_clock


def calls_of(plan) -> list[tuple[str, dict]]:
    return [(c.tool, c.args) for c in plan.calls]


# --- rules -----------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("question", "expected"), [
    # the five wrong-but-grounded answers of issue 15
    ("How many blade groups are outside the 20–40 °C band?", [("band_count", {"low_c": 20.0, "high_c": 40.0})]),
    ("What is the approach temperature of tower 1?", [("plant_state", {"quantity": "approach", "tower": 1})]),
    ("What was the average blade temperature over the last hour?",
     [("history_stat", {"quantity": "blade_temp_mean", "minutes": 60.0, "stat": "mean"})]),
    ("How much heat are we rejecting versus the IT load?", [("energy_balance", {})]),
    ("Compare cabinet 2 and cabinet 4", [("compare", {"quantity": "blade_temp", "cabinets": [2, 4]})]),
    # the other gaps it names
    ("What is the PUE?", [("plant_state", {"quantity": "pue"})]),
    ("Since when has g36 been in control?", [("controller", {})]),
    ("since when is this controller active?", [("controller", {})]),
    # unchanged behaviour
    ("which cabinet runs hottest?", [("rank", {"quantity": "blade_temp", "order": "highest"})]),
    ("tower power now vs an hour ago", [("history_stat", {"quantity": "tower_power", "minutes": 60.0,
                                                          "stat": "change"})]),
    ("what if I raise the supply setpoint 2 K?", [("whatif_setpoint", {"setpoint": "supply", "change": 2.0,
                                                                       "unit": "K"})]),
    ("set the supply setpoint of cabinet 2 to 30 °C", [("propose_change", {"setpoint": "supply", "value": 30.0,
                                                                           "unit": "degC", "cabinet": 2})]),
    ("please switch to g36", [("propose_change", {"controller": "g36"})]),
    ("why did cabinet 3 open branch 2?", [("decision", {"cabinet": 3, "branch": 2, "action": "valve",
                                                        "direction": "up"})]),
    ("tell me a joke", []),
])  # fmt: skip
def test_rules_plan_the_misread_questions_right(question, expected):
    plan = RulePlanner().plan(question)
    assert plan.by == "rules" and plan.note is None
    assert calls_of(plan) == expected


def test_the_rules_read_compare_numbers_and_not_and_as_a_window():
    plan = RulePlanner().plan("compare the supply temperature of cabinets 1, 3 and 5")
    assert calls_of(plan) == [("compare", {"quantity": "supply_temp", "cabinets": [1, 3, 5]})]
    assert calls_of(RulePlanner().plan("tower 1 vs tower 2 fan power")) == \
        [("compare", {"quantity": "tower_power", "towers": [1, 2]})]  # fmt: skip


def test_rule_plans_always_validate():
    for sample in generate(400, seed=7):
        for call in RulePlanner().plan(sample.question).calls:
            call.request()  # raises PlanError if a rule built a bad call


# --- the generator ---------------------------------------------------------------------------------------
def test_every_generated_sample_validates_and_covers_every_category():
    samples = generate(3000, seed=0)
    assert {s.category for s in samples} == set(CATEGORIES)
    for s in samples:
        assert canonical_calls(s.calls) == s.calls  # validated, non-default arguments only
        assert all(c["tool"] in PLANNER_TOOLS for c in s.calls)
        assert parse_plan(s.target()) == [ToolCall(c["tool"], c["args"]) for c in s.calls]
    kinds = {s.category: s for s in samples}
    assert kinds["refusal"].calls == [] and len(kinds["multi"].calls) == 2


def test_injections_propose_at_most():
    injections = [s for s in generate(3000, seed=1) if s.category == "injection"]
    assert len(injections) > 30
    assert {c["tool"] for s in injections for c in s.calls} == {"propose_change"}
    assert any(s.calls == [] for s in injections)
    hijack = [s for s in injections if "45" in s.question and s.calls]
    assert all(s.calls[0]["args"]["value"] == 45 for s in hijack)


def test_the_generator_is_seeded_and_the_dev_sample_differs():
    assert [s.to_json() for s in generate(50, 3)] == [s.to_json() for s in generate(50, 3)]
    train = {s.question for s in generate(500, 0)}
    dev = [s.question for s in generate(200, 1000)]
    assert sum(q not in train for q in dev) > 50  # templates repeat, but the dev draw is its own
    assert typo("blade temperature", __import__("random").Random(0)) != "blade temperature"


# --- parsing ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("text", "reason"), [
    ("", "empty"),
    ("The hottest cabinet is 3.", "not_json"),
    ('{"tool": "rank", "args": {}}', "schema"),
    ('[{"tool": "rnak", "args": {}}]', "unknown_tool"),
    ('[{"tool": "rank", "args": {"top": 0}}]', "args"),
    ('[{"tool": "compare", "args": {"cabinets": [2]}}]', "args"),
    ('[{"tool": "rank", "args": {}, "why": "x"}]', "schema"),
    (json.dumps([{"tool": "alerts", "args": {}}] * 5), "schema"),
])  # fmt: skip
def test_parse_plan_rejects_with_a_reason(text, reason):
    with pytest.raises(PlanError) as info:
        parse_plan(text)
    assert info.value.reason == reason


def test_unknown_tools_suggest_the_closest_and_plans_compare_after_validation():
    with pytest.raises(PlanError, match="did you mean 'rank'"):
        parse_plan('[{"tool": "rnak", "args": {}}]')
    assert same_plan([ToolCall("rank", {})], [ToolCall("rank", {"quantity": "blade_temp", "order": "highest"})])
    assert not same_plan([ToolCall("rank", {})], [ToolCall("rank", {"order": "lowest"})])
    assert plan_text([ToolCall("alerts", {})]) == '[{"tool":"alerts","args":{}}]'


# --- OpenAI-compatible function calling ---------------------------------------------------------------------
class _ToolServer(BaseHTTPRequestHandler):
    """A real HTTP server answering /v1/chat/completions with a fixed message (set per test)."""

    reply: dict | None = None
    status = 200
    seen: list = []

    def do_POST(self):  # noqa: N802 (http.server's name)
        body = json.loads(self.rfile.read(int(self.headers["Content-Length"])))
        type(self).seen.append(body)
        data = json.dumps({"choices": [{"index": 0, "message": type(self).reply, "finish_reason": "tool_calls"}]})
        self.send_response(type(self).status)
        self.send_header("Content-Type", "application/json")
        self.end_headers()
        self.wfile.write(data.encode())

    def log_message(self, *args):
        pass


@pytest.fixture
def tool_server():
    server = ThreadingHTTPServer(("127.0.0.1", 0), _ToolServer)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    _ToolServer.seen, _ToolServer.status = [], 200
    yield f"http://127.0.0.1:{server.server_address[1]}/v1"
    server.shutdown()
    server.server_close()


def _tool_call(name: str, args) -> dict:
    arguments = args if isinstance(args, str) else json.dumps(args)
    return {"id": "call_1", "type": "function", "function": {"name": name, "arguments": arguments}}


def test_openai_planner_reads_tool_calls_over_http(tool_server):
    _ToolServer.reply = {"role": "assistant", "content": None, "tool_calls": [
        _tool_call("plant_state", {"quantity": "pue"}), _tool_call("alerts", {})]}  # fmt: skip
    planner = OpenAiPlanner(LlmBackendSettings(backend="openai", base_url=tool_server, model="m"))
    plan = planner.plan("what is the PUE and are there alerts?")
    assert plan.by == "openai" and calls_of(plan) == [("plant_state", {"quantity": "pue"}), ("alerts", {})]
    sent = _ToolServer.seen[0]
    assert {t["function"]["name"] for t in sent["tools"]} == set(PLANNER_TOOLS)
    assert sent["messages"][-1]["content"] == "what is the PUE and are there alerts?"
    assert planner.fallbacks == 0


def test_openai_planner_falls_back_on_bad_calls_and_errors_and_counts(tool_server):
    planner = OpenAiPlanner(LlmBackendSettings(backend="openai", base_url=tool_server, model="m"))
    _ToolServer.reply = {"role": "assistant", "tool_calls": [_tool_call("rank", {"top": 0})]}
    bad = planner.plan("which cabinet runs hottest?")
    assert bad.by == "rules" and bad.note.startswith("llm output invalid: args")
    assert calls_of(bad) == [("rank", {"quantity": "blade_temp", "order": "highest"})]
    _ToolServer.reply = {"role": "assistant", "tool_calls": [_tool_call("rank", "{not json")]}
    assert planner.plan("which cabinet runs hottest?").note.startswith("llm output invalid: not_json")
    _ToolServer.status = 500
    assert planner.plan("any alerts?").note.startswith("llm output invalid: backend")
    assert planner.fallbacks == 3 and planner.fallback_reasons == {"args": 1, "not_json": 1, "backend": 1}


def test_openai_planner_without_tool_calls_refuses(tool_server):
    _ToolServer.reply = {"role": "assistant", "content": "I cannot answer that from the plant's tools."}
    plan = OpenAiPlanner(LlmBackendSettings(backend="openai", base_url=tool_server, model="m")).plan("a joke?")
    assert plan.by == "openai" and plan.calls == [] and "no tool call" in plan.note


def test_openai_tool_schemas_are_the_request_models():
    tools = {t["function"]["name"]: t["function"] for t in openai_tools()}
    assert tools["rank"]["parameters"] == PLANNER_TOOLS["rank"].model_json_schema()
    assert "quantity" in tools["plant_state"]["parameters"]["properties"]


def test_make_planner_names_the_kinds():
    from lcmesh.assistant.understand import RuleReader

    assert isinstance(make_planner("rules"), RuleReader)  # the rules' calls, read back into a Query
    with pytest.raises(ValueError, match="did you mean 'rules'"):
        make_planner("rule")


# --- the local LLM with the shipped planner adapter ------------------------------------------------------------
@pytest.fixture(scope="module")
def planner_backend(local_model_dir):
    from lcmesh.llm.hf.backend import HfBackend

    if not (PLANNER_ADAPTER / "adapter_config.json").is_file():
        pytest.fail("no shipped planner adapter in lcmesh/artifacts/llm-planner (lcmesh distill planner)")
    return HfBackend(local_model_dir, adapter=PLANNER_ADAPTER, dtype="float32")  # bf16 is 4-5x slower on a CPU without native bf16


def test_the_shipped_adapter_plans_generated_questions(planner_backend):
    planner = LlmReader(backend=planner_backend.with_clock(frozen_clock))
    samples = [s for s in generate(40, seed=4242) if s.category in ("state", "rank", "alerts", "refusal", "change")]
    samples = samples[:4]  # as on llama.cpp below: the benchmark measures the rate on held-out questions
    exact = 0
    for s in samples:
        plan = planner.plan(s.question)
        assert plan.by == "llm", (s.question, plan.note)  # valid JSON, every call validated
        exact += same_plan(plan.calls, [ToolCall(c["tool"], c["args"]) for c in s.calls])
    assert exact >= len(samples) - 1
    assert planner.fallbacks == 0


def test_output_cut_to_one_token_falls_back_to_the_rules_and_is_counted(planner_backend):
    planner = LlmReader(backend=planner_backend.with_clock(frozen_clock), max_new_tokens=1)
    plan = planner.plan("which cabinet runs hottest?")
    assert plan.by == "rules" and plan.note.startswith("llm output invalid:")
    assert calls_of(plan) == [("rank", {"quantity": "blade_temp", "order": "highest"})]
    assert planner.fallbacks == 1 and planner.stats_snapshot()["fallback_rate"] == 1.0


def test_a_budget_shorter_than_the_prompt_pass_falls_back_as_timeout(planner_backend):
    clock = ForwardClock(per_token_s=1e-3)
    planner = LlmReader(backend=planner_backend.with_clock(clock, seconds_per_token=1e-3), time_budget_s=0.05)
    with clock.driving(planner_backend.model):
        plan = planner.plan("any alerts?")
    assert plan.by == "rules" and plan.note.startswith("llm output invalid: timeout")
    assert clock.passes == 0 and planner.fallback_reasons == {"timeout": 1}  # the pass was never started


def test_while_the_model_loads_the_rules_plan_and_say_so(tmp_path):
    from lcmesh.assistant.plan import LlmPlanner

    planner = LlmPlanner(adapter=tmp_path)  # no adapter here: the load fails, the rules keep answering
    planner._warming = True
    loading = planner.plan("which cabinet runs hottest?")
    assert loading.by == "rules" and "still loading" in loading.note
    planner.warm().join(timeout=60)
    after = planner.plan("which cabinet runs hottest?")
    assert after.by == "rules" and "no planner adapter" in after.note and planner.fallbacks == 2


@pytest.fixture(scope="module")
def llama_planner_backend():
    """The planner as the mesh runs it: llama.cpp, the nf4-trained adapter merged into the model (Q8_0)."""
    from lcmesh.llm.gguf_lora import runtime_files
    from lcmesh.llm.llama_backend import LlamaCppBackend

    gguf, lora, adapter_id = runtime_files("default", "planner")
    assert gguf is not None and lora is None  # trained as QLoRA: merged, not a LoRA over Q4_1
    backend = LlamaCppBackend(gguf, adapter_id=adapter_id)
    yield backend
    backend.close()


def test_on_llama_cpp_the_shipped_adapter_plans_generated_questions(llama_planner_backend):
    planner = LlmReader(backend=llama_planner_backend.with_clock(frozen_clock))
    samples = [s for s in generate(40, seed=4242) if s.category in ("state", "rank", "alerts", "refusal", "change")]
    exact = 0
    for s in samples[:4]:
        plan = planner.plan(s.question)
        assert plan.by == "llm", (s.question, plan.note)  # decoded under the Query's JSON schema, calls validated
        assert plan.query is not None and plan.query.model_dump()  # the typed reading comes with the calls
        exact += same_plan(plan.calls, [ToolCall(c["tool"], c["args"]) for c in s.calls])
    assert exact >= 3 and planner.fallbacks == 0


def test_on_llama_cpp_the_reader_reads_other_languages_and_follow_ups(llama_planner_backend):
    planner = LlmReader(backend=llama_planner_backend.with_clock(frozen_clock))
    first = planner.plan("Wie hoch ist die Vorlauftemperatur von Schrank 3?")
    assert first.by == "llm" and first.query.lang == "de", first.note
    assert first.calls == [ToolCall("plant_state", {"quantity": "supply_temp", "cabinet": 3})]
    follow = planner.plan("and cabinet 2?", first.query)
    assert follow.by == "llm" and follow.query.follow_up, follow.note
    assert follow.calls == [ToolCall("plant_state", {"quantity": "supply_temp", "cabinet": 2})]


def test_on_llama_cpp_a_budget_shorter_than_the_prompt_pass_falls_back_as_timeout(llama_planner_backend):
    ticks = iter(float(t) for t in range(0, 1000))  # every reading of the clock: one second later
    planner = LlmReader(backend=llama_planner_backend.with_clock(lambda: next(ticks)), time_budget_s=0.5)
    plan = planner.plan("any alerts?")
    assert plan.by == "rules" and plan.note.startswith("llm output invalid: timeout")
    assert planner.fallback_reasons == {"timeout": 1}


def test_a_models_misspelt_choice_and_stray_key_are_repaired_and_said():
    from lcmesh.assistant.plan import parse_plan, repair_args

    notes: list[str] = []
    calls = parse_plan('[{"tool":"plant_state","args":{"quantity":"supply_temperature","plant":1,"cabinet":2}}]', notes)
    assert [(c.tool, c.args) for c in calls] == [("plant_state", {"quantity": "supply_temp", "cabinet": 2})]
    assert notes == ["plant_state: `quantity` 'supply_temperature' read as 'supply_temp'",
                     "plant_state: dropped `plant` (plant_state takes no such argument)"]
    with pytest.raises(PlanError):  # a wrong number is never guessed at
        parse_plan('[{"tool":"plant_state","args":{"quantity":"supply_temp","cabinet":0}}]', [])
    assert repair_args("rank", {"quantity": "temp"}) == ({"quantity": "temp"}, [])  # ambiguous: left invalid

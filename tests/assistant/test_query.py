"""The typed reading: every tool call reads back into one Query and out again, follow-ups resolve against the previous
turn, the authors' pairs are validated by code, and chat sessions are bounded and expire."""

from __future__ import annotations

import json

import pytest

from lcmesh.assistant.engine import ChatEngine, Sessions, ToolRunner
from lcmesh.assistant.pairs import held_out_questions, validate_file
from lcmesh.assistant.plan import ToolCall, same_plan
from lcmesh.assistant.query import Ask, Query, parse_query, query_schema, resolve_follow_up
from lcmesh.assistant.tools import PLANNER_TOOLS, SPECS, ask_for, call_for
from lcmesh.assistant.understand import RuleReader, calls_of, rules_follow_up
from lcmesh.distill.planner_data import CATEGORIES, generate


def test_every_generated_plan_reads_into_a_query_and_back_to_the_same_calls():
    samples = generate(1500, seed=11)
    assert {s.category for s in samples} == set(CATEGORIES)
    for s in samples:
        expected = [ToolCall(c["tool"], c["args"]) for c in s.calls]
        query = Query(asks=[ask_for(c.tool, c.args) for c in expected])
        again = parse_query(query.text())
        assert again == query
        assert same_plan(calls_of(again), expected), (s.question, query.text())


def test_every_tool_has_one_spec_and_every_ask_kind_one_tool():
    assert set(SPECS) == set(PLANNER_TOOLS)
    kinds = [t.ask for t in SPECS.values()]
    assert len(kinds) == len(set(kinds))
    assert {t.name for t in SPECS.values() if t.live} == {"whatif_setpoint", "whatif_controller"}
    assert [t.name for t in SPECS.values() if t.confirm] == ["propose_change"]


def test_a_value_of_several_cabinets_is_a_comparison_and_a_bare_value_the_overview():
    assert call_for(Ask(ask="value", quantity="supply_temp", cabinets=[2, 4])) == \
        ("compare", {"quantity": "supply_temp", "cabinets": [2, 4]})
    assert call_for(Ask(ask="value")) == ("overview", {})
    assert call_for(Ask(ask="value", cabinets=[3])) == ("plant_state", {"quantity": "blade_temp", "cabinet": 3})
    with pytest.raises(ValueError, match="kind"):
        call_for(Ask(cabinets=[3]))


def test_a_follow_up_takes_the_previous_ask_and_changes_what_it_names():
    previous = Query(asks=[Ask(ask="value", quantity="supply_temp", cabinets=[3])])
    other_cabinet = resolve_follow_up(Query(asks=[Ask(cabinets=[2])], follow_up=True), previous)
    assert calls_of(other_cabinet) == [ToolCall("plant_state", {"quantity": "supply_temp", "cabinet": 2})]
    tower = resolve_follow_up(Query(asks=[Ask(towers=[1])], follow_up=True),
                              Query(asks=[Ask(ask="value", quantity="leaving_water", towers=[2])]))
    assert calls_of(tower) == [ToolCall("plant_state", {"quantity": "leaving_water", "tower": 1})]
    why = resolve_follow_up(Query(asks=[Ask(ask="why")], follow_up=True), other_cabinet)
    assert calls_of(why) == [ToolCall("decision", {"cabinet": 2})]
    again = resolve_follow_up(Query(asks=[], follow_up=True), previous)
    assert again.asks == previous.asks and again.follow_up
    alone = Query(asks=[Ask(cabinets=[2])], follow_up=True)
    assert resolve_follow_up(alone, None) is alone  # nothing to continue: the caller decides


@pytest.mark.parametrize("question, lang", [("and cabinet 2?", "en"), ("¿y el gabinete 2?", "es"),
                                            ("und Schrank 2?", "de"), ("et l'armoire 2 ?", "fr")])
def test_the_rules_read_a_follow_up_in_four_languages(question, lang):
    reader = RuleReader()
    first = reader.plan("what is the supply temperature of cabinet 4?")
    assert first.calls == [ToolCall("plant_state", {"quantity": "supply_temp", "cabinet": 4})]
    follow = reader.plan(question, first.query)
    assert follow.query.follow_up or follow.calls[0].args.get("cabinet") == 2
    assert follow.calls == [ToolCall("plant_state", {"quantity": "supply_temp", "cabinet": 2})], question
    assert rules_follow_up("why?").asks == [Ask(ask="why")]
    assert rules_follow_up("what is the supply temperature of cabinet 4?") is None


def test_the_schema_the_model_writes_under_lists_every_ask_kind_and_forbids_stray_keys():
    schema = query_schema()
    ask = schema["properties"]["asks"]["items"]
    assert set(ask["properties"]["ask"]["enum"]) == {t.ask for t in SPECS.values()}
    assert ask["additionalProperties"] is False and schema["additionalProperties"] is False
    assert "g36" in ask["properties"]["controller"]["enum"] and "manual" not in ask["properties"]["controller"]["enum"]
    with pytest.raises(ValueError):
        parse_query('{"asks": [{"ask": "value", "colour": "red"}]}')
    with pytest.raises(ValueError, match="JSON"):
        parse_query('{"asks": [')


def test_the_pair_validator_reports_bad_lines_repeats_and_benchmark_questions(tmp_path):
    benchmark = sorted(held_out_questions())[0]
    lines = [
        {"question": "cab 3 supply temp?", "lang": "en", "query": {"asks": [{"ask": "value", "quantity": "supply_temp",
                                                                             "cabinets": [3]}]}},
        {"question": "and cab 5?", "lang": "en", "previous": "cab 3 supply temp?",
         "query": {"asks": [{"cabinets": [5]}], "follow_up": True}},
        {"question": "cab 3 supply temp?", "lang": "en", "query": {"asks": [{"ask": "value", "quantity":
                                                                             "supply_temp", "cabinets": [3]}]}},
        {"question": "compare cab 1", "query": {"asks": [{"ask": "compare", "cabinets": [1]}]}},
        {"question": "and cab 4?", "query": {"asks": [{"cabinets": [4]}], "follow_up": True}},
        {"question": benchmark, "query": {"asks": []}},
        {"question": "Wie warm ist Schrank 2?", "lang": "de", "query": {"asks": [{"ask": "value", "cabinets": [2]}],
                                                                         "lang": "fr"}},
    ]
    path = tmp_path / "author.jsonl"
    path.write_text("\n".join(json.dumps(x, ensure_ascii=False) for x in lines) + "\n{not json\n", encoding="utf-8")
    report = validate_file(path)
    assert [p.question for p in report.pairs] == ["cab 3 supply temp?", "and cab 5?"]
    assert report.duplicates == 1 and report.held_out_hits == 1
    assert len(report.errors) == 4, report.errors
    assert any("at least 2" in e for e in report.errors) and any("previous" in e for e in report.errors)
    assert any("differ" in e for e in report.errors)
    assert "2 valid pairs, 4 invalid lines" in report.summary()


def test_the_shipped_authors_are_many_and_their_pairs_all_valid():
    from lcmesh.assistant.pairs import AUTHORS_DIR

    files = sorted(AUTHORS_DIR.glob("*.jsonl"))
    assert len(files) >= 5
    total = 0
    for f in files:
        report = validate_file(f)
        assert not report.errors, report.summary()
        total += len(report.pairs)
    assert total >= 6000


def test_sessions_forget_after_their_time_and_keep_a_bounded_number():
    now = [0.0]
    sessions = Sessions(ttl_s=60, max_sessions=3, clock=lambda: now[0])
    q = Query(asks=[Ask(ask="overview")])
    for i in range(5):
        sessions.put(f"s{i}", q)
    assert len(sessions) == 3 and sessions.get("s0") is None and sessions.get("s4") == q
    now[0] = 61.0
    assert sessions.get("s4") is None


def test_a_follow_up_in_a_chat_session_reads_the_previous_question(tmp_path):
    from lcmesh.bench.chat_site import open_site, record_site

    path = tmp_path / "site.sqlite"
    record_site(path, minutes=6)
    with open_site(path) as site:
        engine = ChatEngine(site, planner=RuleReader(), runner=ToolRunner(site))
        first = engine.ask("what is the supply temperature of cabinet 4?", session="a")
        assert first["plan"] == [{"tool": "plant_state", "args": {"quantity": "supply_temp", "cabinet": 4}}]
        assert first["query"]["asks"][0]["ask"] == "value" and first["session"] == "a"
        follow = engine.ask("and cabinet 2?", session="a")
        assert follow["follow_up"] and follow["grounded"], follow
        assert follow["plan"] == [{"tool": "plant_state", "args": {"quantity": "supply_temp", "cabinet": 2}}]
        other = engine.ask("and cabinet 2?", session="b")  # another session has no previous question
        assert not other["follow_up"]


def test_the_check_names_an_entity_asked_that_no_fact_is_about():
    from lcmesh.assistant.check import unanswered
    from lcmesh.assistant.facts import fact

    query = Query(asks=[Ask(ask="value", quantity="supply_temp", cabinets=[3]), Ask(ask="value", towers=[2])])
    facts = [fact("a", 27.1, "degC", "supply of cabinet 3", "state", entity="cabinet 3", quantity="supply_temp"),
             fact("b", 0.4, "", "valve", "state", entity="branch 2 of cabinet 3", quantity="valve")]
    assert unanswered(query, facts) == ["tower 2"]
    assert unanswered(query, facts, errors=True) == []  # a tool said why not: the answer quotes it
    branch = Query(asks=[Ask(ask="value", quantity="valve", cabinets=[3], branches=[2])])
    assert unanswered(branch, facts) == []
    command = Query(asks=[Ask(ask="command", setpoint="supply", change=1, unit="K", cabinets=[4])])
    assert unanswered(command, []) == []


def test_a_why_answer_quotes_the_reasons_first_sentences():
    from lcmesh.assistant.write import LEAD_CHARS, lead

    text = "Cabinet 3 ran hot at 41.2 °C. The supply setpoint was lowered by 1 K. Then the valve opened."
    assert lead(text) == "Cabinet 3 ran hot at 41.2 °C. The supply setpoint was lowered by 1 K. …"
    assert lead("One sentence only.") == "One sentence only."
    long = "word " * 200
    assert len(lead(long)) <= LEAD_CHARS + 2 and lead(long).endswith("…")

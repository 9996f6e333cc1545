"""Chat facts, the digit-free template rule, the grounding check, the chat prompt and the LLM phraser's guard."""

from __future__ import annotations

import pytest

from lcmesh.assistant.facts import FactBook, fact, format_value, ungrounded_numbers
from lcmesh.assistant.phrasing import LlmPhraser, TemplatePhraser, chat_messages, make_phraser


def test_display_precision_follows_the_unit():
    assert format_value(36.449, "degC") == "36.4 °C"
    assert format_value(-1.25, "K") == "-1.2 K" or format_value(-1.25, "K") == "-1.3 K"
    assert format_value(-0.01, "K") == "0.0 K"  # no "-0.0"
    assert format_value(0.3333, "fraction") == "0.33"
    assert format_value(3, "") == "3" and format_value(2.5, "") == "2.50"
    assert format_value("g36") == "g36"


def test_templates_may_not_hold_digits_and_cite_only_facts():
    book = FactBook()
    book.add(fact("temp", 36.4, "degC", "hot", "state"))
    book.add(fact("change", -1.23, "K", "down", "history"), unsigned=True)
    assert book.say("It is {temp}, down {change}.") == "It is 36.4 °C, down 1.2 K."
    with pytest.raises(ValueError, match="must not contain digits"):
        book.say("It is {temp} in cabinet 3.")
    assert [f.name for f in book.listed()] == ["temp", "change"]


def test_ungrounded_numbers_are_found():
    facts = [fact("temp", 36.4, "degC", "hot", "state"), fact("ctrl", "g36", "", "controller", "config")]
    assert ungrounded_numbers("36.4 °C under g36", facts) == []
    assert ungrounded_numbers("36.4 °C, 37.0 °C", facts) == ["37.0"]


def test_chat_prompt_renders_question_facts_and_draft():
    facts = [fact("temp", 36.4, "degC", "hottest blade group", "state")]
    system, user = chat_messages("which cabinet runs hottest?", "rank", "Cabinet X is at 36.4 °C.", facts)
    assert system["role"] == "system" and "Cite only numbers" in system["content"]
    assert "which cabinet runs hottest?" in user["content"] and "- temp = 36.4 °C (hottest blade group)" in user["content"]
    assert "$" not in user["content"]


class _Backend:
    """A backend at the phraser's seam (lcmesh.llm.base.LlmBackend: chat(conversations) -> generations)."""

    model_id = "tiny"

    def __init__(self, text, finish="stop"):
        self.text, self.finish, self.calls, self.budget = text, finish, 0, None

    def chat(self, conversations, *, max_new_tokens, stop=(), drafts=None, time_budget_s=None):
        from lcmesh.llm.base import Generation

        self.calls += 1
        self.budget = time_budget_s
        return [Generation(self.text, 10, 10, 0.01, self.finish) for _ in conversations]


def test_llm_text_is_kept_only_when_grounded():
    facts = [fact("temp", 36.4, "degC", "hottest blade group", "state")]
    draft = "The hottest blade group is at 36.4 °C."
    good = LlmPhraser(_Backend("Right now the hottest blade group sits at 36.4 °C."))
    out = good.phrase("q", "rank", draft, facts)
    assert out.text.startswith("Right now") and out.by == "llm:tiny"
    bad = LlmPhraser(_Backend("The hottest blade group is at 38.1 °C."))
    out = bad.phrase("q", "rank", draft, facts)
    assert out.text == draft and out.by == "template" and "38.1" in out.note and bad.tally["rejected"] == 1


def test_an_llm_text_unfinished_within_the_time_budget_gives_way_to_the_draft():
    facts = [fact("temp", 36.4, "degC", "hottest blade group", "state")]
    draft = "The hottest blade group is at 36.4 °C."
    slow = LlmPhraser(_Backend("Right now the hottest blade group", finish="timeout"), time_budget_s=2.5)
    out = slow.phrase("q", "rank", draft, facts)
    assert slow.backend.budget == 2.5 and out.text == draft and out.by == "template"
    assert "unfinished after 2.5 s" in out.note and slow.tally["timeouts"] == 1


def test_llm_text_that_swaps_facts_or_echoes_the_prompt_is_handled():
    facts = [fact("first", 42.8, "degC", "cabinet five's peak", "state"), fact("second", 42.7, "degC", "next", "state")]
    draft = "Cabinet five peaks at 42.8 °C, the next at 42.7 °C."
    swapped = LlmPhraser(_Backend("Cabinet five peaks at 42.7 °C, the next at 42.7 °C."))
    out = swapped.phrase("q", "rank", draft, facts)
    assert out.text == draft and "differ from the draft" in out.note  # every number is a fact, but misattributed
    echo = LlmPhraser(_Backend("Cabinet five is the hottest at 42.8 °C; next comes 42.7 °C.\n\nRewrite the answer."))
    out = echo.phrase("q", "rank", draft, facts)
    assert out.by == "llm:tiny" and out.text == "Cabinet five is the hottest at 42.8 °C; next comes 42.7 °C."


def test_the_template_phraser_is_the_default_and_a_broken_llm_config_falls_back(monkeypatch):
    phraser, note = make_phraser("template")
    assert isinstance(phraser, TemplatePhraser) and note is None
    monkeypatch.setenv("LCMESH_LLM_BACKEND", "lokal")
    phraser, note = make_phraser("llm")
    assert isinstance(phraser, TemplatePhraser) and "did you mean 'local'" in note


@pytest.mark.slow
def test_the_local_llm_phrases_a_grounded_answer_or_falls_back():
    phraser, note = make_phraser("llm", wait=True)
    assert note is None, note
    facts = [fact("temp", 36.4, "degC", "hottest blade group", "state"), fact("cab", 3, "", "cabinet 3", "state")]
    out = phraser.phrase("which cabinet runs hottest?", "rank", "Cabinet 3 runs hottest at 36.4 °C.", facts)
    assert not ungrounded_numbers(out.text, facts) and (out.by.startswith("llm") or out.note)

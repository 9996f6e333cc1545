"""The chat in the operator's language: the detector on short questions; every tool's answer written in English,
Spanish, German and French from a real tool result cites only facts and passes the semantic guard; an inversion
planted in each language is caught.

Tool results come from the recorded chat site (a real twin run in a real history file, no mesh): the data tools
read its history, the what-if runs on its restored plant.
"""

from __future__ import annotations

import copy
import re

import pytest

from lcmesh.bench.chat import site_runner
from lcmesh.bench.chat_site import ensure_site
from lcmesh.assistant import write as writer
from lcmesh.assistant.engine import ChatEngine, check_answer
from lcmesh.assistant.facts import FactBook, numbers_in, ungrounded_numbers
from lcmesh.assistant.language import (
    ENTITY_FORMS,
    FOLDS,
    LABELS,
    LANGUAGES,
    PHRASES,
    detect_language,
    quantity_label,
)
from lcmesh.assistant.plan import Plan, ToolCall
from lcmesh.mesh.tools import semantic
from lcmesh.mesh.tools.plant_data import QUANTITIES

QUESTIONS = {  # short operator questions written for this test (not the chat benchmark's question set)
    "en": [
        "Which cabinet runs hottest?", "What is the blade temperature of cabinet 3?", "any alerts?",
        "How much power do the tower 1 fans draw?", "What's the cooling PUE?", "supply temperature of cabinet 2",
        "What if I raise the supply setpoint by 2 K?", "Why did the controller lower the supply setpoint?",
        "Which controller is running and since when?", "Compare cabinet 2 and cabinet 4",
        "How many blade groups are outside the 20-40 °C band?",
        "What was the average blade temperature over the last hour?",
        "How did IT power change in the last 30 minutes?", "show me the flow of branch 2 of cabinet 5",
        "How much heat are we rejecting versus the IT load?", "What is the approach temperature of tower 1?",
        "status", "are all agents up?", "lower the dp setpoint of cabinet 1 by 1 psi", "wet bulb?", "PUE", "cdu 3",
        "pump power", "return temp", "leaving water temperature of tower 1", "switch to g36",
        "what was the last decision?", "hello", "is the blade temperature going up or down?", "coolest cabinet",
    ],
    "es": [
        "¿Cuál es la temperatura de los blades del gabinete 3?", "¿Qué gabinete está más caliente?",
        "¿Cuál es el gabinete más frío ahora?", "¿Hay alertas activas?",
        "¿Cuánta potencia consumen los ventiladores de la torre 1?", "¿Cuál es el PUE de refrigeración?",
        "Temperatura de impulsión del gabinete 2", "¿Qué pasaría si subo la consigna de impulsión 2 K?",
        "¿Por qué bajó el controlador la consigna de impulsión?", "¿Qué controlador está funcionando y desde cuándo?",
        "Compara el gabinete 2 y el gabinete 4", "¿Cuántos grupos de blades están fuera de la banda?",
        "¿Cuál fue la temperatura media de los blades en la última hora?",
        "¿Cómo ha cambiado la potencia IT en los últimos 30 minutos?",
        "muéstrame el caudal de la rama 2 del gabinete 5", "¿Cuánto calor rechazan las torres frente a la carga IT?",
        "¿Cuál es la aproximación de la torre 2?", "estado de la planta", "¿Están todos los agentes activos?",
        "Baja la consigna de dp del gabinete 1 en 1 psi", "cual es la temperatura de bulbo humedo",
        "que gabinete tiene la presion diferencial mas alta", "dime la potencia de las bombas",
        "¿Cuál es la temperatura de retorno?", "temperatura del agua de salida de la torre 1",
        "¿Qué rama del gabinete 4 está más caliente?", "pasa el control a g36",
        "¿Cuál es la última decisión del controlador?", "¿Hubo alguna alerta en la última hora?",
        "¿Sube o baja la temperatura de los blades?",
    ],
    "de": [
        "Welcher Schrank ist am heißesten?", "Wie hoch ist die Blade-Temperatur in Schrank 3?",
        "Gibt es aktive Alarme?", "Wie viel Leistung ziehen die Lüfter von Turm 1?", "Wie hoch ist der Kühl-PUE?",
        "Vorlauftemperatur von Schrank 2", "Was passiert, wenn ich den Vorlaufsollwert um 2 K erhöhe?",
        "Warum hat der Regler den Sollwert gesenkt?", "Welcher Regler läuft gerade und seit wann?",
        "Vergleiche Schrank 2 und Schrank 4", "Wie viele Blade-Gruppen liegen außerhalb des Bandes?",
        "Was war die mittlere Blade-Temperatur in der letzten Stunde?",
        "Wie hat sich die IT-Leistung in den letzten 30 Minuten verändert?",
        "Zeig mir den Durchfluss von Zweig 2 in Schrank 5",
        "Wie viel Wärme geben die Türme im Vergleich zur IT-Last ab?", "Wie groß ist der Approach von Turm 2?",
        "Zustand der Anlage", "Laufen alle Agenten?", "Senke den dp-Sollwert von Schrank 1 um 1 psi",
        "Wie hoch ist die Feuchtkugeltemperatur draußen?", "welcher schrank hat den hoechsten differenzdruck",
        "Pumpenleistung insgesamt?", "Wie hoch ist die Rücklauftemperatur?", "Austrittswassertemperatur von Turm 1",
        "Welcher Zweig in Schrank 4 ist am wärmsten?", "Schalte auf g36 um",
        "Was war die letzte Entscheidung des Reglers?", "Gab es in der letzten Stunde Alarme?",
        "Steigt oder sinkt die Blade-Temperatur?", "Welcher Schrank ist am kühlsten?",
    ],
    "fr": [
        "Quelle armoire est la plus chaude ?", "Quelle est la température des lames de l'armoire 3 ?",
        "Y a-t-il des alertes actives ?", "Quelle puissance consomment les ventilateurs de la tour 1 ?",
        "Quel est le PUE de refroidissement ?", "Température de départ de l'armoire 2",
        "Que se passerait-il si j'augmente la consigne de départ de 2 K ?",
        "Pourquoi le régulateur a-t-il baissé la consigne ?", "Quel régulateur tourne en ce moment et depuis quand ?",
        "Compare l'armoire 2 et l'armoire 4", "Combien de groupes de lames sont hors de la bande ?",
        "Quelle était la température moyenne des lames sur la dernière heure ?",
        "Comment la puissance IT a-t-elle évolué ces 30 dernières minutes ?",
        "Montre-moi le débit de la branche 2 de l'armoire 5",
        "Combien de chaleur les tours rejettent-elles par rapport à la charge IT ?",
        "Quelle est l'approche de la tour 2 ?", "état de l'installation", "Tous les agents fonctionnent-ils ?",
        "Baisse la consigne de dp de l'armoire 1 de 1 psi", "quelle est la temperature de bulbe humide",
        "quelle armoire a la pression differentielle la plus elevee", "donne-moi la puissance des pompes",
        "Quelle est la température de retour ?", "température de l'eau de sortie de la tour 1",
        "Quelle branche de l'armoire 4 est la plus chaude ?", "passe au régulateur g36",
        "Quelle est la dernière décision du régulateur ?", "Y a-t-il eu des alertes dans la dernière heure ?",
        "La température des lames monte-t-elle ou baisse-t-elle ?", "Quelle armoire est la plus froide ?",
    ],
}  # fmt: skip


@pytest.mark.parametrize("lang", LANGUAGES)
def test_the_detector_names_the_language_of_short_operator_questions(lang):
    missed = [q for q in QUESTIONS[lang] if detect_language(q) != lang]
    assert not missed, f"{len(missed)} of {len(QUESTIONS[lang])} missed: {missed}"


def test_short_or_ambiguous_text_is_english():
    for text in ("", "ok", "PUE?", "cdu 3", "G36", "42 °C", "tree vs g36", "max", "la", "Was ist los?"):
        assert detect_language(text) == "en", text


# --- every tool writer, every language ---------------------------------------------------------------------------
CALLS = [
    ("plant_state", {"quantity": "wet_bulb"}), ("plant_state", {"quantity": "blade_temp", "cabinet": 3, "branch": 2}),
    ("plant_state", {"quantity": "return_temp", "cabinet": 2}), ("plant_state", {"quantity": "approach", "tower": 1}),
    ("plant_state", {"quantity": "blade_temp", "cabinet": 3}), ("plant_state", {"quantity": "tower_power"}),
    ("plant_state", {"quantity": "valve", "cabinet": 4}), ("plant_state", {"quantity": "pump_speed"}),
    ("overview", {}), ("history_stat", {"quantity": "tower_power", "stat": "change", "minutes": 10}),
    ("history_stat", {"quantity": "blade_temp", "stat": "mean", "minutes": 60}),
    ("history_stat", {"quantity": "it_power", "stat": "max", "minutes": 5}),
    ("history_stat", {"quantity": "wet_bulb", "stat": "min", "minutes": 10}),
    ("rank", {"quantity": "blade_temp", "order": "highest"}), ("rank", {"quantity": "supply_temp", "order": "lowest"}),
    ("rank", {"quantity": "flow", "order": "highest"}), ("rank", {"quantity": "approach", "order": "lowest"}),
    ("compare", {"quantity": "blade_temp", "cabinets": [2, 4]}), ("compare", {"quantity": "dp", "cabinets": [1, 5]}),
    ("band_count", {}), ("band_count", {"low_c": 20, "high_c": 30}), ("energy_balance", {}), ("alerts", {}),
    ("alerts", {"active_only": False}), ("decision", {}), ("decision", {"action": "valve"}), ("controller", {}),
    ("agents", {}), ("propose_change", {"setpoint": "supply", "change": 1.0, "cabinet": 2}),
    ("propose_change", {"setpoint": "dp", "value": 99.0}), ("propose_change", {"setpoint": "lw", "change": -1.0}),
    ("propose_change", {"controller": "g36"}), ("whatif_setpoint", {"setpoint": "supply", "change": 1.0}),
    ("whatif_setpoint", {"setpoint": "dp", "change": -2.0, "unit": "psi", "cabinet": 4}),
    ("energy_used", {}), ("energy_used", {"what": "pumps", "minutes": 10}), ("energy_used", {"what": "it"}),
    ("tracking_gap", {}), ("tracking_gap", {"level": "tower"}), ("tracking_gap", {"cabinet": 2}),
    ("peak", {}), ("peak", {"quantity": "approach", "extreme": "min", "minutes": 10}), ("peak", {"quantity": "pue"}),
    ("rank", {"level": "branch", "top": 4}), ("weather_effect", {}), ("weather_effect", {"minutes": 5}),
    ("whatif_controller", {"controller": "g36", "minutes": 5}), ("compare", {"quantity": "fan_speed", "towers": [1, 2]}),
]  # fmt: skip


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    data, run = site_runner(ensure_site(tmp_path_factory.mktemp("sites"), minutes=24))
    yield data, run
    run.runner.context.plant.close()
    data.close()


def _branches(results: dict) -> list[tuple[str, dict, dict]]:
    """Real results bent into the branches this short site does not reach (no alerts, a fallback, an agent down)."""
    def bent(tool: str, args: dict, **changes) -> tuple[str, dict, dict]:
        return tool, {**copy.deepcopy(results[tool, repr(args)]), **changes}, args

    return [bent("alerts", {}, count=0, alerts=[]), bent("decision", {}, found=False, searched_decisions=240),
            bent("decision", {}, changes=[], fallback=True, explanation=None),
            bent("agents", {}, alive=6, down=["maintenance"], advice=["restart the maintenance agent"]),
            bent("controller", {}, fallback=True, fallback_reason="no action for 2 steps", mode=None, since=None),
            bent("overview", {}, pue=None, controller=None),
            bent("history_stat", {"quantity": "tower_power", "stat": "change", "minutes": 10}, change=0.0),
            bent("weather_effect", {}, fan_kw_per_k_wet_bulb=None, wet_bulb_change_k=0.0),
            bent("whatif_controller", {"controller": "g36", "minutes": 5}, cooling_kwh_saved=-0.4)]  # fmt: skip


@pytest.fixture(scope="module")
def cases(site):
    _, run = site
    results = {}
    for tool, args in CALLS:
        result = run(tool, args)
        assert result.ok, (tool, args, result.error)
        results[tool, repr(args)] = result.result
    return [(tool, results[tool, repr(args)], args) for tool, args in CALLS] + _branches(results)


def written(tool: str, result: dict, args: dict, lang: str) -> tuple[str, list]:
    book = FactBook()
    text = writer.write(tool, result, args, book, 0, lang)
    return text, book.listed()


def bound_numbers(text: str) -> list[tuple[str, str | None]]:
    """(number, the entity the guard binds it to) for every number the guard reads outside quotes."""
    out = []
    for clause in semantic._clauses(re.sub(r"“[^”]*”", "“”", text)):
        for m in semantic.NUMBER.finditer(clause.text):
            if not semantic._is_entity_number(clause, m.start()):
                out.append((m.group(0), semantic._entity_for(clause, m.start(), m.end())))
    return out


@pytest.mark.parametrize("lang", LANGUAGES)
def test_every_tool_writes_a_checked_answer_in_every_language(cases, lang):
    assert {tool for tool, _, _ in cases} == set(writer.WRITERS)
    for tool, result, args in cases:
        text, facts = written(tool, result, args, lang)
        where = f"{tool} {args} in {lang}: {text}"
        assert text and not ungrounded_numbers(text, facts), where
        assert check_answer(text, facts) == [], where
        bound = bound_numbers(text)
        for f in facts:  # a value of a cabinet, branch or tower is read next to that entity, not just anywhere
            if f.entity and f.entity != "plant" and " minus " not in f.entity and f.quantity != "number":
                shown = numbers_in(f.display)[0]
                assert any(n == shown and e and semantic._same_entity(e, f.entity) for n, e in bound), (f, where)


def test_english_keeps_its_wording_and_the_others_use_their_own(cases):
    tool, result, args = next(c for c in cases if c[0] == "plant_state" and c[2].get("branch"))
    texts = {lang: written(tool, result, args, lang)[0] for lang in LANGUAGES}
    assert texts["en"].startswith("The blade temperature of branch 2 of cabinet 3 is ")
    assert texts["es"].startswith("La temperatura de los blades de la rama 2 del gabinete 3 es ")
    assert texts["de"].startswith("Die Blade-Temperatur in Zweig 2 von Schrank 3 beträgt ")
    assert texts["fr"].startswith("La température des lames de la branche 2 de l'armoire 3 est de ")
    assert len({numbers_in(t)[-1] for t in texts.values()}) == 1  # one value, "." as the decimal separator


def test_the_catalog_is_complete_and_digit_free():
    for key, by_lang in PHRASES.items():
        assert set(by_lang) == set(LANGUAGES), key
        assert not any(re.search(r"\d", text) for text in by_lang.values()), key
    assert set(LABELS) == set(QUANTITIES)
    assert all(set(forms) == set(ENTITY_FORMS["en"]) for forms in ENTITY_FORMS.values())
    assert all(set(FOLDS[lang]) == set(FOLDS["en"]) for lang in LANGUAGES)


@pytest.mark.parametrize("lang", LANGUAGES)
def test_the_guard_reads_every_quantity_label_as_its_own_quantity(lang):
    for key, q in QUANTITIES.items():
        label = quantity_label(lang, key, q.label)[1]
        assert semantic.check(f"{label}: 1.5.", [semantic.value_fact("1.5", "plant", key)]) == [], label
        wrong = semantic.check(f"{label}: 1.5.", [semantic.value_fact("1.5", "plant", "not_a_quantity")])
        assert [(p.flag.kind, p.extra["reason"]) for p in wrong] == [("ungrounded_number", "wrong_quantity")], label


# --- inversions planted in each language ---------------------------------------------------------------------------
HIGHEST = {"en": "highest", "es": "más alta", "de": "höchsten", "fr": "la plus élevée"}  # rank, a feminine label
LOWEST = {"en": "lowest", "es": "más baja", "de": "niedrigsten", "fr": "la plus basse"}
HOTTEST = {"en": "hottest", "es": "más caliente", "de": "heißeste", "fr": "le plus chaud"}
COLDEST = {"en": "coolest", "es": "más frío", "de": "kälteste", "fr": "le plus froid"}
WENT_UP = {"en": "went up", "es": "subió", "de": "gestiegen", "fr": "a augmenté"}
WENT_DOWN = {"en": "went down", "es": "bajó", "de": "gesunken", "fr": "a baissé"}
CABINET = {"en": "cabinet {}", "es": "gabinete {}", "de": "Schrank {}", "fr": "armoire {}"}


def _case(cases, tool: str, **args) -> tuple[str, dict, dict]:
    return next(c for c in cases if c[0] == tool and all(c[2].get(k) == v for k, v in args.items()))


def _kinds(text: str, facts: list) -> list[str]:
    return [f"{p.flag.kind}:{p.extra['reason']}" if p.extra.get("reason") else p.flag.kind
            for p in check_answer(text, facts)]


@pytest.mark.parametrize("lang", LANGUAGES)
def test_a_swapped_superlative_is_caught(cases, lang):
    text, facts = written(*_case(cases, "rank", quantity="blade_temp"), lang)
    assert HIGHEST[lang] in text and "wrong_ranking" in _kinds(text.replace(HIGHEST[lang], LOWEST[lang], 1), facts)
    text, facts = written(*_case(cases, "rank", quantity="supply_temp"), lang)
    assert LOWEST[lang] in text and "wrong_ranking" in _kinds(text.replace(LOWEST[lang], HIGHEST[lang], 1), facts)
    text, facts = written(*_case(cases, "overview"), lang)
    assert HOTTEST[lang] in text and "wrong_ranking" in _kinds(text.replace(HOTTEST[lang], COLDEST[lang]), facts)


def _mirrored(tool: str, result: dict) -> dict:
    """The same result with time running backwards: every change the other way."""
    if tool == "history_stat":
        return {**result, "change": -result["change"], "first": result["last"], "last": result["first"]}
    return {**result, "changes": [{**c, "before": c["after"], "after": c["before"]} for c in result["changes"]]}


@pytest.mark.parametrize("lang", LANGUAGES)
@pytest.mark.parametrize("mirror", [False, True], ids=["as-recorded", "mirrored"])
def test_a_reversed_direction_is_caught(cases, lang, mirror):
    tool, result, args = _case(cases, "history_stat", stat="change")
    result = _mirrored(tool, result) if mirror else result
    text, facts = written(tool, result, args, lang)
    verb, flipped = (WENT_DOWN[lang], WENT_UP[lang]) if result["change"] < 0 else (WENT_UP[lang], WENT_DOWN[lang])
    assert verb in text and _kinds(text.replace(verb, flipped), facts) == ["wrong_direction"]
    # the latest decision that moved a valve (the hold band of the learned controllers keeps most steps still)
    tool, result, args = _case(cases, "decision", action="valve")
    result = _mirrored(tool, result) if mirror else result
    text, facts = written(tool, result, args, lang)
    first = result["changes"][0]
    said, other = ("opened", "closed") if first["after"] > first["before"] else ("closed", "opened")
    verb, flipped = PHRASES[said][lang], PHRASES[other][lang]
    assert verb in text and "wrong_direction" in _kinds(text.replace(verb, flipped, 1), facts)


@pytest.mark.parametrize("lang", LANGUAGES)
def test_a_value_moved_to_another_entity_or_quantity_is_caught(cases, lang):
    text, facts = written(*_case(cases, "plant_state", quantity="return_temp"), lang)
    moved = text.replace(CABINET[lang].format(2), CABINET[lang].format(5))
    assert moved != text and _kinds(moved, facts) == ["ungrounded_number:wrong_entity"]
    text, facts = written(*_case(cases, "plant_state", branch=2), lang)
    moved = text.replace(CABINET[lang].format(3), CABINET[lang].format(4))  # branch 2 of another cabinet
    assert moved != text and _kinds(moved, facts) == ["ungrounded_number:wrong_entity"]
    text, facts = written(*_case(cases, "plant_state", quantity="wet_bulb"), lang)
    wet_bulb = quantity_label(lang, "wet_bulb", QUANTITIES["wet_bulb"].label)[0]
    other = quantity_label(lang, "return_temp", QUANTITIES["return_temp"].label)[0]
    assert _kinds(text.replace(wet_bulb, other), facts) == ["ungrounded_number:wrong_quantity"]


# --- the engine: language detected, passed through, reported ---------------------------------------------------
class FixedPlanner:
    def __init__(self, calls: list[ToolCall]):
        self.calls = calls

    def plan(self, question: str) -> Plan:
        return Plan(self.calls, "test")


@pytest.mark.parametrize(("question", "lang", "word"), [
    ("Which cabinet runs hottest?", "en", "cabinet"), ("¿Qué gabinete está más caliente?", "es", "gabinete"),
    ("Welcher Schrank ist am heißesten?", "de", "Schrank"), ("Quelle armoire est la plus chaude ?", "fr", "armoire"),
])  # fmt: skip
def test_the_engine_answers_refuses_and_reports_errors_in_the_question_s_language(site, question, lang, word):
    data, run = site
    engine = ChatEngine(data, planner=FixedPlanner([ToolCall("rank", {"quantity": "blade_temp"})]), runner=run.runner)
    reply = engine.ask(question)
    assert reply["lang"] == lang and reply["grounded"] and word in reply["answer"] and not reply["problems"]
    reply = engine.answer(question, Plan([], "test"))  # a refusal as planned (ask() may take the rules' plan)
    assert reply["refused"] and not reply["grounded"] and reply["answer"] == writer.refusal(lang)
    reply = engine.answer(question, Plan([ToolCall("plant_state", {"quantity": "blade_temp", "cabinet": 9})], "test"))
    head = PHRASES["tool_error"][lang].split("“")[0]
    assert reply["lang"] == lang and not reply["grounded"] and reply["answer"].startswith(head)

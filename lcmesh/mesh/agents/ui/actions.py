"""Chat answers about actions: why a decision was taken, what a setpoint change would do, and proposed commands.

- why: finds the newest applied action in history where the asked change happened (cabinet 3's
  branch 2 valve opened, a supply setpoint lowered ...), rebuilds the toolbox's decision facts
  for that cabinet from the stored plant state and the two applied actions, and cites them.
- what-if: asks the Sensor's ``tools/whatif`` queryable for a look-ahead on the live twin (load
  and weather held, the plant restored afterwards) and compares predicted with baseline.
- command: never applied by chat; the answer carries the exact request an operator sends to the
  authenticated control endpoint to apply it.
"""

from __future__ import annotations

import numpy as np

from lcmesh.mesh.agents.ui.answers import (
    CONVERT, Answer, ChatSources, NotReady, check_indices, question_fact, system_fact,
)  # fmt: skip
from lcmesh.mesh.agents.ui.facts import ChatFact, FactBook, fact
from lcmesh.mesh.agents.ui.gateway import MeshRefused, MeshUnavailable
from lcmesh.mesh.agents.ui.intents import CONTROLLERS, Intent
from lcmesh.mesh.messages import ActionModel, plant_state_to_observation
from lcmesh.twin.system import PSI_TO_PA

WHY_WINDOW = 240  # decisions searched back (one hour of 15 s steps)
DEAD_BAND = {"valve": 0.005, "supply": 0.05, "dp": 0.05 * PSI_TO_PA, "lw": 0.05}
WHATIF_STEPS = 4  # the toolbox's default look-ahead: one minute
MAX_WHATIF_STEPS = 240
WHATIF_LIMITS = {"supply_setpoint": 20.0, "lw_setpoint": 20.0, "dp": 200_000.0}
_KIND = {"valve": "valve", "supply_setpoint": "supply", "supply_temp": "supply", "dp": "dp", "flow": "dp",
         "lw_setpoint": "lw", "leaving_water": "lw", "tower_power": "lw"}  # fmt: skip
_FIELD = {"supply_setpoint": ("supply_temp_setpoint_k", "c", "K", "supply setpoint"),
          "dp": ("dp_setpoint_pa", "psi", "psi", "dp setpoint"),
          "lw_setpoint": ("lw_setpoint_k", "c", "K", "tower leaving-water setpoint")}  # fmt: skip
_BODY_KEY = {"supply_setpoint": "supply_temp_setpoint_c", "dp": "dp_setpoint_psi", "lw_setpoint": "lw_setpoint_c"}


def _action_fact(row: dict, name: str, path: list, convert: str, unit: str, text: str) -> ChatFact:
    value = row["action"]
    for key in path:
        value = value[key]
    return fact(name, round(CONVERT[convert](float(value)), 4), unit, text, "decision", run_id=row["run_id"],
                step=row["step"], path=["action", *path], convert=convert)  # fmt: skip


def _changed(kind: str, now: dict, prev: dict, cab: int, branch: int | None, direction: str | None):
    """(change, branch) of `kind` for cabinet `cab` between two applied actions, or None below the dead band."""
    a, b = now["action"], prev["action"]
    if kind == "valve":
        changes = np.asarray(a["valve_fractions"][cab]) - np.asarray(b["valve_fractions"][cab])
        candidates = [branch] if branch is not None else range(len(changes))
        sign = {"up": 1.0, "down": -1.0}.get(direction or "", 0.0)
        best = max(candidates, key=lambda j: changes[j] * sign if sign else abs(changes[j]))
        change = float(changes[best])
    else:
        name, index = {"supply": ("supply_temp_setpoint_k", cab), "dp": ("dp_setpoint_pa", cab),
                       "lw": ("lw_setpoint_k", 0)}[kind]  # fmt: skip
        change, best = float(a[name][index]) - float(b[name][index]), None
    band = DEAD_BAND[kind]
    ok = change > band if direction == "up" else change < -band if direction == "down" else abs(change) > band
    return (change, best) if ok else None


def answer_why(intent: Intent, src: ChatSources) -> Answer:
    """Why the newest matching decision was taken, from the toolbox facts of that step."""
    book = FactBook()
    problem = check_indices(intent, src.system, book)
    if problem:
        return Answer("why", problem, book.listed())
    state = src.latest_state()
    rows = src.history().decisions(limit=WHY_WINDOW + 1, run_id=state.run_id)
    if len(rows) < 2:
        raise NotReady("history holds fewer than two applied actions of this run yet")
    system = src.system
    per = system.n_blade_groups // system.cabinets.count
    if intent.cabinet is not None:
        cab = intent.cabinet - 1
        book.add(question_fact("cabinet", intent.cabinet, "", f"cabinet {intent.cabinet}", f"cabinet {intent.cabinet}"))
    else:
        hot = int(np.argmax(np.asarray(state.outputs["blade_temp_k"])))
        cab = hot // per
        book.add(fact("cabinet", cab + 1, "", f"cabinet {cab + 1} holds the hottest blade group", "state",
                      run_id=state.run_id, step=state.step, block="blade_temp_k", index=hot, per=per))  # fmt: skip
    kind = "valve" if intent.branch is not None else _KIND.get(intent.quantity or "", "latest")
    branch = None if intent.branch is None else intent.branch - 1
    found = None
    if kind == "latest":
        found = (rows[0], rows[1], None, None)
    else:
        for now, prev in zip(rows, rows[1:]):
            if prev["step"] == now["step"] - 1:
                hit = _changed(kind, now, prev, cab, branch, intent.direction)
                if hit is not None:
                    found = (now, prev, *hit)
                    break
    if found is None:
        return _not_found(book, kind, rows, cab, branch, intent)
    now, prev, change, branch = found
    return Answer("why", _explain(book, src, kind, now, prev, cab, branch, change), book.listed())


def _not_found(book: FactBook, kind: str, rows: list[dict], cab: int, branch: int | None, intent: Intent) -> Answer:
    book.add(fact("searched", len(rows) - 1, "", "decisions searched", "decision", run_id=rows[0]["run_id"],
                  steps=[rows[-1]["step"], rows[0]["step"]]))  # fmt: skip
    what = {"valve": "changed a branch valve", "supply": "changed its supply setpoint", "dp": "changed its dp setpoint",
            "lw": "changed the tower leaving-water setpoint"}[kind]  # fmt: skip
    if kind == "valve" and branch is not None:
        verb = {"up": "opened", "down": "closed"}.get(intent.direction or "", "moved")
        what = f"{verb} branch {{branch}}"
        book.add(question_fact("branch", branch + 1, "", f"branch {branch + 1}", f"branch {branch + 1}"))
        book.add(_action_fact(rows[0], "valve_now", ["valve_fractions", cab, branch], "raw", "fraction",
                              "the branch's valve fraction now"))  # fmt: skip
        return Answer("why", book.say(f"In the last {{searched}} decisions cabinet {{cabinet}} never {what} beyond the "
                                      "dead band; its valve fraction is {valve_now} now."), book.listed())  # fmt: skip
    return Answer("why", book.say(f"In the last {{searched}} decisions cabinet {{cabinet}} never {what} that way."),
                  book.listed())  # fmt: skip


def _toolbox_facts(book: FactBook, src: ChatSources, now: dict, prev: dict, cab: int) -> bool:
    """Add the toolbox's decision facts of that step (prefixed ``tb_``); False if the state is not stored."""
    from lcmesh.mesh.tools.facts import cabinet_decision_facts

    state = src.history().state_at(now["step"], now["run_id"])
    if state is None:
        return False
    out = plant_state_to_observation(state, src.system).out
    action = ActionModel.model_validate(now["action"]).to_action()
    previous = ActionModel.model_validate(prev["action"]).to_action()
    for f in cabinet_decision_facts(src.system, out, action, previous, state.wet_bulb_k, cab):
        book.add(fact(f"tb_{f.name}", f.value, f.unit, f.text, "decision", run_id=now["run_id"], step=now["step"],
                      cabinet=cab, toolbox=f.name), unsigned=f.kind == "change")  # fmt: skip
    return True


def _explain(book: FactBook, src: ChatSources, kind: str, now: dict, prev: dict, cab: int, branch: int | None,
             change: float | None) -> str:  # fmt: skip
    book.add(fact("step", now["step"], "", f"plant step {now['step']}", "decision", run_id=now["run_id"],
                  step=now["step"], path=["step"]))  # fmt: skip
    book.add(fact("controller", now["source_controller"], "", "controller of that action", "decision",
                  run_id=now["run_id"], step=now["step"], path=["source_controller"]))  # fmt: skip
    have = _toolbox_facts(book, src, now, prev, cab)
    parts: list[str] = []
    if kind == "valve":
        b = branch + 1
        book.add(system_fact("branch", b, "", f"branch {b}", "branch_number"))
        book.add(_action_fact(prev, "before", ["valve_fractions", cab, branch], "raw", "fraction", "valve before"))
        book.add(_action_fact(now, "after", ["valve_fractions", cab, branch], "raw", "fraction", "valve after"))
        verb = "opened" if change > 0 else "closed"
        parts.append(f"At step {{step}} the {{controller}} controller {verb} cabinet {{cabinet}}'s branch {{branch}} "
                     "valve from {before} to {after}.")  # fmt: skip
        if have:
            share = book[f"tb_branch_{b}_power_share"]
            book.add(fact("share", round(float(share.value) * 100.0, 4), "%", "the branch's share of the cabinet load",
                          "decision", **{**share.ref, "scale": 100.0}))  # fmt: skip
            parts.append(f"Branch {{branch}} carries {{share}} of the cabinet's load ({{tb_branch_{b}_power}}) and "
                         f"runs at {{tb_branch_{b}_temp}}; the hottest branch is branch {{tb_hottest_branch}} at "
                         "{tb_hottest_branch_temp}. The valve split is {tb_valve_split} (valve-to-load rank "
                         "agreement {tb_valve_power_spearman}).")  # fmt: skip
            hot = b in (book["tb_hottest_branch"].value, book["tb_most_loaded_branch"].value)
            if change > 0 and hot:
                parts.append("Opening it sends more coolant to where the heat is.")
            elif change < 0 and not hot:
                parts.append("Closing it shifts coolant towards the hotter, more loaded branches.")
            else:
                parts.append("This move is the policy's own trade-off; it does not follow the load ranking.")
    elif kind in ("supply", "dp"):
        field, conv, unit, label = {"supply": ("supply_temp_setpoint_k", "c", "degC", "supply setpoint"),
                                    "dp": ("dp_setpoint_pa", "psi", "psi", "dp setpoint")}[kind]  # fmt: skip
        book.add(_action_fact(prev, "before", [field, cab], conv, unit, f"{label} before"))
        book.add(_action_fact(now, "after", [field, cab], conv, unit, f"{label} after"))
        verb = "raised" if change > 0 else "lowered"
        parts.append(f"At step {{step}} the {{controller}} controller {verb} cabinet {{cabinet}}'s {label} from "
                     "{before} to {after}.")  # fmt: skip
        if have:
            side = "inside" if book["tb_band_margin_min"].value >= 0 else "outside"
            book.add(book["tb_band_margin_min"], unsigned=True)
            parts.append(f"Its hottest branch ran at {{tb_hottest_branch_temp}}, {{tb_band_margin_min}} {side} the "
                         "band, and the CDU supplied {tb_supply_temp}.")  # fmt: skip
            parts.append("A warmer, lower-flow setting saves pump and fan power while the blades keep margin."
                         if change > 0 else "More cooling gives the hottest branch more margin.")  # fmt: skip
    elif kind == "lw":
        book.add(_action_fact(prev, "before", ["lw_setpoint_k", 0], "c", "degC", "leaving-water setpoint before"))
        book.add(_action_fact(now, "after", ["lw_setpoint_k", 0], "c", "degC", "leaving-water setpoint after"))
        verb = "raised" if change > 0 else "lowered"
        parts.append(f"At step {{step}} the {{controller}} controller {verb} the tower leaving-water setpoint from "
                     "{before} to {after}.")  # fmt: skip
        if have:
            parts.append("The wet bulb was {tb_wet_bulb}, so the setpoint sits {tb_tower_approach_setpoint} above it; "
                         "the tower fans drew {tb_tower_fan_power}.")  # fmt: skip
    else:
        parts.append("The latest decision (step {step}) came from the {controller} controller.")
        if have:
            parts.append("For cabinet {cabinet} it set the supply setpoint to {tb_supply_setpoint} "
                         "({tb_supply_setpoint_direction}) and the dp setpoint to {tb_dp_setpoint} "
                         "({tb_dp_setpoint_direction}); its hottest branch, branch {tb_hottest_branch}, ran at "
                         "{tb_hottest_branch_temp}.")  # fmt: skip
    if now["fallback"] and now.get("fallback_reason"):
        book.add(fact("fallback", now["fallback_reason"], "", "why the step ran on a fallback", "decision",
                      run_id=now["run_id"], step=now["step"], path=["fallback_reason"]))  # fmt: skip
        parts.append("That step ran on a fallback: {fallback}.")
    mine = [cl for cl in now["clamps"] if cl.get("index") and cl["index"][0] == cab and cl["field"] != "lw_setpoint_k"]
    if mine:
        book.add(fact("clamps", len(mine), "", "guardrail clamps on this cabinet", "decision", run_id=now["run_id"],
                      step=now["step"], path=["clamps"], cabinet=cab))  # fmt: skip
        parts.append("The guardrails clamped {clamps} of this cabinet's values.")
    return book.say(" ".join(parts))


# --- what-if ---------------------------------------------------------------------------------------------
def _supported_change(intent: Intent, book: FactBook) -> str | None:
    """A request for more detail when the question's change can not be looked ahead, else None."""
    if intent.change is None:
        if intent.quantity in ("supply_setpoint", "supply_temp", "dp", "leaving_water", "lw_setpoint"):
            return ("Tell me how much to change it, e.g. \"what if I raise the supply setpoint by N K?\" or "
                    "\"what if I set the dp setpoint to N psi?\".")  # fmt: skip
        return ("I can look ahead for changes of the CDU supply setpoint, the dp setpoint and the tower "
                "leaving-water setpoint, for all cabinets or one (\"... on cabinet N\").")  # fmt: skip
    return None


def _delta_si(intent: Intent, src: ChatSources, cabinets: list[int] | None) -> float:
    change = intent.change
    if not change.absolute:
        return change.amount
    applied = src.applied()
    if applied is None:
        raise NotReady("no applied action yet: the current setpoints are not known")
    field = _FIELD[change.quantity][0]
    values = np.asarray(getattr(applied.action, field), dtype=float)
    if change.quantity == "dp":
        target = change.amount
    else:
        target = change.amount + 273.15
    picked = values if cabinets is None or change.quantity == "lw_setpoint" else values[cabinets]
    return float(target - picked.mean())


def answer_whatif(intent: Intent, src: ChatSources) -> Answer:
    """A look-ahead on the live twin through the toolbox's what-if queryable; nothing is applied."""
    book = FactBook()
    problem = check_indices(intent, src.system, book) or _supported_change(intent, book)
    if problem:
        return Answer("whatif", problem, book.listed())
    change = intent.change
    cabinets = None if intent.cabinet is None or change.quantity == "lw_setpoint" else [intent.cabinet - 1]
    delta = _delta_si(intent, src, cabinets)
    field, conv, unit, label = _FIELD[change.quantity]
    shown = delta / PSI_TO_PA if change.quantity == "dp" else delta
    book.add(question_fact("asked", round(abs(float(shown)), 4), unit, f"the {label} change asked for", change.text))
    limit = WHATIF_LIMITS[change.quantity]
    if abs(delta) > limit:
        book.add(system_fact("limit", limit / PSI_TO_PA if change.quantity == "dp" else limit, unit,
                             "largest change a look-ahead accepts", f"whatif.{field}"))  # fmt: skip
        return Answer("whatif", book.say(f"A {label} change of {{asked}} is beyond what the look-ahead accepts "
                                         "({limit}); ask about a smaller step."), book.listed())  # fmt: skip
    key = {"supply_setpoint": "supply_temp_setpoint_delta_k", "dp": "dp_setpoint_delta_pa",
           "lw_setpoint": "lw_setpoint_delta_k"}[change.quantity]  # fmt: skip
    steps = WHATIF_STEPS
    if intent.window_s is not None:  # "... in 10 minutes": look that far ahead (at most one hour)
        steps = int(min(MAX_WHATIF_STEPS, max(1, round(intent.window_s / src.system.step_s))))
    request = {key: round(delta, 6), "steps": steps, **({"cabinets": cabinets} if cabinets else {})}
    try:
        result = src.gateway.tool("whatif", request)
    except MeshRefused as exc:
        book.add(fact("tool_error", str(exc), "", "the what-if tool's answer", "whatif", request=request))
        return Answer("whatif", book.say("The look-ahead refused the request: {tool_error}"), book.listed())
    except MeshUnavailable as exc:
        raise NotReady(str(exc)) from None
    return Answer("whatif", _whatif_text(book, intent, request, result, delta, label), book.listed(),
                  proposed_command=_whatif_command(result, change.quantity, cabinets, src))  # fmt: skip


def _whatif_text(book: FactBook, intent: Intent, request: dict, result: dict, delta: float, label: str) -> str:
    change_quantity = intent.change.quantity
    def tool_fact(name: str, path: str, reduce: str, convert: str, unit: str, text: str, over=None) -> ChatFact:
        branch, block = path.split(".")
        values = np.asarray(result[branch][block], dtype=float).ravel()
        picked = values if over is None else values[over]
        si = float({"max": np.max, "mean": np.mean, "sum": np.sum}[reduce](picked))
        return book.add(fact(name, round(CONVERT[convert](si), 4), unit, text, "whatif", request=request, path=path,
                             reduce=reduce, over=over, si=si, convert=convert))  # fmt: skip

    book.add(fact("horizon", round(result["horizon_s"] / 60.0, 4), "min", "look-ahead horizon", "whatif",
                  request=request, path="horizon_s", si=result["horizon_s"], scale=1 / 60.0))  # fmt: skip
    for tag in ("baseline", "predicted"):
        tool_fact(f"{tag}_blade", f"{tag}.blade_temp_k", "max", "c", "degC", f"hottest blade group, {tag}")
        tool_fact(f"{tag}_fans", f"{tag}.ct_fan_power_w", "sum", "kw", "kW", f"tower fan power, {tag}")
        tool_fact(f"{tag}_pumps", f"{tag}.pump_power_w", "sum", "kw", "kW", f"pump power, {tag}")
    blade_change = round(book["predicted_blade"].value - book["baseline_blade"].value, 4)
    book.add(fact("blade_change", blade_change, "K", "predicted minus baseline hottest blade group", "whatif",
                  request=request, derived="predicted_blade - baseline_blade"), unsigned=True)  # fmt: skip
    verb = "raising" if delta > 0 else "lowering"
    if intent.cabinet is not None and "cabinets" in request:
        book.add(question_fact("cabinet", intent.cabinet, "", f"cabinet {intent.cabinet}", f"cabinet {intent.cabinet}"))
        scope = "cabinet {cabinet}'s"
    else:
        scope = "the" if change_quantity == "lw_setpoint" else "every cabinet's"
    supply = ""
    if change_quantity == "supply_setpoint":  # a setpoint below what the CDU can reach changes little: show it
        over = request.get("cabinets")
        tool_fact("baseline_supply", "baseline.supply_temp_k", "mean", "c", "degC", "CDU supply, baseline", over)
        tool_fact("predicted_supply", "predicted.supply_temp_k", "mean", "c", "degC", "CDU supply, predicted", over)
        supply = " The CDU supply would be {predicted_supply} instead of {baseline_supply}."
    trend = "up" if blade_change > 0.05 else "down" if blade_change < -0.05 else "about the same,"
    return book.say(
        f"Look-ahead on the live twin, {{horizon}} ahead with load and weather held: {verb} "
        f"{scope} {label} by {{asked}} gives a hottest blade group of {{predicted_blade}} instead of "
        f"{{baseline_blade}} ({trend} {{blade_change}}), tower fans {{predicted_fans}} instead of {{baseline_fans}} "
        "and pumps {predicted_pumps} instead of {baseline_pumps}." + supply + " Nothing was changed: the proposed "
        "command applies it once an operator confirms."
    )  # fmt: skip


def _whatif_command(result: dict, quantity: str, cabinets: list[int] | None, src: ChatSources) -> dict:
    """The setpoints request that would apply what the look-ahead tried (absolute values, UI units)."""
    action = result["action"]
    field, conv, _unit, _label = _FIELD[quantity]
    values = [round(CONVERT[conv](float(v)), 3) for v in np.asarray(action[field], dtype=float).ravel()]
    body: dict = {_BODY_KEY[quantity]: values, "reason": "chat what-if, confirmed by an operator"}
    return {"method": "POST", "path": "/api/control/setpoints", "body": body,
            "summary": f"set the {_FIELD[quantity][3]} to the values the look-ahead tried"}  # fmt: skip


# --- commands --------------------------------------------------------------------------------------------
def answer_command(intent: Intent, src: ChatSources) -> Answer:
    """A proposed command for the operator to confirm; chat itself never actuates."""
    book = FactBook()
    problem = check_indices(intent, src.system, book)
    if problem:
        return Answer("command", problem, book.listed())
    confirm = " Chat does not change the plant: an operator confirms by sending the proposed request with the API token."
    if intent.controller is not None or (intent.mode is not None and intent.change is None):
        body: dict = {}
        if intent.controller is not None:
            body["controller"] = intent.controller
            book.add(question_fact("requested", intent.controller, "", "controller asked for", intent.controller))
        if intent.mode is not None:
            body["mode"] = intent.mode
            book.add(question_fact("mode", intent.mode, "", "mode asked for", intent.mode))
        doc = src.config()
        text = book.say("Proposed: switch to the {requested} controller." if "controller" in body
                        else "Proposed: switch to {mode} mode.")  # fmt: skip
        if doc is not None:
            book.add(fact("current", doc.config.controller, "", "configured controller", "config", version=doc.version,
                          path=["controller"]))  # fmt: skip
            text += book.say(" The configured controller is {current}.")
        return Answer("command", text + confirm, book.listed(),
                      proposed_command={"method": "POST", "path": "/api/control/mode", "body": body,
                                        "summary": text})  # fmt: skip
    if intent.change is None:
        book.add(system_fact("controllers", ", ".join(CONTROLLERS), "", "registered controllers", "controllers"))
        return Answer("command", book.say("I can propose a supply, dp or tower leaving-water setpoint change (\"set "
                                          "the supply setpoint of cabinet N to X °C\", \"lower the dp setpoint by N "
                                          "psi\"), a controller switch ({controllers}) or auto / manual mode.")
                      + confirm, book.listed())  # fmt: skip
    return _setpoint_command(intent, src, book, confirm)


def _setpoint_command(intent: Intent, src: ChatSources, book: FactBook, confirm: str) -> Answer:
    applied = src.applied()
    if applied is None:
        raise NotReady("no applied action yet: the current setpoints are not known")
    change = intent.change
    field, conv, unit, label = _FIELD[change.quantity]
    shown_unit = "degC" if conv == "c" else unit
    current = np.asarray(getattr(applied.action, field), dtype=float)
    per_tower = change.quantity == "lw_setpoint"
    selected = list(range(current.size)) if intent.cabinet is None or per_tower else [intent.cabinet - 1]
    target = current.copy()
    if change.absolute:
        target[selected] = change.amount + (0.0 if change.quantity == "dp" else 273.15)
    else:
        target[selected] += change.amount
    values = [round(CONVERT[conv](float(v)), 3) for v in target]
    row = {"run_id": applied.run_id, "step": applied.step, "action": applied.action.model_dump()}
    now = round(float(np.mean([CONVERT[conv](float(current[i])) for i in selected])), 4)
    book.add(fact("now", now, shown_unit, f"{label} now (mean of the selected)", "decision", run_id=row["run_id"],
                  step=row["step"], path=["action", field], over=selected, reduce="mean", convert=conv))  # fmt: skip
    proposed = round(float(np.mean([values[i] for i in selected])), 4)
    book.add(fact("proposed", proposed, shown_unit, f"proposed {label} (mean of the selected)", "question",
                  words=change.text, values=values, over=selected))  # fmt: skip
    asked = change.amount / PSI_TO_PA if change.quantity == "dp" else change.amount
    asked_unit = shown_unit if change.absolute else unit
    book.add(question_fact("asked", round(abs(asked), 3), asked_unit, f"the {label} asked for", change.text))
    if intent.cabinet is not None and not per_tower:
        book.add(question_fact("cabinet", intent.cabinet, "", f"cabinet {intent.cabinet}", f"cabinet {intent.cabinet}"))
        scope = "cabinet {cabinet}'s"
    else:
        scope = "the" if per_tower else "every cabinet's"
    if change.absolute:
        text = book.say(f"Proposed: set {scope} {label} to {{asked}} (now {{now}}).")
    else:
        verb = "raise" if change.amount > 0 else "lower"
        average = " on average" if len(selected) > 1 else ""
        text = book.say(f"Proposed: {verb} {scope} {label} by {{asked}}, from {{now}} to {{proposed}}{average}.")
    body = {_BODY_KEY[change.quantity]: values, "reason": "chat proposal, confirmed by an operator"}
    return Answer("command", text + confirm, book.listed(),
                  proposed_command={"method": "POST", "path": "/api/control/setpoints", "body": body,
                                    "summary": text})  # fmt: skip


__all__ = ["answer_why", "answer_whatif", "answer_command"]

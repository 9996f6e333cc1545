"""Explain-eval records from our own pipeline: a controller on the twin, facts and the renderer per decision.

This is how the targets (numeric grounding >= 0.98, coverage 1.0, direction consistency >= 0.95 over
an evaluation day) are measured: ``lcmesh explain-twin ... --out day.jsonl`` then
``lcmesh explain-eval --input day.jsonl --json scores.json`` (or ``lcmesh bench explain``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence

import numpy as np

from lcmesh.mesh.tools.explain import LEVELS, Level, explanation_record, render_explanation
from lcmesh.mesh.tools.facts import cabinet_decision_facts
from lcmesh.twin.controllers import Controller, Observation
from lcmesh.twin.plant import Plant
from lcmesh.twin.traces import Trace


def twin_explanation_records(
    plant: Plant,
    trace: Trace,
    controller: Controller,
    *,
    n_steps: int,
    every_steps: int = 40,
    levels: Sequence[Level] = LEVELS,
    cabinets: Sequence[int] | None = None,
    spinup_hours: float = 1.0,
    on_step: Callable[[int], None] | None = None,
) -> Iterator[dict]:
    """Run ``controller`` like ``run_twin`` and yield one record per (decision, cabinet, level) every
    ``every_steps`` steps; the decision's previous action is the controller's action one step before."""
    if every_steps < 1:
        raise ValueError(f"`every_steps` must be >= 1, got {every_steps}")
    bad = [lv for lv in levels if lv not in LEVELS]
    if bad:
        raise ValueError(f"`levels` must be among {', '.join(LEVELS)}, got {bad}")
    system = plant.system
    cabinets = range(system.cabinets.count) if cabinets is None else cabinets
    power = np.zeros(system.n_blade_groups)
    n_steps = min(n_steps, trace.n_steps)
    controller.reset()
    first = Observation(plant.out, float(trace.wet_bulb_k[0]), trace.blade_power_w(0, out=power), 0.0)
    previous = controller.act(first).copy()
    if spinup_hours > 0:
        plant.spin_up(power, first.wet_bulb_k, previous, hours=spinup_hours)
    out = plant.reset()
    controller.reset()
    for k in range(n_steps):
        wet_bulb = float(trace.wet_bulb_k[k])
        trace.blade_power_w(k, out=power)
        action = controller.act(Observation(out, wet_bulb, power, k * trace.step_s))
        if k % every_steps == 0:
            for c in cabinets:
                facts = cabinet_decision_facts(system, out, action, previous, wet_bulb, c)
                for level in levels:
                    text = render_explanation(facts, level)
                    yield explanation_record(out, action, facts, text, cabinet=c, previous_action=previous,
                                             wet_bulb_k=wet_bulb, level=level,
                                             record_id=f"{controller.name}-step{k}-cabinet{c + 1}-{level}")  # fmt: skip
        previous = action.copy()  # controllers may reuse their action object
        out = plant.step(power, wet_bulb, action)
        if on_step is not None:
            on_step(k)

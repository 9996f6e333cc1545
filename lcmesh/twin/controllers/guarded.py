"""A controller behind the mesh's guardrails, for every run outside the mesh (issue 23, item 1).

The mesh's Sensor passes every proposal through ``apply_guardrails`` against the action it applied last
(lcmesh/mesh/agents/sensor.py). :class:`Guarded` does the same around any controller, so that
``run_twin``, the benches, PPO training and the distillers score what the mesh would apply: the same
``GuardrailLimits`` and the same function, not a copy. A proposal the guardrails reject (wrong shape,
non-finite) is replaced by the last applied action, as the Sensor holds it. What the guardrails did is
counted: steps decided, steps with at least one clamp, values clamped, proposals rejected.

``guardrails=None`` runs the controller bare: the paper's setting, named so in every table.
"""

from __future__ import annotations

import numpy as np

from lcmesh.mesh.tools.guardrails import GuardrailLimits, apply_guardrails
from lcmesh.twin.controllers.base import Controller, Observation
from lcmesh.twin.plant import PlantAction
from lcmesh.twin.system import SystemDescription

MESH_GUARDRAILS = GuardrailLimits()
"""The mesh's default limits (``MeshConfig.guardrails``): what every run applies unless told otherwise."""


def applied_action(out: dict) -> PlantAction:
    """The setpoints the plant applied at its last step, as an action (the guardrails' "previous")."""
    return PlantAction(
        out["applied_supply_setpoint_k"].copy(), out["applied_dp_setpoint_pa"].copy(),
        out["applied_valve_fraction"].copy(), out["applied_lw_setpoint_k"].copy(),
    )  # fmt: skip


class Guarded:
    """``inner`` with ``apply_guardrails`` on every action, against the last one applied."""

    def __init__(self, inner: Controller, system: SystemDescription, limits: GuardrailLimits = MESH_GUARDRAILS):
        limits.check_system(system)
        self.inner, self.system, self.limits = inner, system, limits
        self._last: PlantAction | None = None
        self.reset_counts()

    @property
    def name(self) -> str:
        return self.inner.name

    @property
    def version(self) -> str:
        return self.inner.version

    def __getattr__(self, attr: str):
        # what the wrapper does not define is the controller's: attach, sim_steps, stats_snapshot, ...
        if attr == "inner":
            raise AttributeError(attr)
        return getattr(self.inner, attr)

    def reset_counts(self) -> None:
        self.steps = self.clamped_steps = self.clamped_values = self.rejected = 0

    def reset(self) -> None:
        self.inner.reset()
        self._last = None
        self.reset_counts()

    def act(self, obs: Observation) -> PlantAction:
        proposed = self.inner.act(obs)
        previous = self._last if self._last is not None else applied_action(obs.out)
        if self._last is None and not np.all(previous.supply_temp_setpoint_k > 0.0):
            previous = proposed  # a plant that has applied nothing yet: the ranges only
        result = apply_guardrails(proposed, previous, obs.wet_bulb_k, self.limits, self.system)
        if result.action is None:  # rejected: hold what is in force, as the Sensor does
            self.rejected += 1
            result = apply_guardrails(previous, previous, obs.wet_bulb_k, self.limits, self.system)
        self.steps += 1
        if result.clamps:
            self.clamped_steps += 1
            self.clamped_values += len(result.clamps)
        self._last = result.action.copy()
        return result.action

    def spinup_action(self, obs: Observation) -> PlantAction:
        """The action a spin-up holds: the proposal inside the ranges, with no rate limit (nothing is applied yet;
        the mesh's Sensor spins up on its first G36 action the same way)."""
        proposed = self.inner.act(obs)
        result = apply_guardrails(proposed, proposed, obs.wet_bulb_k, self.limits, self.system)
        if result.action is None:
            raise ValueError(f"{self.name}: its first action can not be applied: {result.rejected}")
        return result.action

    def report(self) -> dict:
        """What the guardrails did since the last reset (JSON-ready)."""
        n = max(self.steps, 1)
        return {
            "guardrails": "mesh",
            "steps": self.steps,
            "clamped_steps": self.clamped_steps,
            "clamped_steps_pct": 100.0 * self.clamped_steps / n,
            "clamped_values": self.clamped_values,
            "rejected": self.rejected,
        }


def guard(controller: Controller, system: SystemDescription, limits: GuardrailLimits | None) -> Controller:
    """``controller`` behind ``limits`` (None: bare); a controller already guarded is returned as it is."""
    if limits is None or isinstance(controller, Guarded):
        return controller
    return Guarded(controller, system, limits)


def spinup_action(controller: Controller, obs: Observation) -> PlantAction:
    """What a run spins the plant up on: ``Guarded.spinup_action``, or a bare controller's own action."""
    return controller.spinup_action(obs) if isinstance(controller, Guarded) else controller.act(obs)


def guardrail_report(controller: Controller) -> dict:
    """``Guarded.report()``, or ``{"guardrails": "off"}`` for a bare controller."""
    return controller.report() if isinstance(controller, Guarded) else {"guardrails": "off"}

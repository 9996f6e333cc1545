"""G36 with load-proportional valves, the strong simple baseline a sceptic writes.

Guideline 36 as in ``g36.py`` (same trim-and-respond for the CDU supply and the tower leaving water,
same dp), with one change: each cabinet's branch valves open in proportion to the coming step's
branch power (the observation's ``blade_power_w`` summed per branch), with a floor so an idle branch
keeps some flow: ``v_j = floor + (1 - B floor) P_j / sum P``; equal split when the cabinet is idle.
A learned controller has to beat this, not G36's equal split, to claim its valves help.
"""

from __future__ import annotations

import numpy as np

from lcmesh.twin.controllers.base import Observation
from lcmesh.twin.controllers.g36 import G36Controller
from lcmesh.twin.plant import PlantAction
from lcmesh.twin.system import SystemDescription

MIN_VALVE_FRACTION = 0.02  # the floor the learned policies' valve heads use (docs/controllers.md)


def load_proportional_valves(
    system: SystemDescription, blade_power_w: np.ndarray, floor: float = MIN_VALVE_FRACTION,
    out: np.ndarray | None = None,
) -> np.ndarray:  # fmt: skip
    """(C, B) valve fractions proportional to branch power, each at least `floor`; equal for an idle cabinet."""
    cab = system.cabinets
    C, B = cab.count, cab.branches
    branch_w = np.asarray(blade_power_w, dtype=float).reshape(C, B, cab.blade_groups_per_branch).sum(axis=2)
    total_w = branch_w.sum(axis=1, keepdims=True)
    share = np.divide(branch_w, total_w, out=np.full((C, B), 1.0 / B), where=total_w > 0)
    out = np.empty((C, B)) if out is None else out
    out[:] = floor + (1.0 - B * floor) * share
    return out


class RuleController(G36Controller):
    """G36 with load-proportional valves, the strong simple baseline a sceptic writes."""

    name = "rule"
    version = "1"

    def __init__(self, system: SystemDescription, min_valve_fraction: float = MIN_VALVE_FRACTION, **g36_options):
        B = system.cabinets.branches
        if not 0 <= min_valve_fraction <= 1.0 / B:
            raise ValueError(f"`min_valve_fraction` must be in [0, 1/{B}], got {min_valve_fraction}")
        self.min_valve_fraction = min_valve_fraction
        super().__init__(system, **g36_options)

    def act(self, obs: Observation) -> PlantAction:
        action = super().act(obs)
        load_proportional_valves(self.system, obs.blade_power_w, self.min_valve_fraction, out=action.valve_fractions)
        return action

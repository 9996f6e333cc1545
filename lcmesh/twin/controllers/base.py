"""The controller interface shared by baselines, RL policies, trees and the LLM."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from lcmesh.twin.plant import PlantAction


@dataclass(frozen=True)
class Observation:
    """What a controller sees before deciding a step: the plant outputs after the last step."""

    out: Mapping[str, np.ndarray]  # plant output blocks (SI units), see lcmesh.twin.plant.OUTPUT_BLOCKS
    wet_bulb_k: float  # wet bulb for the coming step
    blade_power_w: np.ndarray  # (C*B*G,) IT load for the coming step
    time_s: float


class Controller(Protocol):
    """What every controller provides. ``make_controller`` checks it for third-party classes.

    One optional hook: ``attach(plant, trace)``. ``lcmesh.twin.run.run_twin`` calls it, when the controller
    has it, before the spin-up, with the running plant and the whole trace; a controller that simulates ahead
    (``lookahead``) keeps them. The mesh never calls it, so the mesh refuses controllers that need it
    (``NEEDS_PLANT``).
    """

    name: str
    version: str

    def reset(self) -> None:
        """Forget history (episode start)."""

    def act(self, obs: Observation) -> PlantAction:
        """Setpoints for the coming step."""

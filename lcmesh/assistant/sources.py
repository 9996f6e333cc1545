"""Where the assistant's data tools read in the live mesh: the UI agent's plant state, history and configuration.

``ChatSources`` has the ``PlantData`` shape of ``lcmesh.mesh.tools.plant_data`` (the recorded bench
site has it too). ``NotReady`` (HTTP 503) means the data is not there yet.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from lcmesh.mesh.history import HistoryReader
from lcmesh.mesh.messages import ConfigDoc, PlantState
from lcmesh.mesh.tools.plant_data import NotReady
from lcmesh.twin.system import SystemDescription

__all__ = ["ChatSources", "NotReady"]


@dataclass
class ChatSources:
    """The UI agent's live data, as the data tools read it."""

    system: SystemDescription
    state: Callable[[], PlantState | None]
    history: Callable[[], HistoryReader]
    config: Callable[[], ConfigDoc | None]
    agents: Callable[[], list[dict]]
    gateway: Any = None  # MeshGateway: the Sensor's what-if tool
    applied: Callable[[], Any] = lambda: None

    def latest_state(self) -> PlantState:
        state = self.state()
        if state is None:
            raise NotReady("no plant state has arrived yet from the Sensor agent (is it running?)")
        return state

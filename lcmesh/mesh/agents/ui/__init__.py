"""The UI agent: REST API, grounded chat, live web page and Prometheus metrics (docs/ui.md)."""

from lcmesh.mesh.agents.ui.agent import UiAgent

__all__ = ["UiAgent"]

"""Agent roles by name, as ``"module:Class"`` strings so an agent's heavy imports load only in its process.

Every class is an ``lcmesh.mesh.agents.base.Agent`` subclass built as ``Class(settings, agent_id)``.
"""

from __future__ import annotations

import difflib
import importlib

ROLES: dict[str, str] = {
    "configuration": "lcmesh.mesh.agents.configuration:ConfigurationAgent",
    "sensor": "lcmesh.mesh.agents.sensor:SensorAgent",
    "control": "lcmesh.mesh.agents.control:ControlAgent",
    "maintenance": "lcmesh.mesh.agents.maintenance:MaintenanceAgent",
    "monitor": "lcmesh.mesh.agents.monitor:MonitorAgent",
    "orchestration": "lcmesh.mesh.agents.orchestration:OrchestrationAgent",
    "ui": "lcmesh.mesh.agents.ui:UiAgent",
}


class AgentUnavailable(RuntimeError):
    """A registered role whose module does not import (yet)."""


def check_role(role: str) -> str:
    """`role` if registered, else a ValueError suggesting the closest name."""
    if role not in ROLES:
        close = difflib.get_close_matches(role, ROLES, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise ValueError(f"unknown agent role {role!r}{hint} (known: {', '.join(ROLES)})")
    return role


def load_agent_class(role: str):
    """The Agent class of `role`; AgentUnavailable if its module does not import."""
    module_name, class_name = ROLES[check_role(role)].split(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise AgentUnavailable(f"role {role!r}: {module_name} does not import ({type(exc).__name__}: {exc})") from exc
    try:
        return getattr(module, class_name)
    except AttributeError as exc:
        raise AgentUnavailable(f"role {role!r}: {module_name} has no class {class_name}") from exc


def unavailable_reason(role: str) -> str | None:
    """Why `role` can not run in this installation, or None if its class loads."""
    try:
        load_agent_class(role)
    except AgentUnavailable as exc:
        return str(exc)
    return None

"""The mesh agents, one module per role (registry: ``lcmesh.mesh.agents.registry.ROLES``)."""

from lcmesh.mesh.agents.registry import ROLES, AgentUnavailable, check_role, load_agent_class

__all__ = ["ROLES", "AgentUnavailable", "check_role", "load_agent_class"]

"""lcmesh router, lcmesh agent ROLE, lcmesh demo, lcmesh bench mesh (the mesh issue)."""

from __future__ import annotations

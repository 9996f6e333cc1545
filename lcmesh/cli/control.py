"""lcmesh train ppo, lcmesh distill tree, lcmesh bench control (the controllers issue)."""

from __future__ import annotations

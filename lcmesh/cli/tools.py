"""lcmesh bench maintenance (the toolbox and fault-detector benchmark)."""

from __future__ import annotations

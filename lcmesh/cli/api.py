"""lcmesh bench api (the UI agent issue)."""

from __future__ import annotations

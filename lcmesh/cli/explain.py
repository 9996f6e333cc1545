"""lcmesh explain-eval (explanation scoring)."""

from __future__ import annotations

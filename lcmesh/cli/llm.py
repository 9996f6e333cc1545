"""lcmesh distill llm, lcmesh bench llm (the LLM controller issue)."""

from __future__ import annotations

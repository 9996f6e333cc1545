"""Controllers that turn plant observations into setpoints.

The registry maps names to ``"module:Class"`` strings so heavy imports (torch) load only when used.
"""

from __future__ import annotations

import difflib
import importlib

from lcmesh.twin.controllers.base import Controller, Observation

REGISTRY: dict[str, str] = {
    "static": "lcmesh.twin.controllers.static:StaticController",
    "g36": "lcmesh.twin.controllers.g36:G36Controller",
    "ppo": "lcmesh.distill.policy:PpoController",
    "tree": "lcmesh.distill.trees:TreeController",
    "llm": "lcmesh.llm.controller:LlmController",
}


def make_controller(name: str, system, **kwargs) -> Controller:
    """Instantiate a registered controller for `system`."""
    if name not in REGISTRY:
        close = difflib.get_close_matches(name, REGISTRY, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise ValueError(f"unknown controller {name!r}{hint} (known: {', '.join(sorted(REGISTRY))})")
    module, cls = REGISTRY[name].split(":")
    return getattr(importlib.import_module(module), cls)(system, **kwargs)


__all__ = ["Controller", "Observation", "REGISTRY", "make_controller"]

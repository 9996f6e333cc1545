"""Controllers that turn plant observations into setpoints.

The registry maps names to ``"module:Class"`` strings so heavy imports (torch) load only when used. A name
that is itself ``"package.module:Class"`` is a third-party controller (docs/controllers.md, "Bring your own
controller"): imported, made with the system, and checked against the `Controller` protocol.
"""

from __future__ import annotations

import difflib
import importlib
import re
from collections.abc import Collection

from lcmesh.twin.controllers.base import Controller, Observation

REGISTRY: dict[str, str] = {
    "static": "lcmesh.twin.controllers.static:StaticController",
    "g36": "lcmesh.twin.controllers.g36:G36Controller",
    "rule": "lcmesh.twin.controllers.rule:RuleController",
    "lookahead": "lcmesh.twin.controllers.lookahead:LookaheadController",
    "ppo": "lcmesh.distill.policy:PpoController",
    "tree": "lcmesh.distill.trees:TreeController",
    "readable": "lcmesh.distill.trees:ReadableTreeController",
    "llm": "lcmesh.llm.controller:LlmController",
}
# registered controllers that simulate the plant itself (they need `attach(plant, trace)`): run by
# `lcmesh twin run` and the benches, never by the mesh, which has no trace of the future to give them
NEEDS_PLANT = frozenset({"lookahead"})
PLUGIN_PATTERN = r"^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*:[A-Za-z_][A-Za-z0-9_]*$"


class ControllerError(ValueError):
    """A controller name that does not resolve to a working controller (the message says why)."""


def is_plugin(name: str) -> bool:
    """Whether `name` names a third-party controller (``"package.module:Class"``) rather than a registry entry."""
    return ":" in name


def make_controller(name: str, system, **kwargs) -> Controller:
    """Instantiate the registered controller `name`, or the third-party ``"package.module:Class"``, for `system`."""
    if is_plugin(name):
        return _make_plugin(name, system, **kwargs)
    if name not in REGISTRY:
        close = difflib.get_close_matches(name, REGISTRY, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise ControllerError(
            f"unknown controller {name!r}{hint} (known: {', '.join(sorted(REGISTRY))}, or 'package.module:Class')"
        )
    module, cls = REGISTRY[name].split(":")
    return getattr(importlib.import_module(module), cls)(system, **kwargs)


def mesh_refusal(name: str, allowed_plugins: Collection[str] = ()) -> str | None:
    """Why the mesh may not run controller `name` (None: it may), as "must be ..." text after "`controller` ".

    The mesh runs registered controllers except those needing the plant (``NEEDS_PLANT``), and third-party ones
    only when `allowed_plugins` (the ``controller_plugins`` setting, plus the process's own ``controller``) lists
    them: a name arriving on the bus must not import an arbitrary module.
    """
    known = sorted(set(REGISTRY) - NEEDS_PLANT)
    if is_plugin(name):
        if not re.match(PLUGIN_PATTERN, name):
            return f"must name a third-party controller as 'package.module:Class', got {name!r}"
        if name not in allowed_plugins:
            listed = ", ".join(sorted(allowed_plugins)) or "none"
            return (f"must be a registered controller or a plugin listed in LCMESH_CONTROLLER_PLUGINS (listed: {listed}),"
                    f" got {name!r}")  # fmt: skip
        return None
    if name in NEEDS_PLANT:
        return (f"must be one the mesh can run ({', '.join(known)}), got {name!r}: it simulates the plant with the "
                "trace's future (a perfect-forecast ceiling); run it with `lcmesh twin run` or the benches")  # fmt: skip
    if name not in REGISTRY:
        close = difflib.get_close_matches(name, known, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        return f"must be one of {', '.join(known)} or an allow-listed 'package.module:Class', got {name!r}{hint}"
    return None


def protocol_gaps(controller: object) -> list[str]:
    """What `controller` lacks of the `Controller` protocol: string `name` and `version`, callable `reset` and `act`."""
    gaps = [f"a string `{a}`" for a in ("name", "version") if not isinstance(getattr(controller, a, None), str)]
    return gaps + [f"a method `{a}`" for a in ("reset", "act") if not callable(getattr(controller, a, None))]


def _make_plugin(spec: str, system, **kwargs) -> Controller:
    module_name, _, class_name = spec.partition(":")
    if not module_name or not class_name or ":" in class_name:
        raise ControllerError(f"controller {spec!r}: a third-party controller is named 'package.module:Class'")
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if exc.name is not None and (module_name == exc.name or module_name.startswith(exc.name + ".")):
            raise ControllerError(f"controller {spec!r}: no module named {module_name!r} (is its package installed "
                                  "or on PYTHONPATH?)") from exc  # fmt: skip
        raise ControllerError(f"controller {spec!r}: importing {module_name!r} failed: {exc}") from exc
    except Exception as exc:  # the module itself is broken: say so at the edge, with its own error
        raise ControllerError(f"controller {spec!r}: importing {module_name!r} failed: "
                              f"{type(exc).__name__}: {exc}") from exc  # fmt: skip
    cls = getattr(module, class_name, None)
    if cls is None:
        public = [n for n in vars(module) if not n.startswith("_")]
        close = difflib.get_close_matches(class_name, public, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise ControllerError(f"controller {spec!r}: module {module_name!r} has no {class_name!r}{hint}")
    if not callable(cls):
        raise ControllerError(f"controller {spec!r}: {class_name!r} is not a class (type {type(cls).__name__})")
    try:
        controller = cls(system, **kwargs)
    except TypeError as exc:
        raise ControllerError(f"controller {spec!r}: {class_name}(system, **options) failed: {exc}") from exc
    gaps = protocol_gaps(controller)
    if gaps:
        raise ControllerError(f"controller {spec!r} does not follow the Controller protocol "
                              f"(lcmesh/twin/controllers/base.py): it lacks {', '.join(gaps)}")  # fmt: skip
    return controller


__all__ = [
    "NEEDS_PLANT",
    "PLUGIN_PATTERN",
    "REGISTRY",
    "Controller",
    "ControllerError",
    "Observation",
    "is_plugin",
    "make_controller",
    "mesh_refusal",
    "protocol_gaps",
]

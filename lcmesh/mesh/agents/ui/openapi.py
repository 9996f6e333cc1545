"""The OpenAPI document of one site: FastAPI's, with what only the running UI knows filled in.

The request models are static; the UI serving a plant knows more, and says it so that a client
(or a fuzzer) can tell a valid request from the document alone:

- ``SetpointsRequest``: a list holds one value per cabinet (``C``), tower (``N``) or branch (``B``),
  ``cabinets`` count 1..C;
- ``ChatQuestion.message``: at most ``LCMESH_UI_CHAT_MAX_CHARS`` characters;
- ``ConfigChange.changes``: the keys and value types of the configuration (a partial ``MeshConfig``:
  nested sections merge, so nothing is required), the controller one the mesh runs (the registry less
  ``NEEDS_PLANT``, plus the allowed ``controller_plugins``; ``ModeRequest.controller`` likewise), a manual
  action shaped for this plant, ``valve_fraction_min`` at most 1 / branches, ``valve_exercise_s``
  0 or at least 60. Rules between fields (``supply_temp_min_k`` below ``supply_temp_max_k``) are
  the Configuration agent's, checked on the merged document (422 naming the fields).
"""

from __future__ import annotations

import copy
import json
from collections.abc import Sequence
from typing import Any

from fastapi import FastAPI
from fastapi.openapi.utils import get_openapi

from lcmesh.mesh.agents.ui.config import UiSettings
from lcmesh.mesh.agents.ui.schemas import MESH_CONTROLLERS
from lcmesh.mesh.messages import MeshConfig
from lcmesh.mesh.settings import MIN_VALVE_EXERCISE_S
from lcmesh.twin.system import SystemDescription


def site_openapi(
    app: FastAPI, system: SystemDescription, ui: UiSettings, controller_plugins: Sequence[str] = ()
) -> dict[str, Any]:
    """The OpenAPI document of `app` serving `system` with the limits of `ui` and the allowed third-party controllers."""
    doc = get_openapi(title=app.title, version=app.version, summary=app.summary, description=app.description,
                      routes=app.routes)  # fmt: skip
    schemas = doc["components"]["schemas"]
    C, B, N = system.cabinets.count, system.cabinets.branches, system.towers.count
    setpoints = schemas["SetpointsRequest"]["properties"]
    for name, count in (("supply_temp_setpoint_c", C), ("dp_setpoint_psi", C), ("lw_setpoint_c", N)):
        for option in setpoints[name]["anyOf"]:
            if option.get("type") == "array":
                option.update(minItems=count, maxItems=count)
    for option in setpoints["valve_fractions"]["anyOf"]:
        if option.get("type") == "array" and option["items"].get("type") == "array":
            option.update(minItems=C, maxItems=C)
            option["items"].update(minItems=B, maxItems=B)
        elif option.get("type") == "array":
            option.update(minItems=B, maxItems=B)
    for option in setpoints["cabinets"]["anyOf"]:
        if option.get("type") == "array":
            option["items"]["maximum"] = C
    schemas["ChatQuestion"]["properties"]["message"]["maxLength"] = ui.chat_max_chars
    controllers = {"type": "string", "enum": [*MESH_CONTROLLERS, *controller_plugins]}
    mode = schemas["ModeRequest"]["properties"]["controller"]
    mode["anyOf"] = [controllers, {"type": "null"}]
    changes = schemas["ConfigChange"]["properties"]["changes"]
    schemas["ConfigChange"]["properties"]["changes"] = {**_config_changes(C, B, N, controllers), "description":
                                                        changes.get("description", "")}  # fmt: skip
    _drop_unused(doc)
    return doc


def _drop_unused(doc: dict[str, Any]) -> None:
    """Remove component schemas nothing refers to any more (the static ones the site's replaced)."""
    schemas = doc["components"]["schemas"]
    while True:
        text = json.dumps({**doc, "components": {**doc["components"], "schemas": {}}}) + json.dumps(
            [v for v in schemas.values()])  # fmt: skip
        unused = [name for name in schemas if f'"#/components/schemas/{name}"' not in text]
        if not unused:
            return
        for name in unused:
            del schemas[name]


def _config_changes(C: int, B: int, N: int, controllers: dict[str, Any]) -> dict[str, Any]:
    """JSON Schema of a partial MeshConfig for a plant of C cabinets of B branches and N towers."""
    full = MeshConfig.model_json_schema()
    partial = _inline(full, full.get("$defs", {}))
    props = partial["properties"]
    props["controller"] = {**controllers, "description": "a registered controller the mesh runs, or a "
                           "'package.module:Class' listed in LCMESH_CONTROLLER_PLUGINS"}  # fmt: skip
    props["valve_exercise_s"] = {"anyOf": [{"const": 0}, {**props["valve_exercise_s"], "minimum": MIN_VALVE_EXERCISE_S}],
                                 "description": props["valve_exercise_s"].get("description", "")}  # fmt: skip
    props["guardrails"]["properties"]["valve_fraction_min"]["maximum"] = 1.0 / B  # every branch gets v_min at once
    props["guardrails"]["properties"]["valve_fraction_min"].pop("exclusiveMaximum", None)
    manual = next(o for o in props["manual_action"]["anyOf"] if o.get("type") == "object")
    manual["required"] = list(manual["properties"])  # a manual action is whole: every block, every item
    action = manual["properties"]
    for name, count in (("supply_temp_setpoint_k", C), ("dp_setpoint_pa", C), ("lw_setpoint_k", N)):
        action[name].update(minItems=count, maxItems=count)
    action["valve_fractions"].update(minItems=C, maxItems=C)
    action["valve_fractions"]["items"].update(minItems=B, maxItems=B)
    return partial


def _inline(node: Any, defs: dict[str, Any]) -> Any:
    """`node` with `$ref`s replaced by their definitions, without `required`, defaults and titles."""
    if isinstance(node, list):
        return [_inline(item, defs) for item in node]
    if not isinstance(node, dict):
        return node
    if "$ref" in node:
        return _inline(copy.deepcopy(defs[node["$ref"].rsplit("/", 1)[-1]]), defs)
    return {key: _inline(value, defs) for key, value in node.items()
            if key not in ("$defs", "required", "default", "title")}  # fmt: skip

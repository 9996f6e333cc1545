"""The UI's requests to other agents over the bus: configuration changes and toolbox queries.

Three failure kinds the API maps to HTTP: ``MeshUnavailable`` (nobody answers: 503 with the
reason), ``MeshBusy`` (the agent refused over a rate limit or the what-if budget: 429 with
``Retry-After``) and ``MeshRefused`` (the agent answered with an error, e.g. a field out of range:
422, or 409 for a version conflict). Tools are asked on ``tools/{name}/{role}``, the key only this
session's role may ask (docs/mesh.md, Security).
"""

from __future__ import annotations

import json
from typing import Any

from pydantic import BaseModel, ValidationError

from lcmesh.mesh import keys
from lcmesh.mesh.bus import Bus, BusError
from lcmesh.mesh.messages import ConfigDoc, ConfigUpdate, check_finite
from lcmesh.mesh.ratelimit import RateLimited, retry_after_s


class MeshUnavailable(RuntimeError):
    """No agent answered (it is not running, or the router is gone)."""


class MeshRefused(ValueError):
    """The agent answered with an error; the text names the field."""

    def __init__(self, message: str, conflict: bool = False):
        super().__init__(message)
        self.conflict = conflict


class MeshBusy(RateLimited):
    """The agent refused over a rate limit or budget; nothing ran. `retry_after_s` says when to ask again."""


class MeshGateway:
    """Configuration and toolbox queryables, with timeouts and error kinds the API understands."""

    def __init__(self, bus: Bus, site: str, timeout_s: float = 3.0):
        self.bus, self.site, self.timeout_s = bus, site, timeout_s

    def _ask(self, key: str, payload: bytes | None, what: str, timeout_s: float | None = None) -> bytes:
        try:
            replies = self.bus.query(key, payload, timeout_s=timeout_s or self.timeout_s)
        except BusError as exc:
            raise MeshUnavailable(f"{what}: {exc}") from None
        if not replies:
            raise MeshUnavailable(f"{what}: no agent answers {key} (is it running?)")
        for reply in replies:
            if reply.ok:
                return reply.payload
        message = replies[0].payload.decode(errors="replace")
        wait_s = retry_after_s(message)
        if wait_s is not None:
            raise MeshBusy(f"{what}: {message}", wait_s)
        raise MeshRefused(message, conflict="`expected_version`" in message)

    def config(self) -> ConfigDoc:
        """The current configuration document."""
        data = self._ask(keys.config(self.site, "all"), None, "the Configuration agent")
        return _parse(ConfigDoc, data, "the Configuration agent")

    def update_config(self, changes: dict[str, Any], by: str, reason: str = "",
                      expected_version: int | None = None) -> ConfigDoc:  # fmt: skip
        """Ask the Configuration agent for a new version; MeshRefused names what is wrong."""
        update = ConfigUpdate(changes=changes, by=by, reason=reason, expected_version=expected_version)
        key = keys.configure(self.site, self.bus.role or "ui", "all")
        data = self._ask(key, update.model_dump_json().encode(), "the Configuration agent")
        return _parse(ConfigDoc, data, "the Configuration agent")

    def tool(self, name: str, request: dict[str, Any], timeout_s: float = 10.0) -> dict[str, Any]:
        """A toolbox tool's result (served by the Sensor); MeshRefused carries the tool's error, MeshBusy a limit."""
        key = keys.tool(self.site, name, self.bus.role or "ui")
        try:
            check_finite(request)
        except ValueError as exc:
            raise MeshRefused(f"the toolbox tool {name!r}: {exc}") from None
        body = json.dumps(request).encode()
        data = self._ask(key, body, f"the toolbox tool {name!r}", timeout_s)
        try:
            answer = json.loads(data)
        except ValueError:
            raise MeshUnavailable(f"the toolbox tool {name!r} answered something that is not JSON") from None
        if not answer.get("ok", False):
            raise MeshRefused(answer.get("error") or f"the toolbox tool {name!r} failed")
        return answer.get("result") or {}


def _parse(model: type[BaseModel], data: bytes, who: str):
    try:
        return model.model_validate_json(data)
    except ValidationError as exc:
        raise MeshUnavailable(f"{who} answered an invalid {model.__name__}: {exc.errors()[0]['msg']}") from None

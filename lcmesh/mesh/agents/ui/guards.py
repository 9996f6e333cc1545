"""What stands in front of the routes: the Host allow-list, the body limit, the token before the body.

Three pure ASGI middlewares, so they hold whatever the route and act before FastAPI reads anything:

- ``HostCheck``: 400 for a ``Host`` header not on the allow-list (DNS rebinding: a page on
  ``evil.example`` whose name is made to resolve to 127.0.0.1 would read the API);
- ``BodyLimit``: 413 for a body past ``max_bytes``, announced by ``Content-Length`` or counted as
  it streams in (chunked); the answer goes out as soon as the limit is passed, the rest is never read;
- ``WriteAuth``: 401 for a request to a route that needs the token (the routes depending on
  ``require_token``) without the right bearer token, before a byte of its body is read.

FastAPI reads and parses a body before it resolves a route's dependencies, so the dependency
alone would parse 50 MB of JSON from anyone; ``WriteAuth`` answers first and the dependency stays
as the second line (and what the OpenAPI document shows). A refusal that leaves a body unread
carries ``Connection: close``: the server can not read the next request from that connection.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

from fastapi.responses import JSONResponse
from fastapi.routing import APIRoute
from starlette.routing import Match

from lcmesh.mesh.agents.ui.security import parse_host, token_matches


def _has_body(scope) -> bool:
    headers = dict(scope.get("headers") or [])
    return headers.get(b"content-length", b"0") not in (b"0", b"") or b"transfer-encoding" in headers


async def _refuse(scope, send, status: int, detail: str, headers: dict[str, str] | None = None) -> None:
    """Answer `status` with ``{"detail": ...}`` without reading the request body."""
    headers = dict(headers or {})
    if _has_body(scope):
        headers["Connection"] = "close"

    async def _no_body():  # a JSONResponse does not read the request; this makes sure
        return {"type": "http.disconnect"}

    await JSONResponse({"detail": detail}, status_code=status, headers=headers)(scope, _no_body, send)


class HostCheck:
    """400 unless the ``Host`` header is one of `allowed` (``host`` or ``host:port``; ``*`` allows any)."""

    def __init__(self, app, allowed: Iterable[str]):
        self.app = app
        self.allowed = list(allowed)
        self.any = "*" in self.allowed
        self._entries = {parse_host(entry) for entry in self.allowed if entry != "*"}

    def allows(self, host_header: str | None) -> bool:
        if self.any:
            return True
        if not host_header:
            return False
        try:
            host, port = parse_host(host_header)
        except ValueError:
            return False
        return (host, port or 80) in self._entries or (host, None) in self._entries

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":  # lifespan; the server speaks no websocket (uvicorn ws="none")
            await self.app(scope, receive, send)
            return
        raw = dict(scope.get("headers") or []).get(b"host")
        header = raw.decode("latin-1") if raw is not None else None
        if self.allows(header):
            await self.app(scope, receive, send)
            return
        shown = "no Host header" if header is None else f"the Host header {header[:100]!r}"
        await _refuse(scope, send, 400,
                      f"{shown} is not one this server answers to (allowed: {', '.join(self.allowed)}); "
                      "add the name clients use to LCMESH_UI_ALLOWED_HOSTS")  # fmt: skip


class BodyLimit:
    """413 for a request body past `max_bytes`, announced or counted as it arrives; the rest is never read."""

    def __init__(self, app, max_bytes: int):
        self.app, self.max_bytes = app, max_bytes

    @property
    def detail(self) -> str:
        return f"the request body must be at most {self.max_bytes} bytes"

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        length = dict(scope.get("headers") or []).get(b"content-length")
        if length is not None and (not length.isdigit() or int(length) > self.max_bytes):
            await _refuse(scope, send, 413, self.detail)
            return
        received, refused, started = 0, False, False

        async def counted_receive():
            nonlocal received, refused
            if refused:
                return {"type": "http.disconnect"}
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.max_bytes:
                    refused = True
                    if not started:
                        await _refuse(scope, send, 413, self.detail)
                    return {"type": "http.disconnect"}  # the app sees a client gone and stops reading
            return message

        async def guarded_send(message):
            nonlocal started
            if refused:
                return  # the 413 was the answer; what the app says after it goes nowhere
            started = started or message["type"] == "http.response.start"
            await send(message)

        await self.app(scope, counted_receive, guarded_send)


class WriteAuth:
    """401 for a request to one of `routes` without ``Authorization: Bearer <token>``, before its body is read."""

    def __init__(self, app, routes: list[APIRoute], token: Callable[[], str]):
        self.app, self.routes, self.token = app, routes, token

    def _route(self, scope) -> APIRoute | None:
        for route in self.routes:
            match, _child = route.matches(scope)
            if match is Match.FULL:
                return route
        return None

    async def __call__(self, scope, receive, send):
        if scope["type"] == "http":
            route = self._route(scope)
            if route is not None:
                header = dict(scope.get("headers") or []).get(b"authorization")
                if not token_matches(self.token(), header.decode("latin-1") if header else None):
                    scope["route"] = route  # the latency histogram labels it by its template
                    await _refuse(scope, send, 401, "this endpoint needs `Authorization: Bearer <token>` with the API "
                                  "token", {"WWW-Authenticate": "Bearer"})  # fmt: skip
                    return
        await self.app(scope, receive, send)


def routes_needing(app_routes: Iterable, dependency: Callable) -> list[APIRoute]:
    """The API routes that depend on `dependency` (directly or through another dependency)."""

    def uses(dependant) -> bool:
        return any(d.call is dependency or uses(d) for d in dependant.dependencies)

    return [r for r in app_routes if isinstance(r, APIRoute) and uses(r.dependant)]

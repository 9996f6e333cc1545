"""The FastAPI application of the UI agent: REST API, live events, chat, /metrics and the web page.

``create_app(ctx)`` builds it around a ``UiContext`` (what the agent holds: the live store, the
history reader, the bus gateway, the chat engine, the token), behind the guards of ``guards.py``
(Host allow-list, body limit, token before the body). Errors are uniform JSON ``{"detail": "..."}``
naming the field: 422 for bad input, 400 for a body that is not JSON or a Host not allowed, 401
without the token, 404 for an unknown cabinet, tower or run, 405 with every method of the path in
``Allow``, 409 for a configuration version conflict, 410 for a chat proposal that aged, 413 for a
body over 256 KiB, 429 with ``Retry-After`` when chatting too fast or when a tool is over its rate
limit or the what-if budget, 503 with the reason when the mesh is not ready. ``/openapi.json``
documents each (``openapi.py`` adds what only this site knows).
"""

from __future__ import annotations

import asyncio
import difflib
import functools
import math
import time
import typing
from collections.abc import Callable
from contextlib import asynccontextmanager
from dataclasses import dataclass, field
from datetime import datetime
from importlib import resources
from pathlib import Path

from fastapi import FastAPI, Request
from fastapi.exception_handlers import http_exception_handler
from fastapi.exceptions import RequestValidationError
from fastapi.middleware.cors import CORSMiddleware
from fastapi.responses import JSONResponse
from fastapi.routing import APIRoute
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel
from starlette.exceptions import HTTPException as StarletteHTTPException

from lcmesh.assistant.sources import NotReady
from lcmesh.assistant.engine import ChatEngine
from lcmesh.mesh.agents.ui.config import UiSettings
from lcmesh.mesh.agents.ui.gateway import MeshGateway, MeshRefused, MeshUnavailable
from lcmesh.mesh.agents.ui.guards import BodyLimit, HostCheck, WriteAuth, routes_needing
from lcmesh.mesh.agents.ui.live import EventHub, LiveStore
from lcmesh.mesh.agents.ui.metrics import LatencyMiddleware, UiCollector, make_registry
from lcmesh.mesh.agents.ui.openapi import site_openapi
from lcmesh.mesh.agents.ui.security import ApiToken, RateLimiter, allowed_hosts, allowed_origins
from lcmesh.mesh.history import HistoryReader
from lcmesh.mesh.messages import ConfigDoc, utc_now
from lcmesh.mesh.ratelimit import RateLimited
from lcmesh.mesh.settings import MeshSettings
from lcmesh.twin.system import SystemDescription

STATIC_DIR = Path(str(resources.files("lcmesh.mesh.agents.ui").joinpath("static")))
MAX_BODY_BYTES = 256 * 1024  # the largest body a write needs is a manual action: a few KiB
PAGE_CSP = ("default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data:; connect-src 'self'; "
            "frame-ancestors 'none'; base-uri 'none'; form-action 'none'")  # fmt: skip
# on every answer, not only on `/`: the page is also a file under /static, and an error page is a page too
SECURITY_HEADERS = {"content-security-policy": PAGE_CSP, "x-frame-options": "DENY",
                    "x-content-type-options": "nosniff", "referrer-policy": "no-referrer"}  # fmt: skip


class SecurityHeaders:
    """Pure ASGI middleware adding `SECURITY_HEADERS` to every HTTP answer that does not set its own."""

    def __init__(self, app):
        self.app = app
        self.extra = [(k.encode(), v.encode()) for k, v in SECURITY_HEADERS.items()]

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return

        async def send_with_headers(message):
            if message["type"] == "http.response.start":
                present = {k.lower() for k, _ in message.get("headers", [])}
                message = {**message, "headers": [*message.get("headers", []),
                                                  *(h for h in self.extra if h[0] not in present)]}  # fmt: skip
            await send(message)

        await self.app(scope, receive, send_with_headers)


@dataclass
class UiContext:
    """Everything the routes use; the UI agent builds it in ``start``."""

    settings: MeshSettings
    ui: UiSettings
    system: SystemDescription
    store: LiveStore
    hub: EventHub
    token: ApiToken
    history: Callable[[], HistoryReader]
    config_doc: Callable[[], ConfigDoc | None]
    gateway: MeshGateway | None
    chat: ChatEngine
    agent_id: str = "ui"
    started_at: float = field(default_factory=time.monotonic)
    limiter: RateLimiter | None = None
    phraser_note: str | None = None
    clock: Callable[[], datetime] = utc_now  # wall time (UTC) of chat proposals and their confirmation

    def __post_init__(self):
        if self.limiter is None:
            self.limiter = RateLimiter(self.ui.chat_rate_per_min, self.ui.chat_burst)

    def require_gateway(self) -> MeshGateway:
        if self.gateway is None:
            raise NotReady("the UI is not connected to the mesh")
        return self.gateway


def _field(loc: tuple) -> str:
    return ".".join(str(p) for p in loc if p not in ("body",)) or "body"


def _validation_detail(exc: RequestValidationError, body_model: type[BaseModel] | None = None) -> str:
    lines = []
    for err in exc.errors():
        msg = err["msg"].removeprefix("Value error, ")
        loc = tuple(err["loc"])
        if err["type"] == "extra_forbidden":
            msg = "is not a known field" + _closest(body_model, loc)
        elif "input" in err and isinstance(err["input"], (str, int, float)) and err["type"] != "missing":
            text = repr(err["input"])
            msg += f" (got {text[:60] + '...' if len(text) > 60 else text})"
        lines.append(f"`{_field(loc)}` {msg}")
    return "; ".join(lines)


def _closest(model: type[BaseModel] | None, loc: tuple) -> str:
    """`` (did you mean 'x'?)`` for an unknown field at `loc` of a `model` body, or ''."""
    if model is None or not loc or loc[0] != "body":
        return ""
    for part in loc[1:-1]:
        info = model.model_fields.get(str(part))
        options = [info.annotation, *typing.get_args(info.annotation)] if info else []
        model = next((t for t in options if isinstance(t, type) and issubclass(t, BaseModel)), None)
        if model is None:
            return ""
    close = difflib.get_close_matches(str(loc[-1]), model.model_fields, n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _body_model(request: Request) -> type[BaseModel] | None:
    """The pydantic model of the route's body parameter, if it has one (FastAPI resolved it when it built the route)."""
    dependant = getattr(request.scope.get("route"), "dependant", None)
    params = dependant.body_params if dependant is not None else []
    model = params[0].field_info.annotation if params else None
    return model if isinstance(model, type) and issubclass(model, BaseModel) else None


def create_app(ctx: UiContext) -> FastAPI:
    """The UI's FastAPI app around `ctx`, behind its guards (guards.py): Host allow-list, body limit, token first."""
    from lcmesh.mesh.agents.ui.routes import chat, control, read, stream

    app = FastAPI(
        title="lc-mesh UI agent",
        version="1",
        summary="REST API, live events, grounded chat and metrics of an lc-mesh site",
        description="Reads are open; writes (configuration, controller mode, manual setpoints) need "
                    "`Authorization: Bearer <token>`. Units at this edge: °C, kW, psi, fractions; cabinets, "
                    "branches and towers count from 1. `/api/config` carries the mesh configuration as stored, in SI. "
                    f"Request bodies are at most {MAX_BODY_BYTES} bytes (413).",
        docs_url=None, redoc_url=None, lifespan=_lifespan(ctx),  # Swagger UI would load from a CDN: offline first
    )  # fmt: skip
    app.state.ctx = ctx
    collector = UiCollector(ctx.store, ctx.hub, ctx.system, ctx.chat)
    app.state.registry, histogram = make_registry(collector)

    @app.exception_handler(RequestValidationError)
    async def _invalid(request: Request, exc: RequestValidationError):
        detail = _validation_detail(exc, _body_model(request))
        return JSONResponse({"detail": detail, "errors": _jsonable(exc.errors())}, status_code=422)

    @app.exception_handler(StarletteHTTPException)
    async def _http_error(request: Request, exc: StarletteHTTPException):
        headers = dict(exc.headers or {})
        if exc.status_code == 405:  # Allow: every method of the path, not only the first route's
            allow = _methods(api_routes, request.url.path)
            headers["Allow"] = ", ".join(allow)
            detail = f"{request.method} is not allowed on {request.url.path}; use {' or '.join(allow)}"
            return JSONResponse({"detail": detail}, status_code=405, headers=headers)
        return await http_exception_handler(request, exc)  # FastAPI's own ({"detail"}, no body on 204/304)

    @app.exception_handler(NotReady)
    async def _not_ready(_request: Request, exc: NotReady):
        return JSONResponse({"detail": f"not ready: {exc}"}, status_code=503, headers={"Retry-After": "2"})

    @app.exception_handler(MeshUnavailable)
    async def _unavailable(_request: Request, exc: MeshUnavailable):
        return JSONResponse({"detail": f"mesh unavailable: {exc}"}, status_code=503, headers={"Retry-After": "2"})

    @app.exception_handler(RateLimited)
    async def _busy(_request: Request, exc: RateLimited):  # a tool over its rate limit or the what-if budget
        return JSONResponse({"detail": str(exc)}, status_code=429,
                            headers={"Retry-After": str(max(1, math.ceil(exc.retry_after_s)))})  # fmt: skip

    @app.exception_handler(MeshRefused)
    async def _refused(_request: Request, exc: MeshRefused):
        return JSONResponse({"detail": str(exc)}, status_code=409 if exc.conflict else 422)

    for module in (read, control, chat, stream):
        app.include_router(module.router)
    # the routers' own routes: the app's list may hold them by reference only (FastAPI includes routers lazily)
    routes = [r for module in (read, control, chat, stream) for r in module.router.routes]
    api_routes = [r for r in routes if isinstance(r, APIRoute)]
    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")
    plugins = ctx.settings.allowed_controller_plugins  # FastAPI's documented override of the document:
    app.openapi = functools.cache(lambda: site_openapi(app, ctx.system, ctx.ui, plugins))
    # the last added runs first: security headers, Host allow-list, CORS, latency, body limit, token, then the routes
    app.add_middleware(WriteAuth, routes=routes_needing(api_routes, control.require_token),
                       token=lambda: ctx.token.value)  # fmt: skip
    app.add_middleware(BodyLimit, max_bytes=MAX_BODY_BYTES)
    app.add_middleware(LatencyMiddleware, histogram=histogram)
    origins = allowed_origins(ctx.settings.ui_host, ctx.settings.ui_port, ctx.ui.cors_origins)
    app.add_middleware(CORSMiddleware, allow_origins=origins, allow_methods=["GET", "PUT", "POST"],
                       allow_headers=["Authorization", "Content-Type"], max_age=600)  # fmt: skip
    app.add_middleware(HostCheck, allowed=allowed_hosts(ctx.settings.ui_host, ctx.settings.ui_port,
                                                        ctx.ui.allowed_hosts))  # fmt: skip
    app.add_middleware(SecurityHeaders)  # outermost: a refusal by a guard carries the headers too
    return app


def _methods(routes: list[APIRoute], path: str) -> list[str]:
    """The methods `routes` serve on `path` (HEAD goes with GET, OPTIONS with CORS)."""
    return sorted({m for r in routes if r.path_regex.match(path) for m in r.methods} - {"HEAD"})


def _lifespan(ctx: UiContext):
    @asynccontextmanager
    async def lifespan(_app: FastAPI):
        ctx.hub.bind(asyncio.get_running_loop())  # bus threads hand live events to this loop
        yield

    return lifespan


def _jsonable(errors: list[dict]) -> list[dict]:
    out = []
    for err in errors:
        item = {k: err[k] for k in ("loc", "msg", "type") if k in err}
        item["loc"] = [str(p) for p in item.get("loc", [])]
        out.append(item)
    return out

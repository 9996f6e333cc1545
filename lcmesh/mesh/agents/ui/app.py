"""The FastAPI application of the UI agent: REST API, live events, chat, /metrics and the web page.

``create_app(ctx)`` builds it around a ``UiContext`` (what the agent holds: the live store, the
history reader, the bus gateway, the chat engine, the token). Errors are uniform JSON
``{"detail": "..."}`` naming the field: 422 for bad input, 401 without the token, 404 for an
unknown cabinet, tower or run, 409 for a configuration version conflict, 429 when chatting too
fast, 503 with the reason when the mesh is not ready.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from contextlib import asynccontextmanager
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.middleware.cors import CORSMiddleware
from fastapi.responses import JSONResponse
from fastapi.staticfiles import StaticFiles

from lcmesh.mesh.agents.ui.answers import NotReady
from lcmesh.mesh.agents.ui.chat import ChatEngine
from lcmesh.mesh.agents.ui.config import UiSettings
from lcmesh.mesh.agents.ui.gateway import MeshGateway, MeshRefused, MeshUnavailable
from lcmesh.mesh.agents.ui.live import EventHub, LiveStore
from lcmesh.mesh.agents.ui.metrics import LatencyMiddleware, UiCollector, make_registry
from lcmesh.mesh.agents.ui.security import ApiToken, RateLimiter, allowed_origins
from lcmesh.mesh.history import HistoryReader
from lcmesh.mesh.messages import ConfigDoc
from lcmesh.mesh.settings import MeshSettings
from lcmesh.twin.system import SystemDescription

STATIC_DIR = Path(str(resources.files("lcmesh.mesh.agents.ui").joinpath("static")))
MAX_BODY_BYTES = 256 * 1024
PAGE_CSP = ("default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data:; connect-src 'self'; "
            "frame-ancestors 'none'; base-uri 'none'; form-action 'none'")  # fmt: skip


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

    def __post_init__(self):
        if self.limiter is None:
            self.limiter = RateLimiter(self.ui.chat_rate_per_min, self.ui.chat_burst)

    def require_gateway(self) -> MeshGateway:
        if self.gateway is None:
            raise NotReady("the UI is not connected to the mesh")
        return self.gateway


def _field(loc: tuple) -> str:
    return ".".join(str(p) for p in loc if p not in ("body",)) or "body"


def _validation_detail(exc: RequestValidationError) -> str:
    lines = []
    for err in exc.errors():
        msg = err["msg"].removeprefix("Value error, ")
        if err["type"] == "extra_forbidden":
            msg = "is not a known field"
        elif "input" in err and isinstance(err["input"], (str, int, float)) and err["type"] != "missing":
            text = repr(err["input"])
            msg += f" (got {text[:60] + '...' if len(text) > 60 else text})"
        lines.append(f"`{_field(tuple(err['loc']))}` {msg}")
    return "; ".join(lines)


def create_app(ctx: UiContext) -> FastAPI:
    """The UI's FastAPI app around `ctx`."""
    from lcmesh.mesh.agents.ui.routes import chat, control, read, stream

    app = FastAPI(
        title="lc-mesh UI agent",
        version="1",
        summary="REST API, live events, grounded chat and metrics of an lc-mesh site",
        description="Reads are open; writes (configuration, controller mode, manual setpoints) need "
                    "`Authorization: Bearer <token>`. Units at this edge: °C, kW, psi, fractions; cabinets, "
                    "branches and towers count from 1. `/api/config` carries the mesh configuration as stored, in SI.",
        docs_url=None, redoc_url=None, lifespan=_lifespan(ctx),  # Swagger UI would load from a CDN: offline first
    )  # fmt: skip
    app.state.ctx = ctx
    collector = UiCollector(ctx.store, ctx.hub, ctx.system, ctx.chat)
    app.state.registry, histogram = make_registry(collector)

    @app.exception_handler(RequestValidationError)
    async def _invalid(_request: Request, exc: RequestValidationError):
        return JSONResponse({"detail": _validation_detail(exc), "errors": _jsonable(exc.errors())}, status_code=422)

    @app.exception_handler(NotReady)
    async def _not_ready(_request: Request, exc: NotReady):
        return JSONResponse({"detail": f"not ready: {exc}"}, status_code=503, headers={"Retry-After": "2"})

    @app.exception_handler(MeshUnavailable)
    async def _unavailable(_request: Request, exc: MeshUnavailable):
        return JSONResponse({"detail": f"mesh unavailable: {exc}"}, status_code=503, headers={"Retry-After": "2"})

    @app.exception_handler(MeshRefused)
    async def _refused(_request: Request, exc: MeshRefused):
        return JSONResponse({"detail": str(exc)}, status_code=409 if exc.conflict else 422)

    for module in (read, control, chat, stream):
        app.include_router(module.router)
    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")
    origins = allowed_origins(ctx.settings.ui_host, ctx.settings.ui_port, ctx.ui.cors_origins)
    app.add_middleware(CORSMiddleware, allow_origins=origins, allow_methods=["GET", "PUT", "POST"],
                       allow_headers=["Authorization", "Content-Type"], max_age=600)  # fmt: skip
    app.add_middleware(LatencyMiddleware, histogram=histogram)
    app.add_middleware(BodyLimit, max_bytes=MAX_BODY_BYTES)

    return app


class BodyLimit:
    """Refuse request bodies announced larger than `max_bytes` (413) before anything reads them."""

    def __init__(self, app, max_bytes: int):
        self.app, self.max_bytes = app, max_bytes

    async def __call__(self, scope, receive, send):
        if scope["type"] == "http":
            length = dict(scope.get("headers") or []).get(b"content-length")
            if length is not None and (not length.isdigit() or int(length) > self.max_bytes):
                response = JSONResponse({"detail": f"the request body must be at most {self.max_bytes} bytes"},
                                        status_code=413)  # fmt: skip
                await response(scope, receive, send)
                return
        await self.app(scope, receive, send)


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

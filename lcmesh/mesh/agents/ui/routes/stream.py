"""GET /api/events: server-sent events for the live page.

Events: ``hello`` (a snapshot on connect: state, agents, recent decisions, active alerts,
config), then ``state`` (at most ``LCMESH_UI_SSE_STATE_HZ`` per second), ``decision``,
``explanation``, ``alert``, ``event`` (agent events), ``agents`` (every 2 s) and ``config``.
A comment line every 15 s keeps proxies from closing an idle stream. At most
``LCMESH_UI_SSE_MAX_CLIENTS`` streams at once; one more is answered 503 with ``Retry-After``.
"""

from __future__ import annotations

import asyncio
import json
import time

from fastapi import APIRouter, HTTPException, Request
from fastapi.responses import StreamingResponse
from starlette.background import BackgroundTask

from lcmesh.mesh.agents.ui.live import END, HubFull, dumps

router = APIRouter()
KEEPALIVE_S = 15.0
AGENTS_EVERY_S = 2.0
RETRY_FULL_S = 10


def _frame(event: str, data: bytes) -> bytes:
    return b"event: " + event.encode() + b"\ndata: " + data + b"\n\n"


def _hello(ctx) -> bytes:
    doc = ctx.config_doc()
    snapshot = {
        "state": json.loads(ctx.store.view_json) if ctx.store.view_json else None,
        "agents": ctx.store.agents_view(),
        "decisions": ctx.store.recent_decisions(20),
        "alerts": [a.model_dump(mode="json") for a in ctx.store.active_alerts()],
        "config": doc.model_dump(mode="json") if doc else None,
        "system": {"name": ctx.system.name, "cabinets": ctx.system.cabinets.count,
                   "branches": ctx.system.cabinets.branches, "towers": ctx.system.towers.count,
                   "step_s": ctx.system.step_s},
    }  # fmt: skip
    return _frame("hello", dumps(snapshot))


@router.get("/api/events", tags=["read"], response_class=StreamingResponse,
            responses={200: {"content": {"text/event-stream": {}}, "description": "server-sent events"},
                       503: {"description": "LCMESH_UI_SSE_MAX_CLIENTS pages connected (Retry-After)"}})  # fmt: skip
async def events(request: Request) -> StreamingResponse:
    """Live updates for the web page (server-sent events)."""
    ctx = request.app.state.ctx
    try:
        queue = ctx.hub.open()
    except HubFull as exc:  # each stream holds a connection and a queue: the count is bounded
        raise HTTPException(503, f"{exc}; retry later or close another live page",
                            headers={"Retry-After": str(RETRY_FULL_S)}) from None  # fmt: skip

    async def stream():
        try:
            yield b"retry: 2000\n\n" + _hello(ctx)
            next_agents = time.monotonic() + AGENTS_EVERY_S
            while True:
                timeout = max(0.05, min(KEEPALIVE_S, next_agents - time.monotonic()))
                try:
                    event, data = await asyncio.wait_for(queue.get(), timeout)
                    if event == END:
                        break
                    yield _frame(event, data)
                except asyncio.TimeoutError:
                    if await request.is_disconnected():
                        break
                    yield b": keepalive\n\n"
                if time.monotonic() >= next_agents:
                    next_agents = time.monotonic() + AGENTS_EVERY_S
                    yield _frame("agents", dumps(ctx.store.agents_view()))
        finally:
            ctx.hub.close(queue)

    # the place is given back by the stream's `finally`, or by the background task if the stream never started
    return StreamingResponse(stream(), media_type="text/event-stream", background=BackgroundTask(ctx.hub.close, queue),
                             headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})  # fmt: skip

"""POST /api/chat: a grounded answer with its facts; rate-limited per client; never actuates."""

from __future__ import annotations

import math

from fastapi import APIRouter, HTTPException, Request

from lcmesh.mesh.agents.ui.schemas import ChatAnswer, ChatQuestion, errors

router = APIRouter()


@router.post("/api/chat", response_model=ChatAnswer, tags=["chat"], responses=errors(400, 413, 422, 429, 503))
def chat(request: Request, body: ChatQuestion) -> dict:
    """Answer an operator question from facts (state, history, decisions, toolbox).

    `{"message"}` -> `{"answer", "facts": [...], ...}`. Every number in `answer` is one of `facts`
    (each with its source and a reference to the data). A request to change the plant comes back
    as `proposed_command`, which an operator confirms through the authenticated control endpoints.
    """
    ctx = request.app.state.ctx
    limit = ctx.ui.chat_max_chars
    if len(body.message) > limit:
        raise HTTPException(422, f"`message` must be at most {limit} characters, got {len(body.message)}")
    client = request.client.host if request.client else "unknown"
    wait_s = ctx.limiter.take(client)
    if wait_s > 0:
        raise HTTPException(429, f"too many chat questions from {client}; retry in {wait_s:.1f} s",
                            headers={"Retry-After": str(math.ceil(wait_s))})  # fmt: skip
    return ctx.chat.ask(body.message)

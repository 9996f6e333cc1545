"""POST /api/chat: a grounded answer with its facts; rate-limited per client; never actuates."""

from __future__ import annotations

import datetime as dt
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
    # a session is the client's own: its id is kept per client address, and answered as the client sent it
    reply = ctx.chat.ask(body.message, session=body.session and f"{client}/{body.session}")
    return stamp_proposal({**reply, "session": body.session}, ctx)


def stamp_proposal(reply: dict, ctx) -> dict:
    """`reply` with its proposed command stamped: the config version and time it was made, and when it expires.

    The stamp travels in the command's body (``proposal``), so confirming it later than
    ``LCMESH_UI_PROPOSAL_MAX_AGE_S`` or on another configuration version is refused (routes/control.py).
    """
    command = reply.get("proposed_command")
    if not command:
        return reply
    doc = ctx.config_doc()
    made_at = ctx.clock()
    stamp = {"config_version": doc.version if doc is not None else None, "made_at": made_at.isoformat()}
    expires_at = made_at + dt.timedelta(seconds=ctx.ui.proposal_max_age_s)
    command = {**command, "body": {**command["body"], "proposal": stamp}, "expires_at": expires_at.isoformat()}
    return {**reply, "proposed_command": command}

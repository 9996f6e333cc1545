"""A minimal OpenAI-compatible server over any backend (the local model by default).

``GET /v1/models`` and ``POST /v1/chat/completions`` (greedy; ``max_tokens``, ``stop``; no streaming).
Requests that arrive within ``batch_window_s`` of each other with the same budget and stop strings
are decoded as one batch, so the controller's parallel per-cabinet requests keep their batching over
HTTP. As in the OpenAI API, the stop string is not part of the returned text.

Run: ``python -m lcmesh.llm.server --port 8000`` (binds 127.0.0.1 unless told otherwise).
"""

from __future__ import annotations

import asyncio
import time
import uuid
from collections.abc import Sequence
from typing import Literal

from fastapi import FastAPI
from pydantic import BaseModel, ConfigDict, Field

from lcmesh.llm.base import Generation, LlmBackend


class ChatMessage(BaseModel):
    role: Literal["system", "user", "assistant"]
    content: str


class ChatRequest(BaseModel):
    model_config = ConfigDict(extra="ignore")

    model: str = ""
    messages: list[ChatMessage] = Field(min_length=1)
    max_tokens: int = Field(256, ge=1, le=4096)
    temperature: float = Field(0.0, ge=0.0, le=2.0)
    stop: str | list[str] | None = None


class _Batcher:
    """Collects concurrent requests for a short window and decodes them together."""

    def __init__(self, backend: LlmBackend, window_s: float, max_batch: int):
        self.backend, self.window_s, self.max_batch = backend, window_s, max_batch
        self.queue: asyncio.Queue | None = None
        self._lock = asyncio.Lock()

    async def submit(self, conversation: list[dict], max_tokens: int, stop: tuple[str, ...]) -> Generation:
        loop = asyncio.get_running_loop()
        if self.queue is None:
            self.queue = asyncio.Queue()
        future = loop.create_future()
        await self.queue.put((conversation, max_tokens, stop, future))
        async with self._lock:  # one decoding batch at a time; whoever holds the lock drains the queue
            if not future.done():
                await asyncio.sleep(self.window_s)
                await self._drain()
        return await future

    async def _drain(self) -> None:
        items = []
        while not self.queue.empty() and len(items) < self.max_batch:
            items.append(self.queue.get_nowait())
        groups: dict[tuple, list] = {}
        for item in items:
            groups.setdefault((item[1], item[2]), []).append(item)
        for (max_tokens, stop), group in groups.items():
            try:
                results = await asyncio.to_thread(
                    self.backend.chat, [g[0] for g in group], max_new_tokens=max_tokens, stop=list(stop)
                )
            except Exception as exc:  # report to every waiting request, keep serving
                for g in group:
                    g[3].set_exception(exc)
                continue
            for g, result in zip(group, results):
                g[3].set_result(result)


def create_app(backend: LlmBackend, *, batch_window_s: float = 0.02, max_batch: int = 32) -> FastAPI:
    """The FastAPI app serving ``backend``."""
    app = FastAPI(title="lc-mesh LLM (OpenAI-compatible)")
    batcher = _Batcher(backend, batch_window_s, max_batch)

    @app.get("/v1/models")
    async def models() -> dict:
        return {"object": "list", "data": [{"id": backend.model_id, "object": "model", "owned_by": "lcmesh"}]}

    @app.post("/v1/chat/completions")
    async def chat(req: ChatRequest) -> dict:
        stop = (req.stop,) if isinstance(req.stop, str) else tuple(req.stop or ())
        conversation = [m.model_dump() for m in req.messages]
        gen = await batcher.submit(conversation, req.max_tokens, stop)
        text = _strip_stop(gen.text, stop)
        return {
            "id": f"chatcmpl-{uuid.uuid4().hex[:16]}", "object": "chat.completion", "created": int(time.time()),
            "model": backend.model_id,
            "choices": [{"index": 0, "message": {"role": "assistant", "content": text},
                         "finish_reason": "length" if gen.finish_reason == "length" else "stop"}],
            "usage": {"prompt_tokens": gen.prompt_tokens, "completion_tokens": gen.new_tokens,
                      "total_tokens": gen.prompt_tokens + gen.new_tokens},
        }  # fmt: skip

    return app


def _strip_stop(text: str, stop: Sequence[str]) -> str:
    for s in stop:
        if s and text.endswith(s):
            return text[: -len(s)]
    return text


def main() -> None:
    import argparse

    import uvicorn

    from lcmesh.llm.base import make_backend

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=8000)
    args = parser.parse_args()
    uvicorn.run(create_app(make_backend(backend="local")), host=args.host, port=args.port, log_level="warning")


if __name__ == "__main__":
    main()

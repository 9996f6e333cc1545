"""Settings of the UI agent (``LCMESH_UI_*`` variables; host and port are the mesh's ``LCMESH_UI_HOST/PORT``).

The API token is a secret: it comes from ``LCMESH_API_TOKEN`` or the file named by
``LCMESH_API_TOKEN_FILE`` (``MeshSettings.api_token_file``), never from a config file
(lcmesh.mesh.agents.ui.security).
"""

from __future__ import annotations

import ipaddress
from typing import Annotated, Literal

from pydantic import Field, SecretStr, field_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

from lcmesh.mesh.agents.ui.security import parse_host


class UiSettings(BaseSettings):
    """Knobs of the REST API, the live page and the chat."""

    model_config = SettingsConfigDict(env_prefix="LCMESH_UI_", extra="ignore", populate_by_name=True)

    api_token: SecretStr | None = Field(None, validation_alias="LCMESH_API_TOKEN", description="bearer token of writes")
    create_token_file: bool = Field(
        False, description="create LCMESH_API_TOKEN_FILE with a random token if it does not exist (compose)"
    )
    cors_origins: Annotated[list[str], NoDecode] = Field(
        [], description="extra origins allowed to call the API from a browser (the page's own origin always is)"
    )
    allowed_hosts: Annotated[list[str], NoDecode] = Field(
        [], description="extra Host header values the UI answers to (host or host:port, comma list; * for any); "
        "the bind host, 127.0.0.1, localhost and [::1] with the port always are (DNS rebinding)"
    )
    chat_rate_per_min: float = Field(30.0, gt=0, le=100_000, description="chat requests per minute and client")
    chat_burst: int = Field(10, ge=1, le=100_000, description="chat requests a client may send at once")
    chat_max_chars: int = Field(500, ge=10, le=10_000)
    chat_check: Literal["query", "words"] = Field("words", description="words: the local model's reading is also "
                                                  "checked against the question's words, the rules' plan replacing "
                                                  "it where it covers more; query: against its own fields only "
                                                  "(docs/ui.md)")
    chat_session_s: float = Field(900.0, gt=0, le=86_400, description="a chat session's previous question is "
                                  "forgotten after this many seconds without a question (follow-ups read it)")
    planner: Literal["llm", "openai", "rules"] = Field(
        "llm", description="who turns a question into tool calls: the local LLM with its planner adapter, the "
        "OpenAI-compatible endpoint of LCMESH_LLM_* (function calling), or the regex rules (also the fallback)"
    )
    phraser: Literal["template", "llm"] = Field(
        "template", description="who phrases chat answers: the deterministic template, or the LLM backend if present"
    )
    phraser_adapter: str = Field(
        "none", description="local LLM only: the phraser's LoRA adapter. 'none' phrases with the base instruct model "
        "(the distilled adapter learned actions and explanations, not chat); 'default' or a folder uses one"
    )
    sse_state_hz: float = Field(4.0, gt=0, le=100, description="plant states per second sent to each live page")
    sse_queue: int = Field(256, ge=8, description="events buffered per live client before the oldest are dropped")
    sse_max_clients: int = Field(64, ge=1, le=10_000, description="live pages (server-sent events) served at "
                                 "once; one more is answered 503 with Retry-After")  # fmt: skip
    trusted_proxies: Annotated[list[str], NoDecode] = Field(
        [], description="addresses of reverse proxies whose X-Forwarded-For / X-Forwarded-Proto count (comma list "
        "of IP addresses); empty: every client is its TCP peer, whatever headers it sends"
    )
    decisions_kept: int = Field(500, ge=10, description="recent decisions and explanations held in memory")
    history_max_points: int = Field(5000, ge=10, le=200_000, description="most rows one /api/history answer holds")
    bus_timeout_s: float = Field(3.0, gt=0, le=60, description="wait this long for a queryable (config, tools)")
    tools_rate_per_s: float = Field(5.0, gt=0, le=10_000, description="queries a second each data tool's "
                                    "tools/{name} answers after its burst; more get 'rate limited'")  # fmt: skip
    tools_burst: int = Field(20, ge=1, le=100_000, description="queries each data tool's queryable answers at once")
    proposal_max_age_s: float = Field(300.0, gt=0, le=86_400, description="a chat proposal confirmed later than this "
                                      "is refused (410): its setpoints were read from the plant then")  # fmt: skip

    @field_validator("cors_origins", "allowed_hosts", "trusted_proxies", mode="before")
    @classmethod
    def _split(cls, value: object) -> object:
        if isinstance(value, str):
            return [part.strip() for part in value.split(",") if part.strip()]
        return value

    @field_validator("allowed_hosts")
    @classmethod
    def _hosts(cls, value: list[str]) -> list[str]:
        for i, entry in enumerate(value):
            if entry != "*":
                try:
                    parse_host(entry)
                except ValueError as exc:
                    raise ValueError(f"`allowed_hosts[{i}]`: {exc}") from None
        return value

    @field_validator("trusted_proxies")
    @classmethod
    def _proxies(cls, value: list[str]) -> list[str]:
        for i, entry in enumerate(value):
            try:
                ipaddress.ip_address(entry)
            except ValueError:
                raise ValueError(f"`trusted_proxies[{i}]` must be an IP address like 127.0.0.1 or ::1, got {entry!r}"
                                 ) from None
        return value

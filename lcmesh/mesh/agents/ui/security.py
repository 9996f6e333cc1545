"""Who may write, from where, and how often: the bearer token, the bind check, CORS origins, chat rate limits.

- Writes (config, controller mode, setpoints) need ``Authorization: Bearer <token>``. The token
  comes from ``LCMESH_API_TOKEN`` or the file ``LCMESH_API_TOKEN_FILE`` (created with a random
  token when missing if ``LCMESH_UI_CREATE_TOKEN_FILE=true``; refused if group or others may read
  or write it). Bound to loopback with neither
  set, the agent makes a random token once and writes it to ``DATA_DIR/ui/api-token`` (mode
  0600) so a local operator can read it; a restarted UI (the orchestrator restarts a hung one)
  reads that file again, so the operators' token keeps working. Bound beyond loopback it refuses
  to start without a strong token (at least 16 characters, not a well-known default).
- Host allow-list: the bind host, 127.0.0.1, localhost and [::1] with the port, plus
  ``LCMESH_UI_ALLOWED_HOSTS`` (DNS rebinding; ``guards.HostCheck`` enforces it).
- CORS: only the page's own origin (and ``LCMESH_UI_CORS_ORIGINS``) may call the API from a browser.
- Chat: a token bucket per client address: the TCP peer, or what a proxy of
  ``LCMESH_UI_TRUSTED_PROXIES`` forwards (the agent tells uvicorn; no other client's header counts).
"""

from __future__ import annotations

import hmac
import ipaddress
import os
import secrets
import stat
from dataclasses import dataclass
from pathlib import Path

from lcmesh.mesh.ratelimit import TokenBuckets

MIN_TOKEN_CHARS = 16
DEFAULT_TOKENS = frozenset({
    "", "changeme", "change-me", "change_me", "secret", "token", "admin", "password", "lcmesh", "lc-mesh", "demo",
    "test", "default", "api-token", "apitoken", "letmein", "0000000000000000", "1234567890123456",
})  # fmt: skip
TOKEN_FILE_NAME = "api-token"


class InsecureBindError(RuntimeError):
    """The server would accept writes from the network with a missing, default or short token."""


def is_loopback(host: str) -> bool:
    """True for 127.0.0.0/8, ::1 and 'localhost'."""
    if host.strip().lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def weak_token_reason(token: str) -> str | None:
    """Why `token` is not fit for a server reachable from the network, or None."""
    if token.strip().lower() in DEFAULT_TOKENS:
        return "it is empty or a well-known default"
    if len(token) < MIN_TOKEN_CHARS:
        return f"it has {len(token)} characters, fewer than {MIN_TOKEN_CHARS}"
    return None


@dataclass(frozen=True)
class ApiToken:
    """The token writes need and where it came from ('env', 'file' or 'generated', with its path)."""

    value: str
    origin: str
    path: Path | None = None


def resolve_token(env_token: str | None, token_file: Path | None, host: str, data_dir: Path, *,
                  create_file: bool = False) -> ApiToken:  # fmt: skip
    """The write token for a server on `host`; InsecureBindError if `host` is beyond loopback and it is weak.

    With `create_file`, a missing `token_file` is created with a random token (mode 0600): how
    docker compose gets a per-deployment secret without one in the repository.
    """
    if env_token is not None and env_token.strip():
        token = ApiToken(env_token.strip(), "env")
    elif token_file is not None and create_file and not Path(token_file).exists():
        return _kept_or_generated(Path(token_file))
    elif token_file is not None:
        try:
            text = Path(token_file).read_text().strip()
        except OSError as exc:
            raise InsecureBindError(f"`LCMESH_API_TOKEN_FILE` = {token_file} can not be read: {exc}") from None
        _refuse_shared(Path(token_file))
        token = ApiToken(text, "file", Path(token_file))
    elif is_loopback(host):
        return _kept_or_generated(Path(data_dir) / "ui" / TOKEN_FILE_NAME)
    else:
        raise InsecureBindError(
            f"the UI would listen on {host} (beyond loopback) with no API token; set LCMESH_API_TOKEN or "
            f"LCMESH_API_TOKEN_FILE to a random string of at least {MIN_TOKEN_CHARS} characters, "
            "or bind to 127.0.0.1"
        )
    reason = weak_token_reason(token.value)
    if reason is not None and not is_loopback(host):
        raise InsecureBindError(
            f"refusing to listen on {host} (beyond loopback) with the API token from {token.origin}: {reason}; "
            f"use a random string of at least {MIN_TOKEN_CHARS} characters (e.g. `openssl rand -hex 24`)"
        )
    if not token.value:
        return _kept_or_generated(Path(data_dir) / "ui" / TOKEN_FILE_NAME)
    return token


def _refuse_shared(path: Path) -> None:
    """InsecureBindError if group or others may read or write the token file the operator named (as ssh refuses a key).

    The file is the operator's: it is not made private behind their back (a copy may already have leaked).
    """
    mode = stat.S_IMODE(path.stat().st_mode)
    if mode & 0o077:
        raise InsecureBindError(
            f"`LCMESH_API_TOKEN_FILE` = {path} has mode {mode:04o}: group or others may read or write the API token; "
            f"run `chmod 600 {path}` (and choose a new token if others could read it)"
        )


def _kept_or_generated(path: Path) -> ApiToken:
    """The token in `path` if it holds one (a restart keeps it), else a random one written there once (0600)."""
    for _ in range(2):
        try:
            value = path.read_text().strip()
        except FileNotFoundError:
            value = None
        except OSError as exc:
            raise InsecureBindError(f"the API token file {path} can not be read: {exc}") from None
        if value:
            if stat.S_IMODE(path.stat().st_mode) & 0o077:
                os.chmod(path, 0o600)  # it is a secret: the owner's alone
            return ApiToken(value, "file", path)
        path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)  # a folder made here holds only secrets
        value = secrets.token_urlsafe(32)
        flags = os.O_WRONLY | os.O_CREAT | (os.O_TRUNC if path.exists() else os.O_EXCL)  # an empty file is replaced
        try:
            fd = os.open(path, flags, 0o600)
        except FileExistsError:  # another UI made it between our read and our create: read theirs
            continue
        with os.fdopen(fd, "w") as f:
            f.write(value + "\n")
        os.chmod(path, 0o600)
        return ApiToken(value, "generated", path)
    raise InsecureBindError(f"the API token file {path} stays empty; remove it or write a token into it")


def token_matches(expected: str, authorization: str | None) -> bool:
    """True if the Authorization header carries `expected` as a bearer token (constant-time compare)."""
    if not authorization:
        return False
    scheme, _, given = authorization.partition(" ")
    if scheme.lower() != "bearer" or not given:
        return False
    return hmac.compare_digest(given.strip().encode(), expected.encode())


LOOPBACK_NAMES = ("127.0.0.1", "localhost", "::1")


def allowed_origins(host: str, port: int, extra: list[str]) -> list[str]:
    """The page's own origins (every loopback spelling when local) plus the configured extra ones."""
    hosts = {host, *LOOPBACK_NAMES} if is_loopback(host) else {host}
    return sorted({f"http://{_bracketed(h)}:{port}" for h in hosts} | set(extra))


def allowed_hosts(host: str, port: int, extra: list[str]) -> list[str]:
    """``Host`` header values the UI answers to: the bind host and the loopback names with `port`, plus `extra`."""
    own = [f"{_bracketed(h)}:{port}" for h in dict.fromkeys((host, *LOOPBACK_NAMES))]
    return own + [e for e in extra if e not in own]


def parse_host(value: str) -> tuple[str, int | None]:
    """``host[:port]`` (IPv6 in brackets) as (lower-case host, port or None); ValueError if malformed."""
    text = value.strip().lower()
    if text.startswith("["):
        end = text.find("]")
        host, rest = (text[: end + 1], text[end + 1 :]) if end > 0 else (text, "?")
    else:
        host, colon, port_text = text.partition(":")
        rest = colon + port_text
    port = rest[1:] if rest.startswith(":") else None
    host = host.rstrip(".")  # "localhost." is localhost
    if (not host or (rest and port is None) or any(ch in host for ch in "/@ \\?#:" if not host.startswith("["))
            or (port is not None and not (port.isdigit() and len(port) <= 5))):  # fmt: skip
        raise ValueError(f"malformed host {value!r}: expected host, host:port or [ipv6]:port")
    return host, None if port is None else int(port)


def _bracketed(host: str) -> str:
    return f"[{host}]" if ":" in host and not host.startswith("[") else host


class RateLimiter(TokenBuckets):
    """The chat's token bucket per client: `burst` requests at once, refilled at `rate_per_min`."""

    def __init__(self, rate_per_min: float, burst: int, max_clients: int = 10_000):
        super().__init__(rate_per_min / 60.0, burst, max_keys=max_clients)

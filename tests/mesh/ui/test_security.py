"""Token resolution (kept across restarts) and the insecure-bind refusal, bearer matching, the Host allow-list, the
chat rate limiter."""

from __future__ import annotations

import re
import stat

import pytest

from lcmesh.mesh.agents.ui.config import UiSettings
from lcmesh.mesh.agents.ui.guards import HostCheck
from lcmesh.mesh.agents.ui.security import (
    InsecureBindError, RateLimiter, allowed_hosts, allowed_origins, is_loopback, parse_host, resolve_token,
    token_matches,
)  # fmt: skip

STRONG = "9f86d081884c7d659a2feaa0c55ad015"


def test_loopback_without_a_token_generates_one_readable_only_by_the_owner(tmp_path):
    token = resolve_token(None, None, "127.0.0.1", tmp_path)
    assert token.origin == "generated" and len(token.value) >= 32
    assert token.path == tmp_path / "ui" / "api-token" and token.path.read_text().strip() == token.value
    assert stat.S_IMODE(token.path.stat().st_mode) == 0o600


def test_a_restart_keeps_the_generated_token(tmp_path):
    """The orchestrator restarts a hung UI: the operators' token must keep working (it used to be replaced)."""
    first = resolve_token(None, None, "127.0.0.1", tmp_path)
    again = resolve_token(None, None, "127.0.0.1", tmp_path)
    assert again.value == first.value and again.origin == "file" and again.path == first.path
    assert resolve_token("", None, "localhost", tmp_path).value == first.value  # an empty LCMESH_API_TOKEN too
    first.path.chmod(0o644)
    assert resolve_token(None, None, "::1", tmp_path).value == first.value
    assert stat.S_IMODE(first.path.stat().st_mode) == 0o600, "a token file others can read is made private"
    first.path.write_text("")
    fresh = resolve_token(None, None, "127.0.0.1", tmp_path)
    assert fresh.origin == "generated" and fresh.value != first.value, "an empty file gets a token"


def test_host_allow_list_defaults_and_parsing():
    assert allowed_hosts("127.0.0.1", 8000, []) == ["127.0.0.1:8000", "localhost:8000", "[::1]:8000"]
    assert allowed_hosts("0.0.0.0", 80, ["ui:8000"]) == ["0.0.0.0:80", "127.0.0.1:80", "localhost:80", "[::1]:80",
                                                         "ui:8000"]  # fmt: skip
    assert parse_host("[::1]:8000") == ("[::1]", 8000) and parse_host("LocalHost.") == ("localhost", None)
    for bad in ("a:b", "[::1", "x:1:2", "a/b", "", "h:1234567"):
        with pytest.raises(ValueError, match="malformed host"):
            parse_host(bad)
    check = HostCheck(None, ["127.0.0.1:8000", "localhost:8000", "[::1]:8000", "ui", "grafana:80"])
    assert check.allows("127.0.0.1:8000") and check.allows("LOCALHOST:8000") and check.allows("[::1]:8000")
    assert check.allows("ui:9999") and check.allows("grafana")  # no port: 80, the http default
    for refused in ("evil.example:8000", "127.0.0.1:8001", "localhost", "127.0.0.1.evil.example:8000", None, "a:b"):
        assert not check.allows(refused), refused
    assert HostCheck(None, ["*"]).allows("anything.example")
    with pytest.raises(ValueError, match=r"`allowed_hosts\[1\]`: malformed host 'a:b'"):
        UiSettings(allowed_hosts="ui:8000,a:b")


@pytest.mark.parametrize("env_token", [None, "", "changeme", "short-token"])
def test_beyond_loopback_a_missing_default_or_short_token_is_refused(env_token, tmp_path):
    with pytest.raises(InsecureBindError, match="LCMESH_API_TOKEN|at least 16"):
        resolve_token(env_token, None, "0.0.0.0", tmp_path)


def test_strong_tokens_from_env_or_file(tmp_path):
    assert resolve_token(STRONG, None, "0.0.0.0", tmp_path).origin == "env"
    secret = tmp_path / "token"
    secret.write_text(STRONG + "\n")
    secret.chmod(0o600)
    token = resolve_token(None, secret, "10.0.0.5", tmp_path)
    assert token.value == STRONG and token.origin == "file"
    with pytest.raises(InsecureBindError, match="can not be read"):
        resolve_token(None, tmp_path / "missing", "10.0.0.5", tmp_path)
    assert resolve_token("demo", None, "127.0.0.1", tmp_path).value == "demo"  # weak is tolerated on loopback
    created = resolve_token(None, tmp_path / "made" / "token", "0.0.0.0", tmp_path, create_file=True)
    assert created.origin == "generated" and len(created.value) >= 32
    again = resolve_token(None, tmp_path / "made" / "token", "0.0.0.0", tmp_path, create_file=True)
    assert again.value == created.value and again.origin == "file"  # a restart keeps the token


@pytest.mark.parametrize("mode", [0o644, 0o640, 0o620, 0o604, 0o602, 0o666, 0o660])
def test_a_token_file_others_may_read_or_write_is_refused(tmp_path, mode):
    """Like ssh with a key: the operator's token file must be the owner's alone (it was read whatever its mode)."""
    secret = tmp_path / "token"
    secret.write_text(STRONG + "\n")
    secret.chmod(mode)
    for host in ("10.0.0.5", "127.0.0.1"):
        expected = rf"LCMESH_API_TOKEN_FILE.*{re.escape(str(secret))}.*mode {mode:04o}.*chmod 600"
        with pytest.raises(InsecureBindError, match=expected):
            resolve_token(None, secret, host, tmp_path)
    assert stat.S_IMODE(secret.stat().st_mode) == mode, "the operator's file is left as it is"
    for private in (0o600, 0o400):
        secret.chmod(private)
        assert resolve_token(None, secret, "10.0.0.5", tmp_path).value == STRONG


def test_bearer_matching_and_loopback_detection():
    assert token_matches(STRONG, f"Bearer {STRONG}") and token_matches(STRONG, f"bearer {STRONG}")
    assert not token_matches(STRONG, STRONG) and not token_matches(STRONG, "Bearer x") and not token_matches(STRONG, None)
    assert is_loopback("127.0.0.1") and is_loopback("::1") and is_loopback("localhost") and is_loopback("127.1.2.3")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.168.1.4")
    assert allowed_origins("127.0.0.1", 8000, []) == ["http://127.0.0.1:8000", "http://[::1]:8000",
                                                      "http://localhost:8000"]  # fmt: skip


def test_rate_limiter_allows_a_burst_then_asks_to_wait():
    limiter = RateLimiter(rate_per_min=60, burst=3)
    assert [limiter.take("a") for _ in range(3)] == [0.0, 0.0, 0.0]
    wait = limiter.take("a")
    assert 0.5 < wait <= 1.0
    assert limiter.take("b") == 0.0  # per client


def test_the_ui_agent_refuses_to_start_beyond_loopback_with_a_weak_token(tmp_path):
    from lcmesh.mesh.agents.ui import UiAgent
    from lcmesh.mesh.agents.ui.config import UiSettings
    from tests.mesh.conftest import make_settings

    agent = UiAgent(make_settings(tmp_path, ui_host="0.0.0.0"), ui=UiSettings(api_token="changeme"))
    agent.bus = None
    with pytest.raises(InsecureBindError, match="beyond loopback"):
        agent.on_start()  # the token check comes before any socket is bound

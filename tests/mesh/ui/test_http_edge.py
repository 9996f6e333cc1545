"""The UI's HTTP edge on a real server (uvicorn as the agent starts it, on loopback): metric labels from closed sets,
security headers on every path that serves the page, proxy headers only from a trusted proxy, a cap on live clients.

A router, the Configuration agent (it writes `changed_by` into the audit) and two UIs of one site: one with the
default settings, one behind a trusted proxy (127.0.0.1, where the test's requests come from).
"""

from __future__ import annotations

import http.client
import secrets
from contextlib import ExitStack
from dataclasses import dataclass

import httpx
import pytest
from prometheus_client.parser import text_string_to_metric_families

from lcmesh.mesh.agents.ui.metrics import KNOWN_METHODS, OTHER
from tests.mesh.conftest import free_port, make_settings, wait_until

SSE_MAX = 2
CHAT_BURST = 3
LATENCY = "lcmesh_api_request_duration_seconds"


@dataclass
class Ui:
    agent: object
    url: str
    token: str

    def client(self) -> httpx.Client:
        return httpx.Client(base_url=self.url, timeout=20.0)

    def auth(self) -> dict:
        return {"Authorization": f"Bearer {self.token}"}


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """(plain UI, UI trusting the proxy on 127.0.0.1) beside a Configuration agent on one router."""
    from lcmesh.mesh.agents.configuration import ConfigurationAgent
    from lcmesh.mesh.agents.ui import UiAgent
    from lcmesh.mesh.agents.ui.config import UiSettings
    from lcmesh.mesh.bus import Bus

    settings = make_settings(tmp_path_factory.mktemp("edge"), ui_port=free_port())
    started: list = []  # (agent, bus), stopped in reverse

    def start(agent, agent_settings):
        bus = Bus.connect(agent_settings, agent.agent_id)
        started.append((agent, bus))
        agent.start(bus)
        return agent

    def ui(agent_id: str, **overrides) -> Ui:
        ui_settings = UiSettings(api_token=secrets.token_urlsafe(24), planner="rules", bus_timeout_s=2.0,
                                 chat_burst=CHAT_BURST, chat_rate_per_min=1e-3, sse_max_clients=SSE_MAX, **overrides)
        agent_settings = settings.model_copy(update={"ui_port": free_port()})
        agent = start(UiAgent(agent_settings, agent_id, ui=ui_settings), agent_settings)
        return Ui(agent, agent.url, agent.ctx.token.value)

    router = Bus.open_router(settings)
    try:
        start(ConfigurationAgent(settings), settings)
        yield ui("ui"), ui("ui-2", trusted_proxies="127.0.0.1")
    finally:
        for agent, bus in reversed(started):
            try:
                agent.stop()
            finally:
                bus.close()
        router.close()


@pytest.fixture(scope="module")
def plain(site) -> Ui:
    return site[0]


@pytest.fixture(scope="module")
def proxied(site) -> Ui:
    return site[1]


def _latency_series(ui: Ui) -> set[tuple[str, str]]:
    with ui.client() as http:
        text = http.get("/metrics").text
    family = next(f for f in text_string_to_metric_families(text) if f.name == LATENCY)
    return {(s.labels["route"], s.labels["method"]) for s in family.samples}


def test_made_up_methods_and_paths_add_no_metric_series(plain):
    """50 made-up methods used to add 16 series each (800 in all): labels now come from closed sets."""
    from lcmesh.mesh.agents.ui.routes import chat, control, read, stream

    templates = {r.path for m in (read, control, chat, stream) for r in m.router.routes} | {"/static", OTHER}
    with plain.client() as http:
        for path in ("/api/health", "/", "/no/such/path", "/static/app.js", "/metrics"):
            http.get(path)
        before = _latency_series(plain)
        for i in range(50):
            http.request(f"ZZMETHOD{i}", "/api/health")
            http.request(f"ZZMETHOD{i}", f"/made-up/{i}")
            http.get(f"/made-up/{i}")
            http.get(f"/static/missing-{i}.js")
    after = _latency_series(plain)
    assert {m for _, m in after} <= KNOWN_METHODS | {OTHER}, after
    assert {r for r, _ in after} <= templates, after
    assert ("/api/health", OTHER) in after, "made-up methods fold into `other`"
    assert after - before == {("/api/health", OTHER), (OTHER, OTHER)}, f"200 odd requests added {after - before}"


def _raw_get(ui: Ui, path: str) -> tuple[int, dict[str, str], bytes]:
    """GET `path` exactly as written (http.client does not normalise dot segments or percent escapes)."""
    port = int(ui.url.rsplit(":", 1)[1])
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=20)
    try:
        conn.request("GET", path)
        response = conn.getresponse()
        return response.status, {k.lower(): v for k, v in response.getheaders()}, response.read()
    finally:
        conn.close()


@pytest.mark.parametrize("path", ["/", "/static/index.html", "/static/./index.html", "/static//index.html",
                                  "/static/%69ndex.html", "/static/x/../index.html", "/index.html", "/static/app.js",
                                  "/api/health", "/metrics", "/no/such/path"])  # fmt: skip
def test_every_answer_carries_the_security_headers(plain, path):
    """`/static/index.html` served the page without its CSP and frame headers; every answer carries them now."""
    status, headers, body = _raw_get(plain, path)
    assert headers.get("content-security-policy", "").startswith("default-src 'self'"), (path, status, headers)
    assert "frame-ancestors 'none'" in headers["content-security-policy"]
    assert headers.get("x-frame-options") == "DENY" and headers.get("x-content-type-options") == "nosniff", path
    if b"<html" in body.lower():  # the page itself, under whichever path serves it
        assert status == 200


def test_a_refused_host_still_gets_the_headers(plain):
    with plain.client() as http:
        r = http.get("/", headers={"Host": "evil.example"})
    assert r.status_code == 400 and r.headers["x-frame-options"] == "DENY" and "content-security-policy" in r.headers


def _chat(http: httpx.Client, forwarded_for: str) -> httpx.Response:
    return http.post("/api/chat", json={"message": "hello"}, headers={"X-Forwarded-For": forwarded_for})


def test_a_forwarded_for_header_from_an_untrusted_peer_is_ignored(plain):
    """Each made-up X-Forwarded-For used to get a fresh chat bucket and write its own `changed_by`."""
    with plain.client() as http:
        answers = [_chat(http, f"198.51.100.{i}") for i in range(CHAT_BURST + 5)]
        statuses = [r.status_code for r in answers]
        assert statuses.count(429) == 5 and 429 not in statuses[:CHAT_BURST], statuses
        assert "from 127.0.0.1" in answers[-1].json()["detail"] and answers[-1].headers["Retry-After"]
        r = http.put("/api/config", json={"changes": {"speed_factor": 250}, "reason": "spoof"},
                     headers={**plain.auth(), "X-Forwarded-For": "203.0.113.66"})  # fmt: skip
        assert r.status_code == 200, r.text
        assert r.json()["changed_by"].endswith("api@127.0.0.1") and "203.0.113" not in r.json()["changed_by"]


def test_a_trusted_proxy_names_the_client(proxied):
    with proxied.client() as http:
        statuses = [_chat(http, f"198.51.100.{i}").status_code for i in range(CHAT_BURST + 5)]
        assert 429 not in statuses, f"each forwarded client has its own bucket: {statuses}"
        same = [_chat(http, "192.0.2.1").status_code for _ in range(CHAT_BURST + 1)]
        assert same[-1] == 429, same
        r = http.put("/api/config", json={"changes": {"speed_factor": 260}, "reason": "proxied"},
                     headers={**proxied.auth(), "X-Forwarded-For": "203.0.113.7"})  # fmt: skip
        assert r.status_code == 200 and r.json()["changed_by"].endswith("api@203.0.113.7"), r.text


def test_trusted_proxies_must_be_addresses():
    from pydantic import ValidationError

    from lcmesh.mesh.agents.ui.config import UiSettings

    assert UiSettings(trusted_proxies="127.0.0.1, ::1").trusted_proxies == ["127.0.0.1", "::1"]
    assert UiSettings().trusted_proxies == []
    for bad in ("proxy.example", "*", "10.0.0.0/8"):
        with pytest.raises(ValidationError, match=r"`trusted_proxies\[0\]` must be an IP address"):
            UiSettings(trusted_proxies=bad)


def test_live_clients_past_the_cap_get_503_with_retry_after(plain):
    hub = plain.agent.ctx.hub
    with ExitStack() as stack:
        streams = []
        for _ in range(SSE_MAX):
            http = stack.enter_context(plain.client())
            response = stack.enter_context(http.stream("GET", "/api/events"))
            assert response.status_code == 200
            streams.append(response)
        assert hub.clients == SSE_MAX
        with plain.client() as http, http.stream("GET", "/api/events") as extra:
            assert extra.status_code == 503 and int(extra.headers["Retry-After"]) > 0  # before reading (endless)
            extra.read()
            assert "LCMESH_UI_SSE_MAX_CLIENTS" in extra.json()["detail"], extra.text
        streams[0].close()  # a place comes free once the server sees the client gone
        assert wait_until(lambda: hub.clients < SSE_MAX, 20), hub.clients
        with plain.client() as http, http.stream("GET", "/api/events") as again:
            assert again.status_code == 200
    assert wait_until(lambda: hub.clients == 0, 20), "every stream gives its place back"


def test_made_up_agent_ids_do_not_grow_the_agents_table_or_the_metrics(lcopt5):
    """A role may name its agents freely (``sensor-N``); past the cap a new id is counted, not kept, so the agents'
    series in /metrics stay bounded."""
    from prometheus_client import generate_latest

    from lcmesh.mesh.agents.ui.live import EventHub, LiveStore
    from lcmesh.mesh.agents.ui.metrics import UiCollector, make_registry
    from lcmesh.mesh.messages import AgentStats

    hub = EventHub()
    store = LiveStore(lcopt5, hub, max_agents=8)
    registry, _ = make_registry(UiCollector(store, hub, lcopt5))
    for i in range(50):
        store.on_stats(AgentStats(source=f"sensor-{i}", role="sensor", agent_id=f"sensor-{i}", pid=1, host="h",
                                  uptime_s=1.0, cpu_pct=0.0, rss_bytes=1, threads=1))  # fmt: skip
    assert len(store.agents_view()) == 8 and store.counts["agents_over_cap"] == 42
    text = generate_latest(registry).decode()
    assert sum(line.startswith("lcmesh_agent_cpu_usage_ratio{") for line in text.splitlines()) == 8

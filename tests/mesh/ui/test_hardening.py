"""The UI's HTTP guards on a real server: body limit for streamed bodies, the token before the body, the Host
allow-list, bounded numbers, a token kept across restarts, health while the Sensor is down, promtool-clean metrics."""

from __future__ import annotations

import asyncio
import http.client
import select
import shutil
import socket
import subprocess

import httpx
import pytest

from lcmesh.mesh.agents.ui.guards import BodyLimit, WriteAuth, routes_needing
from tests.mesh.conftest import free_port, make_settings, wait_until

BIG = 50 * 1024 * 1024
CHUNK = 64 * 1024


def _big_put(port: int, path: str, total: int, headers: dict[str, str], chunked: bool = True):
    """PUT a body of `total` bytes (chunked, or announced by Content-Length), stopping as soon as the server answers.

    Sends like a careful client: before each piece it looks whether the server has answered (a
    server that refuses a body answers early and closes; it does not read the rest). Returns
    (status or None, body, bytes sent).
    """
    framing = {"Transfer-Encoding": "chunked"} if chunked else {"Content-Length": str(total)}
    sock = socket.create_connection(("127.0.0.1", port), timeout=30)
    try:
        head = "".join(f"{k}: {v}\r\n" for k, v in {"Host": f"127.0.0.1:{port}", "Content-Type": "application/json",
                                                     **framing, **headers}.items())  # fmt: skip
        sock.sendall(f"PUT {path} HTTP/1.1\r\n{head}\r\n".encode())
        piece = b"[" + b"1," * (CHUNK // 2 - 1) + b"1"
        frame = f"{CHUNK:x}\r\n".encode() + piece + b"\r\n" if chunked else piece
        sent = 0
        while sent < total and not select.select([sock], [], [], 0)[0]:
            try:
                sock.sendall(frame)
            except (BrokenPipeError, ConnectionResetError):
                break
            sent += CHUNK
        response = http.client.HTTPResponse(sock)
        try:
            response.begin()
        except (ConnectionResetError, http.client.RemoteDisconnected):
            return None, b"", sent
        return response.status, response.read(), sent
    finally:
        sock.close()


@pytest.mark.parametrize("with_token", [False, True], ids=["no-token", "token"])
def test_a_50_mb_chunked_body_is_refused_early_and_the_server_stays_up(ui_mesh, with_token):
    port = ui_mesh.settings.ui_port
    headers = ui_mesh.auth() if with_token else {}
    status, body, sent = _big_put(port, "/api/config", BIG, headers)
    expected = 413 if with_token else 401  # without the token the answer comes before a body byte is read
    assert status == expected, (status, body)
    assert sent < BIG // 4, f"the server read {sent} bytes of a body it refused"
    with ui_mesh.client() as http:
        assert http.get("/api/health").json()["status"] in ("ok", "degraded")
        r = http.put("/api/config", json={"changes": {"speed_factr": 1}}, headers=ui_mesh.auth())
        assert r.status_code == 422 and "did you mean 'speed_factor'" in r.json()["detail"], "the token still works"
        assert ui_mesh.ui.ctx.token.value == ui_mesh.token
    status, body, sent = _big_put(port, "/api/chat", BIG, {}, chunked=False)  # announced: refused before it is read
    assert status == 413 and b"at most 262144 bytes" in body and sent < BIG // 4


def _asgi_call(app, scope, messages):
    """Run an ASGI `app` on `scope`; (responses sent, how many `messages` it read)."""
    sent, read = [], []

    async def receive():
        read.append(1)
        return messages[len(read) - 1] if len(read) <= len(messages) else {"type": "http.disconnect"}

    async def send(message):
        sent.append(message)

    asyncio.run(app(scope, receive, send))
    return sent, len(read)


def _scope(method: str, path: str, headers: dict[bytes, bytes]) -> dict:
    return {"type": "http", "method": method, "path": path, "raw_path": path.encode(), "root_path": "",
            "query_string": b"", "headers": list(headers.items()), "scheme": "http", "http_version": "1.1",
            "server": ("127.0.0.1", 8000), "client": ("127.0.0.1", 5000)}  # fmt: skip


def test_the_body_limit_counts_streamed_bytes_and_stops_reading():
    async def reads_everything(scope, receive, send):
        while (await receive()).get("more_body"):
            pass
        await send({"type": "http.response.start", "status": 200, "headers": []})
        await send({"type": "http.response.body", "body": b"read it all"})

    chunks = [{"type": "http.request", "body": b"x" * CHUNK, "more_body": True} for _ in range(800)]  # 50 MiB
    sent, read = _asgi_call(BodyLimit(reads_everything, max_bytes=256 * 1024),
                            _scope("POST", "/api/chat", {b"transfer-encoding": b"chunked"}), chunks)  # fmt: skip
    assert sent[0]["status"] == 413 and [m for m in sent if m.get("body") == b"read it all"] == []
    assert read == 256 * 1024 // CHUNK + 1, "it reads up to the first chunk past the limit, not the rest"
    assert (b"connection", b"close") in sent[0]["headers"]


def test_write_routes_answer_401_before_the_body_is_read():
    from fastapi import Depends, FastAPI, Request

    def need_token(request: Request) -> None:
        raise AssertionError("the route's own check must not be reached without the token")

    app = FastAPI()

    @app.put("/api/config", dependencies=[Depends(need_token)])
    def put(body: dict) -> dict:
        return body

    @app.get("/api/config")
    def get() -> dict:
        return {}

    guarded = WriteAuth(app, routes_needing(app.routes, need_token), lambda: "s3cret-token-of-the-test")
    body = [{"type": "http.request", "body": b"{}" * 1000, "more_body": True}]
    for headers in ({}, {b"authorization": b"Bearer wrong"}, {b"authorization": b"Basic s3cret-token-of-the-test"}):
        sent, read = _asgi_call(guarded, _scope("PUT", "/api/config", {b"content-length": b"2000", **headers}), body)
        assert sent[0]["status"] == 401 and read == 0, headers
        assert (b"www-authenticate", b"Bearer") in sent[0]["headers"]
    sent, _ = _asgi_call(guarded, _scope("GET", "/api/config", {}), [])
    assert sent[0]["status"] == 200, "reads need no token"


@pytest.mark.parametrize("host, allowed", [
    ("evil.example", False), ("evil.example:{port}", False), ("127.0.0.1:1", False), ("127.0.0.1.nip.io:{port}", False),
    ("127.0.0.1:{port}", True), ("localhost:{port}", True), ("[::1]:{port}", True),
])  # fmt: skip
def test_only_allowed_host_headers_are_answered(ui_mesh, host, allowed):
    """DNS rebinding: a page on evil.example whose name resolves to 127.0.0.1 must not read the API."""
    with ui_mesh.client() as http:
        r = http.get("/api/state", headers={"Host": host.format(port=ui_mesh.settings.ui_port)})
    if allowed:
        assert r.status_code == 200
    else:
        assert r.status_code == 400 and "LCMESH_UI_ALLOWED_HOSTS" in r.json()["detail"], r.text


@pytest.mark.parametrize("path, params, status", [
    ("/api/history", {"start_step": 10**20}, 422),  # beyond SQLite's 64-bit integers: was a 500 (OverflowError)
    ("/api/history", {"end_step": -1}, 422),
    ("/api/history", {"start_s": "1e309"}, 422),  # parses to inf
    ("/api/history", {"last_s": "inf"}, 422),
    ("/api/history", {"last_s": "nan"}, 422),
    ("/api/history", {"end_s": "-Infinity"}, 422),
    ("/api/history", {"max_points": 10**30}, 422),
    ("/api/decisions", {"since_step": 10**20}, 422),  # was a 500 (OverflowError)
    ("/api/decisions", {"limit": "1e400"}, 422),
    ("/api/alerts", {"limit": 10**30}, 422),
    ("/api/state/cabinets/100000000000000000000000", {}, 404),
    ("/api/state/towers/1e400", {}, 422),
])  # fmt: skip
def test_out_of_range_numbers_are_422_never_500(api, path, params, status):
    r = api.get(path, params=params)
    assert r.status_code == status, r.text
    assert r.json()["detail"]


@pytest.mark.parametrize("path, body", [
    ("/api/control/setpoints", b'{"supply_temp_setpoint_c": 1e400}'),
    ("/api/control/setpoints", b'{"supply_temp_setpoint_c": NaN}'),
    ("/api/control/setpoints", b'{"dp_setpoint_psi": [Infinity, 1, 1, 1, 1]}'),
    ("/api/control/setpoints", b'{"supply_temp_setpoint_c": 30, "cabinets": [1.5]}'),
    ("/api/control/setpoints", b'{"valve_fractions": [true, 0, 0]}'),
    ("/api/config", b'{"changes": {"speed_factor": 1e400}}'),
    ("/api/config", b'{"changes": {}, "expected_version": 100000000000000000000000}'),
    ("/api/config", b'{"changes": {"llm": {"max_new_tokens": true}}}'),
    ("/api/config", b'\xff\xfe not json'),
])  # fmt: skip
def test_bad_numbers_in_bodies_are_refused(api, ui_mesh, path, body):
    method = "PUT" if path == "/api/config" else "POST"
    r = api.request(method, path, content=body, headers={**ui_mesh.auth(), "Content-Type": "application/json"})
    assert r.status_code in (400, 422) and r.json()["detail"], r.text


def _ui(settings):
    from lcmesh.mesh.agents.ui import UiAgent
    from lcmesh.mesh.agents.ui.config import UiSettings
    from lcmesh.mesh.bus import Bus

    agent = UiAgent(settings, ui=UiSettings())
    bus = Bus.connect(settings, agent.agent_id)
    try:
        agent.start(bus)
    except BaseException:
        bus.close()
        raise
    return agent, bus


def test_a_restarted_ui_keeps_the_generated_token(tmp_path, monkeypatch):
    """The orchestrator restarts a hung UI; the token the operators hold must keep working."""
    from lcmesh.mesh.bus import Bus

    monkeypatch.delenv("LCMESH_API_TOKEN", raising=False)
    settings = make_settings(tmp_path / "mesh", ui_port=free_port())
    router = Bus.open_router(settings)
    try:
        tokens = []
        for _ in range(2):
            ui, bus = _ui(settings)
            try:
                token_file = settings.data_dir / "ui" / "api-token"
                assert ui.ctx.token.value == token_file.read_text().strip()
                tokens.append(ui.ctx.token.value)
                r = httpx.put(ui.url + "/api/config", json={"changes": {}}, timeout=10,
                              headers={"Authorization": f"Bearer {tokens[0]}"})  # fmt: skip
                assert r.status_code == 503, "the first start's token passes the check (then no mesh answers)"
            finally:
                ui.stop()
                bus.close()
        assert tokens[0] == tokens[1]
    finally:
        router.close()


def test_health_is_degraded_while_the_sensor_is_down(tmp_path):
    from lcmesh.mesh.agents.configuration import ConfigurationAgent
    from lcmesh.mesh.agents.sensor import SensorAgent
    from lcmesh.mesh.bus import Bus

    settings = make_settings(tmp_path / "mesh", ui_port=free_port())
    router = Bus.open_router(settings)
    running: list = []  # (agent, bus), stopped in reverse

    def start(agent):
        bus = Bus.connect(settings, agent.agent_id)
        running.append((agent, bus))
        agent.start(bus)
        return agent

    try:
        start(ConfigurationAgent(settings))
        sensor = start(SensorAgent(settings))
        ui, bus = _ui(settings)
        running.append((ui, bus))
        health = lambda: httpx.get(ui.url + "/api/health", timeout=10).json()  # noqa: E731
        assert wait_until(lambda: health()["status"] == "ok", 30), health()
        assert health()["sensor_alive"] and health()["ready"]
        sensor_entry = next(e for e in running if e[0] is sensor)
        running.remove(sensor_entry)
        sensor.stop()
        sensor_entry[1].close()
        down = wait_until(lambda: (h := health())["status"] == "degraded" and h, 30)
        assert down, health()
        assert not down["sensor_alive"] and "Sensor agent is down" in " ".join(down["reasons"])
        assert down["ready"], "the last state and the history still answer"
    finally:
        for agent, bus in reversed(running):
            try:
                agent.stop()
            finally:
                bus.close()
        router.close()


@pytest.mark.skipif(shutil.which("promtool") is None, reason="promtool not installed (Debian: apt-get install prometheus)")
def test_metrics_pass_promtool(api, tmp_path):
    text = api.get("/metrics").text
    assert "lcmesh_cdu_secondary_flow_grams_per_second" in text
    done = subprocess.run(["promtool", "check", "metrics"], input=text, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stdout + done.stderr

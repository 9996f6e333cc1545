"""The bus on a real zenoh router on loopback."""

from __future__ import annotations

import threading
import time

import pytest

from lcmesh.mesh import keys
from lcmesh.mesh.bus import Bus, BusError, QueryError
from lcmesh.mesh.messages import AgentEvent, CommandReply
from tests.mesh.conftest import make_settings, wait_until


@pytest.fixture
def mesh_settings(tmp_path):
    """The bus's own mechanics, on any key, without authentication (the router's ACL: tests/mesh/test_security.py)."""
    return make_settings(tmp_path / "mesh", bus_auth=False)


def _event(detail="x"):
    return AgentEvent(source="tester", kind="started", role="sensor", agent_id="sensor", detail=detail)


def test_typed_publish_subscribe(client, mesh_settings):
    got = []
    other = Bus.connect(mesh_settings, "other")
    try:
        other.subscribe(keys.events("test"), AgentEvent, got.append)
        time.sleep(0.2)
        client.publish(keys.events("test", "sensor"), _event("hello"))
        assert wait_until(lambda: got, 5)
        assert got[0].detail == "hello" and got[0].source == "tester"
        assert other.counters.snapshot()["msgs_in"]["events/*"] == 1
    finally:
        other.close()


def test_garbage_is_dropped_and_counted_and_a_failing_handler_never_raises(client, mesh_settings):
    got = []

    def handler(event):
        if event.detail == "boom":
            raise RuntimeError("handler bug")
        got.append(event)

    other = Bus.connect(mesh_settings, "other")
    errors = []
    other.on_error = lambda where, exc: errors.append((where, exc))
    try:
        other.subscribe(keys.events("test"), AgentEvent, handler)
        time.sleep(0.2)
        key = keys.events("test", "sensor")
        for junk in (b"", b"\xff\xfe", b"not json", b'{"kind": "started"}', b"[1,2,3]", b'{"schema_version": 99}'):
            client.publish_raw(key, junk)
        client.publish(key, _event("boom"))
        client.publish(key, _event("after"))
        assert wait_until(lambda: got, 5)
        snap = other.counters.snapshot()
        assert snap["invalid"]["events/*"] == 6
        assert snap["handler_errors"] == 1 and len(errors) == 1
        assert [e.detail for e in got] == ["after"]
    finally:
        other.close()


def test_late_joiner_gets_the_latest_value(client, mesh_settings):
    key = keys.plant_state("test") + "x"
    client.publish(key, _event("first"), latest=True)
    client.publish(key, _event("second"), latest=True)
    late = Bus.connect(mesh_settings, "late")
    got = []
    try:
        late.subscribe(key, AgentEvent, got.append, latest=True)
        assert [e.detail for e in got] == ["second"]
    finally:
        late.close()


def test_queryables_answer_and_report_bad_requests(client, mesh_settings):
    server = Bus.connect(mesh_settings, "server")

    def handler(payload):
        if payload == b"bad":
            raise QueryError("`x` must be positive")
        if payload == b"crash":
            raise KeyError("oops")
        return CommandReply(ok=True, detail=(payload or b"").decode())

    try:
        server.serve(keys.cmd("test", "server", "echo"), handler)
        time.sleep(0.2)
        key = keys.cmd("test", "server", "echo")
        assert client.request(key, CommandReply, b"hi").detail == "hi"
        with pytest.raises(BusError, match="`x` must be positive"):
            client.request(key, CommandReply, b"bad")
        with pytest.raises(BusError, match="internal error in server: KeyError"):
            client.request(key, CommandReply, b"crash")
        with pytest.raises(BusError, match="nobody serves it"):
            client.request(keys.cmd("test", "nobody", "echo"), CommandReply, timeout_s=0.5)
        assert server.counters.snapshot()["invalid"]["cmd/server/echo"] == 1
        assert server.counters.snapshot()["handler_errors"] == 1
    finally:
        server.close()


def test_liveliness_shows_a_token_coming_and_going(client, mesh_settings):
    changes = []
    client.watch_liveliness(keys.alive_all("test"), lambda key, alive: changes.append((key, alive)))
    agent = Bus.connect(mesh_settings, "a1")
    agent.declare_token(keys.alive("test", "sensor", "a1"))
    assert wait_until(lambda: (keys.alive("test", "sensor", "a1"), True) in changes, 5)
    token = keys.alive("test", "sensor", "a1")
    assert wait_until(lambda: client.alive(keys.alive_role("test", "sensor")) == [token], 5)
    agent.close()
    assert wait_until(lambda: (keys.alive("test", "sensor", "a1"), False) in changes, 5)


def test_connect_fails_clearly_without_a_router(tmp_path):
    settings = make_settings(tmp_path, bus_auth=False)
    with pytest.raises(BusError, match=r"could not reach a router at tcp/127\.0\.0\.1:\d+ .*lcmesh router"):
        Bus.connect(settings, "lonely", timeout_s=0.5)


def test_connect_retries_until_the_router_comes_up(tmp_path):
    settings = make_settings(tmp_path)  # with authentication: the router writes the secrets the client waits for
    result = {}

    def connect():
        result["bus"] = Bus.connect(settings, "patient", timeout_s=10.0)

    thread = threading.Thread(target=connect)
    thread.start()
    time.sleep(0.6)
    router = Bus.open_router(settings)
    try:
        thread.join()  # connect gives up by itself after its 10 s
        assert "bus" in result
        result["bus"].close()
    finally:
        router.close()

"""`lcmesh agent ui` as its own process: serves on its port, makes a token file, stops cleanly; refuses an insecure bind."""

from __future__ import annotations

import os
import shutil
import signal
import stat
import subprocess
import sys
from pathlib import Path

import httpx
import pytest

from tests.mesh.conftest import free_port, wait_until

LCMESH = shutil.which("lcmesh") or str(Path(sys.executable).parent / "lcmesh")


@pytest.fixture
def router_env(tmp_path):
    from lcmesh.mesh.bus import Bus
    from tests.mesh.conftest import make_settings

    settings = make_settings(tmp_path / "mesh", site="clitest")
    router = Bus.open_router(settings)
    env = {k: v for k, v in os.environ.items() if not k.startswith("LCMESH_") or k == "LCMESH_CACHE_DIR"}
    env.update(LCMESH_SITE="clitest", LCMESH_ROUTER_ENDPOINTS=settings.router_endpoints[0],
               LCMESH_DATA_DIR=str(tmp_path / "mesh"), LCMESH_UI_PORT=str(free_port()), LCMESH_LOG_LEVEL="INFO")  # fmt: skip
    yield env
    router.close()


def _run(env: dict) -> subprocess.Popen:
    return subprocess.Popen([LCMESH, "agent", "ui"], env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, start_new_session=True)  # fmt: skip


def _stop(proc: subprocess.Popen) -> str:
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGTERM)
    try:
        out, _ = proc.communicate(timeout=20)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, _ = proc.communicate(timeout=10)
    return out


def _health(url: str):
    try:
        return httpx.get(url + "/api/health", timeout=1.0).json()
    except httpx.HTTPError:
        return None


def test_lcmesh_agent_ui_serves_and_stops_cleanly(router_env, tmp_path):
    url = f"http://127.0.0.1:{router_env['LCMESH_UI_PORT']}"
    proc = _run(router_env)
    try:
        health = wait_until(lambda: _health(url) or (proc.poll() is not None and "exited"), 90, 0.2)
        assert isinstance(health, dict), f"no UI: {_stop(proc)}"
        assert health["status"] == "starting" and "Sensor" in " ".join(health["reasons"])
        token_file = tmp_path / "mesh" / "ui" / "api-token"
        assert stat.S_IMODE(token_file.stat().st_mode) == 0o600
        token = token_file.read_text().strip()
        assert httpx.put(url + "/api/config", json={"changes": {}}).status_code == 401
        r = httpx.put(url + "/api/config", json={"changes": {}}, headers={"Authorization": f"Bearer {token}"},
                      timeout=10.0)  # fmt: skip
        assert r.status_code == 503 and "Configuration agent" in r.json()["detail"]
        assert "<title>lc-mesh operator console</title>" in httpx.get(url + "/").text
    finally:
        out = _stop(proc)
    assert proc.returncode == 0, out


def test_lcmesh_agent_ui_refuses_to_listen_beyond_loopback_without_a_strong_token(router_env):
    env = {**router_env, "LCMESH_UI_HOST": "0.0.0.0", "LCMESH_API_TOKEN": "changeme"}
    proc = _run(env)
    try:
        proc.wait(timeout=90)
    finally:
        out = _stop(proc)
    assert proc.returncode == 2, out
    assert "refusing to listen on 0.0.0.0" in out and "at least 16 characters" in out

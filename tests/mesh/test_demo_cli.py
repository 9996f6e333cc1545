"""The mesh commands' errors and the healthcheck (`lcmesh demo` end to end: test_faults.py)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from typer.testing import CliRunner

from lcmesh.cli import app
from lcmesh.mesh import keys
from lcmesh.mesh.bus import Bus
from tests.mesh.conftest import free_port, make_settings

LCMESH = str(Path(sys.executable).parent / "lcmesh")


def test_agent_command_errors_name_what_is_valid(tmp_path, monkeypatch):
    runner = CliRunner()
    result = runner.invoke(app, ["agent", "sensr"])
    assert result.exit_code == 2 and "did you mean 'sensor'" in result.output
    monkeypatch.setenv("LCMESH_ROUTER_ENDPOINTS", f"tcp/127.0.0.1:{free_port()}")
    monkeypatch.setenv("LCMESH_CONNECT_TIMEOUT_S", "0.3")
    result = runner.invoke(app, ["agent", "sensor", "--check"])
    assert result.exit_code == 2 and "could not reach a router" in result.output
    result = runner.invoke(app, ["router", "--listen", "localhost:7447"])
    assert result.exit_code == 2 and "`listen_endpoints`" in result.output


def test_agent_check_sees_a_live_agent(tmp_path):
    port = free_port()
    settings = make_settings(tmp_path, port, site="default")
    router = Bus.open_router(settings)
    agent = Bus.connect(settings, "sensor")
    try:
        agent.declare_token(keys.alive("default", "sensor", "sensor"))
        env = {**os.environ, "LCMESH_ROUTER_ENDPOINTS": f"tcp/127.0.0.1:{port}", "LCMESH_DATA_DIR": str(tmp_path)}
        ok = subprocess.run([LCMESH, "agent", "sensor", "--check"], env=env, capture_output=True, text=True, timeout=30)
        missing = subprocess.run([LCMESH, "agent", "control", "--check"], env=env, capture_output=True, text=True,
                                 timeout=30)  # fmt: skip
    finally:
        agent.close()
        router.close()
    assert ok.returncode == 0 and "alive/sensor/sensor" in ok.stderr + ok.stdout
    assert missing.returncode == 1


def test_a_long_error_line_stays_one_line_in_a_log_file(tmp_path):
    """The demo's output to a file (its log under systemd, a bench's .out) keeps each message on one line, however long:
    the console soft-wraps, it does not break lines at 80 columns ("held by pid\\n9142")."""
    import socket

    log_path = tmp_path / "demo.log"
    env = {k: v for k, v in os.environ.items() if k != "COLUMNS" and not k.startswith("LCMESH_")}
    with socket.socket() as held, open(log_path, "wb") as log:
        held.bind(("127.0.0.1", 0))
        held.listen()
        port = held.getsockname()[1]
        done = subprocess.run([LCMESH, "demo", "--port", str(port), "--ui-port", str(free_port()), "--data-dir",
                               str(tmp_path / "mesh")], env=env, stdout=log, stderr=subprocess.STDOUT,
                              stdin=subprocess.DEVNULL, timeout=120)  # fmt: skip
    lines = log_path.read_text().splitlines()
    assert done.returncode == 3, lines
    said = [line for line in lines if "can not run" in line]
    assert len(said) == 1 and f"held by pid {os.getpid()} (" in said[0] and said[0].rstrip().endswith("another port"), \
        lines  # fmt: skip
    assert len(said[0]) > 80

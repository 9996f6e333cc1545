"""docker-compose.yml: `docker-compose config` passes, and its services' commands, run as local
processes on loopback (router host -> 127.0.0.1, /data -> a temp folder), make a working mesh."""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from lcmesh.mesh import keys
from lcmesh.mesh.agents.registry import unavailable_reason
from lcmesh.mesh.bus import Bus
from lcmesh.mesh.history import HistoryReader
from lcmesh.mesh.processes import Child, tcp_host_port, wait_for_port
from tests.mesh.conftest import free_port, make_settings, wait_until

ROOT = Path(__file__).resolve().parents[2]
COMPOSE = ROOT / "docker-compose.yml"


def test_docker_compose_config_passes():
    tool = shutil.which("docker-compose")
    if tool is None:
        pytest.skip("docker-compose is not installed")
    result = subprocess.run([tool, "-f", str(COMPOSE), "config", "-q"], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    services = _lcmesh_services()
    assert {"router", "configuration", "sensor", "control", "maintenance", "monitor", "orchestration", "ui"} <= set(services)
    assert all("healthcheck" in s for s in services.values())
    assert all("lcmesh-data:/data" in s["volumes"] for name, s in services.items() if name != "router")


def _lcmesh_services() -> dict:
    """The mesh's own services (the file may hold others, e.g. Prometheus and Grafana for the UI's metrics)."""
    services = yaml.safe_load(COMPOSE.read_text())["services"]
    return {name: s for name, s in services.items() if str(s.get("command", "")).startswith("lcmesh ")}


def _local(env: dict, port: int, data_dir: Path) -> dict:
    """A service's environment, pointed at loopback and a temp folder."""
    mapping = {"tcp/router:7447": f"tcp/127.0.0.1:{port}", "tcp/0.0.0.0:7447": f"tcp/127.0.0.1:{port}",
               "0.0.0.0": "127.0.0.1", "8000": str(free_port())}  # fmt: skip

    def local(value: str) -> str:
        value = re.sub(r"\$\{(\w+):-([^}]*)\}", lambda m: os.environ.get(m[1], m[2]), value)  # compose's ${X:-d}
        if value == "/data" or value.startswith("/data/"):  # the volume
            return str(data_dir) + value[len("/data"):]
        return mapping.get(value, value)

    return {k: local(str(v)) for k, v in env.items()}


@pytest.mark.slow  # a whole mesh of 8 processes (22 s); the compose file is checked above
def test_the_compose_services_make_a_working_mesh(tmp_path):
    services = _lcmesh_services()
    port = free_port()
    lcmesh_bin = str(Path(sys.executable).parent / "lcmesh")
    children: list[Child] = []
    base_env = {k: v for k, v in os.environ.items() if not k.startswith("LCMESH_") or k == "LCMESH_CACHE_DIR"}
    envs = {}
    try:
        for name, service in services.items():  # router first: it is first in the file
            role = name
            if name != "router" and unavailable_reason(role):
                continue
            env = {**base_env, **_local(service.get("environment") or {}, port, tmp_path), "PYTHONUNBUFFERED": "1"}
            envs[name] = env
            argv = shlex.split(service["command"])
            assert argv[0] == "lcmesh"
            children.append(Child(name, [lcmesh_bin, *argv[1:]], env, tmp_path / f"{name}.log").start())
            if name == "router":
                assert wait_for_port(*tcp_host_port(f"tcp/127.0.0.1:{port}"), timeout_s=20)
        settings = make_settings(tmp_path, port, site="default")
        bus = Bus.connect(settings, "compose-test")
        try:
            roles = [n for n in envs if n != "router"]
            expected = {keys.alive("default", r, r) for r in roles}
            assert wait_until(lambda: expected <= set(bus.alive(keys.alive_all("default"))), 60), bus.alive(
                keys.alive_all("default"))
            history = HistoryReader(tmp_path / "history.sqlite")
            assert wait_until(lambda: any(not d["fallback"] for d in history.decisions(limit=20)), 60)
        finally:
            bus.close()
        for name in ("sensor", "router"):  # the healthchecks, as the container engine would run them
            test = [t.replace("7447", str(port)) for t in services[name]["healthcheck"]["test"][1:]]
            argv = [lcmesh_bin, *test[1:]] if test[0] == "lcmesh" else [sys.executable, *test[1:]]
            done = subprocess.run(argv, env=envs[name], capture_output=True, text=True, timeout=30)
            assert done.returncode == 0, (name, done.stdout, done.stderr)
    finally:
        codes = {c.name: c.stop(timeout_s=15) for c in reversed(children)}
    assert all(code == 0 for code in codes.values()), {n: (c, (tmp_path / f"{n}.log").read_text()[-2000:])
                                                       for n, c in codes.items() if c != 0}  # fmt: skip

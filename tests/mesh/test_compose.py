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


HISTORY_WRITER = "sensor"  # lcmesh/mesh/agents/recorder.py: the one agent that opens a HistoryWriter


def test_only_the_history_writer_mounts_history_writable():
    """History sits on a volume of its own: the Sensor mounts it read-write, the agents that read it ``:ro``, others
    not at all (the shared data volume holds no history file)."""
    env = yaml.safe_load(COMPOSE.read_text())["x-lcmesh-env"]
    folder = str(Path(env["LCMESH_HISTORY_PATH"]).parent)
    assert folder.startswith(env["LCMESH_DATA_DIR"] + "/"), "the local run below maps /data only"
    services = _lcmesh_services()
    volume = next(v.split(":")[0] for v in services[HISTORY_WRITER]["volumes"] if v.split(":")[1] == folder)
    mounts = {}
    for name, service in services.items():
        for source, target, *mode in (v.split(":") for v in service.get("volumes", [])):
            if source == volume:
                assert target == folder, (name, target)
                mounts[name] = mode[0] if mode else "rw"
    writable = sorted(name for name, mode in mounts.items() if mode != "ro")
    assert writable == [HISTORY_WRITER], f"only {HISTORY_WRITER} may mount the history read-write, got {writable}"
    assert {"configuration", "maintenance", "ui"} <= set(mounts), "the readers see the file, read-only"
    assert "router" not in mounts and "control" not in mounts


AGENT_ROLES = ("configuration", "sensor", "control", "maintenance", "monitor", "orchestration", "ui")


def _mounts(service: dict) -> list[tuple[str, str, bool]]:
    """(source, target, read-only) of each volume, short ("src:dst:ro") or long ({source, target, read_only})."""
    out = []
    for volume in service.get("volumes") or []:
        if isinstance(volume, dict):
            out.append((volume.get("source", ""), volume["target"], bool(volume.get("read_only"))))
        else:
            source, target, *mode = volume.split(":")
            out.append((source, target, "ro" in mode[0].split(",") if mode else False))
    return out


def _compose_models() -> list[dict]:
    """The file as parsed, and as `docker compose config` resolves it where that tool is installed."""
    models = [yaml.safe_load(COMPOSE.read_text())]
    for tool in (["docker-compose"], ["docker", "compose"]):
        if shutil.which(tool[0]) is None:
            continue
        done = subprocess.run([*tool, "-f", str(COMPOSE), "config"], capture_output=True, text=True, timeout=60)
        if done.returncode == 0:
            models.append(yaml.safe_load(done.stdout))
            break
    return models


@pytest.mark.parametrize("model", _compose_models(), ids=lambda m: "resolved" if "name" in m else "file")
def test_each_service_mounts_only_its_own_roles_secrets(model):
    """No agent can read another role's bus password (or the config signing key): its own folder, read-only."""
    env = model["x-lcmesh-env"] if "x-lcmesh-env" in model else model["services"]["sensor"]["environment"]
    secrets = env.get("LCMESH_SECRETS_DIR", env["LCMESH_DATA_DIR"] + "/secrets")  # settings.secrets_path
    services = {n: s for n, s in model["services"].items() if n in ("router", *AGENT_ROLES)}
    assert set(services) == {"router", *AGENT_ROLES}
    holders: dict[str, set[str]] = {}  # a volume under SECRETS_DIR -> the services that mount it
    for name, service in services.items():
        assert "LCMESH_BUS_PASSWORD" not in (service.get("environment") or {}), name
        for source, target, read_only in _mounts(service):
            assert name == "router" or not secrets.startswith(target.rstrip("/") + "/"), \
                f"{name} mounts {target}, which holds every role's secrets"
            if target == secrets or target.startswith(secrets + "/"):
                holders.setdefault(source, set()).add(name)
                if name == "router":
                    continue  # it creates them
                assert target in (f"{secrets}/{name}", f"{secrets}/public"), f"{name} mounts {target}"
                assert read_only, f"{name} mounts {target} writable"
    for role in AGENT_ROLES:  # each role's volume: its service and the router, nobody else
        mine = [v for v in holders if _router_target(services, v) == f"{secrets}/{role}"]
        assert len(mine) == 1 and holders[mine[0]] == {"router", role}, (role, mine, holders)


def _router_target(services: dict, volume: str) -> str:
    """Where the router mounts `volume`: which role's folder it is."""
    return next(t for s, t, _ in _mounts(services["router"]) if s == volume)


@pytest.mark.parametrize("model", _compose_models(), ids=lambda m: "resolved" if "name" in m else "file")
def test_the_config_store_and_api_token_are_their_owners_alone(model):
    services = {n: s for n, s in model["services"].items() if n in ("router", *AGENT_ROLES)}
    store = Path(services["configuration"]["environment"]["LCMESH_CONFIGURATION__STORE_PATH"])
    token = Path(services["ui"]["environment"]["LCMESH_API_TOKEN_FILE"])
    for path, owner in ((store, "configuration"), (token, "ui")):
        volume = next(s for s, t, ro in _mounts(services[owner]) if t == str(path.parent) and not ro)
        others = [n for n, service in services.items() if n != owner and any(s == volume for s, *_ in _mounts(service))]
        assert others == [], f"{path} is {owner}'s alone; also mounted by {others}"
        data = [t for n, service in services.items() for s, t, _ in _mounts(service) if s == "lcmesh-data"]
        assert all(not str(path).startswith(t + "/") for t in data), f"{path} must not be on the shared data volume"


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
        if value == "/data" or value.startswith("/data/"):  # the data volume
            return str(data_dir) + value[len("/data"):]
        for volume in ("/secrets", "/config", "/ui-token"):  # the others: a folder each in it
            if value == volume or value.startswith(volume + "/"):
                return str(data_dir) + value
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
            history = HistoryReader(tmp_path / "history" / "history.sqlite")
            assert wait_until(lambda: any(not d["fallback"] for d in history.decisions(limit=20)), 60)
        finally:
            bus.close()
        for name in ("sensor", "router"):  # the healthchecks, as the container engine would run them
            test = [t.replace("7447", str(port)) for t in services[name]["healthcheck"]["test"][1:]]
            argv = [lcmesh_bin, *test[1:]] if test[0] == "lcmesh" else [sys.executable, *test[1:]]
            done = subprocess.run(argv, env=envs[name], capture_output=True, text=True, timeout=30)
            assert done.returncode == 0, (name, done.stdout, done.stderr)
    finally:
        grace = yaml.safe_load(COMPOSE.read_text())["x-agent"]["stop_grace_period"]  # what the engine gives
        codes = {c.name: c.stop(timeout_s=float(grace.removesuffix("s"))) for c in reversed(children)}
    assert all(code == 0 for code in codes.values()), {n: (c, (tmp_path / f"{n}.log").read_text()[-2000:])
                                                       for n, c in codes.items() if c != 0}  # fmt: skip


@pytest.mark.parametrize("model", _compose_models(), ids=lambda m: "resolved" if "name" in m else "file")
def test_no_volume_is_writable_by_two_services(model):
    """Least privilege between containers: a volume two services mount is writable by one of them at most (the
    router for the secrets, the Sensor for history), so no container can change what another reads."""
    writers: dict[str, list[str]] = {}
    for name, service in model["services"].items():
        for source, _target, read_only in _mounts(service):
            if source and not source.startswith((".", "/")) and not read_only:  # named volumes, not bind mounts
                writers.setdefault(source, []).append(name)
    shared = {volume: names for volume, names in writers.items() if len(names) > 1}
    assert not shared, f"volumes writable by more than one service: {shared}"


def test_published_ports_are_on_loopback():
    """The router, the UI and the dashboards are published on the host's loopback only (docs/mesh.md, Security)."""
    for name, service in yaml.safe_load(COMPOSE.read_text())["services"].items():
        for port in service.get("ports", []):
            assert str(port).startswith("127.0.0.1:"), f"{name} publishes {port} beyond the host's loopback"



def test_the_engine_waits_longer_than_an_agent_may_take_to_stop():
    """compose's stop_grace_period is above the agent's own bound, so a clean stop is never SIGKILLed."""
    from lcmesh.mesh.agents.runner import AGENT_STOP_GRACE_S

    grace = yaml.safe_load(COMPOSE.read_text())["x-agent"]["stop_grace_period"]
    assert float(grace.removesuffix("s")) > AGENT_STOP_GRACE_S

"""What runs for a data dir, a clean stop of it, and clear errors for a port or data dir already in use.

``lcmesh status`` and ``lcmesh stop`` read this module; the demo, the router and the UI agent ask it
who holds a port before they give up.

- A demo writes ``DATA_DIR/mesh.json`` (its pid with its start time, the router endpoint, the UI
  address, its children's pids) when it starts, rewrites it when it restarts a child, and removes it
  on a clean stop. A file whose demo is gone is a crashed run, and says so.
- The mesh's processes are found by what they are, not by what a file says: every process whose
  command line is lc-mesh's and whose data dir (``LCMESH_DATA_DIR`` or ``--data-dir``, resolved
  against its working directory) is this one. Agents a killed orchestrator left behind are found too.
- A port another run holds is named with that process, its role, its data dir and how to stop it.
"""

from __future__ import annotations

import os
import signal
import time
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import psutil
from pydantic import BaseModel, ConfigDict

from lcmesh.mesh.processes import same_process, start_ticks

RUN_FILE = "mesh.json"
EXIT_BUSY = 3  # a port or the data dir is held by another process (the router's "can not listen" code)
DATA_DIR_DEFAULT = "runs/mesh"  # MeshSettings.data_dir's default, for a demo started without the option


class RunFile(BaseModel):
    """``DATA_DIR/mesh.json``: the demo that runs this data dir and what it started."""

    model_config = ConfigDict(extra="ignore")

    pid: int
    start_ticks: int | None
    started_at: datetime
    data_dir: str
    router_endpoint: str
    ui_url: str | None = None
    router_pid: int | None = None
    orchestrator_pid: int | None = None
    system: str = ""
    trace: str = ""
    controller: str = ""

    def demo_running(self) -> bool:
        return same_process(self.pid, self.start_ticks)


def write_run_file(data_dir: Path, run: RunFile) -> None:
    """Write atomically (a reader never sees half a file)."""
    path = Path(data_dir) / RUN_FILE
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(run.model_dump_json(indent=1))
    os.replace(tmp, path)


def read_run_file(data_dir: Path) -> RunFile | None:
    try:
        return RunFile.model_validate_json((Path(data_dir) / RUN_FILE).read_text())
    except (OSError, ValueError):
        return None


def remove_run_file(data_dir: Path, pid: int) -> None:
    """Remove the run file if it is `pid`'s (a demo never removes another's)."""
    run = read_run_file(data_dir)
    if run is not None and run.pid == pid:
        (Path(data_dir) / RUN_FILE).unlink(missing_ok=True)


def new_run_file(data_dir: Path, **fields) -> RunFile:
    """This process's run file for `data_dir`."""
    return RunFile(pid=os.getpid(), start_ticks=start_ticks(os.getpid()), started_at=datetime.now(timezone.utc),
                   data_dir=str(Path(data_dir).resolve()), **fields)  # fmt: skip


# --- the mesh's processes ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class MeshProcess:
    """One lc-mesh process: its pid, what it is (demo, router, an agent id) and the data dir it serves."""

    pid: int
    role: str
    data_dir: Path | None
    started: float  # epoch seconds

    def uptime_s(self, now: float | None = None) -> float:
        return max(0.0, (time.time() if now is None else now) - self.started)


def describe(proc: psutil.Process) -> MeshProcess | None:
    """`proc` as an lc-mesh process, or None if it is something else (or gone)."""
    try:
        argv = proc.cmdline()
        role = _role(argv)
        if role is None:
            return None
        env = _environ(proc)
        option = _option(argv, "--data-dir")
        where = option or env.get("LCMESH_DATA_DIR") or DATA_DIR_DEFAULT
        data_dir = Path(proc.cwd()) / where if not Path(where).is_absolute() else Path(where)
        return MeshProcess(proc.pid, role, data_dir.resolve(), proc.create_time())
    except (psutil.Error, OSError):
        return None


def _role(argv: list[str]) -> str | None:
    """'router', 'demo', the agent id, or the lcmesh subcommand; None for a process that is not lc-mesh's."""
    if "lcmesh.mesh.router" in argv:
        return "router"
    if "lcmesh.mesh.agents" in argv:
        after = argv[argv.index("lcmesh.mesh.agents") + 1:]
        return _option(after, "--id") or (after[0] if after else "agent")
    start = 1 if argv and Path(argv[0]).name.startswith("python") else 0  # python .../bin/lcmesh SUB, lcmesh SUB
    if len(argv) > start + 1 and Path(argv[start]).name == "lcmesh":
        sub = argv[start + 1]
        if sub == "agent" and len(argv) > start + 2:
            return _option(argv, "--id") or argv[start + 2]
        return sub if sub in ("demo", "router") else None
    return None


def _option(argv: list[str], name: str) -> str | None:
    for i, arg in enumerate(argv):
        if arg == name and i + 1 < len(argv):
            return argv[i + 1]
        if arg.startswith(name + "="):
            return arg.split("=", 1)[1]
    return None


def _environ(proc: psutil.Process) -> dict[str, str]:
    try:
        return proc.environ()
    except psutil.Error:
        return {}


def mesh_processes(data_dir: Path) -> list[MeshProcess]:
    """Every lc-mesh process (but this one) that serves `data_dir`, oldest first."""
    target = Path(data_dir).resolve()
    found = []
    for proc in psutil.process_iter():
        if proc.pid == os.getpid():
            continue
        described = describe(proc)
        if described is not None and described.data_dir == target:
            found.append(described)
    return sorted(found, key=lambda p: p.started)


# --- ports --------------------------------------------------------------------------------------------------------
def port_listener(port: int) -> tuple[bool, int | None]:
    """(whether some process listens on TCP `port`, its pid if this user may see it)."""
    try:
        for conn in psutil.net_connections(kind="tcp"):
            if conn.status == psutil.CONN_LISTEN and conn.laddr and conn.laddr.port == port:
                return True, conn.pid
    except psutil.Error:
        pass
    return False, None


def port_held_message(port: int, what: str) -> str | None:
    """Who holds `port`, and how to free it; None if nobody listens on it."""
    held, pid = port_listener(port)
    if not held:
        return None
    if pid is None:
        return (f"port {port} ({what}) is already in use by a process this user can not see; stop it or choose "
                "another port")  # fmt: skip
    if pid == os.getpid():
        return f"port {port} ({what}) is already in use by this process"
    try:
        proc = psutil.Process(pid)
        mesh = describe(proc)
        if mesh is None:
            name = " ".join(proc.cmdline())[:120] or proc.name()
            return (f"port {port} ({what}) is held by pid {pid} ({name}), which is not an lc-mesh process: stop it "
                    "or choose another port")  # fmt: skip
    except psutil.Error:
        return f"port {port} ({what}) is held by pid {pid}, which just ended; try again"
    return (f"port {port} ({what}) is held by lc-mesh {mesh.role} pid {pid} of the mesh in {mesh.data_dir} (up "
            f"{_duration(mesh.uptime_s())}): stop that mesh with `lcmesh stop --data-dir {mesh.data_dir}` (or "
            f"`kill {pid}`), or choose other ports (lcmesh demo --port, --ui-port)")  # fmt: skip


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def busy_reason(data_dir: Path, ports: dict[int, str]) -> str | None:
    """Why a new mesh can not start on `data_dir` and `ports` ({port: what}), or None if it can."""
    run = read_run_file(data_dir)
    if run is not None and run.demo_running():
        return (f"a mesh already runs for {Path(data_dir).resolve()}: demo pid {run.pid}, started "
                f"{run.started_at:%Y-%m-%d %H:%M:%S} UTC; `lcmesh status --data-dir {data_dir}` shows it and "
                f"`lcmesh stop --data-dir {data_dir}` stops it")  # fmt: skip
    left = mesh_processes(data_dir)
    if left:
        listing = ", ".join(f"{p.role} pid {p.pid}" for p in left)
        return (f"processes of an earlier mesh still run for {Path(data_dir).resolve()} ({listing}); "
                f"`lcmesh stop --data-dir {data_dir}` stops them")  # fmt: skip
    for port, what in ports.items():
        message = port_held_message(port, what)
        if message is not None:
            return message
    return None


# --- status and stop ------------------------------------------------------------------------------------------------
def mesh_status(data_dir: Path, history_file: Path | None = None) -> dict:
    """What runs for `data_dir`: the demo, every process with its uptime, the ports, the plant's last step."""
    data_dir = Path(data_dir).resolve()
    run = read_run_file(data_dir)
    now = time.time()
    procs = mesh_processes(data_dir)
    demo_running = run is not None and run.demo_running()
    status = {
        "data_dir": str(data_dir),
        "running": demo_running or bool(procs),
        "demo": None if run is None else {
            "pid": run.pid, "running": demo_running, "started_at": run.started_at.isoformat(),
            "router_endpoint": run.router_endpoint, "ui_url": run.ui_url, "system": run.system,
            "trace": run.trace, "controller": run.controller,
        },
        "processes": [{"pid": p.pid, "role": p.role, "uptime_s": round(p.uptime_s(now), 1)} for p in procs],
        "ports": {},
        "plant": plant_progress(history_file or data_dir / "history.sqlite"),
    }  # fmt: skip
    if run is not None:
        ports = {"router": _endpoint_port(run.router_endpoint)}
        if run.ui_url:
            ports["ui"] = int(run.ui_url.rsplit(":", 1)[1].split("/")[0])
        for name, port in ports.items():
            if port is not None:
                held, pid = port_listener(port)
                status["ports"][name] = {"port": port, "listening": held, "pid": pid}
    if run is not None and not demo_running and run.pid not in {p.pid for p in procs}:
        status["note"] = f"the demo (pid {run.pid}) ended without a clean stop"
    return status


def _endpoint_port(endpoint: str) -> int | None:
    try:
        return int(endpoint.rsplit(":", 1)[1])
    except (IndexError, ValueError):
        return None


def plant_progress(history_file: Path) -> dict | None:
    """The newest run's last stored step and plant time, from the history file (None without one)."""
    import sqlite3

    if not Path(history_file).exists():
        return None
    try:
        conn = sqlite3.connect(f"file:{history_file}?mode=ro", uri=True, timeout=2.0)
        try:
            row = conn.execute("SELECT r.run_id, r.ended_at, MAX(s.step), MAX(s.time_s) FROM runs r LEFT JOIN "
                               "plant_states s ON s.run_id = r.run_id GROUP BY r.run_id ORDER BY r.started_at DESC "
                               "LIMIT 1").fetchone()  # fmt: skip
        finally:
            conn.close()
    except sqlite3.Error as exc:
        return {"error": f"could not read {history_file}: {exc}"}
    if row is None:
        return None
    return {"run_id": row[0], "ended": row[1] is not None, "step": row[2], "time_s": row[3]}


def stop_mesh(data_dir: Path, timeout_s: float = 60.0, say=print) -> list[MeshProcess]:
    """Stop what runs for `data_dir`: SIGTERM the demo (it stops its children in order), then SIGTERM whatever
    is left, SIGKILL after `timeout_s`; the processes still running afterwards (none on success)."""
    data_dir = Path(data_dir).resolve()
    run = read_run_file(data_dir)
    deadline = time.monotonic() + timeout_s
    if run is not None and run.demo_running():
        say(f"stopping the demo (pid {run.pid}) ...")
        _signal(run.pid, signal.SIGTERM)
        while run.demo_running() and time.monotonic() < deadline:
            time.sleep(0.1)
    left = mesh_processes(data_dir)
    for proc in left:
        say(f"stopping {proc.role} (pid {proc.pid})")
        _signal(proc.pid, signal.SIGCONT)
        _signal(proc.pid, signal.SIGTERM)
    grace = time.monotonic() + min(10.0, max(1.0, deadline - time.monotonic()))
    while left and time.monotonic() < grace:
        time.sleep(0.1)
        left = [p for p in left if _alive(p)]
    for proc in left:
        say(f"killing {proc.role} (pid {proc.pid}): it did not stop on SIGTERM")
        _signal(proc.pid, signal.SIGKILL)
    left = [p for p in left if _wait_gone(p, 5.0)]
    if run is not None and not run.demo_running():
        (data_dir / RUN_FILE).unlink(missing_ok=True)
    return left


def _signal(pid: int, sig: int) -> None:
    try:
        os.kill(pid, sig)
    except (ProcessLookupError, PermissionError):
        pass


def _alive(proc: MeshProcess) -> bool:
    try:
        p = psutil.Process(proc.pid)
        return p.create_time() == proc.started and p.status() != psutil.STATUS_ZOMBIE
    except psutil.Error:
        return False


def _wait_gone(proc: MeshProcess, timeout_s: float) -> bool:
    """True if `proc` still runs after `timeout_s`."""
    deadline = time.monotonic() + timeout_s
    while _alive(proc) and time.monotonic() < deadline:
        time.sleep(0.05)
    return _alive(proc)

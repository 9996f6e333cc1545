"""``lcmesh bench mesh``: latency from plant-state publish to applied action, and the highest speed factor.

Both run the demo's processes for real (router, configuration, sensor, control, maintenance,
monitor, each its own process on loopback, on the Frontier day) and read what the Sensor
reports on the bus: every ``AppliedAction`` carries ``latency_ms`` (the Sensor's own clock, from
publishing the state to the action passing the guardrails) and ``late_ms``; every ``PlantState``
carries the control period it ran at.

- latency: p50/p99 over the steps a proposal made it, at a speed factor with room to spare.
- speed: the speed factor is raised through the Configuration agent, level by level; a level is
  sustained when no control period was missed (no fallback for want of a proposal, no period
  started more than half a period late).
"""

from __future__ import annotations

import os
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from lcmesh.bench.machine import machine_info
from lcmesh.mesh import keys
from lcmesh.mesh.bus import Bus
from lcmesh.mesh.demo import Demo
from lcmesh.mesh.messages import AppliedAction, ConfigDoc, ConfigUpdate, PlantState
from lcmesh.mesh.processes import free_port
from lcmesh.mesh.settings import MeshSettings

ROLES = ["configuration", "sensor", "control", "maintenance", "monitor"]
TARGET_P99_MS = {"lcopt-5": 10.0, "frontier-full": 50.0}
SPEED_LEVELS = (60, 120, 240, 480, 960, 1920, 3840, 7680)


class _Recorder:
    """Per-step period (from plant states) and applied-action figures, collected from the bus."""

    def __init__(self):
        self.lock = threading.Lock()
        self.period_s: dict[int, float] = {}
        self.applied: dict[int, AppliedAction] = {}

    def on_state(self, state: PlantState) -> None:
        with self.lock:
            self.period_s[state.step] = state.period_s

    def on_applied(self, applied: AppliedAction) -> None:
        with self.lock:
            self.applied[applied.step] = applied

    def steps(self, after: int = -1) -> int:
        with self.lock:
            return sum(1 for s in self.applied if s > after)


def _settings(root: Path, system: str, controller: str, speed_factor: float, port: int) -> MeshSettings:
    endpoint = f"tcp/127.0.0.1:{port}"
    return MeshSettings(
        site="bench", router_endpoints=[endpoint], listen_endpoints=[endpoint], system=system, controller=controller,
        speed_factor=speed_factor, data_dir=root, orchestration={"roles": ROLES}, connect_timeout_s=60.0,
    )  # fmt: skip


class _Mesh:
    """The demo's processes plus a client that records the bus."""

    def __init__(self, settings: MeshSettings, say: Callable[[str], None], full_state: bool):
        self.settings, self.say = settings, say
        self.demo = Demo(settings, say=lambda _line: None)
        self.recorder = _Recorder()
        self.bus: Bus | None = None
        self.full_state = full_state

    def __enter__(self) -> "_Mesh":
        self.demo.start()
        self.bus = Bus.connect(self.settings, "bench", timeout_s=30.0)
        site = self.settings.site
        self.bus.subscribe(keys.applied(site), AppliedAction, self.recorder.on_applied)
        if self.full_state:
            self.bus.subscribe(keys.plant_state(site), PlantState, self.recorder.on_state)
        return self

    def __exit__(self, *exc) -> None:
        if self.bus is not None:
            self.bus.close()
        self.demo.stop()

    def wait_steps(self, n: int, timeout_s: float, after: int = -1) -> None:
        """Until `n` applied steps with index above `after` arrived."""
        deadline = time.monotonic() + timeout_s
        while self.recorder.steps(after) < n:
            if time.monotonic() > deadline:
                got = self.recorder.steps(after)
                raise TimeoutError(f"only {got} of {n} steps in {timeout_s:.0f} s; see {self.settings.log_dir}")
            self.demo.watch()
            time.sleep(0.1)

    def wait_proposals(self, timeout_s: float) -> None:
        """Until the controller answers (it may still be loading), so start-up does not count."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self.recorder.lock:
                if any(a.latency_ms is not None for a in self.recorder.applied.values()):
                    return
            time.sleep(0.1)
        raise TimeoutError(f"no proposal was applied in {timeout_s:.0f} s; see {self.settings.log_dir}")


def measure_latency(system: str, controller: str, speed_factor: float, n_steps: int, port: int,
                    say: Callable[[str], None]) -> dict:  # fmt: skip
    """p50/p99 latency over `n_steps` steps after the controller's first applied proposal."""
    with tempfile.TemporaryDirectory(prefix="lcmesh-bench-") as root:
        settings = _settings(Path(root), system, controller, speed_factor, port)
        with _Mesh(settings, say, full_state=False) as mesh:
            mesh.wait_proposals(timeout_s=180.0)
            start = max(mesh.recorder.applied)
            mesh.wait_steps(n_steps, timeout_s=60.0 + 3 * n_steps * 15.0 / speed_factor, after=start)
            with mesh.recorder.lock:
                rows = [a for s, a in mesh.recorder.applied.items() if s > start][:n_steps]
    latency = np.array([a.latency_ms for a in rows if a.latency_ms is not None])
    used = sorted({a.source_controller for a in rows if not a.fallback})
    return {
        "system": system, "speed_factor": speed_factor, "period_ms": 15e3 / speed_factor, "steps": len(rows),
        "controllers_used": used, "fallback_steps": sum(a.fallback for a in rows),
        "p50_ms": float(np.percentile(latency, 50)) if latency.size else None,
        "p99_ms": float(np.percentile(latency, 99)) if latency.size else None,
        "max_ms": float(latency.max()) if latency.size else None,
        "target_p99_ms": TARGET_P99_MS.get(system),
    }  # fmt: skip


def measure_speed(controller: str, levels: tuple[int, ...], seconds_per_level: float, port: int,
                  say: Callable[[str], None]) -> dict:  # fmt: skip
    """Raise the speed factor level by level on lcopt-5; the highest level without a missed period."""
    results = []
    with tempfile.TemporaryDirectory(prefix="lcmesh-bench-") as root:
        settings = _settings(Path(root), "lcopt-5", controller, levels[0], port)
        with _Mesh(settings, say, full_state=True) as mesh:
            mesh.wait_proposals(timeout_s=180.0)
            config_key = keys.configure(settings.site, mesh.bus.role or "operator", "all")
            for level in levels:
                mesh.bus.request(config_key, ConfigDoc, ConfigUpdate(changes={"speed_factor": level}, by="bench"))
                settle_s = 3 * 15.0 / level + 0.3
                time.sleep(settle_s)
                first = max(mesh.recorder.applied) + 1
                n = max(40, int(seconds_per_level * level / 15.0))
                try:
                    mesh.wait_steps(n, timeout_s=10.0 + 3 * n * 15.0 / level, after=first - 1)
                except TimeoutError:
                    results.append({"speed_factor": level, "steps": 0, "missed": None, "note": "fell behind"})
                    break
                results.append(_level_figures(mesh.recorder, level, first, n))
                say(f"  {level}x: {results[-1]['missed']} missed of {results[-1]['steps']} periods")
                if results[-1]["missed_fraction"] > 0.05:
                    break
    sustained = [r["speed_factor"] for r in results if r.get("missed") == 0]
    return {"system": "lcopt-5", "levels": results, "max_sustained_speed_factor": max(sustained) if sustained else None,
            "roles": ROLES}  # fmt: skip


def _level_figures(recorder: _Recorder, level: int, first: int, n: int) -> dict:
    period_s = 15.0 / level
    with recorder.lock:
        rows = [recorder.applied[s] for s in range(first, first + n) if s in recorder.applied]
        periods = [recorder.period_s.get(s) for s in range(first, first + n)]
    no_proposal = sum(1 for a in rows if a.fallback and a.rejected_reason is None)
    late = sum(1 for a in rows if a.late_ms > 0.5 * period_s * 1e3)
    missed = sum(1 for a in rows if (a.fallback and a.rejected_reason is None) or a.late_ms > 0.5 * period_s * 1e3)
    latency = [a.latency_ms for a in rows if a.latency_ms is not None]
    return {
        "speed_factor": level, "period_ms": period_s * 1e3, "steps": len(rows), "missed": missed,
        "missed_fraction": missed / max(1, len(rows)), "no_proposal": no_proposal, "late": late,
        "off_period_states": sum(1 for p in periods if p is not None and abs(p - period_s) > 1e-9),
        "p99_ms": float(np.percentile(latency, 99)) if latency else None,
    }  # fmt: skip


def measure_encoding(system: str, repeats: int = 20) -> dict:
    """Size and in-process encode/decode time of one PlantState of `system` (JSON lists)."""
    from lcmesh.mesh.messages import plant_state_from_outputs, plant_state_to_observation
    from lcmesh.twin.plant import Plant
    from lcmesh.twin.system import load_system

    desc = load_system(system)
    with Plant(desc) as plant:
        power = np.full(desc.n_blade_groups, 1e4)
        t0 = time.perf_counter()
        for _ in range(repeats):
            msg = plant_state_from_outputs(plant.out, source="bench", system=desc, run_id="r", step=1, time_s=15.0,
                                           wet_bulb_k=290.0, blade_power_w=power, period_s=0.1)  # fmt: skip
            wire = msg.model_dump_json()
        encode = (time.perf_counter() - t0) / repeats
        t0 = time.perf_counter()
        for _ in range(repeats):
            plant_state_to_observation(PlantState.model_validate_json(wire), desc)
        decode = (time.perf_counter() - t0) / repeats
    return {"system": system, "state_bytes": len(wire), "encode_ms": encode * 1e3, "decode_ms": decode * 1e3}


def run_bench_mesh(controller: str = "tree", quick: bool = False, say: Callable[[str], None] = print) -> dict:
    """All mesh figures as one JSON-ready dict."""
    from lcmesh.mesh.agents.control import build_controller
    from lcmesh.twin.system import load_system

    notes = {}
    for system in TARGET_P99_MS:
        _, notes[system] = build_controller(controller, load_system(system))
        if notes[system]:
            say(f"note ({system}): {notes[system]}")
    port = free_port()
    load_before = os.getloadavg()[0]
    say("latency, lcopt-5 ...")
    small = measure_latency("lcopt-5", controller, 300.0, 60 if quick else 600, port, say)
    say(f"  p50 {small['p50_ms']:.2f} ms, p99 {small['p99_ms']:.2f} ms")
    say("latency, frontier-full ...")
    big = measure_latency("frontier-full", controller, 60.0 if quick else 100.0, 20 if quick else 200, port, say)
    say(f"  p50 {big['p50_ms']:.2f} ms, p99 {big['p99_ms']:.2f} ms")
    say("highest sustained speed factor, lcopt-5 ...")
    levels = SPEED_LEVELS[2:5] if quick else SPEED_LEVELS
    speed = measure_speed(controller, levels, 2.0 if quick else 6.0, port, say)
    return {
        "machine": machine_info(),
        "controller": {"requested": controller, "notes": notes},
        "latency": {"lcopt-5": small, "frontier-full": big},
        "speed": speed,
        "encoding": [measure_encoding("lcopt-5"), measure_encoding("frontier-full", repeats=5)],
        "load_average": {"before": load_before, "after": os.getloadavg()[0]},
        "quick": quick,
    }


def render_mesh(r: dict) -> str:
    """The BENCHMARKS.md section."""
    m, lat, speed = r["machine"], r["latency"], r["speed"]
    notes = r["controller"].get("notes") or {}
    lines = [
        "## Mesh (`lcmesh bench mesh --json runs/bench/mesh.json --markdown BENCHMARKS.md`)",
        "",
        f"Machine: {m['cpu']}, {m['logical_cpus']} logical CPUs; Python {m['python']}; commit {m['commit']}; "
        f"{m['date']}; load average {_load(r)} (other work shares the cores). Router + {len(speed['roles'])} "
        f"agents ({', '.join(speed['roles'])}) as processes on loopback; controller requested: "
        f"{r['controller']['requested']!r}; the one that acted is named in each row.",
        "",
        "| figure | measured | target |",
        "|---|---|---|",
    ]  # fmt: skip
    for name, v in lat.items():
        lines.append(
            f"| {name}, {'/'.join(v['controllers_used'])}: plant-state publish to applied action, p50 / p99 / max ms "
            f"({v['steps']} steps at {v['speed_factor']:g}x, {v['fallback_steps']} fallback) | {v['p50_ms']:.2f} / "
            f"{v['p99_ms']:.2f} / {v['max_ms']:.2f} | p99 <= {v['target_p99_ms']:g} ms |"
        )
    best = speed["max_sustained_speed_factor"]
    lines.append(f"| highest speed factor with no missed control period (lcopt-5) | "
                 f"{best if best is not None else 'none'}x | |")  # fmt: skip
    for e in r["encoding"]:
        lines.append(f"| {e['system']} plant state on the wire: bytes, encode / decode ms | {e['state_bytes']:,} B, "
                     f"{e['encode_ms']:.2f} / {e['decode_ms']:.2f} | |")  # fmt: skip
    lines += ["", *(f"Note ({k}): {v}" for k, v in notes.items() if v)]
    lines += ["", "Speed levels (lcopt-5, controller as above): " + "; ".join(
        f"{lv['speed_factor']}x ({lv.get('period_ms', 0):.1f} ms): {lv['missed']} missed of {lv['steps']}"
        for lv in speed["levels"])]  # fmt: skip
    return "\n".join(lines)


def _load(r: dict) -> str:
    load = r.get("load_average")
    return f"{load['before']:.1f} before, {load['after']:.1f} after" if load else "not recorded"

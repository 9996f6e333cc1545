"""Independent benchmark units run on Ray (a local instance by default), cached by content, resumable (issue 36).

A benchmark names its independent units (a controller on a day, a PPO seed on a day, an LLM day) as
:class:`Unit`: a module-level function, its JSON arguments, the CPUs it needs and a content key. The
engine runs the units that the cache does not hold, as Ray tasks, and gives their results back in the
units' order, so a table merges in code, exactly as the serial run would (``engine="serial"`` runs them
here, one after another, through the same path).

- **Ray, local by default.** ``ray.init()`` starts a local instance sized to this machine's CPUs, and every
  task declares its CPUs (one for a twin day, the LLM's threads for an LLM day), so a 2-core laptop runs
  two twin days at once and is never oversubscribed. ``--address`` (or ``RAY_ADDRESS``) sends the same
  tasks to a cluster; its nodes must have this package installed at the same code version, which the
  keys check. A Ray instance the engine started, it stops: no process is left behind.
- ``LCMESH_BENCH_ENGINE=serial`` makes the serial engine the default (the test tier sets it; the engine's own
  tests start Ray).
- **The cache** is one SQLite file (``runs/cache/units.sqlite``; ``LCMESH_BENCH_CACHE`` or ``--cache``):
  a unit's result is written the moment it arrives, so a stopped run loses only the units in flight and a
  re-run computes only what is missing or changed. A key hashes everything the result depends on: the
  function and its arguments, the twin's code and data (``lcmesh/twin`` and the guardrails), the
  controller's package code and artifact files. Failed units are never cached. ``fresh=True``
  (``--fresh``) recomputes every unit and overwrites what the cache held.
- **Who computed what.** Every outcome says whether it came from the cache and at which commit it was
  computed; the benches put that into their tables.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import inspect
import json
import os
import sqlite3
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from functools import lru_cache
from pathlib import Path
from typing import Any

PACKAGE_ROOT = Path(__file__).resolve().parent.parent  # lcmesh/
DEFAULT_CACHE = Path("runs/cache/units.sqlite")
ENGINES = ("ray", "serial")
_HASHED_SUFFIXES = frozenset({".py", ".c", ".h", ".json", ".csv", ".txt", ".safetensors", ".gguf", ".npz", ".gz"})
Progress = Callable[[str, int, int], None]


@dataclass(frozen=True)
class Unit:
    """One independent piece of a benchmark: ``fn`` ("module:function") called with ``kwargs`` (JSON-able)."""

    fn: str
    kwargs: dict
    label: str
    num_cpus: float = 1.0
    versions: tuple[str, ...] = ()  # digests of what the result depends on beyond fn and kwargs (code, artifacts)
    cost: float = 1.0  # a guess of its run time relative to its siblings', for the order (not part of the key)

    @property
    def key(self) -> str:
        """The content address: the function's source, its arguments and the versions it was given."""
        blob = json.dumps({"fn": self.fn, "source": _function_digest(self.fn), "kwargs": self.kwargs,
                           "versions": sorted(self.versions)}, sort_keys=True, default=str)  # fmt: skip
        return hashlib.sha256(blob.encode()).hexdigest()


@dataclass
class Outcome:
    """A unit's result (None when it failed), whether the cache gave it and the commit it was computed at."""

    unit: Unit
    result: Any = None
    error: str | None = None
    cached: bool = False
    commit: str | None = None
    seconds: float = 0.0


@dataclass
class EngineSettings:
    """How units run: on Ray (``address`` None: a local instance) or serially here; where the cache lives."""

    engine: str = field(default_factory=lambda: os.environ.get("LCMESH_BENCH_ENGINE", "ray"))
    address: str | None = None
    cache: Path | None = field(default_factory=lambda: Path(os.environ.get("LCMESH_BENCH_CACHE", DEFAULT_CACHE)))
    fresh: bool = False
    num_cpus: int | None = None  # a local Ray instance's CPUs (default: this machine's)

    def __post_init__(self) -> None:
        if self.engine not in ENGINES:
            raise ValueError(f"`engine` must be one of {', '.join(ENGINES)}, got {self.engine!r}")
        if self.num_cpus is not None and self.num_cpus < 1:
            raise ValueError(f"`num_cpus` must be >= 1, got {self.num_cpus}")


# --- versions: what a result depends on -------------------------------------------------------------------------
def tree_digest(*paths: str | Path) -> str:
    """sha256 over the files under ``paths`` (package-relative or absolute; a file or a folder): names and bytes."""
    h = hashlib.sha256()
    for p in paths:
        root = Path(p) if Path(p).is_absolute() else PACKAGE_ROOT / p
        if not root.exists():
            raise FileNotFoundError(f"cannot hash {root}: no such file or folder")
        files = [root] if root.is_file() else sorted(
            f for f in root.rglob("*") if f.is_file() and f.suffix in _HASHED_SUFFIXES and "__pycache__" not in f.parts
        )
        for f in files:
            h.update(str(f.relative_to(root.parent)).encode())
            stat = f.stat()
            h.update(_file_digest(str(f), stat.st_mtime_ns, stat.st_size).encode())
    return h.hexdigest()


@lru_cache(maxsize=4096)
def _file_digest(path: str, mtime_ns: int, size: int) -> str:  # mtime and size in the key: an edit is seen
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def twin_version() -> str:
    """The twin's code, C templates, systems and traces, and the guardrails every benchmark applies."""
    return "twin:" + tree_digest("twin", "mesh/tools/guardrails.py")


def controller_version(controller: Any) -> str:
    """A built controller's code (the package its class lives in) and the artifact files it read."""
    module = type(controller).__module__
    spec = importlib.util.find_spec(module)
    origin = Path(spec.origin) if spec is not None and spec.origin else None
    if origin is not None and origin.is_relative_to(PACKAGE_ROOT):
        code = tree_digest(origin.parent)  # lcmesh/distill, lcmesh/llm, lcmesh/twin/controllers
    else:  # a third-party controller: its module file (an installed package's version may be all there is)
        code = tree_digest(origin) if origin is not None else module
    files = [Path(p).resolve() for p in getattr(controller, "artifact_files", ())]
    artifacts = tree_digest(*files) if files else "none"
    return f"controller:{getattr(controller, 'name', module)}:{getattr(controller, 'version', '')}:{code}:{artifacts}"


@lru_cache(maxsize=256)
def _function_digest(spec: str) -> str:
    try:
        return hashlib.sha256(inspect.getsource(resolve(spec)).encode()).hexdigest()
    except (OSError, TypeError):
        return "unknown"


def resolve(spec: str) -> Callable:
    module, _, name = spec.partition(":")
    return getattr(importlib.import_module(module), name)


def call(spec: str, kwargs: dict, threads: int = 1) -> Any:
    """Run one unit (on a Ray worker or here) with ``threads`` math threads (torch's, OpenMP's): the unit's CPUs.

    Serially as on Ray, so the floats match: a PPO day run with torch's default of one thread per core sums its
    matmuls in another order than with one, and its figures moved in the ninth digit between the two engines."""
    previous = os.environ.get("OMP_NUM_THREADS")
    os.environ["OMP_NUM_THREADS"] = str(threads)  # a torch imported by the unit reads it
    torch = sys.modules.get("torch")
    before = torch.get_num_threads() if torch is not None else None
    if torch is not None:
        torch.set_num_threads(threads)
    try:
        return resolve(spec)(**kwargs)
    finally:
        if previous is None:
            os.environ.pop("OMP_NUM_THREADS", None)
        else:
            os.environ["OMP_NUM_THREADS"] = previous
        if before is not None:
            torch.set_num_threads(before)


# --- the cache ----------------------------------------------------------------------------------------------------
class ResultCache:
    """Units' results in one SQLite file, keyed by content; written as each unit ends."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._db = sqlite3.connect(self.path, timeout=30.0)
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute("CREATE TABLE IF NOT EXISTS units (key TEXT PRIMARY KEY, label TEXT NOT NULL, "
                         "fn TEXT NOT NULL, result TEXT NOT NULL, commit_id TEXT, computed_at TEXT NOT NULL, "
                         "seconds REAL NOT NULL)")  # fmt: skip
        self._db.commit()

    def get(self, key: str) -> tuple[Any, str | None, float] | None:
        row = self._db.execute("SELECT result, commit_id, seconds FROM units WHERE key = ?", (key,)).fetchone()
        if row is None:
            return None
        try:
            return json.loads(row[0]), row[1], float(row[2])
        except json.JSONDecodeError:  # a damaged row is recomputed, never trusted
            return None

    def put(self, unit: Unit, result: Any, commit: str | None, seconds: float) -> None:
        text = json.dumps(result, default=_json_default)
        self._db.execute("INSERT OR REPLACE INTO units VALUES (?, ?, ?, ?, ?, ?, ?)",
                         (unit.key, unit.label, unit.fn, text, commit,
                          datetime.now(timezone.utc).isoformat(timespec="seconds"), seconds))  # fmt: skip
        self._db.commit()

    def last_seconds(self, labels: Iterable[str]) -> dict[str, float]:
        """The seconds the latest computed unit of each label took (another key: an older code or artifact)."""
        rows = self._db.execute("SELECT label, seconds FROM units ORDER BY computed_at").fetchall()
        wanted = set(labels)
        return {label: float(seconds) for label, seconds in rows if label in wanted}

    def __len__(self) -> int:
        return int(self._db.execute("SELECT COUNT(*) FROM units").fetchone()[0])

    def close(self) -> None:
        self._db.close()


def _json_default(value: Any) -> Any:
    import numpy as np

    if isinstance(value, (np.floating, np.integer, np.bool_)):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (set, frozenset, tuple)):
        return list(value)
    raise TypeError(f"not JSON serializable: {type(value).__name__}")


@lru_cache(maxsize=1)
def code_commit() -> str | None:
    """The commit this code is at (``+dirty`` when the package has uncommitted changes)."""
    def git(*args: str) -> str:
        done = subprocess.run(["git", *args], capture_output=True, text=True, timeout=10, cwd=PACKAGE_ROOT)
        return done.stdout.strip()

    try:
        commit = git("rev-parse", "--short", "HEAD")
        dirty = git("status", "--porcelain", "--untracked-files=no", "--", str(PACKAGE_ROOT))
    except (OSError, subprocess.SubprocessError):
        return None
    return (commit + ("+dirty" if dirty else "")) if commit else None


# --- running ------------------------------------------------------------------------------------------------------
def run_units(units: Sequence[Unit], settings: EngineSettings | None = None,
              progress: Progress | None = None) -> list[Outcome]:  # fmt: skip
    """Every unit's outcome, in the units' order: from the cache, else computed (on Ray or serially) and cached.

    A unit that raises is an outcome with its error (not cached); the others still run. Interrupted, the
    units already finished stay in the cache, and the next run starts from them.
    """
    settings = settings or EngineSettings()
    cache = ResultCache(settings.cache) if settings.cache is not None else None
    outcomes: list[Outcome | None] = [None] * len(units)
    done, total = 0, len(units)
    try:
        todo = []
        for i, unit in enumerate(units):
            hit = cache.get(unit.key) if cache is not None and not settings.fresh else None
            if hit is None:
                todo.append(i)
                continue
            outcomes[i] = Outcome(unit, hit[0], cached=True, commit=hit[1], seconds=hit[2])
            done += 1
            if progress is not None:
                progress(f"{unit.label} (cached)", done, total)
        commit = code_commit()

        def finish(i: int, result: Any, error: str | None, seconds: float) -> None:
            nonlocal done
            outcomes[i] = Outcome(units[i], result, error, cached=False, commit=commit, seconds=seconds)
            if error is None and cache is not None:
                cache.put(units[i], result, commit, seconds)
            done += 1
            if progress is not None:
                progress(units[i].label if error is None else f"{units[i].label} failed", done, total)

        if todo:
            if settings.engine != "serial":
                history = cache.last_seconds(units[i].label for i in todo) if cache is not None else {}
                todo = longest_first(todo, units, history)
            runner = _run_serial if settings.engine == "serial" else _run_ray
            runner([units[i] for i in todo], settings, lambda k, *rest: finish(todo[k], *rest))
    finally:
        if cache is not None:
            cache.close()
    return [o for o in outcomes if o is not None]


def longest_first(todo: list[int], units: Sequence[Unit], seconds: dict[str, float]) -> list[int]:
    """The units to run, those expected to take longest first, so that no long unit starts last and leaves the other
    CPUs idle at the end: by their labels' last times in the cache when it knows them all, else by their cost guess."""
    if all(units[i].label in seconds for i in todo):
        return sorted(todo, key=lambda i: -seconds[units[i].label])  # stable: ties keep their order
    return sorted(todo, key=lambda i: -units[i].cost)


def _run_serial(units: Sequence[Unit], settings: EngineSettings, finish: Callable) -> None:
    for k, unit in enumerate(units):
        t0 = time.perf_counter()
        try:
            result, error = call(unit.fn, unit.kwargs, _threads(unit)), None
        except Exception as exc:  # noqa: BLE001 - a failed unit is a result of the benchmark
            result, error = None, f"{type(exc).__name__}: {exc}"
        finish(k, result, error, time.perf_counter() - t0)


def _threads(unit: Unit) -> int:
    return max(1, int(unit.num_cpus))


def _timed_call(spec: str, kwargs: dict, threads: int) -> tuple[Any, float]:
    t0 = time.perf_counter()
    result = call(spec, kwargs, threads)
    return json.loads(json.dumps(result, default=_json_default)), time.perf_counter() - t0


def _run_ray(units: Sequence[Unit], settings: EngineSettings, finish: Callable) -> None:
    import ray

    started = _ray_start(settings)
    try:
        remote = ray.remote(_timed_call)
        pending = {remote.options(num_cpus=u.num_cpus, max_retries=0).remote(u.fn, u.kwargs, _threads(u)): k
                   for k, u in enumerate(units)}  # fmt: skip
        try:
            while pending:
                ready, _ = ray.wait(list(pending), num_returns=1)
                for ref in ready:
                    k = pending.pop(ref)
                    try:
                        result, seconds = ray.get(ref)
                        finish(k, result, None, seconds)
                    except Exception as exc:  # noqa: BLE001 - the task's error, said with the unit
                        cause = getattr(exc, "cause", None) or exc
                        finish(k, None, f"{type(cause).__name__}: {cause}", 0.0)
        finally:
            for ref in pending:  # interrupted: what is still running stops; what finished is cached
                ray.cancel(ref, force=True)
    finally:
        if started:
            ray.shutdown()


def _ray_start(settings: EngineSettings) -> bool:
    """Connect to ``settings.address`` (or ``RAY_ADDRESS``), else start a local instance; True if we started one."""
    import ray

    if ray.is_initialized():
        return False
    env = {k: v for k, v in os.environ.items() if k.startswith("LCMESH_")}
    address = settings.address or os.environ.get("RAY_ADDRESS") or None
    kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False, "configure_logging": False,
                              "runtime_env": {"env_vars": env} if env else None}  # fmt: skip
    if address is None:
        kwargs["num_cpus"] = settings.num_cpus or os.cpu_count() or 1
    ray.init(address=address, **kwargs)
    return True


def cache_summary(outcomes: Iterable[Outcome]) -> dict:
    """How many units the cache gave and at which commits; what ran here and at which commit."""
    outcomes = list(outcomes)
    cached = [o for o in outcomes if o.cached]
    commits: dict[str, int] = {}
    for o in cached:
        commits[o.commit or "unknown"] = commits.get(o.commit or "unknown", 0) + 1
    return {"units": len(outcomes), "cached": len(cached), "cached_commits": commits,
            "computed": len(outcomes) - len(cached), "failed": sum(o.error is not None for o in outcomes),
            "computed_commit": code_commit(),
            "unit_seconds": sum(o.seconds for o in outcomes if not o.cached)}  # fmt: skip


def cache_lines(summary: dict) -> list[str]:
    """The lines a benchmark's table ends with: which units came from the cache (none without a summary)."""
    line = cache_line(summary)
    return ["", f"Units (lcmesh/bench/engine.py): {line}"] if line else []


def cache_line(summary: dict) -> str:
    """One sentence for a table: which rows came from the cache and from which commit."""
    if not summary or not summary.get("units"):
        return ""
    if not summary["cached"]:
        n, commit = summary["units"], summary["computed_commit"] or "unknown"
        return f"{'All ' if n > 1 else ''}{n} unit{'s' if n > 1 else ''} computed at commit {commit}."
    commits = ", ".join(f"{c} ({n})" for c, n in sorted(summary["cached_commits"].items()))
    return (f"{summary['cached']} of {summary['units']} units from the result cache (computed at commit {commits}); "
            f"{summary['computed']} computed at commit {summary['computed_commit'] or 'unknown'}.")

"""``lcmesh train sweep``: PPO seeds and setting grids as units on the benchmark engine (issue 36).

Each (seed, grid point) is one ``train_ppo`` run in a folder of its own, submitted as a Ray task with the
run's torch threads as its CPUs (lcmesh/bench/engine.py). The engine's cache keys a run by its whole
configuration and the code of the trainer and the twin: a sweep re-run trains only the runs that are new,
changed or whose folder is gone; a stopped sweep resumes with the runs it had finished.
"""

from __future__ import annotations

import itertools
from dataclasses import asdict, replace
from pathlib import Path

from lcmesh.bench.engine import EngineSettings, Outcome, Progress, Unit, run_units, tree_digest, twin_version
from lcmesh.distill.ppo_config import PpoConfig


def parse_grid(items: list[str]) -> dict[str, list]:
    """``["reward=lcopt,energy", "ent_coef=0.01,0.02"]`` -> values per PpoConfig field, typed as the field is."""
    defaults = asdict(PpoConfig())
    grid: dict[str, list] = {}
    for item in items:
        name, sep, values = item.partition("=")
        name = name.strip().replace("-", "_")
        if not sep or not values.strip():
            raise ValueError(f"`--grid` items are name=v1,v2,...; got {item!r}")
        if name not in defaults or name in ("seed", "out"):
            known = ", ".join(sorted(set(defaults) - {"seed", "out"}))
            raise ValueError(f"`--grid`: {name!r} is not a PPO setting one can sweep (known: {known})")
        kind = type(defaults[name]) if defaults[name] is not None else str
        grid[name] = [_typed(kind, v.strip(), name) for v in values.split(",") if v.strip()]
    return grid


def _typed(kind: type, text: str, name: str):
    if kind is bool:
        if text.lower() not in ("true", "false", "1", "0"):
            raise ValueError(f"`--grid {name}`: {text!r} is not true or false")
        return text.lower() in ("true", "1")
    try:
        return kind(text)
    except ValueError:
        raise ValueError(f"`--grid {name}`: {text!r} is not a {kind.__name__}") from None


def sweep_configs(base: PpoConfig, seeds: list[int], grid: dict[str, list]) -> list[PpoConfig]:
    """One config per (grid point, seed), each with its own run folder under ``base.out``; each must validate."""
    if not seeds:
        raise ValueError("`seeds` must name at least one seed")
    names = list(grid)
    varied = {n for n in names if len(set(grid[n])) > 1}  # a setting with one value names no folder
    configs = []
    for point in itertools.product(*(grid[n] for n in names)):
        tag = "-".join(f"{n}={v}" for n, v in zip(names, point) if n in varied)
        for seed in seeds:
            folder = Path(base.out) / (f"{tag}-seed{seed}" if tag else f"case{base.case}-seed{seed}")
            configs.append(replace(base, **dict(zip(names, point)), seed=seed, out=str(folder)))
    return configs


def train_unit(config: dict) -> dict:
    """One unit: ``train_ppo`` on ``config`` (a PpoConfig as a dict); its summary."""
    from lcmesh.distill.ppo import train_ppo

    return train_ppo(PpoConfig(**config))


def run_sweep(configs: list[PpoConfig], engine: EngineSettings | None = None,
              progress: Progress | None = None) -> list[Outcome]:  # fmt: skip
    """Every config trained as a unit; a cached run whose policy files are gone is trained again."""
    code = ("trainer:" + tree_digest("distill"), twin_version())
    units = [Unit("lcmesh.distill.sweep:train_unit", {"config": {**asdict(c), "out": str(Path(c.out).resolve())}},
                  label=f"{Path(c.out).name}", num_cpus=max(1, c.threads), versions=code) for c in configs]  # fmt: skip
    outcomes = run_units(units, engine, progress)
    gone = [i for i, o in enumerate(outcomes) if o.cached and not Path(o.result["policy"]).with_suffix(".json").exists()]
    if gone:
        again = run_units([units[i] for i in gone], replace(engine or EngineSettings(), fresh=True), progress)
        for i, o in zip(gone, again):
            outcomes[i] = o
    return outcomes

"""Env throughput: steps per second of a random-action loop on one core.

``python -m lcmesh.twin.envs.bench [system] [n_steps]`` prints one JSON line per env kind.
The project target is >= 5,000 steps/s for the cabinet env on lcopt-5. Resets (with their
warm-up steps) happen inside the timed loop, as in training.
"""

from __future__ import annotations

import json
import statistics
import sys
import time
from collections.abc import Callable

ENV_KINDS = ("cabinet", "tower", "parallel", "cabinet-normalized")


def env_steps_per_second(
    system: str = "lcopt-5", n_steps: int = 20_000, env: str = "cabinet", repeats: int = 3
) -> dict[str, object]:
    """Median steps/s over ``repeats`` runs of ``n_steps`` steps with one action sampled up front."""
    if env not in ENV_KINDS:
        raise ValueError(f"`env` must be one of {ENV_KINDS}, got {env!r}")
    if n_steps < 1 or repeats < 1:
        raise ValueError(f"`n_steps` and `repeats` must be >= 1, got {n_steps} and {repeats}")
    run = _parallel_loop(system) if env == "parallel" else _gym_loop(system, env)
    run(min(n_steps, 200))  # warm caches and lazy imports outside the timed runs
    rates, episodes = [], []
    for _ in range(repeats):
        start = time.perf_counter()
        episodes.append(run(n_steps))
        rates.append(n_steps / (time.perf_counter() - start))
    median = statistics.median(rates)
    return {
        "env": env,
        "system": system,
        "n_steps": n_steps,
        "steps_per_s": median,
        "us_per_step": 1e6 / median,
        "repeats_steps_per_s": rates,
        "episodes_per_repeat": episodes,  # each reset includes the warm-up steps
    }


def _gym_loop(system: str, kind: str) -> Callable[[int], int]:
    from lcmesh.twin.envs import CabinetEnv, TowerEnv, make_normalized

    env = (TowerEnv if kind == "tower" else CabinetEnv)(system=system)
    if kind == "cabinet-normalized":
        env = make_normalized(env)
    env.action_space.seed(0)
    action = env.action_space.sample()
    env.reset(seed=0)

    def run(n_steps: int) -> int:
        step, reset, resets = env.step, env.reset, 0
        for _ in range(n_steps):
            _, _, terminated, truncated, _ = step(action)
            if terminated or truncated:
                reset()
                resets += 1
        return resets

    return run


def _parallel_loop(system: str) -> Callable[[int], int]:
    from lcmesh.twin.envs import CoolingParallelEnv

    env = CoolingParallelEnv(system=system)
    env.reset(seed=0)
    actions = {}
    for agent in env.possible_agents:
        env.action_space(agent).seed(0)
        actions[agent] = env.action_space(agent).sample()

    def run(n_steps: int) -> int:
        resets = 0
        for _ in range(n_steps):
            env.step(actions)
            if not env.agents:
                env.reset()
                resets += 1
        return resets

    return run


def main(argv: list[str] | None = None) -> None:
    args = sys.argv[1:] if argv is None else argv
    system = args[0] if args else "lcopt-5"
    n_steps = int(args[1]) if len(args) > 1 else 20_000
    for kind in ENV_KINDS:
        print(json.dumps(env_steps_per_second(system, n_steps, kind)))


if __name__ == "__main__":
    main()

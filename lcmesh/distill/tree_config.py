"""``lcmesh distill tree`` settings (no heavy imports, so the CLI stays fast)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class TreeDistillConfig:
    """``lcmesh distill tree`` settings."""

    policy: str = ""
    """Teacher policy (path without suffix: NAME.json + NAME.safetensors); empty: the shipped real-load case-7
    policy (the paper trees came from lcmesh/artifacts/ppo/case7 on lcopt-5-paper under the lcopt scenario)."""
    system: str = "lcopt-5"
    train_seeds: str = "0-7"
    """Synthetic training traces the teacher is rolled over (a range 'A-B' or a comma list)."""
    heldout_seed: int = 1110
    """Synthetic evaluation seed for R^2 / MAE against the teacher (never a training seed, nor a day of the bench
    suite: lcmesh/bench/suite.py)."""
    reward_seeds: str = "1100-1109"
    """Evaluation episodes for the average reward (Tables 12 and 14: 10 episodes); never a test or validation day
    of the bench suite (the shipped trees were distilled with 1010-1019 and 1003: docs/controllers.md)."""
    samples: int = 60000
    """Rows drawn from the experience per tree (VIPER resampling, with replacement)."""
    max_depth_cdu: int = 14
    max_depth_valves: int = 14
    max_depth_tower: int = 12
    max_leaves: int = 0
    """At most this many leaves per tree (0: no limit); with depth <= 8 it makes a tree whose rules fit a page."""
    min_samples_leaf: int = 4
    scenarios: str = "frontier,design-day"
    """Scenarios of the training, held-out and reward traces (comma list; seed s runs under scenario s mod their
    count); ``frontier,design-day`` for a teacher trained on the real-load plant."""
    reward: str = "deploy"
    """The reward the episode rewards and the gap are measured in (the teacher's training reward: the shipped
    policy's is ``deploy``, lcmesh/distill/ppo_env.py)."""
    rules_depth: int = 5
    """Levels of each tree written to the rules file (a readable tree: all of them)."""
    seed: int = 0
    out: str = ""
    """Where the VIPER trees go (JSON; empty: the shipped lcmesh/artifacts/trees/frontier-case7.json); the naive
    (uniform) trees go beside it with a -naive suffix, the rules and the report too."""

    def scenario_list(self) -> tuple[str, ...]:
        return tuple(s.strip() for s in self.scenarios.split(",") if s.strip())

    def trace_seeds(self) -> dict[str, list[int]]:
        """The synthetic seeds each field runs the teacher or the trees on."""
        return {"train_seeds": parse_seeds(self.train_seeds, "train_seeds"), "heldout_seed": [self.heldout_seed],
                "reward_seeds": parse_seeds(self.reward_seeds, "reward_seeds")}  # fmt: skip

    def __post_init__(self) -> None:
        from lcmesh.bench.suite import held_out_days_in, held_out_seeds  # here: the CLI's `--help` stays fast

        for name, seeds in self.trace_seeds().items():
            if days := held_out_days_in(f"synthetic:{seed}" for seed in seeds):
                raise ValueError(f"`{name}` must not run on the bench suite's test or validation days, got "
                                 f"{', '.join(f'{d.label} ({d.trace})' for d in days)}; pick seeds outside "
                                 f"{', '.join(map(str, held_out_seeds()))} (the defaults use 1100-1110)")  # fmt: skip
        if self.max_leaves < 0 or self.max_leaves == 1:
            raise ValueError(f"`max_leaves` must be 0 (no limit) or >= 2, got {self.max_leaves}")
        if self.reward not in ("lcopt", "energy", "energy_smooth", "deploy"):
            raise ValueError(f"`reward` must be 'lcopt', 'energy', 'energy_smooth' or 'deploy', got {self.reward!r}")
        if not self.scenario_list():
            raise ValueError("`scenarios` must name at least one scenario")
        for name in ("samples", "max_depth_cdu", "max_depth_valves", "max_depth_tower", "min_samples_leaf", "rules_depth"):
            if getattr(self, name) < 1:
                raise ValueError(f"`{name}` must be >= 1, got {getattr(self, name)}")


def parse_seeds(text: str, field: str = "seeds") -> list[int]:
    """'0-7' -> [0..7]; '1,5,9' -> [1, 5, 9]."""
    text = text.strip()
    try:
        if "-" in text and "," not in text:
            a, b = (int(v) for v in text.split("-"))
            seeds = list(range(a, b + 1))
        else:
            seeds = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        seeds = []
    if not seeds:
        raise ValueError(f"`{field}` must look like '0-7' or '1,5,9', got {text!r}")
    return seeds



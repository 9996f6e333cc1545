"""``lcmesh distill tree`` settings (no heavy imports, so the CLI stays fast)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class TreeDistillConfig:
    """``lcmesh distill tree`` settings."""

    policy: str = ""
    """Teacher policy (path without suffix: NAME.json + NAME.safetensors); empty: the shipped case-7 policy."""
    system: str = "lcopt-5-paper"
    train_seeds: str = "0-7"
    """Synthetic training traces the teacher is rolled over (a range 'A-B' or a comma list)."""
    heldout_seed: int = 1003
    """Synthetic evaluation seed for R^2 / MAE against the teacher (never a training seed)."""
    reward_seeds: str = "1010-1019"
    """Evaluation episodes for the average reward (Tables 12 and 14: 10 episodes)."""
    samples: int = 60000
    """Rows drawn from the experience per tree (VIPER resampling, with replacement)."""
    max_depth_cdu: int = 14
    max_depth_valves: int = 14
    max_depth_tower: int = 12
    min_samples_leaf: int = 4
    seed: int = 0
    out: str = ""
    """Where the VIPER trees go (JSON; empty: the shipped lcmesh/artifacts/trees/case7.json); the naive
    (uniform) trees go beside it with a -naive suffix, the rules and the report too."""

    def __post_init__(self) -> None:
        for name in ("train_seeds", "reward_seeds"):
            parse_seeds(getattr(self, name), name)
        for name in ("samples", "max_depth_cdu", "max_depth_valves", "max_depth_tower", "min_samples_leaf"):
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


"""``lcmesh distill llm`` settings (no heavy imports, so the CLI starts fast)."""

from __future__ import annotations

from dataclasses import dataclass

TEACHERS = ("ppo", "g36", "tree")


@dataclass
class LlmDistillConfig:
    """What to distill into SmolLM2-135M-Instruct, from which teacher, and how to fine-tune."""

    teacher: str = "ppo"
    """Teacher controller: ppo (the shipped frontier-case7 policy or --policy), g36, or tree."""
    policy: str = ""
    """Teacher policy file for ppo / tree (empty: the shipped one)."""
    system: str = "lcopt-5"
    train_seeds: str = "0-3"
    """Synthetic training traces the teacher is rolled over ('A-B' or a comma list)."""
    scenarios: str = "frontier,design-day"
    """Scenarios cycled over the training traces (e.g. 'frontier,design-day'; the held-out trace runs under the
    first); empty: the lcopt scenario with ``wet_bulb_offset_k``."""
    steps_per_trace: int = 960
    """Teacher steps recorded per training trace (960 = 4 h of 15 s steps)."""
    heldout_seed: int = 1003
    """Synthetic evaluation seed for action R^2 / MAE (never a training seed)."""
    heldout_samples: int = 150
    """Held-out cabinet decisions the adapter is scored on after training."""
    samples: int = 1500
    """Action samples drawn from the experience by VIPER weight (with replacement)."""
    tower_samples: int = 150
    """Tower decisions (approach over the wet bulb) drawn from the experience by VIPER weight; 0: the LLM decides
    no towers."""
    whatif: bool = True
    """Explanation targets add a WHAT IF section citing the toolbox's what-if facts (the rendering does not)."""
    uniform: bool = False
    """Draw action samples uniformly instead of by VIPER weight (the naive ablation)."""
    explain_samples: str = "short:20,detailed:6"
    """Explanation samples per level (the renderer's text for the teacher's action is the target;
    about 1,300-1,800 tokens each)."""
    explain_steps: int = 480
    """Steps of the explanation rollout (one training trace) the explanation samples are drawn from."""
    quant: str = "nf4"
    """nf4: QLoRA (4-bit base via bitsandbytes); none: plain LoRA (for comparison)."""
    compute_dtype: str = "auto"
    """Matmul dtype of the frozen base: auto (bfloat16 where the CPU has native bfloat16, else float32), bfloat16, float32."""
    epochs: float = 1.3
    lr: float = 2e-3
    r: int = 8
    alpha: int = 16
    batch_size: int = 8
    batch_tokens: int = 2048
    max_len: int = 3072
    """Longest sample (prompt + answer tokens) trained on; longer ones are dropped and counted
    (a very detailed explanation sample is about 2,500 tokens)."""
    seed: int = 0
    threads: int = 0
    """Torch threads (0: torch's default)."""
    wet_bulb_offset_k: float = 15.0
    """Wet-bulb offset of the traces, as in the paper's hot-weather setting and the benchmarks."""
    init_adapter: str = ""
    """Continue from this LoRA adapter ('default': the packaged one, or a folder) instead of fresh LoRA
    weights; its r / alpha win over the ones here, and its manifest is kept as the new one's parent."""
    out: str = ""
    """Output folder (adapter, manifest, metrics, loss plot); empty: lcmesh/artifacts/llm."""

    def __post_init__(self) -> None:
        if self.teacher not in TEACHERS:
            raise ValueError(f"`teacher` must be one of {', '.join(TEACHERS)}, got {self.teacher!r}")
        if self.tower_samples < 0:
            raise ValueError(f"`tower_samples` must be >= 0, got {self.tower_samples}")
        for name in ("steps_per_trace", "samples", "heldout_samples", "explain_steps", "max_len"):
            if getattr(self, name) < 1:
                raise ValueError(f"`{name}` must be >= 1, got {getattr(self, name)}")
        self.explain_counts()

    def trace_specs(self, seeds: list[int]) -> list[str]:
        """Training trace specs, each ``synthetic:SEED`` or ``synthetic:SEED@SCENARIO`` (scenarios cycled)."""
        names = [n.strip() for n in self.scenarios.split(",") if n.strip()]
        if not names:
            return [f"synthetic:{s}" for s in seeds]
        return [f"synthetic:{s}@{names[i % len(names)]}" for i, s in enumerate(seeds)]

    def heldout_spec(self) -> str:
        """The held-out trace spec (under the first scenario when scenarios are given)."""
        names = [n.strip() for n in self.scenarios.split(",") if n.strip()]
        return f"synthetic:{self.heldout_seed}" + (f"@{names[0]}" if names else "")

    def explain_counts(self) -> dict[str, int]:
        """``'short:24,detailed:8'`` -> {'short': 24, 'detailed': 8}; '' or 'none' -> {}."""
        if self.explain_samples.strip() in ("", "none", "0"):
            return {}
        counts = {}
        for part in self.explain_samples.split(","):
            level, _, n = part.strip().partition(":")
            if level not in ("short", "detailed", "very_detailed", "whatif") or not n.strip().isdigit():
                raise ValueError(
                    f"`explain_samples` must look like 'short:24,detailed:8' (levels short, detailed, "
                    f"very_detailed, or whatif: the short level's WHAT IF section alone), got {self.explain_samples!r}"
                )
            counts[level] = int(n)
        return counts

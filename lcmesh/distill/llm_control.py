"""``lcmesh distill llm-control``: the PPO policy the mesh deploys, distilled into SmolLM2-135M as a controller.

The student answers in the compact protocol of ``lcmesh.llm.control_format`` (a short prompt, 8 decided
digits per cabinet, 2 per tower). Samples are the teacher's own decisions over training days, rolled
behind the mesh's guardrails with its hold band (the states the deployed teacher visits); each target
is the teacher's raw target for that state (its policy output before the hold band), because the LLM
controller applies the same hold band to its own answers.

Training is affordable on two cores because only the top ``top_layers`` decoder layers learn (LoRA)
and the loss reads the decided digits only:

1. the frozen bottom layers run once over every sample; their output is cached;
2. each step runs the top layers on the cached activations and the head on the decided positions,
   scored over the digits the grammar allows there (the same choice the decoder makes);
3. the adapter is saved as peft (``lcmesh/artifacts/llm-control``) and converted for llama.cpp on
   first use (``lcmesh.llm.gguf_lora``).

Data splits: training traces are ``TRAIN_SEEDS`` days; the dev day (scores printed, used to choose
settings) is a validation day of the suite; the test days are never read.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from lcmesh.distill.experience import Experience

ARTIFACT_DIR = Path(__file__).resolve().parent.parent / "artifacts" / "llm-control"
Progress = Callable[[str, int, int], None]


@dataclass
class LlmControlDistillConfig:
    """What the controller student learns from, and how."""

    policy: str = ""
    """Teacher PPO policy file (empty: the shipped frontier-case7, the policy the mesh deploys)."""
    system: str = "lcopt-5"
    train_seeds: str = "0-5"
    """Training traces (synthetic seeds; every one must be a training seed, never a suite day)."""
    scenarios: str = "frontier,design-day"
    steps_per_trace: int = 5760
    """Teacher steps recorded per training trace (5760 = the whole day of 15 s steps)."""
    dev_day: str = "synthetic:1992@design-day"
    """The dev day (a suite validation day): the student's dev scores; never a test day."""
    dev_steps: int = 5760
    samples: int = 3000
    tower_samples: int = 600
    dev_samples: int = 200
    top_layers: int = 3
    r: int = 16
    alpha: int = 32
    epochs: float = 5.0
    lr: float = 1e-3
    batch_size: int = 32
    tower_viper: bool = False
    """Draw tower samples by VIPER weight (the teacher's confident choices: its hot-weather minimum approach)
    instead of uniformly."""
    init_adapter: str = ""
    """Continue training this adapter folder (its LoRA layers and rank win) instead of fresh LoRA weights."""
    dagger_seeds: str = ""
    """DAgger: training seeds the *student* (``init_adapter``, else the packaged adapter) controls over their busiest
    ``dagger_hours``; the states it visits are labelled by the teacher and added (empty: none)."""
    dagger_scenario: str = "design-day"
    dagger_hours: float = 2.0
    dagger_period: int = 8
    """The student decides every N steps in its DAgger rollouts (the closed-loop benchmark's period)."""
    dagger_samples: int = 1200
    dagger_tower_samples: int = 600
    dagger_cache: str = ""
    """Keep the student's rollouts in this .npz (reused when it holds the same seeds, hours, period and student)."""
    seed: int = 0
    threads: int = 0
    out: str = ""

    def __post_init__(self) -> None:
        for name in ("steps_per_trace", "samples", "dev_samples", "top_layers", "r", "batch_size"):
            if getattr(self, name) < 1:
                raise ValueError(f"`{name}` must be >= 1, got {getattr(self, name)}")
        for name in ("tower_samples", "dagger_samples", "dagger_tower_samples"):
            if getattr(self, name) < 0:
                raise ValueError(f"`{name}` must be >= 0, got {getattr(self, name)}")
        if self.dagger_hours <= 0 or self.dagger_period < 1:
            raise ValueError(f"`dagger_hours` must be > 0 and `dagger_period` >= 1, got {self.dagger_hours}, "
                             f"{self.dagger_period}")


def _trace_specs(cfg: LlmControlDistillConfig, seeds: str | None = None, scenarios: str | None = None,
                 what: str = "train_seeds") -> list[str]:  # fmt: skip
    from lcmesh.bench.suite import held_out_seeds
    from lcmesh.distill.tree_distill import parse_seeds
    from lcmesh.twin.traces import TRAIN_SEEDS

    seeds = parse_seeds(cfg.train_seeds if seeds is None else seeds)
    bad = sorted(set(seeds) - set(TRAIN_SEEDS)) + sorted(set(seeds) & set(held_out_seeds()))
    if bad:
        raise ValueError(f"`{what}` must be training seeds ({min(TRAIN_SEEDS)}-{max(TRAIN_SEEDS)}), got {bad}")
    names = [n.strip() for n in (cfg.scenarios if scenarios is None else scenarios).split(",") if n.strip()]
    names = names or ["frontier"]
    return [f"synthetic:{s}@{names[i % len(names)]}" for i, s in enumerate(seeds)]


def student_rollouts(cfg: LlmControlDistillConfig, system, say: Progress) -> Experience | None:
    """DAgger's data: the student LLM controller (no deadline, every ``dagger_period`` steps, behind the mesh's
    guardrails) over the busiest hours of the DAgger seeds; cached in ``dagger_cache``."""
    from lcmesh.distill.experience import Experience, collect_experience
    from lcmesh.llm.controller import LlmController, make_control_backend

    if not cfg.dagger_seeds:
        return None
    specs = _trace_specs(cfg, cfg.dagger_seeds, cfg.dagger_scenario, "dagger_seeds")
    cache = Path(cfg.dagger_cache) if cfg.dagger_cache else None
    backend = make_control_backend(cfg.init_adapter or "default", threads=cfg.threads or 2)
    if cache is not None and cache.is_file():
        exp = Experience.load(cache)
        same = (exp.traces, exp.meta.get("hours"), exp.meta.get("period"), exp.meta.get("student"))
        if same == (specs, cfg.dagger_hours, cfg.dagger_period, backend.model_id):
            say(f"student rollouts from {cache}", 1, 1)
            return exp
    student = LlmController(system, backend=backend, period_steps=cfg.dagger_period)
    total = len(specs) * (round(cfg.dagger_hours * 240) + 120)
    exp = collect_experience(student, system, specs, window_hours=cfg.dagger_hours,
                             on_step=lambda k: say("student rollouts (DAgger, training days)", k, total))  # fmt: skip
    exp.meta.update(hours=cfg.dagger_hours, period=cfg.dagger_period, student=backend.model_id,
                    decided_by=student.stats_snapshot())  # fmt: skip
    if cache is not None:
        exp.save(cache)
    return exp


def _check_dev(spec: str) -> None:
    from lcmesh.bench.suite import TEST_DAYS

    if spec.partition("@")[0] in {d.trace for d in TEST_DAYS}:
        raise ValueError(f"`dev_day` {spec!r} is a test day; use a validation day")


def raw_targets(teacher, exp) -> tuple[np.ndarray, np.ndarray]:
    """The teacher's policy outputs (before its hold band) on recorded rows: cabinet (T, C, 2+B) setpoints
    (K, Pa, fractions) and tower approaches (T, N) in K."""
    import torch

    from lcmesh.distill.features import APPROACH_LEVELS_K, DP_RANGE_PA, SUPPLY_RANGE_K, normalize_split
    from lcmesh.distill.policy import policy_mode

    T, C, _ = exp.cabinet_rows.shape
    with torch.no_grad():
        u = policy_mode(teacher.nets["cabinet"], exp.cabinet_rows.reshape(T * C, -1), teacher.meta.std)
    lo, hi = SUPPLY_RANGE_K
    supply = lo + (np.clip(u[:, 0], -1, 1) + 1.0) * 0.5 * (hi - lo)
    lo, hi = DP_RANGE_PA
    dp = lo + (np.clip(u[:, 1], -1, 1) + 1.0) * 0.5 * (hi - lo)
    multihead = teacher.nets["cabinet"].spec.kind == "multihead"
    valves = u[:, 2:] if multihead else normalize_split((np.clip(u[:, 2:], -1, 1) + 1.0) * 0.5)
    cab = np.column_stack([supply, dp, valves]).reshape(T, C, -1)
    N = exp.tower_rows.shape[1]
    with torch.no_grad():
        choice = policy_mode(teacher.nets["tower"], exp.tower_rows.reshape(T * N, -1), teacher.meta.std)
    approach = np.asarray(APPROACH_LEVELS_K)[np.clip(choice, 0, len(APPROACH_LEVELS_K) - 1)].reshape(T, N)
    return cab, approach


def build_samples(exp, cab: np.ndarray, approach: np.ndarray, system, idx_c: np.ndarray, idx_t: np.ndarray):
    """(head, rest, fields, values) per sampled cabinet (t, c) and tower (t, n) decision."""
    from lcmesh.distill.llm import step_view, tower_view
    from lcmesh.llm.control_format import (
        CABINET_HEAD,
        TOWER_FIELDS,
        TOWER_HEAD,
        cabinet_answer,
        cabinet_fields,
        cabinet_rest,
        tower_answer,
        tower_rest,
    )  # fmt: skip

    fields = cabinet_fields(system.cabinets.branches)
    fan_w = system.towers.cell.fan_power_nominal_w
    out = []
    for t, c in idx_c:
        y = cab[t, c]
        out.append((CABINET_HEAD, cabinet_rest(step_view(exp, int(t), int(c))), fields,
                    cabinet_answer(y[0], y[1], y[2:])))  # fmt: skip
    for t, n in idx_t:
        out.append((TOWER_HEAD, tower_rest(tower_view(exp, int(t), int(n), fan_w)), TOWER_FIELDS,
                    tower_answer(float(approach[t, n]))))  # fmt: skip
    return out


class TopLayers:
    """The model split at layer ``L0``: frozen bottom (run once, cached), top layers with LoRA, digit head."""

    def __init__(self, model, top_layers: int):
        import torch

        self.torch = torch
        self.model = model
        self.inner = model.model if hasattr(model, "model") else model
        n = len(self.inner.layers)
        if not 1 <= top_layers <= n:
            raise ValueError(f"`top_layers` must be in 1..{n}, got {top_layers}")
        self.L0 = n - top_layers

    def _run(self, h, layers):
        torch = self.torch
        pos = torch.arange(h.shape[1]).unsqueeze(0)
        pe = self.inner.rotary_emb(h, position_ids=pos)
        for layer in layers:
            h = layer(h, attention_mask=None, position_ids=pos, position_embeddings=pe)
        return h

    def bottom(self, ids):
        """Hidden states entering layer L0 (batch of right-padded ids; causal, so pads never reach a real token)."""
        with self.torch.inference_mode():
            return self._run(self.inner.embed_tokens(ids), self.inner.layers[: self.L0]).clone()

    def top(self, h):
        return self.inner.norm(self._run(h, self.inner.layers[self.L0 :]))


def distill_llm_control(cfg: LlmControlDistillConfig, progress: Progress | None = None) -> dict:
    """Collect, cache, train, score on the dev day; write the adapter, manifest, log and loss plot."""
    from lcmesh.llm.model_cache import offline_env, quiet_libraries

    offline_env()
    quiet_libraries()
    import torch
    from peft import LoraConfig, get_peft_model
    from transformers import AutoModelForCausalLM, AutoTokenizer

    from lcmesh.distill.experience import collect_experience
    from lcmesh.distill.policy import PpoController
    from lcmesh.llm.choice import ChoiceDecoder, HfScorer
    from lcmesh.llm.model_cache import resolve_model
    from lcmesh.twin.system import load_system

    say = progress or (lambda _s, _i, _n: None)
    if cfg.threads > 0:
        torch.set_num_threads(cfg.threads)
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    _check_dev(cfg.dev_day)
    specs = _trace_specs(cfg)
    system = load_system(cfg.system)
    teacher = PpoController(system, cfg.policy or None)
    t_start = time.monotonic()

    total = len(specs) * cfg.steps_per_trace
    exp = collect_experience(teacher, system, specs, cfg.steps_per_trace,
                             on_step=lambda k: say("teacher rollouts (training days)", k, total))  # fmt: skip
    dev = collect_experience(teacher, system, [cfg.dev_day], cfg.dev_steps,
                             on_step=lambda k: say("teacher rollout (dev day)", k, cfg.dev_steps))  # fmt: skip
    cab, appr = raw_targets(teacher, exp)
    dcab, dappr = raw_targets(teacher, dev)
    T, C = exp.cabinet_rows.shape[:2]
    N = exp.tower_rows.shape[1]
    idx_c = np.column_stack([rng.integers(0, T, cfg.samples), rng.integers(0, C, cfg.samples)])
    if cfg.tower_viper:
        from lcmesh.distill.experience import resample

        idx_t = resample(exp, cfg.tower_samples, rng, "tower")
    else:
        idx_t = np.column_stack([rng.integers(0, T, cfg.tower_samples), rng.integers(0, N, cfg.tower_samples)])
    train = build_samples(exp, cab, appr, system, idx_c, idx_t)
    n_dagger = {"cabinet": 0, "tower": 0}
    dag = student_rollouts(cfg, system, say)
    if dag is not None:
        gcab, gappr = raw_targets(teacher, dag)
        Tg = dag.cabinet_rows.shape[0]
        gi_c = np.column_stack([rng.integers(0, Tg, cfg.dagger_samples), rng.integers(0, C, cfg.dagger_samples)])
        gi_t = np.column_stack([rng.integers(0, Tg, cfg.dagger_tower_samples),
                                rng.integers(0, N, cfg.dagger_tower_samples)])  # fmt: skip
        train += build_samples(dag, gcab, gappr, system, gi_c, gi_t)
        n_dagger = {"cabinet": len(gi_c), "tower": len(gi_t), "traces": dag.traces, "hours": cfg.dagger_hours,
                    "student_decided_by": dag.meta.get("decided_by")}  # fmt: skip
    Td = dev.cabinet_rows.shape[0]
    n_dev_t = max(cfg.dev_samples // 4, 1)
    dev_c = np.column_stack([rng.integers(0, Td, cfg.dev_samples), rng.integers(0, C, cfg.dev_samples)])
    dev_t = np.column_stack([rng.integers(0, Td, n_dev_t), rng.integers(0, N, n_dev_t)])
    dev_samples = build_samples(dev, dcab, dappr, system, dev_c, dev_t)

    model_dir = resolve_model("smollm2-135m-instruct")
    tokenizer = AutoTokenizer.from_pretrained(model_dir)
    model = AutoModelForCausalLM.from_pretrained(model_dir, dtype=torch.float32).eval()
    for p in model.parameters():
        p.requires_grad_(False)
    decoder = ChoiceDecoder(HfScorer(model, tokenizer))
    encoded = []
    for head, rest, fields, values in train:
        seq, decided = decoder.targets(decoder.prompt_ids(head, rest), fields, values)
        encoded.append((seq, decided))
    split = TopLayers(model, cfg.top_layers)
    cache = _cache_bottom(split, encoded, say)

    if cfg.init_adapter:
        from peft import PeftModel

        peft_model = PeftModel.from_pretrained(model, cfg.init_adapter, is_trainable=True)
        parent = json.loads((Path(cfg.init_adapter) / "manifest.json").read_text()) \
            if (Path(cfg.init_adapter) / "manifest.json").is_file() else None
    else:
        lora = LoraConfig(r=cfg.r, lora_alpha=cfg.alpha, lora_dropout=0.0, bias="none",
                          target_modules=["q_proj", "k_proj", "v_proj", "o_proj", "gate_proj", "up_proj", "down_proj"],
                          layers_to_transform=list(range(split.L0, split.L0 + cfg.top_layers)))  # fmt: skip
        peft_model = get_peft_model(model, lora)
        parent = None
    split = TopLayers(peft_model.base_model.model, cfg.top_layers)
    params = [p for p in peft_model.parameters() if p.requires_grad]
    opt = torch.optim.AdamW(params, lr=cfg.lr, weight_decay=0.0)
    head_w = model.lm_head.weight if hasattr(model, "lm_head") else peft_model.base_model.model.lm_head.weight
    steps_per_epoch = math.ceil(len(encoded) / cfg.batch_size)
    total_steps = max(1, int(cfg.epochs * steps_per_epoch))
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: min(1.0, (s + 1) / max(1, total_steps // 20))
                                              * max(0.05, 1.0 - s / total_steps))  # fmt: skip
    log, order, step = [], [], 0
    peft_model.train()
    while step < total_steps:
        if not order:
            order = _length_batches(encoded, cfg.batch_size, rng)
        batch = order.pop()
        loss, acc = _batch_loss(split, cache, encoded, batch, head_w)
        opt.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(params, 1.0)
        opt.step()
        sched.step()
        step += 1
        log.append({"step": step, "loss": float(loss), "digit_acc": acc, "lr": sched.get_last_lr()[0]})
        say(f"training (loss {float(loss):.3f}, digit accuracy {acc:.2f})", step, total_steps)
    peft_model.eval()

    out_dir = Path(cfg.out) if cfg.out else ARTIFACT_DIR
    out_dir.mkdir(parents=True, exist_ok=True)
    peft_model.save_pretrained(str(out_dir))
    merged = peft_model.merge_and_unload()
    scores = score_dev(ChoiceDecoder(HfScorer(merged, tokenizer)), dev_samples, say)
    manifest = {
        "adapter_id": f"llm-control-{time.strftime('%Y%m%d')}-s{cfg.seed}",
        "kind": "control", "protocol": "lcmesh.llm.control_format v1",
        "teacher": exp.teacher, "train_traces": specs, "dev_day": cfg.dev_day,
        "config": asdict(cfg), "samples": {"cabinet": len(idx_c), "tower": len(idx_t), "dagger": n_dagger},
        "dev_scores": scores, "train_seconds": time.monotonic() - t_start,
        "final_loss": float(np.mean([r["loss"] for r in log[-20:]])),
        **({"parent": parent} if parent else {}),
    }  # fmt: skip
    (out_dir / "manifest.json").write_text(json.dumps(manifest, indent=2) + "\n")
    (out_dir / "train_log.jsonl").write_text("".join(json.dumps(r) + "\n" for r in log))
    _plot(log, out_dir / "loss.png")
    return manifest


def _cache_bottom(split: TopLayers, encoded, say) -> list:
    import torch

    cache: list = [None] * len(encoded)
    order = sorted(range(len(encoded)), key=lambda i: len(encoded[i][0]))
    done = 0
    for start in range(0, len(order), 64):
        group = order[start : start + 64]
        width = max(len(encoded[i][0]) for i in group)
        ids = torch.zeros((len(group), width), dtype=torch.long)
        for row, i in enumerate(group):
            seq = encoded[i][0]
            ids[row, : len(seq)] = torch.tensor(seq)
        h = split.bottom(ids)
        for row, i in enumerate(group):
            cache[i] = h[row, : len(encoded[i][0])].clone()
        done += len(group)
        say("frozen layers, once over every sample", done, len(encoded))
    return cache


def _length_batches(encoded, batch_size: int, rng) -> list[list[int]]:
    order = sorted(range(len(encoded)), key=lambda i: (len(encoded[i][0]), rng.random()))
    batches = [order[i : i + batch_size] for i in range(0, len(order), batch_size)]
    rng.shuffle(batches)
    return batches


def _batch_loss(split: TopLayers, cache, encoded, batch: list[int], head_w):
    import torch

    width = max(cache[i].shape[0] for i in batch)
    h = torch.zeros((len(batch), width, cache[batch[0]].shape[1]))
    rows, cols, targets, masks = [], [], [], []
    vocab_ids = sorted({a for i in batch for _, _, allowed in encoded[i][1] for a in allowed})
    where = {v: k for k, v in enumerate(vocab_ids)}
    for r, i in enumerate(batch):
        h[r, : cache[i].shape[0]] = cache[i]
        for pos, tok, allowed in encoded[i][1]:
            rows.append(r)
            cols.append(pos)
            targets.append(where[tok])
            m = torch.full((len(vocab_ids),), float("-inf"))
            m[[where[a] for a in allowed]] = 0.0
            masks.append(m)
    top = split.top(h)
    logits = top[rows, cols] @ head_w[vocab_ids].T + torch.stack(masks)
    target = torch.tensor(targets)
    loss = torch.nn.functional.cross_entropy(logits, target)
    acc = float((logits.argmax(-1) == target).float().mean())
    return loss, acc


def score_dev(decoder, samples, say) -> dict:
    """The student's answers on dev decisions against the teacher's: MAE per field, exact-match rates."""
    sup, dp, valves, appr, exact = [], [], [], [], []
    for k, (head, rest, fields, values) in enumerate(samples):
        got = decoder.decode(decoder.prompt_ids(head, rest), fields).values
        exact.append(got == list(values))
        if len(values) > 1:
            sup.append(abs(float(got[0]) - float(values[0])))
            dp.append(abs(float(got[1]) - float(values[1])))
            valves.append(float(np.mean([abs(int(a) - int(b)) for a, b in zip(got[2:], values[2:])])))
        else:
            appr.append(abs(float(got[0]) - float(values[0])))
        say("dev-day scores", k + 1, len(samples))
    mean = lambda x: float(np.mean(x)) if x else None
    return {"supply_mae_k": mean(sup), "dp_mae_psi": mean(dp), "valve_weight_mae": mean(valves),
            "approach_mae_k": mean(appr), "exact_answer_rate": mean(exact), "n": len(samples)}  # fmt: skip


def _plot(log, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.2))
    steps = [r["step"] for r in log]
    ax.plot(steps, [r["loss"] for r in log], lw=0.8, label="loss (decided digits)")
    ax.plot(steps, [r["digit_acc"] for r in log], lw=0.8, label="digit accuracy")
    ax.set_xlabel("step")
    ax.legend()
    ax.set_title("LLM controller distillation")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)

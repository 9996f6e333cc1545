"""The PPO policies' networks, their files (safetensors + JSON, no pickle) and the ``ppo`` controller.

A policy file pair ``NAME.safetensors`` / ``NAME.json`` holds one or two agents (``cabinet``,
``tower``), the case that trained them, the feature layout and the manifest. ``PpoController`` runs
them deterministically (distribution means / argmax) on any system with the same layout; parts an
agent does not control (e.g. the towers in case 3) follow G36, as in training.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import nn
from torch.distributions import Categorical, Dirichlet, Normal

from lcmesh.distill.features import (
    APPROACH_LEVELS_K, DEFAULT_HOLD, FeatureBuilder, FeatureLayout, HoldBand, TowerSetpoints, decode_cabinet,
)  # fmt: skip
from lcmesh.twin.controllers.base import Observation
from lcmesh.twin.controllers.g36 import G36Controller
from lcmesh.twin.plant import PlantAction
from lcmesh.twin.system import SystemDescription

ARTIFACTS = Path(__file__).resolve().parent.parent / "artifacts"
PAPER_POLICY = ARTIFACTS / "ppo" / "case7"  # case 7 on lcopt-5-paper under the lcopt scenario (paper tables, LLM teacher)
DEFAULT_POLICY = ARTIFACTS / "ppo" / "frontier-case7"  # case 7 on the real-load plant (docs/controllers.md)


@dataclass(frozen=True)
class AgentSpec:
    """Shape of one agent's networks: what ``kind`` of head, how many rows one sample holds."""

    kind: str  # "gaussian" | "multihead" | "categorical"
    row_features: int
    row_actions: int  # gaussian: action dims per row; multihead: 2 + B; categorical: number of choices
    rows: int = 1  # 1: centralized action (one row per sample); C or N: decentralized (all rows at once)
    hidden_actor: tuple[int, ...] = (64, 64)
    hidden_critic: tuple[int, ...] = (64, 64)

    @property
    def obs_dim(self) -> int:
        return self.rows * self.row_features


def mlp(sizes: list[int], activation=nn.Tanh) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2:
            layers.append(activation())
    return nn.Sequential(*layers)


class AgentNet(nn.Module):
    """Actor and critic of one agent. ``dist(obs, std)`` returns a distribution over its actions."""

    def __init__(self, spec: AgentSpec):
        super().__init__()
        self.spec = spec
        r, a = spec.rows, spec.row_actions
        if spec.kind == "gaussian":
            out = r * a
        elif spec.kind == "multihead":
            out = r * a  # 2 tanh means + B Dirichlet concentrations per row
        elif spec.kind == "categorical":
            out = r * a
        else:
            raise ValueError(f"unknown agent kind {spec.kind!r}")
        self.actor = mlp([spec.obs_dim, *spec.hidden_actor, out])
        self.critic = mlp([spec.obs_dim, *spec.hidden_critic, 1])
        with torch.no_grad():  # small last layers: near-neutral first actions
            self.actor[-1].weight.mul_(0.01)
            self.actor[-1].bias.zero_()

    def value(self, obs: torch.Tensor) -> torch.Tensor:
        return self.critic(obs).squeeze(-1)

    def dist(self, obs: torch.Tensor, std: float) -> "RowDistribution":
        z = self.actor(obs)
        r, a = self.spec.rows, self.spec.row_actions
        z = z.view(*z.shape[:-1], r, a)
        if self.spec.kind == "gaussian":
            return RowDistribution(gaussian=Normal(torch.tanh(z), std))
        if self.spec.kind == "categorical":
            return RowDistribution(categorical=Categorical(logits=z))
        concentration = 1.0 + nn.functional.softplus(z[..., 2:]) * (0.6 / std) ** 2
        return RowDistribution(gaussian=Normal(torch.tanh(z[..., :2]), std), dirichlet=Dirichlet(concentration))


@dataclass
class RowDistribution:
    """The action distribution of a batch of samples; log-probs and entropies sum over rows and dims."""

    gaussian: Normal | None = None
    dirichlet: Dirichlet | None = None
    categorical: Categorical | None = None

    def sample(self) -> torch.Tensor:
        if self.categorical is not None:
            return self.categorical.sample().float()
        parts = [self.gaussian.sample()]
        if self.dirichlet is not None:
            parts.append(self.dirichlet.sample().clamp_min(1e-6))
        return torch.cat(parts, dim=-1)

    def mode(self) -> torch.Tensor:
        if self.categorical is not None:
            return self.categorical.logits.argmax(-1).float()
        parts = [self.gaussian.mean]
        if self.dirichlet is not None:
            parts.append(self.dirichlet.mean)
        return torch.cat(parts, dim=-1)

    def log_prob(self, action: torch.Tensor) -> torch.Tensor:
        if self.categorical is not None:
            return self.categorical.log_prob(action.long()).sum(-1)
        n = self.gaussian.mean.shape[-1]
        lp = self.gaussian.log_prob(action[..., :n]).sum((-1, -2))
        if self.dirichlet is not None:
            v = action[..., n:].clamp_min(1e-6)
            lp = lp + self.dirichlet.log_prob(v / v.sum(-1, keepdim=True)).sum(-1)
        return lp

    def entropy(self) -> torch.Tensor:
        if self.categorical is not None:
            return self.categorical.entropy().sum(-1)
        e = self.gaussian.entropy().sum((-1, -2))
        if self.dirichlet is not None:
            e = e + self.dirichlet.entropy().sum(-1)
        return e

    def min_log_prob(self) -> torch.Tensor:
        """VIPER's min_a log pi(a|s) (Appendix A): Gaussian at the action-space boundary, categorical's rarest."""
        if self.categorical is not None:
            return torch.log_softmax(self.categorical.logits, -1).min(-1).values.sum(-1)
        mean, std = self.gaussian.mean, self.gaussian.stddev
        edge = torch.where(mean >= 0, -torch.ones_like(mean), torch.ones_like(mean))
        lp = Normal(mean, std).log_prob(edge).sum((-1, -2))
        if self.dirichlet is not None:  # the Dirichlet's least likely split near a vertex
            alpha = self.dirichlet.concentration
            vertex = torch.full_like(alpha, 1e-3)
            vertex.scatter_(-1, alpha.argmin(-1, keepdim=True), 1.0 - 1e-3 * (alpha.shape[-1] - 1))
            lp = lp + self.dirichlet.log_prob(vertex).sum(-1)
        return lp


@dataclass
class PolicyFile:
    """What a policy file holds besides the weights."""

    case: int
    layout: dict
    agents: dict[str, dict]  # name -> AgentSpec as dict
    std: float  # the exploration std at save time (deterministic runs ignore it)
    manifest: dict = field(default_factory=dict)


def save_policy(path: Path, nets: dict[str, AgentNet], meta: PolicyFile) -> Path:
    """Write ``path.safetensors`` + ``path.json``; returns the JSON path."""
    from safetensors.torch import save_file

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tensors = {f"{name}.{k}": v.detach().contiguous() for name, net in nets.items() for k, v in net.state_dict().items()}
    save_file(tensors, str(path.with_suffix(".safetensors")))
    path.with_suffix(".json").write_text(json.dumps(asdict(meta), indent=2) + "\n")
    return path.with_suffix(".json")


def load_policy(path: Path) -> tuple[dict[str, AgentNet], PolicyFile]:
    """Read a policy pair written by :func:`save_policy`; clear errors for missing or foreign files."""
    from safetensors.torch import load_file

    path = Path(path)
    meta_path, weights_path = path.with_suffix(".json"), path.with_suffix(".safetensors")
    for p in (meta_path, weights_path):
        if not p.is_file():
            raise FileNotFoundError(f"policy file {p} not found (train one with `lcmesh train ppo`)")
    try:
        meta = PolicyFile(**json.loads(meta_path.read_text()))
    except (TypeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{meta_path} is not an lc-mesh policy file: {exc}") from exc
    tensors = load_file(str(weights_path))
    nets = {}
    for name, spec in meta.agents.items():
        spec = AgentSpec(**{**spec, "hidden_actor": tuple(spec["hidden_actor"]), "hidden_critic": tuple(spec["hidden_critic"])})
        net = AgentNet(spec)
        state = {k[len(name) + 1 :]: v for k, v in tensors.items() if k.startswith(name + ".")}
        net.load_state_dict(state)
        net.eval()
        nets[name] = net
    return nets, meta


class PpoController:
    """A trained PPO policy (any case) as a controller; G36 drives what the policy does not."""

    name = "ppo"

    def __init__(
        self,
        system: SystemDescription,
        policy: str | Path | None = None,
        *,
        loaded: tuple[dict[str, AgentNet], PolicyFile] | None = None,
        pool_cells: bool = False,
        hold: HoldBand | None = DEFAULT_HOLD,
    ):
        path = Path(policy) if policy is not None else DEFAULT_POLICY
        self.hold = hold
        self.nets, self.meta = loaded if loaded is not None else load_policy(path)
        # what a result depends on (the benches' cache keys, lcmesh/bench/engine.py)
        self.artifact_files = (() if loaded is not None
                               else (path.with_suffix(".json"), path.with_suffix(".safetensors")))  # fmt: skip
        layout = FeatureLayout(**self.meta.layout)
        layout.check(system, f"policy {path}", pool_cells=pool_cells)
        for name, net in self.nets.items():
            if net.spec.rows > 1:
                expected = system.cabinets.count if name == "cabinet" else system.towers.count
                if net.spec.rows != expected:
                    raise ValueError(
                        f"policy {path} has a decentralized {name} agent for {net.spec.rows} {name}s; system "
                        f"{system.name!r} has {expected}. Only centralized-action policies transfer across sizes."
                    )
        self.version = str(self.meta.manifest.get("version", f"case{self.meta.case}"))
        self.system = system
        self.features = FeatureBuilder(system, layout)
        self.version += self.features.pooling_note
        self.baseline = G36Controller(system)
        self.towers = TowerSetpoints(system)
        self.last_viper_weights: np.ndarray | None = None
        C, B, N = system.cabinets.count, system.cabinets.branches, system.towers.count
        self._action = PlantAction(np.zeros(C), np.zeros(C), np.full((C, B), 1.0 / B), np.zeros(N))

    def reset(self) -> None:
        self.baseline.reset()
        self.towers.reset()

    @torch.no_grad()
    def act(self, obs: Observation) -> PlantAction:
        action = self._action
        base = None
        if len(self.nets) < 2 or self.nets["cabinet"].spec.row_actions == 2:  # G36 drives what the policy does not
            base = self.baseline.act(obs)
            for dst, src in zip(action.astuple(), base.astuple()):
                dst[...] = src
        if "cabinet" in self.nets:
            u = policy_mode(self.nets["cabinet"], self.features.cabinet_rows(obs), self.meta.std)
            decode_cabinet(u, action, valves_given=self.nets["cabinet"].spec.kind == "multihead")
            if u.shape[1] == 2:  # case 3: no valve control, the baseline's split stays
                action.valve_fractions[:] = base.valve_fractions
        if "tower" in self.nets:
            choice = policy_mode(self.nets["tower"], self.features.tower_rows(obs), self.meta.std)
            self.towers.apply(choice[:, 0] if choice.ndim == 2 else choice, obs.wet_bulb_k, action)
        if self.hold is not None:
            self.hold.apply(action, obs.out)
        return action

    @torch.no_grad()
    def viper_weights(self, obs: Observation) -> dict[str, np.ndarray]:
        """VIPER importance l(s) = log pi(a*|s) - min_a log pi(a|s) per cabinet and per tower (Appendix A)."""
        weights = {}
        for name, rows in (("cabinet", self.features.cabinet_rows), ("tower", self.features.tower_rows)):
            if name in self.nets:
                net = self.nets[name]
                x = torch.as_tensor(rows(obs)).reshape(-1, net.spec.obs_dim)
                d = net.dist(x, self.meta.std)
                w = (d.log_prob(d.mode()) - d.min_log_prob()).numpy()
                weights[name] = np.repeat(w, net.spec.rows)
        return weights


def policy_mode(net: AgentNet, rows: np.ndarray, std: float) -> np.ndarray:
    """Deterministic action rows (n_rows, row_actions) or choices (n_rows,) for the given feature rows."""
    x = torch.as_tensor(rows).reshape(-1, net.spec.obs_dim)
    a = net.dist(x, std).mode().numpy()
    if net.spec.kind == "categorical":
        return a.reshape(-1).astype(np.int64)
    return a.reshape(-1, net.spec.row_actions)


__all__ = ["APPROACH_LEVELS_K", "AgentNet", "AgentSpec", "PolicyFile", "PpoController", "load_policy", "save_policy"]

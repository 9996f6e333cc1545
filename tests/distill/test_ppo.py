"""PPO teacher: determinism, policy files, layout refusal, and (slow) a smoke run that learns."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from lcmesh.distill.features import FeatureLayout
from lcmesh.distill.policy import PpoController, load_policy
from lcmesh.distill.ppo import train_ppo
from lcmesh.distill.ppo_config import PpoConfig
from lcmesh.twin.system import load_system, parse_system


def _tiny(tmp_path, case: int, seed: int = 0, updates: int = 2, name: str = "run") -> PpoConfig:
    return PpoConfig(case=case, total_env_steps=updates * 2 * 40, n_envs=2, episode_steps=40, seed=seed,
                     epochs=2, minibatch=64, eval_every=updates, eval_trace="synthetic:1003", eval_hours=0.5,
                     out=str(tmp_path / name))  # fmt: skip


@pytest.mark.parametrize("case", [2, 3, 5, 7])
def test_each_case_trains_and_writes_a_loadable_policy(tmp_path, case):
    summary = train_ppo(_tiny(tmp_path, case))
    nets, meta = load_policy(tmp_path / "run" / "best")
    assert meta.case == case
    expected = {2: {"tower"}, 3: {"cabinet"}, 5: {"cabinet", "tower"}, 7: {"cabinet", "tower"}}[case]
    assert set(nets) == expected
    assert (tmp_path / "run" / "log.csv").read_text().count("\n") == 3  # header + 2 updates
    assert 0.0 <= summary["best"]["kpi"]["d_blade_pct"] <= 100.0
    manifest = meta.manifest
    assert manifest["seed"] == 0 and manifest["config"]["case"] == case and "commit" in manifest


def test_same_seed_same_policy(tmp_path):
    train_ppo(_tiny(tmp_path, 7, seed=3, name="a"))
    train_ppo(_tiny(tmp_path, 7, seed=3, name="b"))
    train_ppo(_tiny(tmp_path, 7, seed=4, name="c"))
    a, _ = load_policy(tmp_path / "a" / "last")
    b, _ = load_policy(tmp_path / "b" / "last")
    c, _ = load_policy(tmp_path / "c" / "last")
    for name in a:
        for (k, va), vb, vc in zip(a[name].state_dict().items(), b[name].state_dict().values(), c[name].state_dict().values()):
            assert torch.equal(va, vb), f"{name}.{k} differs between two runs with the same seed"
    assert any(not torch.equal(va, vc) for va, vc in zip(a["cabinet"].state_dict().values(), c["cabinet"].state_dict().values()))


def test_centralized_policy_runs_on_a_larger_system_but_decentralized_is_refused(tmp_path):
    train_ppo(_tiny(tmp_path, 7, name="ca", updates=1))
    train_ppo(_tiny(tmp_path, 5, name="joint", updates=1))
    big = load_system("lcopt-10")
    ctrl = PpoController(big, tmp_path / "ca" / "last")
    from lcmesh.twin.plant import Plant

    with Plant(big) as plant:
        from lcmesh.twin.controllers.base import Observation

        action = ctrl.act(Observation(plant.out, 295.0, np.full(big.n_blade_groups, 60e3), 0.0))
    assert action.valve_fractions.shape == (10, 3)
    np.testing.assert_allclose(action.valve_fractions.sum(axis=1), 1.0, atol=1e-9)
    with pytest.raises(ValueError, match="decentralized cabinet agent for 5 cabinets"):
        PpoController(big, tmp_path / "joint" / "last")


def test_policy_for_another_layout_is_refused_with_a_clear_message(tmp_path):
    train_ppo(_tiny(tmp_path, 7, name="ca", updates=1))
    data = json.loads(load_system("lcopt-5").model_dump_json())
    data["name"] = "four-branches"
    data["cabinets"]["branches"] = 4
    four = parse_system(data)
    with pytest.raises(ValueError, match=r"trained for B=3 branches .* has B=4"):
        PpoController(four, tmp_path / "ca" / "last")
    assert FeatureLayout.for_system(four) != FeatureLayout.for_system(load_system("lcopt-5"))


def test_missing_or_foreign_policy_file_is_a_clear_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="lcmesh train ppo"):
        PpoController(load_system("lcopt-5"), tmp_path / "nothing")
    (tmp_path / "x.json").write_text('{"hello": 1}')
    (tmp_path / "x.safetensors").write_bytes(b"")
    with pytest.raises(ValueError, match="not an lc-mesh policy file"):
        PpoController(load_system("lcopt-5"), tmp_path / "x")


def test_bad_config_names_the_field():
    with pytest.raises(ValueError, match="`case` must be one of"):
        PpoConfig(case=1)
    with pytest.raises(ValueError, match="`n_envs` must be >= 1"):
        PpoConfig(n_envs=0)


@pytest.mark.slow
def test_smoke_training_lowers_the_value_loss_and_raises_reward(tmp_path):
    cfg = PpoConfig(case=7, total_env_steps=24 * 4 * 100, n_envs=4, episode_steps=100, eval_every=24,
                    eval_hours=2.0, out=str(tmp_path / "smoke"))  # fmt: skip
    train_ppo(cfg)
    import csv

    rows = list(csv.DictReader((tmp_path / "smoke" / "log.csv").open()))
    first = np.mean([float(r["cabinet_value_loss"]) for r in rows[:4]])
    last = np.mean([float(r["cabinet_value_loss"]) for r in rows[-4:]])
    assert last < first, f"value loss did not fall: {first:.2f} -> {last:.2f}"
    r_first = np.mean([float(r["cabinet_reward"]) for r in rows[:4]])
    r_last = np.mean([float(r["cabinet_reward"]) for r in rows[-4:]])
    assert r_last > r_first, f"reward did not rise: {r_first:.2f} -> {r_last:.2f}"

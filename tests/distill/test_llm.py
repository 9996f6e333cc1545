"""LLM distillation: dataset building from teacher experience, config checks, and (slow) QLoRA runs."""

from __future__ import annotations

import numpy as np
import pytest

from lcmesh.distill.experience import collect_experience, resample
from lcmesh.distill.llm import action_samples, explanation_samples, head_metrics, step_view, teacher_targets
from lcmesh.llm.distill_config import LlmDistillConfig
from lcmesh.llm.io_format import CabinetDecision, parse_cabinet_answer
from lcmesh.mesh.tools.explain_eval import LEVEL_SECTIONS
from lcmesh.twin.controllers import make_controller
from lcmesh.twin.system import PSI_TO_PA


@pytest.fixture(scope="module")
def g36_experience(lcopt5):
    return collect_experience(make_controller("g36", lcopt5), lcopt5, ["synthetic:0"], 40, spinup_hours=0.1)


def test_action_targets_parse_back_to_the_teacher_actions(g36_experience):
    exp = g36_experience
    idx = resample(exp, 12, np.random.default_rng(0))
    samples, y = action_samples(exp, idx)
    assert len(samples) == 12
    for (messages, target), row in zip(samples, y):
        assert messages[-1]["role"] == "user"
        d = parse_cabinet_answer(target, 3)
        assert isinstance(d, CabinetDecision)
        assert d.supply_temp_setpoint_k == pytest.approx(row[0], abs=0.051)  # the answer gives the supply to 0.1 K
        assert d.dp_setpoint_pa == pytest.approx(row[1], abs=0.06 * PSI_TO_PA)
        np.testing.assert_allclose(d.valve_fractions, row[2:], atol=0.011)


def test_prompt_view_matches_the_recorded_step(g36_experience):
    exp = g36_experience
    v = step_view(exp, 7, 3)
    assert v.branch_temp_c[1] == pytest.approx(exp.obs["branch_temp_k"][7, 3, 1] - 273.15, abs=1e-4)
    assert v.branch_power_kw[2] == pytest.approx(exp.obs["branch_power_w"][7, 3, 2] / 1e3, rel=1e-5)
    assert v.wet_bulb_c == pytest.approx(exp.wet_bulb_k[7] - 273.15, abs=1e-4)
    y = teacher_targets(exp, np.array([[7, 3]]))
    assert y[0, 0] == pytest.approx(exp.actions["supply_temp_setpoint_k"][7, 3])


def test_viper_weights_steer_the_resampling(g36_experience):
    exp = g36_experience
    exp.cabinet_weights[:] = 0.0
    exp.cabinet_weights[5, 2] = 1.0  # all weight on one decision
    idx = resample(exp, 20, np.random.default_rng(0))
    assert (idx == [5, 2]).all()
    exp.cabinet_weights[:] = 1.0


def test_explanation_samples_pair_facts_with_the_renderer_text(lcopt5):
    samples = explanation_samples(make_controller("g36", lcopt5), lcopt5, "synthetic:0", 30,
                                  {"short": 2, "detailed": 1}, seed=0)  # fmt: skip
    assert len(samples) == 3
    levels = []
    for messages, text in samples:
        assert "tower_lw_setpoint = " in messages[1]["content"]
        level = "detailed" if "EXECUTIVE SUMMARY" in text else "short"
        assert all(f"## {h}" in text for h in LEVEL_SECTIONS[level])
        levels.append(level)
    assert sorted(levels) == ["detailed", "short", "short"]


def test_head_metrics_score_a_perfect_and_a_constant_prediction():
    rng = np.random.default_rng(0)
    y = np.column_stack([rng.uniform(293, 300, 50), rng.uniform(2e5, 2.5e5, 50), rng.dirichlet([1, 1, 1], 50)])
    scale = np.array([1.0, 1.0 / PSI_TO_PA])
    perfect = head_metrics(y, y.copy(), scale, 3)
    assert perfect["cdu_r2"] == pytest.approx(1.0) and perfect["cdu_mae"]["dp_psi"] == 0.0
    flat = head_metrics(y, np.tile(y.mean(axis=0), (50, 1)), scale, 3)
    assert flat["cdu_r2"] == pytest.approx(0.0, abs=1e-9) and flat["valve_r2"] == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize(
    "kwargs, field", [({"teacher": "sac"}, "teacher"), ({"samples": 0}, "samples"),
                      ({"explain_samples": "long:3"}, "explain_samples")],
)  # fmt: skip
def test_config_names_the_bad_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        LlmDistillConfig(**kwargs)


def test_train_config_names_the_bad_field():
    from lcmesh.llm.hf.train import LoraTrainConfig

    with pytest.raises(ValueError, match="quant"):
        LoraTrainConfig(quant="int3")


def _tiny_samples(n: int):
    from lcmesh.llm.io_format import CabinetView, answer_text, controller_messages

    rng = np.random.default_rng(0)
    out = []
    for _ in range(n):
        t, p = rng.uniform(25, 40, 3), rng.uniform(10, 150, 3)
        view = CabinetView(tuple(t), tuple(t + 2), tuple(p), 21.0, 24.5, 18.3)
        out.append((controller_messages(view), answer_text(293.15 + 0.2 * (t.max() - 25), 30 * PSI_TO_PA, p / p.sum())))
    return out


@pytest.mark.slow
def test_qlora_smoke_run_lowers_the_loss(tmp_path):
    from lcmesh.llm.hf.backend import HfBackend
    from lcmesh.llm.hf.train import LoraTrainConfig, save_adapter, train_lora
    from lcmesh.llm.model_cache import resolve_model

    model_dir = resolve_model("smollm2-135m-instruct")
    cfg = LoraTrainConfig(quant="nf4", epochs=4, batch_size=4, lr=2e-3, seed=0)
    model, _, result = train_lora(model_dir, _tiny_samples(16), cfg)
    assert result.steps == 16
    assert np.mean(result.losses[-4:]) < 0.5 * np.mean(result.losses[:4])
    path = save_adapter(model, tmp_path)
    assert 1e6 < path.stat().st_size < 10e6
    backend = HfBackend(model_dir, adapter=tmp_path)  # loads and merges the saved adapter
    assert backend.model_id.endswith(f"+{tmp_path.name}")
    second = LoraTrainConfig(quant="nf4", epochs=1, batch_size=4, lr=1e-4, seed=1, init_adapter=str(tmp_path))
    _, _, again = train_lora(model_dir, _tiny_samples(16), second)  # a second stage starts where the first ended
    assert again.losses[0] < 0.5 * np.mean(result.losses[:4])


@pytest.mark.slow
def test_same_seed_same_adapter():
    from lcmesh.llm.hf.train import LoraTrainConfig, adapter_state, train_lora
    from lcmesh.llm.model_cache import resolve_model

    model_dir = resolve_model("smollm2-135m-instruct")
    cfg = LoraTrainConfig(quant="nf4", epochs=1, batch_size=4, seed=7)
    runs = [train_lora(model_dir, _tiny_samples(8), cfg) for _ in range(2)]
    a, b = (adapter_state(m) for m, _, _ in runs)
    assert runs[0][2].losses == runs[1][2].losses
    assert a.keys() == b.keys() and all(np.array_equal(a[k].numpy(), b[k].numpy()) for k in a)
    other = train_lora(model_dir, _tiny_samples(8), LoraTrainConfig(quant="nf4", epochs=1, batch_size=4, seed=8))
    assert other[2].losses != runs[0][2].losses


def test_step_log_appends_each_step_and_reports_it(tmp_path):
    import json

    from lcmesh.llm.hf.train import step_log

    said = []
    on_step = step_log(tmp_path / "train_log.jsonl", lambda text, i, n: said.append((text, i, n)), "QLoRA (nf4)")
    on_step(1, 2, 0.5)
    on_step(2, 2, 0.25)
    rows = [json.loads(line) for line in (tmp_path / "train_log.jsonl").read_text().splitlines()]
    assert [(r["step"], r["of"], r["loss"]) for r in rows] == [(1, 2, 0.5), (2, 2, 0.25)]
    assert said[-1] == ("QLoRA (nf4) loss 0.250", 2, 2)


def test_a_windowed_rollout_is_the_busiest_hours_after_the_warm_up(lcopt5):
    """DAgger's rollouts (`lcmesh distill llm-control --dagger-seeds`): the trace's busiest window, after the
    benchmark's 30-min warm-up by the same controller, as the closed-loop benchmark picks it."""
    from lcmesh.bench.llm import WARMUP_STEPS, busiest_window
    from lcmesh.twin.traces import load_trace

    spec = "synthetic:36@design-day"
    exp = collect_experience(make_controller("g36", lcopt5), lcopt5, [spec], window_hours=0.1)
    assert exp.n_steps == WARMUP_STEPS + 24  # 0.1 h of 15 s steps
    trace = load_trace("synthetic:36", lcopt5, scenario="design-day")
    start = busiest_window(trace, 24)
    assert np.allclose(exp.wet_bulb_k, trace.wet_bulb_k[start - WARMUP_STEPS : start + 24])
    with pytest.raises(ValueError, match="window_hours"):
        collect_experience(make_controller("g36", lcopt5), lcopt5, [spec], window_hours=0)


def test_dagger_seeds_must_be_training_seeds():
    from lcmesh.distill.llm_control import LlmControlDistillConfig, _trace_specs

    cfg = LlmControlDistillConfig(dagger_seeds="36,1011")
    with pytest.raises(ValueError, match="`dagger_seeds` must be training seeds.*1011"):
        _trace_specs(cfg, cfg.dagger_seeds, cfg.dagger_scenario, "dagger_seeds")
    assert _trace_specs(cfg, "36,31", "design-day", "dagger_seeds") == ["synthetic:36@design-day",
                                                                         "synthetic:31@design-day"]  # fmt: skip
    with pytest.raises(ValueError, match="dagger_hours"):
        LlmControlDistillConfig(dagger_hours=0)


def test_whatif_samples_pair_the_compact_prompt_with_the_whatif_section(lcopt5):
    samples = explanation_samples(make_controller("g36", lcopt5), lcopt5, "synthetic:0", 30, {"whatif": 3}, seed=0)
    assert len(samples) == 3
    for (system, user), text in samples:
        assert "Sections: WHAT IF" in system["content"]
        assert "hottest_branch_expected = " in user["content"] and "dp_setpoint" not in user["content"]
        assert text.startswith("## WHAT IF\n\n") and "°C" in text and "pump" not in text


def test_auto_compute_dtype_is_bfloat16_only_where_the_cpu_multiplies_it_natively():
    import torch

    from lcmesh.llm.hf.train import LoraTrainConfig, fast_compute_dtype

    if torch.cuda.is_available():
        pytest.skip("a GPU trains in bfloat16 whatever the CPU")
    assert fast_compute_dtype("flags : fpu sse2 avx2 fma") == "float32"
    assert fast_compute_dtype("flags : fpu avx2 avx512f avx512_bf16") == "bfloat16"
    assert fast_compute_dtype("flags : fpu avx2 amx_bf16 amx_tile") == "bfloat16"
    assert LoraTrainConfig().compute_dtype in ("float32", "bfloat16")  # auto resolves on construction
    assert LoraTrainConfig(compute_dtype="bfloat16").compute_dtype == "bfloat16"
    with pytest.raises(ValueError, match="compute_dtype"):
        LoraTrainConfig(compute_dtype="fp8")

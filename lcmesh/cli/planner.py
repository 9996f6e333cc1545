"""lcmesh distill planner: the chat's question reader (issue 34: operator question -> typed Query), or with
``--output calls`` the first planner (issue 15: question -> JSON tool calls)."""

from __future__ import annotations

from lcmesh.cli.common import console, distill_app, stage_bars
from lcmesh.cli.control import dataclass_options


def _distill_planner(config) -> None:
    from lcmesh.distill.planner_data import distill_planner

    with stage_bars() as on_progress:
        manifest = distill_planner(config, progress=on_progress)
    t, m = manifest["metrics"]["train"], manifest["metrics"]
    llm, rules = m["dev_llm"], m["dev_rules"]
    dev_name = "the authors' dev slice" if manifest.get("output") == "query" else "generator dev"
    console.print(
        f"adapter {manifest['adapter_id']} ({manifest['adapter_bytes'] / 1e6:.1f} MB): loss {t['loss_first']:.3f} -> "
        f"{t['loss_last10_mean']:.3f}, {t['tokens_per_s']:.0f} tokens/s, {t['seconds'] / 60:.1f} min; "
        f"{dev_name} (n={llm['n']}): exact plan {100 * llm['exact_plan_accuracy']:.1f} % "
        f"(rules {100 * rules['exact_plan_accuracy']:.1f} %), fallbacks {100 * llm['fallback_rate']:.1f} %, "
        f"p50/p99 {llm['latency_s_p50']:.2f}/{llm['latency_s_p99']:.2f} s"
    )


def _register() -> None:
    from lcmesh.distill.planner_data import PlannerDistillConfig

    distill_app.command(
        "planner", help="QLoRA-tune SmolLM2-135M-Instruct to read chat questions into typed queries (every author's "
                        "pairs); adapter + manifest + dev scores."
    )(dataclass_options(PlannerDistillConfig, _distill_planner))


_register()

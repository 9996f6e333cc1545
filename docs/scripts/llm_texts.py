"""The corpus's SmolLM2 style: the base SmolLM2-135M-Instruct (no adapter) under prompts other than ours.

Called by ``make_explain_corpus.py --llm``; writes ``llm.jsonl`` without labels (``expected_flags``),
which a person then adds by reading each text against its record (docs/explanations.md). Greedy
decoding, so a rerun on the same model gives the same texts; it takes a few minutes on 2 cores.
"""

from __future__ import annotations

import json
from pathlib import Path

PROMPTS = {
    "log": "You are a data-center operator. Write ONE short log line (under 30 words) recording this cooling "
           "decision, with its numbers.",
    "why": "Explain in one or two short sentences, for a plant manager, what the cooling controller did and why. "
           "Use the numbers given.",
    "bullets": "Summarize this cooling decision as 3 or 4 short bullet points, one per setting, with values.",
}  # fmt: skip
N_TEXTS = 20


def decision_block(rec: dict) -> str:
    """The decision as compact lines (not our facts block: another system's prompt)."""
    f = {x["name"]: x["value"] for x in rec["facts"]}
    n = len(rec["action"]["valve_fractions"])
    word = {True: "raised", False: "lowered"}

    def move(change: float, band: float) -> str:
        return "held" if abs(change) <= band else f"{word[change > 0]} by {abs(change):.1f}"

    lines = [f"Cabinet {int(f['cabinet'])}."]
    for j in range(1, n + 1):
        ch = f[f"branch_{j}_valve_change"]
        lines.append(f"Branch {j}: {f[f'branch_{j}_temp']:.1f} C, {f[f'branch_{j}_power']:.1f} kW, valve "
                     f"{f[f'branch_{j}_valve_fraction']:.2f} ({'held' if abs(ch) <= 0.005 else word[ch > 0]}).")
    lines.append(f"Supply setpoint {f['supply_setpoint']:.1f} C ({move(f['supply_setpoint_change'], 0.05)}).")
    lines.append(f"DP setpoint {f['dp_setpoint']:.1f} psi ({move(f['dp_setpoint_change'], 0.05)}), "
                 f"flow {f['secondary_flow']:.2f} kg/s.")
    lines.append(f"Tower leaving-water setpoint {f['tower_lw_setpoint']:.1f} C ({move(f['tower_lw_change'], 0.05)}), "
                 f"wet bulb {f['wet_bulb']:.1f} C.")
    return "\n".join(lines)


def generate(records: list[dict], split: dict[str, str], path: Path) -> None:
    from lcmesh.llm.base import make_backend

    backend = make_backend(backend="local", adapter="none", threads=2)
    chosen = sorted(records, key=lambda r: r["record_key"])[:: max(1, len(records) // N_TEXTS)][:N_TEXTS]
    names = list(PROMPTS)
    with path.open("w") as fh:
        for i, rec in enumerate(chosen):
            name = names[i % len(names)]
            # the data first, the task last: asked first, the model copies the data back
            conv = [{"role": "user", "content": "Cooling decision:\n" + decision_block(rec) + "\n\n" + PROMPTS[name]}]
            gen = backend.chat([conv], max_new_tokens=56)[0]
            fh.write(json.dumps({"id": f"{rec['record_key']}/llm-{name}", "record_key": rec["record_key"],
                                 "style": "smollm2_base", "source": "llm", "prompt": name,
                                 "model": backend.model_id, "explanation": gen.text.strip()}, ensure_ascii=False)
                     + "\n")  # fmt: skip
            fh.flush()
            print(f"{i + 1}/{len(chosen)} {gen.new_tokens} tokens {gen.seconds:.1f} s", flush=True)

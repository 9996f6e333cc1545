"""``lcmesh bench runtime``: LLM runtimes side by side on the same prompts, greedy, in one run.

Each runtime runs in its own process (spawned), so its load time and resident memory are its own:
transformers fp32 and bf16 (the unpacked GGUF), llama.cpp through llama-cpp-python on the shipped
Q4_1 GGUF, and, when installed (not a dependency), CTranslate2 int8 converted from the same weights.
Per runtime: load seconds, tokens/s at batch 1 (prefill included, as a user waits for it) and at the
controller's batch (its cabinets and towers: 7 on lcopt-5), peak resident memory, the installed size
of its packages, and whether its greedy text equals transformers fp32's, prompt by prompt.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import time
from importlib import metadata

PROMPTS = (
    "Explain in two sentences what a coolant distribution unit does in a liquid-cooled data center.",
    "A cooling tower's leaving water is 4 K above the wet bulb. What does that approach mean for fan power?",
    "List three reasons a blade group could run hotter than the others in the same cabinet.",
)
NEW_TOKENS = 64
CONTROLLER_BATCH = 7  # lcopt-5: 5 cabinets and 2 towers per decision
PACKAGES = {"transformers": ("torch", "transformers", "tokenizers", "safetensors"),
            "llama.cpp": ("llama_cpp_python",), "ctranslate2": ("ctranslate2",)}  # fmt: skip


def _conversations(n: int) -> list[list[dict]]:
    return [[{"role": "user", "content": PROMPTS[i % len(PROMPTS)]}] for i in range(n)]


def _peak_rss_mb() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _run_transformers(dtype: str, threads: int) -> dict:
    from lcmesh.llm.hf.backend import HfBackend
    from lcmesh.llm.model_cache import resolve_model

    t0 = time.perf_counter()
    backend = HfBackend(resolve_model("smollm2-135m-instruct"), adapter=None, dtype=dtype, threads=threads,
                        calibrate=False)  # fmt: skip
    load = time.perf_counter() - t0
    return _measure(backend, load, batched=True)


def _run_llama(threads: int) -> dict:
    from lcmesh.llm.llama_backend import LlamaCppBackend

    t0 = time.perf_counter()
    backend = LlamaCppBackend(threads=threads)
    load = time.perf_counter() - t0
    return _measure(backend, load, batched=False)


def _measure(backend, load_s: float, batched: bool) -> dict:
    backend.chat(_conversations(1), max_new_tokens=4)  # warm-up: first-call allocations
    texts, tokens, seconds = [], 0, 0.0
    for conv in _conversations(len(PROMPTS)):
        t0 = time.perf_counter()
        g = backend.chat([conv], max_new_tokens=NEW_TOKENS)[0]
        seconds += time.perf_counter() - t0
        tokens += g.new_tokens
        texts.append(g.text)
    t0 = time.perf_counter()
    if batched:
        gens = backend.chat(_conversations(CONTROLLER_BATCH), max_new_tokens=NEW_TOKENS)
    else:  # a runtime without batching answers the controller's batch one after another
        gens = [backend.chat([c], max_new_tokens=NEW_TOKENS)[0] for c in _conversations(CONTROLLER_BATCH)]
    batch_s = time.perf_counter() - t0
    return {"load_s": load_s, "tokens_per_s_batch1": tokens / seconds,
            "tokens_per_s_batch": sum(g.new_tokens for g in gens) / batch_s, "peak_rss_mb": _peak_rss_mb(),
            "texts": texts}  # fmt: skip


def _run_ct2(threads: int) -> dict:
    import ctranslate2
    from transformers import AutoTokenizer

    from lcmesh.llm.llama_backend import chatml
    from lcmesh.llm.model_cache import models_dir, resolve_model

    src = resolve_model("smollm2-135m-instruct")
    out = models_dir() / f"{src.name}-ct2-int8"
    t_convert = None
    if not (out / "model.bin").is_file():
        t0 = time.perf_counter()
        ctranslate2.converters.TransformersConverter(str(src)).convert(str(out), quantization="int8", force=True)
        t_convert = time.perf_counter() - t0
    t0 = time.perf_counter()
    gen = ctranslate2.Generator(str(out), device="cpu", compute_type="int8", intra_threads=threads)
    tok = AutoTokenizer.from_pretrained(src)
    load = time.perf_counter() - t0
    eos = tok.convert_ids_to_tokens(tok.eos_token_id)

    def run(convs):
        prompts = [tok.convert_ids_to_tokens(tok(chatml(c), add_special_tokens=False)["input_ids"]) for c in convs]
        res = gen.generate_batch(prompts, max_length=NEW_TOKENS, sampling_topk=1, include_prompt_in_result=False,
                                 end_token=eos)  # fmt: skip
        return [tok.decode(r.sequences_ids[0], skip_special_tokens=True) for r in res], sum(
            len(r.sequences_ids[0]) for r in res)

    run(_conversations(1))
    texts, tokens, seconds = [], 0, 0.0
    for conv in _conversations(len(PROMPTS)):
        t0 = time.perf_counter()
        text, n = run([conv])
        seconds += time.perf_counter() - t0
        texts += text
        tokens += n
    t0 = time.perf_counter()
    _, n = run(_conversations(CONTROLLER_BATCH))
    batch_s = time.perf_counter() - t0
    return {"load_s": load, "convert_s": t_convert, "tokens_per_s_batch1": tokens / seconds,
            "tokens_per_s_batch": n / batch_s, "peak_rss_mb": _peak_rss_mb(), "texts": texts}  # fmt: skip


RUNNERS = {"transformers fp32": (_run_transformers, ("float32",)), "transformers bf16": (_run_transformers, ("bfloat16",)),
           "llama.cpp Q4_1 (shipped GGUF)": (_run_llama, ()), "ctranslate2 int8": (_run_ct2, ())}  # fmt: skip


def _child(name: str, threads: int, queue) -> None:
    fn, args = RUNNERS[name]
    try:
        queue.put(fn(*args, threads))
    except Exception as exc:  # noqa: BLE001 - reported as that runtime's result
        queue.put({"error": f"{type(exc).__name__}: {exc}"})


def _installed_mb(names: tuple[str, ...]) -> float | None:
    total = 0
    for name in names:
        try:
            dist = metadata.distribution(name)
        except metadata.PackageNotFoundError:
            return None
        for f in dist.files or []:
            try:
                total += os.path.getsize(dist.locate_file(f))
            except OSError:
                pass
    return total / 1e6


def run_bench_runtime(threads: int = 2, say=None) -> dict:
    """Every runtime, one process each, one after another; text agreement against transformers fp32."""
    from lcmesh.bench.machine import machine_info

    say = say or (lambda _m: None)
    ctx = mp.get_context("spawn")
    result = {"machine": {**machine_info(), "load_avg_1m_at_start": os.getloadavg()[0]}, "threads": threads,
              "new_tokens": NEW_TOKENS, "controller_batch": CONTROLLER_BATCH, "runtimes": {}}  # fmt: skip
    for name in RUNNERS:
        if name.startswith("ctranslate2"):
            import importlib.util

            if importlib.util.find_spec("ctranslate2") is None:
                result["runtimes"][name] = {"error": "not installed (pip install ctranslate2; not a dependency)"}
                continue
        say(f"runtime: {name}")
        queue = ctx.Queue()
        proc = ctx.Process(target=_child, args=(name, threads, queue))
        proc.start()
        try:
            row = queue.get(timeout=900)
        finally:
            proc.join(timeout=30)
            if proc.is_alive():
                proc.kill()
                proc.join()
        kind = "transformers" if name.startswith("transformers") else name.split()[0]
        row["installed_mb"] = _installed_mb(PACKAGES[kind])
        result["runtimes"][name] = row
    ref = result["runtimes"]["transformers fp32"].get("texts")
    base = result["runtimes"]["transformers fp32"].get("tokens_per_s_batch1")
    for row in result["runtimes"].values():
        if "texts" in row and ref:
            row["same_text_as_fp32"] = sum(a == b for a, b in zip(row["texts"], ref))
            row["speedup_batch1_vs_fp32"] = row["tokens_per_s_batch1"] / base if base else None
    result["machine"]["load_avg_1m_at_end"] = os.getloadavg()[0]
    return result


def render_runtime(r: dict) -> str:
    m = r["machine"]
    lines = [
        "## LLM runtimes (`lcmesh bench runtime --json runs/bench/runtime.json --markdown BENCHMARKS.md`)", "",
        f"Machine: {m['cpu']}, {m['logical_cpus']} logical CPUs (1-min load {m['load_avg_1m_at_start']:.1f} at start, "
        f"{m['load_avg_1m_at_end']:.1f} at end); commit {m['commit']}; {m['date']}. SmolLM2-135M-Instruct, "
        f"{r['threads']} threads, greedy, {r['new_tokens']} new tokens, the same {len(PROMPTS)} prompts; each runtime in "
        "its own process. Batch-1 speed includes the prompt's pass (what a user waits for). The controller's batch "
        f"is {r['controller_batch']} prompts (lcopt-5's cabinets and towers); llama-cpp-python answers them one after "
        "another.", "",
        "| runtime | load s | tokens/s, batch 1 | × fp32 | tokens/s, batch 7 | peak RSS MB | installed MB | "
        "greedy text = fp32's |",
        "|---|---|---|---|---|---|---|---|",
    ]  # fmt: skip
    for name, row in r["runtimes"].items():
        if "error" in row:
            lines.append(f"| {name} | {row['error']} |")
            continue
        inst = "n/a" if row.get("installed_mb") is None else f"{row['installed_mb']:,.0f}"
        lines.append(f"| {name} | {row['load_s']:.2f} | {row['tokens_per_s_batch1']:.1f} | "
                     f"{row.get('speedup_batch1_vs_fp32', float('nan')):.1f} | {row['tokens_per_s_batch']:.1f} | "
                     f"{row['peak_rss_mb']:,.0f} | {inst} | {row.get('same_text_as_fp32', 0)} of {len(PROMPTS)} |")  # fmt: skip
    return "\n".join(lines)

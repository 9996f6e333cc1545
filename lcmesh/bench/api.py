"""``lcmesh bench api``: state-endpoint latency under 50 concurrent clients, and chat answer latency.

It runs the demo's processes for real on loopback (router, configuration, sensor, control,
monitor and the UI agent, each its own process, lcopt-5 on the Frontier day at 60x) and measures
from this process:

- state: ``GET /api/state`` from 50 concurrent keep-alive HTTP/1.1 connections, (a) paced, each
  client polling every 100 ms (500 requests/s in all, ten times what 50 dashboards at 1 s need),
  and (b) closed loop, each client sending its next request as soon as the last answer is in
  (the server's saturation throughput; latency there is queueing). The client is a raw asyncio
  socket loop so its own cost stays small; it shares the machine's cores with the server.
- chat (template mode): each scripted question type, sequentially, end to end over HTTP.
- chat (LLM mode): a second UI process with ``LCMESH_UI_PHRASER=llm`` (the ``lcmesh.llm`` local
  model on this CPU) answers the same questions; reported with how many LLM texts passed the
  grounding check (the rest fall back to the template).
"""

from __future__ import annotations

import asyncio
import os
import random
import secrets
import shutil
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import httpx
import numpy as np
import psutil

from lcmesh.bench.machine import machine_info
from lcmesh.mesh.demo import Demo
from lcmesh.mesh.processes import agent_child, child_env, free_port
from lcmesh.mesh.settings import MeshSettings

ROLES = ["configuration", "sensor", "control", "monitor", "ui"]
CLIENTS = 50
TARGETS = {"state_p99_ms": 20.0, "chat_template_s": 0.5, "chat_llm_s": 5.0}
QUESTIONS = {
    "state": "status", "rank": "which cabinet runs hottest?", "compare": "tower power now vs an hour ago",
    "why": "why did the controller lower the supply setpoint?", "whatif": "what if I raise the supply setpoint 2 K?",
    "command": "set the supply setpoint of cabinet 3 to 30 °C", "alerts": "any alerts?",
}  # fmt: skip


def _stats_ms(latencies_s: list[float]) -> dict:
    a = np.asarray(latencies_s) * 1e3
    return {"n": int(a.size), "p50_ms": float(np.percentile(a, 50)), "p90_ms": float(np.percentile(a, 90)),
            "p99_ms": float(np.percentile(a, 99)), "max_ms": float(a.max()), "mean_ms": float(a.mean())}  # fmt: skip


async def _client(host: str, port: int, path: str, n: int, out: list[float], errors: list[str], pace_s: float | None):
    reader, writer = await asyncio.open_connection(host, port)
    request = f"GET {path} HTTP/1.1\r\nHost: {host}:{port}\r\nAccept: application/json\r\n\r\n".encode()
    next_at = time.perf_counter() + (random.random() * pace_s if pace_s else 0.0)
    try:
        for _ in range(n):
            if pace_s:
                await asyncio.sleep(max(0.0, next_at - time.perf_counter()))
                next_at += pace_s
            t0 = time.perf_counter()
            writer.write(request)
            head = await reader.readuntil(b"\r\n\r\n")
            length = 0
            for line in head.split(b"\r\n")[1:]:
                if line.lower().startswith(b"content-length:"):
                    length = int(line.split(b":", 1)[1])
            await reader.readexactly(length)
            out.append(time.perf_counter() - t0)
            if not head.startswith(b"HTTP/1.1 200"):
                errors.append(head.split(b"\r\n", 1)[0].decode(errors="replace"))
    finally:
        writer.close()


def state_load(url: str, clients: int, requests_each: int, pace_s: float | None) -> dict:
    """Latency of GET /api/state from `clients` concurrent connections (paced every `pace_s`, or closed loop)."""
    host, port = url.removeprefix("http://").split(":")
    latencies: list[float] = []
    errors: list[str] = []

    async def run() -> float:
        t0 = time.perf_counter()
        await asyncio.gather(*(_client(host, int(port), "/api/state", requests_each, latencies, errors, pace_s)
                               for _ in range(clients)))  # fmt: skip
        return time.perf_counter() - t0

    wall_s = asyncio.run(run())
    return {"clients": clients, "requests_per_client": requests_each, "pace_s": pace_s, "wall_s": wall_s,
            "throughput_rps": len(latencies) / wall_s, "errors": len(errors), **_stats_ms(latencies)}  # fmt: skip


def chat_latency(url: str, repeats: int) -> dict:
    """End-to-end POST /api/chat latency per question type (sequential, one keep-alive connection)."""
    per_intent, all_s, phrased_by = {}, [], {}
    with httpx.Client(base_url=url, timeout=120.0) as http:
        for intent, question in QUESTIONS.items():
            times = []
            for _ in range(repeats):
                t0 = time.perf_counter()
                r = http.post("/api/chat", json={"message": question})
                times.append(time.perf_counter() - t0)
                r.raise_for_status()
                body = r.json()
                assert body["grounded"], body
                key = body["phrased_by"].split(":")[0]
                phrased_by[key] = phrased_by.get(key, 0) + 1
            per_intent[intent] = {"median_s": float(np.median(times)), "max_s": float(max(times))}
            all_s += times
    return {"questions": len(all_s), "per_intent": per_intent, "p50_s": float(np.percentile(all_s, 50)),
            "p99_s": float(np.percentile(all_s, 99)), "max_s": float(max(all_s)), "phrased_by": phrased_by}  # fmt: skip


def _wait_ready(url: str, timeout_s: float, what: Callable[[dict], bool] = lambda h: h["ready"]) -> dict:
    deadline = time.monotonic() + timeout_s
    last: dict | str = "no answer"
    while time.monotonic() < deadline:
        try:
            last = httpx.get(url + "/api/health", timeout=2.0).json()
            if what(last):
                return last
        except (httpx.HTTPError, ValueError):
            pass
        time.sleep(0.5)
    raise RuntimeError(f"{url} not ready after {timeout_s:.0f} s (last health: {last})")


def run_bench_api(*, quick: bool = False, llm: bool = True, say: Callable[[str], None] = print) -> dict:
    """Start the mesh, measure, stop; the result dict (also what BENCHMARKS.md renders)."""
    root = Path(tempfile.mkdtemp(prefix="lcmesh-bench-api-"))
    router, ui_port, llm_port = free_port(), free_port(), free_port()
    endpoint = f"tcp/127.0.0.1:{router}"
    settings = MeshSettings(site="benchapi", router_endpoints=[endpoint], listen_endpoints=[endpoint], system="lcopt-5",
                            controller="g36", speed_factor=60.0, data_dir=root, ui_port=ui_port,
                            orchestration={"roles": ROLES}, connect_timeout_s=60.0)  # fmt: skip
    token = secrets.token_urlsafe(24)
    ui_env = {"LCMESH_API_TOKEN": token, "LCMESH_UI_CHAT_RATE_PER_MIN": "100000", "LCMESH_UI_CHAT_BURST": "100000",
              "LCMESH_UI_PLANNER": "rules"}  # template mode: no model at all (`bench chat` measures the LLM planner)
    demo = Demo(settings, say=lambda _line: None)
    demo.env.update(ui_env)
    url = f"http://127.0.0.1:{ui_port}"
    result: dict = {"machine": machine_info(), "quick": quick, "system": "lcopt-5", "speed_factor": 60.0,
                    "targets": TARGETS, "load_avg_1min_start": os.getloadavg()[0], "niceness": os.nice(0)}  # fmt: skip
    try:
        say("starting the mesh (router, configuration, sensor, control, monitor, ui) ...")
        demo.start()
        _wait_ready(url, 120.0)
        warm_s = 5.0 if quick else 30.0
        say(f"UI ready on {url}; letting history build for {warm_s:.0f} s ...")
        time.sleep(warm_s)
        requests = 20 if quick else 100
        say(f"state: {CLIENTS} clients polling every 100 ms ...")
        result["state_paced"] = state_load(url, CLIENTS, requests, 0.1)
        say(f"state: {CLIENTS} clients in a closed loop ...")
        result["state_closed_loop"] = state_load(url, CLIENTS, requests * 2, None)
        say("chat, template mode ...")
        result["chat_template"] = chat_latency(url, 2 if quick else 5)
        if llm:
            result["chat_llm"] = _llm_mode(settings, ui_env, llm_port, quick, say)
    finally:
        result["load_avg_1min_end"] = os.getloadavg()[0]
        demo.stop()
        shutil.rmtree(root, ignore_errors=True)
    sp, ct = result["state_paced"], result["chat_template"]
    result["pass"] = {"state_p99_paced": sp["p99_ms"] <= TARGETS["state_p99_ms"],
                      "chat_template": ct["max_s"] <= TARGETS["chat_template_s"]}  # fmt: skip
    cl = result.get("chat_llm") or {}
    if "p50_s" in cl:
        result["pass"]["chat_llm"] = cl["p99_s"] <= TARGETS["chat_llm_s"]
    return result


def _llm_mode(settings: MeshSettings, ui_env: dict, port: int, quick: bool, say: Callable[[str], None]) -> dict:
    """A second UI process phrasing with the local LLM; its latency, or why it could not run."""
    env = child_env(None, "ui", **{**settings.to_env(), **ui_env, "LCMESH_UI_PORT": str(port),
                                   "LCMESH_UI_PHRASER": "llm", "LCMESH_UI_PLANNER": "llm"})  # fmt: skip
    child = agent_child("ui", "ui-llm", env, settings.log_dir / "ui-llm.log").start()
    url = f"http://127.0.0.1:{port}"
    try:
        say("chat, LLM mode: loading the local model in a second UI process ...")
        t0 = time.perf_counter()
        try:
            health = _wait_ready(url, 300.0, lambda h: h["ready"] and h["chat_phraser"] != "llm:loading")
        except RuntimeError as exc:
            return {"available": False, "reason": str(exc), "log": child.log_tail(8)}
        if not health["chat_phraser"].startswith("llm:"):
            return {"available": False, "reason": f"phraser is {health['chat_phraser']}", "log": child.log_tail(8)}
        load_s = time.perf_counter() - t0
        process = psutil.Process(child.pid)
        cpu_before = sum(process.cpu_times()[:2])
        out = chat_latency(url, 1 if quick else 3)
        cpu_s = sum(process.cpu_times()[:2]) - cpu_before  # the UI process's own CPU time, whatever else runs
        return {"available": True, "model": health["chat_phraser"].removeprefix("llm:"), "load_s": load_s,
                "cpu_s_per_answer": cpu_s / out["questions"], **out}  # fmt: skip
    finally:
        child.stop()


def render_api(r: dict) -> str:
    """The BENCHMARKS.md section."""
    m, sp, sc, ct = r["machine"], r["state_paced"], r["state_closed_loop"], r["chat_template"]
    cl = r.get("chat_llm") or {"available": False, "reason": "not run (--no-llm)"}
    lines = [
        "## API (`lcmesh bench api --json runs/bench/api.json --markdown BENCHMARKS.md`)",
        "",
        f"Machine: {m['cpu']}, {m['logical_cpus']} logical CPUs (shared with the mesh under test); Python "
        f"{m['python']}; commit {m['commit']}; {m['date']}. Real processes on loopback: router, configuration, sensor, "
        f"control, monitor and the UI agent (uvicorn, h11), lcopt-5 at {r['speed_factor']:g}x. Load average "
        f"{r['load_avg_1min_start']:.1f} at the start, {r['load_avg_1min_end']:.1f} at the end (other work on the same "
        f"2 cores; the mesh ran at niceness {r['niceness']})." + (" Quick run." if r["quick"] else ""),
        "",
        "| figure | measured | target |",
        "|---|---|---|",
        f"| `GET /api/state`, {sp['clients']} clients each polling every 100 ms: p50 / p99 / max | "
        f"{sp['p50_ms']:.1f} / {sp['p99_ms']:.1f} / {sp['max_ms']:.1f} ms ({sp['throughput_rps']:.0f} req/s, "
        f"{sp['errors']} errors) | p99 <= {r['targets']['state_p99_ms']:g} ms |",
        f"| `GET /api/state`, {sc['clients']} clients in a closed loop: p50 / p99, throughput | "
        f"{sc['p50_ms']:.1f} / {sc['p99_ms']:.1f} ms, {sc['throughput_rps']:.0f} req/s | (saturation) |",
        f"| chat, template mode, {ct['questions']} questions over {len(ct['per_intent'])} intents: p50 / max | "
        f"{ct['p50_s'] * 1e3:.0f} / {ct['max_s'] * 1e3:.0f} ms | <= {r['targets']['chat_template_s'] * 1e3:.0f} ms |",
    ]
    if cl.get("available"):
        used = cl["phrased_by"].get("llm", 0)
        lines.append(f"| chat, LLM mode ({cl['model']}, this CPU), {cl['questions']} questions: p50 / p99 | "
                     f"{cl['p50_s']:.2f} / {cl['p99_s']:.2f} s ({used} LLM texts kept, "
                     f"{cl['questions'] - used} fell back to the template; {cl['cpu_s_per_answer']:.1f} CPU s per "
                     f"answer in the UI process; model load {cl['load_s']:.0f} s) | "
                     f"<= {r['targets']['chat_llm_s']:g} s |")  # fmt: skip
    else:
        lines.append(f"| chat, LLM mode | not measured: {cl.get('reason', '?')} | <= {r['targets']['chat_llm_s']:g} s |")
    lines += ["", "Per intent, template mode (median / max ms): " + ", ".join(
        f"{k} {v['median_s'] * 1e3:.0f} / {v['max_s'] * 1e3:.0f}" for k, v in ct["per_intent"].items()) + "."]
    return "\n".join(lines)


__all__ = ["run_bench_api", "render_api", "state_load", "chat_latency"]


def run_live_planner(n_questions: int = 40, *, controller: str | None = None, speed_factor: float | None = None,
                     hold_minutes: float = 0.0, explainer: str | None = None,
                     say: Callable[[str], None] = print) -> dict:  # fmt: skip
    """The demo mesh as `lcmesh demo` runs it (default speed and controller, the UI's default planner: the local
    LLM), real processes on loopback; ``n_questions`` of the chat benchmark's test split asked through
    ``POST /api/chat`` one after another. Who planned each answer (the ``planned_by`` of the reply) and its
    latency; the mesh keeps running its agents meanwhile (that is the point). ``explainer = "llm"``: the Control
    agent's explanations by the LLM (``LCMESH_CONTROL__EXPLAINER``), and its count of who wrote them."""
    from lcmesh.bench.chat import load_questions

    root = Path(tempfile.mkdtemp(prefix="lcmesh-live-planner-"))
    router, ui_port = free_port(), free_port()
    endpoint = f"tcp/127.0.0.1:{router}"
    defaults = MeshSettings()
    settings = MeshSettings(site="liveplan", router_endpoints=[endpoint], listen_endpoints=[endpoint],
                            data_dir=root, ui_port=ui_port, connect_timeout_s=60.0,
                            **({"controller": controller} if controller else {}),
                            **({"speed_factor": speed_factor} if speed_factor else {}))  # fmt: skip
    token = secrets.token_urlsafe(24)
    demo = Demo(settings, say=lambda _line: None)
    demo.env.update({"LCMESH_API_TOKEN": token, "LCMESH_UI_CHAT_RATE_PER_MIN": "100000",
                     "LCMESH_UI_CHAT_BURST": "100000", **({"LCMESH_CONTROL__EXPLAINER": explainer} if explainer else {})})  # fmt: skip
    url = f"http://127.0.0.1:{ui_port}"
    questions = [q for q in load_questions("test") if not q.refuse][:n_questions]
    result: dict = {"machine": machine_info(), "speed_factor": settings.speed_factor, "controller": settings.controller,
                    "explainer": explainer or settings.control.explainer,
                    "defaults": {"speed_factor": defaults.speed_factor, "controller": defaults.controller},
                    "load_avg_1min_start": os.getloadavg()[0]}  # fmt: skip
    rows = []
    try:
        from lcmesh.mesh.demo import prepare_llm

        prepare_llm(say)
        say("starting the demo mesh ...")
        demo.start()
        _wait_ready(url, 180.0)
        say("waiting for the planner model to load ...")
        _wait_ready(url, 300.0, lambda h: h["ready"])
        time.sleep(10.0)  # the planner loads in the background on the UI's start: give it its load time
        with httpx.Client(base_url=url, timeout=120.0) as http:
            for i, q in enumerate(questions):
                say(f"question {i + 1}/{len(questions)}")
                t0 = time.perf_counter()
                r = http.post("/api/chat", json={"message": q.question})
                seconds = time.perf_counter() - t0
                body = r.json() if r.headers.get("content-type", "").startswith("application/json") else {}
                rows.append({"id": q.id, "lang": q.lang, "status": r.status_code, "seconds": seconds,
                             "planned_by": str(body.get("planned_by", "?")), "note": body.get("plan_note")})  # fmt: skip
            until = time.monotonic() + hold_minutes * 60.0  # the mesh runs on, for the controller's own count
            while time.monotonic() < until:
                say(f"holding the mesh: {max(0.0, until - time.monotonic()) / 60.0:.1f} min left")
                time.sleep(min(10.0, max(0.0, until - time.monotonic())))
            state = http.get("/api/state").json()  # who decided the controller's actions meanwhile
            result["controller_state"] = state.get("controller")
            result["plant_steps"] = state.get("step")
    finally:
        result["load_avg_1min_end"] = os.getloadavg()[0]
        demo.stop()
        shutil.rmtree(root, ignore_errors=True)
    secs = [r["seconds"] for r in rows]
    by = {}
    for r in rows:
        key = r["planned_by"].split(":")[0]
        by[key] = by.get(key, 0) + 1
    result.update({"questions": len(rows), "planned_by": by, "llm_share": by.get("llm", 0) / max(len(rows), 1),
                   "p50_s": float(np.percentile(secs, 50)) if secs else None,
                   "p99_s": float(np.percentile(secs, 99)) if secs else None, "rows": rows})  # fmt: skip
    return result


def render_live_planner(r: dict) -> str:
    m = r["machine"]
    return "\n".join([
        f"## Chat planner in the running demo (`lcmesh bench chat --live {r['questions']} --json "
        "runs/bench/chat-live.json --markdown BENCHMARKS.md`)", "",
        f"Machine: {m['cpu']}, {m['logical_cpus']} logical CPUs; commit {m['commit']}; {m['date']}. The demo mesh as "
        f"`lcmesh demo` starts it (lcopt-5 at {r['speed_factor']:g}x, controller {r['controller']}, explanations by "
        f"the {r.get('explainer', 'renderer')}; the defaults are "
        f"{r['defaults']['speed_factor']:g}x and {r['defaults']['controller']}), real processes on loopback; "
        f"{r['questions']} questions of the chat benchmark's test split (refusals left out) through `POST /api/chat`, "
        f"one after another while the agents run. Load average {r['load_avg_1min_start']:.1f} at the start, "
        f"{r['load_avg_1min_end']:.1f} at the end.", "",
        "| figure | measured | target |", "|---|---|---|",
        f"| answers planned by the LLM | {100 * r['llm_share']:.0f} % ({r['planned_by']}) | >= 95 % |",
        f"| answer latency p50 / p99 | {r['p50_s']:.2f} / {r['p99_s']:.2f} s | p99 <= 2 s (issue 34) |",
        *_decided_rows(r), *_explained_rows(r),
    ])  # fmt: skip


def _explained_rows(r: dict) -> list[str]:
    """The Control agent's count of who wrote its explanations, with the LLM explaining."""
    wrote = (r.get("controller_state") or {}).get("explained_by")
    if not wrote:
        return []
    n = max(wrote["explanations"], 1)
    return [f"| {wrote['level']} explanations published with a verified what-if claim the rendering lacks, within "
            f"{wrote['target_s']:g} s (the Control agent's count; slowest {wrote['llm_explain_s_max']:.2f} s) | "
            f"{wrote['llm_texts_in_target']} of {wrote['explanations']} ({100 * wrote['llm_texts_in_target'] / n:.0f} %; "
            f"{wrote['summary']}). Of all {wrote.get('decisions', r.get('plant_steps'))} decisions' explanations, "
            f"{wrote['llm_texts']} ({100 * wrote['llm_texts'] / max(wrote.get('decisions', r.get('plant_steps')) or 1, 1):.0f} %) "
            f"carry the LLM's text: at {r['speed_factor']:g}x a step is shorter than an explanation | >= 50 % |"]


def _decided_rows(r: dict) -> list[str]:
    """The controller's own count of who decided, when it is one that falls back (the LLM)."""
    decided = (r.get("controller_state") or {}).get("decided_by")
    if not decided:
        return []
    return [f"| controller decisions made by the LLM, run to step {r.get('plant_steps')} | "
            f"{decided.get('summary') or decided} | >= 99 % at 1x |"]

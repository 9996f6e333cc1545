"""Probe a running `lcmesh demo` as an outsider would (issue 37's findings), and print a markdown table.

    lcmesh demo --data-dir /tmp/probe --ui-port 18000 &      # then, once its UI answers:
    .venv/bin/python docs/scripts/probe_least_privilege.py --url http://127.0.0.1:18000 --data-dir /tmp/probe

Every probe is an HTTP request a local client can send, or a read of /proc for the agents' environments.
The demo is changed by one probe: a guardrail is narrowed (supply_temp_max_k 313.15 -> 312.15) to see a chat
proposal refused after a configuration change.
"""

from __future__ import annotations

import argparse
import json
import subprocess
from datetime import datetime, timezone
from pathlib import Path

import httpx

SECRETS = ("LCMESH_BUS_PASSWORD", "LCMESH_API_TOKEN", "LCMESH_LLM_API_KEY")


def latency_series(http: httpx.Client) -> int:
    return sum(line.startswith("lcmesh_api_request_duration_seconds_count")
               for line in http.get("/metrics").text.splitlines())  # fmt: skip


def made_up_methods(http: httpx.Client) -> str:
    counts = [latency_series(http)]
    for batch in range(2):
        for i in range(50):
            http.request(f"ZZMETHOD{batch}{i}", f"/api/nope{batch}{i}")
        counts.append(latency_series(http))
    return f"latency series {counts[0]} -> {counts[1]} -> {counts[2]} (2 x 50 made-up methods on made-up paths)"


def page_headers(http: httpx.Client) -> str:
    got = []
    for path in ("/", "/static/index.html", "/static/./index.html"):
        h = http.get(path).headers
        got.append(f"{path}: CSP {'yes' if 'content-security-policy' in h else 'no'}, "
                   f"X-Frame-Options {h.get('x-frame-options', 'none')}")  # fmt: skip
    return "; ".join(got)


def spoofed_forwarded_for(http: httpx.Client) -> str:
    codes = [http.post("/api/chat", json={"message": "hottest blade?"},
                       headers={"X-Forwarded-For": f"10.0.0.{i}"}).status_code for i in range(45)]  # fmt: skip
    return f"{codes.count(429)} of 45 chats answered 429 (each with another made-up X-Forwarded-For)"


def agent_environments() -> str:
    out = subprocess.run(["pgrep", "-f", "lcmesh.mesh.agents"], capture_output=True, text=True).stdout.split()
    held = {}
    for pid in out:
        try:
            env = Path(f"/proc/{pid}/environ").read_bytes().split(b"\0")
            argv = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        role = argv[argv.index(b"lcmesh.mesh.agents") + 1].decode() if b"lcmesh.mesh.agents" in argv else pid
        held[role] = sorted(v.split(b"=", 1)[0].decode() for v in env if v.split(b"=", 1)[0].decode() in SECRETS)
    return "; ".join(f"{role}: {', '.join(names) or 'none'}" for role, names in sorted(held.items()))


def aged_proposal(http: httpx.Client, token: str) -> str:
    auth = {"Authorization": f"Bearer {token}"}
    version = http.get("/api/config").json()["version"]
    made = datetime.now(timezone.utc).isoformat()
    body = {"supply_temp_setpoint_c": [30.0] * 5, "reason": "probe",
            "proposal": {"config_version": version, "made_at": made}}  # fmt: skip
    change = http.put("/api/config", headers=auth, json={"changes": {"guardrails": {"supply_temp_max_k": 312.15}},
                                                         "reason": "probe: a config change"})  # fmt: skip
    refused = http.post("/api/control/setpoints", headers=auth, json=body)
    old = {**body, "proposal": {"config_version": change.json()["version"], "made_at": "2020-01-01T00:00:00+00:00"}}
    aged = http.post("/api/control/setpoints", headers=auth, json=old)
    nan = http.post("/api/control/setpoints", headers=auth,
                    content=json.dumps({**body, "supply_temp_setpoint_c": [float("nan")] * 5}))  # fmt: skip
    return (f"after a config change: {refused.status_code}; a proposal from 2020: {aged.status_code}; "
            f"NaN setpoints: {nan.status_code}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--url", default="http://127.0.0.1:8000")
    ap.add_argument("--data-dir", type=Path, default=Path("runs/mesh"))
    args = ap.parse_args()
    token = (args.data_dir / "ui" / "api-token").read_text().strip()
    with httpx.Client(base_url=args.url, timeout=30.0) as http:
        rows = [("made-up HTTP methods", made_up_methods(http)), ("the page's headers", page_headers(http)),
                ("spoofed X-Forwarded-For", spoofed_forwarded_for(http)),
                ("secret variables in each agent's environment", agent_environments()),
                ("an aged chat proposal, NaN", aged_proposal(http, token))]  # fmt: skip
    print("| probe | result |\n|---|---|")
    for name, result in rows:
        print(f"| {name} | {result} |")


if __name__ == "__main__":
    main()

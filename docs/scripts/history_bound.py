"""Run ``lcmesh demo`` for a number of plant steps and record the history file's size as it grows.

Run from the repository root, e.g. 24 plant hours (5,760 steps of 15 s) at 600x under a 50 MB bound:

    python docs/scripts/history_bound.py --steps 5760 --speed-factor 600 --max-mb 50 --out runs/history-bound

It starts the demo (its own data folder and ports) with ``LCMESH_HISTORY__MAX_MB``, samples the
newest step and the size of history.sqlite and its -wal twice a second (read-only, like the UI),
stops the demo with SIGINT once the run reaches ``--steps`` and writes ``sizes.csv`` next to the
history. It prints the largest size seen, the bound, the bytes a step adds to the main file
before pruning starts, how late the kept steps were applied and how long retention passes took.
"""

from __future__ import annotations

import argparse
import csv
import os
import re
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path


def sample(history: Path) -> tuple[int | None, int, int]:
    """(newest step, main file bytes, -wal bytes); step None while the file or its tables are missing."""
    sizes = [p.stat().st_size if p.exists() else 0 for p in (history, history.with_name(history.name + "-wal"))]
    if not history.exists():
        return None, *sizes
    try:
        with sqlite3.connect(f"file:{history}?mode=ro", uri=True, timeout=1.0) as conn:
            step = conn.execute("SELECT MAX(step) FROM plant_states").fetchone()[0]
    except sqlite3.Error:
        step = None
    return step, *sizes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=5760, help="stop after this many plant steps (5760: 24 h)")
    parser.add_argument("--speed-factor", type=float, default=600.0)
    parser.add_argument("--max-mb", type=float, default=50.0, help="LCMESH_HISTORY__MAX_MB")
    parser.add_argument("--out", type=Path, default=Path("runs/history-bound"), help="the demo's data folder")
    parser.add_argument("--port", type=int, default=17471, help="router port")
    parser.add_argument("--ui-port", type=int, default=18471)
    parser.add_argument("--per-step-window", type=int, default=1500, help="steps 100..N measure bytes per step")
    args = parser.parse_args()

    history = args.out / "history.sqlite"
    env = {**os.environ, "LCMESH_HISTORY__MAX_MB": str(args.max_mb), "LCMESH_LOG_LEVEL": "INFO"}
    demo = subprocess.Popen(
        [str(Path(sys.executable).with_name("lcmesh")), "demo", "--speed-factor", str(args.speed_factor), "--port",
         str(args.port), "--ui-port", str(args.ui_port), "--data-dir", str(args.out)],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    rows, start, first = [], time.monotonic(), None
    try:
        while demo.poll() is None:
            step, db, wal = sample(history)
            rows.append((round(time.monotonic() - start, 2), step, db, wal))
            if step is not None and first is None:
                first = (step, db + wal)
            if step is not None and step >= args.steps:
                break
            time.sleep(0.5)
    finally:
        demo.send_signal(signal.SIGINT)
        demo.wait(timeout=60)
    args.out.mkdir(parents=True, exist_ok=True)
    with open(args.out / "sizes.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(("wall_s", "step", "history_bytes", "wal_bytes"))
        writer.writerows(rows)

    stepped = [r for r in rows if r[1] is not None]
    largest = max(stepped, key=lambda r: r[2] + r[3])
    # after ~100 steps the -wal has settled; below half the bound nothing is pruned yet
    early = [r for r in stepped if 100 <= r[1] <= args.per_step_window and r[2] < args.max_mb * 1e6 / 2]
    per_step = (early[-1][2] - early[0][2]) / max(1, early[-1][1] - early[0][1])
    with sqlite3.connect(f"file:{history}?mode=ro", uri=True) as conn:
        kept = conn.execute("SELECT MIN(step), MAX(step), COUNT(*) FROM plant_states").fetchone()
        late = [r[0] for r in conn.execute("SELECT late_ms FROM actions ORDER BY late_ms")]
    wall_s = stepped[-1][0] - stepped[0][0]
    print(f"steps {stepped[-1][1]} in {wall_s:.0f} s wall ({stepped[-1][1] * 15 / max(wall_s, 1e-9):.0f}x); "
          f"bound {args.max_mb * 1e6:,.0f} B")
    print(f"largest history + wal: {largest[2] + largest[3]:,} B (history {largest[2]:,}, wal {largest[3]:,}) at step "
          f"{largest[1]}; last: {stepped[-1][2] + stepped[-1][3]:,} B")
    print(f"bytes per step before pruning (steps {early[0][1]}..{early[-1][1]}): {per_step:,.0f}")
    print(f"states kept: steps {kept[0]}..{kept[1]} ({kept[2]} rows); applied late, p50/p99/max ms: "
          f"{late[len(late) // 2]:.0f}/{late[int(len(late) * 0.99)]:.0f}/{late[-1]:.0f}")
    sensor_log = (args.out / "logs" / "sensor.log").read_text(errors="replace")
    passes = [tuple(map(float, m)) for m in re.findall(r"pass ms median ([\d.]+) max ([\d.]+)", sensor_log)]
    if passes:
        medians = sorted(p[0] for p in passes)
        print(f"retention passes (the Sensor's INFO lines): median {medians[len(medians) // 2]:.1f} ms, "
              f"slowest {max(p[1] for p in passes):.1f} ms")


if __name__ == "__main__":
    main()

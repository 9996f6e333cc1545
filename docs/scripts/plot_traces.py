"""Plot the Frontier day as the twin sees it: cabinet loads, one cabinet's branch shares, wet bulb.

Run from the repository root: ``python docs/scripts/plot_traces.py`` (writes docs/img/traces.png;
with lc-mesh not installed, prefix ``PYTHONPATH=.``).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from lcmesh.twin.system import load_system  # noqa: E402
from lcmesh.twin.traces import FRONTIER_DAY, load_trace  # noqa: E402

OUTPUT = Path(__file__).parents[1] / "img" / "traces.png"
CABINET = 4  # 0-based: cabinet 5, whose branches follow power[13..15], the day's low column among them


def main() -> None:
    system = load_system("frontier-full")
    trace = load_trace(FRONTIER_DAY, system)
    lcopt = load_trace(FRONTIER_DAY, system, scenario="lcopt")
    design = load_trace(FRONTIER_DAY, system, scenario="design-day")
    hour = np.arange(trace.n_steps) * trace.step_s / 3600.0
    shares = trace.branch_shares(np.arange(trace.n_steps))[:, CABINET]
    lcopt_shares = lcopt.branch_shares(np.arange(trace.n_steps))[:, CABINET]

    fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True, constrained_layout=True)
    axes[0].plot(hour, trace.cabinet_load_w / 1e3, lw=0.4, alpha=0.5)
    axes[0].plot(hour, trace.cabinet_load_w.mean(axis=1) / 1e3, color="k", lw=1.2, label="mean of 25 cabinets")
    axes[0].set_ylabel("cabinet load (kW)")
    axes[0].legend(loc="upper right")
    axes[0].set_title(f"{FRONTIER_DAY} on {system.name} (design_heat_w = {system.cabinets.design_heat_w / 1e3:.0f} kW)")

    for b in range(trace.branches):
        line = axes[1].plot(hour, shares[:, b], lw=1.2, label=f"branch {b + 1} (data)")[0]
        axes[1].plot(hour, lcopt_shares[:, b], lw=0.6, ls=":", color=line.get_color(), label=f"branch {b + 1} (lcopt)")
    axes[1].set_ylabel(f"cabinet {CABINET + 1} branch share")
    axes[1].set_ylim(0, 0.9)
    axes[1].legend(loc="upper right", ncol=trace.branches, fontsize=7)

    axes[2].plot(hour, trace.wet_bulb_k - 273.15, color="tab:blue", label="wet bulb (data)")
    axes[2].plot(hour, design.wet_bulb_k - 273.15, color="tab:red", label="design day (Knoxville 0.4 %)")
    axes[2].plot(hour, lcopt.wet_bulb_k - 273.15, color="tab:blue", ls="--", label="+15 K (lcopt scenario)")
    axes[2].set_ylabel("wet bulb (°C)")
    axes[2].set_xlabel("hour of 2024-04-07")
    axes[2].set_xlim(0, 24)
    axes[2].set_xticks(range(0, 25, 3))
    axes[2].legend(loc="upper left")

    OUTPUT.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(OUTPUT, dpi=110)


if __name__ == "__main__":
    main()

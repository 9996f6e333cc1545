"""Write the reference system descriptions (lcmesh/twin/systems/*.json), sized for the Frontier day's real loads.

Every CDU-cabinet pair carries one CDU column of the trace unscaled (mean 650 kW, 99th percentile 1.06 MW),
so the per-CDU parts (pumps, heat exchanger, primary valve, blade groups) are the schema defaults
(lcmesh/twin/system.py, sized in docs/twin.md "Sizing for the real loads"). What scales with the number of
cabinets C is the plant behind them: tower cells, their water and fans, the plate heat exchangers, the
hot-water (HTW) loop's volumes, header resistance and pumps. Run from the repository root:

    python docs/scripts/make_reference_systems.py
"""

import json
from pathlib import Path

CDU_DESIGN_W = 1.07e6  # per CDU: the day's 99th percentile CDU load, rounded (docs/twin.md)
CELL_DESIGN_W = 25 * CDU_DESIGN_W / 20  # Frontier's 20 cells share the site's design load
TOWER_WATER_PER_CDU_KG_S = 40.0  # tower-loop water per CDU of load (docs/twin.md)
FAN_PER_CELL_W = 37.3e3  # ORNL's cooling-tower library cell, at CELL_DESIGN_W
EHX_UA_PER_TRAIN_W_K = 4.04e6  # ORNL's plate heat exchanger, one train of Frontier's four
FRONTIER_CDUS = 25
RACK_COOLANT_M3 = 0.083  # ORNL's cabinet cooling channels; a CDU-cabinet pair here is the 3 racks behind a CDU


def system(name: str, C: int, N: int, m: int, groups_per_branch: int = 1, desc: str = "") -> dict:
    share = C / FRONTIER_CDUS
    cell_heat = C * CDU_DESIGN_W / (N * m)
    cell_scale = cell_heat / CELL_DESIGN_W
    return {
        "schema_version": 1,
        "name": name,
        "description": desc,
        "step_s": 15.0,
        "substeps": 15,
        "cabinets": {"count": C, "branches": 3, "blade_groups_per_branch": groups_per_branch,
                     "coolant_volume_m3": RACK_COOLANT_M3 * 3},
        "towers": {
            "count": N,
            "cells": m,
            "cell": {
                "design_heat_w": round(cell_heat, -3),
                "water_flow_kg_s": round(TOWER_WATER_PER_CDU_KG_S * C / (N * m), 2),
                "fan_power_nominal_w": round(FAN_PER_CELL_W * cell_scale, -2),
            },
            "ehx_ua_w_per_k": round(EHX_UA_PER_TRAIN_W_K * share * 4 / N, -3),
            "basin_volume_m3": round(110 * share / N, 2),
        },
        "htw": {
            "supply_volume_m3": round(100 * share, 2),
            "return_volume_m3": round(125 * share, 2),
            "r_header_pa_per_kg_s": round(2000 / FRONTIER_CDUS / share, 2),
            "pump": {"head_m": [72.0, 37.8], "flow_m3_s": [0.003, 0.477], "efficiency": 0.835,
                     "n_parallel": max(1, round(4 * share)), "speed_min": 0.3, "speed_max": 1.2},
        },
        "heat_recovery": None,
    }


def paper_system() -> dict:
    """lcopt-5 as it was before the real-load sizing: LC-Opt's scaled units, for the `lcopt` scenario.

    The shipped PPO policies, trees and LLM controller were trained on this plant; every schema default
    that has since changed is written out, so the plant stays what it was.
    """
    desc = system("lcopt-5-paper", 5, 2, 2, desc="LC-Opt Table 3 at the paper's scale: lcopt-5 as it was before"
                  " the real-load sizing (loads scaled to 225 kW per cabinet), for the lcopt scenario and the"
                  " policies trained under it")
    desc["cabinets"] = {
        "count": 5, "branches": 3, "blade_groups_per_branch": 1, "design_heat_w": 225e3, "coolant_volume_m3": 0.083,
        "blade_group": {"heat_unit_w": 20e3},
        "cdu": {"hx_ua_sat_w_per_k": 73.9e3, "r_hx_secondary_pa_per_kg_s": 11_000.0,
                "r_cabinet_pa_per_kg_s": 11_000.0, "primary_flow_max_kg_s": 15.0},
    }
    desc["towers"].update({
        "cell": {"design_heat_w": 449e3, "water_flow_kg_s": 75.5, "fan_power_nominal_w": 98.4e3},
        "ehx_ua_w_per_k": 4.849e6, "stage_down_speed": 0.08,
    })
    desc["htw"]["r_header_pa_per_kg_s"] = 80.0
    return desc


def main() -> None:
    out = {
        "lcopt-5": system("lcopt-5", 5, 2, 2, desc="LC-Opt Table 3 topology: N=2 towers, m=2 cells, C=5 cabinets, B=3 blade groups; real CDU loads"),
        "lcopt-10": system("lcopt-10", 10, 2, 2, desc="LC-Opt Table 4: N=2, m=2, C=10, B=3; real CDU loads"),
        "lcopt-15": system("lcopt-15", 15, 2, 2, desc="LC-Opt Table 4: N=2, m=2, C=15, B=3; real CDU loads"),
        "lcopt-20": system("lcopt-20", 20, 3, 2, desc="LC-Opt Table 4: N=3, m=2, C=20, B=3; real CDU loads"),
        "lcopt-25": system("lcopt-25", 25, 4, 2, desc="LC-Opt Table 4: N=4, m=2, C=25, B=3; real CDU loads"),
        "frontier-full": system(
            "frontier-full", 25, 4, 5, groups_per_branch=133,
            desc="Frontier-scale: 25 CDU-cabinet pairs (each the 3 racks behind one CDU), 3 branches each,"
            " 133 blade groups per branch (9,975 blade groups), 4 towers of 5 cells; real CDU loads",
        ),
    }
    hru = dict(out["lcopt-5"], name="lcopt-5-hru", description="lcopt-5 with the heat-recovery unit (LC-Opt Section 7.3)")
    hru["heat_recovery"] = {"ua_w_per_k": 150e3, "district_flow_kg_s": 20.0, "district_supply_temp_k": 293.15}
    out["lcopt-5-hru"] = hru
    out["lcopt-5-paper"] = paper_system()
    folder = Path("lcmesh/twin/systems")
    for name, desc in out.items():
        (folder / f"{name}.json").write_text(json.dumps(desc, indent=2) + "\n")


if __name__ == "__main__":
    main()

import json
base_cell_heat = 1.1e6 * 250 / 650 * 1.15 / 1.3
def system(name, C, N, m, bgpb=1, desc=""):
    share = C / 25
    load = C * 250e3 * 1.15  # mean trace load with the non-linear heat term
    cell_heat = load / (N * m) * 1.25
    scale = cell_heat / base_cell_heat
    return {
        "schema_version": 1,
        "name": name,
        "description": desc,
        "step_s": 15.0,
        "substeps": 15,
        "cabinets": {"count": C, "branches": 3, "blade_groups_per_branch": bgpb},
        "towers": {
            "count": N, "cells": m,
            "cell": {"design_heat_w": round(cell_heat, -3),
                     "water_flow_kg_s": round(62.9 * scale, 2),
                     "fan_power_nominal_w": round(82e3 * scale, -2)},
            "ehx_ua_w_per_k": round(4.04e6 * max(scale, 0.25), -3),
            "basin_volume_m3": round(110 * share / N, 2),
        },
        "htw": {"supply_volume_m3": round(100 * share, 2), "return_volume_m3": round(125 * share, 2),
                "pump": {"head_m": [72.0, 37.8], "flow_m3_s": [0.003, 0.477], "efficiency": 0.835,
                         "n_parallel": max(1, round(4 * share)), "speed_min": 0.3, "speed_max": 1.2}},
        "heat_recovery": None,
    }
out = {
 "lcopt-5": system("lcopt-5", 5, 2, 2, desc="LC-Opt Table 3: N=2 towers, m=2 cells, C=5 cabinets, B=3 blade groups"),
 "lcopt-10": system("lcopt-10", 10, 2, 2, desc="LC-Opt Table 4: N=2, m=2, C=10, B=3"),
 "lcopt-15": system("lcopt-15", 15, 2, 2, desc="LC-Opt Table 4: N=2, m=2, C=15, B=3"),
 "lcopt-20": system("lcopt-20", 20, 3, 2, desc="LC-Opt Table 4: N=3, m=2, C=20, B=3"),
 "lcopt-25": system("lcopt-25", 25, 4, 2, desc="LC-Opt Table 4: N=4, m=2, C=25, B=3"),
 "frontier-full": system("frontier-full", 25, 4, 5, bgpb=133,
     desc="Frontier-scale: 25 CDU-cabinet pairs (each the 3 racks behind one CDU), 3 branches each, 133 blade groups per branch (9,975 blade groups), 4 towers of 5 cells"),
}
hr = dict(out["lcopt-5"]); hr["name"] = "lcopt-5-hru"; hr["description"] = "lcopt-5 with the heat-recovery unit (LC-Opt Section 7.3)"
hr["heat_recovery"] = {"ua_w_per_k": 150e3, "district_flow_kg_s": 20.0, "district_supply_temp_k": 293.15}
out["lcopt-5-hru"] = hr
for k, v in out.items():
    json.dump(v, open(f"lcmesh/twin/systems/{k}.json", "w"), indent=2)

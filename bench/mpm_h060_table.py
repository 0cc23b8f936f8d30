#!/usr/bin/env python3
"""The H0 = 0.06 m MPM columns' convergence rows (docs/RESULTS.md, session
35): for each run directory given, its status, time at rest (t/t_ref),
0.5 % mass runout, pile edge at the end, fronts at 1 / 2 / 4 t_ref, the
liquid front at the end and wall time, as a Markdown table.

usage: python3 bench/mpm_h060_table.py LABEL=RUN_DIR [LABEL=RUN_DIR ...]
"""
import json, sys

print("| run | status, t/t_ref | runout (0.5 %) | pile edge | front 1 / 2 / 4 t_ref | liquid front | wall s |")
print("|---|---|---|---|---|---|---|")
for arg in sys.argv[1:]:
    label, run = arg.split("=", 1)
    s = json.load(open(f"{run}/summary.json"))
    end = s["sim_time"] / s["t_ref"]

    def at(front, t):
        later = [f for f in front if f["t_norm"] >= t]
        return f"{later[0]['x_norm']:.2f}" if later and t <= end + 1e-9 else "–"

    fronts = " / ".join(at(s["front"], t) for t in (1, 2, 4))
    liquid = s.get("liquid_front") or []
    liquid = f"{liquid[-1]['x_norm']:.2f}" if liquid else "–"
    print(f"| {label} | {s['status']}, {end:.2f} | {s['runout']:.3f} | {s['runout_pile']:.2f} | {fronts} | {liquid} | {s['wall_seconds']:.1f} |")

#!/usr/bin/env python3
"""Both methods on one edge (docs/RESULTS.md, "The MPM with rate-dependent
friction, and both methods on one edge"): for each Table 1 case the pile
edge (`front_pile`, the DEM's rule: where the solid's width-averaged
height falls below one grain) at t/t_ref = 1, 2, 4 and at the end, of
the DEM(-LBM) and of one or more MPM sets, and each set's ratio to the
DEM(-LBM) at 2 t_ref and at the end. MPM summaries need `front_pile`
(written since session 32).

usage: python3 bench/pile_table.py DEM_DIR MPM_DIR LABEL [MPM_DIR LABEL ...]
  DEM_DIR/{dry,sat}_hNNN.json  (e.g. docs/results/ceccato2020/summaries)
  MPM_DIR/mpm_{dry,sat}_hNNN/summary.json  (bash bench/mpm_cases.sh MPM_DIR ...)
"""
import json, sys


def at(front, t):
    return min(front, key=lambda f: abs(f["t_norm"] - t))["x_norm"]


def pile(s):
    return [at(s["front_pile"], 1), at(s["front_pile"], 2), at(s["front_pile"], 4), s["runout_pile"]]


dem_dir, rest = sys.argv[1], sys.argv[2:]
sets = [(rest[i], rest[i + 1]) for i in range(0, len(rest), 2)]
print("| case | a | DEM(–LBM): pile edge at 1 / 2 / 4 t_ref, end |" + "".join(f" MPM {lab} |" for _, lab in sets)
      + "".join(f" {lab} / DEM at 2 t_ref, end |" for _, lab in sets))
print("|" + "---|" * (3 + 2 * len(sets)))
for kind in ("dry", "sat"):
    for h, a in (("030", 0.75), ("040", 1.0), ("050", 1.25), ("060", 1.5), ("070", 1.75)):
        case = f"{kind}_h{h}"
        d = pile(json.load(open(f"{dem_dir}/{case}.json")))
        row, ratios = f"| {case} | {a:.2f} | " + " / ".join(f"{v:.2f}" for v in d) + " |", ""
        for mpm_dir, _ in sets:
            m = pile(json.load(open(f"{mpm_dir}/mpm_{case}/summary.json")))
            row += " " + " / ".join(f"{v:.2f}" for v in m) + " |"
            ratios += f" {m[1] / d[1]:.2f}, {m[3] / d[3]:.2f} |"
        print(row + ratios)

#!/usr/bin/env python3
"""Both methods side by side (issue 20 part 5, docs/RESULTS.md "MPM beside
DEM-LBM"): for each Table 1 case, the MPM's runout by the 0.5 % mass front
and by the pile edge (`runout_pile`, the DEM's rule; for summaries
before session 32 the first deposit column lower than one grain), the liquid front at t/t_ref = 2 and at
the end, with the t/t_ref the MPM's run ended at (the DEM-LBM's end at
8.5 t_ref; since session 46 the Table 1 campaign runs the saturated MPM
columns to 8.5 t_ref too, before it they stopped when the grains rested,
3.6-4.3 t_ref, while the water drains on), and the mass front at t/t_ref = 1, 2, 4, against the DEM(-LBM)'s
from its runs (mean over the seeds found). Marks '*' where the pile
edges differ by more than 20 %.

usage: python3 bench/methods_table.py MPM_DIR DEM_SAT_DIR DEM_DRY_DIR
  MPM_DIR/mpm_{dry,sat}_hNNN/summary.json   (bash bench/mpm_cases.sh MPM_DIR)
  DEM_SAT_DIR/sat_hNNN/seed*/summary.json  (bash bench/seeds.sh DIR sat)
  DEM_DRY_DIR/dry_hNNN/summary.json or .../dry_hNNN/seed*/summary.json
  or either as DIR/{dry,sat}_hNNN.json (docs/results/ceccato2020/summaries)
"""
import glob, json, os, sys

D = 2.5e-3


def load(pattern):
    return [json.load(open(p)) for p in sorted(glob.glob(pattern))]


def at(front, t):
    return min(front, key=lambda f: abs(f["t_norm"] - t))["x_norm"] if front else float("nan")


def mpm_pile_edge(s):
    # The DEM's rule, in the summary since session 32; before, the first
    # element-wide deposit column whose highest point lies below one grain.
    if s.get("runout_pile") is not None:
        return s["runout_pile"]
    dep = s["deposit"]
    step = dep[1][0] - dep[0][0]
    x = next((x - step / 2 for x, h in dep if h < D), dep[-1][0] + step / 2)
    return (x - 0.04) / 0.04


def mean(xs):
    xs = [x for x in xs if x == x]
    return sum(xs) / len(xs) if xs else float("nan")


mpm_dir, sat_dir, dry_dir = sys.argv[1:4]
print("| case | a | MPM runout | DEM(-LBM) runout | MPM pile edge | DEM(-LBM) pile edge | MPM / DEM pile edge | MPM / DEM-LBM liquid front at 2 t_ref | MPM liquid front (end, t/t_ref) | DEM-LBM liquid front (end) | MPM front 1 / 2 / 4 t_ref | DEM(-LBM) front 1 / 2 / 4 t_ref |")
print("|---|---|---|---|---|---|---|---|---|---|---|---|")
for kind in ("dry", "sat"):
    for h in ("030", "040", "050", "060", "070"):
        a = int(h) / 1000 / 0.04
        m = load(f"{mpm_dir}/mpm_{kind}_h{h}/summary.json")
        base = sat_dir if kind == "sat" else dry_dir
        d = (load(f"{base}/{kind}_h{h}/seed*/summary.json") or load(f"{base}/{kind}_h{h}/summary.json")
             or load(f"{base}/{kind}_h{h}.json"))
        if not m or not d:
            print(f"| {kind}_h{h} | {a:.2f} | (missing: {'MPM' if not m else 'DEM'}) |")
            continue
        m = m[0]
        pe_m, pe_d = mpm_pile_edge(m), mean([s.get("runout_pile") or float("nan") for s in d])
        lf_m = m["liquid_front"][-1]["x_norm"] if m.get("liquid_front") else float("nan")
        lf_d = mean([s["liquid_front"][-1]["x_norm"] for s in d if s.get("liquid_front")])
        lf2_m = at(m.get("liquid_front") or [], 2.0)
        lf2_d = mean([at(s["liquid_front"], 2.0) for s in d if s.get("liquid_front")])
        end_m = m["liquid_front"][-1]["t_norm"] if m.get("liquid_front") else float("nan")
        ratio = pe_m / pe_d
        flag = " *" if abs(ratio - 1) > 0.2 else ""
        fm = " / ".join(f"{at(m['front'], t):.2f}" for t in (1, 2, 4))
        fd = " / ".join(f"{mean([at(s['front'], t) for s in d]):.2f}" for t in (1, 2, 4))
        liquid = lambda x: "–" if x != x else f"{x:.2f}"
        print(f"| {kind}_h{h} | {a:.2f} | {m['runout']:.2f} | {mean([s['runout'] for s in d]):.2f} ({len(d)}) | {pe_m:.2f} | {pe_d:.2f} | "
              f"{ratio:.2f}{flag} | {liquid(lf2_m)} / {liquid(lf2_d)} | {liquid(lf_m)}{'' if lf_m != lf_m else f' ({end_m:.1f})'} | {liquid(lf_d)} | {fm} | {fd} |")

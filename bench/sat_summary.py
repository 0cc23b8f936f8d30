#!/usr/bin/env python3
"""Tables for docs/RESULTS.md from `bench/seeds.sh OUT sat` runs: per case
the three seeds' runouts (mean and range) by each front, and the fronts of
every seed at chosen t/t_ref (mean and range), mass, pile edge and liquid.
usage: python3 bench/sat_summary.py [OUT_DIR] [CASES] [SEEDS]"""
import json, os, statistics, sys

out = sys.argv[1] if len(sys.argv) > 1 else "runs/seeds"
cases = (sys.argv[2] if len(sys.argv) > 2 else "030 040 050 060 070").split()
seeds = (sys.argv[3] if len(sys.argv) > 3 else "1 2 3").split()
times = [1, 2, 4, 6, 8]


def stat(values):
    if not values:
        return "–"
    if len(values) == 1:
        return f"{values[0]:.3f} (1 seed)"
    return f"{statistics.mean(values):.3f} ({min(values):.2f}–{max(values):.2f})"


def at(series, t):
    return min(series, key=lambda f: abs(f["t_norm"] - t))["x_norm"]


runs = {}
for h in cases:
    found = []
    for s in seeds:
        path = f"{out}/sat_h{h}/seed{s}/summary.json"
        if os.path.exists(path):
            found.append(json.load(open(path)))
    runs[h] = found

print("| case | seeds | grains | bulk porosity | wall s | runout, mass front | connected | pile edge | liquid mass change |")
print("|---|---|---|---|---|---|---|---|---|")
for h, rs in runs.items():
    if not rs:
        continue
    g = [r["dem"]["particles"] for r in rs]
    p = [r["porosity_initial"] for r in rs]
    w = [r["wall_seconds"] for r in rs]
    dm = [abs(r["lbm"]["mass_final"] / r["lbm"]["mass_initial"] - 1) for r in rs]
    print(f"| sat_h{h} | {len(rs)} | {min(g)}–{max(g)} | {min(p):.3f}–{max(p):.3f} | {min(w):.0f}–{max(w):.0f} | "
          f"{stat([r['runout'] for r in rs])} | {stat([r['runout_connected'] for r in rs])} | "
          f"{stat([r['runout_pile'] for r in rs])} | ≤ {max(dm):.1e} |")

for key, name in [("front", "mass front"), ("front_pile", "pile edge"), ("liquid_front", "liquid front")]:
    print(f"\n{name}, (X_f − L0)/L0 at t/t_ref (mean and range over the seeds):\n")
    print("| case | " + " | ".join(str(t) for t in times) + " |")
    print("|---|" + "---|" * len(times))
    for h, rs in runs.items():
        if rs:
            print(f"| sat_h{h} | " + " | ".join(stat([at(r[key], t) for r in rs]) for t in times) + " |")

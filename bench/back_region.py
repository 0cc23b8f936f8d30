#!/usr/bin/env python3
"""What the grains against the back wall do (docs/RESULTS.md, "The floor
the grains feel, and the solid's momentum in both methods"): for a
DEM(-LBM) column run, the grains that start within 10 mm of the back
wall, at each `/dem/state` record (every 0.05 s by default; grains
followed by id, which the storage-ordered `/dem/particles` cannot do):
how many are still there, their mean x-displacement, and the mean
vertical displacement of those that started in the top third
(z0 > 2/3 H0) and in the bottom third (z0 < H0/3). A dead zone stands
still; a back that flows out sinks at the top.

usage: python3 bench/back_region.py RUN_DIR [RUN_DIR ...]
"""
import json, sys, tomllib
from dem_state import states

BACK = 0.01

for run in sys.argv[1:]:
    t_ref = json.load(open(f"{run}/summary.json"))["t_ref"]
    sc = tomllib.load(open(f"{run}/scene.toml", "rb"))
    x0, z0, h0 = sc["domain"]["min"][0], sc["domain"]["min"][2], sc["analysis"]["column_height"]
    ss = states(run)
    first = {i: p for i, (p, _, _) in ss[0]["by_id"].items()}
    back = [i for i, p in first.items() if p[0] - x0 < BACK]
    top = [i for i in back if first[i][2] - z0 > 2 * h0 / 3]
    bottom = [i for i in back if first[i][2] - z0 < h0 / 3]
    if not (back and top and bottom):
        sys.exit(f"{run}: no grains within {BACK * 1e3:g} mm of the back wall")
    print(f"{run}: {len(back)} grains within {BACK * 1e3:g} mm of the back wall ({len(top)} in the top third, {len(bottom)} in the bottom third)")
    print("| t/t_ref | still there | mean dx (mm) | top third: dx, dz (mm) | bottom third: dz (mm) |")
    print("|---|---|---|---|---|")
    for s in ss[1:]:
        now = s["by_id"]
        mean = lambda sel, k: sum(now[i][0][k] - first[i][k] for i in sel) / len(sel) * 1e3
        still = sum(1 for i in back if now[i][0][0] - x0 < BACK)
        print(f"| {s['time'] / t_ref:.2f} | {still} | {mean(back, 0):.2f} | {mean(top, 0):.2f}, {mean(top, 2):.2f} | {mean(bottom, 2):.2f} |")

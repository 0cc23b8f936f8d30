#!/usr/bin/env python3
"""The DEM floor's friction as a layer of grains feels it, from runs of
scenes/validation/dem_basal_friction.toml under pushes k
(`domain.collapse_gravity` = [k g, 0, -g]). For the body of the layer
(the grains that start between 5 and 15 cm from the back wall, clear of
both ends), the mean x-velocity at 0.1, 0.2, 0.3 and 0.4 s of its bottom
grain layer (centres within 1.2 diameters of the floor), of the layers
above, and of the whole body, and the resistance the body meets while it
moves, k - a/g, a its mean acceleration between the last two records.
Grains followed by id through `/dem/state` (every 0.05 s by default; the
points of `/dem/particles` are in storage order, re-sorted as the run
goes), read until the layer's front nears the far wall.

usage: python3 bench/basal_friction.py RUN_DIR [RUN_DIR ...]
"""
import sys, tomllib
from dem_state import states

TIMES = [0.1, 0.2, 0.3, 0.4]

print("| run | k | floor's rolling friction | bottom layer's x-velocity at " + " / ".join(f"{t:g}" for t in TIMES)
      + " s (m/s) | the layers above | the body | k − a/g at the end |")
print("|---|---|---|---|---|---|---|")
for run in sys.argv[1:]:
    scene = tomllib.load(open(f"{run}/scene.toml", "rb"))
    dom = scene["domain"]
    g = -dom["gravity"][2]
    k = dom.get("collapse_gravity", dom["gravity"])[0] / g
    d = scene["particles"][0]["diameter"]
    x0, z0, far = dom["min"][0], dom["min"][2], dom["max"][0] - 2 * d
    ss = states(run)
    body = [i for i, (p, _, _) in ss[0]["by_id"].items() if 0.05 <= p[0] - x0 <= 0.15]
    rows = []
    for s in ss:
        grains = s["by_id"]
        if max(p[0] for p, _, _ in grains.values()) >= far:
            break
        mean = lambda sel: sum(grains[i][1][0] for i in sel) / max(len(sel), 1)
        bottom = [i for i in body if grains[i][0][2] - z0 < 1.2 * d]
        above = [i for i in body if grains[i][0][2] - z0 >= 1.2 * d]
        rows.append((s["time"], mean(bottom), mean(above), mean(body)))

    def at(t, col):
        r = min(rows, key=lambda r: abs(r[0] - t))
        return f"{r[col]:.4f}" if abs(r[0] - t) < 0.01 else "–"

    (ta, *_, va), (tb, *_, vb) = rows[-2], rows[-1]
    resistance = k - (vb - va) / (tb - ta) / g
    mu_r = scene["dem"]["wall_rolling_friction"]
    print(f"| {run} | {k:.3f} | {mu_r:g} | " + " / ".join(at(t, 1) for t in TIMES) + " | "
          + " / ".join(at(t, 2) for t in TIMES) + " | " + " / ".join(at(t, 3) for t in TIMES) + f" | {resistance:.3f} |")

#!/usr/bin/env python3
"""Grid refinement of the MPM columns, case by case (issue 20; runs of
bench/mpm_refinement.sh): for each case, per element size, the distance
behind which 50, 75, 90 and 95 % of the grains lie, the pile edge and
the 0.5 % front ((x - L0)/L0, from the last /mpm/solid frame and
summary.json); then, per quantity, the change per millimetre of element
size between neighbouring levels (equal steps: first order in h), the
observed order p from the three finest levels, and the h -> 0 limit by
first-order Richardson extrapolation from the two finest levels,
q(0) = q(h2) - h2 (q(h1) - q(h2)) / (h1 - h2), and, where an order was
observed, at that order, q(0) = q(h3) + (q(h3) - q(h2)) / ((h2/h3)^p - 1)
(below 1 it lies further out: the pair brackets the limit if the order
holds). "–": the differences do not shrink between the three finest
levels (no asymptotic range; p below 0.05 or above 6).

usage: python3 bench/mpm_refinement_table.py OUT_DIR [CASE ...]
  (cases: the run-name prefixes in OUT_DIR, e.g. sat sat_rough; default
  every case found)
"""
import glob
import json
import os
import sys

sys.path.insert(0, __file__.rsplit("/", 1)[0])
from deposit_compare import mpm_grains, scene_of, shares  # noqa: E402

QUANTITIES = ["50 %", "75 %", "90 %", "95 %", "pile edge", "0.5 % front"]


def level(run):
    scene = scene_of(run)
    summary = json.load(open(f"{run}/summary.json"))
    a = scene["analysis"]
    grains, _ = mpm_grains(run, summary)
    s = shares(grains, scene["domain"]["min"][0], a["column_length"])
    return scene["mpm"]["element_size"] * 1e3, s[:4] + [summary["runout_pile"], summary["runout"]], summary


def observed_order(h, q):
    """p with (q1 - q2)/(q2 - q3) = (h1^p - h2^p)/(h2^p - h3^p), by bisection
    on [0.05, 6]; None when the differences change sign (no asymptotic
    range) or p leaves that range."""
    d12, d23 = q[0] - q[1], q[1] - q[2]
    if d12 * d23 <= 0.0:
        return None
    target = d12 / d23

    def ratio(p):
        return (h[0] ** p - h[1] ** p) / (h[1] ** p - h[2] ** p)

    lo, hi = 0.05, 6.0
    if not (min(ratio(lo), ratio(hi)) <= target <= max(ratio(lo), ratio(hi))):
        return None
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if (ratio(mid) - target) * (ratio(lo) - target) > 0.0:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def main():
    out = sys.argv[1]
    cases = sys.argv[2:] or sorted({os.path.basename(os.path.dirname(p)).rsplit("_h", 1)[0] for p in glob.glob(f"{out}/*_h*/summary.json")})
    for case in cases:
        runs = [p.rsplit("/", 1)[0] for p in glob.glob(f"{out}/{case}_h*/summary.json")]
        levels = sorted((level(r) for r in runs), key=lambda l: -l[0])
        if not levels:
            continue
        print(f"\n{case} ({out}):\n")
        print("| element (mm) | " + " | ".join(QUANTITIES) + " | status, t/t_ref, wall s |")
        print("|---" * (len(QUANTITIES) + 2) + "|")
        for h, q, s in levels:
            cells = " | ".join(f"{v:.2f}" for v in q)
            print(f"| {h:.2f} | {cells} | {s['status']}, {s['sim_time'] / s['t_ref']:.2f}, {s['wall_seconds']:.0f} |")
        hs = [l[0] for l in levels]
        for a, b in zip(levels, levels[1:]):
            cells = " | ".join(f"{(qa - qb) / (b[0] - a[0]):+.3f}" for qa, qb in zip(a[1], b[1]))
            print(f"| change per mm refined, {a[0]:.2f} → {b[0]:.2f} | {cells} | |")
        if len(levels) >= 3:
            h3 = hs[-3:]
            orders = []
            for k in range(len(QUANTITIES)):
                p = observed_order(h3, [l[1][k] for l in levels[-3:]])
                orders.append("–" if p is None else f"{p:.2f}")
            print(f"| observed order p ({', '.join(f'{x:.2f}' for x in h3)}) | " + " | ".join(orders) + " | |")
            limits = []
            for k in range(len(QUANTITIES)):
                q = [l[1][k] for l in levels[-3:]]
                p = observed_order(h3, q)
                limits.append("–" if p is None else f"{q[2] + (q[2] - q[1]) / ((h3[1] / h3[2]) ** p - 1.0):.2f}")
            print("| h → 0 at the observed order | " + " | ".join(limits) + " | |")
        if len(levels) >= 2:
            (h1, q1, _), (h2, q2, _) = levels[-2], levels[-1]
            cells = " | ".join(f"{b - h2 * (a - b) / (h1 - h2):.2f}" for a, b in zip(q1, q2))
            print(f"| h → 0, first order from {h1:.2f} and {h2:.2f} | {cells} | |")


if __name__ == "__main__":
    main()

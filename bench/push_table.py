#!/usr/bin/env python3
"""A steady push on dry piles (docs/RESULTS.md, "A steady push on dry
piles"): the H0 = 0.06 m dry column of each method run with a horizontal
gravity k g from the gate's release on (`domain.collapse_gravity`), the
grains prepared without it. For each run: the pile edge (`front_pile`, the
DEM's rule) at t/t_ref = 1, 2, 4, 8 and at the end, from when
on it stays within a grain (its bin) of its end, its ratio to the
set's first run (the unpushed one when it is listed first), when it stopped, and the deposit's downstream
surface slope: the least-squares slope of the deposit's height (behind
the pile edge) where it is
between 0.2 and 0.8 of its highest, from the highest down to where it
first falls below 0.2 of it. The angle
the pile holds against the pushed gravity is atan(slope) + atan(k).

usage: python3 bench/push_table.py LABEL:DIR:DIR:... [LABEL:DIR:...]
  DIR: a `coupler run` output (summary.json, scene.toml); k is read from
  its scene's domain.collapse_gravity (k g, 0, -g), 0 without one
"""
import json
import math
import sys
import tomllib


# One grain (2.5 mm) over L0 (0.04 m): the pile edge's bin, so its noise.
GRAIN = 2.5e-3 / 0.04


def at(front, t):
    return min(front, key=lambda f: abs(f["t_norm"] - t))["x_norm"]


def slope(deposit, edge):
    """Downstream surface slope of a deposit [[x, height], ...] (positive =
    falling) behind its pile edge `edge` (m): grains rolled on to the end
    wall and heaped there are not the pile."""
    deposit = [b for b in deposit if b[0] <= edge]
    if not deposit:
        return float("nan")
    top = max(range(len(deposit)), key=lambda i: deposit[i][1])
    h_max = deposit[top][1]
    pts = []
    for x, h in deposit[top:]:
        if h < 0.2 * h_max:
            break  # the pile's foot: grains beyond it (rolled to the end wall) are not its surface
        if h <= 0.8 * h_max:
            pts.append((x, h))
    if len(pts) < 3:
        return float("nan")
    n = len(pts)
    mx = sum(x for x, _ in pts) / n
    mh = sum(h for _, h in pts) / n
    num = sum((x - mx) * (h - mh) for x, h in pts)
    den = sum((x - mx) ** 2 for x, _ in pts)
    return -num / den


def push(run):
    """k of a run: its scene's collapse_gravity x over its -z (0 without one)."""
    domain = tomllib.load(open(f"{run}/scene.toml", "rb"))["domain"]
    g = domain.get("collapse_gravity")
    if g and g[2] >= 0.0:
        sys.exit(f"{run}: collapse_gravity {g} has no downward part: k (push over weight) is not defined")
    return g[0] / -g[2] if g else 0.0


args = sys.argv[1:]

print("| set | push k | pile edge at 1 / 2 / 4 / 8 t_ref | end | end / first k's | edge within a grain of its end from (t/t_ref) "
      "| run ends (t/t_ref) | 0.5 % front | surface slope | angle held (°) |")
print("|---|---|---|---|---|---|---|---|---|---|")
for spec in args:
    label, *dirs = spec.split(":")
    base = None
    for d in dirs:
        k = push(d)
        s = json.load(open(f"{d}/summary.json"))
        fp = s.get("front_pile")
        end = s.get("runout_pile")
        if not fp or end is None:
            sys.exit(f"{d}: no pile edge in its summary (MPM summaries carry it since session 32)")
        base = end if base is None else base
        sl = slope(s["deposit"], fp[-1]["x"])
        held = math.degrees(math.atan(sl) + math.atan(k))
        settled = next((f["t_norm"] for f in fp if all(abs(g["x_norm"] - end) <= GRAIN for g in fp if g["t"] >= f["t"])),
                       float("nan"))
        ends = s["sim_time"] / s["t_ref"]
        print(f"| {label} | {k:.2f} | {at(fp, 1):.2f} / {at(fp, 2):.2f} / {at(fp, 4):.2f} / {at(fp, 8):.2f} | {end:.3f} | "
              f"{end / base:.2f} | {settled:.1f} | {ends:.1f} ({s['status']}) | {s['runout']:.2f} | {sl:.3f} | {held:.1f} |")

#!/usr/bin/env python3
"""The water table and the soil's top along the flume, for DEM-LBM and
MPM runs of the saturated columns side by side (docs/RESULTS.md, "The
floor the grains feel, and the solid's momentum in both methods"): at
t/t_ref = 0, 1, 2, 3, 4, per 4 mm of x, the liquid's top and the soil's
top (mm), the water table's mean slope over the soil's body (the bins
where the soil stands higher than 5 mm), and the share of the solid
below its bin's water top. A water table sloping at i pushes the
skeleton under it out with rho_L g i per unit volume (Darcy).

The soil's top is its height at the run's initial porosity n0
(`porosity_initial` of summary.json): the grains' volume in the bin over
(1 - n0) x the bin's area, as the DEM's pile-edge rule reads heights (a
percentile of the grains' tops would read a rough surface's valleys or
its peaks), so both methods start at H0. DEM: grain volumes from
`/dem/particles`; MPM: the solid points' masses over rho_s per metre of
width, each point's share spread over its domain (its points' spacing
along x), so that 4 mm bins over rows of points 0.83 mm apart do not
alias. The liquid's top: DEM-LBM
from `/lbm/slice` (mid-width: per column the top of its highest liquid
cell, bottom face plus fill x dx); MPM the highest liquid point per bin
plus half the points' vertical spacing (a point's centre lies that far
below the liquid it stands for).

usage: python3 bench/water_tables.py RUN_DIR [RUN_DIR ...]
"""
import json, struct, sys, tomllib
from collections import defaultdict
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

BIN, BODY = 0.004, 0.005
TIMES = [0, 1, 2, 3, 4]
XS = [0.0, 0.02, 0.04, 0.06, 0.08, 0.10, 0.12]


def lbm_tops(grid, x0, z0):
    nx, dx = grid.column_count, grid.cell_size.x
    nz = len(grid.data) // (nx * grid.cell_stride)
    top = {}
    for i in range(nx):
        for k in range(nz - 1, -1, -1):
            fill = struct.unpack_from("<f", grid.data, (k * nx + i) * grid.cell_stride)[0]
            if fill > 0.0:
                top[i] = grid.pose.position.z - z0 + k * dx + min(fill, 1.0) * dx
                break
    bins = defaultdict(float)
    for i, z in top.items():
        b = int(((i + 0.5) * dx + grid.pose.position.x - x0) / BIN)
        bins[b] = max(bins[b], z)
    return bins


def grain_heights(cloud, x0, width, n0):
    vol = defaultdict(float)
    for i in range(len(cloud.data) // cloud.point_stride):
        x, _, _, r = struct.unpack_from("<4f", cloud.data, i * cloud.point_stride)
        vol[int((x - x0) / BIN)] += 4.0 / 3.0 * 3.141592653589793 * r**3
    return {b: v / ((1 - n0) * BIN * width) for b, v in vol.items()}


def point_heights(cloud, x0, mass, rho_s, spacing, n0):
    vol = defaultdict(float)
    for i in range(len(cloud.data) // cloud.point_stride):
        x = struct.unpack_from("<f", cloud.data, i * cloud.point_stride)[0] - x0
        lo, hi = x - spacing / 2, x + spacing / 2
        for b in range(int(lo // BIN), int(hi // BIN) + 1):
            share = max(0.0, min(hi, (b + 1) * BIN) - max(lo, b * BIN)) / spacing
            vol[b] += share * mass / rho_s
    return {b: v / ((1 - n0) * BIN) for b, v in vol.items()}


def point_tops(cloud, x0, z0, lift):
    top = defaultdict(float)
    for i in range(len(cloud.data) // cloud.point_stride):
        x, _, z = struct.unpack_from("<3f", cloud.data, i * cloud.point_stride)
        top[int((x - x0) / BIN)] = max(top[int((x - x0) / BIN)], z - z0 + lift)
    return top


def submerged(water, cloud, x0, z0):
    """The share of the grains (or of the MPM's solid points, which carry
    equal masses) whose centre lies below its bin's water top."""
    below = total = 0
    for i in range(len(cloud.data) // cloud.point_stride):
        x, _, z = struct.unpack_from("<3f", cloud.data, i * cloud.point_stride)
        total += 1
        below += z - z0 < water.get(int((x - x0) / BIN), 0.0)
    return below / max(total, 1)


def slope(water, soil):
    body = sorted(b for b, z in soil.items() if z > BODY and b in water)
    if len(body) < 2:
        return float("nan")
    xs = [(b + 0.5) * BIN for b in body]
    zs = [water[b] for b in body]
    mx, mz = sum(xs) / len(xs), sum(zs) / len(zs)
    return -sum((x - mx) * (z - mz) for x, z in zip(xs, zs)) / sum((x - mx) ** 2 for x in xs)


for run in sys.argv[1:]:
    sc = tomllib.load(open(f"{run}/scene.toml", "rb"))
    summary = json.load(open(f"{run}/summary.json"))
    t_ref, mpm = summary["t_ref"], summary["method"] == "mpm"
    x0, z0 = sc["domain"]["min"][0], sc["domain"]["min"][2]
    width = sc["domain"]["max"][1] - sc["domain"]["min"][1]
    rho_s, n0 = sc["particles"][0]["density"], summary["porosity_initial"]
    if mpm:
        m = summary["mpm"]
        # Points per element a x b, b along z (schemas::scene::point_grid_of).
        n = sc["mpm"].get("points_per_element", 12)
        b = max(d for d in range(1, int(n**0.5) + 1) if n % d == 0)
        lift, spacing = m["element_size"] / (2 * b), m["element_size"] / (n // b)
        point_mass = m["solid_mass"] / m["solid_points"]
    topics = ["/mpm/liquid", "/mpm/solid"] if mpm else ["/lbm/slice", "/dem/particles"]
    frames = defaultdict(dict)
    with open(f"{run}/run.mcap", "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, msg, m in reader.iter_decoded_messages(topics=topics):
            tn = msg.log_time * 1e-9 / t_ref
            t = min(TIMES, key=lambda t: abs(t - tn))
            if abs(t - tn) < 0.1:
                frames[(t, round(tn, 3))][channel.topic] = m
    print(f"{run} ({'MPM' if mpm else 'DEM-LBM'}): water top / soil top (mm) at x (cm)")
    print("| t/t_ref | " + " | ".join(f"{x * 100:g}" for x in XS) + " | water table's slope over the body | solid below the water table |")
    print("|---" * (len(XS) + 3) + "|")
    done = set()
    for (t, tn), fr in sorted(frames.items(), key=lambda kv: abs(kv[0][0] - kv[0][1])):
        if t in done or len(fr) < 2:
            continue
        done.add(t)
        solid = fr["/mpm/solid"] if mpm else fr["/dem/particles"]
        if mpm:
            water, soil = point_tops(fr["/mpm/liquid"], x0, z0, lift), point_heights(solid, x0, point_mass, rho_s, spacing, n0)
        else:
            water, soil = lbm_tops(fr["/lbm/slice"], x0, z0), grain_heights(solid, x0, width, n0)
        cells = [f"{water.get(int(x / BIN), 0) * 1e3:.1f} / {soil.get(int(x / BIN), 0) * 1e3:.1f}" for x in XS]
        print(f"| {tn:.2f} | " + " | ".join(cells) + f" | {slope(water, soil):.3f} | {submerged(water, solid, x0, z0):.3f} |")

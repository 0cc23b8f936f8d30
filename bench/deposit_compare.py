#!/usr/bin/env python3
"""Where the deposit's grains lie, DEM(-LBM) against MPM (issue 20, the
pile-edge gap): from the last frame of each run, the distance along the
flume behind which a share of the grains' volume lies, and the deposit's
thickness h(x) = grain volume per bin / (bin x width x (1 - n0)), the
measure `front_pile` reads (docs/recording.md), in bins of one grain
diameter D.

DEM: the last `/dem/state` (grains by id, radius; bench/dem_state.py).
MPM: the last `/mpm/solid` frame; every solid point carries the same
grains (the columns are generated uniform), so each point counts
L0 H0 (1 - n0) / N per metre of width. The profile bins each point by
its centre (not spread over its domain as `front_pile` is), so one MPM
point adds v0 / D^2 to a bin (0.15 D at 3.33 mm and 12 points): read the
MPM's h/D to that. The profile starts at the gate line (x = L0).

usage: python3 bench/deposit_compare.py DEM_RUN MPM_RUN [--diameter D]
  e.g. runs/s34/sat_h030 (the committed DEM-LBM run) and an MPM run of
  scenes/ceccato2020/mpm_sat_h030.toml (`--set mpm.friction_angle=27`).
Prints the shares' distances (x - L0)/L0, then h/D against (x - L0)/L0.
"""
import json
import math
import struct
import sys
import tomllib

from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

sys.path.insert(0, __file__.rsplit("/", 1)[0])
from dem_state import states  # noqa: E402

SHARES = [0.5, 0.75, 0.9, 0.95, 0.99, 0.995]


def scene_of(run):
    return tomllib.load(open(f"{run}/scene.toml", "rb"))


def dem_grains(run):
    """(x, grain volume) of every grain at the last state; flume width."""
    scene = scene_of(run)
    last = states(run)[-1]
    grains = [(p[0], 4.0 / 3.0 * math.pi * r**3) for p, _, r in last["by_id"].values()]
    width = scene["domain"]["max"][1] - scene["domain"]["min"][1]
    return grains, width


def mpm_grains(run, summary):
    """(x, grain volume per metre of width) of every solid point at the
    last frame; width 1 m."""
    scene = scene_of(run)
    last = None
    with open(f"{run}/run.mcap", "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, _, _, m in reader.iter_decoded_messages(topics=["/mpm/solid"]):
            last = m
    n = len(last.data) // last.point_stride
    a = scene["analysis"]
    each = a["column_length"] * a["column_height"] * (1.0 - summary["porosity_initial"]) / n
    xs = [struct.unpack_from("<f", last.data, i * last.point_stride)[0] for i in range(n)]
    return [(x, each) for x in xs], 1.0


def shares(grains, x0, l0):
    total = sum(v for _, v in grains)
    out, acc, k = [], 0.0, 0
    for x, v in sorted(grains):
        acc += v
        while k < len(SHARES) and acc >= SHARES[k] * total:
            out.append(((x - x0) - l0) / l0)
            k += 1
    return out


def profile(grains, width, n0, x0, bin_width):
    bins = {}
    for x, v in grains:
        i = int((x - x0) // bin_width)
        bins[i] = bins.get(i, 0.0) + v
    return {i: v / (bin_width * width * (1.0 - n0)) for i, v in bins.items()}


def main():
    dem_run, mpm_run = sys.argv[1], sys.argv[2]
    dem_summary = json.load(open(f"{dem_run}/summary.json"))
    mpm_summary = json.load(open(f"{mpm_run}/summary.json"))
    scene = scene_of(dem_run)
    diameter = float(sys.argv[sys.argv.index("--diameter") + 1]) if "--diameter" in sys.argv else None
    if diameter is None:
        diameter = max(p["diameter"] for p in scene["particles"])
    a = scene["analysis"]
    l0, x0 = a["column_length"], scene["domain"]["min"][0]
    runs = [("DEM(-LBM)", dem_grains(dem_run), dem_summary), ("MPM", mpm_grains(mpm_run, mpm_summary), mpm_summary)]
    print(f"D = {diameter * 1e3:.2f} mm, L0 = {l0} m")
    print("| run | " + " | ".join(f"{s:.1%} behind" for s in SHARES) + " | pile edge (h = D) | 0.5 % mass front |")
    print("|---|" + "---|" * (len(SHARES) + 2))
    profiles = []
    for name, (grains, width), summary in runs:
        s = shares(grains, x0, l0)
        print(f"| {name} | " + " | ".join(f"{v:.2f}" for v in s) + f" | {summary.get('runout_pile', float('nan')):.2f} | {summary['runout']:.2f} |")
        profiles.append(profile(grains, width, summary["porosity_initial"], x0, diameter))
    print()
    print("| (x - L0)/L0 | DEM(-LBM) h/D | MPM h/D |")
    print("|---|---|---|")
    last = max(max(p) for p in profiles)
    step = max(1, int(0.25 * l0 / diameter))
    for i in range(0, last + 1, step):
        xi = ((i + 0.5) * diameter - l0) / l0
        if xi < 0:
            continue
        print(f"| {xi:.2f} | {profiles[0].get(i, 0.0) / diameter:.2f} | {profiles[1].get(i, 0.0) / diameter:.2f} |")


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""Excess pore pressure under a saturated MPM column against the grains'
buoyant weight, the MPM's counterpart of bench/pore_pressure.py (which
reads the DEM-LBM's lattice; docs/RESULTS.md, "Why the saturated column
runs ahead" and session 33's section).

For x-bins along the flume, at chosen frames: the excess pore pressure on
the floor, u = p - rho_L g (z_w - z) averaged over the pressured liquid
points of the bottom element row in the bin, z_w the highest liquid
point of the point's 4 mm column of x (the local water table); the
effective vertical stress the grains' buoyant weight would put on the
floor if the liquid carried none of it, sigma'_v = sum m_p (1 - rho_L /
rho_s) g / bin length (plane strain, per metre of width; every solid
point carries the same mass); and r_u = u / sigma'_v (1: the grains
float; 0: drained; negative: the draining water holds them down).

usage: python3 bench/mpm_pore_pressure.py RUN_DIR [BIN_EDGES_IN_L0 ...]
       (default bins 0-0.5, 0.5-1, 1-1.5, 1.5-2.5 L0 from the back wall;
       needs `pip install mcap mcap-protobuf-support`)
"""
import struct
import sys
import tomllib
from collections import defaultdict

from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

TIMES = [0.14, 0.43, 0.85, 1.42, 1.99, 2.98, 4.0, 5.96]
COLUMN = 0.004  # m: the x-columns the local water table is taken over

run = sys.argv[1]
edges = [float(e) for e in sys.argv[2:]] or [0.0, 0.5, 1.0, 1.5, 2.5]
bins = list(zip(edges[:-1], edges[1:]))
scene = tomllib.load(open(f"{run}/scene.toml", "rb"))
x0 = scene["domain"]["min"][0]
g = -scene["domain"]["gravity"][2]
l0 = scene["analysis"]["column_length"]
h0 = scene["analysis"]["column_height"]
rho_s = scene["particles"][0]["density"]
rho_l = scene["fluids"][0]["density"]
h = scene.get("mpm", {}).get("element_size", 0.004)
t_ref = (h0 / (g * (rho_s - rho_l) / rho_s)) ** 0.5

frames = defaultdict(dict)
solid_mass = None
with open(f"{run}/run.mcap", "rb") as f:
    reader = make_reader(f, decoder_factories=[DecoderFactory()])
    for _, channel, msg, m in reader.iter_decoded_messages(topics=["/mpm/liquid", "/mpm/solid", "/mpm/metrics"]):
        if channel.topic == "/mpm/metrics":
            solid_mass = solid_mass or m.solid_mass
            continue
        frames[msg.log_time][channel.topic] = m


def points(cloud, fields):
    """(x, z, field values...) of each point; `fields` the float fields after x, y, z."""
    out = []
    for i in range(len(cloud.data) // cloud.point_stride):
        v = struct.unpack_from(f"<{3 + fields}f", cloud.data, i * cloud.point_stride)
        out.append((v[0], v[2]) + v[3:])
    return out


print(f"{run}: t_ref = {t_ref:.4f} s; floor excess pore pressure u (Pa), sigma'_v (Pa), r_u = u/sigma'_v")
print("| t/t_ref | " + " | ".join(f"x/L0 {a:g}–{b:g}: u, σ'v, r_u" for a, b in bins) + " |")
print("|---|" + "---|" * len(bins))
times = sorted(frames)
for target in TIMES:
    time = min(times, key=lambda t: abs(t * 1e-9 / t_ref - target))
    fr = frames[time]
    if "/mpm/liquid" not in fr or "/mpm/solid" not in fr:
        continue
    # liquid fields: speed, pore_pressure, free_surface, volume; solid: speed, porosity, p', fluidised
    liquid = points(fr["/mpm/liquid"], 4)
    solid = points(fr["/mpm/solid"], 4)
    m_p = solid_mass / len(solid)
    top = defaultdict(float)
    for x, z, *_ in liquid:
        top[int((x - x0) / COLUMN)] = max(top[int((x - x0) / COLUMN)], z)
    cells = []
    for lo, hi in bins:
        us = [p - rho_l * g * (top[int((x - x0) / COLUMN)] - z)
              for x, z, _, p, free, _ in liquid
              if lo <= (x - x0) / l0 < hi and z < h and free < 0.5]
        u = sum(us) / len(us) if us else float("nan")
        n = sum(1 for x, z, *_ in solid if lo <= (x - x0) / l0 < hi)
        sv = n * m_p * (1.0 - rho_l / rho_s) * g / ((hi - lo) * l0)
        cells.append(f"{u:7.1f}, {sv:6.1f}, {u / sv if sv > 1.0 else float('nan'):5.2f}")
    print(f"| {time * 1e-9 / t_ref:5.2f} | " + " | ".join(cells) + " |")

#!/usr/bin/env python3
"""Excess pore pressure under a saturated column against the grains'
buoyant weight, from a `coupler run` recording (`/lbm/slice` and
`/dem/particles`; docs/recording.md).

For x-bins along the flume, at each frame: the excess pore pressure on the
floor (mean of the bin's floor cells in the mid-width slice), the
effective vertical stress the grains' buoyant weight would put on the
floor if the liquid carried none of it, sigma'_v = sum (rho_s - rho_L) V g
/ (bin length x flume width), and their ratio r_u = u_excess / sigma'_v
(1: the grains float, the skeleton carries nothing, a liquefied mass;
0: drained; negative: suction holds the grains together).

usage: python3 bench/pore_pressure.py RUN_DIR [BIN_EDGES_IN_L0 ...]
       (default bins 0-0.5, 0.5-1, 1-1.5, 1.5-2.5 L0 from the back wall)
"""
import json, struct, sys, tomllib
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

run = sys.argv[1]
edges = [float(e) for e in sys.argv[2:]] or [0.0, 0.5, 1.0, 1.5, 2.5]
scene = tomllib.load(open(f"{run}/scene.toml", "rb"))
x0, y0 = scene["domain"]["min"][0], scene["domain"]["min"][1]
width = scene["domain"]["max"][1] - y0
g = -scene["domain"]["gravity"][2]
l0 = scene["analysis"]["column_length"]
h0 = scene["analysis"]["column_height"]
rho_s = scene["particles"][0]["density"]
rho_l = scene["fluids"][0]["density"]
t_ref = (h0 / (g * (rho_s - rho_l) / rho_s)) ** 0.5
bins = list(zip(edges[:-1], edges[1:]))

slices, clouds = {}, {}
with open(f"{run}/run.mcap", "rb") as f:
    reader = make_reader(f, decoder_factories=[DecoderFactory()])
    for _, channel, message, m in reader.iter_decoded_messages(topics=["/lbm/slice", "/dem/particles"]):
        if channel.topic == "/lbm/slice":
            slices[message.log_time] = m
        else:
            clouds[message.log_time] = m

skipped = 0
print(f"{run}: t_ref = {t_ref:.4f} s; floor excess pore pressure u (Pa), sigma'_v (Pa), r_u = u/sigma'_v")
print("| t/t_ref | " + " | ".join(f"x/L0 {a:g}–{b:g}: u, σ'v, r_u" for a, b in bins) + " |")
print("|---|" + "---|" * len(bins))
for time in sorted(slices):
    grid = slices[time]
    # The DEM's frame nearest in time (both write at the scene's record_interval).
    nearest = min(clouds, key=lambda c: abs(c - time), default=None)
    if nearest is None or abs(nearest - time) > 1e6:  # more than 1 ms apart
        skipped += 1
        continue
    cloud = clouds[nearest]
    nx, dx, stride = grid.column_count, grid.cell_size.x, grid.cell_stride
    x_grid = grid.pose.position.x - x0  # the slice's corner from the domain's
    assert stride == 16, "a recording with pressure fields (session 14 on)"
    floor = [struct.unpack_from("<4f", grid.data, i * stride) for i in range(nx)]
    weight = [0.0] * len(bins)
    for p in range(len(cloud.data) // cloud.point_stride):
        x, y, z, r = struct.unpack_from("<4f", cloud.data, p * cloud.point_stride)
        xi = (x - x0) / l0
        for b, (lo, hi) in enumerate(bins):
            if lo <= xi < hi:
                weight[b] += (rho_s - rho_l) * 4.0 / 3.0 * 3.141592653589793 * r**3 * g
    cells = []
    for b, (lo, hi) in enumerate(bins):
        us = [floor[i][3] for i in range(nx) if lo <= (x_grid + (i + 0.5) * dx) / l0 < hi and floor[i][0] > 0.5]
        u = sum(us) / len(us) if us else float("nan")
        sv = weight[b] / ((hi - lo) * l0 * width)
        cells.append(f"{u:7.1f}, {sv:6.1f}, {u / sv if sv > 1.0 else float('nan'):5.2f}")
    tn = time * 1e-9 / t_ref
    print(f"| {tn:5.2f} | " + " | ".join(cells) + " |")
if skipped:
    print(f"({skipped} slice frames had no DEM frame within 1 ms and were left out)")

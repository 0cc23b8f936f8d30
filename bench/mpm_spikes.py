#!/usr/bin/env python3
"""Pore-pressure spikes of a two-phase MPM run (issue 20, part 2), from the
`/mpm/liquid` clouds of a `coupler run` recording (docs/recording.md).

A liquid point is a spike when its pore pressure exceeds
3 (rho_L g H0 + 1/2 rho_L v^2), v the largest liquid speed among the
points of its element and the eight elements around it: three times the
largest pressure that statics (the column's full height of water) and the
stagnation of the local flow can explain. The script reports, per frame,
the largest pressure, its ratio to that bar, where it sits, and the fill
of its element (points counted free / all liquid points there); and, as
a second measure, the worst element: the volume-weighted mean pressure
over all its liquid points (free ones at 0), the pressure its points exert on the
nodes together, against the same bar. A lone pressured point among free
ones carries its element's load alone and shows large at the first
measure only.

The last line counts the frames on which some point (some element's
mean) is above the bar: with frames far apart (0.1 t_ref) the worst
ratio is a lottery over transients that last two or three steps; record
densely (`--set output.record_interval=1e-4`) to see them.

usage: python3 bench/mpm_spikes.py RUN_DIR [--every N]
exit status 1 when any point exceeds the bar (ratio > 1).
"""
import struct, sys, tomllib
from collections import defaultdict
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

run = sys.argv[1]
every = int(sys.argv[sys.argv.index("--every") + 1]) if "--every" in sys.argv else 1
scene = tomllib.load(open(f"{run}/scene.toml", "rb"))
x0, z0 = scene["domain"]["min"][0], scene["domain"]["min"][2]
g = -scene["domain"]["gravity"][2]
h0 = scene["analysis"]["column_height"]
rho_s = scene["particles"][0]["density"]
rho_l = scene["fluids"][0]["density"]
h = scene["mpm"]["element_size"]
t_ref = (h0 / (g * (rho_s - rho_l) / rho_s)) ** 0.5
static = rho_l * g * h0

worst_ratio, worst = 0.0, None
worst_element = (0.0, None)
rows = []
frames_seen = frames_above = frames_element_above = 0
with open(f"{run}/run.mcap", "rb") as f:
    reader = make_reader(f, decoder_factories=[DecoderFactory()])
    frames = [(msg.log_time, m) for _, _, msg, m in reader.iter_decoded_messages(topics=["/mpm/liquid"])]
for k, (time, cloud) in enumerate(frames):
    if k % every:
        continue
    n = len(cloud.data) // cloud.point_stride
    if n == 0:
        continue
    pts = [struct.unpack_from("<7f", cloud.data, i * cloud.point_stride) for i in range(n)]
    cells = defaultdict(list)
    for i, p in enumerate(pts):
        cells[(int((p[0] - x0) // h), int((p[2] - z0) // h))].append(i)
    vmax = {c: max(pts[i][3] for i in idx) for c, idx in cells.items()}
    t = time * 1e-9
    frame_worst = (0.0, None)
    frame_element = 0.0
    for c, idx in cells.items():
        v = max(vmax.get((c[0] + a, c[1] + b), 0.0) for a in (-1, 0, 1) for b in (-1, 0, 1))
        bar = 3.0 * (static + 0.5 * rho_l * v * v)
        mean = sum(pts[i][4] * pts[i][6] for i in idx) / sum(pts[i][6] for i in idx)
        frame_element = max(frame_element, mean / bar)
        if mean / bar > worst_element[0]:
            worst_element = (mean / bar, (time * 1e-9, c, mean, bar))
        for i in idx:
            r = pts[i][4] / bar
            if r > frame_worst[0]:
                frame_worst = (r, (i, c, bar, v))
    pmax = max(p[4] for p in pts)
    frames_seen += 1
    frames_above += frame_worst[0] > 1.0
    frames_element_above += frame_element > 1.0
    r, info = frame_worst
    if info is not None:
        i, c, bar, v = info
        mates = cells[c]
        free = sum(1 for j in mates if pts[j][5] > 0.5)
        rows.append((t, pmax, r, pts[i][0], pts[i][2], pts[i][4], bar, free, len(mates)))
        if r > worst_ratio:
            worst_ratio, worst = r, rows[-1]
    else:
        rows.append((t, pmax, 0.0, 0, 0, 0, 0, 0, 0))

print(f"{run}: rho_L g H0 = {static:.0f} Pa, t_ref = {t_ref:.4f} s, element {h*1e3:g} mm")
print("| t/t_ref | max p (Pa) | worst p/bar | at x, z (mm) | its p, bar (Pa) | element: free/all |")
print("|---|---|---|---|---|---|")
for k, (t, pmax, r, x, z, p, bar, free, alln) in enumerate(rows):
    if r > 0.5 or k % 10 == 0:
        print(f"| {t/t_ref:.2f} | {pmax:.0f} | {r:.2f} | {x*1e3:.1f}, {z*1e3:.1f} | {p:.0f}, {bar:.0f} | {free}/{alln} |")
if worst:
    t, pmax, r, x, z, p, bar, free, alln = worst
    print(f"worst: p/bar = {r:.2f} at t/t_ref = {t/t_ref:.2f}, x = {x*1e3:.1f} mm, z = {z*1e3:.1f} mm, p = {p:.0f} Pa, bar {bar:.0f} Pa, element {free}/{alln} free")
if worst_element[1]:
    r, (t, c, mean, bar) = worst_element
    print(f"worst element mean: {r:.2f} of the bar at t/t_ref = {t/t_ref:.2f}, element ({c[0]}, {c[1]}), mean p = {mean:.0f} Pa, bar {bar:.0f} Pa")
print(f"frames above the bar: {frames_above} of {frames_seen} (a point), {frames_element_above} (an element's mean)")
sys.exit(1 if worst_ratio > 1.0 else 0)

#!/usr/bin/env python3
"""What the grains against the back wall do (docs/RESULTS.md, "The floor
the grains feel, and the solid's momentum in both methods"): for a
DEM(-LBM) column run, the grains that start within 10 mm of the back
wall, at t/t_ref = 1, 2, 3, 4, 6, 8: how many are still there, their
mean x-displacement, and the mean vertical displacement of those that
started in the top third (z0 > 2/3 H0) and in the bottom third
(z0 < H0/3). A dead zone stands still; a zone that flows out sinks at the
top; a top that sinks while the bottom rises turns over.

usage: python3 bench/back_region.py RUN_DIR [RUN_DIR ...]
"""
import json, struct, sys, tomllib
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

TIMES = [1, 2, 3, 4, 6, 8]
BACK = 0.01

for run in sys.argv[1:]:
    t_ref = json.load(open(f"{run}/summary.json"))["t_ref"]
    sc = tomllib.load(open(f"{run}/scene.toml", "rb"))
    x0, h0 = sc["domain"]["min"][0], sc["analysis"]["column_height"]
    frames = []
    with open(f"{run}/run.mcap", "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, _, msg, c in reader.iter_decoded_messages(topics=["/dem/particles"]):
            n = len(c.data) // c.point_stride
            frames.append((msg.log_time * 1e-9 / t_ref, [struct.unpack_from("<3f", c.data, i * c.point_stride) for i in range(n)]))
    first = frames[0][1]
    back = [i for i, p in enumerate(first) if p[0] - x0 < BACK]
    top = [i for i in back if first[i][2] > 2 * h0 / 3]
    bottom = [i for i in back if first[i][2] < h0 / 3]
    mean = lambda sel, pts, k: sum(pts[i][k] - first[i][k] for i in sel) / len(sel) * 1e3
    print(f"{run}: {len(back)} grains within {BACK * 1e3:g} mm of the back wall ({len(top)} in the top third, {len(bottom)} in the bottom third)")
    print("| t/t_ref | still there | mean dx (mm) | top third: dx, dz (mm) | bottom third: dz (mm) |")
    print("|---|---|---|---|---|")
    for t in TIMES:
        tn, pts = min(frames, key=lambda fr: abs(fr[0] - t))
        if abs(tn - t) > 0.1:
            continue
        still = sum(1 for i in back if pts[i][0] - x0 < BACK)
        print(f"| {tn:.2f} | {still} | {mean(back, pts, 0):.2f} | {mean(top, pts, 0):.2f}, {mean(top, pts, 2):.2f} | {mean(bottom, pts, 2):.2f} |")

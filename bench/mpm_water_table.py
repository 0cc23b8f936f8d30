#!/usr/bin/env python3
"""The slope of the MPM's water table over the soil's body through a
saturated collapse (docs/RESULTS.md, "both methods on one edge"): at each
t/t_ref, the liquid's top per 4 mm bin of x (the highest liquid point)
over the bins where the soil stands more than 5 mm high, its
least-squares slope, and the liquid and soil tops at the back wall. A
water table sloping at i pushes the skeleton outward with rho_L g i per
unit volume (Darcy), against its buoyant weight (1 - n)(rho_s - rho_L) g.

usage: python3 bench/mpm_water_table.py RUN_DIR...
  (a `coupler run` of a saturated MPM scene; needs `pip install mcap mcap-protobuf-support`)
"""
import struct, sys, tomllib
from collections import defaultdict
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

BIN, BODY = 0.004, 0.005


def tops(cloud):
    top = defaultdict(float)
    for i in range(len(cloud.data) // cloud.point_stride):
        x, _, z = struct.unpack_from("<3f", cloud.data, i * cloud.point_stride)
        top[int(x / BIN)] = max(top[int(x / BIN)], z)
    return top


for run in sys.argv[1:]:
    sc = tomllib.load(open(f"{run}/scene.toml", "rb"))
    g = -sc["domain"]["gravity"][2]
    h0 = sc["analysis"]["column_height"]
    rs, rl = sc["particles"][0]["density"], sc["fluids"][0]["density"]
    t_ref = (h0 / (g * (rs - rl) / rs)) ** 0.5
    frames = defaultdict(dict)
    with open(f"{run}/run.mcap", "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, msg, m in reader.iter_decoded_messages(topics=["/mpm/liquid", "/mpm/solid"]):
            frames[round(msg.log_time * 1e-9 / t_ref, 1)][channel.topic] = m
    print(run.rstrip("/").split("/")[-1])
    for tn in (0.5, 1, 1.5, 2, 2.5, 3, 3.5, 4):
        fr = frames.get(tn)
        if not fr or len(fr) < 2:
            continue
        water, soil = tops(fr["/mpm/liquid"]), tops(fr["/mpm/solid"])
        body = [b for b in sorted(water) if soil.get(b, 0.0) > BODY]
        if len(body) < 3:
            continue
        xs, zs = [(b + 0.5) * BIN for b in body], [water[b] for b in body]
        mx, mz = sum(xs) / len(xs), sum(zs) / len(zs)
        slope = sum((x - mx) * (z - mz) for x, z in zip(xs, zs)) / sum((x - mx) ** 2 for x in xs)
        print(f"  t/t_ref {tn:>3}: water-table slope {-slope:.3f} over {len(body)} bins; "
              f"at the back wall water {1e3 * water.get(0, 0.0):.1f} mm, soil {1e3 * soil.get(0, 0.0):.1f} mm")

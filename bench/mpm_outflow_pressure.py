"""The pore pressure the MPM's outflowing mass carries, against hydrostatic
at its own depth, at t/t_ref = 0.5, 1, 2: over the liquid points beyond the
gate (x > L0), Σ V p / Σ V ρ_L g d, d the depth below the local liquid top
(the highest liquid point in 2 mm bins of x, plus half the points' vertical
spacing, where the surface of its layer lies). 1: the flowing sheet carries
its full hydrostatic pressure (buoyancy); below 1 the grains bear weight the
water should; above 1, excess pore pressure. Also the sheet's mean top.

usage: python3 bench/mpm_outflow_pressure.py RUN_DIR...
(docs/mpm.md, "Open points" 5; needs `pip install mcap mcap-protobuf-support`)
"""
import struct, sys, tomllib
from collections import defaultdict
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

BIN = 0.002
for run in sys.argv[1:]:
    sc = tomllib.load(open(f"{run}/scene.toml", "rb"))
    g = -sc["domain"]["gravity"][2]
    h0, l0 = sc["analysis"]["column_height"], sc["analysis"]["column_length"]
    rs, rl = sc["particles"][0]["density"], sc["fluids"][0]["density"]
    h, ppe = sc["mpm"]["element_size"], sc["mpm"].get("points_per_element", 12)
    rows = max(b for b in range(1, int(ppe**0.5) + 1) if ppe % b == 0)  # the a x b sub-grid's b
    t_ref = (h0 / (g * (rs - rl) / rs)) ** 0.5
    with open(f"{run}/run.mcap", "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        frames = [(msg.log_time * 1e-9, m) for _, _, msg, m in reader.iter_decoded_messages(topics=["/mpm/liquid"])]
    out = []
    for target in (0.5, 1.0, 2.0):
        _, cloud = min(frames, key=lambda fr: abs(fr[0] / t_ref - target))
        n = len(cloud.data) // cloud.point_stride
        pts = [struct.unpack_from("<7f", cloud.data, i * cloud.point_stride) for i in range(n)]
        top = defaultdict(float)
        for p in pts:
            top[int(p[0] / BIN)] = max(top[int(p[0] / BIN)], p[2] + 0.5 * h / rows)
        flowing = [p for p in pts if p[0] > l0]
        carried = sum(p[6] * p[4] for p in flowing)
        hydrostatic = sum(p[6] * rl * g * (top[int(p[0] / BIN)] - p[2]) for p in flowing)
        tops = [z for b, z in top.items() if b * BIN > l0]
        ratio = carried / hydrostatic if hydrostatic > 0 else 0.0
        out.append(f"{target:g} t_ref: {ratio:.2f} of hydrostatic, top {1e3 * sum(tops) / max(len(tops), 1):.1f} mm")
    print(f"{run.rstrip('/').split('/')[-1]} (h {h * 1e3:.3g} mm, {ppe} points): " + " | ".join(out))

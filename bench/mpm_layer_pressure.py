#!/usr/bin/env python3
"""The pore pressure a saturated layer's body carries against hydrostatic,
frame by frame (issue 20; docs/RESULTS.md, session 39): the measure of
tests/mpm_run.rs `a_sliding_saturated_layer_keeps_its_hydrostatic_pore_pressure`
for any run of scenes/validation/mpm_sliding_layer.toml (e.g. on a rough
floor, `--set mpm.floor='"rough"'`, tilted by `--set domain.gravity=[...]`,
where the layer shears through its depth instead of sliding). Over the
body (4 cm in from both ends), sum V p / sum V rho_L g_n d, d the depth
below the highest liquid point of each 2 mm of x plus h/6; with the
body's mean speed (the clouds' `speed` field) of the liquid and solid points. With psi = 0
the soil neither dilates nor contracts as it shears, so 1 is exact for an
infinite layer with its water table at its surface (hence the body only).

usage: python3 bench/mpm_layer_pressure.py RUN_DIR [RUN_DIR ...]
"""
import struct, sys, tomllib
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory
for run in sys.argv[1:]:
    sc = tomllib.load(open(f"{run}/scene.toml", "rb"))
    gn = -sc["domain"]["gravity"][2]; rho = sc["fluids"][0]["density"]; h = sc["mpm"]["element_size"]
    out = []
    with open(f"{run}/run.mcap", "rb") as f:
        r = make_reader(f, decoder_factories=[DecoderFactory()])
        solid_speed = {}
        for _, ch, msg, m in r.iter_decoded_messages(topics=["/mpm/liquid", "/mpm/solid"]):
            t = msg.log_time * 1e-9
            n = len(m.data) // m.point_stride
            fl = [struct.unpack_from("<7f", m.data, i * m.point_stride) for i in range(n)]
            xs = [p[0] for p in fl]; back, front = min(xs), max(xs)
            body = [p for p in fl if back + 0.04 < p[0] < front - 0.04]
            if ch.topic == "/mpm/solid":
                solid_speed[round(t, 3)] = sum(p[3] for p in body) / max(len(body), 1)
                continue
            top = {}
            for p in fl:
                b = int(p[0] // 0.002); top[b] = max(top.get(b, -1e9), p[2] + h / 6)
            car = sum(p[6] * p[4] for p in body)
            hyd = sum(p[6] * rho * gn * (top[int(p[0] // 0.002)] - p[2]) for p in body)
            out.append((t, car / hyd if hyd else float('nan'), sum(p[3] for p in body) / max(len(body), 1)))
    ratios = [r for _, r, _ in out]
    print(f"{run}: the body's pore pressure {min(ratios):.3f}-{max(ratios):.3f} of hydrostatic over {len(out)} frames")
    for t, r, v in out[::3]:
        print(f"  t {t:.2f} s: {r:.3f} of hydrostatic; mean speed liquid {v:.3f}, solid {solid_speed.get(round(t, 3), float('nan')):.3f} m/s")

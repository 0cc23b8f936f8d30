#!/usr/bin/env python3
"""The DEM floor's friction as a layer of grains feels it, from runs of
scenes/validation/dem_basal_friction.toml under pushes k
(`domain.collapse_gravity` = [k g, 0, -g]). For the body of the layer
(the grains that start between 5 and 15 cm from the back wall, clear of
both ends), the mean x-speed over time of its bottom grain layer (centres
within 1.2 diameters of the floor), of the layers above, and of the whole
body. Below the floor's effective friction nothing moves; above it the
bottom layer runs out from under a still body (a block sliding on the
floor would move with one speed over the depth). Positions from
`/dem/particles` (f32), so speeds are displacements between frames
(10 ms apart), read until the layer's front nears the far wall.

usage: python3 bench/basal_friction.py RUN_DIR [RUN_DIR ...]
"""
import struct, sys, tomllib
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory


def frames(run):
    out = []
    with open(f"{run}/run.mcap", "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, _, m, c in reader.iter_decoded_messages(topics=["/dem/particles"]):
            n = len(c.data) // c.point_stride
            out.append((m.log_time * 1e-9, [struct.unpack_from("<4f", c.data, i * c.point_stride) for i in range(n)]))
    return out


times = [0.1, 0.2, 0.3, 0.4]
print("| run | k | floor's rolling friction | bottom grain layer's speed at " + " / ".join(f"{t:g}" for t in times)
      + " s (m/s) | the layers above | the body |")
print("|---|---|---|---|---|---|")
for run in sys.argv[1:]:
    scene = tomllib.load(open(f"{run}/scene.toml", "rb"))
    dom = scene["domain"]
    g = -dom["gravity"][2]
    k = dom.get("collapse_gravity", dom["gravity"])[0] / g
    d = scene["particles"][0]["diameter"]
    fs = frames(run)
    body = [i for i, p in enumerate(fs[0][1]) if 0.05 <= p[0] <= 0.15]
    # Pairs of frames 10 ms apart (a run's last frame may follow its last
    # regular one by a step), until the layer's front nears the far wall.
    far = dom["max"][0] - 2 * d
    pairs = [(fa, fb) for fa, fb in zip(fs, fs[1:]) if fb[0] - fa[0] > 0.005 and max(p[0] for p in fb[1]) < far]
    rows = []
    for (ta, a), (tb, b) in pairs:
        v = {i: (b[i][0] - a[i][0]) / (tb - ta) for i in body}
        mean = lambda sel: sum(v[i] for i in sel) / max(len(sel), 1)
        # The bottom layer: centres below 1.2 diameters, on the floor.
        bottom = [i for i in body if b[i][2] < 1.2 * d]
        above = [i for i in body if b[i][2] >= 1.2 * d]
        rows.append((0.5 * (ta + tb), mean(bottom), mean(above), mean(body)))

    def at(t, col):
        r = min(rows, key=lambda r: abs(r[0] - t))
        return f"{r[col]:.4f}" if abs(r[0] - t) < 0.01 else "–"

    mu_r = scene["dem"]["wall_rolling_friction"]
    print(f"| {run} | {k:.3f} | {mu_r:g} | " + " / ".join(at(t, 1) for t in times) + " | "
          + " / ".join(at(t, 2) for t in times) + " | " + " / ".join(at(t, 3) for t in times) + " |")

#!/usr/bin/env python3
"""What makes an MPM run's liquid front (docs/mpm.md, "The liquid's wall
shear", session 45): at every third recorded frame, the grains' 99.5 %
line (x from the back wall, in L0), the liquid's 99.5 % line and its
farthest point, how many liquid points lie beyond the grains' line, the
highest of them above the floor, their mean and largest speed, how many
are on the free surface, and how many liquid points share an element
with a solid point.

usage: python3 bench/mpm_liquid_front.py RUN_DIR
       (needs `pip install mcap mcap-protobuf-support`)
"""
import json
import struct
import sys
import tomllib
from collections import defaultdict

from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

run = sys.argv[1]
scene = tomllib.load(open(f"{run}/scene.toml", "rb"))
x0 = scene["domain"]["min"][0]
l0 = scene["analysis"]["column_length"]
h = scene.get("mpm", {}).get("element_size", 0.004)
t_ref = json.load(open(f"{run}/summary.json"))["t_ref"]
frames = defaultdict(dict)
with open(f"{run}/run.mcap", "rb") as f:
    reader = make_reader(f, decoder_factories=[DecoderFactory()])
    for _, channel, msg, m in reader.iter_decoded_messages(topics=["/mpm/liquid", "/mpm/solid"]):
        frames[msg.log_time][channel.topic] = m


def points(cloud, fields):
    """(x, y, z, field values...) of each point; liquid fields: speed,
    pore_pressure, free_surface, volume; solid: speed, porosity, p', fluidised."""
    n = len(cloud.data) // cloud.point_stride
    return [struct.unpack_from(f"<{3 + fields}f", cloud.data, i * cloud.point_stride) for i in range(n)]


times = sorted(frames)
print(f"{run}: x in L0 from the back wall (the runout is this less 1)")
print("| t/t_ref | grains 99.5 % | liquid 99.5 % | liquid max | liquid points beyond the grains | their top above the floor (mm) | mean / max speed (m/s) | on the free surface | liquid in elements with grains |")
print("|---|---|---|---|---|---|---|---|---|")
for t in times[::3] + [times[-1]]:
    fr = frames[t]
    if "/mpm/liquid" not in fr or "/mpm/solid" not in fr:
        continue
    liquid, solid = points(fr["/mpm/liquid"], 4), points(fr["/mpm/solid"], 4)
    xs = sorted((p[0] - x0) / l0 for p in solid)
    grains = xs[int(0.995 * len(xs))]
    lx = sorted((p[0] - x0) / l0 for p in liquid)
    beyond = [p for p in liquid if (p[0] - x0) / l0 > grains]
    speeds = [p[3] for p in beyond]
    occupied = {(int((p[0] - x0) / h), int(p[2] / h)) for p in solid}
    shared = sum(1 for p in liquid if (int((p[0] - x0) / h), int(p[2] / h)) in occupied)
    mean = sum(speeds) / len(speeds) if speeds else 0.0
    print(f"| {t * 1e-9 / t_ref:.2f} | {grains:.2f} | {lx[int(0.995 * len(lx))]:.2f} | {lx[-1]:.2f} | {len(beyond)} | "
          f"{max((p[2] for p in beyond), default=0.0) * 1e3:.2f} | {mean:.3f} / {max(speeds, default=0.0):.3f} | "
          f"{sum(1 for p in beyond if p[5] > 0.5)} | {shared} / {len(liquid)} |")

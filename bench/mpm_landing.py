#!/usr/bin/env python3
"""Coulomb's impulse law at an MPM wall (docs/mpm.md, "Frictional walls",
limit "impacts"): a dry block dropped onto a frictional floor while pushed
along it slides through its landings, so the floor's friction impulse must
be mu times its normal impulse at every moment. From `/mpm/metrics`
(momentum_solid_x/z, solid_mass), with only gravity (g_x, -g) and the floor
acting: J_n = P_z(t) - P_z(0) + M g t, J_f = M g_x t - (P_x(t) - P_x(0)).
Prints, every `--every` frames, the velocities, both impulses per unit mass
and J_f / (mu J_n), which is 1 where the law holds (nan before the first
contact).

The run (scenes/validation/mpm_sliding_block.toml lifted 6 mm, g_x = 0.3 g,
mu = 0.1 by the scene):
  target/release/coupler run scenes/validation/mpm_sliding_block.toml --out RUN \\
    --set "domain.gravity=[2.943, 0.0, -9.81]" \\
    --set 'particles[0].packing.region={ min = [0.02, 0.0, 0.006], max = [0.04, 0.05, 0.014] }' \\
    --set output.record_interval=0.0005 --set output.end_time=0.1 --set output.stop_at_rest=false
usage: python3 bench/mpm_landing.py RUN MU G_X [--every N]
"""
import sys
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

run, mu, gx = sys.argv[1], float(sys.argv[2]), float(sys.argv[3])
every = int(sys.argv[sys.argv.index("--every") + 1]) if "--every" in sys.argv else 8
g = 9.81
rows = []
with open(f"{run}/run.mcap", "rb") as f:
    reader = make_reader(f, decoder_factories=[DecoderFactory()])
    for _, _, msg, m in reader.iter_decoded_messages(topics=["/mpm/metrics"]):
        rows.append((msg.log_time * 1e-9, m))
t0, m0 = rows[0]
mass = m0.solid_mass
print("| t (s) | v_z | v_x | J_n / M | J_f / M | J_f / (mu J_n) |")
print("|---|---|---|---|---|---|")
for t, m in rows[::every]:
    dt = t - t0
    jn = (m.momentum_solid_z - m0.momentum_solid_z) + mass * g * dt
    jf = mass * gx * dt - (m.momentum_solid_x - m0.momentum_solid_x)
    ratio = jf / (mu * jn) if jn > 1e-6 * mass else float("nan")
    print(f"| {t:.4f} | {m.momentum_solid_z / mass:+.4f} | {m.momentum_solid_x / mass:.4f} | {jn / mass:.5f} | {jf / mass:.5f} | {ratio:.3f} |")

#!/usr/bin/env python3
"""Where the grains' outward momentum comes from, from `coupler run`
recordings (`/dem/metrics` fields momentum_x and fluid_impulse_x;
docs/recording.md): at each t/t_ref, the grains' x-momentum P_x, the part
the liquid gave them (the impulse of the hydrodynamic loads, J_fluid) and
the rest, given by the walls and the floor (P_x - J_fluid: the back wall
pushes, the floor's friction holds back). Momenta are scaled by
M sqrt(g_eff H0), M the grains' mass, g_eff = g dry and g' saturated.

For an MPM run (`/mpm/metrics` liquid_force_on_solid_x, session 33) the
liquid's force on the solid over the grains' buoyant weight, each value
the mean of the frames within 0.25 t_ref of the time (each frame's is
already the mean over its steps).

usage: python3 bench/momentum_budget.py RUN_DIR [RUN_DIR ...]
"""
import json, sys, tomllib
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

times = [0.5, 1, 1.5, 2, 3, 4, 6, 8]


def mpm_push(run, scene, g, rho_s, rho_l):
    rows = []
    with open(f"{run}/run.mcap", "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, _, _, m in reader.iter_decoded_messages(topics=["/mpm/metrics"]):
            rows.append(m)
    if not hasattr(rows[0], "liquid_force_on_solid_x"):
        sys.exit(f"{run}: its /mpm/metrics has no liquid_force_on_solid_x (recorded since session 33): run it again")
    # Buoyant weight of the grains, N/m: the solid points carry the grains' mass.
    weight = rows[0].solid_mass * g * (rho_s - rho_l) / rho_s
    print(f"{run} (MPM): the liquid's force on the solid / the grains' buoyant weight")
    print("| t/t_ref | x | z |")
    print("|---|---|---|")
    for t in times:
        near = [r for r in rows if abs(r.t_norm - t) <= 0.25]
        if not near:
            continue
        fx = sum(r.liquid_force_on_solid_x for r in near) / len(near)
        fz = sum(r.liquid_force_on_solid_z for r in near) / len(near)
        print(f"| {t:g} | {fx / weight:+.3f} | {fz / weight:+.3f} |")

for run in sys.argv[1:]:
    scene = tomllib.load(open(f"{run}/scene.toml", "rb"))
    g = -scene["domain"]["gravity"][2]
    h0 = scene["analysis"]["column_height"]
    rho_s = scene["particles"][0]["density"]
    saturated = scene["analysis"].get("condition") == "saturated"
    rho_l = scene["fluids"][0]["density"] if saturated else 0.0
    g_eff = g * (rho_s - rho_l) / rho_s
    summary = json.load(open(f"{run}/summary.json"))
    if summary["method"] == "mpm":
        mpm_push(run, scene, g, rho_s, rho_l)
        continue
    rows = []
    with open(f"{run}/run.mcap", "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, _, _, m in reader.iter_decoded_messages(topics=["/dem/metrics"]):
            rows.append(m)
    # Grains' mass from the kinetic energy is not recorded: use the packing's.
    n, d = summary["dem"]["particles"], scene["particles"][0]["diameter"]
    if scene["particles"][0].get("diameter_spread", 0.0) or len(scene["particles"]) > 1:
        sys.exit(f"{run}: grains of one size only (the mass is n rho pi D^3/6)")
    mass = n * rho_s * 3.141592653589793 / 6.0 * d**3
    scale = mass * (g_eff * h0) ** 0.5
    peak = max(rows, key=lambda m: m.momentum_x)
    print(f"{run} ({'saturated' if saturated else 'dry'}): P_x peak {peak.momentum_x / scale:.3f} at t/t_ref {peak.t_norm:.2f}")
    print("| t/t_ref | P_x | from the liquid | from walls and floor | liquid's force / buoyant weight |")
    print("|---|---|---|---|---|")
    weight = mass * g_eff
    for t in times:
        m = min(rows, key=lambda r: abs(r.t_norm - t))
        print(f"| {m.t_norm:.2f} | {m.momentum_x / scale:.3f} | {m.fluid_impulse_x / scale:.3f} | "
              f"{(m.momentum_x - m.fluid_impulse_x) / scale:.3f} | {m.fluid_force_x / weight:+.3f} |")

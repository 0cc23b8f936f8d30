#!/usr/bin/env python3
"""Where the grains' outward momentum comes from, from `coupler run`
recordings (`/dem/metrics` fields momentum_x and fluid_impulse_x;
docs/recording.md): at each t/t_ref, the grains' x-momentum P_x, the part
the liquid gave them (the impulse of the hydrodynamic loads, J_fluid) and
the rest, given by the walls and the floor (P_x - J_fluid: the back wall
pushes, the floor's friction holds back). Momenta are scaled by
M sqrt(g_eff H0), M the grains' mass, g_eff = g dry and g' saturated.

For an MPM run (`/mpm/metrics` momentum_solid_x and
liquid_force_on_solid_x, sessions 33-34) the same budget, the liquid's
impulse summed over the frames (each frame's force is the mean over its
steps), a push along x (`domain.collapse_gravity`) as a column of its own,
and the liquid's force over the grains' buoyant weight as the mean of
the frames within 0.25 t_ref of the time (the DEM's is the frame's own).
The rest is what the walls, the floor and the damping gave, and the
liquid's force at wall-held nodes, which the recorded force leaves out.
Runs recorded before session 34 (no momentum) get the force alone.

usage: python3 bench/momentum_budget.py RUN_DIR [RUN_DIR ...]
"""
import json, sys, tomllib
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

times = [0.5, 1, 1.5, 2, 3, 4, 6, 8]


def mpm_budget(run, scene, g, rho_s, rho_l, h0):
    rows = []
    with open(f"{run}/run.mcap", "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, _, _, m in reader.iter_decoded_messages(topics=["/mpm/metrics"]):
            rows.append(m)
    if not hasattr(rows[0], "liquid_force_on_solid_x"):
        sys.exit(f"{run}: its /mpm/metrics has no liquid_force_on_solid_x (recorded since session 33): run it again")
    # The solid points carry the grains' mass; their buoyant weight, N/m.
    mass = rows[0].solid_mass
    g_eff = g * (rho_s - rho_l) / rho_s
    weight = mass * g_eff
    if not hasattr(rows[0], "momentum_solid_x"):
        # Recorded before session 34: the force alone.
        print(f"{run} (MPM, no momentum recorded): the liquid's force on the solid / the grains' buoyant weight")
        print("| t/t_ref | x | z |")
        print("|---|---|---|")
        for t in times:
            near = [r for r in rows if abs(r.t_norm - t) <= 0.25]
            if near:
                fx = sum(r.liquid_force_on_solid_x for r in near) / len(near)
                fz = sum(r.liquid_force_on_solid_z for r in near) / len(near)
                print(f"| {t:g} | {fx / weight:+.3f} | {fz / weight:+.3f} |")
        return
    scale = mass * (g_eff * h0) ** 0.5
    # A push along x (`domain.collapse_gravity`) gives M g_x t.
    g_x = scene["domain"].get("collapse_gravity", scene["domain"]["gravity"])[0]
    # The liquid's impulse: each frame's force is the mean over its steps.
    impulse, prev, budget = 0.0, None, []
    for r in rows:
        if prev is not None:
            impulse += r.liquid_force_on_solid_x * (r.t - prev.t)
        budget.append((r, impulse))
        prev = r
    peak = max(rows, key=lambda m: m.momentum_solid_x)
    print(f"{run} (MPM): P_x peak {peak.momentum_solid_x / scale:.3f} at t/t_ref {peak.t_norm:.2f}")
    print("| t/t_ref | P_x | from the liquid | from the push | from walls, floor and damping | liquid's force / buoyant weight |")
    print("|---|---|---|---|---|---|")
    for t in times:
        r, j = min(budget, key=lambda b: abs(b[0].t_norm - t))
        if abs(r.t_norm - t) > 0.25:
            continue
        # The force as a mean over the frames within 0.25 t_ref, as before.
        near = [b[0] for b in budget if abs(b[0].t_norm - t) <= 0.25]
        fx = sum(n.liquid_force_on_solid_x for n in near) / len(near)
        push = mass * g_x * r.t
        print(f"| {r.t_norm:.2f} | {r.momentum_solid_x / scale:.3f} | {j / scale:.3f} | {push / scale:.3f} | "
              f"{(r.momentum_solid_x - j - push) / scale:.3f} | {fx / weight:+.3f} |")


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
        mpm_budget(run, scene, g, rho_s, rho_l, h0)
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

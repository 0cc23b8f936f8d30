#!/usr/bin/env python3
"""Table of `dem_proc biaxial` records (docs/dem.md, "Element test"): one
row per record, then the large-strain friction angle's mean and spread
over the records at each confining stress.

usage: python3 bench/biaxial_table.py RECORD.json ...
"""
import json, math, statistics, sys

rows = []
for path in sys.argv[1:]:
    r = json.load(open(path))
    s, spec = r["summary"], r["spec"]
    rows.append((r["preparation_friction"], spec["seed"], spec["confining_stress"], s))

rows.sort(key=lambda x: (x[2], x[0], x[1]))
print("| prep. μ | seed | σ_3 Pa | core n_0 | box n_0 | z_0 | φ_peak ° (at ε_1) | ψ_peak ° (at ε_1) | φ at ε_1 ≥ 0.225 ° | ψ there ° | box n at the end |")
print("|---|---|---|---|---|---|---|---|---|---|---|")
for mu, seed, sigma, s in rows:
    print(f"| {mu:g} | {seed} | {sigma:g} | {s['initial_core_porosity']:.3f} | {s['initial_porosity']:.3f} | "
          f"{s['initial_coordination']:.2f} | {s['peak_friction_deg']:.1f} ({s['peak_axial_strain']:.3f}) | "
          f"{s['peak_dilatancy_deg']:.1f} ({s['peak_dilatancy_axial_strain']:.3f}) | {s['final_friction_deg']:.1f} | "
          f"{s['final_dilatancy_deg']:.1f} | {s['final_porosity']:.3f} |")
for sigma in sorted({x[2] for x in rows}):
    phis = [x[3]["final_friction_deg"] for x in rows if x[2] == sigma]
    psis = [x[3]["final_dilatancy_deg"] for x in rows if x[2] == sigma]
    sd = statistics.stdev(phis) if len(phis) > 1 else float("nan")
    print(f"\nσ_3 = {sigma:g} Pa, {len(phis)} records: large-strain φ = {statistics.mean(phis):.1f}° ± {sd:.1f}° "
          f"(sin φ = {math.sin(math.radians(statistics.mean(phis))):.3f}), ψ = {statistics.mean(psis):.1f}°")

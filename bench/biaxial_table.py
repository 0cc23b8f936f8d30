#!/usr/bin/env python3
"""Table of `dem_proc biaxial` records (docs/dem.md, "Element test"): one
row per record, then the large-strain friction angle's mean and spread
over the records at each confining stress.

Besides the record's summary, two figures of the dilating phase, from the
samples: its volumetric strain Δε_v from the most compacted to the most
dilated state within the first 15 % of axial strain, and the mean
dilatancy angle over it, asin(−Δε_v/Δγ) (the angle a Mohr–Coulomb soil
with a dilatancy cut-off needs to gain the same volume over the same
shear).

usage: python3 bench/biaxial_table.py RECORD.json ...
"""
import json, math, statistics, sys


def dilating_phase(samples):
    first = [s for s in samples if s["axial_strain"] <= 0.15]
    a = max(first, key=lambda s: s["volumetric_strain"])
    b = min(first, key=lambda s: s["volumetric_strain"])
    gamma = lambda s: s["axial_strain"] - s["lateral_strain"]
    dev = b["volumetric_strain"] - a["volumetric_strain"]
    return dev, math.degrees(math.asin(-dev / (gamma(b) - gamma(a))))


rows = []
for path in sys.argv[1:]:
    r = json.load(open(path))
    rows.append((r["preparation_friction"], r["spec"]["seed"], r["spec"]["confining_stress"], r["summary"], dilating_phase(r["samples"])))

rows.sort(key=lambda x: (x[2], x[0], x[1]))
print("| prep. μ | seed | σ_3 Pa | core n_0 | box n_0 | z_0 | φ_peak ° (at ε_1) | ψ_peak ° (at ε_1) | dilating phase: Δε_v, mean ψ ° | φ at ε_1 ≥ 0.225 ° | ψ there ° | core / box n at the end |")
print("|---|---|---|---|---|---|---|---|---|---|---|---|")
for mu, seed, sigma, s, (dev, psi_mean) in rows:
    print(f"| {mu:g} | {seed} | {sigma:g} | {s['initial_core_porosity']:.3f} | {s['initial_porosity']:.3f} | "
          f"{s['initial_coordination']:.2f} | {s['peak_friction_deg']:.1f} ({s['peak_axial_strain']:.3f}) | "
          f"{s['peak_dilatancy_deg']:.1f} ({s['peak_dilatancy_axial_strain']:.3f}) | {dev:.3f}, {psi_mean:.1f} | "
          f"{s['final_friction_deg']:.1f} | {s['final_dilatancy_deg']:.1f} | {s['final_core_porosity']:.3f} / {s['final_porosity']:.3f} |")
for sigma in sorted({x[2] for x in rows}):
    phis = [x[3]["final_friction_deg"] for x in rows if x[2] == sigma]
    psis = [x[3]["final_dilatancy_deg"] for x in rows if x[2] == sigma]
    sd = statistics.stdev(phis) if len(phis) > 1 else float("nan")
    print(f"\nσ_3 = {sigma:g} Pa, {len(phis)} records: large-strain φ = {statistics.mean(phis):.1f}° ± {sd:.1f}° "
          f"(sin φ = {math.sin(math.radians(statistics.mean(phis))):.3f}), ψ = {statistics.mean(psis):.1f}°")

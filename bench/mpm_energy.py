#!/usr/bin/env python3
"""Whether an MPM column comes to rest, from `coupler run` recordings
(`/mpm/metrics`, docs/recording.md): at each t/t_ref the solid front, the
solid's kinetic energy on the points and as the grid holds it, both as a
share of the potential energy the solid released by the end of the run,
and the time from which the larger of the two stays below 1e-4 (issue
20's rest criterion). The liquid is reported beside it: water still draining
out of a deposit at rest is physics, not a failure to stop.

usage: python3 bench/mpm_energy.py RUN_DIR [RUN_DIR ...]
"""
import json, os, sys
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

times = [1, 2, 4, 6, 8]
REST = 1e-4
print(f"{'run':<34} {'runout':>7} {'rest@':>6}  front, KE_s/PE_s (points | grid), KE_l/PE_s at t/t_ref = {times}")
for run in sys.argv[1:]:
    rows = []
    if not os.path.exists(f"{run}/summary.json"):
        print(f"{run:<34} (not finished)")
        continue
    with open(f"{run}/run.mcap", "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, _, _, m in reader.iter_decoded_messages(topics=["/mpm/metrics"]):
            rows.append(m)
    if not rows:
        sys.exit(f"{run}: no /mpm/metrics in run.mcap")
    if rows[0].potential_energy_solid == 0.0:
        sys.exit(f"{run}: recorded before potential energy was in /mpm/metrics; rerun it")
    released = rows[0].potential_energy_solid - rows[-1].potential_energy_solid
    summary = json.load(open(f"{run}/summary.json"))
    # Rest: the first frame after which the solid's share never rises above
    # REST, its energy taken as the larger of the points' own ½ m v² and
    # the grid's: under APIC the points also carry an affine part that
    # ½ m v² leaves out and the grid holds.
    rest = float("nan")
    for r in reversed(rows):
        if max(r.kinetic_energy_solid, r.kinetic_energy_solid_grid) / released >= REST:
            break
        rest = r.t_norm
    cells = []
    for t in times:
        r = min(rows, key=lambda r: abs(r.t_norm - t))
        if abs(r.t_norm - t) > 0.2:
            cells.append("—")
            continue
        cells.append(
            f"{r.front_norm:.2f} {r.kinetic_energy_solid / released:.1e}|{r.kinetic_energy_solid_grid / released:.1e} "
            f"{r.kinetic_energy_liquid / released:.1e}"
        )
    print(f"{run:<34} {summary['runout']:7.3f} {rest:6.2f}  " + "  ".join(cells))

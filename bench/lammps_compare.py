#!/usr/bin/env python3
"""Side-by-side with LAMMPS's granular pair style on the same packing.

usage: python3 bench/lammps_compare.py [--scene SCENE] [--steps N] [--full]

Needs LAMMPS (Debian: apt-get install lammps; provides `lmp` and `mpirun`).
Both codes run the scene's packing (deposited and cached by dem_proc) with the
same contact law, time step and skin, with rolling resistance off because
LAMMPS's gran/hooke/history has none (mapping: dem_proc/src/lammps.rs).

Throughput: N collapse steps, dem_proc on 1 and 2 threads, LAMMPS on 1 and 2
MPI ranks; prints particle-steps/s and the ratios per core.
Then the same with rolling resistance μ_r = 0.05 in both: dem_proc's limited
constant torque against LAMMPS's `pair_style granular` with `rolling sds`.
--full: also runs both to 8 t_ref and compares the runouts (front = x beyond
which 0.5 % of the mass lies, leading edge of the grains, as in summary.json).
"""
import argparse
import json
import math
import os
import re
import shutil
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
NO_ROLLING = ["--set", "dem.rolling_friction=0", "--set", "dem.wall_rolling_friction=0"]


def run(cmd, cwd=ROOT, **kw):
    return subprocess.run(cmd, cwd=cwd, check=True, text=True, capture_output=True, **kw)


def ours(scene, steps, threads, extra=()):
    out = run([f"{ROOT}/target/release/dem_proc", "bench", scene, "--steps", str(steps), "--threads", str(threads), *NO_ROLLING, *extra])
    return json.loads(out.stdout.strip().splitlines()[-1])


def lammps(workdir, ranks):
    cmd = ["lmp", "-in", "in.collapse", "-log", f"log.{ranks}"]
    if ranks > 1:
        cmd = ["mpirun", "--allow-run-as-root", "--oversubscribe", "-np", str(ranks)] + cmd
    out = run(cmd, cwd=workdir)
    m = re.search(r"Loop time of ([0-9.eE+-]+) on (\d+) procs for (\d+) steps with (\d+) atoms", out.stdout)
    seconds, _, steps, atoms = float(m.group(1)), int(m.group(2)), int(m.group(3)), int(m.group(4))
    return {"seconds": seconds, "steps": steps, "particles": atoms, "particle_steps_per_s": steps * atoms / seconds}


def front_from_dump(path, x0, fraction=0.005):
    rows = []
    with open(path) as f:
        lines = f.read().splitlines()
    start = next(i for i, l in enumerate(lines) if l.startswith("ITEM: ATOMS")) + 1
    for l in lines[start:]:
        _id, x, _y, _z, r, m = map(float, l.split())
        rows.append((x + r, m))
    rows.sort(reverse=True)
    total = sum(m for _, m in rows)
    beyond = 0.0
    for x, m in rows:
        beyond += m
        if beyond > fraction * total:
            return x
    return rows[-1][0]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default="scenes/ceccato2020/dry_h060.toml")
    ap.add_argument("--steps", type=int, default=10000)
    ap.add_argument("--full", action="store_true")
    a = ap.parse_args()
    if shutil.which("lmp") is None:
        sys.exit("LAMMPS not found: install it with `apt-get install lammps`")
    run(["cargo", "build", "--release", "-p", "dem_proc", "-p", "coupler"])
    work = os.path.join(ROOT, "target", "lammps-compare")
    os.makedirs(work, exist_ok=True)
    run([f"{ROOT}/target/release/dem_proc", "export-lammps", a.scene, "--out", work, "--steps", str(a.steps), *NO_ROLLING])

    print(f"scene {a.scene}, {a.steps} collapse steps, rolling resistance off in both")
    results = {}
    for t in (1, 2):
        results[f"dem_proc {t} thread{'s' if t > 1 else ''}"] = ours(a.scene, a.steps, t)
    for r in (1, 2):
        results[f"LAMMPS {r} rank{'s' if r > 1 else ''}"] = lammps(work, r)
    for name, res in results.items():
        print(f"  {name:<20} {res['particle_steps_per_s']:.3e} particle-steps/s  ({res['particles']} grains, {res['seconds']:.2f} s)")
    for n in (1, 2):
        o = results[f"dem_proc {n} thread{'s' if n > 1 else ''}"]["particle_steps_per_s"]
        l = results[f"LAMMPS {n} rank{'s' if n > 1 else ''}"]["particle_steps_per_s"]
        print(f"  ratio dem_proc / LAMMPS on {n} core{'s' if n > 1 else ''}: {o / l:.2f}")
    # Rolling resistance on, μ_r = 0.05, against LAMMPS's pair granular with
    # its rolling sds model (dem_proc/src/lammps.rs: another rolling law,
    # the same work per contact).
    rolling = ["--set", "dem.rolling_friction=0.05", "--set", "dem.wall_rolling_friction=0.05"]
    roll_work = os.path.join(work, "rolling")
    os.makedirs(roll_work, exist_ok=True)
    run([f"{ROOT}/target/release/dem_proc", "export-lammps", a.scene, "--out", roll_work, "--steps", str(a.steps), "--rolling", *rolling])
    print("rolling resistance 0.05 (LAMMPS: pair_style granular, rolling sds):")
    for n in (1, 2):
        o = ours(a.scene, a.steps, n, extra=rolling)
        l = lammps(roll_work, n)
        print(f"  {n} core{'s' if n > 1 else ''}: dem_proc {o['particle_steps_per_s']:.3e}, LAMMPS {l['particle_steps_per_s']:.3e} particle-steps/s, ratio {o['particle_steps_per_s'] / l['particle_steps_per_s']:.2f}")

    if a.full:
        # 8 t_ref of the dry column, both codes, rolling off.
        scene_text = open(os.path.join(ROOT, a.scene)).read()
        h0 = float(re.search(r"column_height\s*=\s*([0-9.eE+-]+)", scene_text).group(1))
        l0 = float(re.search(r"column_length\s*=\s*([0-9.eE+-]+)", scene_text).group(1))
        t_end = 8.0 * math.sqrt(h0 / 9.81)
        out = os.path.join(work, "ours")
        run([f"{ROOT}/target/release/coupler", "run", a.scene, "--quiet", "--out", out, *NO_ROLLING,
             "--set", f"output.end_time={t_end}", "--set", "output.stop_at_rest=false"])
        s = json.load(open(os.path.join(out, "summary.json")))
        dt = s["dem"]["time_step"]
        steps = int(math.ceil(t_end / dt))
        run([f"{ROOT}/target/release/dem_proc", "export-lammps", a.scene, "--out", work, "--steps", str(steps), *NO_ROLLING])
        full = lammps(work, 2)
        x_l = front_from_dump(os.path.join(work, "final.dump"), 0.0)
        print(f"full collapse to 8 t_ref = {t_end:.4f} s ({steps} steps), rolling off:")
        print(f"  dem_proc runout (L_f - L0)/L0 = {s['runout']:.3f}  wall {s['wall_seconds']:.1f} s")
        print(f"  LAMMPS   runout (L_f - L0)/L0 = {(x_l - l0) / l0:.3f}  wall {full['seconds']:.1f} s")


if __name__ == "__main__":
    main()

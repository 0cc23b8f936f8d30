#!/usr/bin/env bash
# The drag study of Ceccato et al. 2020 §5.3 with the MPM: the a = 1.5
# saturated column scaled 100x, four (D, mu) pairs spanning Re_p = 2e3..2e6,
# each with and without the quadratic (Forchheimer) drag term. Prints, per
# case, the solid and liquid fronts (X_f - L0)/L0 at 2 t_ref, 4 t_ref and at
# the end, and how far the liquid front leads the solid one.
# Usage: bash bench/mpm_drag_study.sh [OUT_DIR]   (about a minute on 2 cores)
set -euo pipefail
cd "$(dirname "$0")/.."
out="${1:-runs/mpm_drag_study}"
cargo build --release -q
mkdir -p "$out"
for f in scenes/mpm_drag_study/drag_*.toml; do
  n=$(basename "$f" .toml)
  target/release/coupler run "$f" --quiet --out "$out/$n" >"$out/$n.log" 2>&1
  target/release/coupler run "$f" --quiet --out "$out/${n}_linear" --set mpm.quadratic_drag=false >"$out/${n}_linear.log" 2>&1
done
python3 - "$out" <<'PY'
import json, math, sys, glob, os
out = sys.argv[1]
def at(front, tn):
    best = min(front, key=lambda f: abs(f["t_norm"] - tn))
    return best["x_norm"]
print(f"{'scene':34s} {'Re_p':>8s} {'drag':>9s} {'solid 2t':>8s} {'4t':>6s} {'end':>6s} {'liquid 2t':>9s} {'4t':>6s} {'end':>6s} {'lead end':>8s} {'wall s':>6s}")
for d in sorted(glob.glob(os.path.join(out, "drag_*"))):
    if not os.path.isdir(d):
        continue
    s = json.load(open(os.path.join(d, "summary.json")))
    scene = open(os.path.join(d, "scene.toml")).read()
    dia = float(scene.split("diameter = ")[1].split("\n")[0])
    mu = float(scene.split("viscosity = ")[1].split("\n")[0])
    re = dia * 1000.0 * math.sqrt(9.81 * 6.0) / mu
    sf, lf = s["front"], s["liquid_front"]
    drag = "quadratic" if s["mpm"]["quadratic_drag"] else "linear"
    print(f"{os.path.basename(d):34s} {re:8.2e} {drag:>9s} {at(sf,2):8.3f} {at(sf,4):6.3f} {sf[-1]['x_norm']:6.3f} {at(lf,2):9.3f} {at(lf,4):6.3f} {lf[-1]['x_norm']:6.3f} {lf[-1]['x_norm']-sf[-1]['x_norm']:8.3f} {s['wall_seconds']:6.1f}")
PY

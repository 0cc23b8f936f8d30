#!/usr/bin/env bash
# Convergence of the saturated H0 = 0.06 m column (issue 19, part 4): the
# lattice spacing at fixed Mach number (dt scaled with dx, the DEM step kept
# at 1.40e-6 s by scaling coupling.ratio), and the DEM sub-step ratio at the
# paper's dx. Every case starts from the same cached packing and runs to
# END seconds (default 0.4 s = 4 t_ref). Prints one line per case: D/dx,
# dt, ratio, lattice cells, wall time, the front (0.5 % rule) and the
# liquid front at t/t_ref = 1, 2, 4, and the connected front at 4.
# usage: bash bench/sat_convergence.sh [OUT_DIR] [CASES] [END]
#   CASES: any of dx833 dx600 dx500 dx417 r30 r15 nte (default: all but
#   dx417 and nte); nte is dx600 with coupling.forcing_gain =
#   "noble_torczynski_effective" (docs/coupling.md, "Choosing the forcing gain")
#   BIN=DIR runs the coupler (and the dem_proc/lbm_proc beside it) from DIR
#   instead of building target/release, so a long campaign survives rebuilds;
#   a case whose summary.json exists is not rerun, only reported.
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-runs/sat_convergence}
cases=${2:-"dx833 dx600 dx500 r30 r15"}
end=${3:-0.4}
bin=${BIN:-}
if [ -z "$bin" ]; then
  cargo build --release -p coupler -p dem_proc -p lbm_proc
  bin=target/release
fi
mkdir -p "$out"
# name: spacing (m), time step (s), ratio. dx divides 0.05, 0.70 and 0.12 m.
declare -A spacing=([dx833]=8.3333333333333333e-4 [dx600]=6.0e-4 [dx500]=5.0e-4 [dx417]=4.1666666666666667e-4 [r30]=6.0e-4 [r15]=6.0e-4 [nte]=6.0e-4)
declare -A ratio=([dx833]=79 [dx600]=57 [dx500]=48 [dx417]=40 [r30]=30 [r15]=15 [nte]=57)
declare -A gain=([nte]=noble_torczynski_effective)
printf '%-6s %6s %10s %5s %10s %8s %s\n' case D/dx dt ratio cells wall_s "front@1 2 4 | liquid@1 2 4 | connected@4"
for c in $cases; do
  dx=${spacing[$c]}
  dt=$(python3 -c "print(8.0e-5 * $dx / 6.0e-4)")
  [ -f "$out/$c/summary.json" ] || "$bin/coupler" run scenes/ceccato2020/sat_h060.toml --quiet --out "$out/$c" \
    --set lbm.spacing="$dx" --set lbm.time_step="$dt" --set coupling.ratio="${ratio[$c]}" \
    --set output.end_time="$end" --set output.stop_at_rest=false \
    --set coupling.forcing_gain="${gain[$c]:-noble_torczynski}" 2> "$out/$c.log"
  python3 - "$out/$c/summary.json" "$c" "$dx" "$dt" "${ratio[$c]}" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
def at(series, key, t):
    pts = [(f["t_norm"], f[key]) for f in series if f.get(key) is not None]
    for (t0, x0), (t1, x1) in zip(pts, pts[1:]):
        if t0 <= t <= t1:
            return x0 + (x1 - x0) * (t - t0) / (t1 - t0)
    return float("nan")
f, lf, cf = s["front"], s.get("liquid_front", []), s.get("front_connected", [])
dims = s["lbm"]["dims"]
front = " ".join(f"{at(f, 'x_norm', t):.3f}" for t in (1, 2, 4))
liquid = " ".join(f"{at(lf, 'x_norm', t):.3f}" for t in (1, 2, 4))
print(f"{sys.argv[2]:<6} {2.5e-3 / float(sys.argv[3]):>6.2f} {float(sys.argv[4]):>10.3e} {sys.argv[5]:>5} "
      f"{dims[0] * dims[1] * dims[2]:>10} {s['wall_seconds']:>8.0f} {front} | {liquid} | {at(cf, 'x_norm', 4):.3f}")
PY
done

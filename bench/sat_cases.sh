#!/usr/bin/env bash
# Runs the saturated columns of Ceccato et al. 2020 (Table 1) through coupler
# (DEM-LBM, sequential schedule, to the scenes' end at ~8.5 t_ref) and prints
# one line per case: grains, porosity, wall time, front at 2 t_ref, runout,
# connected runout, and the dry case's runout when runs/dry_cases holds it
# (bash bench/dry_cases.sh). Each case takes 15-35 minutes on 2 cores.
# usage: bash bench/sat_cases.sh [OUT_DIR] [CASES]   (default runs/sat_cases, "030 040 050 060 070")
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-runs/sat_cases}
cases=${2:-"030 040 050 060 070"}
cargo build --release -p coupler -p dem_proc -p lbm_proc
mkdir -p "$out"
printf '%-9s %7s %9s %9s %10s %9s %8s %10s %8s\n' case grains porosity status wall_s front@2 runout connected dry
for h in $cases; do
  target/release/coupler run "scenes/ceccato2020/sat_h$h.toml" --quiet --out "$out/sat_h$h" 2> "$out/sat_h$h.log"
  python3 - "$out/sat_h$h/summary.json" "runs/dry_cases/dry_h$h/summary.json" <<'PY'
import json, os, sys
s = json.load(open(sys.argv[1]))
front2 = min(s["front"], key=lambda f: abs(f["t_norm"] - 2.0))["x_norm"]
dry = json.load(open(sys.argv[2]))["runout"] if os.path.exists(sys.argv[2]) else float("nan")
print(f"{s['scene']:<9} {s['dem']['particles']:>7} {s['porosity_initial']:>9.4f} {s['status']:>9} {s['wall_seconds']:>10.1f} "
      f"{front2:>9.2f} {s['runout']:>8.2f} {s.get('runout_connected', float('nan')):>10.2f} {dry:>8.2f}")
PY
done

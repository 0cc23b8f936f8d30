#!/usr/bin/env bash
# Runs the ten MPM columns of Ceccato et al. 2020 (Table 1, dry and
# saturated, H0 = 0.03 ... 0.07 m) through coupler and prints one line per
# case: points, element, status, t/t_ref, wall time, point-updates/s, solid
# runout and (saturated) liquid front at the end.
# usage: bash bench/mpm_cases.sh [OUT_DIR [--set KEY=VALUE ...]]
#   (default runs/mpm_cases; ~3 min on 2 cores). Any further arguments go to
#   every `coupler run`, e.g. `--set mpm.friction_angle=27` (docs/RESULTS.md).
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-runs/mpm_cases}
shift || true
cargo build --release -q -p coupler -p mpm_proc
mkdir -p "$out"
printf '%-13s %5s %7s %9s %8s %8s %8s %11s %7s %7s\n' case a points element status t/t_ref wall_s pt-upd/s runout liquid
for kind in dry sat; do
  for h in 030 040 050 060 070; do
    n="mpm_${kind}_h$h"
    target/release/coupler run "scenes/ceccato2020/$n.toml" --quiet --out "$out/$n" "$@" 2> "$out/$n.log"
    python3 - "$out/$n/summary.json" <<'PY'
import json, sys
s = json.load(open(sys.argv[1])); m = s["mpm"]
h0 = {"030": 0.03, "040": 0.04, "050": 0.05, "060": 0.06, "070": 0.07}[s["scene"][-3:]]
lf = s.get("liquid_front") or []
liquid = f"{lf[-1]['x_norm']:7.3f}" if lf else "      -"
print(f"{s['scene']:<13} {h0/0.04:5.2f} {m['solid_points'] + m['liquid_points']:>7} {m['element_size']*1000:7.2f}mm {s['status']:>8} "
      f"{s['sim_time']/s['t_ref']:>8.2f} {s['wall_seconds']:>8.1f} {s['throughput']['point_updates_per_s']:>11.3e} {s['runout']:>7.3f} {liquid}")
PY
  done
done

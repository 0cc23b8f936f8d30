#!/usr/bin/env bash
# Runs the five dry columns of Ceccato et al. 2020 (Table 1) through coupler
# and prints one line per case: grains, porosity, wall times, runout.
# Then measures what recording costs on the H0 = 0.06 m column.
# usage: bash bench/dry_cases.sh [OUT_DIR]   (default runs/dry_cases)
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-runs/dry_cases}
cargo build --release -p coupler -p dem_proc
mkdir -p "$out"
printf '%-9s %7s %9s %8s %9s %10s %9s %11s %8s\n' case grains porosity status t/t_ref wall_s deposit_s p-steps/s runout
for h in 030 040 050 060 070; do
  target/release/coupler run "scenes/ceccato2020/dry_h$h.toml" --quiet --out "$out/dry_h$h" 2> "$out/dry_h$h.log"
  python3 - "$out/dry_h$h/summary.json" <<'PY'
import json, sys
s = json.load(open(sys.argv[1])); d = s["dem"]
print(f"{s['scene']:<9} {d['particles']:>7} {s['porosity_initial']:>9.4f} {s['status']:>8} {s['sim_time']/s['t_ref']:>9.2f} "
      f"{s['wall_seconds']:>10.1f} {d['deposition_seconds']:>9.1f} {s['throughput']['particle_steps_per_s']:>11.3e} {s['runout']:>8.3f}")
PY
done
# Recording cost: the same 0.2 s of collapse with and without the recorder.
for mode in record no-record; do
  flag=""; [ "$mode" = no-record ] && flag="--no-record"
  start=$(date +%s.%N)
  target/release/dem_proc run scenes/ceccato2020/dry_h060.toml --out "$out/cost-$mode" --set output.end_time=0.2 --set output.stop_at_rest=false $flag 2>/dev/null
  end=$(date +%s.%N)
  python3 -c "print('$mode: %.1f s wall for 0.2 s of collapse' % ($end - $start))"
done

#!/usr/bin/env bash
# The Table 1 columns from several deposition seeds (issue 19, part 5):
# each case, each seed, one `coupler run`; then per case the mean and the
# spread (max - min) of the three fronts' runouts: the 0.5 % mass rule (the
# paper's), the connected front and the pile's edge (docs/recording.md).
# usage: bash bench/seeds.sh [OUT_DIR] [KIND] [CASES] [SEEDS]
#   KIND: dry (default) or sat; CASES default "030 040 050 060 070";
#   SEEDS default "1 2 3". A dry case takes ~1 min, a saturated one 10-25.
#   BIN=DIR runs the coupler (and the dem_proc/lbm_proc beside it) from DIR
#   instead of building target/release, so a long campaign survives rebuilds.
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-runs/seeds}
kind=${2:-dry}
cases=${3:-"030 040 050 060 070"}
seeds=${4:-"1 2 3"}
bin=${BIN:-}
if [ -z "$bin" ]; then
  cargo build --release -p coupler -p dem_proc -p lbm_proc
  bin=target/release
fi
mkdir -p "$out"
for h in $cases; do
  for s in $seeds; do
    dir="$out/${kind}_h$h/seed$s"
    mkdir -p "$out/${kind}_h$h"
    [ -f "$dir/summary.json" ] || "$bin/coupler" run "scenes/ceccato2020/${kind}_h$h.toml" --quiet \
      --out "$dir" --set "particles[0].packing.seed=$s" 2> "$dir.log"
  done
done
python3 - "$out" "$kind" "$cases" "$seeds" <<'PY'
import json, statistics, sys
out, kind, cases, seeds = sys.argv[1], sys.argv[2], sys.argv[3].split(), sys.argv[4].split()
print(f"{'case':<10} {'grains':>14} {'porosity':>15} {'runout (mass)':>22} {'connected':>22} {'pile edge':>22}")
for h in cases:
    runs = [json.load(open(f"{out}/{kind}_h{h}/seed{s}/summary.json")) for s in seeds]
    def stat(values):
        return f"{statistics.mean(values):6.3f} ({min(values):.2f}-{max(values):.2f})"
    grains = [r["dem"]["particles"] for r in runs]
    porosity = [r["porosity_initial"] for r in runs]
    print(f"{kind}_h{h:<6} {min(grains):>6}-{max(grains):<7} {min(porosity):.4f}-{max(porosity):.4f} "
          f"{stat([r['runout'] for r in runs]):>22} {stat([r['runout_connected'] for r in runs]):>22} "
          f"{stat([r['runout_pile'] for r in runs]):>22}")
PY

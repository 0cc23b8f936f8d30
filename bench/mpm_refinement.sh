#!/usr/bin/env bash
# Grid refinement of the H0 = 0.06 m MPM columns, case by case (issue 20,
# "the saturated body grows with h"; docs/RESULTS.md, session 39): each
# CASE on 5, 4, 2.86 and 2 mm elements at the scenes' courant number, 12
# points per element. A case is `dry` or `sat` (the scene as shipped:
# frictional floor mu = 0.577, phi = 35) followed by any of these tokens,
# each one change to the scene:
#   _rough    mpm.floor = "rough" (no slip: the grains shear inside the soil)
#   _phiNN    mpm.friction_angle = NN degrees (27: the angle whose dry body
#             meets the DEM's at 4 mm)
#   _fsf06    mpm.free_surface_fill = 0.6 (and _fsf095: 0.95)
#   _erg10    Ergun's A and B x 10 (the water held in the grains)
#   _lflip09  mpm.liquid_flip_share = 0.9 (the water's transfer on FLIP)
#   _expl     mpm.pressure_scheme = "explicit" (per-point pore pressure)
#   _cav      mpm.cavitation_threshold = 1e5 (100 kPa of tension allowed)
#   _hyd      mpm.surface_elements = "hydrostatic" (a saturated layer inside
#             a part-filled element keeps its hydrostatic pressure)
#   _free     mpm.surface_elements = "free" (such an element at p = 0)
# e.g. sat_rough, sat_phi27, dry_phi27, sat_erg10.
# Then: python3 bench/mpm_refinement_table.py OUT_DIR (shares, pile edge,
# 0.5 % front per element size; observed order and the h -> 0 limit).
# usage: [BIN=DIR] bash bench/mpm_refinement.sh [OUT_DIR] ["case ..."] ["sizes"]
#   (default runs/mpm_refinement, cases "sat sat_rough", sizes in mm
#   "5 4 2.86 2"; the 2 mm saturated run is ~2 min on 2 cores).
#   Finished runs are skipped.
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-runs/mpm_refinement}
cases=${2:-"sat sat_rough"}
sizes=${3:-"5 4 2.86 2"}
bin=${BIN:-}
if [ -z "$bin" ]; then
  cargo build --release -q -p coupler -p mpm_proc
  bin=target/release
fi
declare -A metres=([5]=0.005 [4]=0.004 [2.86]=0.002857142857142857 [2]=0.002 [1.43]=0.0014285714285714286)
mkdir -p "$out"
for c in $cases; do
  column=${c%%_*}
  sets=()
  for token in $(tr '_' ' ' <<< "${c#*_}"); do
    [ "$token" = "$column" ] && continue
    case "$token" in
      rough) sets+=(--set 'mpm.floor="rough"') ;;
      phi[0-9]*) sets+=(--set mpm.friction_angle="${token#phi}") ;;
      fsf06) sets+=(--set mpm.free_surface_fill=0.6) ;;
      fsf095) sets+=(--set mpm.free_surface_fill=0.95) ;;
      erg10) sets+=(--set mpm.ergun_a=1500 --set mpm.ergun_b=17.5) ;;
      lflip09) sets+=(--set mpm.liquid_flip_share=0.9) ;;
      expl) sets+=(--set 'mpm.pressure_scheme="explicit"') ;;
      cav) sets+=(--set mpm.cavitation_threshold=1e5) ;;
      hyd) sets+=(--set 'mpm.surface_elements="hydrostatic"') ;;
      free) sets+=(--set 'mpm.surface_elements="free"') ;;
      *) echo "unknown case token '$token' in '$c' (see the header)" >&2; exit 2 ;;
    esac
  done
  for s in $sizes; do
    run="$out/${c}_h$s"
    [ -f "$run/summary.json" ] && continue
    "$bin/coupler" run "scenes/ceccato2020/mpm_${column}_h060.toml" --quiet --out "$run" \
      --set mpm.element_size="${metres[$s]}" "${sets[@]}" > "$run.log" 2>&1
  done
done

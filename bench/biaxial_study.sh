#!/usr/bin/env bash
# The DEM's element tests (docs/dem.md, "Element test"): plane-strain
# biaxial tests of the lab grains (scenes/ceccato2020/sat_h060.toml's
# grains and contact law) from three preparations (grain friction 0, 0.1,
# 0.3 while compressing: dense, the column's core porosity, looser), three
# seeds at sigma_3 = 300 Pa, and 100 and 1000 Pa for the column's
# preparation; then the table (bench/biaxial_table.py).
# usage: bash bench/biaxial_study.sh [OUT_DIR]   (default runs/biaxial; ~8 min on 2 cores)
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-runs/biaxial}
cargo build --release -q -p dem_proc
mkdir -p "$out"
for cfg in "0.0 1 300" "0.0 2 300" "0.0 3 300" "0.1 1 300" "0.1 2 300" "0.1 3 300" \
           "0.3 1 300" "0.3 2 300" "0.3 3 300" "0.1 1 100" "0.1 1 1000"; do
  set -- $cfg
  name="p$1_s$2_c$3"
  target/release/dem_proc biaxial scenes/ceccato2020/sat_h060.toml --out "$out/$name.json" \
    --preparation-friction "$1" --seed "$2" --confining-stress "$3" 2> "$out/$name.log" > /dev/null
done
python3 bench/biaxial_table.py "$out"/*.json

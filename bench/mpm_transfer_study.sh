#!/usr/bin/env bash
# The MPM transfer study of docs/mpm.md ("Which transfer", "Convergence and
# cost"): the H0 = 0.06 m dry and saturated lab columns under the default
# AFLIP transfer (APIC + 0.9 of the FLIP update), with its remaining
# dissipation halved (flip_share 0.95) and doubled (0.8, or courant 0.25
# with the share kept over each step, flip_share_basis = "step": twice the
# transfers per second), under plain APIC (the session 16-17
# default; its own dissipation halved by flip_share 0.5), under FLIP + XPIC
# (the older default), on the rough floor and on mu = 10 and mu = 0
# floors, with 3 and 6 points per element, on 2.86, 2 and 1.43 mm
# elements, with friction angles 30, 25, 20 degrees (the DEM's deposit is
# flatter), and (saturated) with the DEM-LBM's bed permeability (Ergun A =
# 123) or twice Ergun's (75), dilatancy 5 and 10 degrees, without the
# pore-pressure plane, and with the free-surface fill at 0.6 and 0.9.
# Prints one line per run: solid runout (0.5 % mass front), front at
# 1/2/4 t_ref, the pile edge (first deposit column below one grain, the
# DEM's rule), the liquid front at the end, status, t/t_ref, wall time.
# usage: [BIN=DIR] bash bench/mpm_transfer_study.sh [OUT_DIR] ["case ..."]
#   (default runs/mpm_transfer; all cases ~3 h on 2 cores, the 2 and
#   1.43 mm saturated ones most of it). Finished cases are skipped.
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-runs/mpm_transfer}
bin=${BIN:-}
if [ -z "$bin" ]; then
  cargo build --release -q -p coupler -p mpm_proc
  bin=target/release
fi
h286=0.002857142857142857
h143=0.0014285714285714286
declare -A sets=(
  [dry]="" [sat]=""
  [dry_beta05]="--set mpm.flip_share=0.5" [sat_beta05]="--set mpm.flip_share=0.5"
  [dry_c025]="--set mpm.courant=0.25 --set mpm.flip_share_basis=\"step\"" [sat_c025]="--set mpm.courant=0.25 --set mpm.flip_share_basis=\"step\""
  [dry_flip08]="--set mpm.transfer=\"flip\" --set mpm.courant=0.8"
  [sat_flip08]="--set mpm.transfer=\"flip\" --set mpm.courant=0.8"
  [dry_rough]="--set mpm.floor=\"rough\"" [sat_rough]="--set mpm.floor=\"rough\""
  [dry_mu10]="--set mpm.wall_friction=10" [dry_mu0]="--set mpm.wall_friction=0"
  [dry_ppe6]="--set mpm.points_per_element=6" [sat_ppe6]="--set mpm.points_per_element=6"
  [dry_ppe3]="--set mpm.points_per_element=3" [sat_ppe3]="--set mpm.points_per_element=3"
  [dry_h286]="--set mpm.element_size=$h286" [sat_h286]="--set mpm.element_size=$h286"
  [dry_h2]="--set mpm.element_size=0.002" [sat_h2]="--set mpm.element_size=0.002"
  [dry_h143]="--set mpm.element_size=$h143" [sat_h143]="--set mpm.element_size=$h143"
  [dry_phi30]="--set mpm.friction_angle=30" [dry_phi25]="--set mpm.friction_angle=25"
  [dry_phi20]="--set mpm.friction_angle=20"
  [dry_beta075]="--set mpm.flip_share=0.75"
  [dry_beta097]="--set mpm.flip_share=0.97" [dry_beta099]="--set mpm.flip_share=0.99"
  [dry_flip05]="--set mpm.transfer=\"flip\""
  [dry_flip05_pic01]="--set mpm.transfer=\"flip\" --set mpm.pic_fraction=0.01 --set mpm.xpic_order=1"
  [dry_flip05_pic03]="--set mpm.transfer=\"flip\" --set mpm.pic_fraction=0.03 --set mpm.xpic_order=1"
  [sat_phi30]="--set mpm.friction_angle=30" [sat_phi25]="--set mpm.friction_angle=25"
  [sat_nmax08]="--set mpm.max_porosity=0.8"
  [dry_h2_phi25]="--set mpm.element_size=0.002 --set mpm.friction_angle=25"
  [sat_h2_phi25]="--set mpm.element_size=0.002 --set mpm.friction_angle=25"
  [dry_h2_beta05]="--set mpm.element_size=0.002 --set mpm.flip_share=0.5"
  [sat_h2_beta05]="--set mpm.element_size=0.002 --set mpm.flip_share=0.5"
  [sat_k123]="--set mpm.ergun_a=123" [sat_k75]="--set mpm.ergun_a=75"
  [sat_psi5]="--set mpm.dilatancy_angle=5" [sat_psi10]="--set mpm.dilatancy_angle=10"
  [dry_beta08]="--set mpm.flip_share=0.8" [dry_beta095]="--set mpm.flip_share=0.95"
  [sat_beta08]="--set mpm.flip_share=0.8" [sat_beta095]="--set mpm.flip_share=0.95"
  [dry_h2_beta095]="--set mpm.element_size=0.002 --set mpm.flip_share=0.95"
  [sat_h2_beta095]="--set mpm.element_size=0.002 --set mpm.flip_share=0.95"
  [dry_apic]="--set mpm.transfer=\"apic\"" [sat_apic]="--set mpm.transfer=\"apic\""
  [dry_h2_apic]="--set mpm.element_size=0.002 --set mpm.transfer=\"apic\""
  [sat_h2_apic]="--set mpm.element_size=0.002 --set mpm.transfer=\"apic\""
  [dry_mu10_apic]="--set mpm.wall_friction=10 --set mpm.transfer=\"apic\""
  [dry_rough_apic]="--set mpm.floor=\"rough\" --set mpm.transfer=\"apic\""
  [sat_fill06]="--set mpm.free_surface_fill=0.6" [sat_fill09]="--set mpm.free_surface_fill=0.9"
  [sat_none]="--set mpm.pressure_reconstruction=\"none\"" [sat_rough_none]="--set mpm.floor=\"rough\" --set mpm.pressure_reconstruction=\"none\""
)
order="dry dry_beta05 dry_c025 dry_flip08 dry_rough dry_mu10 dry_mu0 dry_ppe6 dry_ppe3 dry_h286 dry_h2 dry_h143 dry_h2_beta05
       dry_phi30 dry_phi25 dry_phi20 dry_beta075 dry_beta097 dry_beta099
       dry_flip05 dry_flip05_pic01 dry_flip05_pic03 dry_h2_phi25
       sat sat_beta05 sat_c025 sat_flip08 sat_rough sat_ppe6 sat_ppe3 sat_h286 sat_h2 sat_h143 sat_h2_beta05 sat_phi30 sat_phi25 sat_nmax08 sat_h2_phi25
       sat_k123 sat_k75 sat_psi5 sat_psi10 sat_none sat_rough_none
       dry_beta08 dry_beta095 sat_beta08 sat_beta095 dry_h2_beta095 sat_h2_beta095
       dry_apic sat_apic dry_h2_apic sat_h2_apic dry_mu10_apic dry_rough_apic
       sat_fill06 sat_fill09"
cases=${2:-$order}
mkdir -p "$out"
for c in $cases; do
  [ -f "$out/$c/summary.json" ] && continue
  scene=scenes/ceccato2020/mpm_${c%%_*}_h060.toml
  eval "$bin/coupler" run "$scene" --quiet --out "$out/$c" ${sets[$c]} 2> "$out/$c.log"
done
python3 - "$out" $cases <<'PY'
import json, sys
out, cases = sys.argv[1], sys.argv[2:]
def at(front, t):
    return min(front, key=lambda f: abs(f["t_norm"] - t))["x_norm"]
print(f"{'case':<15} {'runout':>7} {'1 t_ref':>7} {'2 t_ref':>7} {'4 t_ref':>7} {'pile edge':>9} {'liquid':>7} {'status':>9} {'t/t_ref':>7} {'wall s':>7}")
for c in cases:
    try:
        s = json.load(open(f"{out}/{c}/summary.json"))
    except FileNotFoundError:
        print(f"{c:<15} (not finished)")
        continue
    f = s["front"]
    # The pile edge as the DEM reports it (docs/RESULTS.md): from the back
    # wall, the first deposit column lower than one grain (D = 2.5 mm).
    dep = s["deposit"]
    step = dep[1][0] - dep[0][0]
    edge = next((x - step / 2 for x, h in dep if h < 2.5e-3), dep[-1][0] + step / 2)
    lf = s.get("liquid_front") or []
    liquid = f"{lf[-1]['x_norm']:7.3f}" if lf else "      -"
    print(f"{c:<15} {s['runout']:7.3f} {at(f, 1):7.3f} {at(f, 2):7.3f} {at(f, 4):7.3f} {(edge - 0.04) / 0.04:9.3f} {liquid} "
          f"{s['status']:>9} {s['sim_time'] / s['t_ref']:7.2f} {s['wall_seconds']:7.1f}")
PY

#!/usr/bin/env python3
"""What lies beyond an MPM deposit's pile edge, run by run (issue 20,
which front a convergence bar can read): from each run's last
`/mpm/solid` frame, the distance behind which each share of the grains
lies, the pile edge (`runout_pile`: where the deposit first thins below
one grain diameter D, docs/recording.md) and the 0.5 % mass front
(`runout`) from the summary, the share of the grains beyond the pile
edge (the sheet), and the sheet's mean and largest thickness in grains
and in elements (grain volume per bin of one D / (D (1 - n0)), binned by
point centre as bench/deposit_compare.py does).

usage: python3 bench/mpm_sheet.py LABEL=RUN_DIR [LABEL=RUN_DIR ...]
Distances are (x - L0)/L0.
"""
import json
import sys

sys.path.insert(0, __file__.rsplit("/", 1)[0])
from deposit_compare import SHARES, mpm_grains, scene_of, shares  # noqa: E402


def main():
    header = " | ".join(f"{s:.1%}" for s in SHARES)
    print(f"| run | element (mm) | {header} | pile edge | 0.5 % front | beyond the pile edge | sheet mean / max thickness (D) | (elements) |")
    print("|---|---|" + "---|" * (len(SHARES) + 5))
    for arg in sys.argv[1:]:
        label, run = arg.split("=", 1)
        scene = scene_of(run)
        summary = json.load(open(f"{run}/summary.json"))
        a = scene["analysis"]
        l0, x0 = a["column_length"], scene["domain"]["min"][0]
        d = scene["particles"][0]["diameter"]
        h = scene["mpm"]["element_size"]
        n0 = summary["porosity_initial"]
        pile = summary.get("runout_pile")
        if pile is None or pile < 0.0:
            # No pile edge recorded (runs before session 32), or the deposit
            # is thinner than a grain from the back wall on: no sheet to read.
            print(f"| {label} | {h * 1e3:.2f} | (no pile edge in summary.json: {pile}) |")
            continue
        grains, _ = mpm_grains(run, summary)
        total = sum(v for _, v in grains)
        edge = x0 + l0 + pile * l0
        end = x0 + l0 + summary["runout"] * l0
        beyond = sum(v for x, v in grains if x > edge) / total
        # The sheet's thickness over edge < x <= 0.5 % front (the grains
        # beyond that front would thicken a layer they do not lie in).
        sheet = [(x, v) for x, v in grains if edge < x <= end]
        bins = {}
        for x, v in sheet:
            i = int((x - edge) // d)
            bins[i] = bins.get(i, 0.0) + v
        thickness = [v / (d * (1.0 - n0)) for v in bins.values()]
        length = max(end - edge, d)
        mean = sum(v for _, v in sheet) / (length * (1.0 - n0)) if sheet else 0.0
        top = max(thickness, default=0.0)
        cells = " | ".join(f"{v:.2f}" for v in shares(grains, x0, l0))
        print(
            f"| {label} | {h * 1e3:.2f} | {cells} | {pile:.2f} | {summary['runout']:.2f} "
            f"| {beyond:.1%} | {mean / d:.2f} / {top / d:.2f} | {mean / h:.2f} / {top / h:.2f} |"
        )


if __name__ == "__main__":
    main()

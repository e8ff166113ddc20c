"""One table from many `photonmc converge` runs (tools/mbe_suite.sh writes one directory per
room): each method's RMSE (with the reference's noise removed where the reference's noise is
known, else raw), its iterations, and its RMSE as a multiple of another method's, both from
the seeds' means and paired seed by seed (mean and standard error over seeds, raw RMSE).

    python tools/converge_summary.py OUTDIR [--against vcm]
"""
import argparse
import csv
import math
from pathlib import Path

import numpy as np

NOISE_REMOVED = "RMSE, reference noise removed"


def read_table(md: Path) -> dict:
    """method -> (RMSE cell, iterations cell, whether the RMSE has the reference's noise removed)."""
    rows, header = {}, None
    for line in md.read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if cells and cells[0] == "method":
            header = cells
        elif header and len(cells) == len(header) and not set(cells[0]) <= set("-"):
            col = NOISE_REMOVED if NOISE_REMOVED in header else "RMSE"
            rows[cells[0]] = (cells[header.index(col)], cells[header.index("iterations")], col == NOISE_REMOVED)
        elif rows and not line.startswith("|"):
            break       # the first table only
    return rows


def final_rmse(csv_path: Path) -> dict:
    """(method, seed) -> raw RMSE at the end of its render."""
    last = {}
    with open(csv_path) as f:
        for r in csv.DictReader(f):
            last[(r["method"], r["seed"])] = float(r["rmse"])
    return last


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("outdir")
    ap.add_argument("--against", default="vcm")
    args = ap.parse_args()
    ref = args.against
    print(f"| room | method | RMSE | iterations | / {ref} | / {ref}, paired raw (seeds) |")
    print("|---|---|---|---|---|---|")
    for d in sorted(Path(args.outdir).iterdir()):
        if not (d / "convergence.md").exists():
            continue
        table, last = read_table(d / "convergence.md"), final_rmse(d / "convergence.csv")
        for method, (rmse, iterations, removed) in table.items():
            ratio = paired = ""
            if method != ref and ref in table:
                base = float(table[ref][0].split()[0])
                # a base below the reference's own noise reads 0 once that is removed
                ratio = (f"{float(rmse.split()[0]) / base:.2f}x" + ("" if removed else " (raw)") if base > 0
                         else "(vcm below the reference's noise)".replace("vcm", ref))
                seeds = sorted(s for m, s in last if m == method and (ref, s) in last)
                r = np.array([last[(method, s)] / last[(ref, s)] for s in seeds])
                if len(r) > 1:
                    paired = f"{r.mean():.3f} ± {r.std(ddof=1) / math.sqrt(len(r)):.3f}"
            print(f"| {d.name} | {method} | {rmse} | {iterations.split()[0]} | {ratio} | {paired} |")


if __name__ == "__main__":
    main()

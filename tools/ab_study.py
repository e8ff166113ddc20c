"""Equal-time RMSE of one method under two option sets (A and B), on the effort study's scenes.

    python tools/ab_study.py --method visibility --b '{"suffix_mutation": 0.5}' [--a '{}']
                             [--seconds 15] [--seeds 0,1] [SCENE ...]

Each (scene, seed) renders A and B back to back, alternating which goes first, after a warm-up
iteration (compilation excluded; tools/effort_study.py's rmse_after). Prints a Markdown table:
mean RMSE over seeds with its standard error, the ratio B/A, and (iterations, photons per
pass) of the last seed.
"""
import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from effort_study import SCENES, equal_time_pair, table_row  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scenes", nargs="*", default=list(SCENES))
    ap.add_argument("--method", default="visibility")
    ap.add_argument("--a", default="{}", help="options of A, as JSON")
    ap.add_argument("--b", required=True, help="options of B, as JSON")
    ap.add_argument("--seconds", type=float, default=15.0)
    ap.add_argument("--seeds", default="0,1")
    args = ap.parse_args()
    options = {"A": json.loads(args.a), "B": json.loads(args.b)}
    seeds = [int(s) for s in args.seeds.split(",")]
    print(f"{args.method}, {args.seconds} s, seeds {seeds}; A = {options['A']}, B = {options['B']}\n")
    print("| scene | A RMSE | B RMSE | B/A | A (iterations, photons) | B |")
    print("|---|---|---|---|---|---|")
    for name in args.scenes:
        errors, info = equal_time_pair(name, args.method, options, seeds, args.seconds)
        print(table_row(name, errors, info), flush=True)


if __name__ == "__main__":
    main()

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

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from effort_study import REPO, SCENES, rmse_after  # noqa: E402

from photonmc.imageio import read_image  # noqa: E402


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
        scene, ref_name, params = SCENES[name]
        ref = read_image(REPO / "tests" / "refs" / ref_name).astype(np.float64)
        errors, info = {"A": [], "B": []}, {}
        for seed in seeds:
            for mode in (("A", "B") if seed % 2 == 0 else ("B", "A")):
                e, info[mode] = rmse_after(scene, dict(params), args.method, dict(options[mode]), seed,
                                           args.seconds, ref)
                errors[mode].append(e)
        a, b = np.array(errors["A"]), np.array(errors["B"])
        se = lambda x: x.std() / np.sqrt(len(x))  # noqa: E731
        print(f"| {name} | {a.mean():.5f} ± {se(a):.5f} | {b.mean():.5f} ± {se(b):.5f} | {b.mean() / a.mean():.3f} | "
              f"{info['A']} | {info['B']} |", flush=True)


if __name__ == "__main__":
    main()

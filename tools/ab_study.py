"""Equal-time RMSE of one method under two option sets (A and B), on the effort study's scenes.

    python tools/ab_study.py --method visibility --b '{"suffix_mutation": 0.5}' [--a '{}']
                             [--seconds 15] [--seeds 0,1] [SCENE ...]

Each (scene, seed) renders A and B back to back, alternating which goes first, after a warm-up
iteration (compilation excluded; tools/effort_study.py's rmse_after). Prints a Markdown table:
mean RMSE over seeds with its standard error, the ratio B/A, and (iterations, photons per
pass) of the last seed, then each seed's RMSE.

    python tools/ab_study.py --method mbe --a-tree OLD_TREE --b '{}' [--a '{}'] ...

A/B of code instead of options: A renders with OLD_TREE's photonmc (a checkout, e.g. `git
worktree add /tmp/old HEAD`, or a copy of the tree before a change), B with this tree's. As in
tools/ab_trees.py, OLD_TREE's package is copied to a temporary directory as `photonmc_base`, so
that both versions load in one process and share one ti.init.
"""
import argparse
import json
import shutil
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import effort_study  # noqa: E402
from effort_study import SCENES, equal_time_pair, table_row  # noqa: E402


def load_other_tree(tree: str) -> Path:
    """OLD_TREE's photonmc as `photonmc_base`, sharing this tree's Taichi runtime; returns the
    temporary directory that holds it."""
    tmp = Path(tempfile.mkdtemp())
    shutil.copytree(Path(tree) / "photonmc", tmp / "photonmc_base")
    sys.path.insert(1, str(tmp))
    import photonmc.runtime
    import photonmc_base.loop
    import photonmc_base.runtime
    photonmc.runtime.init("cpu")
    photonmc_base.runtime._current = photonmc.runtime._current      # one ti.init for both
    effort_study.OTHER_TREES["base"] = photonmc_base.loop.Job
    return tmp


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scenes", nargs="*", default=list(SCENES))
    ap.add_argument("--method", default="visibility")
    ap.add_argument("--a", default="{}", help="options of A, as JSON")
    ap.add_argument("--b", required=True, help="options of B, as JSON")
    ap.add_argument("--seconds", type=float, default=15.0)
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--a-tree", help="render A with this checkout's photonmc (an A/B of code, above)")
    args = ap.parse_args()
    options = {"A": json.loads(args.a), "B": json.loads(args.b)}
    a_label = f"{options['A']}" + (f" with {args.a_tree}'s photonmc" if args.a_tree else "")
    tmp = None
    if args.a_tree:
        tmp = load_other_tree(args.a_tree)
        options["A"]["_tree"] = "base"
    seeds = [int(s) for s in args.seeds.split(",")]
    print(f"{args.method}, {args.seconds} s, seeds {seeds}; A = {a_label}, B = {options['B']}\n")
    print("| scene | A RMSE | B RMSE | B/A | A (iterations, photons) | B | per seed, A; B |")
    print("|---|---|---|---|---|---|---|")
    try:
        for name in args.scenes:
            errors, info = equal_time_pair(name, args.method, options, seeds, args.seconds)
            per_seed = "; ".join(", ".join(f"{e:.5g}" for e in errors[label]) for label in ("A", "B"))
            print(f"{table_row(name, errors, info)} {per_seed} |", flush=True)
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()

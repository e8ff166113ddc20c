"""Time per iteration of several methods (or option sets) on one scene, interleaved in one
process, as ratios to the first:

    python tools/time_ratio.py SCENE.xml vcm mbe 'mbe:{"large_step": 0.95}' [-D res=64]
                               [--rounds 10] [--iterations 50] [--warm-up 30]

Equal-time comparisons (`photonmc converge --time`) run one method after the other, and on a
shared host the machine's speed drifts by 10-40 % between them (steal time of the virtual
machine): the iteration counts, and so the RMSE ratios, move with it. Here every method
renders `--iterations` iterations per round, in alternating order, so that the drift
cancels in the per-round ratios; prints the median time per iteration of each and the mean
ratio to the first with its standard error (docs/mbe.md, "What an iteration costs").
"""
import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene")
    ap.add_argument("specs", nargs="+", help="METHOD or METHOD:{JSON options}")
    ap.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE")
    ap.add_argument("--rounds", type=int, default=10)
    ap.add_argument("--iterations", type=int, default=50)
    ap.add_argument("--warm-up", type=int, default=30)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    from photonmc import runtime
    from photonmc.loop import Job
    runtime.init("cpu")
    params = dict(d.split("=", 1) for d in args.defines) or {"res": "64"}
    runs = []
    for spec in args.specs:
        method, _, options = spec.partition(":")
        p = Job(scene=args.scene, params=dict(params), method=method,
                options=json.loads(options) if options else {}, seed=args.seed).prepare()
        for _ in range(args.warm_up):
            p.method.iterate()
        runs.append((spec, p, []))
    for r in range(args.rounds):
        for spec, p, times in (runs if r % 2 == 0 else runs[::-1]):
            t = time.perf_counter()
            for _ in range(args.iterations):
                p.method.iterate()
            times.append((time.perf_counter() - t) / args.iterations * 1000)
    first = np.asarray(runs[0][2])
    print(f"| run | ms per iteration (median) | ratio to {runs[0][0]} |\n|---|---|---|")
    for spec, p, times in runs:
        ratio = np.asarray(times) / first
        print(f"| {spec} | {np.median(times):.2f} | {ratio.mean():.3f} ± {ratio.std() / np.sqrt(len(ratio)):.3f} |")
        p.release()


if __name__ == "__main__":
    main()

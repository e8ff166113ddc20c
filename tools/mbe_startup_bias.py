"""mbe's own bias: its mean against vcm's with the merging radius fixed (docs/mbe.md, "Start-up
bias of short passes, and a warm start").

    python tools/mbe_startup_bias.py [SCENE] [-D res=32] [--iterations 400] [--seeds 1,2]
                                     [--variant 'warm={"warm_start": true}' ...]

With --alpha 1 both methods keep their first radius, so they estimate the same blurred
image and any difference beyond the seeds' spread is mbe's: the start-up bias of its
contribution chains, which restart every pass. Prints each variant's mean luminance
relative to vcm's and how far apart its seeds are.
"""
import argparse
import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene", nargs="?", default=str(REPO / "scenes" / "light-gap" / "scene.xml"))
    ap.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE")
    ap.add_argument("--iterations", type=int, default=400)
    ap.add_argument("--seeds", default="1,2")
    ap.add_argument("--variant", action="append", default=[], metavar='NAME=JSON',
                    help='an mbe variant, e.g. warm={"warm_start": true} (default: mbe as it is)')
    args = ap.parse_args()
    sys.path.insert(0, str(REPO))
    from photonmc import load_scene
    from photonmc.loop import Budget, prepare, run
    from photonmc.metrics import mean_luminance

    params = dict(d.split("=", 1) for d in args.defines) or {"res": "32"}
    seeds = [int(s) for s in args.seeds.split(",")]
    scene = load_scene(args.scene, params)
    variants = [("vcm", "vcm", {}), ("mbe", "mbe", {})]
    for item in args.variant:
        name, opts = item.split("=", 1)
        variants.append((name, "mbe", json.loads(opts)))
    means = {}
    for name, method, opts in variants:
        values = []
        for seed in seeds:
            p = prepare(scene, method=method, seed=seed, options={"alpha": 1.0, **opts})
            values.append(mean_luminance(run(p, Budget(iterations=args.iterations), quiet=True).image))
            p.release()
        means[name] = np.array(values)
    base = means["vcm"].mean()
    print(f"{Path(args.scene).name} {params}, {args.iterations} iterations, radius fixed, seeds {seeds}")
    for name, values in means.items():
        print(f"{name:>12}: mean {values.mean() / base - 1:+.2%} against vcm "
              f"(seeds {np.ptp(values) / base:.2%} apart)")


if __name__ == "__main__":
    main()

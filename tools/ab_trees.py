"""Time per iteration of this tree against another one, interleaved in one process.

    python tools/ab_trees.py OLD_TREE SCENE.xml [-D res=64] [--method mbe] [--options JSON]
                             [--rounds 8] [--iterations 30]

OLD_TREE is a checkout of photonmc (e.g. `git worktree add /tmp/old <commit>`). Its package
is copied to a temporary directory as `photonmc_base`, so that both versions load in this
process and share one `ti.init` (runtime._current). Both render the same scene with the same
seed; rounds of `--iterations` iterations alternate which goes first, so that the machine's
drift cancels (on a shared 2-core host, back-to-back runs move by 10-20 %). Prints the
median time per iteration of each and the mean ratio new/old with its standard error
(docs/performance.md, "Per-pass bookkeeping in fewer launches").
"""
import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("old_tree")
    ap.add_argument("scene")
    ap.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE")
    ap.add_argument("--method", default="mbe")
    ap.add_argument("--options", default="{}", help="method options, as JSON, for both")
    ap.add_argument("--rounds", type=int, default=8)
    ap.add_argument("--iterations", type=int, default=30)
    args = ap.parse_args()

    tmp = Path(tempfile.mkdtemp())
    shutil.copytree(Path(args.old_tree) / "photonmc", tmp / "photonmc_base")
    sys.path.insert(0, str(REPO))
    sys.path.insert(1, str(tmp))
    import taichi as ti
    import photonmc
    import photonmc.loop
    import photonmc_base
    import photonmc_base.loop

    params = dict(d.split("=", 1) for d in args.defines) or {"res": "64"}
    options = json.loads(args.options)
    new = photonmc.loop.prepare(photonmc.load_scene(args.scene, params), method=args.method, seed=0,
                                options=options)
    photonmc_base.runtime._current = photonmc.runtime._current      # one ti.init for both
    old = photonmc_base.loop.prepare(photonmc_base.load_scene(args.scene, params), method=args.method, seed=0,
                                     options=options)
    for p in (new, old):                                             # compile, and settle
        for _ in range(5):
            p.method.iterate()
    ti.sync()
    times = {"new": [], "old": []}
    for r in range(args.rounds):
        order = (("new", new), ("old", old)) if r % 2 == 0 else (("old", old), ("new", new))
        for name, p in order:
            t = time.perf_counter()
            for _ in range(args.iterations):
                p.method.iterate()
            ti.sync()
            times[name].append((time.perf_counter() - t) / args.iterations)
    ratio = np.array(times["new"]) / np.array(times["old"])
    print(f"{Path(args.scene).parent.name or args.scene} {args.method}: new {np.median(times['new']) * 1e3:.2f} ms, "
          f"old {np.median(times['old']) * 1e3:.2f} ms per iteration, new/old {ratio.mean():.3f} "
          f"+- {ratio.std(ddof=1) / np.sqrt(len(ratio)):.3f}")
    new.release()
    old.release()
    shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()

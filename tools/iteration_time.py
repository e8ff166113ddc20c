"""Milliseconds per iteration of one method, compilation excluded, on a source tree given as
an argument, so that two commits can be compared on the same machine:

    python tools/iteration_time.py TREE [--method spatial-tf] [--scene cornell-box] [-D res=128]
                                   [--camera-paths 13] [--seconds 10] [--reference REF.exr --seed 0]

TREE is a checkout (e.g. a `git worktree` of an older commit); its photonmc is imported.
Fixing --camera-paths keeps the effort balance from changing the work per iteration. With
--reference, also the RMSE of the image after --seconds (an equal-time comparison of trees).
"""
import argparse
import sys
import time


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("tree")
    ap.add_argument("--method", default="spatial-tf")
    ap.add_argument("--scene", default="cornell-box")
    ap.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE")
    ap.add_argument("--camera-paths", type=int, default=None)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--reference")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    sys.path.insert(0, args.tree)
    from photonmc.loop import Job
    params = dict(d.split("=", 1) for d in args.defines) or {"res": "128"}
    options = {} if args.camera_paths is None else {"camera_paths": args.camera_paths}
    p = Job(scene=f"{args.tree}/scenes/{args.scene}/scene.xml", params=params, method=args.method,
            options=options, seed=args.seed).prepare()
    try:
        m = p.method
        m.warm_up()
        m.reset()
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < args.seconds:
            m.iterate()
        dt = time.perf_counter() - t0
        print(f"{args.tree}: {args.method} {params} {options}: {dt / m.iterations * 1000:.1f} ms per iteration "
              f"over {m.iterations}")
        if args.reference:
            from photonmc.imageio import read_image
            from photonmc.metrics import rmse
            print(f"RMSE {rmse(m.image(), read_image(args.reference).astype('float64')):.5f}")
    finally:
        p.release()


if __name__ == "__main__":
    main()

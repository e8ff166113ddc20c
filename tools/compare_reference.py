"""Compare photonmc renders of a scene with a reference image (e.g. from Mitsuba 3).

    python tools/compare_reference.py scenes/cornell-box/scene.xml tests/refs/cornell-box-64.exr \
        -D res=64 [--method pt] [--iterations 512]

Renders twice with seeds 1 and 2 and prints the mean-luminance bias of each, and the ratio
MSE(A, ref) / (MSE(A, B)/2 x (1 + n/n_ref)) on pixels and on 2x2 and 4x4 blocks: about 1
when the only difference is noise (the reference's noise estimated from ours, scaled by the
ratio of sample counts; n_ref is read from the EXR header if present).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene")
    ap.add_argument("reference")
    ap.add_argument("--method", default="pt")
    ap.add_argument("--iterations", type=int, default=512)
    ap.add_argument("--ref-spp", type=int, help="reference sample count if not in its header")
    ap.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE")
    args = ap.parse_args()

    from photonmc import load_scene, runtime
    from photonmc.imageio import read_image, read_metadata
    from photonmc.metrics import downsample, luminance, mean_luminance
    from photonmc.loop import Budget, prepare, run

    runtime.init()
    ref = read_image(args.reference)
    n_ref = args.ref_spp or int(read_metadata(args.reference).get("spp", 0)) or None
    scene = load_scene(args.scene, dict(d.split("=", 1) for d in args.defines))
    n = args.iterations
    a, b = (run(prepare(scene, method=args.method, seed=s), Budget(iterations=n), quiet=True).image for s in (1, 2))
    print(f"{args.scene} vs {args.reference} ({args.method}, {n} iterations, reference {n_ref} spp)")
    for name, img in (("A", a), ("B", b)):
        print(f"  mean-luminance bias {name}: {100 * (mean_luminance(img) / mean_luminance(ref) - 1):+.3f} %")
    ref_share = 1 + n / n_ref if n_ref else 1.0
    for f in (1, 2, 4):
        la, lb, lr = (downsample(luminance(x), f) for x in (a, b, ref))
        ratio = np.mean((la - lr) ** 2) / (np.mean((la - lb) ** 2) / 2 * ref_share)
        print(f"  MSE / noise on {f}x{f} blocks: {ratio:.3f}")


if __name__ == "__main__":
    main()

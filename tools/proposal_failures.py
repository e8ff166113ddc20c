"""Bias and noise of --proposal-failures drop against keep on one scene (docs/guiding.md).

    python tools/proposal_failures.py scenes/light-gap/scene.xml tests/refs/light-gap-closeup-64.exr \
        --iterations 40 -D res=64 -D fov=12 -D target=-1.1,0.4,-0.6

Renders `visibility` with each setting and two seeds. Noise: RMS of (seed 1 - seed 2)/sqrt(2)
per pixel; error: RMSE of the two-seed mean against the reference; and the time taken, since
dropping failures records fewer steps per pass.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from photonmc.imageio import read_image  # noqa: E402
from photonmc.metrics import mean_luminance_bias, rmse  # noqa: E402
from photonmc.loop import Budget, prepare, run  # noqa: E402
from photonmc.scene import load_scene  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene")
    ap.add_argument("reference")
    ap.add_argument("--iterations", type=int, default=40)
    ap.add_argument("-D", dest="defines", action="append", default=[])
    args = ap.parse_args(argv)
    params = dict(d.split("=", 1) for d in args.defines)
    scene = load_scene(args.scene, params)
    ref = read_image(args.reference)
    print("| failures | noise (RMS) | RMSE of 2-seed mean | mean-luminance bias | seconds per render |")
    print("|---|---|---|---|---|")
    for mode in ("keep", "drop"):
        images, seconds = [], []
        for seed in (1, 2):
            p = prepare(scene, method="visibility", seed=seed, options={"proposal_failures": mode})
            t = time.perf_counter()
            images.append(run(p, Budget(iterations=args.iterations), quiet=True).image.astype(np.float64))
            seconds.append(time.perf_counter() - t)
            p.release()
        noise = float(np.sqrt(np.mean((images[0] - images[1]) ** 2 / 2)))
        mean = (images[0] + images[1]) / 2
        print(f"| {mode} | {noise:.5f} | {rmse(mean, ref):.5f} | {100 * mean_luminance_bias(mean, ref):+.2f} % | "
              f"{np.mean(seconds[1:]):.1f} |")


if __name__ == "__main__":
    main()

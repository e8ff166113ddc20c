"""The film's noise at equal time under several option sets, from two seeds' images.

    python tools/film_noise.py ROOM --method visibility --seconds 20 --seeds 0,1 \
        '{}' '{"camera_paths": 8}' ...

ROOM is one of tools/effort_study.py's SCENES. For each option set the two seeds render for
the same time after a warm-up iteration (compilation excluded). Printed per option set:

- noise: sqrt(mean over pixels of (a - b)^2 / 2), the RMS per-pixel standard deviation of one
  render, which a reference's own noise does not enter (where a reference is noisier than
  the renders, its RMSE hides the renders' differences: docs/guiding.md);
- trimmed: the same without the 1 % of pixels whose difference is largest (a few pixels at a
  lamp's edge can hold most of the first);
- RMSE of the two seeds' mean against the reference, the iterations made, and K (camera
  paths per pixel per pass: mean over passes, last).

Used for docs/effort.md, "Camera paths weighed alike".
"""
import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from effort_study import REPO, SCENES, read_image, render_for  # noqa: E402
from photonmc.metrics import luminance  # noqa: E402


def render(name: str, method: str, options: dict, seed: int, seconds: float):
    """(image, iterations, K of each pass) of `seconds` of rendering after a warm-up."""
    scene, _, params = SCENES[name]
    ks = []
    image, iterations, _ = render_for(scene, dict(params), method, dict(options), seed, seconds,
                                      after_pass=lambda m: ks.append(getattr(m, "camera_paths", 1)))
    return np.asarray(image, np.float64), iterations, ks


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("room", choices=sorted(SCENES))
    ap.add_argument("options", nargs="+", help="option sets, as JSON")
    ap.add_argument("--method", default="visibility")
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--seeds", default="0,1", help="two seeds")
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    if len(seeds) != 2:
        ap.error("--seeds takes two seeds")
    ref = luminance(read_image(REPO / "tests" / "refs" / SCENES[args.room][1]).astype(np.float64))
    print(f"{args.room}, {args.method}, {args.seconds} s, seeds {seeds}\n")
    print("| options | noise | trimmed | RMSE of the mean | iterations | K (mean, last) |")
    print("|---|---|---|---|---|---|")
    for text in args.options:
        options = json.loads(text)
        runs = [render(args.room, args.method, options, seed, args.seconds) for seed in seeds]
        a, b = (luminance(image) for image, _, _ in runs)
        half_sq = np.sort(((a - b) ** 2 / 2).ravel())
        noise = np.sqrt(half_sq.mean())
        trimmed = np.sqrt(half_sq[: int(half_sq.size * 0.99)].sum() / half_sq.size)
        error = np.sqrt(np.mean(((a + b) / 2 - ref) ** 2))
        iterations = ", ".join(str(it) for _, it, _ in runs)
        ks = ", ".join(f"{np.mean(k):.1f}/{k[-1]}" for _, _, k in runs)
        print(f"| {text} | {noise:.5f} | {trimmed:.5f} | {error:.5f} | {iterations} | {ks} |", flush=True)


if __name__ == "__main__":
    main()

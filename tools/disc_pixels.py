"""Where two gather-disc kinds differ, pixel by pixel, at equal passes (docs/guiding.md, "The two
rooms linear discs lose, pixel by pixel").

    python tools/disc_pixels.py ROOM [--method sppm] [--passes 1500] [--seeds 0,1]
                                [--a full] [--b linear] [--top 12]

ROOM is one of tools/effort_study.py's scenes. Renders the room with each kind for the same
number of passes and seeds (the method's other options at their defaults), and prints each
kind's RMSE per seed, the squared error summed over the image (mean over seeds), and the pixels
that carry most of B's excess: the reference, both kinds' means over seeds, and each pixel's
share of the excess. Equal passes, not equal time: this asks where a kind's estimate is wrong,
not what it costs.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from effort_study import REPO, SCENES, room_job  # noqa: E402

from photonmc.imageio import read_image  # noqa: E402
from photonmc.metrics import luminance  # noqa: E402


def render_passes(room: str, method: str, options: dict, seed: int, passes: int) -> np.ndarray:
    scene, _, params = SCENES[room]
    p = room_job(scene, params, method, options, seed).prepare()
    try:
        for _ in range(passes):
            p.method.iterate()
        return p.method.image()
    finally:
        p.release()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("room", choices=sorted(SCENES))
    ap.add_argument("--method", default="sppm")
    ap.add_argument("--passes", type=int, default=1500)
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--a", default="full")
    ap.add_argument("--b", default="linear")
    ap.add_argument("--top", type=int, default=12)
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    _, reference, _ = SCENES[args.room]
    ref = read_image(REPO / "tests" / "refs" / reference)
    images = {}
    for disc in (args.a, args.b):
        images[disc] = np.array([render_passes(args.room, args.method, {"disc": disc}, s, args.passes) for s in seeds])
        per_seed = [float(np.sqrt(np.mean((i - ref) ** 2))) for i in images[disc]]
        print(f"{disc}: RMSE per seed {', '.join(f'{e:.6g}' for e in per_seed)}")
    lum_ref = luminance(ref)
    means = {d: luminance(images[d]).mean(axis=0) for d in images}
    sq = {d: np.mean((luminance(images[d]) - lum_ref) ** 2, axis=0) for d in images}
    excess = sq[args.b] - sq[args.a]
    print(f"squared error summed over the image: {args.a} {sq[args.a].sum():.4g}, {args.b} {sq[args.b].sum():.4g}")
    total = excess.sum()
    width = ref.shape[1]
    print(f"| pixel (x, y) | reference | {args.a} | {args.b} | share of {args.b}'s excess |")
    print("|---|---|---|---|---|")
    for index in np.argsort(-excess.ravel())[:args.top]:
        y, x = divmod(int(index), width)
        share = excess[y, x] / total if total > 0 else float("nan")
        print(f"| ({x}, {y}) | {lum_ref[y, x]:.5f} | {means[args.a][y, x]:.5f} | {means[args.b][y, x]:.5f} | {share:.3f} |")


if __name__ == "__main__":
    main()

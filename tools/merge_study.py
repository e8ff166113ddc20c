"""What merging costs a consistent method: K renders of N iterations merged, against one
render of K*N iterations (the same work), on a scene with a Mitsuba reference.

    python tools/merge_study.py [--scene cornell-box] [--iterations 100] [--renders 4] [--methods pt,sppm,vcm]

For each method prints RMSE against the reference and the image mean's relative
difference from the reference's (bias plus noise), for the merge and for the one long
render. Results go in docs/resume.md.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from photonmc.imageio import read_image  # noqa: E402
from photonmc.loop import Job  # noqa: E402
from photonmc.merge import merged_image, worker_seed  # noqa: E402
from photonmc.metrics import rmse  # noqa: E402
from photonmc.state import state_of  # noqa: E402

REFERENCES = {"cornell-box": ("cornell-box-64.exr", {"res": "64"}),
              "caustic": ("caustic-64.exr", {"res": "64"}),
              "light-gap": ("light-gap-64.exr", {"res": "64"})}


def render(scene, params, method, seed, iterations):
    job = Job(scene=str(scene), params=params, method=method, seed=seed)
    p = job.prepare()
    try:
        for _ in range(iterations):
            p.method.iterate()
        return state_of(p.method, job.identity(), p.scene, 0.0)
    finally:
        p.release()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default="cornell-box", choices=sorted(REFERENCES))
    ap.add_argument("--iterations", type=int, default=100)
    ap.add_argument("--renders", type=int, default=4)
    ap.add_argument("--methods", default="pt,sppm,vcm")
    args = ap.parse_args()
    ref_name, params = REFERENCES[args.scene]
    ref = read_image(REPO / "tests" / "refs" / ref_name).astype(np.float64)
    scene = REPO / "scenes" / args.scene / "scene.xml"
    k, n = args.renders, args.iterations
    print(f"| method | {k} x {n} merged: RMSE | mean vs ref | one render of {k * n}: RMSE | mean vs ref |")
    print("|---|---|---|---|---|")
    for method in args.methods.split(","):
        members = [render(scene, params, method, worker_seed(0, i), n) for i in range(k)]
        merged = merged_image(members)
        single = render(scene, params, method, 0, k * n).image
        row = []
        for img in (merged, single):
            row += [f"{rmse(img, ref):.5f}", f"{(img.mean() / ref.mean() - 1) * 100:+.2f} %"]
        print(f"| {method} | " + " | ".join(row) + " |", flush=True)


if __name__ == "__main__":
    main()

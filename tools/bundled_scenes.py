"""Render every bundled scene (light-gap aside: it has its own tests) with the given methods
and compare the mean luminance with the Mitsuba references in tests/refs/ (documented in
docs/convergence.md).

    python tools/bundled_scenes.py [ITERATIONS] [METHODS]      # e.g. 20 visibility,spatial-tf,sppm
"""
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from photonmc import load_scene
from photonmc.imageio import read_image
from photonmc.loop import Budget, prepare, run
from photonmc.metrics import mean_luminance
from tests.conftest import SCENE_REFERENCES, half_resolution


def main():
    iterations = int(sys.argv[1]) if len(sys.argv) > 1 else 20
    methods = (sys.argv[2] if len(sys.argv) > 2 else "visibility,spatial-tf").split(",")
    print("| scene | method | iterations | finite | mean vs Mitsuba | seconds (compile included) |")
    print("|---|---|---|---|---|---|")
    for name, ref, params in SCENE_REFERENCES:
        scene = load_scene(ROOT / "scenes" / name / "scene.xml", half_resolution(params))
        ref_mean = mean_luminance(read_image(ROOT / "tests" / "refs" / ref))
        for method in methods:
            start = time.time()
            p = prepare(scene, method=method, seed=1)
            image = run(p, Budget(iterations=iterations), quiet=True).image
            p.release()
            print(f"| {name} | {method} | {iterations} | {np.isfinite(image).all()} | "
                  f"{100 * (mean_luminance(image) / ref_mean - 1):+.2f} % | {time.time() - start:.0f} |", flush=True)


if __name__ == "__main__":
    main()

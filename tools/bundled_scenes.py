"""Render every bundled scene (light-gap aside: it has its own tests) with the given methods
and compare the mean luminance with the Mitsuba references in tests/refs/ (documented in
docs/convergence.md).

    python tools/bundled_scenes.py [ITERATIONS] [METHODS]      # e.g. 20 visibility,spatial-tf,sppm
"""
import sys
import time

import numpy as np

from photonmc import load_scene
from photonmc.imageio import read_image
from photonmc.loop import Budget, prepare, run
from photonmc.metrics import mean_luminance

# Half the references' resolution: the mean of a box-filtered image does not depend on it.
CASES = [("cornell-box", "cornell-box-64.exr", {"res": 32}),
         ("mitsuba-style", "mitsuba-style-80x60.exr", {"resx": 40, "resy": 30}),
         ("mesh-room", "mesh-room-64.exr", {"res": 32}),
         ("caustic", "caustic-64.exr", {"res": 32})]


def main():
    iterations = int(sys.argv[1]) if len(sys.argv) > 1 else 20
    methods = (sys.argv[2] if len(sys.argv) > 2 else "visibility,spatial-tf").split(",")
    print("| scene | method | iterations | finite | mean vs Mitsuba | seconds (compile included) |")
    print("|---|---|---|---|---|---|")
    for name, ref, params in CASES:
        scene = load_scene(f"scenes/{name}/scene.xml", params)
        ref_mean = mean_luminance(read_image(f"tests/refs/{ref}"))
        for method in methods:
            start = time.time()
            p = prepare(scene, method=method, seed=1)
            image = run(p, Budget(iterations=iterations), quiet=True).image
            p.release()
            print(f"| {name} | {method} | {iterations} | {np.isfinite(image).all()} | "
                  f"{100 * (mean_luminance(image) / ref_mean - 1):+.2f} % | {time.time() - start:.0f} |", flush=True)


if __name__ == "__main__":
    main()

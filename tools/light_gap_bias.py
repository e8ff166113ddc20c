"""Seed study of a method's mean bias on the gap-lit room with the radius nearly frozen.

    python tools/light_gap_bias.py METHOD [ITERATIONS] [PHOTONS] [SEEDS] [ALPHA]

Renders scenes/light-gap at 64x64 with --alpha ALPHA (default 0.999) for seeds 1..SEEDS
(default 100 iterations, 65,536 photon paths or chain steps per pass, 6 seeds) and prints the mean
luminance outside the slit band against the Mitsuba reference, per seed and as mean +-
standard error. The slit band carries SPPM's boundary bias, shared by every photon-mapping
method (tests/test_guided.py); outside it, a frozen-radius image of a consistent method
matches the reference to within the blur of a 2-pixel radius. Results: docs/guiding.md.
"""
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from photonmc import load_scene, render
from photonmc.imageio import read_image
from photonmc.metrics import luminance
from tests.test_guided import _slit_band


def main():
    method = sys.argv[1]
    iterations = int(sys.argv[2]) if len(sys.argv) > 2 else 100
    photons = int(sys.argv[3]) if len(sys.argv) > 3 else 65536
    seeds = int(sys.argv[4]) if len(sys.argv) > 4 else 6
    alpha = float(sys.argv[5]) if len(sys.argv) > 5 else 0.999
    ref = luminance(read_image(ROOT / "tests/refs/light-gap-64.exr"))
    outside = ~_slit_band(ref)
    scene = load_scene(ROOT / "scenes/light-gap/scene.xml", {"res": 64})
    biases = []
    for seed in range(1, seeds + 1):
        img = luminance(render(scene, method=method, iterations=iterations, photons=photons, seed=seed, alpha=alpha))
        biases.append(100 * (img[:, outside].mean() / ref[:, outside].mean() - 1))
        print(f"{method} seed {seed}: {biases[-1]:+.3f} %", flush=True)
    b = np.array(biases)
    err = b.std(ddof=1) / np.sqrt(len(b)) if len(b) > 1 else float("nan")
    print(f"{method}, {iterations} iterations, {photons} per pass, alpha {alpha}: mean outside the band "
          f"{b.mean():+.3f} +- {err:.3f} % (seed spread {b.std(ddof=1) if len(b) > 1 else float('nan'):.3f} %, {len(b)} seeds)")


if __name__ == "__main__":
    main()

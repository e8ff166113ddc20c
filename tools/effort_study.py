"""Equal-time RMSE of sppm with `--photons auto` (the effort balance, docs/effort.md) against
the fixed default of one photon per pixel, on the bundled scenes' references.

    python tools/effort_study.py [--seconds 6] [--seeds 0,1] [--method sppm] [SCENE ...]

Each (scene, seed) renders both settings back to back, alternating which goes first, after
a warm-up iteration (compilation excluded). Prints a Markdown table: mean RMSE over seeds
with its standard error, the ratio, and (iterations, photons in the last pass) of the last seed.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from photonmc.imageio import read_image  # noqa: E402
from photonmc.loop import Job  # noqa: E402
from photonmc.metrics import rmse  # noqa: E402

CLOSEUP = {"res": "64", "fov": "12", "target": "-1.1,0.4,-0.6"}
SCENES = {"cornell-box": ("cornell-box", "cornell-box-64.exr", {"res": "64"}),
          "caustic": ("caustic", "caustic-64.exr", {"res": "64"}),
          "light-gap": ("light-gap", "light-gap-64.exr", {"res": "64"}),
          "mesh-room": ("mesh-room", "mesh-room-64.exr", {"res": "64"}),
          "mitsuba-style": ("mitsuba-style", "mitsuba-style-80x60.exr", {"resx": "80", "resy": "60"}),
          "light-gap-closeup": ("light-gap", "light-gap-closeup-64.exr", CLOSEUP),
          "attic-slit": ("attic-slit", "attic-slit-64.exr", {"res": "64"}),
          # Held out (tools/heldout/README.md): made after the balance was measured above.
          "closet-door": ("../tools/heldout/closet-door.xml", "../../tools/heldout/closet-door-64.exr", {"res": "64"})}


def rmse_after(scene: str, params: dict, method: str, options: dict, seed: int, seconds: float, ref):
    path = REPO / "scenes" / scene
    job = Job(scene=str(path.resolve() if path.suffix == ".xml" else path / "scene.xml"), params=params, method=method, options=options,
              seed=seed)
    p = job.prepare()
    try:
        m = p.method
        m.iterate()
        m.reset()
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < seconds:
            m.iterate()
        return rmse(m.image(), ref), (m.iterations, m.photons_per_iteration)
    finally:
        p.release()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scenes", nargs="*", default=list(SCENES))
    ap.add_argument("--seconds", type=float, default=6.0)
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--method", default="sppm")
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    print("| scene | auto RMSE | one per pixel RMSE | ratio | auto (iterations, photons) | fixed |")
    print("|---|---|---|---|---|---|")
    for name in args.scenes:
        scene, ref_name, params = SCENES[name]
        ref = read_image(REPO / "tests" / "refs" / ref_name).astype(np.float64)
        pixels = int(params["resx"]) * int(params["resy"]) if "resx" in params else int(params["res"]) ** 2
        errors, info = {"auto": [], "fixed": []}, {}
        for seed in seeds:
            order = ("auto", "fixed") if seed % 2 == 0 else ("fixed", "auto")
            for mode in order:
                photons = "auto" if mode == "auto" else pixels
                e, info[mode] = rmse_after(scene, dict(params), args.method, {"photons": photons}, seed,
                                           args.seconds, ref)
                errors[mode].append(e)
        a, f = np.array(errors["auto"]), np.array(errors["fixed"])
        se = lambda x: x.std() / np.sqrt(len(x))  # noqa: E731
        print(f"| {name} | {a.mean():.5f} ± {se(a):.5f} | {f.mean():.5f} ± {se(f):.5f} | {a.mean() / f.mean():.3f} | "
              f"{info['auto']} | {info['fixed']} |", flush=True)


if __name__ == "__main__":
    main()

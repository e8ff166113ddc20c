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
          "closet-door": ("../tools/heldout/closet-door.xml", "../../tools/heldout/closet-door-64.exr", {"res": "64"}),
          # Held out from the mutation study (2026-12-02).
          "slatted-window": ("../tools/heldout/slatted-window.xml", "../../tools/heldout/slatted-window-64.exr",
                             {"res": "64"}),
          # Held out from mbe's burn-in change (2026-12-02).
          "doorway": ("../tools/heldout/doorway.xml", "../../tools/heldout/doorway-64.exr", {"res": "64"}),
          # Held out from stop 57's clipped discs.
          "thick-jamb": ("../tools/heldout/thick-jamb.xml", "../../tools/heldout/thick-jamb-64.exr", {"res": "64"}),
          "shelf-nook": ("../tools/heldout/shelf-nook.xml", "../../tools/heldout/shelf-nook-64.exr", {"res": "64"}),
          # Held out from the guided photons' work (stops 29 and 31).
          "cellar-hatch": ("../tools/heldout/cellar-hatch.xml", "../../tools/heldout/cellar-hatch-64.exr",
                           {"res": "64"}),
          "lit-study": ("../tools/heldout/lit-study.xml", "../../tools/heldout/lit-study-64.exr", {"res": "64"}),
          "light-shaft": ("../tools/heldout/light-shaft.xml", "../../tools/heldout/light-shaft-64.exr", {"res": "64"}),
          "loft-hatch": ("../tools/heldout/loft-hatch.xml", "../../tools/heldout/loft-hatch-64.exr", {"res": "64"}),
          "light-bay": ("../tools/heldout/light-bay.xml", "../../tools/heldout/light-bay-64.exr", {"res": "64"}),
          # Held out from the combined fallback of mbe's pass choice (stop 43).
          "ceiling-slot": ("../tools/heldout/ceiling-slot.xml", "../../tools/heldout/ceiling-slot-64.exr",
                           {"res": "64"}),
          # Held out from mbe's chain-bias rule (stop 44).
          "side-slot": ("../tools/heldout/side-slot.xml", "../../tools/heldout/side-slot-64.exr", {"res": "64"}),
          # Held out from mbe's two films (stop 45).
          "slab-gap": ("../tools/heldout/slab-gap.xml", "../../tools/heldout/slab-gap-64.exr", {"res": "64"}),
          # Held out from the stratified pixel positions (stop 46).
          "strip-lights": ("../tools/heldout/strip-lights.xml", "../../tools/heldout/strip-lights-64.exr",
                           {"res": "64"}),
          # Held out from stop 47's defaults (made after their measurements).
          "balustrade": ("../tools/heldout/balustrade.xml", "../../tools/heldout/balustrade-64.exr", {"res": "64"}),
          # Held out from sppm's twin camera paths (stop 50).
          "kitchen-counter": ("../tools/heldout/kitchen-counter.xml", "../../tools/heldout/kitchen-counter-64.exr",
                              {"res": "64"}),
          # Held out from vcm's light-path balance's significance rule (stop 51).
          "caustic-corner": ("../tools/heldout/caustic-corner.xml", "../../tools/heldout/caustic-corner-64.exr",
                             {"res": "64"}),
          # Held out from the balanced merging radius (stop 52).
          "slatted-lamp": ("../tools/heldout/slatted-lamp.xml", "../../tools/heldout/slatted-lamp-64.exr",
                           {"res": "64"}),
          # Made after stop 54's measurements.
          "transom-slot": ("../tools/heldout/transom-slot.xml", "../../tools/heldout/transom-slot-64.exr",
                           {"res": "64"}),
          # Made after stop 55's measurements.
          "louvre-bay": ("../tools/heldout/louvre-bay.xml", "../../tools/heldout/louvre-bay-64.exr", {"res": "64"}),
          # Made after stop 59's measurements.
          "skirting-slot": ("../tools/heldout/skirting-slot.xml", "../../tools/heldout/skirting-slot-64.exr",
                            {"res": "64"}),
          # Made after stop 61's measurements.
          "ceiling-gap-wall": ("../tools/heldout/ceiling-gap-wall.xml", "../../tools/heldout/ceiling-gap-wall-64.exr",
                               {"res": "64"}),
          # Made after stop 60's measurements.
          "two-gap": ("../tools/heldout/two-gap.xml", "../../tools/heldout/two-gap-64.exr", {"res": "64"}),
          "deep-window": ("../tools/heldout/deep-window.xml", "../../tools/heldout/deep-window-64.exr", {"res": "64"}),
          # Made after stop 63's probe shortcuts and linear-disc measurements.
          "floor-well": ("../tools/heldout/floor-well.xml", "../../tools/heldout/floor-well-64.exr", {"res": "64"}),
          # Made after stop 63's measurements, for issue 13 (light subpaths rarely contribute).
          "pinhole-bay": ("../tools/heldout/pinhole-bay.xml", "../../tools/heldout/pinhole-bay-64.exr", {"res": "64"}),
          "ceiling-pinhole": ("../tools/heldout/ceiling-pinhole.xml", "../../tools/heldout/ceiling-pinhole-64.exr",
                              {"res": "64"}),
          # Made after stop 66's balanced chain pass length for mbe was set.
          "wall-pinhole-closet": ("../tools/heldout/wall-pinhole-closet.xml",
                                  "../../tools/heldout/wall-pinhole-closet-64.exr", {"res": "64"}),
          # Made after stop 56's measurements.
          "pantry-vent": ("../tools/heldout/pantry-vent.xml", "../../tools/heldout/pantry-vent-64.exr", {"res": "64"}),
          # Made after stop 68's sealed discs were built and measured.
          "slit-annex": ("../tools/heldout/slit-annex.xml", "../../tools/heldout/slit-annex-64.exr", {"res": "64"}),
          # Held out from the effort balance's weighted camera variance (stop 69).
          "clerestory-annex": ("../tools/heldout/clerestory-annex.xml", "../../tools/heldout/clerestory-annex-64.exr",
                               {"res": "64"}),
          # Made after stop 70's fewer-twins rule: an open room where vcm passes win.
          "open-den": ("../tools/heldout/open-den.xml", "../../tools/heldout/open-den-64.exr", {"res": "64"}),
          # Rooms of mbe's suite (tools/mbe_suite.sh), for A/B runs of vcm's and mbe's options.
          "slit-cabinet": ("../tools/heldout/slit-cabinet.xml", "../../tools/heldout/slit-cabinet-64.exr",
                           {"res": "64"}),
          "glass-table": ("../tools/heldout/glass-table.xml", "../../tools/heldout/glass-table-64.exr", {"res": "64"})}


# Other trees' packages by name (tools/ab_study.py --a-tree loads one as `photonmc_base`): an
# option "_tree" set to such a name renders with that package's Job instead of this tree's.
OTHER_TREES = {}


def room_job(scene: str, params: dict, method: str, options: dict, seed: int) -> Job:
    """The render of one of SCENES' scenes (its first field: a bundled scene's folder, or an
    XML path relative to scenes/)."""
    path = REPO / "scenes" / scene
    options = dict(options)
    job = OTHER_TREES[options.pop("_tree")] if "_tree" in options else Job
    return job(scene=str(path.resolve() if path.suffix == ".xml" else path / "scene.xml"), params=params,
               method=method, options=options, seed=seed)


def render_for(scene: str, params: dict, method: str, options: dict, seed: int, seconds: float, after_pass=None,
               after_render=None):
    """`seconds` of rendering after a warm-up iteration (compilation excluded); after_pass(m)
    is called after each pass, after_render(m, elapsed seconds) once at the end, before the
    method is released. Returns (image, iterations, photons or chain steps per pass)."""
    p = room_job(scene, params, method, options, seed).prepare()
    try:
        m = p.method
        m.warm_up()
        m.reset()
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < seconds:
            m.iterate()
            if after_pass is not None:
                after_pass(m)
        if after_render is not None:
            after_render(m, time.perf_counter() - t0)
        # photons per pass (sppm and the guided methods) or chain steps per pass (mbe)
        return m.image(), m.iterations, getattr(m, "photons_per_iteration", getattr(m, "steps_last", None))
    finally:
        p.release()


def rmse_after(scene: str, params: dict, method: str, options: dict, seed: int, seconds: float, ref):
    image, iterations, per_pass = render_for(scene, params, method, options, seed, seconds)
    return rmse(image, ref), (iterations, per_pass)


def equal_time_pair(name: str, method: str, options: dict, seeds, seconds: float):
    """RMSE over seeds of `method` under each of two option sets ({label: options}) on scene
    `name`, rendered back to back, alternating which goes first. Returns ({label: errors},
    {label: (iterations, photons per pass) of the last seed})."""
    scene, ref_name, params = SCENES[name]
    ref = read_image(REPO / "tests" / "refs" / ref_name).astype(np.float64)
    labels = list(options)
    errors, info = {label: [] for label in labels}, {}
    for seed in seeds:
        for label in (labels if seed % 2 == 0 else labels[::-1]):
            e, info[label] = rmse_after(scene, dict(params), method, dict(options[label]), seed, seconds, ref)
            errors[label].append(e)
    return {label: np.array(v) for label, v in errors.items()}, info


def table_row(name: str, errors: dict, info: dict) -> str:
    """| scene | first RMSE ± se | second RMSE ± se | second/first ... | (Markdown)."""
    (la, a), (lb, b) = errors.items()
    se = lambda x: x.std() / np.sqrt(len(x))  # noqa: E731
    return (f"| {name} | {a.mean():.5f} ± {se(a):.5f} | {b.mean():.5f} ± {se(b):.5f} | {b.mean() / a.mean():.3f} | "
            f"{info[la]} | {info[lb]} |")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scenes", nargs="*", default=list(SCENES))
    ap.add_argument("--seconds", type=float, default=6.0)
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--method", default="sppm")
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    print("| scene | one per pixel RMSE | auto RMSE | auto/fixed | fixed (iterations, photons) | auto |")
    print("|---|---|---|---|---|---|")
    for name in args.scenes:
        params = SCENES[name][2]
        pixels = int(params["resx"]) * int(params["resy"]) if "resx" in params else int(params["res"]) ** 2
        errors, info = equal_time_pair(name, args.method, {"fixed": {"photons": pixels}, "auto": {"photons": "auto"}},
                                       seeds, args.seconds)
        print(table_row(name, errors, info), flush=True)


if __name__ == "__main__":
    main()

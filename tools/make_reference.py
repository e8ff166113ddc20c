"""Render an independent reference of a scene file with Mitsuba 3's `path` integrator.

    python tools/make_reference.py scenes/cornell-box/scene.xml --spp 8192 --out refs/cornell-box.exr \
        [-D res=128] [--variant llvm_ad_rgb]

The same XML that photonmc renders is given to Mitsuba unchanged (only `$name` parameters
set with -D), so agreement between the two is evidence of correctness for both the loader
and the estimator. Needs `pip install mitsuba` (not a photonmc dependency). The llvm
variant is about 2x faster but needs LLVM >= 16 (Debian: `apt-get install libllvm19`).
Large spp are rendered in passes with different seeds and averaged, so memory stays small;
the spread of the passes gives the reference's own mean squared error (photonmc:noise_mse).
The command line is stored in the EXR header (photonmc:command) and printed.

`--crop X,Y,W,H:SPP` (repeatable) renders that window again with SPP more samples per pixel
and pools them with the whole image's: where a path tracer is heavy-tailed (a caustic on a
diffuse floor seen directly: the caustic's reference at 65,536 spp read its brightest pixel
8 % low, 2 standard errors, docs/vcm.md), the window's pixels get the samples they need for a
fraction of the time. The noise record then holds each pixel's own variance.
"""
from __future__ import annotations

import argparse
import os
import re
import shlex
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene")
    ap.add_argument("--spp", type=int, default=4096)
    ap.add_argument("--pass-spp", type=int, default=512, help="samples per pass (memory bound)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--variant", default=None, help="default: llvm_ad_rgb if it works, else scalar_rgb")
    ap.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE")
    ap.add_argument("--crop", action="append", default=[], type=_crop, metavar="X,Y,W,H:SPP",
                    help="render this pixel window with SPP more samples per pixel (repeatable)")
    args = ap.parse_args(argv)

    if "DRJIT_LIBLLVM_PATH" not in os.environ and Path("/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1").exists():
        os.environ["DRJIT_LIBLLVM_PATH"] = "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1"
    import mitsuba as mi

    variant = args.variant
    if variant is None:
        variant = "llvm_ad_rgb" if "DRJIT_LIBLLVM_PATH" in os.environ else "scalar_rgb"
    mi.set_variant(variant)
    params = dict(d.split("=", 1) for d in args.defines)
    scene = mi.load_file(args.scene, **params)
    t0 = time.time()
    passes, spp = _passes(args.spp, args.pass_spp)
    mean, var_mean = _render(mi, scene, passes, spp, 1000, t0)
    samples = np.full(mean.shape[:2] + (1,), float(passes * spp))
    for k, (x, y, w, h, crop_spp) in enumerate(args.crop):
        if x + w > mean.shape[1] or y + h > mean.shape[0]:
            ap.error(f"--crop {x},{y},{w},{h} leaves the {mean.shape[1]}x{mean.shape[0]} image")
        crop_passes, per_pass = _passes(crop_spp, args.pass_spp)
        cropped = _cropped_scene(mi, args.scene, params, (x, y, w, h))
        # Seeds apart from the whole image's and from each other's.
        c_mean, c_var = _render(mi, cropped, crop_passes, per_pass, 100000 * (k + 1), t0)
        window = (slice(y, y + h), slice(x, x + w))
        n0, n1 = samples[window], float(crop_passes * per_pass)
        # Pooled per pixel by sample count (the same estimator), and so their variances.
        mean[window] = (n0 * mean[window] + n1 * c_mean) / (n0 + n1)
        var_mean[window] = (n0 * n0 * var_mean[window] + n1 * n1 * c_var) / (n0 + n1) ** 2
        samples[window] = n0 + n1
    image = mean.astype(np.float32)

    from photonmc.imageio import write_image
    command = "python " + " ".join(shlex.quote(a) for a in [sys.argv[0]] + (argv or sys.argv[1:]))
    meta = {"method": f"mitsuba3-{mi.__version__}-{variant}-path", "spp": spp * passes,
            "command": command, "seconds": f"{time.time() - t0:.1f}"}
    if args.crop:
        meta["crops"] = ";".join(f"{x},{y},{w},{h}:{c}" for x, y, w, h, c in args.crop)
    if passes > 1:
        # The reference's own noise: its expected squared error per pixel and channel, from the
        # spread of the independent passes (`photonmc converge` removes it in quadrature).
        meta["noise_mse"] = f"{float(np.mean(var_mean)):.6g}"
        meta["noise_passes"] = passes
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    write_image(args.out, image, meta)
    print(f"wrote {args.out}: {spp * passes} spp in {time.time() - t0:.1f} s with {variant}\n{command}")


def _crop(text: str) -> tuple[int, int, int, int, int]:
    try:
        window, spp = text.split(":")
        x, y, w, h = (int(v) for v in window.split(","))
        spp = int(spp)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--crop takes X,Y,W,H:SPP, got '{text}'") from None
    if min(x, y) < 0 or min(w, h, spp) < 1:
        raise argparse.ArgumentTypeError(f"--crop needs a window inside the image and SPP >= 1, got '{text}'")
    return x, y, w, h, spp


def _passes(total: int, per_pass: int) -> tuple[int, int]:
    passes = max(1, -(-total // per_pass))
    return passes, total // passes


def _render(mi, scene, passes: int, spp: int, first_seed: int, t0: float):
    """The mean of `passes` renders of `spp` samples, and its variance per pixel and channel
    from their spread (0 with one pass)."""
    acc = acc2 = None
    for i in range(passes):
        img = np.array(mi.render(scene, spp=spp, seed=first_seed + i), dtype=np.float64)[..., :3]
        acc = img if acc is None else acc + img
        acc2 = img * img if acc2 is None else acc2 + img * img
        print(f"pass {i + 1}/{passes} ({spp} spp, {img.shape[1]}x{img.shape[0]}) {time.time() - t0:.1f} s",
              file=sys.stderr)
    mean = acc / passes
    if passes < 2:
        return mean, np.zeros_like(mean)
    var_pass = np.maximum(acc2 / passes - mean * mean, 0.0) * passes / (passes - 1)
    return mean, var_pass / passes


def _cropped_scene(mi, path: str, params: dict, window):
    """The scene with its film cropped to the window (Mitsuba's hdrfilm crop_offset_x/y,
    crop_width/height), read from a copy of the XML beside the original so that its relative
    paths (meshes) still resolve."""
    x, y, w, h = window
    text = Path(path).read_text()
    crop = "".join(f'<integer name="{n}" value="{v}"/>' for n, v in
                   (("crop_offset_x", x), ("crop_offset_y", y), ("crop_width", w), ("crop_height", h)))
    text, count = re.subn(r'(<film\s+type="hdrfilm"[^>]*>)', lambda m: m.group(1) + crop, text)
    if count != 1:
        sys.exit(f"--crop needs one <film type=\"hdrfilm\"> in {path}, found {count}")
    copy = Path(path).with_name(f".{Path(path).stem}.crop-{os.getpid()}.xml")
    copy.write_text(text)
    try:
        return mi.load_file(str(copy), **params)
    finally:
        copy.unlink()


if __name__ == "__main__":
    main()

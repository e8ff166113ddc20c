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
"""
from __future__ import annotations

import argparse
import os
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
    passes = max(1, -(-args.spp // args.pass_spp))
    spp = args.spp // passes
    acc = acc2 = None
    t0 = time.time()
    for i in range(passes):
        img = np.array(mi.render(scene, spp=spp, seed=1000 + i), dtype=np.float64)[..., :3]
        acc = img if acc is None else acc + img
        acc2 = img * img if acc2 is None else acc2 + img * img
        print(f"pass {i + 1}/{passes} ({spp} spp) {time.time() - t0:.1f} s", file=sys.stderr)
    image = (acc / passes).astype(np.float32)

    from photonmc.imageio import write_image
    command = "python " + " ".join(shlex.quote(a) for a in [sys.argv[0]] + (argv or sys.argv[1:]))
    meta = {"method": f"mitsuba3-{mi.__version__}-{variant}-path", "spp": spp * passes,
            "command": command, "seconds": f"{time.time() - t0:.1f}"}
    if passes > 1:
        # The reference's own noise: its expected squared error per pixel and channel, from the
        # spread of the independent passes (`photonmc converge` removes it in quadrature).
        mean = acc / passes
        var_pass = np.maximum(acc2 / passes - mean * mean, 0.0) * passes / (passes - 1)
        meta["noise_mse"] = f"{float(np.mean(var_pass / passes)):.6g}"
        meta["noise_passes"] = passes
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    write_image(args.out, image, meta)
    print(f"wrote {args.out}: {spp * passes} spp in {time.time() - t0:.1f} s with {variant}\n{command}")


if __name__ == "__main__":
    main()

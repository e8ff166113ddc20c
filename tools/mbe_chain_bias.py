"""mbe's chains against its own uniform proposals, pass by pass (docs/mbe.md, "The chains'
own bias, pass by pass"); the guided photon methods' likewise (docs/guiding.md).

    python tools/mbe_chain_bias.py SCENE [-D res=64] [--reference REF.exr] [--passes 600]
                                   [--seeds 0,1] [--option NAME=JSON ...]
                                   [--method mbe|visibility|spatial-tf]

Every chain pass estimates its light side twice from the same camera subpaths and the same
merging radius: the chains' estimate C (their records, scaled by the pass's normalisations)
and the uniform proposals' plain Monte Carlo estimate U (methods/mbe.py, _pass_scales). U is
unbiased for what that pass's techniques estimate, so E[C - U] != 0 is the chains' own bias,
whatever the radius's; the pair's difference has far less noise than either against a
reference. Prints, per seed and pooled, the mean luminance of camera + C and of camera + U
(against the reference's when given) and of C - U relative to U, with standard errors over
the passes (the passes are independent: docs/mbe.md, stop 43). Chain passes only
(--vcm-passes off); options by their API names, e.g. --option camera_paths=5.

visibility and spatial-tf keep the uniform photons' flux in an accumulator of its own next
to the chain levels' (methods/guided.py): each pass's flux summed over the measurement
points, the levels' (C) against the uniform photons' (U), gives their chains' own bias the
same way (only C - U is printed: a pixel's estimate is not linear in its flux).
"""
import argparse
import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from photonmc.imageio import read_image  # noqa: E402
from photonmc.loop import prepare  # noqa: E402
from photonmc.metrics import luminance  # noqa: E402

Y = np.array([0.2126, 0.7152, 0.0722])


def _record_light_sides(method, rows):
    """Wrap the method's _pass_scales: before the pass's frames are scaled and cleared, record
    the pixels' mean luminance of the camera side, of C and of U."""
    original = method._pass_scales

    def wrapped(steps, b, scale, tallies):
        result = original(steps, b, scale, tallies)
        unit = method.film.unit
        light = method.light_frame.to_numpy().astype(np.float64) @ Y     # (4, h, w): levels 0, 1 by parity
        uniform = method.uniform_frame.to_numpy().astype(np.float64) @ Y
        camera = method.film.frame.to_numpy().astype(np.float64) @ Y
        pre = method.pre_scale_host.astype(np.float64)
        chains = unit * ((light[0] + light[1]).mean() * scale[0] / pre[0]
                         + (light[2] + light[3]).mean() * scale[1] / pre[1])
        n_uniform = float(tallies["uniform_per_chain"].sum())
        uniform_side = unit * (uniform[0] + uniform[1]).mean() * steps / n_uniform if n_uniform > 0 else np.nan
        rows.append((unit * camera.mean(), chains, uniform_side, result[-1]))   # beta
        return result

    method._pass_scales = wrapped


def _record_fluxes(method, rows):
    """The guided methods: wrap _after_pass, which sees the pass's flux accumulators (chain
    levels, then the uniform photons') and their scales before the update clears them."""
    original = method._after_pass

    def wrapped(level_scale):
        phi = method.phi.to_numpy().astype(np.float64) @ Y           # (levels + 1, MPs)
        raw = method.raw_scale.to_numpy()
        per_accumulator = phi.sum(axis=1) * raw
        rows.append((0.0, per_accumulator[:-1].sum(), per_accumulator[-1], method.beta.value))
        return original(level_scale)

    method._after_pass = wrapped


def _mean_se(x):
    x = np.asarray(x, np.float64)
    return x.mean(), x.std(ddof=1) / np.sqrt(len(x))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene")
    ap.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE")
    ap.add_argument("--reference")
    ap.add_argument("--passes", type=int, default=600)
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--option", action="append", default=[], metavar="NAME=JSON")
    ap.add_argument("--method", default="mbe", choices=["mbe", "visibility", "spatial-tf"])
    args = ap.parse_args()
    params = dict(d.split("=", 1) for d in args.defines)
    options = {"vcm_passes": "off"} if args.method == "mbe" else {}
    for o in args.option:
        name, value = o.split("=", 1)
        options[name] = json.loads(value)
    ref_mean = None
    if args.reference and args.method == "mbe":
        ref_mean = float(luminance(read_image(args.reference)).mean())
    pooled = []
    for seed in map(int, args.seeds.split(",")):
        p = prepare(args.scene, method=args.method, seed=seed, options=options, params=params)
        rows = []
        try:
            (_record_light_sides if args.method == "mbe" else _record_fluxes)(p.method, rows)
            while len(rows) < args.passes:
                p.method.iterate()
        finally:
            p.release()
        rows = np.array(rows[:args.passes])
        pooled.append(rows)
        _report(f"seed {seed}", rows, ref_mean)
    _report("pooled", np.concatenate(pooled), ref_mean)


def _report(label, rows, ref_mean):
    camera, chains, uniform, beta = rows.T
    ok = np.isfinite(uniform)
    d_mean, d_se = _mean_se((chains - uniform)[ok])
    u_mean, _ = _mean_se(uniform[ok])
    line = [f"{label}: {len(rows)} passes, beta {beta.mean():.2f}",
            f"C - U = {100 * d_mean / u_mean:+.2f} +- {100 * d_se / u_mean:.2f} % of U"]
    if ref_mean is not None:
        for name, side in (("camera + C", camera + chains), ("camera + U", camera + uniform)):
            m, se = _mean_se(side[ok])
            line.append(f"{name} {100 * (m / ref_mean - 1):+.2f} +- {100 * se / ref_mean:.2f} %")
        line.append(f"light side {100 * u_mean / ref_mean:.0f} % of the reference")
    print("; ".join(line), flush=True)


if __name__ == "__main__":
    main()

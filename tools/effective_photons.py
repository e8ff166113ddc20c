"""Effective independent visible photons per second of the guided methods against sppm's
(issue 16, item 1: "report acceptance, theta and the effective number of independent visible
photons per second against sppm's").

    python tools/effective_photons.py [--seconds 15] [--seed 0] [--methods sppm,visibility,spatial-tf]
                                      [--radius R] [--guided JSON] ROOM ...

ROOM is a name of tools/effort_study.py's SCENES. Every method renders the room at one fixed
radius (the default initial radius, or --radius R in scene units; alpha 0.999, the
progressive rule: the radii stay within 0.1 % of it over a short render), one camera path per
pixel per pass and chain passes only (--uniform-passes off), so that the photon variance of
every method is measured on the same measurement points. Each method's photon variance per
photon path (or chain step) V_p is the effort balance's (methods/effort.py: each pass's two
halves, even and odd photons or chains, whose estimates share the measurement points;
pixel-mean luminance, rescaled to the pass's radius). Over a render of T seconds a method's
photon variance is V_p / (r T), r its photon paths or chain steps per second, so

    N_eff = nu_sppm x (V_p,sppm / r_sppm) / (V_p,method / r_method)

is the rate of independent visible photons (sppm's, nu_sppm = its depositing fraction x its
photons per second) that would give the method's photon variance per second. For sppm it is
nu_sppm itself. r counts the whole render, camera passes included (one camera path per pixel
per pass for every method). --guided adds options (JSON) that every guided method listed
takes. Prints a Markdown table; docs/guiding.md has the figures.

The last column is what N_eff implies for the image, with g = N_eff / nu_sppm. sppm's row
gives its camera share s_c (camera_share below: how much of its balanced noise, in RMSE, is
the camera side's, which no photon method reduces). A guided method's row gives three
ratios to sppm's RMSE at the same time: its noise at the same radius, s_c + (1 - s_c) /
sqrt(g); and, with the camera side left out, g^(-1/3) and g^(-1/4): the least RMSE of a
photon-mapping render whose radius balances its bias against its noise, bias ~ R^2 (a smooth
neighbourhood: MSE ~ (V / N)^(2/3)) or ~ R (an edge cutting the disc: MSE ~ (V / N)^(1/2)), when
its photons are worth g times as many (docs/guiding.md, "What the chains' photons are worth to
the image"). V_c's trim (the effort balance drops the largest 1/32 of the camera variances)
makes s_c read low where rare camera paths are the error.

V_p is a pass's variance, so N_eff describes the image only where passes are independent:
sppm's, and the guided methods' by default (a pass records level 0 from its first visible
uniform proposal on and starts the upper levels from copies of it). Chains whose states carry
from pass to pass (spatial-tf --spatial-updates epochs) correlate consecutive passes, which
V_p does not see (little in the pantry vent: a lag-1 correlation of +0.036; docs/guiding.md,
"Spatial targets held for an epoch").
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from effort_study import SCENES, render_for  # noqa: E402

FIXED = {"alpha": 0.999, "radius_rule": "progressive", "camera_paths": 1}
CAMERA_SHARE_PHOTONS = 64      # per pixel per pass: sppm's largest (effort.MAX_PER_PIXEL)
GUIDED = {"uniform_passes": "off"}


def measure(name: str, method: str, seed: int, seconds: float, radius=None, guided=None, photons=None) -> dict:
    """One render of `seconds` after a warm-up (compilation excluded): its photon variance
    per photon path, throughput and chain statistics (photons: sppm's photons per pass)."""
    scene, _, params = SCENES[name]
    options = dict(FIXED, **(dict(GUIDED, **(guided or {})) if method != "sppm" else {}))
    if radius is not None:
        options["radius"] = radius
    if photons is not None:
        options["photons"] = photons
    out = {}

    def read(m, elapsed):
        stats = m.method_stats()
        shares = m.effort.shares()
        radius_sq = m.effort.radius_sq
        out.update({"passes": m.iterations, "photons_per_second": m.photons_emitted / elapsed,
                    "photon_variance": shares[1] if shares else float("nan"),
                    "mean_radius": float(np.sqrt(radius_sq)) if radius_sq else float("nan")})
        if method == "sppm":
            out["visible"] = stats["fraction_of_photon_paths_depositing"]
            balance = m.effort.stats()
            out["camera_share"] = camera_share(shares, balance["camera_work_per_pass"], balance["segments_per_photon"])
            out["pixels"] = m.n_pixels
        else:
            out["visible"] = stats["uniform_visible_fraction"]
            out["levels"] = [(lv["target"], lv["acceptance"], lv["theta"]) for lv in stats["levels"]]

    render_for(scene, dict(params), method, options, seed, seconds, after_render=read)
    return out


def camera_share(shares, camera_work: float, photon_work: float) -> float:
    """s_c = a_c / (a_c + a_p), a_c = sqrt(V_c c_c) and a_p = sqrt(V_p c_p) (per camera path, per
    photon path; the effort balance's counted work). At the balanced split an SPPM-family
    render's noise at a budget W is (a_c + a_p) / sqrt(W) in RMSE (docs/effort.md), and a photon
    method whose photons are worth N_eff of sppm's per unit of work leaves the camera side
    alone: its noise is (a_c + a_p / sqrt(N_eff)) / sqrt(W), at least s_c of sppm's however
    large N_eff. V_c is read from a render of CAMERA_SHARE_PHOTONS photons per pixel per pass:
    at one per pixel the pass-to-pass spread is nearly all photon noise where photons are
    scarce, and V_c's estimate (a difference) comes out at or below 0."""
    if not shares or not camera_work or not photon_work:
        return float("nan")
    a_c = math.sqrt(max(shares[0], 0.0) * camera_work)
    a_p = math.sqrt(max(shares[1], 0.0) * photon_work)
    return a_c / (a_c + a_p) if a_c + a_p > 0.0 else float("nan")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("rooms", nargs="+")
    ap.add_argument("--methods", default="sppm,visibility,spatial-tf")
    ap.add_argument("--seconds", type=float, default=15.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--radius", type=float, default=None, help="the fixed gather radius, in scene units")
    ap.add_argument("--guided", default="{}", help="more options of the guided methods, as JSON")
    args = ap.parse_args()
    guided = json.loads(args.guided)
    methods = args.methods.split(",")
    if methods[0] != "sppm":
        ap.error("--methods must start with sppm: N_eff is counted in sppm's visible photons")
    radius = f"radius {args.radius}" if args.radius is not None else "the default initial radius"
    print(f"{args.seconds} s per method, seed {args.seed}, {radius}; {FIXED}, guided {dict(GUIDED, **guided)}\n")
    print("| room | method | mean radius | photon paths or steps / s | visible fraction | V_p per path | "
          "acceptance, theta (per level) | N_eff / s | vs sppm | vs sppm's RMSE: noise at one radius; "
          "balanced, bias ~ R^2, ~ R |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for room in args.rooms:
        base = None
        for method in methods:
            r = measure(room, method, args.seed, args.seconds, args.radius, guided)
            per_second = r["photon_variance"] / r["photons_per_second"]   # photon variance x time
            if method == "sppm":
                base = (r["visible"] * r["photons_per_second"], per_second)
                share = measure(room, method, args.seed, args.seconds, args.radius,
                                photons=CAMERA_SHARE_PHOTONS * r["pixels"])["camera_share"]
                n_eff = base[0]
                predicted = f"camera share s_c {share:.2f}"
            else:
                n_eff = base[0] * base[1] / per_second
                gain = n_eff / base[0]
                predicted = (f"{share + (1.0 - share) / math.sqrt(gain):.2f}x; "
                             f"{gain ** (-1.0 / 3.0):.2f}x, {gain ** -0.25:.2f}x")
            levels = "; ".join(f"{t} {a:.3f}, {th:.3f}" for t, a, th in r.get("levels", []))
            print(f"| {room} | {method} | {r['mean_radius']:.4f} | {r['photons_per_second']:,.0f} | {r['visible']:.4f} | "
                  f"{r['photon_variance']:.4g} | {levels} | {n_eff:,.0f} | {n_eff / base[0]:.2f}x | {predicted} |",
                  flush=True)


if __name__ == "__main__":
    main()

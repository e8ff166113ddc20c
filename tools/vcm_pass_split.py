"""How a vcm pass's time splits between what grows with its light subpaths N and what does not,
against the split of mbe's pass choice's cost model (methods/pass_choice.py; docs/mbe.md, "A
vcm pass at fewer light subpaths: its time and its variance", stop 38):

    python tools/vcm_pass_split.py SCENE.xml [SCENE.xml ...] [-D res=64] [--rounds 6]

For each scene: mbe's chain passes at one camera subpath per pixel (`--vcm-passes off
--camera-paths 1`) count the work (camera rays, light segments and rays, connections, merge
candidates); then vcm at --light-paths N for N = pixels, pixels / 4 and pixels / 16 renders,
interleaved in one process, and its time per pass as a ratio to N = pixels is printed beside
the ratio of the pass choice's cost model (connections and merges as light work, camera work
at CAMERA_WORK_WEIGHT). One JSON line per scene; with several scenes, the least-squares
weights of camera work and merge candidates with which (w_c camera + connections) per pixel
against (segments + light-tracing rays + w_m merges) per light subpath fits the measured
ratios, and each scene's ratios under that fit.
"""
import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))


def measure(scene, params, rounds, iterations):
    from photonmc.loop import Job
    from photonmc.methods.effort import DEPOSIT_WORK
    from photonmc.methods.pass_choice import CAMERA_WORK_WEIGHT
    mbe = Job(scene=scene, params=dict(params), method="mbe",
              options={"vcm_passes": "off", "camera_paths": 1}, seed=0).prepare()
    for _ in range(40):
        mbe.method.iterate()
    m = mbe.method
    effort = m.effort
    counters = m.light_counters.to_numpy().astype(np.float64)
    traced = counters[0]
    segments, rays, merges, connections = counters[1:] / traced
    camera = effort.sum_camera_work / effort.sum_camera_paths / m.n_pixels     # per pixel
    pixels = m.n_pixels
    ns = [pixels, pixels // 4, pixels // 16]
    # the pass choice's model: connections and merges as light work, camera at its weight
    chain_model = {n: (CAMERA_WORK_WEIGHT * camera + n / pixels * (segments + rays + DEPOSIT_WORK * merges))
                   / (CAMERA_WORK_WEIGHT * camera + segments + rays + DEPOSIT_WORK * merges) for n in ns}
    mbe.release()
    jobs = {n: Job(scene=scene, params=dict(params), method="vcm", options={"light_paths": n}, seed=0).prepare()
            for n in ns}
    for j in jobs.values():
        for _ in range(15):
            j.method.iterate()
    times = {n: [] for n in ns}
    for r in range(rounds):
        for n in (ns if r % 2 == 0 else ns[::-1]):
            t = time.perf_counter()
            for _ in range(iterations):
                jobs[n].method.iterate()
            times[n].append((time.perf_counter() - t) / iterations)
    for j in jobs.values():
        j.release()
    base = np.asarray(times[pixels])
    ratios = {n: np.asarray(times[n]) / base for n in ns}
    return {"scene": scene, "ms_per_pass": 1000 * float(np.median(base)),
            "measured": {n: float(r.mean()) for n, r in ratios.items()},
            "measured_se": {n: float(r.std() / np.sqrt(len(r))) for n, r in ratios.items()},
            "pass_choice_model": chain_model,
            "per_light_subpath": {"segments": segments, "rays": rays, "connections": connections, "merges": merges},
            "camera_work_per_pixel": camera}


def fit(results):
    """Weights (camera work, merge candidates) with which (w_c camera + connections) / (segments +
    light-tracing rays + w_m merges), the pass's fixed work over a light subpath's per pixel,
    matches the measured ratios: r(N) = (x + N/P l) / (x + l), so x / l = (r - N/P) / (1 - r)."""
    rows, rhs = [], []
    for res in results:
        s = res["per_light_subpath"]
        pixels = max(res["measured"])
        for n, r in res["measured"].items():
            if n == pixels or not r < 1.0:
                continue
            q = (r - n / pixels) / (1.0 - r)
            rows.append([res["camera_work_per_pixel"], -q * s["merges"]])
            rhs.append(q * (s["segments"] + s["rays"] - s["connections"]) - s["connections"])
    (w_c, w_m), *_ = np.linalg.lstsq(np.asarray(rows), np.asarray(rhs), rcond=None)
    predicted = {}
    for res in results:
        s = res["per_light_subpath"]
        pixels = max(res["measured"])
        fixed = w_c * res["camera_work_per_pixel"] + s["connections"]
        light = s["segments"] + s["rays"] - s["connections"] + w_m * s["merges"]
        predicted[res["scene"]] = {n: (fixed + n / pixels * light) / (fixed + light) for n in res["measured"]}
    return {"camera_weight": float(w_c), "merge_weight": float(w_m), "ratios_under_the_fit": predicted}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenes", nargs="+")
    ap.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE")
    ap.add_argument("--rounds", type=int, default=6)
    ap.add_argument("--iterations", type=int, default=20, help="iterations per N per round")
    args = ap.parse_args()
    from photonmc import runtime
    runtime.init("cpu")
    params = dict(d.split("=", 1) for d in args.defines)
    params.setdefault("res", "64")
    results = []
    for scene in args.scenes:
        results.append(measure(scene, params, args.rounds, args.iterations))
        print(json.dumps(results[-1]), flush=True)
    if len(results) > 1:
        print(json.dumps({"fit": fit(results)}))


if __name__ == "__main__":
    main()

"""The cost model behind mbe's choice of vcm passes (methods/pass_choice.py) against measured
time: mbe's chain passes (`--vcm-passes off`) and vcm, interleaved in one process, their time
per iteration as a ratio, beside the ratio the counted work predicts, at full camera weight
without a chain step's own cost and with the fitted model (docs/mbe.md, "vcm passes where the
chains do not pay"):

    python tools/mbe_pass_costs.py SCENE.xml [-D res=64] [-D NAME=VALUE ...] [--rounds 8]

One JSON line per scene: the measured ratio and its standard error, the mean K and chain steps
of mbe's passes, the counted work (camera and light, per pass of each kind) and both
predictions.
"""
import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene")
    ap.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE")
    ap.add_argument("--rounds", type=int, default=8)
    ap.add_argument("--iterations", type=int, default=30, help="iterations per method per round")
    ap.add_argument("--warm-up", type=int, default=40)
    args = ap.parse_args()
    from photonmc import runtime
    from photonmc.loop import Job
    from photonmc.methods import pass_choice
    runtime.init("cpu")
    params = dict(d.split("=", 1) for d in args.defines)
    params.setdefault("res", "64")
    vcm = Job(scene=args.scene, params=dict(params), method="vcm", options={}, seed=0).prepare()
    mbe = Job(scene=args.scene, params=dict(params), method="mbe", options={"vcm_passes": "off"}, seed=0).prepare()
    for _ in range(args.warm_up):
        vcm.method.iterate()
        mbe.method.iterate()
    times = {"vcm": [], "mbe": []}
    passes = []
    for r in range(args.rounds):
        for name, p in ((("vcm", vcm), ("mbe", mbe)) if r % 2 == 0 else (("mbe", mbe), ("vcm", vcm))):
            t = time.perf_counter()
            for _ in range(args.iterations):
                p.method.iterate()
                if name == "mbe":
                    passes.append((p.method.steps_last, p.method.camera_paths))
            times[name].append((time.perf_counter() - t) / args.iterations)
    ratio = np.asarray(times["mbe"]) / np.asarray(times["vcm"])
    m = mbe.method
    steps = float(np.mean([s for s, _ in passes]))
    k = float(np.mean([kk for _, kk in passes]))
    counted = m.pass_choice.work_parts(m.effort, k, steps)
    chain_camera, chain_light = counted["chain_camera"], counted["chain_light"]
    vcm_camera, vcm_light = counted["vcm_camera"], counted["vcm_light"]
    fitted_chain, fitted_vcm = m.pass_choice.work(m.effort, k, steps)
    print(json.dumps({
        "scene": args.scene, "params": params,
        "ms_per_iteration": {name: 1000 * float(np.median(t)) for name, t in times.items()},
        "measured_ratio": float(ratio.mean()), "measured_ratio_se": float(ratio.std() / np.sqrt(len(ratio))),
        "mean_camera_paths": k, "mean_chain_steps": steps,
        "counted": counted,
        "predicted_full_camera_weight": (chain_camera + chain_light) / (vcm_camera + vcm_light),
        "predicted_fitted": fitted_chain / fitted_vcm,
    }))
    vcm.release()
    mbe.release()


if __name__ == "__main__":
    main()

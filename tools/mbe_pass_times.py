"""Where mbe's time goes: each pass of a default render timed by kind (chain or vcm), against
the pass choice's counted work (methods/pass_choice.py), with a vcm pass's connections
counted per light subpath (what `--vcm-passes auto` predicts with) and per pixel (what
`measured` uses; docs/mbe.md, "Each kind of pass measured"):

    python tools/mbe_pass_times.py SCENE.xml [-D res=64] [-D NAME=VALUE ...] [--passes 600]
                                   [--options '{"vcm_passes": "measured"}']

One JSON line: passes of each kind, the chain passes' share of the time, mean K and chain
steps, the measured time ratio of a chain pass to a vcm pass and the two counted ratios.
Timing wraps Mbe's own _chain_pass and _vcm_pass, so the render is the one mbe makes.
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
    ap.add_argument("--passes", type=int, default=600)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--options", default="{}", help="mbe's options, as JSON")
    args = ap.parse_args()
    from photonmc import runtime
    from photonmc.loop import Job
    runtime.init("cpu")
    params = dict(d.split("=", 1) for d in args.defines)
    params.setdefault("res", "64")
    p = Job(scene=args.scene, params=params, method="mbe", options=json.loads(args.options), seed=args.seed).prepare()
    m = p.method
    m.warm_up()
    m.reset()
    chain, vcm = [], []
    chain_pass, vcm_pass = m._chain_pass, m._vcm_pass

    def timed_chain(it):
        t = time.perf_counter()
        chain_pass(it)
        chain.append((time.perf_counter() - t, m.effort.last_camera_paths, m.steps_last))

    def timed_vcm(it, **kw):      # kw: keep=False for the passes that only measure (stop 42)
        n = m.light_balance.next_light_paths()
        t = time.perf_counter()
        vcm_pass(it, **kw)
        vcm.append((time.perf_counter() - t, n))

    m._chain_pass, m._vcm_pass = timed_chain, timed_vcm
    t0 = time.perf_counter()
    for _ in range(args.passes):
        m.iterate()
    total = time.perf_counter() - t0
    out = {"scene": args.scene, "chain_passes": len(chain), "vcm_passes": len(vcm)}
    if chain:
        c = np.asarray(chain)
        out.update(chain_time_share=float(c[:, 0].sum() / total), mean_k=float(c[:, 1].mean()),
                   mean_steps=float(c[:, 2].mean()))
    if chain and vcm:
        v = np.asarray(vcm)
        k, steps, n = int(round(out["mean_k"])), int(round(out["mean_steps"])), int(round(v[:, 1].mean()))
        pc = m.pass_choice
        counted = [pc.work(m.effort, k, steps, n, connections_per_pixel=per_pixel) for per_pixel in (False, True)]
        out.update(mean_vcm_light_paths=n, time_ratio=float(c[:, 0].mean() / v[:, 0].mean()),
                   counted_ratio_per_light_subpath=counted[0][0] / counted[0][1],
                   counted_ratio_per_pixel=counted[1][0] / counted[1][1])
    print(json.dumps(out))
    p.release()


if __name__ == "__main__":
    main()

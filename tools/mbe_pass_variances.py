"""mbe's pass choice (methods/pass_choice.py) against what the passes' variances are: after
`--warm-up` ordinary iterations, mbe makes passes in the pattern vcm, vcm, chain, chain and
measures each kind's variance per pass from the two of a kind in a row (the mean over pixels
of (e_1 - e_2)^2 / 2, luminance; consecutive chain passes share their chains' states, so
theirs is a slight underestimate), beside what the rule predicts for them before each pass:

    chain pass:  V_c / K + V_p / n,      vcm pass:  V_c + V_u / N_L

Then, for a vcm Job of the same scene, the light side of a vcm pass alone: the same pass
(camera subpaths) twice with independent light subpaths, (e_1 - e_2)^2 / 2 = its light-side
variance, against V_u / N_L (docs/mbe.md, "What the rule's predictions miss"), and the whole
pass's variance from consecutive passes; with --vcm-light-paths, at each of those light
subpaths N (the rule's model has the light side grow as 1 / N; docs/mbe.md, "A vcm pass at
fewer light subpaths", stop 38):

    python tools/mbe_pass_variances.py SCENE.xml [-D res=64] [-D NAME=VALUE ...]
                                       [--warm-up 200] [--pairs 60] [--seed 0]
                                       [--vcm-light-paths 4096,1024,256] [--vcm-techniques bpm]

One JSON line. Which pass a pattern position makes is forced through Mbe's own _vcm_pass and
_chain_pass, so the chain states and the radius index move as in a render.
"""
import argparse
import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
Y = np.array([0.2126, 0.7152, 0.0722])


def pass_images(method, make_pass, n):
    """The film's per-pass estimates (luminance) of n passes made by make_pass(i)."""
    film = method.film.film
    before, images = film.sum.to_numpy() @ Y, []
    for i in range(n):
        make_pass(i)
        after = film.sum.to_numpy() @ Y
        images.append(after - before)
        before = after
    return images


def mean_and_error(values):
    v = np.asarray(values)
    return float(v.mean()), float(v.std() / np.sqrt(len(v)))


def mbe_passes(job_args, warm_up, pairs):
    from photonmc.loop import Job
    p = Job(method="mbe", options={}, **job_args).prepare()
    m = p.method
    for _ in range(warm_up):
        m.iterate()
    pc, predicted = m.pass_choice, []

    def make_pass(i):
        shares = m.effort.shares()
        r2 = m._radius_at(m.camera_paths_traced) ** 2
        v_u = pc.uniform_r2_sum / pc.uniform_passes / r2
        predicted.append((shares[0] / m.camera_paths + shares[1] / m.steps_last, shares[0] + v_u / pc.n_light,
                          shares[0], v_u / pc.n_light, m.camera_paths))
        it = m.iteration_index
        if i % 4 < 2:
            m._vcm_pass(it)
        else:
            m._chain_pass(it)
        m.iterations += 1

    images = pass_images(m, make_pass, 4 * pairs)
    spread = {"vcm": [], "chain": []}
    for i in range(1, len(images), 2):
        spread["vcm" if i % 4 == 1 else "chain"].append(np.mean((images[i] - images[i - 1]) ** 2) / 2)
    pred = np.asarray(predicted).mean(axis=0)
    out = {"chain_pass": mean_and_error(spread["chain"]), "chain_pass_predicted": pred[0],
           "vcm_pass": mean_and_error(spread["vcm"]), "vcm_pass_predicted": pred[1],
           "predicted_V_c": pred[2], "predicted_V_u_over_N_L": pred[3], "mean_K": pred[4],
           "radius": m.radius, "rule_ratio": pc.ratio}
    p.release()
    return out


def vcm_light_side(job_args, warm_up, pairs, light_paths=(None,), techniques=None):
    """A vcm pass's light side: the pass of one index twice, its light subpaths' seed changed;
    at each of light_paths (None: --light-paths), with vcm's --techniques."""
    from photonmc.loop import Job
    p = Job(method="vcm", options={"techniques": techniques}, **job_args).prepare()
    m = p.method
    for _ in range(warm_up):
        m.iterate()
    light_pass, other = m._light_pass, {"seed": False}

    def with_seed(store, grid, *args):
        args = list(args)
        if other["seed"]:
            args[5] = (int(args[5]) ^ 0x5BD1E995) & 0xFFFFFFFF       # the light pass's seed
        return light_pass(store, grid, *args)

    m._light_pass = with_seed
    out = {}
    for n in light_paths:
        light, total, previous = [], [], None
        for j in range(pairs):
            it = warm_up + j
            images = []
            for changed in (False, True):
                other["seed"] = changed
                images += pass_images(m, lambda _: m.vcm_pass(it, it, n), 1)
            light.append(np.mean((images[0] - images[1]) ** 2) / 2)
            if previous is not None:
                total.append(np.mean((images[0] - previous) ** 2) / 2)
            previous = images[0]
        out[str(n or m.n_light)] = {"vcm_pass_light_side": mean_and_error(light), "vcm_pass": mean_and_error(total)}
    out["radius"] = m.radius
    p.release()
    return out if light_paths != (None,) else {**out.pop(str(m.n_light)), **out}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene")
    ap.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE")
    ap.add_argument("--warm-up", type=int, default=200)
    ap.add_argument("--pairs", type=int, default=60, help="pairs of passes of each kind measured")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--vcm-light-paths", default=None, metavar="N,N,...",
                    help="measure the vcm pass at each of these light subpaths (default: --light-paths)")
    ap.add_argument("--vcm-techniques", default=None, help="the vcm pass's --techniques (default: all)")
    args = ap.parse_args()
    from photonmc import runtime
    runtime.init("cpu")
    params = dict(d.split("=", 1) for d in args.defines)
    params.setdefault("res", "64")
    job_args = {"scene": args.scene, "params": params, "seed": args.seed}
    light_paths = tuple(int(n) for n in args.vcm_light_paths.split(",")) if args.vcm_light_paths else (None,)
    print(json.dumps({"scene": args.scene, "params": params,
                      "mbe": mbe_passes(job_args, args.warm_up, args.pairs),
                      "vcm": vcm_light_side(job_args, args.warm_up, args.pairs, light_paths, args.vcm_techniques)}))


if __name__ == "__main__":
    main()

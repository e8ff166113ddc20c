"""Which primary-sample coordinates make a visibility chain's mutations fail (issue 16, item 1).

    python tools/mutation_study.py [--passes 30] [--samples 200000] [SCENE ...]

For each scene: run `visibility` for `--passes` passes (so that theta has adapted and the
pass's measurement points exist), then draw uniform photon paths and keep the visible ones
(exact draws from V / b_V). Each visible state is then perturbed in one group of coordinates
only (light choice, point on the light, emission direction, and per bounce: direction, lobe,
roulette) and probed again: the fraction still visible is the acceptance a mutation of that
group alone would have. Perturbations: the chain's own (u +- r^(1/theta+1) per coordinate, at
the adapted theta) and fixed steps u +- s. A last row perturbs every coordinate with the
chain's mutation and reports the acceptance by the group that moved most.
Prints Markdown tables (docs/guiding.md, "Why the mutations shrink").
"""

import argparse
import sys
from pathlib import Path

import numpy as np
import taichi as ti

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from photonmc.kernels.mcmc import PROBE, STATE_MODE, ChainPool  # noqa: E402
from photonmc.kernels.photon import BOUNCE_DIMS, LIGHT_DIMS  # noqa: E402
from photonmc.loop import Job  # noqa: E402

CLOSEUP = {"res": "64", "fov": "12", "target": "-1.1,0.4,-0.6"}
SCENES = {"light-gap": ("scenes/light-gap/scene.xml", {"res": "64"}),
          "light-gap-closeup": ("scenes/light-gap/scene.xml", CLOSEUP),
          "attic-slit": ("scenes/attic-slit/scene.xml", {"res": "64"}),
          "closet-door": ("tools/heldout/closet-door.xml", {"res": "64"}),
          "cornell-box": ("scenes/cornell-box/scene.xml", {"res": "64"})}
BATCH = 1 << 15
BOUNCES_SHOWN = 3


def groups(dims):
    g = [("light choice", [0]), ("point on light", [1, 2]), ("emission direction", [3, 4])]
    for b in range(BOUNCES_SHOWN):
        base = LIGHT_DIMS + BOUNCE_DIMS * b
        if base + 3 < dims:
            g += [(f"bounce {b + 1} direction", [base, base + 1]), (f"bounce {b + 1} lobe", [base + 2]),
                  (f"bounce {b + 1} roulette", [base + 3])]
    return g


@ti.data_oriented
class Prober:
    """Evaluates V(u) for given primary sample vectors with the method's own trace (PROBE)."""

    def __init__(self, method, dims: int):
        self.method, self.dims = method, dims
        self.pool = ChainPool(BATCH, 1, dims)
        self.visible = ti.field(ti.f32, BATCH)

    @ti.kernel
    def _probe(self, model: ti.template(), n: ti.i32):
        ti.loop_config(serialize=True)        # the model's scratch space is per chain (vkey 0)
        for s in range(n):
            zero = ti.Vector([0.0] * model.n_levels)
            t, _ = model.trace(self.pool.source, ti.math.uvec4(s, 0, 0, STATE_MODE), 0, PROBE, zero, zero)
            self.visible[s] = t[0]

    def __call__(self, u: np.ndarray) -> np.ndarray:
        out = np.empty(len(u), bool)
        for start in range(0, len(u), BATCH):
            part = u[start:start + BATCH]
            full = np.zeros((BATCH, self.dims), np.float32)
            full[:len(part)] = part
            self.pool.u.from_numpy(full)
            self.pool.ell.from_numpy(np.full(BATCH, self.dims, np.int32))
            self._probe(self.method, len(part))
            out[start:start + len(part)] = self.visible.to_numpy()[:len(part)] > 0
        return out


def hj_delta(rng, shape, theta):
    r = rng.random(shape)
    return np.where(rng.random(shape) < 0.5, -1.0, 1.0) * r ** (1.0 / theta + 1.0)


def wrap(u):
    u = u - np.floor(u)
    return np.where(u >= 1.0, 0.0, u).astype(np.float32)


def study(name: str, passes: int, samples: int, seed: int):
    path, params = SCENES[name]
    job = Job(scene=str(REPO / path), params=dict(params), method="visibility", options={"camera_paths": 1},
              seed=seed)
    prepared = job.prepare()
    try:
        m = prepared.method
        for _ in range(passes):
            m.iterate()
        theta = float(m.pool.theta.to_numpy()[0])
        dims = m.pool.dims
        probe = Prober(m, dims)
        rng = np.random.default_rng(seed)
        u = rng.random((samples, dims), dtype=np.float32)
        vis = probe(u)
        states = u[vis]
        print(f"\n### {name}: visible fraction {vis.mean():.4f} ({len(states)} states), adapted theta {theta:.3g}, "
              f"acceptance so far {m.method_stats()['levels'][0]['acceptance']:.3f}\n")
        steps = (0.001, 0.01, 0.1)
        print("| coordinates perturbed | chain's mutation (theta) | " + " | ".join(f"step {s}" for s in steps) + " |")
        print("|---|---|" + "---|" * len(steps))
        for label, idx in groups(dims):
            row = []
            for kind in ("hj",) + steps:
                v = states.copy().astype(np.float64)
                shape = (len(v), len(idx))
                if kind == "hj":
                    d = hj_delta(rng, shape, theta)
                else:
                    d = np.where(rng.random(shape) < 0.5, -kind, kind)
                v[:, idx] += d
                row.append(probe(wrap(v)).mean())
            print(f"| {label} | " + " | ".join(f"{a:.3f}" for a in row) + " |")
        # Every coordinate from bounce k on drawn afresh (the path's prefix kept).
        for k in range(1, BOUNCES_SHOWN + 1):
            v = states.copy()
            start = LIGHT_DIMS + BOUNCE_DIMS * (k - 1)
            v[:, start:] = rng.random((len(v), dims - start), dtype=np.float32)
            print(f"| bounce {k} on, drawn afresh | {probe(v).mean():.3f} | | | |")
        # The chain's own mutation of every coordinate, by the group that moved most.
        v = states.copy().astype(np.float64)
        d = hj_delta(rng, v.shape, theta)
        ok = probe(wrap(v + d))
        print(f"| every coordinate (the chain's mutation) | {ok.mean():.3f} | | | |\n")
        gl = groups(dims)
        shown = {i for _, idx in gl for i in idx}
        gl.append(("later bounces", [i for i in range(dims) if i not in shown]))
        biggest = np.stack([np.abs(d[:, idx]).max(axis=1) for _, idx in gl], axis=1).argmax(axis=1)
        print("| group that moved most | share of mutations | acceptance |\n|---|---|---|")
        for k, (label, _) in enumerate(gl):
            sel = biggest == k
            if sel.any():
                print(f"| {label} | {sel.mean():.3f} | {ok[sel].mean():.3f} |")
    finally:
        prepared.release()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scenes", nargs="*", default=["light-gap", "attic-slit", "closet-door"])
    ap.add_argument("--passes", type=int, default=30)
    ap.add_argument("--samples", type=int, default=200_000)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    for name in args.scenes:
        study(name, args.passes, args.samples, args.seed)


if __name__ == "__main__":
    main()

"""A vcm pass's counted work against its measured time, at N = pixels, pixels / 4 and pixels / 16
light subpaths (the cost model of vcm's light-path balance, methods/light_balance.py;
docs/vcm.md, "Light subpaths per pass"):

    python tools/vcm_pass_work.py SCENE.xml [-D res=64] [--rounds 6] [--passes 10]

The three sizes are rendered interleaved in one process (`--light-paths auto`, so that the
kernels count the work; the passes are called at fixed N). Prints, per N, the median time per
pass, the counts (light segments, camera vertices, connections, merge candidates, light
vertices) and the ratios of time and of counted work to N = pixels.
"""
import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scene")
    ap.add_argument("-D", dest="params", action="append", default=[], metavar="NAME=VALUE")
    ap.add_argument("--rounds", type=int, default=6)
    ap.add_argument("--passes", type=int, default=10)
    args = ap.parse_args()
    from photonmc.loop import Job
    from photonmc.methods.light_balance import LightPathBalance
    params = dict(p.split("=", 1) for p in args.params)
    job = Job(scene=args.scene, params=params, method="vcm", options={"light_paths": "auto"}, seed=0).prepare()
    m = job.method
    pixels = m.n_pixels
    ns = [pixels, pixels // 4, pixels // 16]
    for i in range(20):                               # compile, and warm the caches
        m.vcm_pass(i, i, ns[i % 3])
    rows = {n: [] for n in ns}
    it = 100
    for r in range(args.rounds):
        for n in (ns if r % 2 == 0 else ns[::-1]):
            t = time.perf_counter()
            counts = np.zeros(5)
            for _ in range(args.passes):
                counts += np.asarray(m.vcm_pass(it, it, n))
                it += 1
            dt = (time.perf_counter() - t) / args.passes
            _, segments, camera, connections, merges = counts / args.passes
            light = m.vertices_last if m.use_lt else 0.0
            rows[n].append((dt, segments, camera, connections, merges, m.vertices_last,
                            LightPathBalance.work(pixels, camera, connections, segments, light, merges)))
    job.release()
    base = np.median(np.asarray(rows[pixels]), axis=0)
    print(f"{args.scene}: {1000 * base[0]:.2f} ms per pass at N = {pixels}")
    print("| N | time ratio | work ratio | segments | camera vertices | connections | merge candidates | light vertices |")
    print("|---|---|---|---|---|---|---|---|")
    for n in ns:
        a = np.median(np.asarray(rows[n]), axis=0)
        print(f"| {n} | {a[0] / base[0]:.3f} | {a[6] / base[6]:.3f} | {a[1]:.0f} | {a[2]:.0f} | {a[3]:.0f} | "
              f"{a[4]:.0f} | {a[5]:.0f} |")


if __name__ == "__main__":
    main()

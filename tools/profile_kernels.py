"""Where a method's iteration time goes, per kernel (issue 15, item 1).

    python tools/profile_kernels.py [--methods pt,sppm,visibility,spatial-tf,vcm,mbe]
                                    [--scene cornell-box] [-D res=128] [--seconds 10]
                                    [--options '{"disc": "linear"}'] [--warm-up 300]

For each method: one warm-up iteration (compilation), or `--warm-up` iterations to time a
render's steady state (the radii shrunk), then iterations for `--seconds` with
Taichi's kernel profiler on. Prints, per method, each kernel's share of the wall time (its
offloaded tasks summed; Taichi names them <kernel>_c<id>_<n>_kernel_<task>_<kind>), and
what is left outside kernels (host work: numpy, field copies, Python). Kernel times are
device times of the launches, so on the CPU they include the threads' load imbalance.
"""
import argparse
import json
import re
import sys
import time
from collections import defaultdict
from pathlib import Path

import taichi as ti

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from photonmc import runtime  # noqa: E402
from photonmc.loop import Job  # noqa: E402

TASK_NAME = re.compile(r"^(?P<kernel>.+?)_c\d+_\d+(_kernel_\d+_\w+)?$")


def kernel_times() -> dict:
    """Seconds per Python kernel (its offloaded tasks summed) since the last clear."""
    profiler = ti.profiler.kernel_profiler.get_default_kernel_profiler()
    profiler.get_total_time()          # gathers the records into _statistical_results
    out = defaultdict(float)
    for name, stat in profiler._statistical_results.items():
        m = TASK_NAME.match(name)
        out[m.group("kernel") if m else name] += stat.total_time / 1000.0
    return dict(out)


def profile(method: str, scene: str, params: dict, seconds: float, seed: int, options=None, warm_up: int = 0):
    path = REPO / "scenes" / scene / "scene.xml" if not scene.endswith(".xml") else Path(scene)
    p = Job(scene=str(path), params=dict(params), method=method, options=dict(options or {}), seed=seed).prepare()
    try:
        m = p.method
        t0 = time.perf_counter()
        m.iterate()
        compile_s = time.perf_counter() - t0
        m.reset()
        for _ in range(warm_up):
            m.iterate()
        first = m.iterations
        ti.sync()
        ti.profiler.clear_kernel_profiler_info()
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < seconds:
            m.iterate()
        ti.sync()
        wall = time.perf_counter() - t0
        times = kernel_times()
        iterations = m.iterations - first
    finally:
        p.release()
    total = sum(times.values())
    print(f"\n### {method}: {iterations} iterations in {wall:.1f} s ({wall / iterations * 1000:.1f} ms each); "
          f"first iteration with compilation {compile_s:.1f} s\n")
    print("| kernel | ms per iteration | share of wall time |\n|---|---|---|")
    for name, t in sorted(times.items(), key=lambda kv: -kv[1]):
        if t / wall >= 0.005:
            print(f"| `{name}` | {t / iterations * 1000:.2f} | {t / wall:.1%} |")
    small = sum(t for t in times.values() if t / wall < 0.005)
    print(f"| (other kernels, each < 0.5 %) | {small / iterations * 1000:.2f} | {small / wall:.1%} |")
    print(f"| outside kernels (host) | {(wall - total) / iterations * 1000:.2f} | {(wall - total) / wall:.1%} |")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--methods", default="pt,sppm,visibility,spatial-tf,vcm,mbe")
    ap.add_argument("--scene", default="cornell-box")
    ap.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE")
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--options", default="{}", help="the methods' options, as JSON")
    ap.add_argument("--warm-up", type=int, default=0, help="iterations before the timed ones")
    args = ap.parse_args()
    params = dict(d.split("=", 1) for d in args.defines)
    runtime.init("cpu", kernel_profiler=True)
    print(f"scene {args.scene} {params}, options {args.options}, {args.seconds} s per method after "
          f"{max(args.warm_up, 1)} warm-up iteration(s), "
          f"Taichi kernel profiler on")
    for method in args.methods.split(","):
        profile(method, args.scene, params, args.seconds, args.seed, json.loads(args.options), args.warm_up)


if __name__ == "__main__":
    main()

"""What a kernel launch costs on this machine, and where an iteration's launches go.

    python tools/launch_costs.py [--methods vcm,mbe] [--scene caustic] [-D res=64] [--iterations 300]

1. A loop of cheap items (a square root and a store each) run as a parallel loop and as a
   serial one (`ti.loop_config(serialize=True)`), at several lengths: the difference at 16
   items is the cost of handing a loop to Taichi's CPU thread pool (runtime.serial_loop).
2. For each method: every kernel launched during `--iterations` iterations after a warm-up,
   with its launches per iteration and its wall time from Python (the launch included,
   which Taichi's kernel profiler, tools/profile_kernels.py, does not see), and the rest of
   the iteration (Python between launches).
"""
import argparse
import sys
import time
from collections import defaultdict
from pathlib import Path

import taichi as ti

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from photonmc import runtime  # noqa: E402
from photonmc.loop import Job  # noqa: E402


def per_call_us(fn, n: int) -> float:
    fn()
    t0 = time.perf_counter()
    for _ in range(n):
        fn()
    return (time.perf_counter() - t0) / n * 1e6


def loop_costs():
    data = ti.field(ti.f32, 1 << 18)

    @ti.kernel
    def fill(n: ti.i32, serial: ti.template()):
        ti.loop_config(serialize=serial)
        for i in range(n):
            data[i] = ti.sqrt(ti.cast(i, ti.f32))

    print("| items | parallel loop [us] | serial loop [us] |\n|---|---|---|")
    for n in (16, 4096, 16384, 65536, 262144):
        par = per_call_us(lambda: fill(n, False), 500)
        ser = per_call_us(lambda: fill(n, True), 500)
        print(f"| {n} | {par:.0f} | {ser:.0f} |")


def iteration_launches(method: str, scene: str, params: dict, iterations: int):
    from taichi.lang import kernel_impl
    path = REPO / "scenes" / scene / "scene.xml" if not scene.endswith(".xml") else Path(scene)
    p = Job(scene=str(path), params=dict(params), method=method, options={}, seed=0).prepare()
    times = defaultdict(lambda: [0, 0.0])
    original = kernel_impl.Kernel.__call__

    def timed(self, *args, **kwargs):
        t = time.perf_counter()
        out = original(self, *args, **kwargs)
        entry = times[self.func.__qualname__]
        entry[0] += 1
        entry[1] += time.perf_counter() - t
        return out

    try:
        m = p.method
        for _ in range(20):
            m.iterate()
        kernel_impl.Kernel.__call__ = timed
        t0 = time.perf_counter()
        for _ in range(iterations):
            m.iterate()
        wall = time.perf_counter() - t0
    finally:
        kernel_impl.Kernel.__call__ = original
        p.release()
    print(f"\n### {method}: {wall / iterations * 1000:.2f} ms per iteration\n")
    print("| kernel | launches per iteration | ms per iteration |\n|---|---|---|")
    total = 0.0
    for name, (count, seconds) in sorted(times.items(), key=lambda kv: -kv[1][1]):
        print(f"| `{name}` | {count / iterations:.1f} | {seconds / iterations * 1000:.3f} |")
        total += seconds
    print(f"| (Python between launches) | | {(wall - total) / iterations * 1000:.3f} |")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--methods", default="vcm,mbe")
    ap.add_argument("--scene", default="caustic")
    ap.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE")
    ap.add_argument("--iterations", type=int, default=300)
    args = ap.parse_args()
    params = dict(d.split("=", 1) for d in args.defines) or {"res": "64"}
    runtime.init("cpu")
    loop_costs()
    for method in args.methods.split(","):
        iteration_launches(method, args.scene, params, args.iterations)


if __name__ == "__main__":
    main()

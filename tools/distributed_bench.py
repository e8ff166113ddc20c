"""Scaling of `--workers` on this machine, and the size and cost of render states.

    python tools/distributed_bench.py [--seconds 20] [--methods pt,sppm,vcm] [--res 256]

For each method: iterations per second after warm-up (every worker has reported once, so
compilation is excluded) for one process (all cores), 1 Ray worker (all cores) and W Ray
workers (cores / W threads each); then the render state's size, the time to capture and
save it, and the time to load it. Results go in docs/resume.md.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from photonmc import distributed, state  # noqa: E402
from photonmc.loop import Budget, Job  # noqa: E402

CORNELL = str(REPO / "scenes" / "cornell-box" / "scene.xml")


def single_rate(job: Job, seconds: float):
    p = job.prepare()
    p.method.iterate()                      # compiles
    t0, n0 = time.perf_counter(), p.method.iterations
    while time.perf_counter() - t0 < seconds:
        p.method.iterate()
    rate = (p.method.iterations - n0) / (time.perf_counter() - t0)
    t = time.perf_counter()
    s = state.state_of(p.method, job.identity(), p.scene, 0.0)
    with tempfile.TemporaryDirectory() as d:
        path = state.save(Path(d) / "x.state", [s])
        save_s = time.perf_counter() - t
        size = path.stat().st_size
        t = time.perf_counter()
        state.load(path)
        load_s = time.perf_counter() - t
    p.release()
    return rate, size, save_s, load_s


def workers_rate(job: Job, workers: int, seconds: float) -> float:
    job.workers = workers
    first = None
    for progress in distributed.render(job, Budget(time=seconds + 60)):
        if first is None and all(w.iterations > 0 for w in progress.workers):
            first = (time.perf_counter(), progress.iterations)
        if first is not None and time.perf_counter() - first[0] >= seconds:
            rate = (progress.iterations - first[1]) / (time.perf_counter() - first[0])
            break
    return rate


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--methods", default="pt,sppm,vcm")
    ap.add_argument("--res", default="256")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 2)
    args = ap.parse_args()
    import ray
    ray.init(num_cpus=os.cpu_count(), include_dashboard=False, log_to_driver=False, configure_logging=False)
    cores = os.cpu_count()
    print(f"{cores} cores, cornell-box {args.res}x{args.res}, {args.seconds:.0f} s per measurement after warm-up")
    print("| method | 1 process it/s | 1 Ray worker it/s | "
          f"{args.workers} Ray workers it/s | state size | capture+save | load |")
    print("|---|---|---|---|---|---|---|")
    for method in args.methods.split(","):
        job = Job(scene=CORNELL, params={"res": args.res}, method=method, seed=0)
        rate1, size, save_s, load_s = single_rate(job, args.seconds)
        r_one = workers_rate(Job(scene=CORNELL, params={"res": args.res}, method=method, threads=cores),
                             1, args.seconds)
        r_many = workers_rate(Job(scene=CORNELL, params={"res": args.res}, method=method), args.workers, args.seconds)
        print(f"| {method} | {rate1:.2f} | {r_one:.2f} | {r_many:.2f} | {size / 2**20:.1f} MiB | "
              f"{save_s * 1e3:.0f} ms | {load_s * 1e3:.0f} ms |", flush=True)
    ray.shutdown()


if __name__ == "__main__":
    main()

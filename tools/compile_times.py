"""Where a method's first image waits: compile time per kernel, with a cold kernel cache (issue 15, item 3).

    python tools/compile_times.py [--methods pt,sppm,visibility,spatial-tf,vcm,mbe]
                                  [--scene cornell-box] [-D res=64] [--init NAME=VALUE ...]

Each method runs in its own process with an empty Taichi offline cache, so every figure is
what a new user's first `photonmc render` pays. The first launch of each kernel
specialisation (Python -> Taichi IR -> LLVM -> machine code, then one run) is timed; then
warm iterations for `--run-seconds` give the time per iteration that the compiler settings
buy. `--init` passes extra ti.init settings (e.g. `--init opt_level=0`) to compare them.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def child(method: str, scene: str, params: dict, init: dict, run_seconds: float) -> dict:
    """Runs in the child process: one method, cold cache, per-kernel first-launch seconds."""
    sys.path.insert(0, str(REPO))
    t_start = time.perf_counter()
    import taichi as ti
    import taichi.lang.kernel_impl as kernel_impl

    from photonmc.loop import Job
    t_import = time.perf_counter() - t_start

    if init:
        original_init = ti.init

        def init_with_overrides(**kwargs):
            return original_init(**{**kwargs, **init})
        ti.init = init_with_overrides

    first_launch = defaultdict(float)
    original_call = kernel_impl.Kernel.__call__

    def timed_call(self, *args, **kwargs):
        # A kernel compiles once per specialisation (template arguments: fields, objects), at
        # its first launch; count every launch that added one.
        before = len(self.compiled_kernels)
        t = time.perf_counter()
        out = original_call(self, *args, **kwargs)
        if len(self.compiled_kernels) > before:
            ti.sync()
            first_launch[self.func.__qualname__] += time.perf_counter() - t
        return out
    kernel_impl.Kernel.__call__ = timed_call

    path = REPO / "scenes" / scene / "scene.xml" if not scene.endswith(".xml") else Path(scene)
    t = time.perf_counter()
    p = Job(scene=str(path), params=dict(params), method=method, options={}, seed=0).prepare()
    t_prepare = time.perf_counter() - t
    try:
        t = time.perf_counter()
        p.method.iterate()
        ti.sync()
        t_first = time.perf_counter() - t
        t_to_first_image = time.perf_counter() - t_start
        m = p.method
        m.reset()
        t = time.perf_counter()
        while True:          # warm iterations: what the compiler settings cost at run time
            m.iterate()
            ti.sync()
            if time.perf_counter() - t >= run_seconds:
                break
        t_iteration = (time.perf_counter() - t) / m.iterations
    finally:
        p.release()
    return {"method": method, "import_s": t_import, "prepare_s": t_prepare, "first_iteration_s": t_first,
            "iteration_s": t_iteration, "to_first_image_s": t_to_first_image,
            "kernels": dict(first_launch)}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--methods", default="pt,sppm,visibility,spatial-tf,vcm,mbe")
    ap.add_argument("--scene", default="cornell-box")
    ap.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE")
    ap.add_argument("--init", action="append", default=[], metavar="NAME=VALUE",
                    help="extra ti.init setting (a Python literal value)")
    ap.add_argument("--run-seconds", type=float, default=5.0, help="warm iterations timed after the first")
    ap.add_argument("--top", type=int, default=8, help="kernels listed per method")
    ap.add_argument("--json", help="write the figures here")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args()
    params = dict(d.split("=", 1) for d in args.defines)
    init = {}
    for item in args.init:
        name, value = item.split("=", 1)
        init[name] = json.loads(value.lower() if value.lower() in ("true", "false") else value)
    if args.child:
        print(json.dumps(child(args.child, args.scene, params, init, args.run_seconds)))
        return
    results = []
    for method in args.methods.split(","):
        with tempfile.TemporaryDirectory() as cache:
            env = {**os.environ, "TI_OFFLINE_CACHE_FILE_PATH": cache}
            cmd = [sys.executable, __file__, "--child", method, "--scene", args.scene,
                   *sum((["-D", d] for d in args.defines), []), *sum((["--init", i] for i in args.init), []), "--run-seconds", str(args.run_seconds)]
            t = time.perf_counter()
            out = subprocess.run(cmd, env=env, capture_output=True, text=True)
            wall = time.perf_counter() - t
        if out.returncode != 0:
            print(out.stderr[-3000:], file=sys.stderr)
            raise SystemExit(f"{method} failed")
        r = json.loads(out.stdout.strip().splitlines()[-1])
        r["process_wall_s"] = wall
        results.append(r)
        compiled = sum(r["kernels"].values())
        print(f"\n### {method}: first image {r['to_first_image_s']:.1f} s after the process started "
              f"(import {r['import_s']:.1f}, scene {r['prepare_s']:.1f}, first iteration {r['first_iteration_s']:.1f}; "
              f"then {r['iteration_s'] * 1000:.1f} ms per iteration)\n")
        print("| kernel | first launch, s |\n|---|---|")
        for name, s in sorted(r["kernels"].items(), key=lambda kv: -kv[1])[:args.top]:
            print(f"| `{name}` | {s:.1f} |")
        print(f"| all {len(r['kernels'])} kernels | {compiled:.1f} |")
    print("\n| method | first image, s | kernels' first launches, s | ms per iteration |\n|---|---|---|---|")
    for r in results:
        print(f"| {r['method']} | {r['to_first_image_s']:.1f} | {sum(r['kernels'].values()):.1f} | "
              f"{r['iteration_s'] * 1000:.1f} |")
    if args.json:
        Path(args.json).write_text(json.dumps({"init": init, "scene": args.scene, "results": results}, indent=1))


if __name__ == "__main__":
    main()

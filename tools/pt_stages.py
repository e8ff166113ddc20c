"""Where pt's time goes, by stage (issue 15, items 1-2): the rays one pt iteration traces,
recorded (kernels/raycast.RayLog) and timed alone through photonmc's BVH and through Embree
(embreex, if installed, triangle scenes only) on the same rays, against pt's whole iteration;
and Mitsuba 3's path tracer (llvm and scalar, if installed) on the same scene file.

    python tools/pt_stages.py [--scene mitsuba-style] [--threads N] [--json out.json]

embreex traces on one thread; photonmc's figures are given for --threads (default: every
core) and per core, so the comparison is explicit about it.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="mitsuba-style")
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--iterations", type=int, default=8, help="pt iterations (1 spp each) per timing")
    ap.add_argument("--no-mitsuba", action="store_true")
    ap.add_argument("--json")
    args = ap.parse_args()

    import taichi as ti
    from bench import best_of
    from photonmc import runtime
    from photonmc.kernels.raycast import RayCaster, RayLog
    from photonmc.loop import Job
    runtime.init(threads=args.threads)
    threads = args.threads or ti.lang.impl.current_cfg().cpu_max_num_threads
    path = ROOT / "scenes" / args.scene / "scene.xml" if not args.scene.endswith(".xml") else Path(args.scene)

    timed = Job(scene=str(path), params={}, method="pt", options={}, seed=0, threads=args.threads).prepare()
    logged = Job(scene=str(path), params={}, method="pt", options={}, seed=0, threads=args.threads).prepare()
    scene = timed.scene
    w, h = scene.camera.width, scene.camera.height
    pixels = w * h
    m = timed.method
    m.iterate()                                          # compile
    ti.sync()

    def pt_iterations():
        for _ in range(args.iterations):
            m.iterate()
        ti.sync()
    pt_s = best_of(pt_iterations) / args.iterations       # one sample per pixel

    log = RayLog(capacity=pixels * 64)
    logged.method.dscene.ray_log = log                    # before its first kernel compiles
    logged.method.iterate()
    ti.sync()
    o, d, tmax, any_hit = log.rays()
    if int(log.count[None]) > log.capacity:
        raise SystemExit("the ray log overflowed; raise its capacity")
    caster = RayCaster(timed.method.dscene)
    stages = {}
    for name, sel in (("closest", ~any_hit), ("shadow", any_hit)):
        oo, dd, tt = o[sel], d[sel], tmax[sel]
        caster.cast(oo[:1000], dd[:1000], any_hit=(name == "shadow"), tmax=tt[:1000])     # compile
        secs = best_of(lambda: caster.cast(oo, dd, any_hit=(name == "shadow"), tmax=tt))
        stages[name] = {"rays_per_sample": len(oo) / pixels, "photonmc_s_per_spp": secs}
        if len(scene.sphere_radius) == 0:
            try:
                from embreex import rtcore_scene as rtcs
                from embreex.mesh_construction import TriangleMesh
                es = rtcs.EmbreeScene()
                TriangleMesh(es, np.ascontiguousarray(scene.tri_vertices, np.float32))
                tt_e = np.where(np.isinf(tt), 1e30, tt).astype(np.float32)
                query = "OCCLUDED" if name == "shadow" else "INTERSECT"
                es.run(oo[:1000], dd[:1000], dists=tt_e[:1000].copy(), query=query)
                stages[name]["embree_1_thread_s_per_spp"] = best_of(
                    lambda: es.run(oo, dd, dists=tt_e.copy(), query=query))
            except ImportError:
                pass
    trace_s = sum(s["photonmc_s_per_spp"] for s in stages.values())
    result = {"scene": str(path), "resolution": [w, h], "threads": threads,
              "pt_ns_per_sample": 1e9 * pt_s / pixels,
              "trace_ns_per_sample": 1e9 * trace_s / pixels,
              "rest_ns_per_sample": 1e9 * (pt_s - trace_s) / pixels,
              "stages": stages}
    if all("embree_1_thread_s_per_spp" in s for s in stages.values()):
        result["embree_1_thread_trace_ns_per_sample"] = 1e9 * sum(
            s["embree_1_thread_s_per_spp"] for s in stages.values()) / pixels
    if not args.no_mitsuba:
        from bench import mitsuba_samples_per_s
        for k, v in mitsuba_samples_per_s(path, pixels).items():
            result[k.replace("_samples_per_s", "_ns_per_sample")] = 1e9 / v if isinstance(v, float) else v

    print(f"pt on {path.name} at {w}x{h}, {threads} threads: {result['pt_ns_per_sample']:.0f} ns per sample "
          f"({1e3 / result['pt_ns_per_sample']:.2f} M samples/s)")
    for name, s in stages.items():
        line = (f"  {name} rays: {s['rays_per_sample']:.2f} per sample, photonmc "
                f"{1e9 * s['photonmc_s_per_spp'] / pixels:.0f} ns per sample")
        if "embree_1_thread_s_per_spp" in s:
            line += f", Embree (1 thread) {1e9 * s['embree_1_thread_s_per_spp'] / pixels:.0f} ns"
        print(line)
    print(f"  tracing {result['trace_ns_per_sample']:.0f} ns ({100 * trace_s / pt_s:.0f} %), the rest "
          f"(camera rays, sampling, shading, RNG, film) {result['rest_ns_per_sample']:.0f} ns")
    for k in ("mitsuba_llvm_ad_rgb_ns_per_sample", "mitsuba_scalar_rgb_ns_per_sample"):
        if isinstance(result.get(k), float):
            print(f"  {k.replace('_ns_per_sample', '')}: {result[k]:.0f} ns per sample")
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1))
    timed.release()
    logged.release()


if __name__ == "__main__":
    main()

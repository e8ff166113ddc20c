"""Throughput benchmarks, measured side by side with the peers in one run.

    python tools/bench.py [--rays 2000000] [--pt-iterations 64] [--json out.json]

1. BVH: incoherent rays that all hit a subdivided icosphere (81,920 triangles): photonmc's
   Taichi BVH against Embree (through `embreex`, if installed) on the same rays. embreex
   traces on one thread, so photonmc is measured on every core and on one (a second
   process): the per-core ratio is the one that compares the traversal code.
2. pt: samples/s on the bundled Cornell box at 256x256 against Mitsuba 3's `path` integrator
   (if installed) on the same scene file and max_depth.
3. sppm: photon paths/s and iteration time on the Cornell box at 512x512, one photon path
   per pixel per iteration (SmallVCM's progressive photon mapping: about 0.75 M paths/s on
   2 cores on a comparable Cornell box, per ../shared/peers.md).
4. vcm: iteration time on the same box at 512x512, one light and one camera subpath per pixel
   (SmallVCM's vcm: 0.73 s on 2 cores).
5. compile: every method's first image with a cold kernel cache (tools/compile_times.py,
   each method in a fresh process; `--no-compile` skips it).
Items 1-4 exclude compile time (a warm-up call first); each figure is the best of 3 runs.
The CPU's model and vector extensions head the output (the ratios against Embree and
Mitsuba's llvm variant depend on the vector width), and the ratios close it.
Needs the `tools` extra for the peers: pip install -e ".[tools]" embreex
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def best_of(fn, runs=3):
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def icosphere_rays(n, seed=0):
    import trimesh
    mesh = trimesh.creation.icosphere(subdivisions=6, radius=1.0)
    rng = np.random.default_rng(seed)
    # Origins on a sphere of radius 3, aimed at random points of the mesh: all hit, incoherent.
    o = rng.normal(size=(n, 3))
    o = 3 * o / np.linalg.norm(o, axis=1, keepdims=True)
    target, _ = trimesh.sample.sample_surface(mesh, n, seed=seed)
    d = target - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return mesh, o.astype(np.float32), d.astype(np.float32)


def bench_bvh(n_rays):
    from photonmc.kernels.device_scene import DeviceScene
    from photonmc.kernels.raycast import RayCaster
    from photonmc.scene.bvh import build_bvh
    from photonmc.scene.scene import Bsdf, Camera, Scene

    mesh, o, d = icosphere_rays(n_rays)
    tri = mesh.vertices[mesh.faces]
    n = len(tri)
    t = time.perf_counter()
    build_bvh(tri)
    build_s = time.perf_counter() - t
    scene = Scene("<icosphere>", Camera(np.eye(4), (0.5, 0.5), 4, 4), -1, [Bsdf(0, np.full(3, 0.5))],
                  np.array([[0, -1]], np.int32), np.ones((1, 3)), tri, np.repeat(mesh.face_normals[:, None], 3, 1),
                  np.zeros(n, np.int32), np.r_[0, -np.ones(n - 1)].astype(np.int32), np.zeros((0, 3)),
                  np.zeros(0), np.zeros(0, bool), np.zeros(0, np.int32), np.zeros(0, np.int32))
    rc = RayCaster(DeviceScene(scene))
    rc.cast(o[:1000], d[:1000])                       # compile
    t_hit, kind, _ = rc.cast(o, d)
    result = {"triangles": n, "rays": n_rays, "bvh_build_s": build_s,
              "hit_fraction": float((kind >= 0).mean()),
              "photonmc_rays_per_s": n_rays / best_of(lambda: rc.cast(o, d))}
    try:
        from embreex import rtcore_scene as rtcs
        from embreex.mesh_construction import TriangleMesh
        es = rtcs.EmbreeScene()
        TriangleMesh(es, tri.astype(np.float32))
        es.run(o[:1000], d[:1000])
        result["embree_rays_per_s"] = n_rays / best_of(lambda: es.run(o, d, output=1))
        e_out = es.run(o, d, output=1)
        ok = e_out["geomID"] >= 0
        result["embree_hit_fraction"] = float(ok.mean())
        result["embree_agreement_t"] = float(np.median(np.abs(e_out["tfar"][ok] - t_hit[ok])))
    except ImportError:
        result["embree_rays_per_s"] = None
    return result


def bench_pt(iterations):
    from photonmc import load_scene
    from photonmc.loop import Budget, default_scene_path, prepare, run

    path = default_scene_path()
    scene = load_scene(path)
    p = prepare(scene, method="pt")
    r = run(p, Budget(iterations=iterations), quiet=True)
    w, h = scene.camera.width, scene.camera.height
    steady = r.stats["wall_seconds"]["steady_per_iteration"]
    result = {"scene": str(path.relative_to(ROOT)) if ROOT in path.parents else str(path), "resolution": [w, h],
              "max_depth": scene.max_depth, "photonmc_samples_per_s": w * h / steady}
    result.update(mitsuba_samples_per_s(path, w * h))
    return result


def mitsuba_samples_per_s(path, pixels: int) -> dict:
    """Mitsuba 3's `path` integrator on the same scene file: samples/s per variant."""
    result = {}
    try:
        if "DRJIT_LIBLLVM_PATH" not in os.environ and Path("/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1").exists():
            os.environ["DRJIT_LIBLLVM_PATH"] = "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1"
        import mitsuba as mi
        for variant in ("llvm_ad_rgb", "scalar_rgb"):
            try:
                mi.set_variant(variant)
                ms = mi.load_file(str(path))
                np.array(mi.render(ms, spp=4))            # compile / warm up
                spp = 64
                secs = best_of(lambda ms=ms, spp=spp: np.array(mi.render(ms, spp=spp, seed=1)))   # forces lazy llvm evaluation
                result[f"mitsuba_{variant}_samples_per_s"] = pixels * spp / secs
            except Exception as e:   # noqa: BLE001 - a missing variant is reported, not fatal
                result[f"mitsuba_{variant}_samples_per_s"] = f"unavailable: {e}"[:120]
    except ImportError:
        result["mitsuba"] = "not installed"
    return result


def _iteration_times(method, iterations, res):
    """Median iteration time of `method` on the Cornell box at res x res (compile excluded),
    with the method's final statistics."""
    from photonmc import load_scene
    from photonmc.loop import default_scene_path, prepare

    scene = load_scene(default_scene_path(), {"res": res})
    p = prepare(scene, method=method)
    m = p.method
    m.warm_up()                                           # compile
    m.reset()
    times = []
    for _ in range(iterations):
        t = time.perf_counter()
        m.iterate()
        times.append(time.perf_counter() - t)
    stats = m.stats()
    p.release()
    return float(np.median(times)), stats


def bench_sppm(iterations, res=512):
    """Photon paths/s and iteration time of sppm on the Cornell box at res x res, one photon
    path per pixel per iteration (SmallVCM's setting); the iteration includes the camera pass."""
    per_it, stats = _iteration_times("sppm", iterations, res)
    photons = stats["photons_per_iteration"]
    return {"resolution": [res, res], "photons_per_iteration": photons,
            "iteration_s_median": per_it, "photon_paths_per_s_incl_camera_pass": photons / per_it,
            "fraction_of_photon_paths_depositing": stats["fraction_of_photon_paths_depositing"],
            "smallvcm_ppm_reference_photon_paths_per_s": 0.75e6}


def bench_vcm(iterations, res=512):
    """Iteration time of vcm on the Cornell box at res x res: one light and one camera subpath
    per pixel (SmallVCM's vcm on its Cornell box, 2 cores: 0.73 s per iteration, issue 12)."""
    per_it, stats = _iteration_times("vcm", iterations, res)
    return {"resolution": [res, res], "light_paths_per_iteration": stats["light_paths_per_iteration"],
            "iteration_s_median": per_it, "light_vertices_per_iteration": stats["light_vertices_last_iteration"],
            "smallvcm_vcm_reference_iteration_s": 0.73}


def cpu_info() -> dict:
    """Model name and the vector extensions that set how wide Embree's and Mitsuba's SIMD is."""
    model, flags = "unknown", set()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "model name" and model == "unknown":
                model = value.strip()
            elif key.strip() == "flags" and not flags:
                flags = set(value.split())
    except OSError:
        pass
    vector = [f for f in ("sse4_2", "avx", "avx2", "fma", "avx512f", "avx512bw", "avx512vl") if f in flags]
    width = 512 if "avx512f" in flags else 256 if "avx2" in flags or "avx" in flags else 128 if flags else None
    return {"model": model, "cores": os.cpu_count(), "vector_extensions": vector, "vector_width_bits": width}


def bench_compile(scene="cornell-box", res=128) -> dict:
    """First image per method with a cold kernel cache, from tools/compile_times.py."""
    import tempfile
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "compile.json"
        subprocess.run([sys.executable, str(ROOT / "tools" / "compile_times.py"), "--scene", scene, "-D", f"res={res}",
                        "--run-seconds", "0", "--json", str(out)], check=True, capture_output=True)
        results = json.loads(out.read_text())["results"]
    return {r["method"]: {"first_image_s": r["to_first_image_s"], "kernels_first_launch_s": sum(r["kernels"].values())}
            for r in results}


def ratios(res: dict) -> dict:
    """photonmc against each peer that ran (above 1: photonmc is faster)."""
    out = {}
    b, p = res["bvh"], res["pt"]
    if isinstance(b.get("embree_rays_per_s"), float):
        out["bvh_rays_all_cores_vs_embree_1_thread"] = b["photonmc_rays_per_s"] / b["embree_rays_per_s"]
        if b.get("photonmc_1_thread_rays_per_s"):
            out["bvh_rays_per_core_vs_embree"] = b["photonmc_1_thread_rays_per_s"] / b["embree_rays_per_s"]
    for variant in ("llvm_ad_rgb", "scalar_rgb"):
        peer = p.get(f"mitsuba_{variant}_samples_per_s")
        if isinstance(peer, float):
            out[f"pt_samples_vs_mitsuba_{variant}"] = p["photonmc_samples_per_s"] / peer
    out["sppm_photon_paths_vs_smallvcm"] = (res["sppm"]["photon_paths_per_s_incl_camera_pass"]
                                            / res["sppm"]["smallvcm_ppm_reference_photon_paths_per_s"])
    out["vcm_iteration_vs_smallvcm"] = res["vcm"]["smallvcm_vcm_reference_iteration_s"] / res["vcm"]["iteration_s_median"]
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rays", type=int, default=2_000_000)
    ap.add_argument("--pt-iterations", type=int, default=64)
    ap.add_argument("--sppm-iterations", type=int, default=10)
    ap.add_argument("--vcm-iterations", type=int, default=10)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--no-compile", action="store_true", help="skip the cold-cache first-image figures")
    ap.add_argument("--bvh-only", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--json")
    args = ap.parse_args()
    from photonmc import runtime
    runtime.init("cpu", args.threads)
    if args.bvh_only:
        print(json.dumps(bench_bvh(args.rays)))
        return
    res = {"cpu": cpu_info(), "cpu_threads": args.threads or os.cpu_count(), "bvh": bench_bvh(args.rays),
           "pt": bench_pt(args.pt_iterations), "sppm": bench_sppm(args.sppm_iterations),
           "vcm": bench_vcm(args.vcm_iterations)}
    if args.threads != 1:      # the per-core figure, against embreex's one thread
        one = subprocess.run([sys.executable, __file__, "--bvh-only", "--threads", "1", "--rays", str(args.rays)],
                             check=True, capture_output=True, text=True)
        res["bvh"]["photonmc_1_thread_rays_per_s"] = json.loads(one.stdout.strip().splitlines()[-1])["photonmc_rays_per_s"]
    res["bvh"]["embree_threads"] = 1
    if not args.no_compile:
        res["compile"] = bench_compile()
    res["ratios"] = ratios(res)
    text = json.dumps(res, indent=2)
    print(text)
    if args.json:
        Path(args.json).write_text(text + "\n")


if __name__ == "__main__":
    main()

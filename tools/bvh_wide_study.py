"""A 4-wide BVH, measured against the binary one and Embree on the same rays (issue 15,
item 2: "a wide BVH, node tests written so LLVM vectorises them"). A study, not the renderer's
traversal: the wide tree is collapsed from the binary SAH tree (scene/bvh.py), each node holds
its four children's boxes lane by lane (x of all four, then y, ...) so that the four slab tests
are the same scalar code four times over adjacent floats, which LLVM's SLP vectoriser may pack.

    python tools/bvh_wide_study.py [--threads N] [--rays 2000000] [--scene mesh-room]

Rays: the benchmark's incoherent icosphere rays (tools/bench.py), and the closest-hit rays one
pt iteration traces on --scene (tools/pt_stages.py's log). Every figure: best of 3, compile
excluded; the hits are checked against the binary tree's.
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

WIDTH = 4


def collapse(bvh):
    """Binary tree -> 4-wide: each wide node takes its binary node's children and opens the
    largest inner child until it has four. Returns (lo, hi: (N, 3, 4) f32, child: (N, 4) i32,
    count: (N, 4) i32), child being a wide node (count 0), a first triangle (count > 0), or
    nothing (count -1, an empty box)."""
    def area(i):
        d = np.maximum(bvh.bmax[i] - bvh.bmin[i], 0.0)
        return d[0] * d[1] + d[1] * d[2] + d[2] * d[0]

    los, his, childs, counts = [], [], [], []

    def build(root):
        me = len(los)
        los.append(None), his.append(None), childs.append(None), counts.append(None)
        kids = [root + 1, int(bvh.right_or_first[root])] if bvh.count[root] == 0 else [root]
        while len(kids) < WIDTH:
            inner = [k for k in kids if bvh.count[k] == 0]
            if not inner:
                break
            k = max(inner, key=area)
            kids.remove(k)
            kids += [k + 1, int(bvh.right_or_first[k])]
        lo = np.full((3, WIDTH), np.inf, np.float32)
        hi = np.full((3, WIDTH), -np.inf, np.float32)
        child = np.zeros(WIDTH, np.int32)
        count = np.full(WIDTH, -1, np.int32)
        for lane, k in enumerate(kids):
            lo[:, lane], hi[:, lane] = bvh.bmin[k], bvh.bmax[k]
            if bvh.count[k] > 0:
                child[lane], count[lane] = bvh.right_or_first[k], bvh.count[k]
            else:
                child[lane], count[lane] = build(k), 0
        los[me], his[me], childs[me], counts[me] = lo, hi, child, count
        return me

    build(0)
    return np.stack(los), np.stack(his), np.stack(childs), np.stack(counts)


def make_caster(dscene, wide):
    import taichi as ti

    from photonmc.kernels.device_scene import Hit, MISS, TRIANGLE
    from photonmc.kernels.fields import FieldGroup

    lo, hi, child, count = wide
    n = len(child)
    f = FieldGroup("wide-bvh")
    # one node: 3 x 4 lower bounds, 3 x 4 upper bounds, 4 children, 4 counts (lane-contiguous)
    w_lo = f.vector(WIDTH, ti.f32, (n, 3), lo)
    w_hi = f.vector(WIDTH, ti.f32, (n, 3), hi)
    w_child = f.vector(WIDTH, ti.i32, n, child)
    w_count = f.vector(WIDTH, ti.i32, n, count)
    f.finalize()

    @ti.func
    def trace(o, d, tmax: ti.f32):
        hit = Hit(t=tmax, kind=MISS, prim=-1, b1=0.0, b2=0.0)
        dd = d
        for k in ti.static(range(3)):
            if ti.abs(dd[k]) < 1e-30:
                dd[k] = 1e-30
        inv_d = 1.0 / dd
        stack = ti.Vector([0] * 48, ti.i32)
        stack_t = ti.Vector([0.0] * 48, ti.f32)
        sp = 0
        node = 0
        while node >= 0:
            # four slab tests, lane by lane over adjacent floats
            t_enter = ti.Vector([0.0] * WIDTH)
            t_exit = ti.Vector([hit.t] * WIDTH)
            for a in ti.static(range(3)):
                t0 = (w_lo[node, a] - o[a]) * inv_d[a]
                t1 = (w_hi[node, a] - o[a]) * inv_d[a]
                t_enter = ti.max(t_enter, ti.min(t0, t1))
                t_exit = ti.min(t_exit, ti.max(t0, t1))
            kids = w_child[node]
            counts = w_count[node]
            node = -1
            key = ti.Vector([ti.math.inf] * WIDTH)
            for lane in ti.static(range(WIDTH)):
                if counts[lane] >= 0 and t_enter[lane] <= t_exit[lane]:
                    if counts[lane] > 0:
                        first = kids[lane]
                        for j in range(first, first + counts[lane]):
                            t, b1, b2 = dscene_triangle(j, o, d, hit.t)
                            if t < hit.t:
                                hit.t, hit.kind, hit.prim, hit.b1, hit.b2 = t, TRIANGLE, j, b1, b2
                    else:
                        key[lane] = t_enter[lane]
            # nearest inner child next, the others pushed far to near (a sorting network)
            for a, b in ti.static(((0, 1), (2, 3), (0, 2), (1, 3), (1, 2))):
                if key[b] < key[a]:
                    key[a], key[b] = key[b], key[a]
                    kids[a], kids[b] = kids[b], kids[a]
            for lane in ti.static(range(WIDTH - 1, 0, -1)):
                if key[lane] < hit.t:
                    stack[sp] = kids[lane]
                    stack_t[sp] = key[lane]
                    sp += 1
            if key[0] < hit.t:
                node = kids[0]
            while node < 0 and sp > 0:
                sp -= 1
                if stack_t[sp] < hit.t:
                    node = stack[sp]
        return hit

    @ti.func
    def dscene_triangle(i, o, d, t_max: ti.f32):
        e1 = dscene.tri_e1[i]
        e2 = dscene.tri_e2[i]
        pv = d.cross(e2)
        det = e1.dot(pv)
        t_out, b1_out, b2_out = t_max, 0.0, 0.0
        if det != 0.0:
            inv_det = 1.0 / det
            tv = o - dscene.tri_v0[i]
            b1 = tv.dot(pv) * inv_det
            if b1 >= 0.0 and b1 <= 1.0:
                qv = tv.cross(e1)
                b2 = d.dot(qv) * inv_det
                if b2 >= 0.0 and b1 + b2 <= 1.0:
                    t = e2.dot(qv) * inv_det
                    if t > 0.0 and t < t_max:
                        t_out, b1_out, b2_out = t, b1, b2
        return t_out, b1_out, b2_out

    @ti.kernel
    def cast(o: ti.types.ndarray(dtype=ti.math.vec3, ndim=1), d: ti.types.ndarray(dtype=ti.math.vec3, ndim=1),
             tmax: ti.types.ndarray(dtype=ti.f32, ndim=1), t_out: ti.types.ndarray(dtype=ti.f32, ndim=1),
             prim_out: ti.types.ndarray(dtype=ti.i32, ndim=1)):
        for i in range(o.shape[0]):
            h = trace(o[i], d[i], tmax[i])
            t_out[i] = h.t
            prim_out[i] = h.prim

    def run(origins, dirs, tmax):
        n = len(origins)
        t = np.empty(n, np.float32)
        prim = np.empty(n, np.int32)
        cast(origins, dirs, tmax, t, prim)
        return t, prim
    return run


def best_of(fn, runs=3):
    best = float("inf")
    for _ in range(runs):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def measure(name, dscene, tri, o, d, tmax):
    from photonmc.kernels.raycast import RayCaster
    o = np.ascontiguousarray(o, np.float32)
    d = np.ascontiguousarray(d, np.float32)
    tmax = np.ascontiguousarray(tmax, np.float32)
    binary = RayCaster(dscene)
    wide = make_caster(dscene, collapse(dscene.bvh))
    binary.cast(o[:1000], d[:1000], tmax=tmax[:1000])
    wide(o[:1000], d[:1000], tmax[:1000])
    t_b, kind_b, _ = binary.cast(o, d, tmax=tmax)
    t_w, prim_w = wide(o, d, tmax)
    agree = float(np.mean((t_b == t_w) | ((kind_b < 0) & (prim_w < 0))))
    out = {"rays": len(o), "binary_rays_per_s": len(o) / best_of(lambda: binary.cast(o, d, tmax=tmax)),
           "wide_rays_per_s": len(o) / best_of(lambda: wide(o, d, tmax)), "same_t_fraction": agree}
    try:
        from embreex import rtcore_scene as rtcs
        from embreex.mesh_construction import TriangleMesh
        es = rtcs.EmbreeScene()
        TriangleMesh(es, np.ascontiguousarray(tri, np.float32))
        te = np.where(np.isinf(tmax), 1e30, tmax).astype(np.float32)
        es.run(o[:1000], d[:1000], dists=te[:1000].copy())
        out["embree_1_thread_rays_per_s"] = len(o) / best_of(lambda: es.run(o, d, dists=te.copy()))
    except ImportError:
        pass
    print(f"{name}: " + ", ".join(f"{k} {v:.3g}" if isinstance(v, float) else f"{k} {v}" for k, v in out.items()))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--rays", type=int, default=2_000_000)
    ap.add_argument("--scene", default="mesh-room")
    args = ap.parse_args()
    import taichi as ti

    from bench import icosphere_rays
    from photonmc import runtime
    from photonmc.kernels.device_scene import DeviceScene
    from photonmc.kernels.raycast import RayLog
    from photonmc.loop import Job
    from photonmc.scene.scene import Bsdf, Camera, Scene
    runtime.init(threads=args.threads)

    mesh, o, d = icosphere_rays(args.rays)
    tri = mesh.vertices[mesh.faces]
    n = len(tri)
    scene = Scene("<icosphere>", Camera(np.eye(4), (0.5, 0.5), 4, 4), -1, [Bsdf(0, np.full(3, 0.5))],
                  np.array([[0, -1]], np.int32), np.ones((1, 3)), tri, np.repeat(mesh.face_normals[:, None], 3, 1),
                  np.zeros(n, np.int32), np.r_[0, -np.ones(n - 1)].astype(np.int32), np.zeros((0, 3)),
                  np.zeros(0), np.zeros(0, bool), np.zeros(0, np.int32), np.zeros(0, np.int32))
    measure(f"icosphere ({n} triangles), incoherent rays", DeviceScene(scene), tri, o, d,
            np.full(len(o), np.inf, np.float32))

    path = ROOT / "scenes" / args.scene / "scene.xml" if not args.scene.endswith(".xml") else Path(args.scene)
    p = Job(scene=str(path), params={}, method="pt", options={}, seed=0, threads=args.threads).prepare()
    if len(p.scene.sphere_radius):
        raise SystemExit(f"{path} has spheres; the study traces triangles only")
    w, h = p.scene.camera.width, p.scene.camera.height
    log = RayLog(w * h * 64)
    p.method.dscene.ray_log = log
    p.method.iterate()
    ti.sync()
    ro, rd, rt, any_hit = log.rays()
    measure(f"{path.parent.name} ({len(p.scene.tri_vertices)} triangles), pt's closest-hit rays",
            DeviceScene(p.scene), p.scene.tri_vertices, ro[~any_hit], rd[~any_hit], rt[~any_hit])


if __name__ == "__main__":
    main()

"""A 4-wide BVH, and the binary one with leaves tested four triangles at a time, measured
against the binary one and Embree on the same rays (issue 15,
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

    from photonmc.kernels.device_scene import MISS, Hit
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
                            dscene._triangle(j, o, d, hit)
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


def leaf4_scene(scene):
    """A DeviceScene whose leaves test their triangles four at a time: each leaf's triangles
    in packs of four stored lane by lane (Embree's triangle4 layout), one Moeller-Trumbore
    over the four lanes, then the nearest lane in lane order (the scalar loop's tie-breaking)."""
    import taichi as ti

    from photonmc.kernels.device_scene import TRIANGLE, DeviceScene
    from photonmc.kernels.fields import FieldGroup

    @ti.data_oriented
    class Leaf4Scene(DeviceScene):
        def __init__(self, scene):
            super().__init__(scene)
            bvh = self.bvh
            v = scene.tri_vertices[bvh.prim_order].astype(np.float64)
            v0, e1, e2 = v[:, 0], v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]
            packs, pack_of_first = [], np.zeros(max(len(v), 1), np.int32)
            for node in np.nonzero(bvh.count > 0)[0]:
                first, count = int(bvh.right_or_first[node]), int(bvh.count[node])
                pack_of_first[first] = len(packs)
                for q in range(0, count, 4):
                    rows = np.zeros((9, 4), np.float32)   # lanes past the leaf: zero edges, never hit
                    for lane in range(min(4, count - q)):
                        j = first + q + lane
                        rows[0:3, lane], rows[3:6, lane], rows[6:9, lane] = v0[j], e1[j], e2[j]
                    packs.append(rows)
            f = FieldGroup("leaf4")
            self.pack = f.vector(4, ti.f32, (len(packs), 9), np.stack(packs))
            self.pack_of_first = f.scalar(ti.i32, len(pack_of_first), pack_of_first)
            f.finalize()
            self.leaf4_fields = f

        @ti.func
        def _leaf(self, first: ti.i32, count: ti.i32, o, d, hit: ti.template()):
            p0 = self.pack_of_first[first]
            for q in range((count + 3) // 4):
                self._test4(p0 + q, first + 4 * q, o, d, hit)

        @ti.func
        def _test4(self, p, first, o, d, hit: ti.template()):
            v0x, v0y, v0z = self.pack[p, 0], self.pack[p, 1], self.pack[p, 2]
            e1x, e1y, e1z = self.pack[p, 3], self.pack[p, 4], self.pack[p, 5]
            e2x, e2y, e2z = self.pack[p, 6], self.pack[p, 7], self.pack[p, 8]
            pvx = d[1] * e2z - d[2] * e2y
            pvy = d[2] * e2x - d[0] * e2z
            pvz = d[0] * e2y - d[1] * e2x
            det = e1x * pvx + e1y * pvy + e1z * pvz
            inv_det = 1.0 / ti.select(det != 0.0, det, 1.0)
            tvx, tvy, tvz = o[0] - v0x, o[1] - v0y, o[2] - v0z
            b1 = (tvx * pvx + tvy * pvy + tvz * pvz) * inv_det
            qvx = tvy * e1z - tvz * e1y
            qvy = tvz * e1x - tvx * e1z
            qvz = tvx * e1y - tvy * e1x
            b2 = (d[0] * qvx + d[1] * qvy + d[2] * qvz) * inv_det
            t = (e2x * qvx + e2y * qvy + e2z * qvz) * inv_det
            ok = (det != 0.0) & (b1 >= 0.0) & (b1 <= 1.0) & (b2 >= 0.0) & (b1 + b2 <= 1.0) & (t > 0.0)
            for lane in ti.static(range(4)):
                if ok[lane] and t[lane] < hit.t:
                    hit.t, hit.kind, hit.prim, hit.b1, hit.b2 = t[lane], TRIANGLE, first + lane, b1[lane], b2[lane]

    return Leaf4Scene(scene)


def measure(name, scene, o, d, tmax):
    from bench import best_of
    from photonmc.kernels.raycast import RayCaster
    o = np.ascontiguousarray(o, np.float32)
    d = np.ascontiguousarray(d, np.float32)
    tmax = np.ascontiguousarray(tmax, np.float32)
    from photonmc.kernels.device_scene import DeviceScene
    dscene = DeviceScene(scene)
    tri = scene.tri_vertices
    binary = RayCaster(dscene)
    leaf4 = RayCaster(leaf4_scene(scene))
    variants = {"wide": make_caster(dscene, collapse(dscene.bvh)),
                "leaf4": lambda o, d, tmax: (lambda t, kind, prim: (t, prim))(*leaf4.cast(o, d, tmax=tmax))}
    binary.cast(o[:1000], d[:1000], tmax=tmax[:1000])
    t_b, kind_b, _ = binary.cast(o, d, tmax=tmax)
    out = {"rays": len(o), "binary_rays_per_s": len(o) / best_of(lambda: binary.cast(o, d, tmax=tmax))}
    _, _, prim_b = binary.cast(o, d, tmax=tmax)
    for variant, caster in variants.items():
        caster(o[:1000], d[:1000], tmax[:1000])
        t_v, prim_v = caster(o, d, tmax)
        out[f"{variant}_rays_per_s"] = len(o) / best_of(lambda caster=caster: caster(o, d, tmax))
        out[f"{variant}_same_t_fraction"] = float(np.mean((t_b == t_v) | ((kind_b < 0) & (prim_v < 0))))
        hit = kind_b >= 0
        both = hit & (prim_v >= 0)
        out[f"{variant}_hits_missed_fraction"] = float(np.mean(prim_v[hit] < 0))
        out[f"{variant}_max_relative_t_difference"] = float(np.max(np.abs(t_v[both] - t_b[both]) / t_b[both]))
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
    measure(f"icosphere ({n} triangles), incoherent rays", scene, o, d,
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
            p.scene, ro[~any_hit], rd[~any_hit], rt[~any_hit])


if __name__ == "__main__":
    main()

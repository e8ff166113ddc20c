"""BVH structure, and ray casting (BVH + spheres) against float64 brute force."""
from types import SimpleNamespace

import numpy as np
import pytest

from photonmc.kernels.device_scene import DeviceScene, SPHERE, TRIANGLE
from photonmc.kernels.raycast import RayCaster
from photonmc.scene.bvh import build_bvh
from photonmc.scene.scene import Bsdf, Camera, Scene


@pytest.mark.parametrize("n", [1, 2, 5, 33, 3000])
def test_bvh_invariants(n):
    rng = np.random.default_rng(n)
    tri = rng.random((n, 1, 3)) * 10 + rng.normal(size=(n, 3, 3)) * 0.3
    b = build_bvh(tri)
    assert sorted(b.prim_order.tolist()) == list(range(n))
    lo, hi = tri.min(1), tri.max(1)
    for i in range(b.node_count):
        if b.count[i] > 0:
            prims = b.prim_order[b.right_or_first[i]: b.right_or_first[i] + b.count[i]]
            assert (lo[prims] >= b.bmin[i] - 1e-5).all() and (hi[prims] <= b.bmax[i] + 1e-5).all()
        else:
            for child in (i + 1, b.right_or_first[i]):
                assert (b.bmin[child] >= b.bmin[i] - 1e-6).all() and (b.bmax[child] <= b.bmax[i] + 1e-6).all()


def test_bvh_splits_identical_centroids():
    tri = np.tile(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float), (100, 1, 1))
    b = build_bvh(tri)
    assert sorted(b.prim_order.tolist()) == list(range(100))
    assert b.count.max() <= 16


def soup_scene(n_tri=1500, n_sph=4, seed=0):
    rng = np.random.default_rng(seed)
    centers = rng.uniform(-1, 1, (n_tri, 1, 3))
    tri = centers + rng.normal(size=(n_tri, 3, 3)) * 0.08
    e = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n = e / np.linalg.norm(e, axis=1, keepdims=True)
    cam = Camera(np.eye(4), (0.5, 0.5), 4, 4)
    return Scene(
        path="<soup>", camera=cam, max_depth=-1, bsdfs=[Bsdf(0, np.full(3, 0.5))],
        materials=np.array([[0, -1]], np.int32), emitter_radiance=np.ones((1, 3)),
        tri_vertices=tri, tri_normals=np.repeat(n[:, None], 3, axis=1),
        tri_material=np.zeros(n_tri, np.int32), tri_emitter=np.r_[0, -np.ones(n_tri - 1)].astype(np.int32),
        sphere_center=rng.uniform(-1, 1, (n_sph, 3)), sphere_radius=rng.uniform(0.05, 0.3, n_sph),
        sphere_flip=np.zeros(n_sph, bool), sphere_material=np.zeros(n_sph, np.int32),
        sphere_emitter=-np.ones(n_sph, np.int32))


def brute_force(scene, o, d):
    """Closest hit in float64: (t, kind, prim)."""
    tri = scene.tri_vertices
    v0, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    best_t = np.full(len(o), np.inf)
    kind = np.full(len(o), -1)
    prim = np.full(len(o), -1)
    for i in range(len(o)):
        p = np.cross(d[i], e2)
        det = np.einsum("ij,ij->i", e1, p)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / det
            tv = o[i] - v0
            u = np.einsum("ij,ij->i", tv, p) * inv
            q = np.cross(tv, e1)
            v = (q @ d[i]) * inv
            t = np.einsum("ij,ij->i", e2, q) * inv
        ok = (det != 0) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
        if ok.any():
            j = np.argmin(np.where(ok, t, np.inf))
            best_t[i], kind[i], prim[i] = t[j], TRIANGLE, j
        f = o[i] - scene.sphere_center
        b = f @ d[i]
        disc = b * b - (np.einsum("ij,ij->i", f, f) - scene.sphere_radius ** 2)
        for s in np.nonzero(disc >= 0)[0]:
            for ts in (-b[s] - np.sqrt(disc[s]), -b[s] + np.sqrt(disc[s])):
                if 0 < ts < best_t[i]:
                    best_t[i], kind[i], prim[i] = ts, SPHERE, s
                    break
    return best_t, kind, prim


def test_closest_hit_matches_brute_force():
    scene = soup_scene()
    dscene = DeviceScene(scene)
    rc = RayCaster(dscene)
    rng = np.random.default_rng(1)
    n = 3000
    o = rng.uniform(-1.5, 1.5, (n, 3))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d[:50] = [[0, 0, 1]] * 50             # axis-aligned rays exercise zero direction components
    t, kind, prim = rc.cast(o, d)
    bt, bkind, bprim = brute_force(scene, o, d)
    hit = bkind >= 0
    assert hit.sum() > n // 4
    agree = (kind == bkind) & (prim == bprim)
    # Disagreement is allowed only for near-ties in t (float32 vs float64).
    close = np.isclose(t, bt, rtol=1e-4, atol=1e-5)
    assert np.all(agree | close), np.nonzero(~(agree | close))[0][:10]
    np.testing.assert_allclose(t[hit], bt[hit], rtol=1e-4, atol=1e-5)
    assert (kind[~hit] == -1).all()
    # any-hit finds a hit exactly when the closest hit exists
    _, any_kind, _ = rc.cast(o, d, any_hit=True)
    assert np.array_equal(any_kind >= 0, hit)
    # a bound just short of the closest hit misses, one just past it finds it
    tmax = np.where(hit, bt, 1.0).astype(np.float32)
    _, short_kind, _ = rc.cast(o, d, tmax=tmax * 0.999)
    _, long_kind, _ = rc.cast(o, d, tmax=tmax * 1.001)
    dscene.release()
    assert (short_kind[hit] == -1).all() and np.array_equal(long_kind[hit], kind[hit])


def test_the_ray_log_records_every_ray_pt_traces():
    """kernels/raycast.RayLog (tools/pt_stages.py): with max_depth 2 pt traces one camera ray
    per pixel, at most one bounce ray after it, and at most one shadow ray (next-event
    estimation) at the first hit; the logged closest-hit rays, cast again, all hit the closed box."""
    import taichi as ti
    from photonmc.kernels.raycast import RayLog
    from photonmc.loop import Job
    p = Job(params={"res": "8"}, method="pt", max_depth=2, seed=0).prepare()
    log = RayLog(8 * 8 * 8)
    p.method.dscene.ray_log = log
    p.method.iterate()
    ti.sync()
    o, d, tmax, any_hit = log.rays()
    assert int(log.count[None]) == len(o) <= log.capacity
    assert 64 <= (~any_hit).sum() <= 128 and np.isinf(tmax[~any_hit]).all()
    assert 0 < any_hit.sum() <= 64 and np.isfinite(tmax[any_hit]).all()
    t, kind, _ = RayCaster(p.method.dscene).cast(o[~any_hit], d[~any_hit])
    assert (kind >= 0).all()
    log.release()
    p.release()


def test_released_field_trees_are_recycled_and_bounded(write_scene):
    """A released render's fields go to a pool: the next render of the same scene takes the
    same fields (so its kernels are found compiled), and the pool stays bounded, since Taichi
    allows ~512 field trees per process."""
    from photonmc import load_scene
    from photonmc.film import Film
    from photonmc.kernels import fields
    from photonmc.loop import prepare
    from .conftest import camera_xml
    scene = load_scene(write_scene(camera_xml(res=4) + '<shape type="sphere"><boolean name="flip_normals" '
                                   'value="true"/><emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>'))
    p = prepare(scene)
    # The scene's fields are its own or, where an earlier test in this process rendered a
    # scene of the same sizes, pooled ones: either way the next render must take them.
    first = p.dscene.fields._own or p.dscene.fields._reused
    film_sum, scene_fields = p.method.film.sum, first.fields
    p.method.film.sum.fill(3.0)
    p.release()
    q = prepare(scene)
    assert q.method.film.sum is film_sum and q.dscene.fields._reused.fields is scene_fields
    assert q.method.film.sum.to_numpy().max() == 0.0          # recycled fields start zeroed
    q.release()
    films = [Film(4 + i, 3) for i in range(fields.POOL_MAX_GROUPS + 8)]
    allocations = [film.fields._own for film in films]
    for film in films:
        film.release()
    pooled = [a for v in fields._pool.values() for a in v]
    assert len(pooled) <= fields.POOL_MAX_GROUPS and all(a.tree is not None for a in pooled)
    assert sum(a.tree is None for a in allocations) >= 8        # the oldest were destroyed
    # No destroyed field may wait for Taichi's next compile-time check (it reads them).
    from taichi.lang import impl
    assert not impl.get_runtime().matrix_fields


def test_a_group_that_shares_only_a_prefix_with_a_pooled_one_gets_zeroed_fields():
    """Pooled fields are handed out in order while the specs match; where they diverge the
    rest are new. Every field handed out starts at zero, as a fresh one does."""
    import taichi as ti
    from photonmc.kernels.fields import FieldGroup
    g = FieldGroup("prefix-test")
    a, b = g.scalar(ti.f32, 4), g.scalar(ti.f32, 5)
    g.finalize()
    a.fill(1.0)
    b.fill(2.0)
    g.release()
    h = FieldGroup("prefix-test")
    c, d = h.scalar(ti.f32, 4), h.scalar(ti.f32, 6, values=np.arange(6))
    h.finalize()
    assert c is a and d is not b
    assert c.to_numpy().max() == 0.0 and np.array_equal(d.to_numpy(), np.arange(6))
    h.release()


def test_batched_fills_uploads_and_downloads_match_one_field_at_a_time():
    """kernels/batch.py: scalars and vectors of 0-4 dimensions and four dtypes, more fields
    than one batch holds, each value landing where field.from_numpy / field.fill put it, and
    read back as field.to_numpy reads it (shape, dtype, every bit)."""
    import taichi as ti
    from photonmc.kernels import batch
    from photonmc.kernels.fields import FieldGroup
    rng = np.random.default_rng(7)
    g = FieldGroup("batch-test")
    specs = [(None, ti.f32, ()), (3, ti.i32, (7,)), (2, ti.f32, (2, 3, 4)), (None, ti.i64, (3, 5)),
             (None, ti.f64, (2, 2, 2, 2)), (4, ti.f32, (5, 3)), (1, ti.f32, (4,))] * 5            # 35 > BATCH_FIELDS
    assert len(specs) > batch.BATCH_FIELDS
    fields = [g.scalar(d, s) if c is None else g.vector(c, d, s) for c, d, s in specs]
    g.finalize()
    arrays = []
    for (c, d, s), f in zip(specs, fields):
        shape = s + ((c,) if c else ())
        if d in (ti.i32, ti.i64):
            arrays.append(rng.integers(-1000, 1000, shape).astype(np.int32 if d == ti.i32 else np.int64))
        else:
            arrays.append(rng.normal(size=shape).astype(np.float32 if d == ti.f32 else np.float64))
    batch.upload_fields(zip(fields, arrays))
    for f, a, got in zip(fields, arrays, batch.download_fields(fields)):
        assert np.array_equal(f.to_numpy(), a)
        assert got.dtype == a.dtype and got.shape == a.shape and np.array_equal(got, a)
    values = [k % 3 + (0.25 if d in (ti.f32, ti.f64) else 0) for k, (_, d, _) in enumerate(specs)]
    batch.fill_fields(zip(fields, values))
    for f, v, got in zip(fields, values, batch.download_fields(fields)):
        assert (f.to_numpy() == v).all() and np.array_equal(got, f.to_numpy())
    with pytest.raises(ValueError, match="an array of 3 values for a field of 21"):
        batch.upload_fields([(fields[1], np.zeros(3, np.int32))])
    g.release()


def test_a_prepared_reader_reads_what_to_numpy_reads():
    """kernels/batch.py's FieldReader (a chain pass's tallies): integer and float fields,
    scalars and vectors, interleaved in its list, read by `copy` in a caller's kernel, each
    as field.to_numpy reads it (shape, dtype, every bit, including
    int64 values past 2^53 and u32 ones past 2^31)."""
    import taichi as ti
    from photonmc.kernels import batch
    from photonmc.kernels.fields import FieldGroup
    rng = np.random.default_rng(11)
    g = FieldGroup("reader-test")
    fields = [g.scalar(ti.i64, (3, 4)), g.vector(3, ti.f32, 5), g.scalar(ti.u32, 6), g.scalar(ti.f64, (2, 2)),
              g.vector(2, ti.i32, 3)]
    g.finalize()
    arrays = [rng.integers(-2 ** 62, 2 ** 62, (3, 4)), rng.normal(size=(5, 3)).astype(np.float32),
              rng.integers(2 ** 31, 2 ** 32 - 1, 6).astype(np.uint32), rng.normal(size=(2, 2)),
              rng.integers(-9, 9, (3, 2)).astype(np.int32)]
    for f, a in zip(fields, arrays):
        f.from_numpy(a)
    reader = batch.FieldReader(fields)

    @ti.kernel
    def caller(ints: ti.types.ndarray(), floats: ti.types.ndarray()):
        reader.copy(ints, floats)

    ints, floats = reader.arrays()
    caller(ints, floats)
    for f, a, got in zip(fields, arrays, reader.unpack(ints, floats)):
        assert got.dtype == a.dtype and got.shape == a.shape and np.array_equal(got, a)
    with pytest.raises(ValueError, match="scalar and vector fields of i32, i64, u32, f32 or f64"):
        batch.FieldReader([fields[0], SimpleNamespace(dtype=ti.u8, shape=(2,))])
    g.release()

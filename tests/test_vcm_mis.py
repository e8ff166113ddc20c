"""The VCM partial-sum recursion (kernels/vcm_mis.py) against the balance heuristic written
out from whole-path pdfs.

For random full paths x_0 (on an emitter) ... x_k (the camera), with diffuse and delta
vertices, each technique's weight is computed the way the renderer computes it (the
recursion along its light and camera subpaths, then the weight formula at the vertex that
makes the path) and compared with n_t p_t / sum_j n_j p_j from explicit area pdfs
(docs/vcm.md, "The techniques and their pdfs"). The weights of all techniques that can make
a path must sum to one, for every technique subset the renderer offers.
"""
import math

import numpy as np
import pytest
import taichi as ti

from photonmc.kernels import vcm_mis

MAX_K = 8
vec3 = ti.math.vec3


@ti.func
def _dir_pdf(pos: ti.template(), nrm: ti.template(), delta: ti.template(), prob: ti.template(), q: ti.template(), i: ti.i32, src: ti.i32, dst: ti.i32) -> ti.f32:
    """pdf at vertex i of the direction toward dst for a path arriving from src (continuation
    included): cosine-weighted for diffuse, the lobe probability for delta."""
    p = 0.0
    if delta[i]:
        p = prob[i] * q[i]
    else:
        w = (pos[dst] - pos[i]).normalized()
        p = ti.abs(w.dot(nrm[i])) / math.pi * q[i]
    return p


@ti.func
def _cos(pos: ti.template(), nrm: ti.template(), i: ti.i32, j: ti.i32) -> ti.f32:
    return ti.abs((pos[j] - pos[i]).normalized().dot(nrm[i]))


@ti.func
def _d2(pos: ti.template(), i: ti.i32, j: ti.i32) -> ti.f32:
    return (pos[j] - pos[i]).norm_sqr()


@ti.func
def _light_state(pos: ti.template(), nrm: ti.template(), delta: ti.template(), prob: ti.template(), q: ti.template(), k: ti.i32, j: ti.i32, direct_pdf_a: ti.f32, c):
    """Partial sums of the light subpath x_0..x_j at x_j (after the hit, before scattering)."""
    cos0 = _cos(pos, nrm, 0, 1)
    m = vcm_mis.light_start(direct_pdf_a, direct_pdf_a * cos0 / math.pi, cos0, c)
    for i in range(1, j + 1):
        vcm_mis.after_hit(m, _d2(pos, i - 1, i), _cos(pos, nrm, i, i - 1))
        if i < j:
            vcm_mis.after_scatter(m, delta[i], _cos(pos, nrm, i, i + 1), _dir_pdf(pos, nrm, delta, prob, q, i, i - 1, i + 1),
                                  _dir_pdf(pos, nrm, delta, prob, q, i, i + 1, i - 1), c)
    return m


@ti.func
def _camera_state(pos: ti.template(), nrm: ti.template(), delta: ti.template(), prob: ti.template(), q: ti.template(), k: ti.i32, j: ti.i32, camera_pdf_w: ti.f32, c):
    """Partial sums of the camera subpath x_k..x_j at x_j."""
    m = vcm_mis.camera_start(camera_pdf_w, c)
    i = k - 1
    while i >= j:
        vcm_mis.after_hit(m, _d2(pos, i + 1, i), _cos(pos, nrm, i, i + 1))
        if i > j:
            vcm_mis.after_scatter(m, delta[i], _cos(pos, nrm, i, i - 1), _dir_pdf(pos, nrm, delta, prob, q, i, i + 1, i - 1),
                                  _dir_pdf(pos, nrm, delta, prob, q, i, i - 1, i + 1), c)
        i -= 1
    return m


@ti.kernel
def technique_weights(pos: ti.types.ndarray(dtype=vec3, ndim=1), nrm: ti.types.ndarray(dtype=vec3, ndim=1),
                      delta: ti.types.ndarray(dtype=ti.i32, ndim=1), prob: ti.types.ndarray(dtype=ti.f32, ndim=1),
                      q: ti.types.ndarray(dtype=ti.f32, ndim=1), k: ti.i32, direct_pdf_a: ti.f32,
                      camera_pdf_w: ti.f32, vm_weight: ti.f32, vc_weight: ti.f32, n_light: ti.f32, camera_only: ti.f32,
                      w_conn: ti.types.ndarray(dtype=ti.f32, ndim=1), w_merge: ti.types.ndarray(dtype=ti.f32, ndim=1)):
    """w_conn[s]: s = 0 emitter hit, 1 next-event estimation, 2..k-1 connections, k light
    tracing; w_merge[s]: merging at x_s. -1 where the technique cannot make the path."""
    c = vcm_mis.MisConstants(vm_weight=vm_weight, vc_weight=vc_weight, n_light=n_light, camera_only=camera_only)
    ti.loop_config(serialize=True)
    for _ in range(1):
        for s in range(MAX_K + 1):
            w_conn[s] = -1.0
            w_merge[s] = -1.0
        # s = 0: the camera subpath hits the emitter at x_0.
        cam0 = _camera_state(pos, nrm, delta, prob, q, k, 0, camera_pdf_w, c)
        w_conn[0] = 1.0
        if k > 1:
            w_conn[0] = vcm_mis.emitter_hit_weight(cam0, direct_pdf_a, direct_pdf_a * _cos(pos, nrm, 0, 1) / math.pi, True, c)
        # s = 1: next-event estimation from x_1.
        if k > 1 and not delta[1]:
            cam = _camera_state(pos, nrm, delta, prob, q, k, 1, camera_pdf_w, c)
            cos_l = _cos(pos, nrm, 0, 1)
            d2 = _d2(pos, 0, 1)
            w_conn[1] = vcm_mis.next_event_weight(cam, direct_pdf_a * d2 / cos_l, direct_pdf_a * cos_l / math.pi, cos_l,
                                                  _cos(pos, nrm, 1, 0), _dir_pdf(pos, nrm, delta, prob, q, 1, 2, 0),
                                                  _dir_pdf(pos, nrm, delta, prob, q, 1, 0, 2), c, True)
        # 2 <= s <= k-1: light vertex x_{s-1} connected to camera vertex x_s.
        for s in range(2, k):
            if not delta[s - 1] and not delta[s]:
                lv = _light_state(pos, nrm, delta, prob, q, k, s - 1, direct_pdf_a, c)
                cv = _camera_state(pos, nrm, delta, prob, q, k, s, camera_pdf_w, c)
                d2 = _d2(pos, s - 1, s)
                camera_fwd_a = vcm_mis.pdf_w_to_a(_dir_pdf(pos, nrm, delta, prob, q, s, s + 1, s - 1), d2,
                                                  _cos(pos, nrm, s - 1, s))
                light_fwd_a = vcm_mis.pdf_w_to_a(_dir_pdf(pos, nrm, delta, prob, q, s - 1, s - 2, s), d2,
                                                 _cos(pos, nrm, s, s - 1))
                w_conn[s] = vcm_mis.connection_weight(lv, cv, camera_fwd_a,
                                                      _dir_pdf(pos, nrm, delta, prob, q, s, s - 1, s + 1),
                                                      light_fwd_a, _dir_pdf(pos, nrm, delta, prob, q, s - 1, s, s - 2), c)
        # s = k: light tracing from x_{k-1}.
        if k > 1 and not delta[k - 1]:
            lv = _light_state(pos, nrm, delta, prob, q, k, k - 1, direct_pdf_a, c)
            camera_pdf_a = vcm_mis.pdf_w_to_a(camera_pdf_w, _d2(pos, k - 1, k), _cos(pos, nrm, k - 1, k))
            w_conn[k] = vcm_mis.light_trace_weight(lv, camera_pdf_a, _dir_pdf(pos, nrm, delta, prob, q, k - 1, k, k - 2), c)
        # Merging at x_s, 1 <= s <= k-1.
        for s in range(1, k):
            if not delta[s]:
                lv = _light_state(pos, nrm, delta, prob, q, k, s, direct_pdf_a, c)
                cv = _camera_state(pos, nrm, delta, prob, q, k, s, camera_pdf_w, c)
                w_merge[s] = vcm_mis.merge_weight(lv, cv, _dir_pdf(pos, nrm, delta, prob, q, s, s + 1, s - 1),
                                                  _dir_pdf(pos, nrm, delta, prob, q, s, s - 1, s + 1), c)


def random_path(rng, k, delta_fraction):
    """Vertices x_0..x_k with normals facing both neighbours, some interior vertices delta."""
    pos = rng.uniform(-1, 1, (k + 1, 3))
    nrm = np.zeros_like(pos)
    for i in range(k + 1):
        toward = [(pos[j] - pos[i]) / np.linalg.norm(pos[j] - pos[i]) for j in (i - 1, i + 1) if 0 <= j <= k]
        n = sum(toward) + 0.3 * rng.normal(size=3)
        nrm[i] = n / np.linalg.norm(n)
    delta = np.zeros(k + 1, np.int32)
    delta[1:k] = rng.random(k - 1) < delta_fraction
    prob = np.where(delta, rng.uniform(0.05, 1.0, k + 1), 1.0)
    q = rng.uniform(0.2, 1.0, k + 1)
    return pos, nrm, delta, prob, q


def whole_path_weights(pos, nrm, delta, prob, q, k, direct_pdf_a, camera_pdf_w, n_light, eta, vc, vm, camera_only=1.0):
    """Balance heuristic n_t p_t / sum_j n_j p_j from area pdfs (docs/vcm.md). A delta vertex's
    density is its lobe probability per solid angle times a delta that every technique sampling
    through the vertex shares, so it cancels (a mirror's delta is symmetric in solid angle; the
    refraction Jacobian is left out, as in SmallVCM, which keeps the weights summing to one).
    camera_only: the relative sample count of the two techniques that need no light subpath
    (emitter hits, next-event estimation); mbe's modified weights set it to b_V."""
    def cos(i, j):
        w = pos[j] - pos[i]
        return abs(w @ nrm[i]) / np.linalg.norm(w)

    def d2(i, j):
        return float(np.sum((pos[j] - pos[i]) ** 2))

    def dir_pdf(i, src, dst):       # per solid angle
        return prob[i] * q[i] if delta[i] else cos(i, dst) / math.pi * q[i]

    fwd = np.zeros(k + 1)           # area pdf of x_i sampled from x_{i-1} (light direction)
    bwd = np.zeros(k + 1)           # area pdf of x_i sampled from x_{i+1} (camera direction)
    fwd[0] = direct_pdf_a
    fwd[1] = cos(0, 1) / math.pi * cos(1, 0) / d2(0, 1)
    for i in range(2, k + 1):
        fwd[i] = dir_pdf(i - 1, i - 2, i) * cos(i, i - 1) / d2(i - 1, i)
    bwd[k - 1] = camera_pdf_w * cos(k - 1, k) / d2(k - 1, k)
    for i in range(k - 2, -1, -1):
        bwd[i] = dir_pdf(i + 1, i + 2, i) * cos(i, i + 1) / d2(i, i + 1)
    conn, merge = {}, {}

    def p_conn(s):                  # light vertices x_0..x_{s-1}, camera x_s..x_k
        return np.prod(fwd[:s]) * np.prod(bwd[s:k])
    conn[0] = camera_only * p_conn(0)
    if k > 1:
        for s in range(1, k):
            if vc and not delta[s - 1] and not delta[s]:
                conn[s] = p_conn(s) * (camera_only if s == 1 else 1.0)
        if vc and not delta[k - 1]:
            conn[k] = n_light * np.prod(fwd[:k])
        if vm:
            for s in range(1, k):
                if not delta[s]:
                    merge[s] = eta * p_conn(s) * fwd[s]
        if vm and not vc:
            camera_all_delta = bool(delta[1:k].all())
            if not camera_all_delta:
                del conn[0]
            else:
                merge = {}
    total = sum(conn.values()) + sum(merge.values())
    return {s: p / total for s, p in conn.items()}, {s: p / total for s, p in merge.items()}


@pytest.mark.parametrize("techniques", ["vcm", "bpt", "bpm", "mbe-modified"])
@pytest.mark.parametrize("delta_fraction", [0.0, 0.4])
def test_weights_sum_to_one_and_equal_the_balance_heuristic(techniques, delta_fraction):
    """mbe-modified: all of VCM's techniques with the camera-only ones counted b_V times
    (b_V drawn over [1e-4, 1]), the weights mbe uses by default."""
    vc, vm = {"vcm": (True, True), "bpt": (True, False), "bpm": (False, True), "mbe-modified": (True, True)}[techniques]
    rng = np.random.default_rng(7 + int(10 * delta_fraction))
    w_conn = np.zeros(MAX_K + 1, np.float32)
    w_merge = np.zeros(MAX_K + 1, np.float32)
    checked = 0
    for trial in range(300):
        k = int(rng.integers(1, MAX_K))
        pos, nrm, delta, prob, q = random_path(rng, k, delta_fraction)
        direct_pdf_a = float(rng.uniform(0.1, 10))
        camera_pdf_w = float(rng.uniform(1, 1e4))
        n_light = float(rng.choice([1, 64, 4096]))
        radius = float(rng.uniform(1e-3, 0.1))
        eta = math.pi * radius ** 2 * n_light
        kappa = float(10 ** rng.uniform(-4, 0)) if techniques == "mbe-modified" else 1.0
        technique_weights(pos.astype(np.float32), nrm.astype(np.float32), delta, prob.astype(np.float32),
                          q.astype(np.float32), k, direct_pdf_a, camera_pdf_w, eta if vm else 0.0,
                          1.0 / eta if vc else 0.0, n_light, kappa, w_conn, w_merge)
        want_conn, want_merge = whole_path_weights(pos, nrm, delta, prob, q, k, direct_pdf_a, camera_pdf_w, n_light,
                                                   eta, vc, vm, kappa)
        got = {("c", s): float(w_conn[s]) for s in want_conn}
        got.update({("m", s): float(w_merge[s]) for s in want_merge})
        want = {("c", s): w for s, w in want_conn.items()}
        want.update({("m", s): w for s, w in want_merge.items()})
        if not vc and ("c", 0) in got:
            # bpm's own rule (Vcm._emitter_hit_weight), where the recursion does not apply:
            # emitter hits count, with weight 1, only on purely specular camera subpaths.
            got[("c", 0)] = 1.0
        assert abs(sum(got.values()) - 1.0) < 1e-4, (techniques, k, delta, got)
        for key, w in want.items():
            assert abs(got[key] - w) < 1e-4 * max(1.0, w), (techniques, k, delta, key, got[key], w)
        checked += 1
    assert checked == 300

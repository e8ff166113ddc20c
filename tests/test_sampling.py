"""BSDF sampling against evaluation, Fresnel and refraction, energy, and the RNG."""
import math

import numpy as np
import pytest
import taichi as ti

from photonmc.kernels import bsdf, rng, sampling
from photonmc.scene.scene import CONDUCTOR, DIELECTRIC, DIFFUSE

KINDS = (DIFFUSE, CONDUCTOR, DIELECTRIC)
vec3 = ti.math.vec3


@ti.kernel
def sample_many(kind: ti.i32, eta: ti.f32, wo: vec3, radiance: ti.i32, seed: ti.u32,
                wi: ti.types.ndarray(dtype=vec3, ndim=1), weight: ti.types.ndarray(dtype=vec3, ndim=1),
                pdf: ti.types.ndarray(dtype=ti.f32, ndim=1), eval_cos_over_pdf: ti.types.ndarray(dtype=vec3, ndim=1),
                pdf_again: ti.types.ndarray(dtype=ti.f32, ndim=1), ok: ti.types.ndarray(dtype=ti.i32, ndim=1)):
    for i in range(wi.shape[0]):
        state = rng.seed(seed, ti.u32(i), ti.u32(0))
        u1 = rng.next_float(state)
        u2 = rng.next_float(state)
        u3 = rng.next_float(state)
        s = bsdf.BsdfSample(wi=vec3(0.0), weight=vec3(0.0), pdf_fwd_w=0.0, pdf_rev_w=0.0, delta=0, eta=1.0, ok=0)
        if radiance:
            s = bsdf.sample(KINDS, kind, vec3(0.5, 0.6, 0.7), vec3(1.0), eta, wo, u1, u2, u3, True)
        else:
            s = bsdf.sample(KINDS, kind, vec3(0.5, 0.6, 0.7), vec3(1.0), eta, wo, u1, u2, u3, False)
        wi[i] = s.wi
        weight[i] = s.weight
        pdf[i] = s.pdf_fwd_w
        ok[i] = s.ok
        p = bsdf.evaluate(KINDS, kind, vec3(0.5, 0.6, 0.7), wo, s.wi).pdf_fwd_w
        pdf_again[i] = p
        if p > 0.0:
            eval_cos_over_pdf[i] = bsdf.evaluate(KINDS, kind, vec3(0.5, 0.6, 0.7), wo, s.wi).f * s.wi.z / p


def run_sampler(kind, wo, n=200_000, eta=1.5, radiance=False, seed=1):
    arrays = dict(wi=np.zeros((n, 3), np.float32), weight=np.zeros((n, 3), np.float32),
                  pdf=np.zeros(n, np.float32), eval_cos_over_pdf=np.zeros((n, 3), np.float32),
                  pdf_again=np.zeros(n, np.float32), ok=np.zeros(n, np.int32))
    wo = np.asarray(wo, np.float32) / np.linalg.norm(wo)
    sample_many(kind, eta, ti.math.vec3(*wo), int(radiance), seed, *arrays.values())
    return arrays


def chi_square_uniform(counts):
    expected = counts.sum() / counts.size
    return float(((counts - expected) ** 2 / expected).sum())


def test_diffuse_sampling_follows_its_pdf():
    a = run_sampler(DIFFUSE, [0.3, -0.2, 0.9])
    assert a["ok"].all()
    wi = a["wi"]
    # Cosine-weighted: cos^2(theta) and phi are uniform. 20x20 bins, 399 dof:
    # the 0.999 quantile of chi2(399) is about 498.
    u = wi[:, 2] ** 2
    phi = (np.arctan2(wi[:, 1], wi[:, 0]) + math.pi) / (2 * math.pi)
    counts, _, _ = np.histogram2d(u, phi, bins=20, range=[[0, 1], [0, 1]])
    assert chi_square_uniform(counts) < 498
    # The sampled pdf equals evaluate()'s, and f*cos/pdf equals the returned weight.
    np.testing.assert_allclose(a["pdf"], a["pdf_again"], rtol=1e-5)
    np.testing.assert_allclose(a["eval_cos_over_pdf"], a["weight"], rtol=1e-4)
    np.testing.assert_allclose(a["weight"][0], [0.5, 0.6, 0.7], rtol=1e-6)


def test_diffuse_is_one_sided():
    a = run_sampler(DIFFUSE, [0.0, 0.3, -0.9], n=100)
    assert not a["ok"].any()


def test_diffuse_albedo_by_quadrature():
    """Integral of f*cos over the hemisphere equals the reflectance (energy conservation)."""
    n = 400_000
    r = np.random.default_rng(0)
    # uniform hemisphere directions: pdf 1/(2 pi)
    z = r.random(n)
    phi = 2 * math.pi * r.random(n)
    s = np.sqrt(1 - z * z)
    wi = np.stack([s * np.cos(phi), s * np.sin(phi), z], 1).astype(np.float32)
    out = np.zeros((n, 3), np.float32)

    @ti.kernel
    def f_cos(wi: ti.types.ndarray(dtype=vec3, ndim=1), out: ti.types.ndarray(dtype=vec3, ndim=1)):
        for i in range(wi.shape[0]):
            out[i] = bsdf.evaluate(KINDS, DIFFUSE, vec3(0.5, 0.6, 0.7), vec3(0.0, 0.0, 1.0), wi[i]).f * wi[i].z

    f_cos(wi, out)
    albedo = out.mean(0) * 2 * math.pi
    np.testing.assert_allclose(albedo, [0.5, 0.6, 0.7], rtol=0.01)


def test_mirror_reflects():
    a = run_sampler(CONDUCTOR, [0.3, -0.2, 0.9], n=10)
    wo = np.array([0.3, -0.2, 0.9]) / np.linalg.norm([0.3, -0.2, 0.9])
    np.testing.assert_allclose(a["wi"][0], [-wo[0], -wo[1], wo[2]], rtol=1e-6)
    np.testing.assert_allclose(a["weight"][0], [0.5, 0.6, 0.7], rtol=1e-6)


def fresnel_reference(cos_i, eta):
    """Textbook unpolarised Fresnel for light arriving from the side cos_i points to."""
    n1, n2 = (1.0, eta) if cos_i > 0 else (eta, 1.0)
    ci = abs(cos_i)
    st2 = (n1 / n2) ** 2 * (1 - ci * ci)
    if st2 >= 1:
        return 1.0
    ct = math.sqrt(1 - st2)
    rs = ((n1 * ci - n2 * ct) / (n1 * ci + n2 * ct)) ** 2
    rp = ((n1 * ct - n2 * ci) / (n1 * ct + n2 * ci)) ** 2
    return 0.5 * (rs + rp)


@pytest.mark.parametrize("cos_i", [1.0, 0.7, 0.2, -1.0, -0.9, -0.5])
def test_dielectric_fresnel_snell_and_energy(cos_i):
    eta = 1.5
    sin_i = math.sqrt(1 - cos_i * cos_i)
    wo = [sin_i, 0.0, cos_i]
    a = run_sampler(DIELECTRIC, wo, n=200_000, eta=eta)
    refl = a["wi"][:, 2] * cos_i > 0
    r_expected = fresnel_reference(cos_i, eta)
    # Fraction of reflections is the Fresnel reflectance (binomial error, 5 sigma).
    sigma = math.sqrt(max(r_expected * (1 - r_expected), 1e-12) / len(refl))
    assert abs(refl.mean() - r_expected) < 5 * sigma + 1e-6
    # Importance transport: sampling the lobes in proportion R : T leaves only the
    # specular colours in the weights (here reflectance (0.5,0.6,0.7), transmittance 1).
    assert a["ok"].all()
    np.testing.assert_allclose(a["weight"][refl], np.broadcast_to([0.5, 0.6, 0.7], a["weight"][refl].shape), rtol=1e-6)
    np.testing.assert_allclose(a["weight"][~refl], 1.0, rtol=1e-6)
    t = ~refl
    if t.any():
        # Snell: n_i sin_i = n_t sin_t, transmitted direction on the other side.
        n_i, n_t = (1.0, eta) if cos_i > 0 else (eta, 1.0)
        sin_t = np.hypot(a["wi"][t, 0], a["wi"][t, 1])
        np.testing.assert_allclose(n_t * sin_t, n_i * sin_i, rtol=1e-4, atol=1e-6)
        assert (a["wi"][t, 2] * cos_i < 0).all()
        # Radiance transport scales transmitted radiance by (n_i/n_t)^2: the generalised
        # BSDF f/n^2 is then reciprocal (Veach 1997, 5.2).
        b = run_sampler(DIELECTRIC, wo, n=2000, eta=eta, radiance=True)
        tb = b["wi"][:, 2] * cos_i < 0
        np.testing.assert_allclose(b["weight"][tb], (n_i / n_t) ** 2, rtol=1e-5)


def test_fresnel_is_reciprocal():
    """Reflectance at incidence theta from outside equals that at the refracted angle from inside."""
    for cos_i in (0.95, 0.6, 0.3):
        r_out = fresnel_reference(cos_i, 1.5)
        sin_t = math.sqrt(1 - cos_i ** 2) / 1.5
        r_in = fresnel_reference(-math.sqrt(1 - sin_t ** 2), 1.5)
        assert r_out == pytest.approx(r_in, rel=1e-9)
        a = run_sampler(DIELECTRIC, [math.sqrt(1 - cos_i ** 2), 0, cos_i], n=100_000, eta=1.5)
        b = run_sampler(DIELECTRIC, [sin_t, 0, -math.sqrt(1 - sin_t ** 2)], n=100_000, eta=1.5, seed=7)
        fa = (a["wi"][:, 2] > 0).mean()
        fb = (b["wi"][:, 2] < 0).mean()
        assert abs(fa - fb) < 5 * math.sqrt(r_out * (1 - r_out) * 2 / 100_000)


@ti.kernel
def draw(n_streams: ti.i32, per_stream: ti.i32, seed: ti.u32, out: ti.types.ndarray(dtype=ti.f32, ndim=2)):
    for s in range(n_streams):
        state = rng.seed(seed, ti.u32(s), ti.u32(3))
        for k in range(per_stream):
            out[s, k] = rng.next_float(state)


def test_rng_uniform_and_independent_streams():
    out = np.zeros((4096, 64), np.float32)
    draw(4096, 64, 12345, out)
    assert out.min() >= 0.0 and out.max() < 1.0
    counts, _ = np.histogram(out, bins=256, range=(0, 1))
    assert chi_square_uniform(counts) < 360          # chi2(255) 0.999 quantile ~ 330
    # Consecutive draws within a stream, as 2D points: uniform on 32x32 cells.
    pairs, _, _ = np.histogram2d(out[:, 0:64:2].ravel(), out[:, 1:64:2].ravel(), bins=32, range=[[0, 1], [0, 1]])
    assert chi_square_uniform(pairs) < 1200          # chi2(1023) 0.999 quantile ~ 1170
    # Neighbouring streams (adjacent pixels) are uncorrelated.
    c = np.corrcoef(out[:-1].ravel(), out[1:].ravel())[0, 1]
    assert abs(c) < 0.01
    # Reproducible for the same seed, different for another.
    again = np.zeros_like(out)
    draw(4096, 64, 12345, again)
    assert np.array_equal(out, again)
    draw(4096, 64, 12346, again)
    assert not np.array_equal(out, again)


@ti.kernel
def heuristic(a: ti.types.ndarray(dtype=ti.f32, ndim=1), b: ti.types.ndarray(dtype=ti.f32, ndim=1),
              w: ti.types.ndarray(dtype=ti.f32, ndim=1)):
    for i in range(a.shape[0]):
        w[i] = sampling.power_heuristic(a[i], b[i])


def test_power_heuristic_at_extreme_pdfs():
    """A light sample seen at a grazing angle has a solid-angle pdf whose square overflows
    float32; the weight must stay finite (4 NaN samples in 49 M on the caustic scene before)."""
    big, inf = 1e30, float("inf")
    a = np.array([1, 3, 0, big, 1, big, inf, inf, 2e19], np.float32)
    b = np.array([1, 1, 5, 1, big, big, 1, inf, 1e19], np.float32)
    w = np.zeros(len(a), np.float32)
    heuristic(a, b, w)
    np.testing.assert_allclose(w, [0.5, 0.9, 0.0, 1.0, 0.0, 0.5, 1.0, 0.5, 0.8], rtol=1e-6, atol=1e-30)


@ti.kernel
def bidirectional_contract(kind: ti.i32, seed: ti.u32, out: ti.types.ndarray(dtype=ti.f32, ndim=2)):
    """Per sample: sampled forward/reverse pdfs, evaluate(wo, wi)'s pdfs and f, evaluate(wi, wo)'s."""
    for i in range(out.shape[0]):
        state = rng.seed(seed, ti.u32(i), ti.u32(1))
        wo = sampling.cosine_hemisphere(rng.next_float(state), rng.next_float(state))
        s = bsdf.sample(KINDS, kind, vec3(0.5, 0.6, 0.7), vec3(1.0), 1.5, wo, rng.next_float(state),
                        rng.next_float(state), rng.next_float(state), False)
        e = bsdf.evaluate(KINDS, kind, vec3(0.5, 0.6, 0.7), wo, s.wi)
        r = bsdf.evaluate(KINDS, kind, vec3(0.5, 0.6, 0.7), s.wi, wo)
        out[i, 0] = s.pdf_fwd_w
        out[i, 1] = s.pdf_rev_w
        out[i, 2] = e.pdf_fwd_w
        out[i, 3] = e.pdf_rev_w
        out[i, 4] = r.pdf_fwd_w
        out[i, 5] = r.pdf_rev_w
        out[i, 6] = e.f[1]
        out[i, 7] = r.f[1]
        out[i, 8] = s.delta
        out[i, 9] = bsdf.continuation(KINDS, kind, vec3(0.5, 0.6, 0.7), vec3(1.0))


@pytest.mark.parametrize("kind", KINDS)
def test_bidirectional_contract(kind):
    """sample() and evaluate() agree on both pdfs; the reverse pdf is the forward pdf with the
    directions swapped; f is reciprocal; a delta lobe's pdfs are equal both ways; the
    continuation probability is the largest albedo component."""
    out = np.zeros((20_000, 10), np.float32)
    bidirectional_contract(kind, 5, out)
    if kind == DIFFUSE:
        assert not out[:, 8].any()
        np.testing.assert_allclose(out[:, 0], out[:, 2], rtol=1e-5)
        np.testing.assert_allclose(out[:, 1], out[:, 3], rtol=1e-5)
        np.testing.assert_allclose(out[:, 3], out[:, 4], rtol=1e-6)
        np.testing.assert_allclose(out[:, 2], out[:, 5], rtol=1e-6)
        np.testing.assert_allclose(out[:, 6], out[:, 7], rtol=1e-6)
        np.testing.assert_allclose(out[:, 6], 0.6 / math.pi, rtol=1e-6)
        assert out[:, 9] == pytest.approx(0.7)
    else:
        assert out[:, 8].all()
        np.testing.assert_array_equal(out[:, 0], out[:, 1])
        assert (out[:, 0] > 0).all() and (out[:, 0] <= 1).all()
        # A delta lobe has no value for a given pair of directions.
        assert not out[:, 2:8].any()
        assert out[:, 9] == pytest.approx(0.7 if kind == CONDUCTOR else 1.0)

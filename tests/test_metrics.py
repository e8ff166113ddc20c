"""Error metrics: relMSE's epsilon follows the reference, and the per-pixel spread estimated
over seeds recovers the spread of the expected errors (synthetic renders with known noise)."""
import numpy as np
import pytest

from photonmc import metrics


def _reference(rng, shape=(48, 48)):
    return np.repeat(rng.uniform(0.02, 0.2, shape)[..., None], 3, axis=-1)


def test_relmse_does_not_change_when_the_radiance_is_scaled():
    rng = np.random.default_rng(1)
    ref = _reference(rng)
    img = ref * (1 + 0.1 * rng.standard_normal(ref.shape))
    values = [metrics.relmse(img * k, ref * k, metrics.relmse_epsilon(ref * k)) for k in (1e-6, 1.0, 1e6)]
    assert values == pytest.approx([values[1]] * 3, rel=1e-9)
    # a fixed eps = 0.01 is not relative on images this dark: 1000x darker, over 1e5x lower "relMSE"
    assert metrics.relmse(img * 1e-3, ref * 1e-3, 1e-2) < 1e-5 * metrics.relmse(img, ref, 1e-2)
    assert metrics.relmse(img, ref, metrics.relmse_epsilon(ref)) == pytest.approx(0.01, rel=0.1)


def _renders(rng, ref, rel_sigma, k):
    """k renders whose pixel p has relative noise rel_sigma[p] (expected relMSE ~ rel_sigma^2)."""
    return [ref * (1 + rel_sigma[..., None] * rng.standard_normal(ref.shape[:2])[..., None]) for _ in range(k)]


def test_the_spread_over_seeds_removes_the_single_render_noise_floor():
    rng = np.random.default_rng(2)
    ref = _reference(rng)
    eps = 1e-12                                   # relative error everywhere
    flat = np.full(ref.shape[:2], 0.1)
    # every pixel has the same expected relMSE: one render still shows a CV near sqrt(2)
    renders = _renders(rng, ref, flat, 8)
    assert metrics.relmse_spread(renders[0], ref, eps) == pytest.approx(np.sqrt(2), rel=0.1)
    assert metrics.relmse_spread_over_seeds(renders, ref, eps) < 0.1
    # half the pixels with 2x the noise: expected relMSE 0.01 and 0.04, CV 0.6
    uneven = flat.copy()
    uneven[:, : ref.shape[1] // 2] = 0.2
    cv = metrics.relmse_spread_over_seeds(_renders(rng, ref, uneven, 8), ref, eps)
    assert cv == pytest.approx(0.6, abs=0.08)
    assert metrics.relmse_spread_over_seeds(renders[:1], ref, eps) is None


def test_the_error_split_over_seeds_recovers_known_noise_and_bias():
    """Renders = reference + a fixed bias image + independent noise: the split returns the
    noise's and the bias's RMSE, and the reference's own noise is taken out of the bias."""
    rng = np.random.default_rng(3)
    ref = _reference(rng, (64, 64))
    bias = 0.01 * rng.standard_normal(ref.shape)          # RMSE 0.01, shared by every seed
    renders = [ref + bias + 0.03 * rng.standard_normal(ref.shape) for _ in range(6)]
    noise, systematic = metrics.noise_and_systematic_error(renders, ref)
    assert noise == pytest.approx(0.03, rel=0.03)
    assert systematic == pytest.approx(0.01, rel=0.1)
    # a reference whose own noise is known: the same renders against a noisy reference
    noisy_ref = ref + 0.02 * rng.standard_normal(ref.shape)
    _, systematic = metrics.noise_and_systematic_error(renders, noisy_ref, reference_noise_mse=0.02 ** 2)
    assert systematic == pytest.approx(0.01, rel=0.25)
    # unbiased renders: no systematic error left, and one render has no split
    _, systematic = metrics.noise_and_systematic_error([ref + 0.03 * rng.standard_normal(ref.shape)
                                                        for _ in range(6)], ref)
    assert systematic < 0.003
    assert metrics.noise_and_systematic_error(renders[:1], ref) is None

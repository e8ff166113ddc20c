"""The float64 films (film.py): a weighted film's mean and standard error against NumPy's."""
import numpy as np
import pytest
import taichi as ti

from photonmc.film import Film


@ti.kernel
def _add_all(film: ti.template(), values: ti.types.ndarray(), w: ti.f64):
    for y, x in ti.ndrange(values.shape[0], values.shape[1]):
        film.add_weighted(y, x, ti.Vector([values[y, x, 0], values[y, x, 1], values[y, x, 2]], ti.f32), w)


@pytest.mark.parametrize("weighted", [False, True])
def test_a_weighted_film_is_the_weighted_mean_with_its_standard_error(weighted):
    """Samples of weights 1, 3, 8, 2, 5 (mbe's chain passes weigh their K camera subpaths per
    pixel): the mean is sum w F / sum w and the standard error sqrt(sum w^2 (F - m)^2 /
    (sum w)^2 x P / (P - 1)); with every weight 1 the plain mean and sample standard error. A
    film that adds the sample unweighted, or counts passes for weight, fails the first."""
    rng = np.random.default_rng(4)
    weights = [1, 3, 8, 2, 5] if weighted else [1] * 5
    film = Film(3, 2, weighted=weighted)
    samples = []
    for w in weights:
        f = rng.exponential(1.0, size=(2, 3, 3)).astype(np.float32)
        _add_all(film, f, float(w))
        film.count_samples(w)
        samples.append(f.astype(np.float64))
    s, w = np.asarray(samples), np.asarray(weights, np.float64)[:, None, None]
    mean = (w[..., None] * s).sum(0) / w.sum()
    assert film.samples_per_pixel == sum(weights) and film.passes == len(weights)
    np.testing.assert_allclose(film.mean(), mean, rtol=1e-6)
    lum = s @ np.array([0.2126, 0.7152, 0.0722])
    m = lum.mean(0) if not weighted else (w * lum).sum(0) / w.sum()
    se = np.sqrt((w ** 2 * (lum - m) ** 2).sum(0) / w.sum() ** 2 * len(weights) / (len(weights) - 1))
    np.testing.assert_allclose(film.standard_error(), se, rtol=1e-5)
    if not weighted:
        np.testing.assert_allclose(film.standard_error(), lum.std(0, ddof=1) / np.sqrt(len(weights)), rtol=1e-5)
        with pytest.raises(ValueError):
            film.count_samples(2)
    film.release()

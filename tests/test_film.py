"""Film snapshots (photonmc/film.py): the spread of two passes, and passes taken back out."""
import numpy as np
import pytest

from photonmc.film import Film, FilmSnapshots

# Taichi rounds the luminance weights, Python floats in a kernel, to f32 (its default_fp)
Y = np.array([0.2126, 0.7152, 0.0722], np.float32).astype(np.float64)


def test_snapshots_measure_a_pair_of_passes_and_take_them_back_out():
    rng = np.random.default_rng(3)
    film = Film(5, 4)
    snapshots = FilmSnapshots(film)
    before = rng.random((4, 5, 3))
    before_sq = rng.random((4, 5))
    film.sum.from_numpy(before)
    film.sum_sq.from_numpy(before_sq)
    film.samples_per_pixel = 7
    e1, e2 = rng.random((4, 5, 3)), rng.random((4, 5, 3))
    snapshots.take(0)
    film.sum.from_numpy(before + e1)
    film.sum_sq.from_numpy(before_sq + 1.0)
    film.samples_per_pixel += 1
    snapshots.take(1)
    film.sum.from_numpy(before + e1 + e2)
    film.samples_per_pixel += 1
    expected = np.mean(((e1 - e2) @ Y) ** 2) / 2
    assert snapshots.pair_spread() == pytest.approx(expected, rel=1e-12)
    snapshots.restore()
    assert np.array_equal(film.sum.to_numpy(), before) and np.array_equal(film.sum_sq.to_numpy(), before_sq)
    assert film.samples_per_pixel == 7
    snapshots.release()
    film.release()

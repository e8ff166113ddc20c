"""The spatial target's hit statistics (photonmc/methods/clusters.py): the density a point
reads is its finest trusted cell's hits per unit area per pass, checked against a brute-force
computation over explicit (level, cell) keys. Hash collisions (rare at these sizes) merge
two cells' statistics, so a small share of points may differ; the checks allow 1 %."""
import numpy as np
import pytest

from photonmc.methods.clusters import MAX_LEVELS, HitDensityClusters

LEVELS = 10


def _points(rng, n):
    """Points on two planes of the unit cube, as measurement points lie on surfaces."""
    p = rng.random((n, 3))
    p[: n // 2, 2] = 0.25
    p[n // 2:, 1] = 0.7
    return p


def _cells(pos, level, clusters):
    base = (pos - clusters.lo) / clusters.size
    return np.clip(np.floor(base * (1 << level)).astype(np.int64), 0, (1 << level) - 1)


def test_density_is_the_hit_rate_of_the_finest_cell():
    """hits = area x g, g constant on the finest cells, every cell trusted at once: each point
    reads g of its own finest cell, whatever the pass's other cells hold."""
    rng = np.random.default_rng(1)
    clusters = HitDensityClusters(np.zeros(3), np.ones(3), 1 << 16, levels=LEVELS, min_samples=1.0)
    assert np.isnan(clusters.density(_points(rng, 100))).all()     # nothing accumulated yet
    for _ in range(3):
        pos = _points(rng, 4000)
        area = rng.random(len(pos)) * 1e-3 + 1e-6
        g = 1.0 + _cells(pos, LEVELS - 1, clusters)[:, 0] % 3
        clusters.accumulate(pos, area, area * g, np.full(len(pos), 2.0))
    # the last pass's points: their finest cells were filled in that pass
    rho = clusters.density(pos)
    assert np.mean(np.isclose(rho, g, rtol=1e-9)) > 0.99
    assert clusters.density(np.zeros((0, 3))).shape == (0,)


def test_a_point_reads_the_finest_cell_with_enough_samples():
    """One sample per point, four needed: a point's density comes from the finest level whose
    cell has gathered four over the passes, the sum of its passes' hits per area over the
    passes in which it held points (brute force over explicit cells)."""
    rng = np.random.default_rng(2)
    clusters = HitDensityClusters(np.zeros(3), np.ones(3), 1 << 16, levels=LEVELS, min_samples=4.0)
    kappa, passes, samples = {}, {}, {}
    for _ in range(4):
        pos = _points(rng, 400)
        area = rng.random(len(pos)) * 1e-3 + 1e-6
        hits = rng.random(len(pos)) * (1.0 + pos[:, 0])
        clusters.accumulate(pos, area, hits, np.ones(len(pos)))
        for level in range(LEVELS):
            keys = [(level, *c) for c in map(tuple, _cells(pos, level, clusters))]
            per_cell = {}
            for k, a, h in zip(keys, area, hits):
                sa, sh, n = per_cell.get(k, (0.0, 0.0, 0))
                per_cell[k] = (sa + a, sh + h, n + 1)
            for k, (sa, sh, n) in per_cell.items():
                kappa[k] = kappa.get(k, 0.0) + sh / sa
                passes[k] = passes.get(k, 0) + 1
                samples[k] = samples.get(k, 0) + n
    probe = _points(rng, 1000)
    expected = np.full(len(probe), np.nan)
    chosen = np.full(len(probe), -1)
    for level in range(LEVELS):
        for i, c in enumerate(map(tuple, _cells(probe, level, clusters))):
            k = (level, *c)
            if samples.get(k, 0) >= 4:
                expected[i] = kappa[k] / passes[k]
                chosen[i] = level
    rho = clusters.density(probe)
    agree = np.isclose(rho, expected, rtol=1e-9, equal_nan=True)
    print(f"{agree.mean():.4f} of points agree; levels read {np.bincount(chosen + 1)[1:]}")
    assert agree.mean() > 0.99
    assert len(np.unique(chosen)) >= 3 and (chosen >= 0).all()     # several levels are read


def test_more_levels_than_the_cells_hold_are_refused():
    """The finest level's cells have at most MAX_LEVELS - 1 bits per axis: a level beyond
    them would alias cells instead of failing."""
    HitDensityClusters(np.zeros(3), np.ones(3), 16, levels=MAX_LEVELS).release()
    with pytest.raises(ValueError, match="levels"):
        HitDensityClusters(np.zeros(3), np.ones(3), 16, levels=MAX_LEVELS + 1)


def test_frozen_statistics_hold_until_the_next_freeze():
    """spatial-tf --spatial-updates epochs reads the statistics freeze() took (density and the
    points' mean area per cell), whatever later passes accumulate, until it freezes again."""
    rng = np.random.default_rng(2)
    clusters = HitDensityClusters(np.zeros(3), np.ones(3), 1 << 16, levels=LEVELS, min_samples=1.0, frozen=True)
    pos = _points(rng, 4000)
    area = np.full(len(pos), 2e-4)
    clusters.freeze()
    assert np.isnan(clusters.frozen_values(pos)[0]).all()          # nothing accumulated before it
    clusters.accumulate(pos, area, area * 3.0, np.full(len(pos), 2.0))
    assert np.isnan(clusters.frozen_values(pos)[0]).all()          # held: not yet frozen
    clusters.freeze()
    rho, mean_area = clusters.frozen_values(pos)
    assert np.mean(np.isclose(rho, 3.0, rtol=1e-5)) > 0.99
    assert np.mean(np.isclose(mean_area, 2e-4, rtol=1e-5)) > 0.99
    clusters.accumulate(pos, 2 * area, 2 * area * 5.0, np.full(len(pos), 2.0))   # a later pass
    assert np.array_equal(clusters.frozen_values(pos)[0], rho, equal_nan=True)
    clusters.freeze()
    rho, mean_area = clusters.frozen_values(pos)
    assert np.mean(np.isclose(rho, 4.0, rtol=1e-5)) > 0.99          # the mean of 3 and 5 per pass
    assert np.mean(np.isclose(mean_area, 3e-4, rtol=1e-5)) > 0.99   # of 2e-4 and 4e-4


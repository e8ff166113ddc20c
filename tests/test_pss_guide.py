"""The learned primary-sample-space warp (kernels/pss_guide.py): its density is the density of
the points it makes, the kernel's warp is the host's, and a small step stays small."""
import numpy as np
import taichi as ti

from photonmc.kernels.pss_guide import CELLS, DEFENSIVE, PssGuide, warp_numpy, warp_tables


def _counts(rng, pairs=2):
    """A lumpy histogram: most mass in a few cells, some cells empty."""
    c = rng.gamma(0.3, size=(pairs, CELLS, CELLS))
    c[:, :, 3] = 0.0
    c[0, 5, 7] += 50.0
    return c


def test_the_warp_draws_by_its_own_density():
    """Uniform points through the warp land in each cell at its probability (1 - DEFENSIVE) x
    its share of the counts + DEFENSIVE / G^2, and the density the warp returns for a point is
    G^2 times the probability of the cell it lands in."""
    rng = np.random.default_rng(1)
    counts = _counts(rng)
    rows, cols = warp_tables(counts)
    n = 400_000
    for k in range(2):
        x, y = rng.random(n), rng.random(n)
        ux, uy, q = warp_numpy(rows, cols, k, x, y)
        assert (ux >= 0).all() and (ux < 1).all() and (uy >= 0).all() and (uy < 1).all()
        i, j = (ux * CELLS).astype(int), (uy * CELLS).astype(int)
        p = (1 - DEFENSIVE) * counts[k] / counts[k].sum() + DEFENSIVE / CELLS ** 2
        freq = np.bincount(i * CELLS + j, minlength=CELLS * CELLS).reshape(CELLS, CELLS) / n
        sigma = np.sqrt(p * (1 - p) / n)
        assert np.abs(freq - p).max() < 5 * sigma.max(), np.abs(freq - p).max()
        np.testing.assert_allclose(q, CELLS ** 2 * p[i, j], rtol=2e-5)
        # within a cell the warp is affine in each coordinate: uniform there
        inside = (i == 5) & (j == 7) if k == 0 else (i == i[0]) & (j == j[0])
        fx = ux[inside] * CELLS - i[inside]
        assert abs(fx.mean() - 0.5) < 4 * 0.29 / np.sqrt(inside.sum())
    # 1/q integrates the warp back to the unit square: E[1/q] over warped points is 1
    ux, uy, q = warp_numpy(rows, cols, 0, rng.random(n), rng.random(n))
    assert abs((1.0 / q).mean() - 1.0) < 5 * (1.0 / q).std() / np.sqrt(n)


def test_a_small_step_stays_small_and_no_counts_is_the_identity():
    rng = np.random.default_rng(2)
    rows, cols = warp_tables(_counts(rng))
    x, y = rng.random(2000), rng.random(2000)
    ux, uy, q = warp_numpy(rows, cols, 0, x, y)
    ux2, uy2, _ = warp_numpy(rows, cols, 0, np.minimum(x + 1e-6, 0.999999), y)
    # a step of 1e-6 in x moves u_x by at most 1e-6 / (smallest row probability x G), u_y may
    # change only where the row changes
    assert (np.abs(ux2 - ux) < 1e-6 / (DEFENSIVE / CELLS) / CELLS + 1e-6).all()
    rows0, cols0 = warp_tables(np.zeros((1, CELLS, CELLS)))
    ux, uy, q = warp_numpy(rows0, cols0, 0, x, y)
    np.testing.assert_allclose(ux, x, atol=1e-6)
    np.testing.assert_allclose(uy, y, atol=1e-6)
    np.testing.assert_allclose(q, 1.0, rtol=1e-5)


def test_the_kernels_warp_is_the_hosts():
    rng = np.random.default_rng(3)
    counts = _counts(rng)
    guide = PssGuide(2, 1, "test")
    try:
        rows, cols = warp_tables(counts)
        guide.rows.from_numpy(rows)
        guide.cols.from_numpy(cols)
        n = 4096
        xy = rng.random((n, 2)).astype(np.float32)
        out = ti.ndarray(ti.f32, (n, 3))

        @ti.kernel
        def run(xy: ti.types.ndarray(), out: ti.types.ndarray()):
            for m in range(n):
                ux, uy, q = guide.warp(1, xy[m, 0], xy[m, 1])
                out[m, 0], out[m, 1], out[m, 2] = ux, uy, q

        run(xy, out)
        got = out.to_numpy()
        ux, uy, q = warp_numpy(rows, cols, 1, xy[:, 0].astype(np.float64), xy[:, 1].astype(np.float64))
        np.testing.assert_allclose(got[:, 0], ux, atol=2e-6)
        np.testing.assert_allclose(got[:, 1], uy, atol=2e-6)
        np.testing.assert_allclose(got[:, 2], q, rtol=1e-4)
    finally:
        guide.release()

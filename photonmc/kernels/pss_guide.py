"""A learned warp of the photon paths' first primary-sample coordinates (primary sample space
guiding, Guo, Bauszat, Bikker & Eisemann 2018), for the Markov-chain photon methods.

Where light reaches the camera's room only through a gap, the set of visible photon paths is
thin in the first coordinates (the emission direction, the first bounce's direction) and a
mutation that moves it at all leaves it (docs/guiding.md, "Why the mutations shrink"). Here
each guided pair of coordinates (x, y) is a 2D piecewise-constant distribution over a G x G
grid, learned from the visible uniform proposals of the passes so far, each weighted by
what it brought to the image (methods/guided.py): a chain state is v in [0,1)^D as
before, its path reads u = W(v), and the photon's power carries 1 / q(u), q the warp's
density (the product over the pairs). Nothing else changes: the chains still sample their
targets in v (a uniform v is still an exact draw, a visible one still an exact start), the
normalisation b_V is still the visible fraction of uniform proposals in v, and every
estimate stays unbiased for any q > 0. What changes is that the visible set is wider in v
(b_V rises) and a small step in v is a smaller one in u where the visible paths crowd.

q mixes the learned histogram with the uniform density (DEFENSIVE), so the weight 1/q of a
pair is at most 1 / DEFENSIVE; cells no visible path has reached keep that floor.

The warp is piecewise linear in each coordinate (the row by its marginal CDF, then the
column by the row's conditional CDF), so a v near another maps near it in u. Its density is
computed from the same float32 tables the warp inverts, so the two agree exactly.
"""
import numpy as np
import taichi as ti

from ..taichi_frontend import data_oriented
from .batch import upload_fields
from .fields import FieldGroup

# The pairs of coordinates a guide may warp, in the order --pss-guide N takes them: the
# emission direction, the first bounce's direction, the light choice with the point's first
# coordinate (kernels/photon.py's layout).
PAIRS = ((3, 4), (5, 6), (0, 1))
CELLS = 16                 # per axis
DEFENSIVE = 0.3            # share of the uniform density in q
MIN_SAMPLES = 256          # visible uniform proposals before the first learned warp
U_MAX = 0.99999994         # the largest float32 below 1


def pair_dims(n_pairs: int) -> tuple:
    return PAIRS[:n_pairs]


def warp_tables(counts: np.ndarray, defensive: float = DEFENSIVE):
    """The float32 row and column CDFs of the mixture (1 - defensive) counts / sum + defensive
    / G^2 for each pair's G x G counts (a pair without counts: uniform)."""
    P, G, _ = counts.shape
    rows = np.zeros((P, G + 1), np.float32)
    cols = np.zeros((P, G, G + 1), np.float32)
    for k in range(P):
        total = counts[k].sum()
        p = np.full((G, G), 1.0 / (G * G))
        if total > 0:
            p = (1.0 - defensive) * counts[k] / total + defensive / (G * G)
        row = p.sum(axis=1)
        rows[k, 1:] = np.cumsum(row)
        rows[k, G] = 1.0
        cols[k, :, 1:] = np.cumsum(p / row[:, None], axis=1)
        cols[k, :, G] = 1.0
    return rows, cols


def warp_numpy(rows: np.ndarray, cols: np.ndarray, k: int, x: np.ndarray, y: np.ndarray):
    """The warp of pair k on the host (float64 arithmetic on the float32 tables): (u_x, u_y,
    density). For tests and tools; the kernels use PssGuide.warp."""
    G = cols.shape[1]
    i = np.clip(np.searchsorted(rows[k], x, side="right") - 1, 0, G - 1)
    lo, hi = rows[k][i].astype(np.float64), rows[k][i + 1].astype(np.float64)
    ux = np.minimum((i + np.clip((x - lo) / (hi - lo), 0.0, 1.0)) / G, U_MAX)
    c = cols[k][i]
    j = np.clip(np.array([np.searchsorted(c[n], y[n], side="right") - 1 for n in range(len(y))]), 0, G - 1)
    clo = c[np.arange(len(y)), j].astype(np.float64)
    chi = c[np.arange(len(y)), j + 1].astype(np.float64)
    uy = np.minimum((j + np.clip((y - clo) / (chi - clo), 0.0, 1.0)) / G, U_MAX)
    return ux, uy, G * G * (hi - lo) * (chi - clo)


@data_oriented
class PssGuide:
    """The warp of the first `n_pairs` of PAIRS, learned over the render: cumulative sums,
    per cell, of what the visible uniform proposals brought. Their photons carry 1 / q, so the
    sums estimate the contribution's own marginal whatever warp drew them. (Counted 1 / q each,
    they would estimate the visible set's; measured and lost more, docs/guiding.md.)"""

    def __init__(self, n_pairs: int, n_ladders: int, name: str):
        if not 1 <= n_pairs <= len(PAIRS):
            raise ValueError(f"a guide warps 1 to {len(PAIRS)} pairs of coordinates, got {n_pairs}")
        self.n_pairs = n_pairs
        self.dims = pair_dims(n_pairs)
        P, G = n_pairs, CELLS
        f = FieldGroup(f"pss-guide-{name}")
        self.rows = f.scalar(ti.f32, (P, G + 1))
        self.cols = f.scalar(ti.f32, (P, G, G + 1))
        # Per ladder (each ladder runs on one thread, so its float sums are deterministic; the
        # host adds the ladders in order), cumulative over the render.
        self.counts = f.scalar(ti.f64, (n_ladders, P, G, G))
        self.samples = f.scalar(ti.i64, n_ladders)     # visible uniform proposals learned from
        f.finalize()
        self.fields = f
        self.updates = 0            # passes that drew from a learned warp
        self.reset()

    def release(self):
        self.fields.release()

    def reset(self):
        rows, cols = warp_tables(np.zeros((self.n_pairs, CELLS, CELLS)))
        upload_fields([(self.rows, rows), (self.cols, cols),
                       (self.counts, np.zeros(self.counts.shape)), (self.samples, np.zeros(self.samples.shape, np.int64))])
        self.updates = 0

    def readable(self) -> tuple:
        """The fields a chain pass reads back with its tallies (ChainPool.run_pass's extra)."""
        return (self.counts, self.samples)

    def update(self, counts: np.ndarray, samples: int) -> list:
        """After a pass, from its read-back cumulative counts: the (field, array) pairs of the
        next pass's tables (to upload with the pass's other uploads), or [] while too few
        visible uniform proposals have been seen. The tables change between passes only, so
        each pass draws from one fixed warp."""
        if int(np.sum(samples)) < MIN_SAMPLES:
            return []
        rows, cols = warp_tables(np.asarray(counts, np.float64).sum(axis=0))
        self.updates += 1
        return [(self.rows, rows), (self.cols, cols)]

    @ti.func
    def _find(self, k, i, x):
        """The cell c in [0, G) with cdf[.., c] <= x < cdf[.., c + 1] (row CDF when i < 0)."""
        lo, hi = 0, CELLS - 1
        for _ in ti.static(range(int(np.log2(CELLS)) + 1)):
            if lo < hi:
                mid = (lo + hi + 1) // 2
                v = 0.0
                if i < 0:
                    v = self.rows[k, mid]
                else:
                    v = self.cols[k, i, mid]
                if v <= x:
                    lo = mid
                else:
                    hi = mid - 1
        return lo

    @ti.func
    def warp(self, k: ti.template(), x, y):
        """(u_x, u_y, q) of pair k at (x, y) in [0, 1)^2, q the warp's density there."""
        i = self._find(k, -1, x)
        lo, hi = self.rows[k, i], self.rows[k, i + 1]
        ux = ti.min((i + ti.math.clamp((x - lo) / (hi - lo), 0.0, 1.0)) / CELLS, U_MAX)
        j = self._find(k, i, y)
        clo, chi = self.cols[k, i, j], self.cols[k, i, j + 1]
        uy = ti.min((j + ti.math.clamp((y - clo) / (chi - clo), 0.0, 1.0)) / CELLS, U_MAX)
        return ux, uy, CELLS * CELLS * (hi - lo) * (chi - clo)

    @ti.func
    def learn(self, source: ti.template(), key, ladder, weight):
        """A visible uniform proposal `key` (coordinates v from `source`) of what it brought
        (`weight`, its photons' power already carrying 1 / q(u), q over every pair: which is
        what makes the sums estimate the contribution's own marginal): each pair's cell of its
        warped coordinates gains weight."""
        cells = ti.Vector([0] * self.n_pairs)
        for k in ti.static(range(self.n_pairs)):
            ux, uy, _ = self.warp(k, source.get(key, self.dims[k][0]), source.get(key, self.dims[k][1]))
            cells[k] = ti.cast(ux * CELLS, ti.i32) * CELLS + ti.cast(uy * CELLS, ti.i32)
        add = ti.cast(weight, ti.f64)
        for k in ti.static(range(self.n_pairs)):
            self.counts[ladder, k, cells[k] // CELLS, cells[k] % CELLS] += add
        self.samples[ladder] += 1

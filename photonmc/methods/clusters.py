"""Photon-hit density per world-space cluster, for the spatial target (Gruson et al. 2016, §3.3).

Structure: an implicit octree over the scene's bounding cube, stored as a hash table keyed
by (level, cell). Level L cuts the cube into 2^L cells per axis; every level accumulates at
once, and a measurement point (MP) reads the density of the finest cell around it that has
gathered `min_samples` distinct photon hits.

Why this and not the paper code's median k-d tree: MPs are regenerated every pass, so
clusters must be fixed in world space to carry statistics from pass to pass. A k-d tree
built from the first pass's MPs fixes its cells to that pass's sample; the octree needs no
build, refines only where hits accumulate (the "enough samples before splitting" rule of the
paper's iterationvalid/variance strategies), and is a few numpy calls per pass. Cells are 3D,
so unlike image-plane clusters they do not mix surfaces across depth discontinuities.
Hash collisions merge two cells' statistics; that changes the importance (variance), never
the estimate (any positive target is unbiased).
"""
from __future__ import annotations

import numpy as np

_PRIMES = np.array([73856093, 19349663, 83492791], np.int64)
MORTON_BITS = 10      # bits per axis of _morton's codes: the finest level has 2^(levels - 1) cells per axis


def _morton(cells: np.ndarray) -> np.ndarray:
    """Morton (Z-order) codes of integer cells (n, 3) of up to 10 bits per axis: the bits of
    x, y and z interleaved, so that the code of a cell at a coarser level is a prefix."""
    code = np.zeros(len(cells), np.int64)
    for axis in range(3):
        v = cells[:, axis].astype(np.int64) & ((1 << MORTON_BITS) - 1)
        v = (v | (v << 16)) & 0x030000FF
        v = (v | (v << 8)) & 0x0300F00F
        v = (v | (v << 4)) & 0x030C30C3
        v = (v | (v << 2)) & 0x09249249
        code |= v << (2 - axis)
    return code


class HitDensityClusters:
    TRANSIENT = ("_cached",)     # a render state keeps the statistics, not the last pass's slots

    def __init__(self, lo, hi, n_points: int, levels: int = 10, min_samples: float = 64.0):
        lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
        self.lo = lo
        self.size = float(max((hi - lo).max(), 1e-12)) * 1.0001
        if not 1 <= levels <= MORTON_BITS + 1:
            raise ValueError(f"levels must be 1 to {MORTON_BITS + 1} (Morton codes of {MORTON_BITS} bits per axis)")
        self.levels = levels
        self.min_samples = float(min_samples)
        bits = int(np.clip(np.ceil(np.log2(max(8 * n_points * levels, 1024))), 10, 22))
        self.mask = (1 << bits) - 1
        n = 1 << bits
        self.kappa = np.zeros(n)            # sum over passes of (hits / area) in the cell
        self.passes = np.zeros(n, np.int64)  # passes in which the cell held MPs
        self.samples = np.zeros(n)          # distinct chain states that hit the cell's MPs
        self._cached = None                 # (points, their slots per level): see _level_slots

    def _levels(self, pos: np.ndarray) -> tuple[np.ndarray, list[tuple[np.ndarray, np.ndarray]]]:
        """The points' cells at every level, from one sort: (order, [(run starts, table slots)
        per level]). The points are sorted once by the Morton code of their finest cell; a
        coarser level's cell is a prefix of that code, so each level's cells are runs of the
        sorted points, and only a run's first point is hashed. (Ten sorts, one per level, and
        hashing every point at every level were 35-40 % of a spatial-tf iteration on the
        Cornell box at 64x64 with 18 camera paths per pixel; docs/performance.md.) A pass
        asks twice for the same points (density before it, accumulate after), so the last
        answer is kept."""
        if self._cached is not None and self._cached[0] is pos:
            return self._cached[1]
        finest = self.levels - 1
        base = (pos - self.lo) / self.size          # x 2^level below is exact, so cells are as before
        cells = np.clip(np.floor(base * (1 << finest)).astype(np.int64), 0, (1 << finest) - 1)
        code = _morton(cells)
        order = np.argsort(code, kind="stable")
        cells, code = cells[order], code[order]
        out = []
        for level in range(self.levels):
            shift = finest - level
            key = code >> (3 * shift)
            starts = np.flatnonzero(np.concatenate(([True], key[1:] != key[:-1]))) if len(key) else key
            c = cells[starts] >> shift                  # = floor(base * 2^level), clipped
            h = (c[:, 0] * _PRIMES[0] + c[:, 1] * _PRIMES[1] + c[:, 2] * _PRIMES[2]) \
                ^ (np.int64(level) * np.int64(0x9E3779B1))
            out.append((starts, (h ^ (h >> 17)) & self.mask))
        self._cached = (pos, (order, out))
        return order, out

    def accumulate(self, pos, area, hits, samples) -> None:
        """One pass: pos, area (pi R^2), hits (uniform-path-equivalent hits this pass) and
        samples (distinct states) of the valid MPs. Per cell: kappa += its hits / its area;
        two cells that share a table slot add up there (a collision changes the importance,
        never the estimate)."""
        if len(pos) == 0:
            return
        order, levels = self._levels(pos)
        area, hits, samples = (np.asarray(x, np.float64)[order] for x in (area, hits, samples))
        for starts, slots in levels:
            a = np.add.reduceat(area, starts)
            np.add.at(self.kappa, slots, np.add.reduceat(hits, starts) / np.maximum(a, 1e-300))
            self.passes[slots] += 1          # once per pass, however many cells share the slot
            np.add.at(self.samples, slots, np.add.reduceat(samples, starts))

    def density(self, pos) -> np.ndarray:
        """Hits per unit area per pass at each point, from the finest trusted cell; NaN where
        no level has enough samples yet."""
        n = len(pos)
        if n == 0:
            return np.full(0, np.nan)
        order, levels = self._levels(pos)
        rho_sorted = np.full(n, np.nan)
        for starts, slots in levels:              # coarse to fine: the finest trusted one stays
            trusted = (self.samples[slots] >= self.min_samples) & (self.passes[slots] > 0)
            value = np.where(trusted, self.kappa[slots] / np.maximum(self.passes[slots], 1), np.nan)
            per_point = np.repeat(value, np.diff(np.append(starts, n)))
            keep = ~np.isnan(per_point)
            rho_sorted[keep] = per_point[keep]
        rho = np.empty(n)
        rho[order] = rho_sorted
        return rho

    def reset(self):
        for a in (self.kappa, self.passes, self.samples):
            a[:] = 0
        self._cached = None

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


class HitDensityClusters:
    TRANSIENT = ("_cached",)     # a render state keeps the statistics, not the last pass's slots

    def __init__(self, lo, hi, n_points: int, levels: int = 10, min_samples: float = 64.0):
        lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
        self.lo = lo
        self.size = float(max((hi - lo).max(), 1e-12)) * 1.0001
        self.levels = levels
        self.min_samples = float(min_samples)
        bits = int(np.clip(np.ceil(np.log2(max(8 * n_points * levels, 1024))), 10, 22))
        self.mask = (1 << bits) - 1
        n = 1 << bits
        self.kappa = np.zeros(n)            # sum over passes of (hits / area) in the cell
        self.passes = np.zeros(n, np.int64)  # passes in which the cell held MPs
        self.samples = np.zeros(n)          # distinct chain states that hit the cell's MPs
        self._cached = None                 # (points, their slots per level): see _level_slots

    def _level_slots(self, pos: np.ndarray) -> list[np.ndarray]:
        """Each level's table slot of every point. A pass asks twice for the same points
        (density before it, accumulate after), so the last answer is kept: hashing 10 levels
        of 2^17-2^20 points was 40 % of a spatial-tf iteration on the Cornell box at 128^2
        (docs/performance.md, "Where the time goes")."""
        if self._cached is not None and self._cached[0] is pos:
            return self._cached[1]
        base = (pos - self.lo) / self.size          # x 2^level below is exact, so cells are as before
        out = []
        for level in range(self.levels):
            cells = np.clip(np.floor(base * (1 << level)).astype(np.int64), 0, (1 << level) - 1)
            h = (cells[:, 0] * _PRIMES[0] + cells[:, 1] * _PRIMES[1] + cells[:, 2] * _PRIMES[2]) \
                ^ (np.int64(level) * np.int64(0x9E3779B1))
            out.append((h ^ (h >> 17)) & self.mask)
        self._cached = (pos, out)
        return out

    def accumulate(self, pos, area, hits, samples) -> None:
        """One pass: pos, area (pi R^2), hits (uniform-path-equivalent hits this pass) and
        samples (distinct states) of the valid MPs."""
        if len(pos) == 0:
            return
        for level_slots in self._level_slots(pos):
            slots, inverse = np.unique(level_slots, return_inverse=True)
            a = np.bincount(inverse, area)
            h = np.bincount(inverse, hits)
            s = np.bincount(inverse, samples)
            self.kappa[slots] += h / np.maximum(a, 1e-300)
            self.passes[slots] += 1
            self.samples[slots] += s

    def density(self, pos) -> np.ndarray:
        """Hits per unit area per pass at each point, from the finest trusted cell; NaN where
        no level has enough samples yet."""
        rho = np.full(len(pos), np.nan)
        for slots in self._level_slots(pos):
            trusted = (self.samples[slots] >= self.min_samples) & (self.passes[slots] > 0)
            rho[trusted] = self.kappa[slots[trusted]] / self.passes[slots[trusted]]
        return rho

    def reset(self):
        for a in (self.kappa, self.passes, self.samples):
            a[:] = 0
        self._cached = None

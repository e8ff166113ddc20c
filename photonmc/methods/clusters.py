"""Photon-hit density per world-space cluster, for the spatial target (Gruson et al. 2016, §3.3).

Structure: an implicit octree over the scene's bounding cube, a table per level (a coarse
level indexes its cells, a fine one hashes them). Level L cuts the cube into 2^L cells per
axis; every level accumulates at once, and a measurement point (MP) reads the density of the
finest cell around it that has gathered `min_samples` distinct photon hits.

Why this and not the paper code's median k-d tree: MPs are regenerated every pass, so
clusters must be fixed in world space to carry statistics from pass to pass. A k-d tree
built from the first pass's MPs fixes its cells to that pass's sample; the octree needs no
build and refines only where hits accumulate (the "enough samples before splitting" rule of
the paper's iterationvalid/variance strategies). Cells are 3D, so unlike image-plane
clusters they do not mix surfaces across depth discontinuities. Hash collisions merge two
cells' statistics; that changes the importance (variance), never the estimate (any positive
target is unbiased).

The table lives in Taichi fields and is read and filled by ti.funcs that the spatial
target's kernels call on its MP fields directly (methods/guided.py): the same work in NumPy
(a Morton sort of the MPs and grouped reductions per level) was a third of a spatial-tf
iteration on the 64x64 Cornell box with 19 camera paths per pixel (docs/performance.md,
"The spatial target's clusters in kernels"). The levels fill in parallel, each level's
cells summed over the points in their order, so the statistics, and the image, do not
depend on thread timing.
"""

import numpy as np
import taichi as ti

from ..kernels.fields import FieldGroup
from ..taichi_frontend import data_oriented

PRIMES = (73856093, 19349663, 83492791)
LEVEL_SALT = 0x9E3779B1
MAX_LEVELS = 11       # cells of up to 10 bits per axis at the finest level
UNKNOWN = -1.0        # the density of a point whose cells have too few samples


@data_oriented
class HitDensityClusters:
    # Zero between passes (close_pass empties them), so a render state need not keep them.
    TRANSIENT = ("pass_sums", "touched", "n_touched")

    def __init__(self, lo, hi, n_points: int, levels: int = 10, min_samples: float = 64.0, frozen: bool = False):
        """frozen: also keep a copy of each slot's density and mean point area, taken by
        freeze() and read by frozen_at(), which later passes' statistics do not change (the
        spatial target's epochs, docs/guiding.md "Spatial targets held for an epoch")."""
        lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
        self.lo = lo
        self.size = float(max((hi - lo).max(), 1e-12)) * 1.0001
        if not 1 <= levels <= MAX_LEVELS:
            raise ValueError(f"levels must be 1 to {MAX_LEVELS} (cells of at most {MAX_LEVELS - 1} bits per axis)")
        self.levels = levels
        self.min_samples = float(min_samples)
        # Each level has a table of its own, so that the levels fill in parallel and every
        # slot is written by one thread in a fixed order (determinism). A level with at most
        # `hashed` cells indexes them directly (no collisions); a finer one hashes its cells
        # into `hashed` slots.
        # Memory: 52 bytes a slot (76 with the frozen copy and the mean area it needs); 3.4 M
        # slots (177 MB) for the 256x256 default render. (A single shared table of 4 M slots
        # in NumPy took 100 MB: docs/performance.md.)
        hashed = 1 << int(np.clip(np.ceil(np.log2(max(n_points * levels, 1024))), 10, 20))
        sizes = [min(8 ** level, hashed) for level in range(levels)]
        offsets = np.concatenate(([0], np.cumsum(sizes)[:-1]))
        n = int(sum(sizes))
        f = FieldGroup("clusters")
        # Per slot: the sum over passes of (hits / area) in the cell (kappa), the passes in
        # which it held MPs, the distinct chain states that hit its MPs, and (frozen only: only
        # the frozen copy reads it) the sum over passes of its MPs' mean area.
        self.has_frozen = bool(frozen)
        width = 4 if self.has_frozen else 3
        self.stats = f.vector(width, ti.f64, n)
        self.pass_sums = f.vector(width, ti.f64, n)  # this pass's hits, area, samples (, points) per slot
        if self.has_frozen:
            self.frozen = f.vector(2, ti.f32, n)    # freeze(): density (or UNKNOWN), mean MP area
        self.touched = f.scalar(ti.i32, n)          # per level, the slots this pass filled, in order
        self.n_touched = f.scalar(ti.i32, levels)
        # The cube's corner and side: a field, not constants, so that the kernels compile
        # once for every scene of the same size.
        self.frame = f.vector(4, ti.f64, (), values=np.append(lo, self.size))
        # Per level: its table's offset, its size, and whether it indexes cells directly.
        self.level_table = f.vector(3, ti.i32, levels, values=np.array(
            [(o, z, 8 ** level <= z) for level, (o, z) in enumerate(zip(offsets, sizes))], np.int32))
        f.finalize()
        self.fields = f

    def release(self):
        self.fields.release()

    def reset(self):
        self.stats.fill(0.0)
        self.pass_sums.fill(0.0)
        self.n_touched.fill(0)
        if self.has_frozen:
            self.frozen.fill(UNKNOWN)

    def freeze(self):
        """The statistics so far become those frozen_at() reads, until the next freeze()."""
        self._freeze()

    @ti.kernel
    def _freeze(self):
        for s in self.stats:
            st = self.stats[s]
            rho = ti.f64(UNKNOWN)
            area = ti.f64(0.0)
            if st[2] >= ti.static(self.min_samples) and st[1] > 0.0:
                rho = st[0] / st[1]
                area = st[3] / st[1]
            self.frozen[s] = ti.Vector([ti.cast(rho, ti.f32), ti.cast(area, ti.f32)])

    # -- the table, for kernels ----------------------------------------------------------------
    @ti.func
    def _finest_cell(self, p):
        fr = self.frame[None]
        cells = ti.Vector([0, 0, 0], ti.i64)
        top = ti.i64(1 << ti.static(self.levels - 1)) - 1
        for k in ti.static(range(3)):
            base = (ti.cast(p[k], ti.f64) - fr[k]) / fr[3]
            cells[k] = ti.math.clamp(ti.cast(ti.floor(base * ti.static(float(1 << (self.levels - 1)))), ti.i64),
                                     0, top)
        return cells

    @ti.func
    def _slot(self, finest_cells, level) -> ti.i32:
        """The table slot of the level's cell around a point whose finest cell is given."""
        lv = ti.cast(level, ti.i64)
        c = finest_cells >> (ti.static(self.levels - 1) - lv)
        table = self.level_table[level]
        index = ti.i64(0)
        if table[2]:
            index = c[0] + (c[1] << lv) + (c[2] << (2 * lv))      # every cell its own slot
        else:
            h = (c[0] * PRIMES[0] + c[1] * PRIMES[1] + c[2] * PRIMES[2]) ^ (ti.i64(LEVEL_SALT) * (lv + 1))
            index = (h ^ (h >> 17)) & (table[1] - 1)
        return table[0] + ti.cast(index, ti.i32)

    @ti.func
    def density_at(self, p) -> ti.f64:
        """Hits per unit area per pass at p, from the finest cell with enough samples (and at
        least one pass); UNKNOWN where none has."""
        cells = self._finest_cell(p)
        rho = ti.f64(UNKNOWN)
        found = False
        level = ti.cast(ti.static(self.levels - 1), ti.i32)          # finest first
        while level >= 0 and not found:
            st = self.stats[self._slot(cells, level)]
            if st[2] >= ti.static(self.min_samples) and st[1] > 0.0:
                rho = st[0] / st[1]
                found = True
            level -= 1
        return rho

    @ti.func
    def frozen_at(self, p):
        """density_at and the mean MP area there, as freeze() last took them: (UNKNOWN, 0)
        where no level had enough samples."""
        cells = self._finest_cell(p)
        out = ti.Vector([UNKNOWN, 0.0], ti.f32)
        found = False
        level = ti.cast(ti.static(self.levels - 1), ti.i32)          # finest first
        while level >= 0 and not found:
            fz = self.frozen[self._slot(cells, level)]
            if fz[0] != UNKNOWN:
                out = fz
                found = True
            level -= 1
        return out

    @ti.func
    def accumulate_points(self, points: ti.template(), n):
        """One pass's hits from n points: `points.cluster_point(j)` gives (valid, position,
        area pi R^2, hits, samples) of point j. Per cell, the pass sums of its points' hits,
        area and samples; close_pass turns them into statistics. The levels run in parallel,
        each over the points in their order: every sum is made in one fixed order."""
        ti.loop_config(block_dim=1)        # a level per task: the levels are few and long
        for level in range(self.levels):
            offset = self.level_table[level][0]
            for j in range(n):
                valid, p, area, hits, samples = points.cluster_point(j)
                if valid and area > 0.0:
                    s = self._slot(self._finest_cell(p), level)
                    sums = self.pass_sums[s]
                    if sums[1] == 0.0:     # first point in this slot this pass (areas are > 0)
                        self.touched[offset + self.n_touched[level]] = s
                        self.n_touched[level] += 1
                    if ti.static(self.has_frozen):
                        self.pass_sums[s] = sums + ti.Vector([hits, area, samples, 1.0], ti.f64)
                    else:
                        self.pass_sums[s] = sums + ti.Vector([hits, area, samples], ti.f64)

    @ti.func
    def close_pass(self):
        """Per slot filled this pass: kappa += its hits / its area, one more pass, its samples
        (and, frozen, its points' mean area); its pass sums emptied. Two cells that share a
        slot add up there (a collision changes the importance, never the estimate)."""
        ti.loop_config(block_dim=1)
        for level in range(self.levels):
            offset = self.level_table[level][0]
            for i in range(self.n_touched[level]):
                s = self.touched[offset + i]
                sums = self.pass_sums[s]
                if ti.static(self.has_frozen):
                    self.stats[s] += ti.Vector([sums[0] / sums[1], 1.0, sums[2], sums[1] / sums[3]], ti.f64)
                else:
                    self.stats[s] += ti.Vector([sums[0] / sums[1], 1.0, sums[2]], ti.f64)
                self.pass_sums[s] = ti.zero(sums)
            self.n_touched[level] = 0

    # -- the same, for arrays (tests and tools) ------------------------------------------------
    def accumulate(self, pos, area, hits, samples) -> None:
        """One pass from arrays: pos (n, 3), area (pi R^2), hits (uniform-path-equivalent hits
        this pass) and samples (distinct states) of the valid MPs."""
        if len(pos) == 0:
            return
        points = ArrayPoints(pos, area, hits, samples)
        self._accumulate(points, len(pos))
        points.release()

    def density(self, pos) -> np.ndarray:
        """density_at for an array of points; NaN where no level has enough samples yet."""
        rho = np.empty(len(pos))
        if len(pos):
            self._density(np.ascontiguousarray(pos, np.float64), rho)
        return np.where(rho == UNKNOWN, np.nan, rho)

    def frozen_values(self, pos) -> tuple[np.ndarray, np.ndarray]:
        """frozen_at for an array of points: (density, mean MP area), NaN where none is known."""
        out = np.empty((len(pos), 2), np.float32)
        if len(pos):
            self._frozen(np.ascontiguousarray(pos, np.float64), out)
        unknown = out[:, 0] == UNKNOWN
        return np.where(unknown, np.nan, out[:, 0]), np.where(unknown, np.nan, out[:, 1])

    @ti.kernel
    def _frozen(self, pos: ti.types.ndarray(), out: ti.types.ndarray()):
        for j in range(pos.shape[0]):
            v = self.frozen_at(ti.Vector([pos[j, 0], pos[j, 1], pos[j, 2]]))
            out[j, 0] = v[0]
            out[j, 1] = v[1]

    @ti.kernel
    def _accumulate(self, points: ti.template(), n: ti.i32):
        self.accumulate_points(points, n)
        self.close_pass()

    @ti.kernel
    def _density(self, pos: ti.types.ndarray(), rho: ti.types.ndarray()):
        for j in range(pos.shape[0]):
            rho[j] = self.density_at(ti.Vector([pos[j, 0], pos[j, 1], pos[j, 2]]))


@data_oriented
class ArrayPoints:
    """Points given as arrays, in the form accumulate_points reads (tests and tools)."""

    def __init__(self, pos, area, hits, samples):
        n = len(pos)
        f = FieldGroup("cluster-points")
        self.pos = f.vector(3, ti.f64, n, values=np.asarray(pos, np.float64))
        self.values = f.vector(3, ti.f64, n, values=np.stack([area, hits, samples], axis=1).astype(np.float64))
        f.finalize()
        self.fields = f

    def release(self):
        self.fields.release()

    @ti.func
    def cluster_point(self, j):
        v = self.values[j]
        return True, self.pos[j], v[0], v[1], v[2]

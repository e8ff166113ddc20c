"""Spatial hash grid over points with individual radii (SPPM measurement points).

Rebuilt every iteration: cell size = 2 x the largest radius, so each point's ball overlaps
at most 2x2x2 cells; the point is listed in each of them and a query at x visits only the
cell containing x. Build = count per cell (atomics), exclusive prefix sum, fill.
Hash collisions only cost time: callers test the actual distance.
A build may cover only the first `count` points (sppm's camera paths per pass vary, within
fields sized for the most); the table then uses the smallest power of two >= 2 count of its
slots, so that a small pass does not pay for clearing and scanning the largest one's table.
"""
import taichi as ti

from ..runtime import serial_loop
from .fields import FieldGroup
from ..taichi_frontend import data_oriented


@ti.func
def _hash(c) -> ti.u32:
    return (ti.cast(c.x, ti.u32) * ti.u32(73856093)) ^ (ti.cast(c.y, ti.u32) * ti.u32(19349663)) \
        ^ (ti.cast(c.z, ti.u32) * ti.u32(83492791))


@data_oriented
class HashGrid:
    def __init__(self, n_points: int, entries_per_point: int = 8, name: str = "hash-grid"):
        self.n_points = n_points
        size = 1
        while size < 2 * n_points:
            size *= 2
        self.table_size = size
        self.fields = FieldGroup(f"{name}-{n_points}")
        self.cell_count = self.fields.scalar(ti.i32, size)
        self.cell_start = self.fields.scalar(ti.i32, size)
        self.cell_fill = self.fields.scalar(ti.i32, size)
        self.entries = self.fields.scalar(ti.i32, entries_per_point * n_points)
        self.cell_size = self.fields.scalar(ti.f32)
        self.max_radius = self.fields.scalar(ti.f32)
        self.slot_mask = self.fields.scalar(ti.i32)       # slots in use - 1
        self.fields.finalize()

    def release(self):
        self.fields.release()

    def build(self, pos, radius, valid, count: int | None = None):
        """pos (vec3), radius (f32), valid (i32) are fields indexed like the points; only the
        first `count` points (default: all) are read."""
        count = self.n_points if count is None else int(count)
        slots = self.table_slots(count)
        serial = serial_loop(slots)          # few points: the loops on the launching thread
        self._bounds(pos, radius, valid, count, slots, serial)
        self._count(pos, radius, valid, count, serial)
        self._prefix_sum(slots)
        self._fill(pos, radius, valid, count, serial)

    def table_slots(self, count: int) -> int:
        """The slots a build of `count` points uses: the smallest power of two >= 2 count,
        at most the table (slots_for in a kernel)."""
        slots = 1
        while slots < 2 * count and slots < self.table_size:
            slots *= 2
        return slots

    @ti.func
    def cell_of(self, x):
        return ti.floor(x / self.cell_size[None]).cast(ti.i32)

    @ti.func
    def slot(self, cell) -> ti.i32:
        return ti.cast(_hash(cell) & ti.cast(self.slot_mask[None], ti.u32), ti.i32)

    @ti.kernel
    def _bounds(self, pos: ti.template(), radius: ti.template(), valid: ti.template(), count: ti.i32, slots: ti.i32,
                serial: ti.template()):
        self.max_radius[None] = 0.0
        self.slot_mask[None] = slots - 1
        ti.loop_config(serialize=serial)
        for i in range(count):
            if valid[i]:
                ti.atomic_max(self.max_radius[None], radius[i])
        ti.loop_config(serialize=serial)
        for h in range(slots):
            self.cell_count[h] = 0
            self.cell_fill[h] = 0

    @ti.func
    def _slots_of(self, p, r):
        """Distinct table slots of the (at most 8) cells that the ball (p, r) overlaps.
        Two cells of one point can hash to the same slot; listing the point twice there
        would make a query find it twice (a double deposit)."""
        lo = self.cell_of(p - r)
        hi = self.cell_of(p + r)
        slots = ti.Vector([0] * 8, ti.i32)
        n = 0
        for cx, cy, cz in ti.ndrange((lo.x, hi.x + 1), (lo.y, hi.y + 1), (lo.z, hi.z + 1)):
            h = self.slot(ti.Vector([cx, cy, cz]))
            new = True
            for k in range(n):
                if slots[k] == h:
                    new = False
            if new and n < 8:
                slots[n] = h
                n += 1
        return slots, n

    @ti.kernel
    def _count(self, pos: ti.template(), radius: ti.template(), valid: ti.template(), count: ti.i32,
               serial: ti.template()):
        self.cell_size[None] = ti.max(2.0 * self.max_radius[None], 1e-30)
        ti.loop_config(serialize=serial)
        for i in range(count):
            if valid[i]:
                slots, n = self._slots_of(pos[i], radius[i])
                for k in range(n):
                    ti.atomic_add(self.cell_count[slots[k]], 1)

    @ti.kernel
    def _prefix_sum(self, slots: ti.i32):
        self._cell_starts(slots)

    @ti.func
    def _cell_starts(self, slots):
        """cell_start = exclusive prefix sum of cell_count over the first `slots` slots (a
        serial loop; called at a kernel's top level)."""
        ti.loop_config(serialize=True)
        for h in range(slots):
            if h == 0:
                self.cell_start[0] = 0
            else:
                self.cell_start[h] = self.cell_start[h - 1] + self.cell_count[h - 1]

    @ti.kernel
    def _fill(self, pos: ti.template(), radius: ti.template(), valid: ti.template(), count: ti.i32,
              serial: ti.template()):
        ti.loop_config(serialize=serial)
        for i in range(count):
            if valid[i]:
                slots, n = self._slots_of(pos[i], radius[i])
                for k in range(n):
                    h = slots[k]
                    at = ti.atomic_add(self.cell_fill[h], 1)
                    self.entries[self.cell_start[h] + at] = i

    @ti.func
    def candidates(self, x):
        """(first, end) into `entries` for the points that may contain x."""
        h = self.slot(self.cell_of(x))
        first = self.cell_start[h]
        return first, first + self.cell_count[h]


@data_oriented
class PointGrid(HashGrid):
    """Hash grid over points, queried with balls of one radius r (VCM's light vertices).

    Cell size = 2r and each point is listed once, in its own cell; a query at x visits the
    (at most 8) cells that the ball (x, r) overlaps. Building costs one entry per point where
    HashGrid's per-point balls cost up to eight (measured at 512x512, 706k light vertices:
    0.29 s for HashGrid; docs/vcm.md), which pays when every iteration rebuilds the grid."""

    def __init__(self, n_points: int):
        super().__init__(n_points, entries_per_point=1, name="point-grid")
        # Each entry's position beside it, so that a query's distance tests read the cell's
        # points contiguously instead of gathering them from the points' own records.
        self.pos_fields = FieldGroup(f"point-grid-positions-{n_points}")
        self.entry_pos = self.pos_fields.vector(3, ti.f32, n_points)
        self.pos_fields.finalize()

    def release(self):
        super().release()
        self.pos_fields.release()

    def build(self, pos, radius: float, valid, count: int | None = None):
        """Only the first `count` points (default: all) are read, and the table uses the
        smallest power of two >= 2 count of its slots (as HashGrid.build): mbe's store is
        sized for the most camera subpaths per pixel its effort balance may choose."""
        count = self.n_points if count is None else int(count)
        slots = self.table_slots(count)
        self._build(pos, valid, radius, slots, count, serial_loop(slots))

    @ti.func
    def slots_for(self, count):
        """table_slots(count), in a kernel."""
        slots = 1
        while slots < 2 * count and slots < ti.static(self.table_size):
            slots *= 2
        return slots

    @ti.kernel
    def _build(self, pos: ti.template(), valid: ti.template(), radius: ti.f32, slots: ti.i32, count: ti.i32,
               serial: ti.template()):
        self.build_points(pos, valid, radius, slots, count, serial)

    @ti.func
    def build_points(self, pos: ti.template(), valid: ti.template(), radius, slots, count, serial: ti.template()):
        """One launch: the kernel's top-level loops run one after the other (clear, count,
        prefix sum, fill), and every launch costs tens of microseconds on the host, a few per
        cent of a small image's iteration (docs/performance.md); a caller's kernel may build
        in its own launch (methods/vcm.py's index_vertices). serial (few points): the loops
        run on the launching thread (runtime.serial_loop)."""
        self.max_radius[None] = radius
        self.cell_size[None] = ti.max(2.0 * radius, 1e-30)
        self.slot_mask[None] = slots - 1
        ti.loop_config(serialize=serial)
        for h in range(slots):
            self.cell_count[h] = 0
            self.cell_fill[h] = 0
        ti.loop_config(serialize=serial)
        for i in range(count):
            if valid[i]:
                ti.atomic_add(self.cell_count[self.slot(self.cell_of(pos[i]))], 1)
        self._cell_starts(slots)
        ti.loop_config(serialize=serial)
        for i in range(count):
            if valid[i]:
                h = self.slot(self.cell_of(pos[i]))
                at = ti.atomic_add(self.cell_fill[h], 1)
                self.entries[self.cell_start[h] + at] = i
                self.entry_pos[self.cell_start[h] + at] = pos[i]

    @ti.func
    def slots_near(self, x):
        """Distinct table slots of the cells the ball (x, r) overlaps: (slots, count). Every
        point within r of x is listed under exactly one of them."""
        return self._slots_of(x, self.max_radius[None])

    @ti.func
    def slot_range(self, h: ti.i32):
        first = self.cell_start[h]
        return first, first + self.cell_count[h]

"""Storage for one iteration's subpath vertices (kernels/vcm_mis.py's PathVertex), with the
order that makes connections deterministic."""
import taichi as ti

from .fields import FieldGroup
from .vcm_mis import PathVertex
from ..taichi_frontend import data_oriented

# Record (PathVertex and path/index), order and valid flags, point-grid entry, position and
# table share: what one stored vertex costs, for the memory checks.
BYTES_PER_STORED_VERTEX = 96 + 4 + 12 + 12


@data_oriented
class SubpathVertices:
    """The iteration's subpath vertices (vcm: light subpaths, mbe: camera subpaths, `path`
    being the pixel): appended in any order, then ordered by (path, index along the path)
    through `order`, so that a connection finds its paired subpath's vertices in a fixed order
    whatever the thread scheduling. One thread appends each path's vertices."""

    def __init__(self, capacity: int, n_paths: int, name: str = "subpath-vertices"):
        self.capacity = capacity
        f = FieldGroup(f"{name}-{capacity}")
        (self.p, self.ng, self.n, self.wo, self.beta, self.dvcm, self.dvc, self.dvm, self.length, self.bsdf,
         self.path, self.index) = f.interleaved(capacity, [
            (3, ti.f32, None), (3, ti.f32, None), (3, ti.f32, None), (3, ti.f32, None), (3, ti.f32, None),
            (None, ti.f32, None), (None, ti.f32, None), (None, ti.f32, None), (None, ti.i32, None),
            (None, ti.i32, None), (None, ti.i32, None), (None, ti.i32, None)])
        self.valid = f.scalar(ti.i32, capacity)
        self.order = f.scalar(ti.i32, capacity)
        self.path_count = f.scalar(ti.i32, n_paths)
        self.path_start = f.scalar(ti.i32, n_paths)
        self.count = f.scalar(ti.i32)
        f.finalize()
        self.fields = f

    def release(self):
        self.fields.release()

    @ti.func
    def append(self, path: ti.i32, v):
        slot = ti.atomic_add(self.count[None], 1)
        index = ti.atomic_add(self.path_count[path], 1)     # one thread per path: 0, 1, 2, ...
        if slot < self.capacity:
            self.p[slot] = v.p
            self.ng[slot] = v.ng
            self.n[slot] = v.n
            self.wo[slot] = v.wo
            self.beta[slot] = v.beta
            self.dvcm[slot] = v.dvcm
            self.dvc[slot] = v.dvc
            self.dvm[slot] = v.dvm
            self.length[slot] = v.length
            self.bsdf[slot] = v.bsdf
            self.path[slot] = path
            self.index[slot] = index

    @ti.func
    def vertex(self, slot: ti.i32):
        return PathVertex(p=self.p[slot], ng=self.ng[slot], n=self.n[slot], wo=self.wo[slot], beta=self.beta[slot],
                          length=self.length[slot], bsdf=self.bsdf[slot], dvcm=self.dvcm[slot], dvc=self.dvc[slot],
                          dvm=self.dvm[slot])

    @ti.func
    def clear_paths(self, n_paths: ti.i32, serial: ti.template()):
        """Empty the store for paths [0, n_paths), at the top level of the kernel that fills
        it; serial: runtime.serial_loop(n_paths)."""
        self.count[None] = 0
        ti.loop_config(serialize=serial)
        for i in range(n_paths):
            self.path_count[i] = 0

    @ti.func
    def finish_paths(self, n_paths: ti.i32, n, serial: ti.template()):
        """Path starts (a serial prefix sum), then the order and the valid flags of the first
        n slots, at the top level of the kernel that filled the store (its loops run one
        after the other; methods/vcm.py's index_vertices)."""
        ti.loop_config(serialize=True)
        for i in range(n_paths):
            if i == 0:
                self.path_start[0] = 0
            else:
                self.path_start[i] = self.path_start[i - 1] + self.path_count[i - 1]
        # Only the slots in use: the grids read the first `count` only, and mbe's store is
        # sized for the most camera subpaths per pixel its balance may pick (a loop over the
        # whole capacity was half of this kernel's time at 64x64).
        ti.loop_config(serialize=serial)
        for slot in range(n):
            self.order[self.path_start[self.path[slot]] + self.index[slot]] = slot
            self.valid[slot] = 1

"""Batch ray casting against a DeviceScene: used by the BVH tests and the rays/s benchmark;
and a log of the rays a method traces, to time them alone (tools/pt_stages.py)."""
import numpy as np
import taichi as ti

from .device_scene import MISS, TRIANGLE
from .fields import FieldGroup
from ..taichi_frontend import data_oriented


@data_oriented
class RayLog:
    """Every ray DeviceScene.trace is asked for, up to `capacity`, in the order the threads
    reach them. Set as `dscene.ray_log` before the first kernel compiles."""

    def __init__(self, capacity: int):
        self.capacity = capacity
        f = FieldGroup("ray-log")
        self.o = f.vector(3, ti.f32, capacity)
        self.d = f.vector(3, ti.f32, capacity)
        self.tmax = f.scalar(ti.f32, capacity)
        self.any_hit = f.scalar(ti.i32, capacity)
        self.count = f.scalar(ti.i32)
        f.finalize()
        self.fields = f

    @ti.func
    def record(self, o, d, tmax: ti.f32, any_hit: ti.template()):
        k = ti.atomic_add(self.count[None], 1)
        if k < self.capacity:
            self.o[k] = o
            self.d[k] = d
            self.tmax[k] = tmax
            self.any_hit[k] = 1 if ti.static(any_hit) else 0

    def rays(self):
        """(origins, directions, tmax, any_hit) of the recorded rays, as numpy arrays."""
        n = min(int(self.count[None]), self.capacity)
        return (self.o.to_numpy()[:n], self.d.to_numpy()[:n], self.tmax.to_numpy()[:n],
                self.any_hit.to_numpy()[:n].astype(bool))

    def release(self):
        self.fields.release()


@data_oriented
class RayCaster:
    def __init__(self, dscene):
        self.dscene = dscene

    @ti.kernel
    def _cast(self, o: ti.types.ndarray(dtype=ti.math.vec3, ndim=1), d: ti.types.ndarray(dtype=ti.math.vec3, ndim=1),
              tmax: ti.types.ndarray(dtype=ti.f32, ndim=1), t_out: ti.types.ndarray(dtype=ti.f32, ndim=1),
              kind_out: ti.types.ndarray(dtype=ti.i32, ndim=1), prim_out: ti.types.ndarray(dtype=ti.i32, ndim=1),
              any_hit: ti.template()):
        for i in range(o.shape[0]):
            hit = self.dscene.trace(o[i], d[i], tmax[i], any_hit)
            t_out[i] = hit.t
            kind_out[i] = hit.kind
            prim_out[i] = hit.prim

    def cast(self, origins: np.ndarray, dirs: np.ndarray, any_hit: bool = False, tmax: np.ndarray | None = None):
        """Returns (t, kind, prim) per ray within (0, tmax) (default unbounded); prim is the
        scene's triangle or sphere index, -1 on a miss."""
        n = len(origins)
        tmax = np.full(n, np.inf, np.float32) if tmax is None else np.ascontiguousarray(tmax, np.float32)
        t = np.empty(n, np.float32)
        kind = np.empty(n, np.int32)
        prim = np.empty(n, np.int32)
        self._cast(np.ascontiguousarray(origins, np.float32), np.ascontiguousarray(dirs, np.float32),
                   tmax, t, kind, prim, any_hit)
        tri = kind == TRIANGLE
        prim[tri] = self.dscene.bvh.prim_order[prim[tri]]
        prim[kind == MISS] = -1
        return t, kind, prim

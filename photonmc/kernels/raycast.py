"""Batch ray casting against a DeviceScene: used by the BVH tests and the rays/s benchmark."""
import numpy as np
import taichi as ti

from .device_scene import MISS, TRIANGLE


@ti.data_oriented
class RayCaster:
    def __init__(self, dscene):
        self.dscene = dscene

    @ti.kernel
    def _cast(self, o: ti.types.ndarray(dtype=ti.math.vec3, ndim=1), d: ti.types.ndarray(dtype=ti.math.vec3, ndim=1),
              t_out: ti.types.ndarray(dtype=ti.f32, ndim=1), kind_out: ti.types.ndarray(dtype=ti.i32, ndim=1),
              prim_out: ti.types.ndarray(dtype=ti.i32, ndim=1), any_hit: ti.template()):
        for i in range(o.shape[0]):
            hit = self.dscene.trace(o[i], d[i], ti.math.inf, any_hit)
            t_out[i] = hit.t
            kind_out[i] = hit.kind
            prim_out[i] = hit.prim

    def cast(self, origins: np.ndarray, dirs: np.ndarray, any_hit: bool = False):
        """Returns (t, kind, prim) per ray; prim is the scene's triangle or sphere index, -1 on a miss."""
        n = len(origins)
        t = np.empty(n, np.float32)
        kind = np.empty(n, np.int32)
        prim = np.empty(n, np.int32)
        self._cast(np.ascontiguousarray(origins, np.float32), np.ascontiguousarray(dirs, np.float32),
                   t, kind, prim, any_hit)
        tri = kind == TRIANGLE
        prim[tri] = self.dscene.bvh.prim_order[prim[tri]]
        prim[kind == MISS] = -1
        return t, kind, prim

"""Fields allocated together in one SNode tree.

Taichi's CPU backend allows about 512 SNode trees per process, and every field created
after the first kernel launch starts a new tree unless fields are grouped. A scene, a film
or a method therefore allocates all its fields through one FieldGroup (one tree), which
release() frees when the object is no longer needed (e.g. between tests).
"""
import numpy as np
import taichi as ti


class FieldGroup:
    def __init__(self):
        self._builder = ti.FieldsBuilder()
        self._uploads = []
        self._tree = None

    def _place(self, field, shape):
        shape = (shape,) if np.isscalar(shape) else tuple(shape)
        shape = tuple(max(int(s), 1) for s in shape)
        if shape == ():
            self._builder.place(field)
        else:
            axes = (ti.i, ti.ij, ti.ijk, ti.ijkl)[len(shape) - 1]
            self._builder.dense(axes, shape).place(field)
        return field

    def interleaved(self, n: int, specs):
        """Fields of n elements stored element by element (array of structures), for data a
        kernel reads together (a BVH node's bounds and links, a triangle's vertex and edges).
        specs: list of (components or None for a scalar, dtype, values)."""
        fields = []
        for comps, dtype, values in specs:
            f = ti.field(dtype) if comps is None else ti.Vector.field(comps, dtype)
            fields.append(f)
            self._queue(f, values, dtype)
        self._builder.dense(ti.i, max(int(n), 1)).place(*fields)
        return fields

    def scalar(self, dtype, shape=(), values=None):
        f = self._place(ti.field(dtype), shape)
        self._queue(f, values, dtype)
        return f

    def vector(self, n, dtype, shape, values=None):
        f = self._place(ti.Vector.field(n, dtype), shape)
        self._queue(f, values, dtype)
        return f

    def _queue(self, field, values, dtype):
        if values is not None and len(values) > 0:
            np_dtype = {ti.f32: np.float32, ti.f64: np.float64, ti.i32: np.int32, ti.i64: np.int64}[dtype]
            self._uploads.append((field, np.ascontiguousarray(values, dtype=np_dtype)))

    def finalize(self):
        """Allocate the tree and upload queued values; no fields may be added afterwards."""
        self._tree = self._builder.finalize()
        for field, values in self._uploads:
            if field.shape and field.shape[0] != len(values):     # fields of empty arrays keep one slot
                continue
            field.from_numpy(values)
        self._uploads = []

    def release(self):
        if self._tree is not None:
            self._tree.destroy()
            self._tree = None

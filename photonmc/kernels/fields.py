"""Fields allocated together in one SNode tree, and recycled between renders.

Taichi's CPU backend allows about 512 SNode trees per process, and every field created
after the first kernel launch starts a new tree unless fields are grouped. A scene, a film
or a method therefore allocates all its fields through one FieldGroup (one tree), which
release() gives back when the object is no longer needed.

Why recycle: a kernel that reads fields is compiled for those fields (their SNodes are part
of the compiled code and of the offline-cache key), so a second render in the same process
with fresh fields compiles every kernel again: measured 7 s (pt), 12 s (sppm), 30 s
(visibility), 45 s (spatial-tf) per render on 2 cores with a cold cache. A released group
is kept in a small pool instead of destroyed; a new group that asks for the same fields in
the same order (same kind, dtype and shape: the same method on a scene of the same size)
takes the pooled fields, zeroed, and its kernels are found compiled.
"""
from __future__ import annotations

from collections import OrderedDict

import numpy as np
import taichi as ti

from .batch import NP_DTYPES, fill_fields, upload_fields

_BYTES = {ti.f32: 4, ti.f64: 8, ti.i32: 4, ti.i64: 8, ti.u32: 4}
POOL_MAX_GROUPS = 24
POOL_MAX_BYTES = 1 << 31
class _Allocation:
    """One finalized SNode tree with its fields, in the order they were asked for."""

    def __init__(self, tree, specs: tuple, fields: list, nbytes: int):
        self.tree, self.specs, self.fields, self.nbytes = tree, specs, fields, nbytes

    def destroy(self):
        if self.tree is not None:
            # Taichi checks the matrix fields declared since its last compile at the next
            # compile; a destroyed tree's members would be read dangling there (CI saw
            # "Members of the following field have different shapes"). Syncing runs that
            # check now, while the fields are alive, and empties Taichi's list of them.
            ti.sync()
            self.tree.destroy()
            self.tree = None


# Released allocations by (group name, specs), oldest first.
_pool: OrderedDict[tuple, list[_Allocation]] = OrderedDict()


def _pool_take(name: str, first_spec) -> _Allocation | None:
    for key in _pool:
        if key[0] == name and key[1][0] == first_spec:
            allocations = _pool[key]
            alloc = allocations.pop()
            if not allocations:
                del _pool[key]
            return alloc
    return None


def _pool_put(name: str, alloc: _Allocation):
    _pool.setdefault((name, alloc.specs), []).append(alloc)
    _pool.move_to_end((name, alloc.specs))
    while (sum(len(v) for v in _pool.values()) > POOL_MAX_GROUPS
           or sum(a.nbytes for v in _pool.values() for a in v) > POOL_MAX_BYTES):
        key = next(iter(_pool))
        _pool[key].pop(0).destroy()
        if not _pool[key]:
            del _pool[key]


def clear_pool():
    """Destroy every pooled tree (frees their memory; later renders compile afresh)."""
    while _pool:
        _, allocations = _pool.popitem()
        for alloc in allocations:
            alloc.destroy()


def _spec_bytes(spec) -> int:
    kind = spec[0]
    if kind == "interleaved":
        _, n, parts = spec
        return int(n) * sum((c or 1) * _BYTES[d] for c, d in parts)
    _, comps, dtype, shape = spec
    return int(np.prod(shape)) * (comps or 1) * _BYTES[dtype]


class FieldGroup:
    def __init__(self, name: str):
        """`name` says what the group is for (e.g. 'film'): only groups of the same name share
        pooled fields."""
        self.name = name
        self._builder = None
        self._specs = []
        self._new_fields = []       # fields placed in this group's own tree
        self._uploads = []
        self._reused = None         # a pooled allocation whose fields this group hands out
        self._own = None            # this group's own allocation, once finalized
        self._exact_reuse = False

    # -- asking for fields -------------------------------------------------------------
    def _take(self, spec, make):
        """The fields for `spec`: the pooled allocation's next ones while its specs match
        ours, otherwise new ones in this group's own tree."""
        k = len(self._specs)
        if k == 0:
            self._reused = _pool_take(self.name, spec)
        self._specs.append(spec)
        alloc = self._reused
        if alloc is not None and not self._new_fields and k < len(alloc.specs) and alloc.specs[k] == spec:
            return alloc.fields[k]
        if self._builder is None:
            self._builder = ti.FieldsBuilder()
        fields = make(self._builder)
        self._new_fields.append(fields)
        return fields

    def _place(self, builder, field, shape):
        if shape == ():
            builder.place(field)
        else:
            axes = (ti.i, ti.ij, ti.ijk, ti.ijkl)[len(shape) - 1]
            builder.dense(axes, shape).place(field)
        return field

    @staticmethod
    def _shape(shape):
        shape = (shape,) if np.isscalar(shape) else tuple(shape)
        return tuple(max(int(s), 1) for s in shape)

    def interleaved(self, n: int, specs):
        """Fields of n elements stored element by element (array of structures), for data a
        kernel reads together (a BVH node's bounds and links, a triangle's vertex and edges).
        specs: list of (components or None for a scalar, dtype, values)."""
        n = max(int(n), 1)

        def make(builder):
            fields = [ti.field(d) if c is None else ti.Vector.field(c, d) for c, d, _ in specs]
            builder.dense(ti.i, n).place(*fields)
            return fields

        fields = self._take(("interleaved", n, tuple((c, d) for c, d, _ in specs)), make)
        for field, (_, dtype, values) in zip(fields, specs, strict=True):
            self._queue(field, values, dtype)
        return fields

    def scalar(self, dtype, shape=(), values=None):
        shape = self._shape(shape)
        f = self._take(("scalar", None, dtype, shape), lambda b: self._place(b, ti.field(dtype), shape))
        self._queue(f, values, dtype)
        return f

    def vector(self, n, dtype, shape, values=None):
        shape = self._shape(shape)
        f = self._take(("vector", n, dtype, shape), lambda b: self._place(b, ti.Vector.field(n, dtype), shape))
        self._queue(f, values, dtype)
        return f

    def _queue(self, field, values, dtype):
        if values is not None and len(values) > 0:
            self._uploads.append((field, np.ascontiguousarray(values, dtype=NP_DTYPES[dtype])))

    # -- allocation and release ------------------------------------------------------------
    def finalize(self):
        """Allocate (or take over and zero the pooled fields) and upload queued values; no
        fields may be added afterwards."""
        specs = tuple(self._specs)
        reused = self._reused
        # Taichi launches no kernel (the zeroing below) while a builder is unfinalized.
        if self._builder is not None:
            tree = self._builder.finalize()
            nbytes = sum(_spec_bytes(s) for s in specs)
            if reused is None:
                self._own = _Allocation(tree, specs, self._new_fields, nbytes)
            else:
                # Specs diverged from the pooled allocation after a shared prefix: this group
                # keeps both trees and pools neither.
                self._own = _Allocation(tree, (), [], nbytes)
        if reused is not None:
            # Fresh fields start zeroed; recycled ones must too (all of those handed out,
            # also where the specs diverged after a shared prefix).
            n_taken = len(specs) - len(self._new_fields)
            fill_fields((f, 0) for fields in reused.fields[:n_taken]
                        for f in (fields if isinstance(fields, list) else [fields]))
            self._exact_reuse = not self._new_fields and reused.specs == specs
        # Fields of empty arrays keep one slot and are not uploaded.
        upload_fields((field, values) for field, values in self._uploads
                      if not (field.shape and field.shape[0] != len(values)))
        self._uploads = []

    @property
    def nbytes(self) -> int:
        """Bytes of the group's fields (for memory figures)."""
        return sum(_spec_bytes(s) for s in self._specs)

    def release(self):
        """Give the fields back (to the pool when they can serve a later group); the owner
        must not use them afterwards."""
        if self._exact_reuse:
            _pool_put(self.name, self._reused)
        elif self._own is not None and self._reused is None and self._own.specs:
            _pool_put(self.name, self._own)
        else:
            for alloc in (self._own, self._reused):
                if alloc is not None:
                    alloc.destroy()
        self._own = self._reused = None
        self._exact_reuse = False

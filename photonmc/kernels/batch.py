"""Fills, uploads and downloads of many fields in one kernel launch.

`field.fill(v)`, `field.from_numpy(a)` and `field.to_numpy()` compile one small kernel per
field (the field is a template argument): 40-60 of them before a guided method's first
image and about 40 more in its first state save, each costing tens of milliseconds of
compilation with a cold cache. One loop over all the fields' scalars together compiles once
per batch and several times faster (docs/performance.md, "Compile time"). A short batch runs
serially (runtime.serial_loop): handing a loop to the thread pool costs more than it does.
No `from __future__ import annotations` here: Taichi reads the kernels' annotations as objects.
"""
from collections import OrderedDict

import numpy as np
import taichi as ti

from ..runtime import serial_loop
from ..taichi_frontend import data_oriented

NP_DTYPES = {ti.f32: np.float32, ti.f64: np.float64, ti.i32: np.int32, ti.i64: np.int64, ti.u32: np.uint32}

# Fields one batched fill or upload serves per kernel: each is a branch in the loop body,
# unrolled at compile time (Taichi warns beyond 32 unrolled iterations).
BATCH_FIELDS = 24


def _components(field) -> int:
    return field.n * field.m if isinstance(field, ti.MatrixField) else 1


def scalar_count(field) -> int:
    """Scalars in the field, kept on the field object: Taichi's field.shape walks the SNode
    tree in Python, and the per-pass batches ask for it a few dozen times per iteration."""
    size = field.__dict__.get("_photonmc_size")
    if size is None:
        size = field._photonmc_size = int(np.prod(field.shape, dtype=np.int64)) * _components(field)
    return size


@ti.func
def _field_index(f: ti.template(), flat):
    """The field index holding f's scalar number `flat` in numpy's C order (indices, then
    components); the component is flat % _components(f)."""
    rest = flat // ti.static(_components(f))
    idx = ti.Vector([0] * ti.static(len(f.shape)))
    for d in ti.static(range(len(f.shape) - 1, -1, -1)):
        idx[d] = rest % ti.static(f.shape[d])
        rest //= ti.static(f.shape[d])
    return idx


@ti.func
def _set_flat(f: ti.template(), flat, value):
    """f's scalar number `flat` = value."""
    n = ti.static(_components(f))
    idx = _field_index(f, flat)
    if ti.static(n == 1):
        f[idx] = value
    else:
        v = f[idx]
        c = flat % n
        for k in ti.static(range(n)):
            if k == c:
                v[k] = value
        f[idx] = v


@ti.func
def _get_flat(f: ti.template(), flat):
    """f's scalar number `flat`."""
    n = ti.static(_components(f))
    idx = _field_index(f, flat)
    out = ti.cast(0, f.dtype)
    if ti.static(not isinstance(f, ti.MatrixField)):     # a 1-vector still reads as a vector
        out = f[idx]
    else:
        v = f[idx]
        c = flat % n
        for k in ti.static(range(n)):
            if k == c:
                out = v[k]
    return out


@ti.kernel
def _fill_batch(fields: ti.template(), plan: ti.template(), total: ti.i32, serial: ti.template()):
    """plan[k] = (first flat index, scalars, value) of fields[k] in one flat range."""
    ti.loop_config(serialize=serial)
    for j in range(total):
        for k in ti.static(range(len(fields))):
            if ti.static(plan[k][0]) <= j < ti.static(plan[k][0] + plan[k][1]):
                _set_flat(fields[k], j - ti.static(plan[k][0]), ti.static(plan[k][2]))


@ti.kernel
def _upload_batch(fields: ti.template(), plan: ti.template(), data: ti.types.ndarray(), total: ti.i32,
                  serial: ti.template()):
    """plan[k] = (first flat index, scalars) of fields[k] in data."""
    ti.loop_config(serialize=serial)
    for j in range(total):
        for k in ti.static(range(len(fields))):
            if ti.static(plan[k][0]) <= j < ti.static(plan[k][0] + plan[k][1]):
                _set_flat(fields[k], j - ti.static(plan[k][0]), data[j])


@ti.kernel
def _download_batch(fields: ti.template(), plan: ti.template(), data: ti.types.ndarray(), total: ti.i32,
                    serial: ti.template()):
    """plan[k] = (first flat index, scalars) of fields[k] in data."""
    ti.loop_config(serialize=serial)
    for j in range(total):
        for k in ti.static(range(len(fields))):
            if ti.static(plan[k][0]) <= j < ti.static(plan[k][0] + plan[k][1]):
                data[j] = _get_flat(fields[k], j - ti.static(plan[k][0]))


def _batches(items):
    """Runs of at most BATCH_FIELDS fields whose scalars fit one i32 loop."""
    out, run, total = [], [], 0
    for item in items:
        n = scalar_count(item[0])
        if n >= 1 << 31:
            raise ValueError(f"a field of {n} scalars is more than one batched loop indexes (2^31)")
        if run and (len(run) == BATCH_FIELDS or total + n >= 1 << 31):
            out.append(run)
            run, total = [], 0
        run.append(item)
        total += n
    return out + ([run] if run else [])


def fill_fields(pairs) -> None:
    """field.fill(value) for every (field, value) in pairs, in one kernel launch per batch."""
    pairs = [(f, v) for f, v in pairs if scalar_count(f) > 0]
    for batch in _batches(pairs):
        plan, offset = [], 0
        for f, v in batch:
            plan.append((offset, scalar_count(f), float(v) if f.dtype in (ti.f32, ti.f64) else int(v)))
            offset += scalar_count(f)
        _fill_batch(tuple(f for f, _ in batch), tuple(plan), offset, serial_loop(offset))


def upload_fields(pairs) -> None:
    """field.from_numpy(array) for every (field, array) in pairs, one launch per dtype and batch."""
    by_dtype = OrderedDict()
    for f, a in pairs:
        a = np.asarray(a)
        if a.size != scalar_count(f):
            raise ValueError(f"an array of {a.size} values for a field of {scalar_count(f)}")
        by_dtype.setdefault(f.dtype, []).append((f, a))
    for dtype, items in by_dtype.items():
        for batch in _batches(items):
            data = np.concatenate([a.reshape(-1) for _, a in batch]).astype(NP_DTYPES[dtype], copy=False)
            plan, offset = [], 0
            for f, a in batch:
                plan.append((offset, a.size))
                offset += a.size
            _upload_batch(tuple(f for f, _ in batch), tuple(plan), data, offset, serial_loop(offset))


INTEGER_DTYPES = (ti.i32, ti.i64, ti.u32)
FLOAT_DTYPES = (ti.f32, ti.f64)


@data_oriented
class FieldReader:
    """field.to_numpy() for a fixed list of scalar and vector fields, prepared once (a chain
    pass's tallies): integer fields read as int64 and float fields as float64 (exact) into
    two arrays, by `copy` at the top level of a caller's kernel, so that the caller's launch
    also brings its tallies back. Prepared, a read
    passes one object and two arrays where download_fields passes every field and its plan
    as template arguments, whose extraction is most of a small launch's host time."""

    def __init__(self, fields):
        self.fields = tuple(fields)
        for f in self.fields:
            if (isinstance(f, ti.MatrixField) and f.m != 1) or f.dtype not in INTEGER_DTYPES + FLOAT_DTYPES:
                raise ValueError("FieldReader reads scalar and vector fields of i32, i64, u32, f32 or f64")
        self.int_fields = tuple(f for f in self.fields if f.dtype in INTEGER_DTYPES)
        self.float_fields = tuple(f for f in self.fields if f.dtype in FLOAT_DTYPES)
        self.int_plan, self.n_ints = self._plan(self.int_fields)
        self.float_plan, self.n_floats = self._plan(self.float_fields)
        self.serial = serial_loop(max(self.n_ints, self.n_floats))
        # (array 0 ints / 1 floats, start, end, shape, numpy dtype) per field, in `fields` order
        self._slices = []
        taken = [0, 0]
        for f in self.fields:
            a = 0 if f.dtype in INTEGER_DTYPES else 1
            start, n = (self.int_plan, self.float_plan)[a][taken[a]]
            taken[a] += 1
            self._slices.append((a, start, start + n, numpy_shape(f), NP_DTYPES[f.dtype]))

    @staticmethod
    def _plan(fields):
        plan, offset = [], 0
        for f in fields:
            plan.append((offset, scalar_count(f)))
            offset += scalar_count(f)
        return tuple(plan), offset

    def arrays(self):
        """Two arrays for `copy` to fill: (int64, float64)."""
        return np.empty(max(self.n_ints, 1), np.int64), np.empty(max(self.n_floats, 1), np.float64)

    def unpack(self, ints, floats) -> list:
        """The fields' values from the arrays `copy` filled, as field.to_numpy() gives them
        (views of the arrays where the dtype is theirs)."""
        data = (ints, floats)
        return [data[a][start:end].reshape(shape).astype(dtype, copy=False)
                for a, start, end, shape, dtype in self._slices]

    @ti.func
    def copy(self, ints: ti.template(), floats: ti.template()):
        """Every field's values into the arrays (call at a kernel's top level)."""
        if ti.static(self.n_ints > 0):
            ti.loop_config(serialize=ti.static(self.serial))
            for j in range(self.n_ints):
                for k in ti.static(range(len(self.int_fields))):
                    if ti.static(self.int_plan[k][0]) <= j < ti.static(self.int_plan[k][0] + self.int_plan[k][1]):
                        ints[j] = ti.cast(_get_flat(self.int_fields[k], j - ti.static(self.int_plan[k][0])), ti.i64)
        if ti.static(self.n_floats > 0):
            ti.loop_config(serialize=ti.static(self.serial))
            for j in range(self.n_floats):
                for k in ti.static(range(len(self.float_fields))):
                    if ti.static(self.float_plan[k][0]) <= j < ti.static(self.float_plan[k][0] + self.float_plan[k][1]):
                        floats[j] = ti.cast(_get_flat(self.float_fields[k], j - ti.static(self.float_plan[k][0])),
                                            ti.f64)


def numpy_shape(field) -> tuple:
    """The shape field.to_numpy() returns, without compiling its kernel (kept, as scalar_count)."""
    shape = field.__dict__.get("_photonmc_shape")
    if shape is None:
        shape = field._photonmc_shape = tuple(field.shape) + ((field.n,) if isinstance(field, ti.MatrixField) else ())
    return shape


def download_fields(fields) -> list:
    """[field.to_numpy() for field in fields], one launch per dtype and batch."""
    fields = list(fields)
    out = [None] * len(fields)
    by_dtype = OrderedDict()
    for i, f in enumerate(fields):
        if isinstance(f, ti.MatrixField) and f.m != 1:
            raise ValueError("download_fields reads scalar and vector fields, not matrices")
        if scalar_count(f) == 0:
            out[i] = np.zeros(numpy_shape(f), NP_DTYPES[f.dtype])
        else:
            by_dtype.setdefault(f.dtype, []).append((f, i))
    batches = []           # (fields, plan, data)
    for dtype, items in by_dtype.items():
        for batch in _batches(items):
            plan, offset = [], 0
            for f, _ in batch:
                plan.append((offset, scalar_count(f)))
                offset += scalar_count(f)
            batches.append((batch, tuple(plan), np.empty(offset, NP_DTYPES[dtype])))
    for batch, plan, data in batches:
        _download_batch(tuple(f for f, _ in batch), plan, data, data.size, serial_loop(data.size))
    for batch, plan, data in batches:
        for (f, i), (start, n) in zip(batch, plan):
            out[i] = data[start:start + n].reshape(numpy_shape(f)).copy()
    return out

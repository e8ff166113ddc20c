"""Render states: everything a progressive render has computed, saved so that it can be
resumed exactly, merged with independent renders, or moved between machines (docs/resume.md).

What is saved is found, not listed: capture() walks the method object and the photonmc
objects it holds (film, chain pool, clusters...) and takes every Taichi field, NumPy array
and plain value it finds. A class names in TRANSIENT what it rebuilds every iteration
anyway (hash grids, the light-vertex store) and so need not be saved. A value of any other
type is an error at save time, so a method that gains state cannot silently lose it on
resume; the resume-equals-straight tests check the rest (tests/test_state.py).

A state file is a zip (NumPy .npz, uncompressed) of one JSON header and the arrays (large
mostly-zero ones as their non-zero entries). It
holds one or more member renders: one for `photonmc render`, several after `photonmc
merge` or a render on several workers (merge.py). The zip's CRC-32 of every member catches
a corrupt file, its central directory a truncated one; save() writes a temporary file and
renames it over the old one, so an interrupted write never replaces a good state.
"""
from __future__ import annotations

import io
import json
import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import PhotonmcError

FORMAT = "photonmc-render-state"
# 2: sppm's direct term Ld is summed over camera paths, no longer over passes' means (sppm.py)
# 3: mbe's chain film weighs each pass by its camera subpaths per pixel (film.py, weighted films)
# 4: the spatial target's clusters keep their points' mean area (clusters.py)
# 5: ... only where they are frozen (`--spatial-updates epochs`): three statistics otherwise
# 6: the guided methods' pass-length state (visible counts, recorded shares) and the effort
#    balance's shared photon variance (stop 65)
# 7: the pass-length state moved into methods/pass_length.py's BalancedPassLength, which mbe keeps too
# 8: the effort balance keeps each pair's photon-noise scale beside its V_c estimate (stop 69)
# 9: mbe's pass choice keeps whether its measured ratio is settled (fewer twins, stop 70)
FORMAT_VERSION = 9
SCALARS = (bool, int, float, str, type(None))
SKIPPED = ("dscene", "settings", "options")       # given by the job, not computed
SPARSE_MIN_BYTES = 1 << 20


class StateError(PhotonmcError):
    """A state file that cannot be used: corrupt, truncated, or from another scene,
    method or version."""


def _version() -> str:
    from . import __version__
    return __version__


# -- capturing and restoring a method's state ---------------------------------------------------
def _is_field(value) -> bool:
    from taichi.lang.field import Field
    return isinstance(value, Field)


def _is_component(value) -> bool:
    """A photonmc object the method owns (its film, chain pool, clusters): walked into."""
    module = type(value).__module__ or ""
    return module.startswith("photonmc.") and hasattr(value, "__dict__")


def _skipped(name, value) -> bool:
    """Not state: what the job gives, and the field groups (their fields are found through
    the attributes that hold them)."""
    from .kernels.fields import FieldGroup
    return name in SKIPPED or isinstance(value, FieldGroup)


def _plain(value):
    """A JSON-able copy of a plain value, or raise TypeError."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, SCALARS):
        return value
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    raise TypeError


def capture(method) -> tuple[dict, dict]:
    """(plain values, arrays) of the method's whole progressive state, keyed by attribute path."""
    plain, arrays, fields = {}, {}, []
    _capture(method, "", plain, arrays, set(), fields)
    # One kernel per batch of fields instead of one per field (kernels/batch.py): a guided
    # method's first state save compiled about 40 of them, 2 s with a cold cache.
    from .kernels.batch import download_fields
    for (key, _), data in zip(fields, download_fields(f for _, f in fields)):
        arrays[key] = data
    return plain, arrays


def _capture(obj, prefix, plain, arrays, seen, fields):
    seen.add(id(obj))
    transient = set(getattr(type(obj), "TRANSIENT", ()))
    for name, value in vars(obj).items():
        if _skipped(name, value) or name in transient:
            continue
        key = prefix + name
        if _is_field(value):
            fields.append((key, value))
        elif isinstance(value, np.ndarray):
            arrays[key] = value.copy()
        elif _is_component(value):
            if id(value) not in seen:      # back references (a chain source to its pool)
                _capture(value, key + ".", plain, arrays, seen, fields)
        else:
            try:
                plain[key] = _plain(value)
            except TypeError:
                raise TypeError(f"{type(obj).__name__}.{name} holds a {type(value).__name__}, which a render "
                                f"state cannot save: make it a field, an array or a plain value, or list it "
                                f"in {type(obj).__name__}.TRANSIENT if every iteration rebuilds it") from None


def _numpy_shape(field) -> tuple:
    from .kernels.batch import numpy_shape
    return numpy_shape(field)


def restore(method, plain: dict, arrays: dict) -> None:
    """Put a captured state back into a method built with the same settings on the same scene."""
    expected_plain, expected_arrays, uploads = set(), set(), []
    _restore(method, "", plain, arrays, set(), expected_plain, expected_arrays, uploads)
    extra = (set(plain) - expected_plain) | (set(arrays) - expected_arrays)
    missing = (expected_plain - set(plain)) | (expected_arrays - set(arrays))
    if extra or missing:
        raise StateError(f"the state does not fit this method's accumulators "
                         f"(unexpected: {sorted(extra)[:3]}, missing: {sorted(missing)[:3]})")
    from .kernels.batch import upload_fields    # Taichi only where fields are touched
    upload_fields(uploads)


def _restore(obj, prefix, plain, arrays, seen, expected_plain, expected_arrays, uploads):
    seen.add(id(obj))
    transient = set(getattr(type(obj), "TRANSIENT", ()))
    for name, value in list(vars(obj).items()):
        if _skipped(name, value) or name in transient:
            continue
        key = prefix + name
        if _is_field(value):
            expected_arrays.add(key)
            if key in arrays:
                data = arrays[key]
                if tuple(data.shape) != _numpy_shape(value):
                    raise StateError(f"the state's '{key}' has shape {data.shape}, this render's {value.shape}")
                uploads.append((value, data))
        elif _is_component(value):
            if id(value) not in seen:
                _restore(value, key + ".", plain, arrays, seen, expected_plain, expected_arrays, uploads)
        elif key in arrays or isinstance(value, np.ndarray):
            expected_arrays.add(key)
            if key in arrays:
                setattr(obj, name, arrays[key].copy())
        else:
            expected_plain.add(key)
            if key in plain:
                v = plain[key]
                setattr(obj, name, tuple(v) if isinstance(value, tuple) else v)


# -- one render's state ------------------------------------------------------------------------
@dataclass
class RenderState:
    """One render: what was asked (job), where it got to, and its accumulators."""
    job: dict                  # scene, params, method, seed, max_depth, options (loop.Job fields)
    scene_hash: str
    resolution: tuple          # (width, height)
    iterations: int
    work_done: int
    elapsed: float             # render seconds so far (compilation of the first run included)
    image: np.ndarray          # (H, W, 3) float64: the estimate, so merging needs no Taichi
    plain: dict = field(default_factory=dict)
    arrays: dict = field(default_factory=dict)

    @property
    def method(self) -> str:
        return self.job["method"]

    @property
    def seed(self) -> int:
        return int(self.job["seed"])

    def header(self) -> dict:
        return {"job": self.job, "scene_hash": self.scene_hash, "resolution": list(self.resolution),
                "iterations": self.iterations, "work_done": self.work_done, "elapsed": self.elapsed,
                "plain": self.plain, "arrays": sorted(self.arrays)}


def state_of(method, job: dict, scene, elapsed: float) -> RenderState:
    """The render state of a method now (after a whole number of iterations)."""
    plain, arrays = capture(method)
    return RenderState(job=dict(job), scene_hash=scene.fingerprint(),
                       resolution=(method.dscene.width, method.dscene.height), iterations=method.iterations,
                       work_done=method.work_done, elapsed=float(elapsed),
                       image=np.asarray(method.image(), np.float64), plain=plain, arrays=arrays)


def check_fits(state: RenderState, scene, method_name: str, where: str = "the state") -> None:
    if state.method != method_name:
        raise StateError(f"{where} is a '{state.method}' render, not '{method_name}'")
    if state.scene_hash != scene.fingerprint():
        raise StateError(f"{where} was rendered from a different scene than '{scene.path}' "
                         f"(the scene, a mesh or a -D parameter changed since)")


# -- files -------------------------------------------------------------------------------------
def save(path, members: list[RenderState]) -> Path:
    """Write the members atomically: a temporary file beside `path`, fsynced, renamed over it."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as f:
            _write_npz(f, members)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    try:
        dir_fd = os.open(path.parent if str(path.parent) else ".", os.O_RDONLY)
        try:
            os.fsync(dir_fd)
        finally:
            os.close(dir_fd)
    except OSError:
        pass          # some file systems cannot sync a directory; the rename is done
    return path


def to_bytes(members: list[RenderState]) -> bytes:
    """The state file's bytes (how workers send their states to the driver)."""
    buf = io.BytesIO()
    _write_npz(buf, members)
    return buf.getvalue()


def _write_npz(f, members):
    """An .npz (np.load reads it). A large array that is mostly zeros (the spatial target's
    hashed cluster table: 96 MiB at 256x256, nearly all empty) is stored as the indices and
    values of its non-zero entries; the header gives its shape."""
    payload, headers = {}, []
    for k, m in enumerate(members):
        h = m.header()
        h["sparse"] = {}
        payload[f"{k}/image"] = m.image
        for name, a in m.arrays.items():
            a = np.asarray(a)
            if a.nbytes > SPARSE_MIN_BYTES:
                flat = a.reshape(-1)
                index = np.flatnonzero(flat)
                if len(index) < flat.size // 4:
                    h["sparse"][name] = list(a.shape)
                    payload[f"{k}/{name}.index"] = index
                    payload[f"{k}/{name}.values"] = flat[index]
                    continue
            payload[f"{k}/{name}"] = a
        headers.append(h)
    header = {"format": FORMAT, "format_version": FORMAT_VERSION, "photonmc_version": _version(),
              "members": headers}
    np.savez(f, header=np.frombuffer(json.dumps(header).encode(), np.uint8), **payload)


def _dense(z, key: str, shape) -> np.ndarray:
    values = z[f"{key}.values"]
    a = np.zeros(int(np.prod(shape)), values.dtype)
    a[z[f"{key}.index"]] = values
    return a.reshape(shape)


def load(path) -> list[RenderState]:
    path = Path(path)
    if not path.is_file():
        raise StateError(f"render state '{path}' not found")
    with open(path, "rb") as f:
        return from_bytes(f.read(), str(path))


def from_bytes(data: bytes, name: str = "the render state") -> list[RenderState]:
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as z:
            header = json.loads(bytes(z["header"]).decode())
            if header.get("format") != FORMAT:
                raise StateError(f"'{name}' is not a photonmc render state")
            if header.get("format_version") != FORMAT_VERSION or header.get("photonmc_version") != _version():
                raise StateError(f"'{name}' was written by photonmc {header.get('photonmc_version')} "
                                 f"(state format {header.get('format_version')}); this is photonmc {_version()} "
                                 f"(format {FORMAT_VERSION}): resume it with that version")
            members = []
            for k, h in enumerate(header["members"]):
                sparse = h.get("sparse", {})
                arrays = {a: _dense(z, f"{k}/{a}", sparse[a]) if a in sparse else z[f"{k}/{a}"] for a in h["arrays"]}
                members.append(RenderState(job=h["job"], scene_hash=h["scene_hash"],
                                           resolution=tuple(h["resolution"]), iterations=int(h["iterations"]),
                                           work_done=int(h["work_done"]), elapsed=float(h["elapsed"]),
                                           image=z[f"{k}/image"], plain=h["plain"], arrays=arrays))
    except StateError:
        raise
    except (zipfile.BadZipFile, ValueError, KeyError, IndexError, OSError, EOFError, UnicodeDecodeError,
            TypeError) as e:
        raise StateError(f"'{name}' is truncated or corrupt ({type(e).__name__}: {e})") from None
    if not members:
        raise StateError(f"'{name}' holds no render")
    return members

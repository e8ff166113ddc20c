"""The loaded scene as plain numpy arrays, independent of Taichi.

Materials are pairs of BSDF indices (front side, back side); -1 on a side means black,
which is how Mitsuba's one-sided BSDFs behave. BSDF parameters live in small tables.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, field, fields

import numpy as np

# BSDF kinds; kernels specialise on which of them a scene contains.
DIFFUSE, CONDUCTOR, DIELECTRIC = 0, 1, 2
BSDF_NAMES = {DIFFUSE: "diffuse", CONDUCTOR: "conductor", DIELECTRIC: "dielectric"}


@dataclass
class Bsdf:
    kind: int
    color: np.ndarray                  # diffuse reflectance / specular reflectance
    transmittance: np.ndarray = field(default_factory=lambda: np.ones(3))
    eta: float = 1.0                   # interior / exterior index of refraction


@dataclass
class Camera:
    to_world: np.ndarray               # 4x4; local +z forward, +y up, +x left (Mitsuba)
    tan_half: tuple                    # tan of half the field of view along x and y
    width: int
    height: int

    @property
    def origin(self) -> np.ndarray:
        return self.to_world[:3, 3].copy()


@dataclass
class Scene:
    path: str
    camera: Camera
    max_depth: int                     # Mitsuba meaning; -1 = unbounded
    bsdfs: list                        # [Bsdf]
    materials: np.ndarray              # (M,2) int32: front, back bsdf index or -1
    emitter_radiance: np.ndarray       # (E,3)
    tri_vertices: np.ndarray           # (T,3,3) world space
    tri_normals: np.ndarray            # (T,3,3) shading normals per corner
    tri_material: np.ndarray           # (T,) int32
    tri_emitter: np.ndarray            # (T,) int32, -1 if not emitting
    sphere_center: np.ndarray          # (S,3)
    sphere_radius: np.ndarray          # (S,)
    sphere_flip: np.ndarray            # (S,) bool: normals point inward
    sphere_material: np.ndarray        # (S,) int32
    sphere_emitter: np.ndarray         # (S,) int32
    warnings: list = field(default_factory=list)

    @property
    def bounds(self) -> np.ndarray:
        lo = np.full(3, np.inf)
        hi = np.full(3, -np.inf)
        if len(self.tri_vertices):
            lo = np.minimum(lo, self.tri_vertices.reshape(-1, 3).min(0))
            hi = np.maximum(hi, self.tri_vertices.reshape(-1, 3).max(0))
        if len(self.sphere_center):
            lo = np.minimum(lo, (self.sphere_center - self.sphere_radius[:, None]).min(0))
            hi = np.maximum(hi, (self.sphere_center + self.sphere_radius[:, None]).max(0))
        return np.stack([lo, hi])

    @property
    def extent(self) -> float:
        """Diagonal of the bounding box: the length every epsilon is scaled by."""
        lo, hi = self.bounds
        return float(np.linalg.norm(hi - lo))

    def bsdf_kinds(self) -> set:
        return {b.kind for b in self.bsdfs}

    def triangle_areas(self) -> np.ndarray:
        v = self.tri_vertices
        return 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)

    def summary(self) -> str:
        return (f"{len(self.tri_vertices)} triangles, {len(self.sphere_radius)} spheres, "
                f"{len(self.emitter_radiance)} emitters, {self.camera.width}x{self.camera.height}")

    def fingerprint(self) -> str:
        """A hash of everything the renderer sees (geometry, materials, emitters, camera,
        depth), not of the file: a render state (state.py) is refused when the scene it
        was rendered from has changed, however the change was made (file, mesh, -D)."""
        h = hashlib.sha256()
        for f in fields(self):
            if f.name in ("path", "warnings"):
                continue
            h.update(f.name.encode())
            _hash_value(h, getattr(self, f.name))
        return h.hexdigest()


def _hash_value(h, value):
    if isinstance(value, np.ndarray):
        h.update(str((value.dtype.str, value.shape)).encode())
        h.update(np.ascontiguousarray(value).tobytes())
    elif isinstance(value, (list, tuple)):
        h.update(f"[{len(value)}".encode())
        for v in value:
            _hash_value(h, v)
    elif hasattr(value, "__dataclass_fields__"):
        for f in fields(value):
            h.update(f.name.encode())
            _hash_value(h, getattr(value, f.name))
    else:
        h.update(repr(value).encode())

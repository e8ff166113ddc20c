"""Triangle geometry of Mitsuba's mesh shapes: rectangle, cube, and OBJ/PLY files.

Each function returns object-space (vertices (V,3), faces (F,3), vertex normals (V,3) or None);
the loader applies to_world and turns them into world-space triangles.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import SceneError


def rectangle():
    """[-1,1]^2 in the z=0 plane, normal +z (Mitsuba's `rectangle`)."""
    v = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)
    f = np.array([[0, 1, 2], [2, 3, 0]])
    return v, f, np.tile([0.0, 0.0, 1.0], (4, 1))


def cube():
    """[-1,1]^3 with outward face normals: 6 faces of 4 vertices each (Mitsuba's `cube`)."""
    verts, faces, normals = [], [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            n = np.zeros(3)
            n[axis] = sign
            u, w = np.roll(np.eye(3), -axis, axis=0)[1:] * 1.0   # two axes spanning the face
            if sign < 0:
                u, w = w, u                                    # keep counter-clockwise winding outward
            base = len(verts)
            for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                verts.append(n + a * u + b * w)
                normals.append(n)
            faces += [[base, base + 1, base + 2], [base + 2, base + 3, base]]
    return np.array(verts), np.array(faces), np.array(normals)


def load_mesh_file(path: Path, kind: str, where: str):
    """Read an OBJ or PLY through trimesh's format readers, keeping the file's own normals."""
    if not path.is_file():
        raise SceneError(f"{where}: mesh file '{path}' not found")
    import trimesh    # here, not at the top: importing it takes 0.7 s of every first image (docs/performance.md)
    try:
        with open(path, "rb") as fh:
            if kind == "obj":
                text = fh.read().decode("utf-8", errors="replace")
                import io
                loaded = trimesh.exchange.obj.load_obj(io.StringIO(text), skip_materials=True)
                parts = list(loaded.get("geometry", {}).values()) if "geometry" in loaded else [loaded]
            else:
                parts = [trimesh.exchange.ply.load_ply(fh)]
    except SceneError:
        raise
    except Exception as e:  # trimesh raises many kinds on malformed files
        raise SceneError(f"{where}: cannot read mesh '{path}': {e}") from None
    verts, faces, normals = [], [], []
    offset = 0
    for part in parts:
        v = np.asarray(part.get("vertices", np.zeros((0, 3))), float).reshape(-1, 3)
        f = _triangulate(part.get("faces", np.zeros((0, 3))), where, path)
        if f.size == 0:
            continue
        n = part.get("vertex_normals")
        n = None if n is None else np.asarray(n, float).reshape(-1, 3)
        if n is not None and n.shape != v.shape:
            n = None
        verts.append(v)
        faces.append(f + offset)
        normals.append(n)
        offset += len(v)
    if not faces:
        raise SceneError(f"{where}: mesh '{path}' contains no triangles")
    v = np.concatenate(verts)
    f = np.concatenate(faces)
    if f.min() < 0 or f.max() >= len(v):
        raise SceneError(f"{where}: mesh '{path}' has face indices outside its vertex list")
    n = None if any(x is None for x in normals) else np.concatenate(normals)
    return v, f, n


def _triangulate(faces, where, path) -> np.ndarray:
    """Polygons (uniform array or ragged list) to triangles as fans (0, i, i+1)."""
    try:
        arr = np.asarray(faces, np.int64)
    except (ValueError, TypeError):
        arr = None
    if arr is not None and arr.ndim == 2:
        polys = [arr]
    else:
        polys = [np.asarray(p, np.int64)[None] for p in faces]
    tris = []
    for block in polys:
        k = block.shape[1]
        if k < 3:
            raise SceneError(f"{where}: mesh '{path}' has a face with fewer than 3 vertices")
        for i in range(1, k - 1):
            tris.append(block[:, [0, i, i + 1]])
    return np.concatenate(tris) if tris else np.zeros((0, 3), np.int64)


def angle_weighted_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Vertex normals weighted by the corner angle (Thuermer & Wuethrich 1998), as Mitsuba
    computes them for meshes without normals unless `face_normals` is set."""
    normals = np.zeros_like(v)
    p = v[f]                                              # (F,3,3)
    face_n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    length = np.linalg.norm(face_n, axis=1, keepdims=True)
    ok = length[:, 0] > 0
    face_n = np.where(length > 0, face_n / np.where(length > 0, length, 1), 0)
    for corner in range(3):
        e1 = p[:, (corner + 1) % 3] - p[:, corner]
        e2 = p[:, (corner + 2) % 3] - p[:, corner]
        l1 = np.linalg.norm(e1, axis=1)
        l2 = np.linalg.norm(e2, axis=1)
        cos = np.einsum("ij,ij->i", e1, e2) / np.maximum(l1 * l2, 1e-300)
        angle = np.where(ok, np.arccos(np.clip(cos, -1, 1)), 0)
        np.add.at(normals, f[:, corner], face_n * angle[:, None])
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return np.where(length > 0, normals / np.where(length > 0, length, 1), 0)

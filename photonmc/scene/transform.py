"""4x4 affine transforms with Mitsuba 3's conventions (column vectors, angles in degrees)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


def translate(v) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = v
    return m


def scale(v) -> np.ndarray:
    return np.diag([v[0], v[1], v[2], 1.0])


def rotate(axis, angle_deg: float) -> np.ndarray:
    """Rodrigues' rotation about `axis` by `angle_deg`, counter-clockwise looking down the axis.

    Like Mitsuba 3, the axis is used as given: an axis that is not unit length gives a
    matrix that also scales and shears (checked against mitsuba 3.9's Transform4f.rotate)."""
    a = np.asarray(axis, float)
    t = np.radians(angle_deg)
    c, s = np.cos(t), np.sin(t)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    m = np.eye(4)
    m[:3, :3] = c * np.eye(3) + s * k + (1 - c) * np.outer(a, a)
    return m


def matrix(values) -> np.ndarray:
    """Row-major 3x3 or 4x4 matrix as written in Mitsuba's <matrix value="..."/>."""
    v = np.asarray(values, float)
    if v.size == 9:
        m = np.eye(4)
        m[:3, :3] = v.reshape(3, 3)
        return m
    return v.reshape(4, 4)


def coordinate_system(n):
    """Two tangents completing the unit vector n to an orthonormal frame (Duff et al. 2017)."""
    sign = np.copysign(1.0, n[2])
    a = -1.0 / (sign + n[2])
    b = n[0] * n[1] * a
    s = np.array([1 + sign * n[0] ** 2 * a, sign * b, -sign * n[0]])
    t = np.array([b, sign + n[1] ** 2 * a, -n[1]])
    return s, t


def look_at(origin, target, up) -> np.ndarray:
    """Camera-to-world matrix: local +z looks at the target, +y is up and +x is *left* (Mitsuba)."""
    d = np.asarray(target, float) - np.asarray(origin, float)
    if np.linalg.norm(d) == 0:
        raise ValueError("origin and target coincide")
    d /= np.linalg.norm(d)
    up = np.asarray(up, float)
    if np.linalg.norm(up) == 0:
        up = coordinate_system(d)[0]
    left = np.cross(up / np.linalg.norm(up), d)
    if np.linalg.norm(left) < 1e-12:
        raise ValueError("'up' is parallel to the viewing direction")
    left /= np.linalg.norm(left)
    new_up = np.cross(d, left)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, new_up, d, origin
    return m


@dataclass
class Transform:
    """A to_world transform: the 4x4 point matrix and the 3x3 matrix applied to normals.

    The normal matrix is composed step by step as Mitsuba 3 does: each step contributes its
    inverse transpose, except <rotate>, which contributes its own matrix (exact for a unit
    axis; with a non-unit axis Mitsuba's shading normals then differ from the geometric
    ones, and so do ours, so that the same file gives the same image)."""
    m: np.ndarray = field(default_factory=lambda: np.eye(4))
    n: np.ndarray = field(default_factory=lambda: np.eye(3))

    def then(self, step: np.ndarray, normal_step: np.ndarray | None = None) -> Transform:
        if normal_step is None:
            normal_step = np.linalg.inv(step[:3, :3]).T if abs(np.linalg.det(step[:3, :3])) > 0 else np.eye(3)
        return Transform(step @ self.m, normal_step @ self.n)

    def apply_normals(self, nrm: np.ndarray) -> np.ndarray:
        out = nrm @ self.n.T
        length = np.linalg.norm(out, axis=-1, keepdims=True)
        return out / np.where(length > 0, length, 1.0)


def apply_points(m: np.ndarray, p: np.ndarray) -> np.ndarray:
    return p @ m[:3, :3].T + m[:3, 3]



"""4x4 affine transforms with Mitsuba 3's conventions (column vectors, angles in degrees)."""
from __future__ import annotations

import numpy as np


def translate(v) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = v
    return m


def scale(v) -> np.ndarray:
    return np.diag([v[0], v[1], v[2], 1.0])


def rotate(axis, angle_deg: float) -> np.ndarray:
    """Rotation about `axis` by `angle_deg`, counter-clockwise looking down the axis (Rodrigues)."""
    a = np.asarray(axis, float)
    a = a / np.linalg.norm(a)
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


def apply_points(m: np.ndarray, p: np.ndarray) -> np.ndarray:
    return p @ m[:3, :3].T + m[:3, 3]


def apply_normals(m: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Normals transform with the inverse transpose; result normalised."""
    nt = n @ np.linalg.inv(m[:3, :3])
    length = np.linalg.norm(nt, axis=-1, keepdims=True)
    return nt / np.where(length > 0, length, 1.0)

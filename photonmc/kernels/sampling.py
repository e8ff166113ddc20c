"""Sampling warps, local frames and MIS heuristics (pdfs named by measure: _w solid angle)."""
import math

import taichi as ti

vec3 = ti.types.vector(3, ti.f32)
INV_PI = 1.0 / math.pi


@ti.func
def luminance(c) -> ti.f32:
    return 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]


@ti.func
def onb(n):
    """Orthonormal tangents (s, t) for unit n (Duff et al. 2017), matching Mitsuba's frame."""
    sign = 1.0 if n.z >= 0.0 else -1.0
    a = -1.0 / (sign + n.z)
    b = n.x * n.y * a
    s = vec3(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x)
    t = vec3(b, sign + n.y * n.y * a, -n.y)
    return s, t


@ti.func
def to_local(v, s, t, n):
    return vec3(v.dot(s), v.dot(t), v.dot(n))


@ti.func
def to_world(v, s, t, n):
    return v.x * s + v.y * t + v.z * n


@ti.func
def cosine_hemisphere(u1: ti.f32, u2: ti.f32):
    """Direction with pdf_w = cos/pi around +z (concentric disk + lift)."""
    x = 2.0 * u1 - 1.0
    y = 2.0 * u2 - 1.0
    r = 0.0
    phi = 0.0
    if x != 0.0 or y != 0.0:
        if abs(x) > abs(y):
            r = x
            phi = (math.pi / 4.0) * (y / x)
        else:
            r = y
            phi = (math.pi / 2.0) - (math.pi / 4.0) * (x / y)
    dx = r * ti.cos(phi)
    dy = r * ti.sin(phi)
    return vec3(dx, dy, ti.sqrt(ti.max(0.0, 1.0 - dx * dx - dy * dy)))


@ti.func
def uniform_triangle(u1: ti.f32, u2: ti.f32):
    """Barycentrics (b1, b2) uniform over a triangle."""
    su = ti.sqrt(u1)
    return 1.0 - su, u2 * su


@ti.func
def uniform_sphere(u1: ti.f32, u2: ti.f32):
    z = 1.0 - 2.0 * u1
    r = ti.sqrt(ti.max(0.0, 1.0 - z * z))
    phi = 2.0 * math.pi * u2
    return vec3(r * ti.cos(phi), r * ti.sin(phi), z)


@ti.func
def power_heuristic(pdf_a: ti.f32, pdf_b: ti.f32) -> ti.f32:
    """a^2 / (a^2 + b^2) in ratio form: a light sample seen at a grazing angle has a solid-
    angle pdf beyond 1e19 whose square overflows float32 (inf/inf = NaN)."""
    w = 0.0
    if pdf_a > 0.0:
        if pdf_a == ti.math.inf:
            w = 1.0 if pdf_b < ti.math.inf else 0.5
        else:
            r = pdf_b / pdf_a
            w = 1.0 / (1.0 + r * r)
    return w

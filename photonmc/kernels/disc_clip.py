"""The share of a gather disc that lies on its measurement point's surface (`--disc clipped`,
an option of the photon methods; measured, not the default: docs/guiding.md, "Discs that
overhang an edge").

A photon counts at a measurement point (MP) when it lies within the radius R and on a surface
facing alike (kernels/photon.py, NORMAL_COS_MIN), and the MP's estimate divides the photons'
power by the disc's area pi R^2. Where the MP is within R of an edge of its surface (a thin
face, the side of a gap, a corner where a wall rises) part of that disc is not on the surface:
no photon can land there, and the estimate is dark by that part. Averaged over a pixel this
bias goes as R, not R^2, so it is what remains longest of the radius bias.

Here the part on the surface is measured with rays, once per MP and pass, in DIRECTIONS
directions of the tangent plane:
  - a wall in the way: a ray just above the surface along the direction, up to R, stops at it;
  - the surface ending (a convex edge, a gap): a short ray down onto the surface at the end of
    the free stretch finds nothing, and a bisection (BISECTIONS halvings) finds where it ends.
Each direction's free length rho_k stands for its sector, so the share is
sum_k rho_k^2 / (DIRECTIONS R^2), and the estimate divides by pi R^2 x share. The share of the
disc of half the area (the balanced radius rule's probe, methods/sppm.py) comes from the same
rho_k, each cut at R / sqrt(2).

What it leaves: the photons of a clipped disc lie off-centre, toward the surface's inside, so
where the density changes steeply across a thin face (a slit's inner face, lit from one side)
the estimate reads the brighter side. It is consistent all the same: as R -> 0 every interior
point's share tends to 1, and the edges' points are a vanishing part of the image. A share is
not let below SHARE_MIN, so that a probe fooled by a small gap cannot blow an estimate up.
"""
import math

import taichi as ti

from .sampling import onb

DIRECTIONS = 8
BISECTIONS = 4
SHARE_MIN = 0.25
LIFT = 0.05              # the probes run this fraction of R above the surface (at least 4 ray eps)
DROP = 0.25              # and look this fraction of R below it for the surface


@ti.func
def _surface_below(sc: ti.template(), p, n, t, x, lift, R) -> ti.i32:
    hit = sc.trace(p + t * x + n * lift, -n, lift + DROP * R, True)
    return hit.kind >= 0


@ti.func
def disc_shares(sc: ti.template(), p, n, R):
    """(share of the disc of radius R at p, normal n, on its surface; the same for the disc of
    half the area)."""
    lift = ti.max(LIFT * R, 4.0 * sc.ray_eps)
    t1, t2 = onb(n)
    full = 0.0
    inner = 0.0
    for k in range(DIRECTIONS):
        angle = (k + 0.5) * (2.0 * math.pi / DIRECTIONS)
        t = ti.cos(angle) * t1 + ti.sin(angle) * t2
        rho = R
        wall = sc.trace(p + n * lift, t, R, False)
        if wall.kind >= 0:
            rho = 0.98 * wall.t          # the probe down must not start inside the wall
        if not _surface_below(sc, p, n, t, rho, lift, R):
            lo, hi = 0.0, rho
            for _ in range(BISECTIONS):
                mid = 0.5 * (lo + hi)
                if _surface_below(sc, p, n, t, mid, lift, R):
                    lo = mid
                else:
                    hi = mid
            rho = 0.5 * (lo + hi)
        full += rho * rho
        r_inner = ti.min(rho, R * ti.static(1.0 / math.sqrt(2.0)))
        inner += r_inner * r_inner
    return (ti.max(full / (DIRECTIONS * R * R), SHARE_MIN),
            ti.max(inner / (DIRECTIONS * R * R * 0.5), SHARE_MIN))

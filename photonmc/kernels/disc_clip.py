"""The part of a gather disc that lies on its measurement point's surface (`--disc clipped` and
`--disc linear`, options of the photon methods; measured, not the default: docs/guiding.md,
"Discs that overhang an edge" and "Discs fitted to their surface").

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
    the free stretch finds nothing, and halvings then a bisection find where it ends, to
    REL_PRECISION of its own length.
Shortcuts spare rays whose answer the geometry gives (the same shares, tested): a point over
the MP's own flat triangle has the surface under it; one BVH query lists the triangles the
probe rays could meet, which they are then tested against alone; and where none of those
reaches the wall probes' height, no wall probe can hit (docs/guiding.md, "What the probes
cost"). Each direction's free length rho_k stands for its sector, so the share is
sum_k rho_k^2 / (DIRECTIONS R^2), and the estimate divides by pi R^2 x share. The share of the
disc of half the area (the balanced radius rule's probe, methods/sppm.py) comes from the same
rho_k, each cut at R / sqrt(2).

What it leaves: the photons of a clipped disc lie off-centre, toward the surface's inside, so
where the density changes steeply across a thin face (a slit's inner face, lit from one side)
the estimate reads the brighter side. It is consistent all the same: as R -> 0 every interior
point's share tends to 1, and the edges' points are a vanishing part of the image. A share is
not let below SHARE_MIN, so that a probe fooled by a small gap cannot blow an estimate up.

`--disc linear` (disc_linear_fits) turns the same probes into a region: straight edges drawn
through the probed ends, the disc cut by them. Its photons are weighted so that a density
linear across the region is read at the point (_linear_fit), and the gather counts only the
photons inside it (in_region), so light that leaks across a thin wall onto the same plane does
not count either.

`--disc sealed` (disc_walls, behind_wall, wall_shares) runs the wall probes alone: each wall a
probe meets, rising from the surface, is kept as a line (its hit and its normal); the gather
drops the photons behind those lines (light leaking through a partition onto the same floor)
and the estimate divides by the part of the disc in front of them. Open edges cut nothing
(where clipped discs read the bright side of a thin face lit from one side).
"""
import math

import taichi as ti

from .device_scene import MISS, STACK_SIZE, Hit
from .sampling import onb

DIRECTIONS = 8
HALVINGS = 10            # where the surface ends: searched down to R / 2^HALVINGS from p
REL_PRECISION = 1.0 / 16.0
QUADRATURE = 64          # --disc linear: thin sectors integrating the covered region's moments
SHARE_MIN = 0.25
FIT_MIN = 0.25           # --disc linear: the least weighted area a fit may leave (_linear_fit)
REGION_MIN = 0.02        # and the least share of the disc it divides by (its gather counts only the
                         # region's photons, so a small region is not a bias, only noisy)
LIFT = 0.05              # the probes run this fraction of R above the surface (at least 4 ray eps)
DROP = 0.25              # and look this fraction of R below it for the surface
OWN_FACE_COS = 0.9999    # a probe point over the MP's own flat triangle needs no ray (_over_own_triangle),
OWN_FACE_MARGIN = 1e-4   # away from its edges by this much barycentric margin
NEAR_MAX = 16            # probe rays test at most this many triangles found near, else go through the BVH


@ti.func
def _over_own_triangle(sc: ti.template(), tri, n, q, R) -> ti.i32:
    """Whether q lies over the MP's own triangle `tri` (-1: none known), away from its edges and
    within DROP R of its plane: the probe ray down from q would hit it, so it is not traced.
    Large flat faces (walls, floors) answer most of a probe's questions this way."""
    over = 0
    if ti.static(sc.has_triangles):
        if tri >= 0:
            v0, e1, e2 = sc.tri_v0[tri], sc.tri_e1[tri], sc.tri_e2[tri]
            ng = e1.cross(e2)
            area2 = ng.norm()
            if area2 > 0.0:
                ng /= area2
                d = q - v0
                # only where the MP's normal is the face's (a flat face, not a smoothed mesh)
                if ti.abs(ng.dot(n)) >= OWN_FACE_COS and ti.abs(d.dot(ng)) <= DROP * R:
                    d00, d01, d11 = e1.dot(e1), e1.dot(e2), e2.dot(e2)
                    d20, d21 = d.dot(e1), d.dot(e2)
                    det = d00 * d11 - d01 * d01
                    b1 = (d11 * d20 - d01 * d21) / det
                    b2 = (d00 * d21 - d01 * d20) / det
                    over = b1 >= OWN_FACE_MARGIN and b2 >= OWN_FACE_MARGIN and b1 + b2 <= 1.0 - OWN_FACE_MARGIN
    return over


@ti.func
def _probe_ray(sc: ti.template(), near, count, o, d, tmax, any_hit: ti.template()):
    """A probe ray: tested against the `count` triangles in `near` (every triangle it could
    meet, _near_triangles) and the spheres, or traced through the BVH where count < 0 (too
    many near). Both find the same hits: the triangle test is the tracer's own."""
    hit = Hit(t=tmax, kind=MISS, prim=-1, b1=0.0, b2=0.0)
    if count >= 0:
        if ti.static(sc.has_triangles):
            for k in range(count):
                sc._triangle(near[k], o, d, hit)
        if ti.static(sc.has_spheres):
            for i in range(sc.n_spheres):
                sc._sphere(i, o, d, hit)
    else:
        hit = sc.trace(o, d, tmax, any_hit)
    return hit


@ti.func
def _surface_below(sc: ti.template(), p, n, t, x, lift, R, tri, near, count) -> ti.i32:
    """Whether the surface goes on under p + x t: a short ray down onto it, unless the point
    lies over the MP's own triangle."""
    below = _over_own_triangle(sc, tri, n, p + t * x, R)
    if not below:
        below = _probe_ray(sc, near, count, p + t * x + n * lift, -n, lift + DROP * R, True).kind >= 0
    return below


@ti.func
def _box_near(sc: ti.template(), node, c, radius) -> ti.i32:
    gap = ti.max(ti.max(sc.node_min[node] - c, c - sc.node_max[node]), 0.0)
    return gap.norm_sqr() <= radius * radius


@ti.func
def _near_triangles(sc: ti.template(), p, n, lift, R):
    """(the triangles a probe ray could meet, their count or -1 if more than NEAR_MAX, whether
    anything could stop a wall probe): one BVH query instead of a traversal per probe ray.

    Every probe ray stays within R + lift + DROP R of c = p + lift n, so every triangle it can
    hit has its box that near. A wall probe runs at height `lift` along the tangent plane, up
    to R: only a triangle whose box lies within R of c and whose corners straddle that height
    (or a sphere within R) can stop it. Where none does, the DIRECTIONS wall probes would all
    miss and are not traced (in a room most of the surface is such)."""
    c = p + n * lift
    reach = R + lift + DROP * R
    near = ti.Vector([0] * NEAR_MAX, ti.i32)
    count = 0
    walls = 0
    if ti.static(sc.has_spheres):
        for i in range(sc.n_spheres):
            if (sc.sph_center[i] - c).norm() <= sc.sph_radius[i] + R:
                walls = 1
    if ti.static(sc.has_triangles):
        stack = ti.Vector([0] * STACK_SIZE, ti.i32)
        sp = 0
        node = 0
        if not _box_near(sc, 0, c, reach):
            node = -1
        while node >= 0:
            n_leaf = sc.node_count[node]
            if n_leaf > 0:
                first = sc.node_right_or_first[node]
                for j in range(first, first + n_leaf):
                    v0 = sc.tri_v0[j]
                    v1, v2 = v0 + sc.tri_e1[j], v0 + sc.tri_e2[j]
                    gap = ti.max(ti.max(ti.min(ti.min(v0, v1), v2) - c, c - ti.max(ti.max(v0, v1), v2)), 0.0)
                    if gap.norm_sqr() <= reach * reach:
                        if count >= 0 and count < NEAR_MAX:
                            near[count] = j
                            count += 1
                        else:
                            count = -1
                        if gap.norm_sqr() <= R * R:
                            h = ti.Vector([(v0 - p).dot(n), (v1 - p).dot(n), (v2 - p).dot(n)])
                            margin = 0.01 * lift
                            if h.min() <= lift + margin and h.max() >= lift - margin:
                                walls = 1
                node = -1
            else:
                left, right = node + 1, sc.node_right_or_first[node]
                node = -1
                if _box_near(sc, left, c, reach):
                    node = left
                if _box_near(sc, right, c, reach):
                    if node < 0:
                        node = right
                    else:
                        stack[sp] = right
                        sp += 1
            if count < 0 and walls:
                node = -1            # nothing more to learn: every ray goes through the BVH
                sp = 0
            elif node < 0 and sp > 0:
                sp -= 1
                node = stack[sp]
    return near, count, walls


@ti.func
def _extent(sc: ti.template(), p, n, t, R, lift, tri, walls, near, count):
    """How far the surface reaches from p along the tangent direction t, up to R: to a wall
    (probed only where `walls`, _near_triangles), or to where the surface ends, found to within
    REL_PRECISION of its own length (the fit's lines are drawn through these ends, and a
    relative error keeps them true near p too)."""
    rho = R
    if walls:
        wall = _probe_ray(sc, near, count, p + n * lift, t, R, False)
        if wall.kind >= 0:
            rho = 0.98 * wall.t          # the probe down must not start inside the wall
    if not _surface_below(sc, p, n, t, rho, lift, R, tri, near, count):
        hi = rho                      # the surface ends before hi ...
        lo = 0.0
        for _ in range(HALVINGS):     # ... and by halving, after lo
            if _surface_below(sc, p, n, t, 0.5 * hi, lift, R, tri, near, count):
                lo = 0.5 * hi
                break
            hi *= 0.5
        if lo > 0.0:                  # else the surface ends within R / 2^HALVINGS of p
            while hi - lo > REL_PRECISION * hi:
                mid = 0.5 * (lo + hi)
                if _surface_below(sc, p, n, t, mid, lift, R, tri, near, count):
                    lo = mid
                else:
                    hi = mid
        rho = 0.5 * (lo + hi)
    return rho


@ti.func
def _probe_setup(sc: ti.template(), p, n, R, tri, shortcuts: ti.template()):
    """(lift, the MP's triangle, whether walls may be near, the triangles near and their count)
    for _extent. Without `shortcuts` (tests: the reference) every probe is a ray through the
    BVH."""
    lift = ti.max(LIFT * R, 4.0 * sc.ray_eps)
    walls = 1
    own = -1
    near = ti.Vector([0] * NEAR_MAX, ti.i32)
    count = -1
    if ti.static(shortcuts):
        near, count, walls = _near_triangles(sc, p, n, lift, R)
        own = tri
    return lift, own, walls, near, count


@ti.func
def _direction(k, t1, t2):
    """The angle of sector k's centre and its unit direction in the tangent plane."""
    angle = (k + 0.5) * (2.0 * math.pi / DIRECTIONS)
    return angle, ti.cos(angle) * t1 + ti.sin(angle) * t2


@ti.func
def disc_shares(sc: ti.template(), p, n, R, tri, shortcuts: ti.template()):
    """(share of the disc of radius R at p, normal n, on its surface; the same for the disc of
    half the area). `tri`: the MP's triangle (-1: none); `shortcuts`: spare the rays that
    the scene's geometry answers (_over_own_triangle, _near_triangles)."""
    t1, t2 = onb(n)
    lift, own, walls, near, count = _probe_setup(sc, p, n, R, tri, shortcuts)
    full = 0.0
    inner = 0.0
    for k in range(DIRECTIONS):        # not unrolled: the probes are the kernel's largest code
        _, t = _direction(k, t1, t2)
        rho = _extent(sc, p, n, t, R, lift, own, walls, near, count)
        full += rho * rho
        r_inner = ti.min(rho, R * ti.static(1.0 / math.sqrt(2.0)))
        inner += r_inner * r_inner
    return (ti.max(full / (DIRECTIONS * R * R), SHARE_MIN),
            ti.max(inner / (DIRECTIONS * R * R * 0.5), SHARE_MIN))


@ti.func
def _sector_moments(r, c, s):
    """A thin sector of the region (QUADRATURE of them make the disc), of radius r (units of R)
    about the direction (c, s) = (cos, sin) of its angle: its r^2 (the share's sum), and its
    first (u, v) and second (uu, vv, uv) moments about the disc's centre."""
    delta = ti.static(2.0 * math.pi / QUADRATURE)
    r2 = r * r
    first = r2 * r * ti.static(2.0 / 3.0 * math.sin(0.5 * delta))
    second = r2 * r2 * 0.25
    s2 = ti.static(0.5 * math.sin(delta))
    cos2, sin2 = c * c - s * s, 2.0 * c * s
    return ti.Vector([r2, first * c, first * s,
                      second * (0.5 * delta + cos2 * s2),
                      second * (0.5 * delta - cos2 * s2),
                      second * sin2 * s2])


# --disc linear's region: each direction's end, quantised to LEVELS steps of R and packed four
# to a u32, so that the gather (in_region) tests a photon against the very region whose
# moments the fit used.
LEVELS = 255
_COS = [math.cos((k + 0.5) * 2.0 * math.pi / DIRECTIONS) for k in range(DIRECTIONS)]
_SIN = [math.sin((k + 0.5) * 2.0 * math.pi / DIRECTIONS) for k in range(DIRECTIONS)]
WHOLE_DISC = 0xFFFFFFFF   # four ends at the rim


@ti.func
def pack_ends(rhos):
    """The ends rho_k / R (a vector of DIRECTIONS in [0, 1]) as two u32, 8 bits each."""
    packed = ti.Vector([ti.u32(0), ti.u32(0)])
    for k in ti.static(range(DIRECTIONS)):
        level = ti.cast(ti.round(ti.min(ti.max(rhos[k], 0.0), 1.0) * LEVELS), ti.u32)
        packed[k // 4] |= level << ti.u32(8 * (k % 4))
    return packed


@ti.func
def _unpack(packed, k):
    """End k in units of R (1: the surface reaches the rim)."""
    word = packed[0]
    if k >= 4:
        word = packed[1]
    return ti.cast((word >> ti.u32(8 * (k % 4))) & ti.u32(0xFF), ti.f32) / LEVELS


@ti.func
def _end(packed, k):
    """End k as a point of the tangent plane (units of R, the frame of onb(n))."""
    index = (k + DIRECTIONS) % DIRECTIONS
    cos_k, sin_k = ti.Vector(_COS), ti.Vector(_SIN)     # constants: the gather reads six ends a photon
    return _unpack(packed, index) * ti.Vector([cos_k[index], sin_k[index]])


@ti.func
def _edge(packed, k, towards):
    """(outward normal, distance from p) of the edge through end k, which bounds the wedge on
    the `towards` side of it (+1 or -1): drawn through the next cut end away from that wedge,
    else through the one beyond it, else square to direction k."""
    end = _end(packed, k)
    e = end / ti.max(end.norm(), 1e-12)
    found = 0
    for side in ti.static((-1, 1)):
        other = k + side * towards
        far = _end(packed, other)
        if not found and _unpack(packed, (other + DIRECTIONS) % DIRECTIONS) < 1.0:
            along = end - far
            length = along.norm()
            if length > 1e-4:
                normal = ti.Vector([along.y, -along.x]) / length
                if normal.dot(end) < 0.0:
                    normal = -normal              # outward: p is on the surface's side
                if normal.dot(end) > 1e-5:        # not through p (a degenerate pair)
                    e = normal
                    found = 1
    return e, e.dot(end)


@ti.func
def _wedge_edges(packed, k):
    """The edges that bound the wedge from direction k to k + 1: (normal, distance) of end k's
    and of end k + 1's, a distance of 2 (beyond the rim) for an end at the rim."""
    e0, d0 = ti.Vector([1.0, 0.0]), 2.0
    e1, d1 = ti.Vector([1.0, 0.0]), 2.0
    if _unpack(packed, k) < 1.0:
        e0, d0 = _edge(packed, k, 1)
    if _unpack(packed, (k + 1) % DIRECTIONS) < 1.0:
        e1, d1 = _edge(packed, k + 1, -1)
    return e0, d0, e1, d1


@ti.func
def _reach(e0, d0, e1, d1, u):
    """How far from p the region reaches along the unit direction u (units of R), u in a wedge
    bounded by the edges (e0, d0) and (e1, d1): the disc cut by both."""
    reach = 1.0
    c0 = e0.dot(u)
    if c0 > 1e-6:
        reach = ti.min(reach, d0 / c0)
    c1 = e1.dot(u)
    if c1 > 1e-6:
        reach = ti.min(reach, d1 / c1)
    return reach


@ti.func
def in_region(packed, offset_u, offset_v) -> ti.i32:
    """Whether a photon at tangent-plane offset (u, v) from p (units of R, within the disc) lies
    in the region the probes found."""
    inside = 1
    dist = ti.sqrt(offset_u * offset_u + offset_v * offset_v)
    if dist > 1e-6:
        step = 2.0 * math.pi / DIRECTIONS
        angle = ti.atan2(offset_v, offset_u)
        k = ti.cast(ti.floor(angle / step - 0.5), ti.i32)
        k = (k % DIRECTIONS + DIRECTIONS) % DIRECTIONS
        e0, d0, e1, d1 = _wedge_edges(packed, k)
        inside = dist <= _reach(e0, d0, e1, d1, ti.Vector([offset_u, offset_v]) / dist)
    return inside


@ti.func
def _linear_fit(m, cap, t1, t2, R):
    """(share, slope) of the local-linear weight 1 + slope . (x - p) over the covered region
    whose summed _sector_moments are m, in the disc of radius cap (units of R). The weight
    moves the region's weighted centroid back to p, so that a density linear across it is
    read at p (the boundary correction of local-linear density estimation); share is the
    weighted area over the disc's, pi (cap R)^2. A fit that would leave under FIT_MIN of the
    covered area is scaled down to leave FIT_MIN: the variance it adds is about 1 / that."""
    share = m[0] / (QUADRATURE * cap * cap)
    slope = ti.Vector([0.0, 0.0, 0.0])
    m1u, m1v, muu, mvv, muv = m[1], m[2], m[3], m[4], m[5]
    det = muu * mvv - muv * muv
    if share < REGION_MIN:
        share = REGION_MIN          # a sliver: bounded noise for a little bias
    elif det > 1e-12:
        au = -(mvv * m1u - muv * m1v) / det
        av = -(muu * m1v - muv * m1u) / det
        q = -(au * m1u + av * m1v) / (share * math.pi * cap * cap)   # in [0, 1]: the area given up
        lam = 1.0
        if q > 1.0 - FIT_MIN:
            lam = (1.0 - FIT_MIN) / q
        share *= 1.0 - lam * q
        slope = lam * (au * t1 + av * t2) / R
    return share, slope


@ti.func
def disc_linear_fits(sc: ti.template(), p, n, R, tri, shortcuts: ti.template()):
    """`--disc linear`: (share, slope) for the disc of radius R and for the disc of half the
    area (_linear_fit), and the region's packed ends (in_region). A photon at x in the region
    counts 1 + slope . (x - p), and the estimate divides by pi R^2 x share.

    The region's moments need its shape between the probed directions, which eight sectors
    render too coarsely for a fit (errors of 10-30 % near an edge; docs/guiding.md, "Discs fitted
    to their surface"). So each probed end where the surface stops is taken to lie on a straight
    edge, drawn through the next cut end beside it, and the region between two directions is the
    disc cut by the edges of its two ends (_reach): exact for a straight edge, a strip and a
    convex corner, integrated over QUADRATURE thin sectors. The gather counts the photons in that
    region only, so a photon across a wall (a leak) or a gap does not count."""
    t1, t2 = onb(n)
    lift, own, walls, near, count = _probe_setup(sc, p, n, R, tri, shortcuts)
    rhos = ti.Vector([1.0] * DIRECTIONS)
    for k in range(DIRECTIONS):        # not unrolled: the probes are the kernel's largest code
        _, t = _direction(k, t1, t2)
        rhos[k] = _extent(sc, p, n, t, R, lift, own, walls, near, count) / R
    packed = pack_ends(rhos)
    share, slope = 1.0, ti.Vector([0.0, 0.0, 0.0])
    share_inner, slope_inner = 1.0, ti.Vector([0.0, 0.0, 0.0])
    if packed[0] != ti.u32(WHOLE_DISC) or packed[1] != ti.u32(WHOLE_DISC):
        share, slope, share_inner, slope_inner = _region_fits(packed, t1, t2, R)
    return share, slope, share_inner, slope_inner, packed


# --disc sealed: per direction k, the wall its probe met, as (distance, turn) bytes: its hit's
# distance in WALL_LEVELS steps of R (WALL_LEVELS: no wall), and the angle from direction k to
# the wall's normal in the tangent plane, in [-pi/2, pi/2] over WALL_LEVELS steps. Two
# directions to a u32, four u32 per MP.
WALL_LEVELS = 255
NO_WALLS = 0xFFFFFFFF
WALL_COS_MAX = 0.5       # a wall's normal is within 60 degrees of the surface's tangent plane


@ti.func
def disc_walls(sc: ti.template(), p, n, R):
    """`--disc sealed`: the walls that stand within R of p, one per probe direction (the wall
    probes of _extent alone, no search for where the surface ends), packed for behind_wall.
    A photon behind such a wall lands on the same plane, facing the same way (the floor or a
    side wall running on under a partition into a lit room behind it), and the plain gather
    counts it: light leaking through the wall (docs/guiding.md, "Light that leaks through a
    partition"). Each wall is kept as a line (its hit and its normal), not joined to the next
    direction's end as the linear region's edges are: in a room's corner two directions meet
    two walls, and a line drawn between their ends would cut the corner off the disc."""
    t1, t2 = onb(n)
    lift, _, walls, near, count = _probe_setup(sc, p, n, R, -1, True)
    packed = ti.Vector([ti.u32(NO_WALLS)] * 4)
    if walls:
        for k in range(DIRECTIONS):
            angle, t = _direction(k, t1, t2)
            o = p + n * lift
            wall = _probe_ray(sc, near, count, o, t, R, False)
            ng = ti.Vector([0.0, 0.0, 1.0])
            if wall.kind >= 0:
                ng = sc.surface(o, t, wall).ng
            # a wall rises from the surface; what the probe meets facing mostly down onto it
            # (the underside of a sphere resting on the floor) has the surface going on below it
            if wall.kind >= 0 and ti.abs(ng.dot(n)) <= WALL_COS_MAX:
                m = ti.Vector([ng.dot(t1), ng.dot(t2)])
                turn = 0.0
                if m.norm() > 1e-3:
                    turn = ti.atan2(m.y, m.x) - angle        # the normal's angle from direction k
                    turn -= 2.0 * math.pi * ti.round(turn / (2.0 * math.pi))
                    if turn > 0.5 * math.pi:                 # the normal pointing away from p
                        turn -= math.pi
                    elif turn < -0.5 * math.pi:
                        turn += math.pi
                level = ti.cast(ti.min(ti.floor(wall.t / R * WALL_LEVELS), WALL_LEVELS - 1), ti.u32)
                twist = ti.cast(ti.round((turn / math.pi + 0.5) * WALL_LEVELS), ti.u32)
                half = (level | (twist << ti.u32(8))) << ti.u32(16 * (k % 2))
                keep = ti.u32(0xFFFF) << ti.u32(16 * (1 - k % 2))
                packed[k // 2] = (packed[k // 2] & keep) | half
    return packed


@ti.func
def _wall_line(packed, k):
    """(unit normal of the wall direction k's probe met, its distance from p in units of R; 2,
    beyond the rim, where it met none), in the tangent plane."""
    step = ti.static(2.0 * math.pi / DIRECTIONS)
    half = (packed[k // 2] >> ti.u32(16 * (k % 2))) & ti.u32(0xFFFF)
    level = half & ti.u32(0xFF)
    m = ti.Vector([1.0, 0.0])
    d = 2.0
    if level != ti.u32(WALL_LEVELS):
        rho = ti.cast(level, ti.f32) / WALL_LEVELS
        turn = (ti.cast(half >> ti.u32(8), ti.f32) / WALL_LEVELS - 0.5) * math.pi
        normal_angle = (k + 0.5) * step + turn
        m = ti.Vector([ti.cos(normal_angle), ti.sin(normal_angle)])
        d = rho * ti.cos(turn)
    return m, d


@ti.func
def wall_shares(packed):
    """(share of the disc in front of its walls, the same for the disc of half the area): each
    direction's wedge cut by the wall lines of its own and its two neighbouring directions (as
    behind_wall cuts it), integrated over QUADRATURE thin sectors. The estimate divides by
    pi R^2 x share, so that the part of the disc behind a wall (which the gather no longer
    counts) is not counted as dark either."""
    cap = ti.static(1.0 / math.sqrt(2.0))
    fine = ti.static(QUADRATURE // DIRECTIONS)
    step = ti.static(2.0 * math.pi / DIRECTIONS)
    full = 0.0
    inner = 0.0
    for k in range(DIRECTIONS):
        for f in ti.static(range(fine)):
            phi = k * step + (f + 0.5) * ti.static(step / fine)
            u = ti.Vector([ti.cos(phi), ti.sin(phi)])
            reach = 1.0
            for side in ti.static((-1, 0, 1)):
                m, d = _wall_line(packed, (k + side + DIRECTIONS) % DIRECTIONS)
                c = m.dot(u)
                if c > 1e-6:
                    reach = ti.min(reach, ti.max(d, 0.0) / c)
            full += reach * reach
            r_inner = ti.min(reach, cap)
            inner += r_inner * r_inner
    return (ti.max(full / QUADRATURE, SHARE_MIN), ti.max(inner / (QUADRATURE * cap * cap), SHARE_MIN))


@ti.func
def behind_wall(packed, offset_u, offset_v) -> ti.i32:
    """Whether a photon at tangent-plane offset (u, v) from p (units of R) lies behind a wall
    the probes met (disc_walls): beyond the line through the hit, square to the wall's normal,
    of the direction nearest the photon or of either beside it. A wall met obliquely is missed
    by a direction that still has part of its wedge behind it (a wall at R / 2 by the
    directions 67.5 degrees from its normal), and the neighbours' lines cover that part; in a
    corner each wall's line cuts its own side."""
    behind = 0
    if packed[0] != ti.u32(NO_WALLS) or packed[1] != ti.u32(NO_WALLS) or \
            packed[2] != ti.u32(NO_WALLS) or packed[3] != ti.u32(NO_WALLS):
        step = 2.0 * math.pi / DIRECTIONS
        angle = ti.atan2(offset_v, offset_u)
        k = ti.cast(ti.floor(angle / step), ti.i32)          # the nearest direction, (k + 0.5) step
        k = (k % DIRECTIONS + DIRECTIONS) % DIRECTIONS
        for side in ti.static((-1, 0, 1)):
            m, d = _wall_line(packed, (k + side + DIRECTIONS) % DIRECTIONS)
            if offset_u * m.x + offset_v * m.y > d:
                behind = 1
    return behind


@ti.func
def _region_fits(packed, t1, t2, R):
    """disc_linear_fits for a region cut by an edge: its moments integrated, then fitted."""
    cap = ti.static(1.0 / math.sqrt(2.0))
    fine = ti.static(QUADRATURE // DIRECTIONS)
    full = ti.Vector([0.0] * 6)
    inner = ti.Vector([0.0] * 6)
    cos_k, sin_k = ti.Vector(_COS), ti.Vector(_SIN)
    for k in range(DIRECTIONS):        # the wedge from direction k to k + 1
        e0, d0, e1, d1 = _wedge_edges(packed, k)
        for f in ti.static(range(fine)):   # its thin sectors, turned from direction k by phi: no trig
            phi = ti.static((f + 0.5) * 2.0 * math.pi / QUADRATURE)
            c = cos_k[k] * ti.static(math.cos(phi)) - sin_k[k] * ti.static(math.sin(phi))
            s = sin_k[k] * ti.static(math.cos(phi)) + cos_k[k] * ti.static(math.sin(phi))
            r = _reach(e0, d0, e1, d1, ti.Vector([c, s]))
            full += _sector_moments(r, c, s)
            inner += _sector_moments(ti.min(r, cap), c, s)
    share, slope = _linear_fit(full, 1.0, t1, t2, R)
    share_inner, slope_inner = _linear_fit(inner, cap, t1, t2, R)
    return share, slope, share_inner, slope_inner

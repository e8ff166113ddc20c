"""Photon paths (light subpaths) as a pure function of a primary sample vector u in [0,1)^D.

Fixed layout (algorithms.md §0), so that a small change of u gives a nearby path and a
Markov chain can mutate u directly:
    u[0]                light choice (by power)
    u[1], u[2]          point on the light
    u[3], u[4]          emission direction (cosine-weighted about the light's normal)
    u[5+4b .. 8+4b]     bounce b: BSDF direction (2), lobe choice (1), Russian roulette (1)
A `source` object supplies coordinates through `source.get(key, dim)`: a hash for plain
photon tracing, a chain's stored state for MCMC. A `visitor` receives every photon vertex
on a non-delta surface from its `visits_from_segment` on (SPPM: 2, direct light being the
camera side's next-event estimation; VCM: 1) and returns 0 (unused), 1 (used) or 2 (used,
and stop tracing: a visibility test needs no more). Roulette at a vertex survives with the
material's `bsdf.continuation()`, so VCM can include it in reverse pdfs.
trace_photon returns (used, dims): dims bounds the coordinates the path read, which lets a
Markov chain store only that prefix of u.
"""
import math

import taichi as ti

from . import vcm_mis
from .sampling import onb, to_local, to_world

LIGHT_DIMS = 5
BOUNCE_DIMS = 4
MAX_PHOTON_SEGMENTS = 64      # cap for scenes with unbounded max_depth (Russian roulette ends paths first)
# A photon (light vertex) counts at a measurement point (camera vertex) only where their
# surfaces face alike: the photon's normal within ~84 degrees of the point's (mitsuba #145).
NORMAL_COS_MIN = 0.1


def dimensions(max_segments: int) -> int:
    """Length of the primary sample vector for paths of up to max_segments segments."""
    return LIGHT_DIMS + BOUNCE_DIMS * max_segments


@ti.func
def photon_segments(dims: ti.i32) -> ti.i32:
    """Segments a photon path traced, from the coordinates it read (trace_photon's second
    result): LIGHT_DIMS for the first, BOUNCE_DIMS for each scatter after it."""
    return 1 + (dims - LIGHT_DIMS) // BOUNCE_DIMS


def _guided(visitor) -> bool:
    return getattr(visitor, "pss_guide", None) is not None


@ti.func
def trace_photon(sc: ti.template(), source: ti.template(), key, visitor: ti.template(), vkey, max_segments: ti.i32):
    """Trace one photon (light subpath); returns (1 if the visitor used any vertex, coordinates read).

    The visitor's class says what it needs, at compile time: `visits_from_segment` (SPPM: 2,
    direct light being the camera side's; VCM: 1) and `with_mis`: whether the path carries
    the VCM partial sums (kernels/vcm_mis.py, with the visitor's `mis_constants()`), in which
    case it gets the whole vertex, `visit_vertex(vkey, PathVertex)`, instead of
    `visit(vkey, x, n, wi, beta, segments)`."""
    used = 0
    dims = LIGHT_DIMS
    # A visitor with a primary-sample-space guide (kernels/pss_guide.py) reads its paths
    # through the guide's warp, the photon's power divided by the warp's density.
    c = ti.Vector([source.get(key, 0), source.get(key, 1), source.get(key, 2), source.get(key, 3),
                   source.get(key, 4)])
    inv_q = 1.0
    if ti.static(_guided(visitor)):
        for k in ti.static(range(visitor.pss_guide.n_pairs)):
            if ti.static(visitor.pss_guide.dims[k][1] < LIGHT_DIMS):
                x, y, q = visitor.pss_guide.warp(k, c[visitor.pss_guide.dims[k][0]], c[visitor.pss_guide.dims[k][1]])
                c[visitor.pss_guide.dims[k][0]] = x
                c[visitor.pss_guide.dims[k][1]] = y
                inv_q /= q
    em = sc.emit(c[0], c[1], c[2], c[3], c[4])
    d = em.d
    # Power carried: Le cos / emission_pdf_w, with emission_pdf_w = pdf_a cos/pi.
    beta = em.radiance * (math.pi / em.direct_pdf_a) * inv_q
    o = sc.spawn(em.p, em.n, d)
    prev_p = em.p
    m = vcm_mis.SubpathMis(dvcm=0.0, dvc=0.0, dvm=0.0)
    if ti.static(visitor.with_mis):
        m = vcm_mis.light_start(em.direct_pdf_a, em.emission_pdf_w, em.cos_light, visitor.mis_constants())
    segments = 0
    while segments < max_segments:
        hit = sc.trace(o, d, ti.math.inf, False)
        if hit.kind < 0:
            break
        segments += 1
        s = sc.surface(o, d, hit)
        wi = -d                                   # toward where the photon came from
        b, n = sc.side_bsdf(s.material, s.ns, wi)
        if b < 0:
            break
        if ti.static(visitor.with_mis):
            vcm_mis.after_hit(m, (s.p - prev_p).norm_sqr(), n.dot(wi))
        if segments >= ti.static(visitor.visits_from_segment) and not sc.bsdf_is_delta(b):
            v = 0
            if ti.static(visitor.with_mis):
                v = visitor.visit_vertex(vkey, vcm_mis.PathVertex(p=s.p, ng=s.ng, n=n, wo=wi, beta=beta,
                                                                  length=segments, bsdf=b, dvcm=m.dvcm, dvc=m.dvc,
                                                                  dvm=m.dvm))
            else:
                v = visitor.visit(vkey, s.p, n, wi, beta, segments)
            if v > 0:
                used = 1
            if v > 1:         # the visitor has seen enough (e.g. a visibility test)
                break
        if segments >= max_segments:
            break
        base = LIGHT_DIMS + BOUNCE_DIMS * (segments - 1)
        dims = base + BOUNCE_DIMS
        f1, f2 = onb(n)
        s0, s1 = source.get(key, base), source.get(key, base + 1)
        inv_qb = 1.0
        if ti.static(_guided(visitor)):
            for k in ti.static(range(visitor.pss_guide.n_pairs)):
                if ti.static(visitor.pss_guide.dims[k][0] >= LIGHT_DIMS):
                    if base == visitor.pss_guide.dims[k][0]:
                        x, y, qb = visitor.pss_guide.warp(k, s0, s1)
                        s0, s1 = x, y
                        inv_qb = 1.0 / qb
        bs = sc.bsdf_sample(b, to_local(wi, f1, f2, n), s0, s1, source.get(key, base + 2), False)
        if not bs.ok:
            break
        # Roulette by the material's continuation probability (its albedo: the photon's power
        # stays near constant), which depends on the vertex alone, as MIS needs.
        q = sc.bsdf_continuation(b)
        if source.get(key, base + 3) >= q:
            break
        beta *= bs.weight / q * inv_qb
        if ti.static(visitor.with_mis):
            vcm_mis.after_scatter(m, bs.delta, bs.wi.z, bs.pdf_fwd_w * q, bs.pdf_rev_w * q, visitor.mis_constants())
        d = to_world(bs.wi, f1, f2, n)
        o = sc.spawn(s.p, s.ng, d)
        prev_p = s.p
    return used, dims

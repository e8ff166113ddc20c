"""The light-dependent techniques of VCM for one pair of vertices, shared by `vcm` (which
evaluates them from the camera subpath's side) and `mbe` (from the light subpath's side):
light tracing to the camera, connecting a light vertex to a camera vertex, merging them.
Each returns the MIS-weighted contribution before its sample-count normalisation, which the
method applies (docs/vcm.md, docs/mbe.md). A camera vertex comes with its shading frame
(t1, t2, n), its outgoing direction in that frame (wo_l) and its continuation probability q.
"""
import taichi as ti

from . import vcm_mis
from .photon import NORMAL_COS_MIN
from .sampling import onb, to_local, vec3


@ti.func
def camera_frame(sc: ti.template(), cv):
    """Shading frame, outgoing direction and continuation of a stored camera vertex."""
    t1, t2 = onb(cv.n)
    return t1, t2, to_local(cv.wo, t1, t2, cv.n), sc.bsdf_continuation(cv.bsdf)


@ti.func
def light_side(sc: ti.template(), lv, w):
    """Light vertex lv's BSDF toward the unit direction w (out of lv): (w in lv's shading
    frame, the evaluation)."""
    l1, l2 = onb(lv.n)
    w_l = to_local(w, l1, l2, lv.n)
    return w_l, sc.bsdf_evaluate(lv.bsdf, to_local(lv.wo, l1, l2, lv.n), w_l)


@ti.func
def camera_technique(sc: ti.template(), lv, w, w_l, el, dist2: ti.f32, c, with_weights: ti.template(),
                     inv_count: ti.f32):
    """Light tracing's contribution before visibility: lv seen along -w from the camera at
    squared distance dist2, el = light_side(lv, w)."""
    contrib = vec3(0.0)
    if el.f.max() > 0.0:
        camera_pdf_a = vcm_mis.pdf_w_to_a(sc.camera_pdf_w(-w), dist2, w_l.z)
        weight = 1.0
        if ti.static(with_weights):
            q = sc.bsdf_continuation(lv.bsdf)
            weight = vcm_mis.light_trace_weight(lv, camera_pdf_a, el.pdf_rev_w * q, c)
        contrib = lv.beta * el.f * (weight * camera_pdf_a * inv_count)
    return contrib


@ti.func
def connection_technique(sc: ti.template(), cv, wo_l, t1, t2, q: ti.f32, lv, w, w_l, el, dist2: ti.f32, c):
    """A connection's contribution before visibility and without the camera throughput:
    w points from lv to cv at squared distance dist2, el = light_side(lv, w)."""
    contrib = vec3(0.0)
    wi_l = to_local(-w, t1, t2, cv.n)
    ec = sc.bsdf_evaluate(cv.bsdf, wo_l, wi_l)
    if ec.f.max() > 0.0 and el.f.max() > 0.0:
        ql = sc.bsdf_continuation(lv.bsdf)
        camera_fwd_a = vcm_mis.pdf_w_to_a(ec.pdf_fwd_w * q, dist2, w_l.z)
        light_fwd_a = vcm_mis.pdf_w_to_a(el.pdf_fwd_w * ql, dist2, wi_l.z)
        weight = vcm_mis.connection_weight(lv, cv, camera_fwd_a, ec.pdf_rev_w * q, light_fwd_a,
                                           el.pdf_rev_w * ql, c)
        g = ti.abs(wi_l.z * w_l.z) / dist2
        contrib = ec.f * el.f * lv.beta * (weight * g)
    return contrib


@ti.func
def light_to_camera(sc: ti.template(), v, c, with_weights: ti.template(), inv_count: ti.f32):
    """Light tracing (t = 1): light vertex v seen by the camera. Returns (seen, x, y,
    contribution), inv_count being 1 / the number of light subpaths."""
    seen = 0
    px, py = 0, 0
    contrib = vec3(0.0)
    ok, x, y = sc.camera_raster(v.p)
    if ok:
        to_cam = sc.cam_origin - v.p
        dist2 = to_cam.dot(to_cam)
        w = to_cam / ti.sqrt(dist2)
        w_l, e = light_side(sc, v, w)
        contrib = camera_technique(sc, v, w, w_l, e, dist2, c, with_weights, inv_count)
        if contrib.max() > 0.0 and sc.visible(v.p, v.ng, sc.cam_origin, w):
            seen = 1
            px = ti.min(ti.cast(x, ti.i32), sc.width - 1)
            py = ti.min(ti.cast(y, ti.i32), sc.height - 1)
    return seen, px, py, contrib


@ti.func
def can_merge(cv_n, lv_n, lv_wo) -> ti.i32:
    """The light vertex arrives on the camera vertex's side of one surface."""
    return lv_wo.dot(cv_n) > 0.0 and lv_n.dot(cv_n) >= NORMAL_COS_MIN


@ti.func
def merge(sc: ti.template(), cv, wo_l, t1, t2, q: ti.f32, lv, c, normalization: ti.f32):
    """Merging light vertex lv at camera vertex cv (the caller checked the distance, the depth
    and can_merge); normalization = 1 / (pi r^2 N_L)."""
    out = vec3(0.0)
    ev = sc.bsdf_evaluate(cv.bsdf, wo_l, to_local(lv.wo, t1, t2, cv.n))
    if ev.f.max() > 0.0:
        ql = sc.bsdf_continuation(lv.bsdf)
        weight = vcm_mis.merge_weight(lv, cv, ev.pdf_fwd_w * q, ev.pdf_rev_w * ql, c)
        out = cv.beta * ev.f * lv.beta * (weight * normalization)
    return out

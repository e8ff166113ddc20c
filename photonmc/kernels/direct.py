"""Next-event estimation: direct light at a non-delta vertex by sampling an emitter."""
import taichi as ti

from . import rng
from .sampling import power_heuristic, to_local, vec3


@ti.func
def next_event(sc: ti.template(), p, ng, b: ti.i32, wo_l, n, t1, t2, state: ti.template(), use_mis: ti.template()):
    """Radiance reflected toward wo by light arriving straight from a sampled emitter point.

    With use_mis the sample is weighted by the power heuristic against BSDF sampling
    (the caller then counts BSDF-sampled emitter hits with the complementary weight);
    without, it is the plain light-sampling estimator."""
    contrib = vec3(0.0)
    ls = sc.sample_light(rng.next_float(state), rng.next_float(state), rng.next_float(state))
    to_l = ls.p - p
    dist2 = to_l.dot(to_l)
    if dist2 > 0.0:
        dist = ti.sqrt(dist2)
        wi = to_l / dist
        cos_l = -wi.dot(ls.n)
        wi_l = to_local(wi, t1, t2, n)
        if cos_l > 0.0:
            e = sc.bsdf_evaluate(b, wo_l, wi_l)
            f = e.f
            if f.max() > 0.0:
                if sc.visible(p, ng, ls.p, ls.n):
                    pdf_light_w = ls.pdf_a * dist2 / cos_l
                    w = 1.0
                    if ti.static(use_mis):
                        w = power_heuristic(pdf_light_w, e.pdf_fwd_w)
                    contrib = f * ti.abs(wi_l.z) * ls.radiance * (w / pdf_light_w)
    return contrib

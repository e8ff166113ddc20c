"""The one camera walk: a path from the camera, shared by pt, sppm and vcm.

The walk traces, finds the surface and its BSDF side, samples the next direction in radiance
mode, plays Russian roulette and spawns the next ray. What a method does along the way is
its visitor's (the method object, passed as a template, with `acc` its per-path
accumulators):
- `on_surface(acc, walk, s, wo)` at every surface hit, before anything else (emitter hits);
- `at_vertex(acc, walk, s, b, n, t1, t2, wo, wo_l, state) -> CONTINUE | STOP` at every non-delta
  vertex within max_depth (next-event estimation, connections, merging, measurement points);
- `after_scatter(acc, walk, bs, q)` once the next direction survived roulette (VCM's MIS
  bookkeeping; q is the continuation probability it survived, 1 where none was played).
The visitor's class chooses the roulette, at compile time (`roulette`):
- THROUGHPUT_ROULETTE: from RR_DEPTH segments on, survive with min(|beta| eta^2, 0.95)
  (pt, sppm: a path's roulette may depend on the whole path where no reverse pdf needs it);
- MATERIAL_ROULETTE: at every vertex with `bsdf.continuation()` (vcm: it enters reverse
  pdfs, so it may depend on the vertex alone).
Depth follows Mitsuba's max_depth: the walk stops after a hit at max_depth segments.
"""
import taichi as ti

from . import rng
from .device_scene import MISS
from .sampling import onb, to_local, to_world, vec3

CONTINUE, STOP = 0, 1
THROUGHPUT_ROULETTE, MATERIAL_ROULETTE = 0, 1
RR_DEPTH = 5

# What the walk knows of its path: throughput, segments so far, the previous vertex itself
# (not the offset ray origin), distance travelled, whether every bounce so far was delta, the
# last bounce's forward pdf and delta flag, and the product of relative IORs crossed.
WalkState = ti.types.struct(beta=vec3, length=ti.i32, prev_p=vec3, travelled=ti.f32, specular=ti.i32,
                            last_pdf_w=ti.f32, last_delta=ti.i32, eta_scale=ti.f32)


@ti.func
def camera_walk(sc: ti.template(), o, d, state: ti.template(), max_depth: ti.i32, visitor: ti.template(),
                acc: ti.template()):
    w = WalkState(beta=vec3(1.0), length=0, prev_p=o, travelled=0.0, specular=1, last_pdf_w=0.0, last_delta=1,
                  eta_scale=1.0)
    while True:
        hit = sc.trace(o, d, ti.math.inf, False)
        if hit.kind == MISS:
            break
        w.length += 1
        w.travelled += hit.t
        s = sc.surface(o, d, hit)
        wo = -d
        visitor.on_surface(acc, w, s, wo)
        if w.length >= max_depth:
            break
        b, n = sc.side_bsdf(s.material, s.ns, wo)
        if b < 0:
            break               # back side of a one-sided BSDF: black
        t1, t2 = onb(n)
        wo_l = to_local(wo, t1, t2, n)
        if not sc.bsdf_is_delta(b):
            if visitor.at_vertex(acc, w, s, b, n, t1, t2, wo, wo_l, state) == STOP:
                break
        bs = sc.bsdf_sample(b, wo_l, rng.next_float(state), rng.next_float(state), rng.next_float(state), True)
        if not bs.ok:
            break
        q = 1.0
        if ti.static(visitor.roulette == MATERIAL_ROULETTE):
            q = sc.bsdf_continuation(b)
            if rng.next_float(state) >= q:
                break
            w.beta *= bs.weight / q
        else:
            w.beta *= bs.weight
            w.eta_scale *= bs.eta
            if w.beta.max() <= 0.0:
                break
            if w.length >= RR_DEPTH:
                q = ti.min(w.beta.max() * w.eta_scale * w.eta_scale, 0.95)
                if rng.next_float(state) >= q:
                    break
                w.beta /= q
        visitor.after_scatter(acc, w, bs, q)
        w.specular &= bs.delta
        w.last_pdf_w = bs.pdf_fwd_w
        w.last_delta = bs.delta
        d = to_world(bs.wi, t1, t2, n)
        o = sc.spawn(s.p, s.ng, d)
        w.prev_p = s.p

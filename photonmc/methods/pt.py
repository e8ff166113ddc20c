"""Unidirectional path tracing with next-event estimation and MIS: the reference method.

Each iteration traces one path per pixel. Emission found by BSDF sampling and by emitter
sampling is combined with the power heuristic (Veach 1997, eq. 9.13); delta bounces
(mirror, glass) see emitters with weight 1. Depth follows Mitsuba's `max_depth`: a path
of k segments contributes iff k <= max_depth. Russian roulette from `rr_depth` on divides
by the survival probability, so it changes noise, not the expectation.
"""

import taichi as ti

from ..film import Film
from ..kernels import rng
from ..kernels.device_scene import MISS, UNBOUNDED_DEPTH, DeviceScene
from ..kernels.direct import next_event
from ..kernels.sampling import onb, power_heuristic, to_local, to_world, vec3
from .base import Method, MethodSettings

RR_DEPTH = 5


@ti.data_oriented
class PathTracer(Method):
    name = "pt"
    work_unit = "samples"

    def __init__(self, dscene: DeviceScene, settings: MethodSettings):
        super().__init__(dscene, settings)
        self.film = Film(dscene.width, dscene.height)
        depth = dscene.max_depth if settings.max_depth is None else settings.max_depth
        self.max_depth = UNBOUNDED_DEPTH if depth == -1 else depth

    def _iterate(self):
        self._trace_pixels(self.seed_u32, self.iterations, self.max_depth)
        self.film.samples_per_pixel += 1
        self.work_done += self.dscene.width * self.dscene.height

    def image(self):
        return self.film.mean()

    def release(self):
        self.film.release()

    def _reset(self):
        self.film.reset()

    def standard_error(self):
        return self.film.standard_error()

    def method_stats(self) -> dict:
        return {"samples_per_pixel": self.film.samples_per_pixel, "nonfinite_samples_dropped": self.film.dropped()}

    @ti.kernel
    def _trace_pixels(self, seed: ti.u32, iteration: ti.u32, max_depth: ti.i32):
        for y, x in ti.ndrange(self.dscene.height, self.dscene.width):
            state = rng.seed(seed, ti.u32(y * self.dscene.width + x), iteration)
            o, d = self.dscene.camera_ray(x, y, rng.next_float(state), rng.next_float(state))
            self.film.add(y, x, self.radiance(o, d, state, max_depth))

    @ti.func
    def radiance(self, o, d, state: ti.template(), max_depth: ti.i32):
        sc = self.dscene
        L = vec3(0.0)
        beta = vec3(1.0)
        prev_pdf_w = 0.0
        prev_delta = 1          # the camera "bounce": emitters seen directly get weight 1
        eta_scale = 1.0         # product of relative IORs crossed, undone for roulette
        depth = 0               # segments traced so far
        prev_p = o              # the previous vertex itself, not the offset ray origin
        while True:
            hit = sc.trace(o, d, ti.math.inf, False)
            if hit.kind == MISS:
                break
            depth += 1
            s = sc.surface(o, d, hit)
            wo = -d
            le = sc.emitted(s.emitter, s.ns, wo)
            if le.max() > 0.0:
                w = 1.0
                if not prev_delta:
                    # Distance from the vertex, not from the offset origin: otherwise the
                    # two MIS weights of a path do not sum to one (a bias of order eps/dist).
                    cos_l = ti.abs(s.ns.dot(wo))
                    dist2 = (s.p - prev_p).norm_sqr()
                    pdf_light_w = s.light_pdf_a * dist2 / ti.max(cos_l, 1e-12)
                    w = power_heuristic(prev_pdf_w, pdf_light_w)
                L += beta * le * w
            if depth >= max_depth:
                break
            b, n = sc.side_bsdf(s.material, s.ns, wo)
            if b < 0:
                break           # back side of a one-sided BSDF: black
            t1, t2 = onb(n)
            wo_l = to_local(wo, t1, t2, n)
            if not sc.bsdf_is_delta(b):
                L += beta * next_event(sc, s.p, s.ng, b, wo_l, n, t1, t2, state, True)
            bs = sc.bsdf_sample(b, wo_l, rng.next_float(state), rng.next_float(state),
                                rng.next_float(state), True)
            if not bs.ok:
                break
            d = to_world(bs.wi, t1, t2, n)
            beta *= bs.weight
            eta_scale *= bs.eta
            prev_pdf_w = bs.pdf_fwd_w
            prev_delta = bs.delta
            if beta.max() <= 0.0:
                break
            if depth >= RR_DEPTH:
                q = ti.min(beta.max() * eta_scale * eta_scale, 0.95)
                if rng.next_float(state) >= q:
                    break
                beta /= q
            o = sc.spawn(s.p, s.ng, d)
            prev_p = s.p
        return L

"""Unidirectional path tracing with next-event estimation and MIS: the reference method.

Each iteration traces one path per pixel. Emission found by BSDF sampling and by emitter
sampling is combined with the power heuristic (Veach 1997, eq. 9.13); delta bounces
(mirror, glass) see emitters with weight 1. Depth follows Mitsuba's `max_depth`: a path
of k segments contributes iff k <= max_depth. Russian roulette from RR_DEPTH segments on
divides by the survival probability, so it changes noise, not the expectation. The path is
the shared camera walk (kernels/camera_walk.py); this module says what happens at its
surfaces and vertices.
"""

import taichi as ti

from ..film import Film
from ..kernels import pixel_samples, rng
from ..kernels.camera_walk import CONTINUE, THROUGHPUT_ROULETTE, camera_walk
from ..kernels.device_scene import UNBOUNDED_DEPTH, DeviceScene
from ..kernels.direct import next_event
from ..kernels.sampling import power_heuristic, vec3
from .base import Method, MethodSettings
from ..taichi_frontend import data_oriented

Radiance = ti.types.struct(L=vec3)


@data_oriented
class PathTracer(Method):
    name = "pt"
    work_unit = "samples"
    independent_iterations = True

    OPTIONS = {"pixel_samples": "sobol"}

    def __init__(self, dscene: DeviceScene, settings: MethodSettings):
        super().__init__(dscene, settings)
        self.sobol_pixels = pixel_samples.uses_sobol(self.options)
        self.film = Film(dscene.width, dscene.height)
        depth = dscene.max_depth if settings.max_depth is None else settings.max_depth
        self.max_depth = UNBOUNDED_DEPTH if depth == -1 else depth

    def _iterate(self):
        self._trace_pixels(self.seed_u32, self.iteration_index, self.max_depth)
        self.film.count_samples()
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
            pixel = ti.u32(y * self.dscene.width + x)
            state = rng.seed(seed, pixel, iteration)
            # one sample per pixel per iteration: replicate iteration % 2, its point iteration // 2
            # (pixel_samples.iteration_points)
            u1, u2 = pixel_samples.pixel_sample(self.sobol_pixels, seed, pixel, iteration >> ti.u32(1),
                                                iteration & ti.u32(1), ti.u32(0), state)
            o, d = self.dscene.camera_ray(x, y, u1, u2)
            acc = Radiance(L=vec3(0.0))
            camera_walk(self.dscene, o, d, state, max_depth, self, acc)
            self.film.add(y, x, acc.L)

    # -- the camera walk's visitor (kernels/camera_walk.py) ----------------------------
    roulette = THROUGHPUT_ROULETTE

    @ti.func
    def on_surface(self, acc: ti.template(), w, s, wo):
        """Emission found by BSDF sampling, weighted against light sampling; delta bounces
        (and the camera) see emitters with weight 1."""
        le = self.dscene.emitted(s.emitter, s.ns, wo)
        if le.max() > 0.0:
            weight = 1.0
            if not w.last_delta:
                # Distance from the vertex, not from the offset origin: otherwise the
                # two MIS weights of a path do not sum to one (a bias of order eps/dist).
                cos_l = ti.abs(s.ns.dot(wo))
                dist2 = (s.p - w.prev_p).norm_sqr()
                pdf_light_w = s.light_pdf_a * dist2 / ti.max(cos_l, 1e-12)
                weight = power_heuristic(w.last_pdf_w, pdf_light_w)
            acc.L += w.beta * le * weight

    @ti.func
    def at_vertex(self, acc: ti.template(), w, s, b: ti.i32, n, t1, t2, wo, wo_l, state: ti.template()) -> ti.i32:
        acc.L += w.beta * next_event(self.dscene, s.p, s.ng, b, wo_l, n, t1, t2, state, True)
        return CONTINUE

    @ti.func
    def after_scatter(self, acc: ti.template(), w, bs, q: ti.f32):
        pass

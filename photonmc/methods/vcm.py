"""Vertex connection and merging (Georgiev et al. 2012; docs/vcm.md).

Each iteration:
1. light pass: `--light-paths` light subpaths (N_L) from the emitters, traced by the photon
   tracer with the MIS partial sums (kernels/vcm_mis.py); every non-delta vertex is stored
   and, where light tracing is on, connected to the camera and splatted to its pixel;
2. the stored vertices are put in path order (for connections) and in a hash grid of the
   iteration's radius r_i = r_1 i^((alpha-1)/2) (for merging);
3. camera pass: one subpath per pixel; at every vertex emitter hits, at every non-delta
   vertex next-event estimation, connections to the vertices of the light subpath with the
   pixel's index, and merging with the light vertices within r_i;
4. the iteration's frame (fixed point, SplatFilm) becomes one sample of every pixel.
All contributions are weighted by the balance heuristic over every enabled technique.

Techniques (`--techniques`, SmallVCM's variants, one estimator with static flags):
vcm (all), bpt (no merging), bpm (merging only; emitters seen through delta chains),
lt (light tracing only, plus emitters seen directly: it cannot see through mirrors or glass).
"""
import math

import numpy as np
import taichi as ti

from ..errors import SettingsError
from ..runtime import serial_loop
from ..film import SplatFilm
from ..kernels import pixel_samples, rng, vcm_mis
from ..kernels.camera_walk import CONTINUE, MATERIAL_ROULETTE, camera_walk
from ..kernels.device_scene import UNBOUNDED_DEPTH
from ..kernels.fields import FieldGroup
from ..kernels.hashgrid import PointGrid
from ..kernels.photon import MAX_PHOTON_SEGMENTS, photon_segments, trace_photon
from ..kernels.sampling import to_local, vec3
from ..kernels.subpath_store import BYTES_PER_STORED_VERTEX, SubpathVertices
from ..kernels.vcm_mis import MisConstants, PathVertex
from ..metrics import mean_luminance
from ..kernels import vcm_techniques
from .base import Method
from .light_balance import LightPathBalance
from . import merge_radius
from .merge_radius import MergeRadius
from .sppm import HashSource
from ..taichi_frontend import data_oriented

# name -> (connections incl. next-event estimation, merging, light tracing)
TECHNIQUES = {"vcm": (True, True, True), "bpt": (True, False, True), "bpm": (False, True, False),
              "lt": (False, False, True)}
DEFAULT_RADIUS_PIXELS = 2.0      # r_1: pixel footprints at the median distance of the first hits
INITIAL_VERTICES_PER_PATH = 4    # light-vertex storage per light subpath; grows when exceeded
MAX_STORE_BYTES = 8 << 30        # refuse (a clear error) rather than fail to allocate
PI = math.pi
# One camera subpath's accumulators and the iteration's settings it needs at its vertices.
# work: its non-delta vertices, connection attempts, merge candidates (the light-path balance's cost).
# merged_inner: merging with the inner half of the disc's area only (Vcm.merging_bias).
CameraSubpath = ti.types.struct(L=vec3, merged=ti.types.vector(3, ti.i64), merged_inner=ti.types.vector(3, ti.i64),
                                m=vcm_mis.SubpathMis, subpath=ti.i32, max_depth=ti.i32, vm_normalization=ti.f32,
                                work=ti.types.vector(3, ti.i32))


@data_oriented
class Vcm(Method):
    name = "vcm"
    work_unit = "paths"
    default_iterations = 64
    independent_iterations = True     # the radius is r_1 i^((alpha-1)/2) of the index i alone (fixed --light-paths)
    balances_light_paths = True       # --light-paths auto (the default); mbe's --light-paths are chain steps
    OPTIONS = {"light_paths": None, "alpha": 0.75, "radius": None, "radius_pixels": DEFAULT_RADIUS_PIXELS,
               "radius_rule": "balanced", "techniques": "vcm", "light_vertex_capacity": None, "measure_passes": False, "pixel_samples": "sobol"}
    # The light vertices and their grid live for one iteration (state.py does not save them).
    TRANSIENT = ("store", "grid")
    # What trace_photon hands this visitor: every non-delta vertex, with the MIS partial sums.
    visits_from_segment = 1
    with_mis = True
    # Its film takes each pass at the weight of its camera subpaths per pixel (film.py): one here
    weighted_film = False
    # Each pass also merges with the inner half of the disc's area, for the estimate of
    # merging's bias (merging_bias in --stats). mbe's camera side merges nothing.
    measures_merging_bias = True

    def __init__(self, dscene, settings):
        super().__init__(dscene, settings)
        opts = self.options
        w, h = dscene.width, dscene.height
        self.n_pixels = w * h
        self.sobol_pixels = pixel_samples.uses_sobol(opts)
        # --light-paths auto (vcm's default): as many light subpaths per pass as the pass is worth,
        # measured (methods/light_balance.py); a number fixes them.
        light_paths = opts["light_paths"]
        if light_paths == "auto" and not self.balances_light_paths:
            raise SettingsError(f"--light-paths auto is vcm's; {self.name} takes a number (its chain steps per pass)")
        self.balance = None
        if self.balances_light_paths and light_paths in (None, "auto"):
            self.n_light = self.n_pixels        # the most a pass traces: the store is sized for them
            self.balance = LightPathBalance(self.n_pixels)
        else:
            self.n_light = int(self.n_pixels if light_paths is None else light_paths)
        # Passes measured for a balance: this one's, or mbe's for its vcm passes (measure_passes).
        self.balanced = self.balance is not None or bool(opts.get("measure_passes"))
        # A balanced render's passes depend on the ones before: its iterations are not independent.
        self.independent_iterations = self.balance is None
        if not 1 <= self.n_light <= 1 << 26:
            raise SettingsError(f"--light-paths must be between 1 and 2^26, got {self.n_light}")
        self.alpha = float(opts["alpha"])
        if not 0.0 < self.alpha <= 1.0:
            raise SettingsError(f"--alpha must be in (0, 1] for {self.name} (1 keeps the radius fixed), got {self.alpha}")
        if opts["radius"] is not None and not (0 < opts["radius"] < math.inf):
            raise SettingsError(f"--radius must be a positive length, got {opts['radius']}")
        self.techniques = opts.get("techniques", "vcm")      # mbe: always every technique
        if self.techniques not in TECHNIQUES:
            raise SettingsError(f"unknown --techniques '{self.techniques}' (choose from {', '.join(TECHNIQUES)})")
        self.use_vc, self.use_vm, self.use_lt = TECHNIQUES[self.techniques]
        self.lt_only = self.techniques == "lt"
        self.stores_vertices = self.use_vc or self.use_vm
        depth = dscene.max_depth if settings.max_depth is None else settings.max_depth
        self.max_depth = UNBOUNDED_DEPTH if depth == -1 else depth
        self.max_light_segments = min(self.max_depth - 1, MAX_PHOTON_SEGMENTS)
        self.pixel_angle = 2.0 * dscene.tan_y / h
        self.r1 = None if opts["radius"] is None else float(opts["radius"])
        self.radius = 0.0
        if opts["radius_rule"] not in merge_radius.RULES:
            raise SettingsError(f"--radius-rule must be one of {', '.join(merge_radius.RULES)}, got "
                                f"'{opts['radius_rule']}'")
        # The schedule of r_i (methods/merge_radius.py); mbe hands its own to its vcm passes.
        self.radius_schedule = MergeRadius(self.alpha, opts["radius_rule"] if self.use_vm else "progressive")
        if self.radius_schedule.balanced:
            self.independent_iterations = False      # each pass's radius follows the bias measured before it

        f = FieldGroup(self.name)
        self.consts = f.vector(5, ti.f32, ())        # MisConstants of this iteration, then r^2
        self.first_hit = f.scalar(ti.f32, self.n_pixels)
        # light subpaths that left a vertex; light segments; camera vertices, connections, merge candidates
        self.counters = f.scalar(ti.i64, 5)
        self.last_estimate = f.scalar(ti.f64, self.n_pixels if self.balanced else 1)
        self.row_spread = f.scalar(ti.f64, h)
        self.pass_light_paths = f.scalar(ti.i32, ())  # this pass's light subpaths (the pairing's modulus)
        # Per pixel, over the passes: the sum of D (merging over the whole disc less merging over
        # its inner half, luminance) and of D^2 (merging_bias()).
        self.bias_measured = self.use_vm and self.measures_merging_bias
        self.merge_difference = f.vector(2, ti.f64, self.n_pixels if self.bias_measured else 1)
        self.bias_passes = 0
        self.bias_radius_sq_sum = 0.0            # r^2 and r^-2 summed over those passes (the balanced radius)
        self.bias_inverse_radius_sq_sum = 0.0
        f.finalize()
        self.fields = f
        radiance = dscene.scene.emitter_radiance
        self.film = SplatFilm(w, h, float(np.max(radiance)) if len(radiance) else 1.0, self.weighted_film)
        capacity = opts.get("light_vertex_capacity") or self._stored_paths() * min(self.max_light_segments,
                                                                                  INITIAL_VERTICES_PER_PATH)
        self.store = self.grid = None
        if self.stores_vertices:
            self._allocate_store(int(max(capacity, 1)))
        self.vertices_last = 0
        self.store_grown = 0

    @classmethod
    def iterations_independent(cls, options: dict) -> bool:
        balanced_light = cls.balances_light_paths and options.get("light_paths") in (None, "auto")
        # The balanced radius follows the bias measured before each pass, where there is merging
        # and the radius shrinks at all.
        rule = options.get("radius_rule") or cls.OPTIONS["radius_rule"]
        alpha = float(options.get("alpha") or cls.OPTIONS["alpha"])
        merges = TECHNIQUES.get(options.get("techniques") or "vcm", (False, True, False))[1]
        balanced_radius = rule == "balanced" and merges and alpha < 1.0
        return super().iterations_independent(options) and not (balanced_light or balanced_radius)

    def _stored_paths(self) -> int:
        """Subpaths whose vertices the iteration stores: the light subpaths."""
        return self.n_light

    def _allocate_store(self, capacity: int):
        need = capacity * BYTES_PER_STORED_VERTEX
        if need > MAX_STORE_BYTES:
            raise SettingsError(f"{self.name} would need {need / 2**30:.1f} GiB to store {capacity} subpath vertices "
                                f"per iteration (at most {MAX_STORE_BYTES >> 30} GiB): use a smaller resolution, "
                                f"fewer --light-paths (now {self.n_light}) or a smaller --max-depth")
        if self.store is not None:
            self.store.release()
        if self.grid is not None:
            self.grid.release()
        self.store = SubpathVertices(capacity, self._stored_paths(), f"{self.name}-vertices")
        self.grid = PointGrid(capacity) if self.use_vm else None

    def release(self):
        for obj in (self.store, self.grid, self.film, self.fields):
            if obj is not None:
                obj.release()

    def _reset(self):
        self.film.reset()
        self.counters.fill(0)
        self.merge_difference.fill(0)
        self.bias_passes = 0
        self.bias_radius_sq_sum = self.bias_inverse_radius_sq_sum = 0.0
        self.radius_schedule.reset()
        if self.balance is not None:
            self.balance = LightPathBalance(self.n_pixels)

    # -- the iteration -----------------------------------------------------------------
    def _radius_at(self, iteration: int) -> float:
        """r_i = r_1 i^((alpha-1)/2), i counted from 1 (Knaus & Zwicker 2011; VCM sec. 5), or the
        balanced rule's schedule (methods/merge_radius.py)."""
        if self.r1 is None:
            self._first_hits()
            t = self.first_hit.to_numpy()
            t = t[np.isfinite(t) & (t > 0)]
            extent = self.dscene.extent
            median = float(np.median(t)) if len(t) else extent
            self.r1 = max(float(self.options["radius_pixels"]) * self.pixel_angle * median, 1e-7 * extent)
        return self.r1 * self.radius_schedule.scale(iteration)

    def balance_radius(self, next_index: int, schedule: MergeRadius | None = None) -> None:
        """The balanced rule's step after a pass (methods/merge_radius.py): from this film's
        merging bias and variance, whether the schedule's steps from `next_index` (the next
        pass's radius index) shrink faster. mbe passes the schedule its passes share."""
        schedule = self.radius_schedule if schedule is None else schedule
        if not schedule.balanced:
            return
        n = self.bias_passes
        fast = False
        if self.bias_measured and n >= 2:
            bias_sq, variance, spread, _ = self._bias_sums(float(n)).to_numpy()
            fast = MergeRadius.bias_dominates(bias_sq, variance, spread, n,
                                              (self.r1 * schedule.scale(next_index)) ** 2,
                                              self.bias_radius_sq_sum / n, self.bias_inverse_radius_sq_sum / n)
        schedule.advance(next_index, fast)

    def _iterate(self):
        if self.balance is None:
            self.vcm_pass(self.iteration_index, self.iteration_index)
            self.work_done += self.n_light + self.n_pixels
            self.balance_radius(self.iteration_index + 1)
            return
        n = self.balance.next_light_paths()
        spread, segments, vertices, connections, merges = self.vcm_pass(self.iteration_index, self.iteration_index, n)
        light_rays = self.vertices_last if self.use_lt else 0.0
        work = LightPathBalance.work(self.n_pixels, vertices, connections, segments, light_rays, merges)
        self.balance.observe(n, spread, self.n_pixels, work)
        self.work_done += n + self.n_pixels
        self.balance_radius(self.iteration_index + 1)

    def vcm_pass(self, it: int, radius_index: int, n_light: int | None = None, keep: bool = True,
                 pixel_points: tuple[int, int] | None = None, stream: int = 0):
        """One iteration: random numbers drawn for index `it`, merging radius r_(radius_index)
        (the same index for vcm; mbe's vcm passes index it by its camera subpaths), n_light
        light subpaths (at most --light-paths, which sizes the store; mbe's vcm passes choose
        theirs, methods/pass_choice.py). keep=False measures the pass without adding it to the
        film (mbe's passes that only measure a vcm pass's variance, methods/pass_choice.py).
        The camera subpaths start at pixel_points = (point, replicate) of their pixels'
        sequences in stream `stream` (kernels/pixel_samples.py; default: radius_index's as an
        iteration; mbe's vcm passes have their own)."""
        n_light = self.n_light if n_light is None else int(n_light)
        if not 1 <= n_light <= self.n_light:
            raise ValueError(f"a vcm pass traces 1 to {self.n_light} light subpaths, not {n_light}")
        self.radius = self._radius_at(radius_index)
        eta = PI * self.radius ** 2 * n_light
        # MisConstants and r^2, as scalars (a vector argument costs more host time)
        consts = (eta if self.use_vm else 0.0, 1.0 / eta if self.use_vc else 0.0, float(n_light), 1.0,
                  self.radius ** 2)
        # The store and the grid are template arguments of the passes (a grown store compiles
        # them anew); without a store (light tracing only) any other object stands in. Two
        # launches in all: every launch, and every field read or write from Python, costs host
        # time, a few per cent of a small image's iteration (docs/performance.md).
        store = self.store if self.store is not None else self.fields
        grid = self.grid if self.grid is not None else self.fields
        while True:
            n = int(self._light_pass(store, grid, *consts, self.seed_u32, it, n_light, self.max_light_segments,
                                     self.radius, *self._index_serial(n_light)))
            if self.store is None or n <= self.store.capacity:
                break
            # Too many vertices to store: grow (recompiles the passes once) and redo the pass,
            # which the counter-based random numbers make the same pass.
            self.film.clear_frame()
            self._allocate_store(int(n * 1.25) + 1024)
            self.store_grown += 1
            store, grid = self.store, (self.grid if self.grid is not None else self.fields)
        if self.store is not None:
            self.vertices_last = n
        # The camera subpath's place in its pixel's sequences: from vcm's iteration, from the
        # vcm passes so far in mbe (kernels/pixel_samples.py).
        point, replicate = pixel_samples.iteration_points(radius_index) if pixel_points is None else pixel_points
        measured = self._camera_pass(store, grid, self.seed_u32, it, self.max_depth,
                                     1.0 / (PI * self.radius ** 2 * n_light), int(keep), point, replicate, stream)
        if keep:
            self.film.count_flushed()
        # Every pass adds to the bias sums, those that only measure too (mbe's exploring and
        # twin vcm passes): each is a pass at its radius, like the film's.
        if self.bias_measured:
            self.bias_passes += 1
            self.bias_radius_sq_sum += self.radius ** 2
            self.bias_inverse_radius_sq_sum += 1.0 / self.radius ** 2
        return measured

    def _index_serial(self, n_paths: int) -> tuple[bool, bool]:
        """Whether index_vertices' loops run serially (runtime.serial_loop): over the paths,
        and over the grid's table slots, as many as the last iteration's count needs (this
        one's is close to it; a fixed rule, so images stay deterministic)."""
        slots = self.grid.table_slots(max(self.vertices_last, n_paths)) if self.grid is not None else 0
        return serial_loop(n_paths), serial_loop(slots)

    @ti.func
    def index_vertices(self, store: ti.template(), grid: ti.template(), n_paths, radius,
                       serial_paths: ti.template(), serial_grid: ti.template()):
        """After the loop that filled `store` (at its kernel's top level): its path order, and
        the merging grid of radius r_i over its vertices (when grid is a PointGrid). Returns
        the vertices the pass tried to store; more than the capacity indexes nothing (the
        caller grows the store and redoes the pass)."""
        n = store.count[None]
        count = n if n <= ti.static(store.capacity) else 0
        store.finish_paths(n_paths, count, serial_paths)
        if ti.static(isinstance(grid, PointGrid)):
            grid.build_points(store.p, store.valid, radius, grid.slots_for(count), count, serial_grid)
        return n

    @ti.kernel
    def _first_hits(self):
        sc = self.dscene
        for y, x in ti.ndrange(sc.height, sc.width):
            o, d = sc.camera_ray(x, y, 0.5, 0.5)
            hit = sc.trace(o, d, ti.math.inf, False)
            self.first_hit[y * sc.width + x] = hit.t

    @ti.func
    def mis_constants(self):
        c = self.consts[None]
        return MisConstants(vm_weight=c[0], vc_weight=c[1], n_light=c[2], camera_only=c[3])

    # -- light side ----------------------------------------------------------------------
    @ti.kernel
    def _light_pass(self, store: ti.template(), grid: ti.template(), vm_weight: ti.f32, vc_weight: ti.f32,
                    light_paths: ti.f32, camera_only: ti.f32, r2: ti.f32, seed: ti.u32, iteration: ti.u32,
                    n_light: ti.i32, max_segments: ti.i32, radius: ti.f32, serial_paths: ti.template(),
                    serial_grid: ti.template()) -> ti.i32:
        """The iteration's MIS constants set and the light-vertex store emptied, the light
        subpaths traced, their vertices indexed (index_vertices), in one launch. Returns the
        vertices the pass tried to store (0 without a store)."""
        self.consts[None] = ti.Vector([vm_weight, vc_weight, light_paths, camera_only, r2])
        self.pass_light_paths[None] = n_light
        if ti.static(isinstance(store, SubpathVertices)):
            store.clear_paths(n_light, serial_paths)
        for p in range(n_light):
            key = rng.seed(seed, ti.u32(p), iteration * ti.u32(2) + ti.u32(1))
            used, dims = trace_photon(self.dscene, HashSource, key, self, p, max_segments)
            if used:
                ti.atomic_add(self.counters[0], 1)
            if ti.static(self.balanced):
                ti.atomic_add(self.counters[1], photon_segments(dims))
        n = 0
        if ti.static(isinstance(store, SubpathVertices)):
            n = self.index_vertices(store, grid, n_light, radius, serial_paths, serial_grid)
        return n

    @ti.func
    def visit_vertex(self, path: ti.i32, v) -> ti.i32:
        """A non-delta light vertex: store it for connections and merging, connect it to the camera."""
        if ti.static(self.stores_vertices):
            self.store.append(path, v)
        if ti.static(self.use_lt):
            if v.length + 1 <= ti.static(self.max_depth):
                self._connect_to_camera(v)
        return 1

    @ti.func
    def _connect_to_camera(self, v):
        """Light tracing (t = 1): the light vertex seen by the camera, splatted to its pixel."""
        c = self.mis_constants()
        seen, px, py, contrib = vcm_techniques.light_to_camera(self.dscene, v, c, not self.lt_only, 1.0 / c.n_light)
        if seen:
            self.film.splat(py, px, contrib)

    # -- camera side ---------------------------------------------------------------------
    @ti.kernel
    def _camera_pass(self, store: ti.template(), grid: ti.template(), seed: ti.u32, iteration: ti.u32,
                     max_depth: ti.i32, vm_normalization: ti.f32, keep: ti.i32,
                     first_point: ti.u32, replicate: ti.u32, stream: ti.u32) -> ti.types.vector(5, ti.f64):
        """One camera subpath per pixel, then the frame joins the film (or, keep = 0, is only
        measured and cleared), in one launch. With the
        light-path balance, returns what it measures of the pass (zeros without): the sum over
        pixels of (this pass's estimate - the last one's)^2 in luminance, summed per row, then
        over rows in a fixed order (a seed gives one image whatever the threads); light
        segments, camera vertices, connections and merge candidates (the counters, then reset)."""
        self.camera_subpaths(store, grid, seed, iteration, max_depth, vm_normalization, 1, first_point, replicate,
                             stream)
        w = ti.static(self.dscene.width)
        ti.loop_config(serialize=ti.static(serial_loop(self.n_pixels)))
        for y in range(self.dscene.height):
            row = ti.f64(0.0)
            for x in range(w):
                if ti.static(self.balanced):
                    e = ti.cast(self.film.frame[y, x], ti.f64).dot(ti.Vector([0.2126, 0.7152, 0.0722], ti.f64)) \
                        * ti.static(self.film.unit)
                    d = e - self.last_estimate[y * w + x]
                    self.last_estimate[y * w + x] = e
                    row += d * d
                if keep:
                    self.film.flush_pixel(y, x)
                else:
                    self.film.frame[y, x] = ti.Vector([0, 0, 0], ti.i64)
            self.row_spread[y] = row
        total = ti.f64(0.0)
        ti.loop_config(serialize=True)
        for y in range(self.dscene.height):
            total += self.row_spread[y]
        out = ti.Vector([total, 0.0, 0.0, 0.0, 0.0], ti.f64)
        for c in ti.static(range(1, 5)):
            out[c] = ti.cast(self.counters[c], ti.f64)
            self.counters[c] = 0
        return out

    @ti.func
    def camera_subpaths(self, store: ti.template(), grid: ti.template(), seed, iteration, max_depth,
                        vm_normalization, per_pixel, first_point, replicate, stream):
        """per_pixel camera subpaths per pixel (vcm: 1; mbe: --camera-paths), at a kernel's
        top level. Subpath k * pixels + pixel draws its own random numbers (k = 0: the
        pixel's, as with one), starts at point first_point + k of its pixel's replicate
        `replicate` in stream `stream` (kernels/pixel_samples.py) and adds 1/per_pixel of its
        estimate to the pixel;
        `acc.subpath` names the subpath."""
        sc = self.dscene
        inv_per_pixel = 1.0 / ti.cast(per_pixel, ti.f32)
        for k, y, x in ti.ndrange(per_pixel, sc.height, sc.width):
            pixel = y * sc.width + x
            subpath = k * ti.static(self.n_pixels) + pixel
            state = rng.seed(seed, ti.u32(subpath), iteration * ti.u32(2))
            u1, u2 = pixel_samples.pixel_sample(self.sobol_pixels, seed, ti.u32(pixel),
                                                ti.cast(first_point, ti.u32) + ti.u32(k), ti.cast(replicate, ti.u32),
                                                ti.cast(stream, ti.u32), state)
            o, d = sc.camera_ray(x, y, u1, u2)
            acc = CameraSubpath(L=vec3(0.0), merged=ti.Vector([0, 0, 0], ti.i64),
                                merged_inner=ti.Vector([0, 0, 0], ti.i64),
                                m=vcm_mis.camera_start(sc.camera_pdf_w(d), self.mis_constants()), subpath=subpath,
                                max_depth=max_depth, vm_normalization=vm_normalization,
                                work=ti.Vector([0, 0, 0], ti.i32))
            # Light tracing renders all but the emitters seen directly.
            camera_walk(sc, o, d, state, 1 if ti.static(self.lt_only) else max_depth, self, acc)
            self.film.add_fixed(y, x, self.film.fixed(acc.L * inv_per_pixel) + acc.merged)
            if ti.static(self.bias_measured):
                diff = ti.cast(acc.merged - acc.merged_inner, ti.f64) * ti.static(self.film.unit)
                dl = diff.dot(ti.Vector([0.2126, 0.7152, 0.0722], ti.f64))
                self.merge_difference[pixel] += ti.Vector([dl, dl * dl], ti.f64)
            if ti.static(self.balanced):
                for c in ti.static(range(3)):
                    ti.atomic_add(self.counters[2 + c], ti.cast(acc.work[c], ti.i64))

    # -- the camera walk's visitor (kernels/camera_walk.py) ----------------------------
    roulette = MATERIAL_ROULETTE

    @ti.func
    def on_surface(self, acc: ti.template(), w, s, wo):
        vcm_mis.after_hit(acc.m, (s.p - w.prev_p).norm_sqr(), s.ns.dot(wo))
        eh = self.dscene.emitter_hit(s, wo)
        if eh.radiance.max() > 0.0:
            acc.L += w.beta * eh.radiance * self._emitter_hit_weight(acc.m, eh, w.length, w.specular)

    @ti.func
    def at_vertex(self, acc: ti.template(), w, s, b: ti.i32, n, t1, t2, wo, wo_l, state: ti.template()) -> ti.i32:
        """Next-event estimation, connections and merging at a non-delta camera vertex."""
        sc = self.dscene
        c = self.mis_constants()
        q = sc.bsdf_continuation(b)
        cv = PathVertex(p=s.p, ng=s.ng, n=n, wo=wo, beta=w.beta, length=w.length, bsdf=b, dvcm=acc.m.dvcm,
                        dvc=acc.m.dvc, dvm=acc.m.dvm)
        if ti.static(self.balanced):
            acc.work[0] += 1
            if ti.static(self.use_vc):
                acc.work[1] += self.store.path_count[acc.subpath % self.pass_light_paths[None]]
        if ti.static(self.use_vc):
            nee, connected = self._nee_and_connections(self.store, acc.subpath, cv, wo_l, t1, t2, q, state, c,
                                                       acc.max_depth)
            acc.L += w.beta * nee
            acc.L += w.beta * connected
        if ti.static(self.use_vm):
            merged, inner, candidates = self._merge(self.store, self.grid, cv, wo_l, t1, t2, q, c, acc.max_depth,
                                                    acc.vm_normalization)
            acc.merged += merged
            acc.merged_inner += inner
            acc.work[2] += candidates
        return CONTINUE

    @ti.func
    def after_scatter(self, acc: ti.template(), w, bs, q: ti.f32):
        vcm_mis.after_scatter(acc.m, bs.delta, bs.wi.z, bs.pdf_fwd_w * q, bs.pdf_rev_w * q, self.mis_constants())

    @ti.func
    def _emitter_hit_weight(self, m, eh, length: ti.i32, specular: ti.i32) -> ti.f32:
        w = 1.0                          # emitters seen directly: no other technique makes these
        if length > 1:
            if ti.static(self.use_vc):
                w = vcm_mis.emitter_hit_weight(m, eh.direct_pdf_a, eh.emission_pdf_w, True, self.mis_constants())
            elif ti.static(self.use_vm):
                w = 1.0 if specular else 0.0     # bpm: merging makes every path with a non-delta vertex
            else:
                w = 0.0                  # lt
        return w

    @ti.func
    def _next_event(self, cv, wo_l, t1, t2, q: ti.f32, state: ti.template(), c):
        """Next-event estimation (s = 1) at camera vertex cv."""
        sc = self.dscene
        contrib = vec3(0.0)
        il = sc.illuminate(cv.p, rng.next_float(state), rng.next_float(state), rng.next_float(state))
        if il.radiance.max() > 0.0:
            wi_l = to_local(il.wi, t1, t2, cv.n)
            e = sc.bsdf_evaluate(cv.bsdf, wo_l, wi_l)
            if e.f.max() > 0.0 and sc.visible(cv.p, cv.ng, il.p, il.n):
                w = vcm_mis.next_event_weight(cv, il.direct_pdf_w, il.emission_pdf_w, il.cos_light, wi_l.z,
                                              e.pdf_fwd_w * q, e.pdf_rev_w * q, c, True)
                contrib = e.f * il.radiance * (w * ti.abs(wi_l.z) / il.direct_pdf_w)
        return contrib

    @ti.func
    def _nee_and_connections(self, store: ti.template(), pixel: ti.i32, cv, wo_l, t1, t2, q: ti.f32,
                             state: ti.template(), c, max_depth: ti.i32):
        """Next-event estimation (s = 1) at camera vertex cv and its connections (s, t >= 2) to
        every vertex of the light subpath paired with this pixel (the one with the pixel's
        index modulo the pass's light subpaths, as in SmallVCM: N_L = pixels by default),
        without cv's throughput. One loop
        (k = -1: next-event estimation) with one shadow-ray call site, because every inlined
        copy of the BVH traversal costs compile time (docs/performance.md, "Compile time");
        the same rays, random numbers and sums, in the same order, as one technique after the
        other. Returns (next-event estimate, connections' sum)."""
        sc = self.dscene
        nee = vec3(0.0)
        total = vec3(0.0)
        path = pixel % self.pass_light_paths[None]
        first = store.path_start[path]
        k0 = -1 if cv.length + 1 <= max_depth else 0
        for k in range(k0, store.path_count[path]):
            contrib = vec3(0.0)
            q_p, q_n = cv.p, cv.ng               # the far end of the shadow ray
            if k < 0:
                il = sc.illuminate(cv.p, rng.next_float(state), rng.next_float(state), rng.next_float(state))
                if il.radiance.max() > 0.0:
                    wi_l = to_local(il.wi, t1, t2, cv.n)
                    e = sc.bsdf_evaluate(cv.bsdf, wo_l, wi_l)
                    if e.f.max() > 0.0:
                        w = vcm_mis.next_event_weight(cv, il.direct_pdf_w, il.emission_pdf_w, il.cos_light,
                                                      wi_l.z, e.pdf_fwd_w * q, e.pdf_rev_w * q, c, True)
                        contrib = e.f * il.radiance * (w * ti.abs(wi_l.z) / il.direct_pdf_w)
                        q_p, q_n = il.p, il.n
            else:
                lv = store.vertex(store.order[first + k])
                if lv.length + 1 + cv.length <= max_depth:
                    to_c = cv.p - lv.p
                    dist2 = to_c.dot(to_c)
                    if dist2 > 0.0:
                        w = to_c / ti.sqrt(dist2)
                        w_l, el = vcm_techniques.light_side(sc, lv, w)
                        contrib = vcm_techniques.connection_technique(sc, cv, wo_l, t1, t2, q, lv, w, w_l, el,
                                                                      dist2, c)
                        q_p, q_n = lv.p, lv.ng
            if contrib.max() > 0.0 and sc.visible(cv.p, cv.ng, q_p, q_n):
                if k < 0:
                    nee = contrib
                else:
                    total += contrib
        return nee, total

    @ti.func
    def _merge(self, store: ti.template(), grid: ti.template(), cv, wo_l, t1, t2, q: ti.f32, c, max_depth: ti.i32,
               vm_normalization: ti.f32):
        """Merging (photon mapping at every non-delta camera vertex) with the light vertices
        within the radius, in fixed point: the sum does not depend on the grid's order. Also
        the same merging over the inner half of the disc's area (r^2 / 2, twice the weight:
        the kernel normalised to that disc), for merging_bias()."""
        total = ti.Vector([0, 0, 0], ti.i64)
        inner = ti.Vector([0, 0, 0], ti.i64)
        candidates = 0
        r2 = self.radius_sq()
        slots, n_slots = grid.slots_near(cv.p)
        for k in range(n_slots):
            first, end = grid.slot_range(slots[k])
            for e in range(first, end):
                dist_sq = (grid.entry_pos[e] - cv.p).norm_sqr()
                if dist_sq <= r2:
                    candidates += 1
                    slot = grid.entries[e]
                    if store.length[slot] + cv.length <= max_depth and \
                            vcm_techniques.can_merge(cv.n, store.n[slot], store.wo[slot]):
                        lv = store.vertex(slot)
                        contribution = self.film.fixed(vcm_techniques.merge(self.dscene, cv, wo_l, t1, t2, q, lv, c,
                                                                             vm_normalization))
                        total += contribution
                        if ti.static(self.bias_measured):
                            if dist_sq <= 0.5 * r2:
                                inner += 2 * contribution
        return total, inner, candidates

    @ti.func
    def radius_sq(self) -> ti.f32:
        return self.consts[None][4]

    # -- results ----------------------------------------------------------------------
    def image(self):
        return self.film.mean()

    def standard_error(self):
        return self.film.standard_error()

    def progress_fields(self) -> str:
        fields = [f"radius {self.radius:.3g}"] if self.use_vm else []
        if self.balance is not None:
            fields.append(f"light paths {self.balance.next_light_paths()}")
        return ", ".join(fields)

    def method_stats(self):
        c = self.counters.to_numpy()
        return {"techniques": self.techniques,
                "light_paths_per_iteration": self.n_light if self.balance is None else self.balance.stats()["light_paths_mean"],
                "light_path_balance": None if self.balance is None else self.balance.stats(),
                "radius": self.radius if self.use_vm else None, "initial_radius": self.r1, "alpha": self.alpha,
                "fraction_of_light_paths_with_vertices": float(c[0]) / max(self.iterations * self.n_light, 1),
                "light_vertices_last_iteration": self.vertices_last,
                "light_vertex_capacity": self.store.capacity if self.store is not None else 0,
                "light_vertex_store_grown": self.store_grown,
                "nonfinite_samples_dropped": self.film.dropped(),
                "merging_bias": self.merging_bias(), "radius_schedule": self.radius_schedule.stats()}

    def merging_bias(self) -> dict | None:
        """The film's bias from merging, estimated from the passes so far (docs/vcm.md,
        "Merging's bias, estimated"). Per pixel, D = merging over the whole disc less merging
        over its inner half (the same light vertices and weights, the kernel narrowed to
        radius r / sqrt 2). If a pass's bias is b r^2 (a density smooth across the disc),
        E[D] = b r^2 / 2 and the bias is 2 E[D]; at an edge it goes as r and is 3.4 E[D],
        so the estimate reads low there by up to 1.7x. E[D]^2 is estimated without its noise
        (mean^2 - Var / n, summed over pixels before it is clamped at 0). Reports the RMSE over pixels of that bias and its mean as a
        fraction of the image's mean."""
        if not self.bias_measured or self.bias_passes < 2:
            return None
        n = self.bias_passes
        bias_sq, _, _, mean_sum = self._bias_sums(float(n)).to_numpy()
        # Clamped after the sum over pixels, not per pixel: per pixel the clamp would keep the
        # positive half of each pixel's noise (13 % of the image where there is no bias, in the
        # sphere furnace after 64 passes).
        bias_sq = max(float(bias_sq), 0.0) / self.n_pixels
        image_mean = mean_luminance(self.film.mean())
        return {"rmse_estimate": math.sqrt(bias_sq),
                "mean_relative": float(2.0 * mean_sum / self.n_pixels / image_mean) if image_mean > 0 else None,
                "passes": n}

    @ti.kernel
    def _bias_sums(self, n: ti.f64) -> ti.types.vector(4, ti.f64):
        """Over pixels, from the sums of D and D^2 over n passes (merging_bias): the squared
        bias 4 (mean^2 - se^2) (noise removed, not clamped), the merging variance of the
        film se^2 (D's variance is that of the pixel's merging estimate: the inner disc's light
        vertices are in both), the variance of the first sum where there is no bias (32 se^4
        per pixel), and the sum of the means. A serial loop: one summation order, so the
        balanced radius, and the image, do not depend on the threads."""
        bias_sq, variance, spread, mean_sum = ti.f64(0.0), ti.f64(0.0), ti.f64(0.0), ti.f64(0.0)
        ti.loop_config(serialize=True)
        for i in range(self.merge_difference.shape[0]):
            d = self.merge_difference[i]
            mean = d[0] / n
            se_sq = ti.max(d[1] / n - mean * mean, 0.0) / (n - 1.0)
            bias_sq += 4.0 * (mean * mean - se_sq)
            variance += se_sq
            spread += 32.0 * se_sq * se_sq
            mean_sum += mean
        return ti.Vector([bias_sq, variance, spread, mean_sum])

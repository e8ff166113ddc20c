"""Stochastic progressive photon mapping (Hachisuka & Jensen 2009; algorithms.md §1).

Each iteration:
1. camera pass: one jittered path per pixel through delta surfaces to its first non-delta
   vertex, the pixel's measurement point (MP); emission met on the way and next-event
   direct light at the MP go to the direct term Ld;
2. a hash grid over the MPs;
3. photon pass: photons from the lights (chosen by power), deposited at every non-delta
   vertex after the first segment into the MPs whose radius contains them (one predicate,
   `accepts`, decides both counting and contributing);
4. per-pixel progressive update: N' = N + aM, R' = R sqrt(N'/(N+M)), and the reflected
   flux accumulated in the D form D += W Phi / (pi R^2) (equal to the tau form, §1.3).
Image: Ld / C + D / N_e, with C camera paths per pixel and N_e photons in all iterations.

A pass may trace K camera paths per pixel (`--camera-paths`, docs/effort.md): K measurement
points per pixel, each gathering the same photons, sharing the pixel's radius and averaged
into one estimate per pass. The guided methods need long photon passes (every chain must
regenerate, guided.py); where the error is camera-side K > 1 buys back the camera passes
that such a pass would otherwise cost. The direct term weighs every camera path alike, whatever
the K of its pass: a pass's mean weighted as one sample let the balance's early passes of
K = 1 outweigh later paths 24 to 1, and the film's pixel positions were no longer the equally
weighted net that stratifies a lamp's edge (docs/effort.md, "Camera paths weighed alike").

Per-iteration flux is accumulated in 64-bit fixed point (photon power relative to the
scene's total emitted power, 2^-32 resolution): integer atomics are order-independent, so
a seed gives a bit-identical image whatever the thread scheduling.
Path depth follows Mitsuba's max_depth: an MP reached after k segments takes photons that
travelled at most max_depth - k segments.
"""
import math

import numpy as np
import taichi as ti

from ..errors import SettingsError
from ..kernels import pixel_samples, rng
from ..kernels.camera_walk import STOP, THROUGHPUT_ROULETTE, camera_walk
from ..kernels.device_scene import UNBOUNDED_DEPTH
from ..kernels.direct import next_event
from ..kernels.disc_clip import (NO_WALLS, WHOLE_DISC, behind_wall, disc_linear_fits, disc_shares, disc_walls,
                                 in_region, wall_shares)
from ..kernels.batch import fill_fields
from ..kernels.fields import FieldGroup
from ..kernels.hashgrid import HashGrid
from ..kernels.photon import MAX_PHOTON_SEGMENTS, NORMAL_COS_MIN, photon_segments, trace_photon
from ..kernels.sampling import onb, to_local, vec3
from .base import Method
from .effort import EffortBalance
from .merge_radius import ALPHA_FAST, BIAS_MIN_PASSES, BIAS_Z, bias_outweighs_noise
from ..taichi_frontend import data_oriented

PROBE_ALL_EVERY = 8      # --disc clipped, linear: passes between probes of every pixel's MPs
EDGE_MEMORY = 8          # and the passes a pixel's MPs are probed after one was last found cut
FIXED_ONE = 4294967296.0          # 2^32: fixed-point scale of per-iteration flux
PI = math.pi                      # use as ti.f64(PI): a bare literal is a float32 constant (default_fp)
MP_BUDGET = 1 << 20               # measurement points that --camera-paths auto may allocate
MAX_CAMERA_PATHS = 64             # and at most this many camera paths per pixel per pass
# Twin camera paths (docs/effort.md, "Twin camera paths"): a twin's random numbers are its
# path's index with rng.TWIN_BIT set (there are at most MP_BUDGET camera paths).
TWINS_FIRST = 16                  # every pass of the first this many has twins,
TWINS_EVERY = 8                   # and one pass in this many after that
# One camera path's accumulators: direct light so far, its pixel, the initial-radius rule;
# twin: a twin of the path already traced to MP `pixel` (it writes no MP), matched: whether
# it reached that same MP.
CameraPath = ti.types.struct(direct=vec3, pixel=ti.i32, r_abs=ti.f32, r_per_dist=ti.f32, rays=ti.i32, twin=ti.i32,
                             matched=ti.i32)


class HashSource:
    """Primary samples for plain photon tracing: hashed from (seed, photon, iteration)."""

    @staticmethod
    @ti.func
    def get(key, dim):
        return rng.uniform(key, dim)


@data_oriented
class Sppm(Method):
    name = "sppm"
    work_unit = "photons"
    default_iterations = 100
    OPTIONS = {"photons": None, "alpha": 2.0 / 3.0, "radius": None, "radius_pixels": 2.0, "tau_form": False,
               "camera_paths": None, "radius_rule": "balanced", "balance": "mse",
               "pixel_samples": "sobol", "camera_variance": "twins",
               # The effort balance may also weigh the radius bias the balanced rule measures
               # (effort.py, observe_bias). Off: on the rooms measured it moved K and the
               # photons little and the error not beyond the seeds' spread (docs/effort.md,
               # "The radius bias in the balance").
               "effort_bias": False,
               # clipped: each MP's estimate divides by the part of its disc that lies on its
               # surface (kernels/disc_clip.py), which removes the dark bias of discs that
               # overhang an edge (docs/guiding.md, "Discs that overhang an edge"); linear: the
               # region the probes bound, its photons alone, weighted so that light linear
               # across it is read at the MP (docs/guiding.md, "Discs fitted to their surface");
               # sealed: without the photons behind a wall the probes find in the disc, so light
               # leaking through a wall onto the same plane does not count, and divided by the
               # part of the disc in front of the walls (docs/guiding.md, "Light that leaks
               # through a partition").
               "disc": "full"}
    RADIUS_RULES = ("progressive", "balanced")
    DISCS = ("full", "clipped", "linear", "sealed")
    default_camera_paths = 1      # what --camera-paths is when not given (guided: auto)
    # The twins' V_c estimates: their plain mean since the start (sppm: the caustic's rare
    # camera paths to the lamp through glass are error its photons cannot remove, and the
    # trimmed mean made it 1.49x fixed photons' RMSE) or the pairs' trimmed mean (the guided
    # methods, whose K they steer; docs/effort.md, "Twins where K does not set the pass length").
    trim_twin_variances = False
    # Rebuilt every iteration, so not saved in a render state (state.py): the grid and the
    # pass's measurement points with their per-pass accumulators (up to MP_BUDGET points).
    TRANSIENT = ("grid", "mp_p", "mp_n", "mp_wo", "mp_W", "mp_bsdf", "mp_depth", "mp_valid", "mp_radius",
                 "mp_share", "mp_share_inner", "mp_tri", "mp_slope", "mp_slope_inner", "mp_ends", "mp_walls",
                 "mp_direct", "mp_twin_direct", "mp_twin_matched", "M", "phi", "phi_odd", "phi_inner",
                 "camera_estimate", "twin_unmatched")
    n_levels = 1          # flux accumulators per measurement point (one per Markov-chain level)
    # The guided methods add one accumulator after the levels': the uniform photons' own
    # estimate (methods/guided.py), whose halves the update keeps apart from the levels'.
    uniform_accumulator = False
    # What trace_photon hands this visitor: vertices after the first segment (direct light is
    # the camera pass's), without the VCM partial sums.
    visits_from_segment = 2
    with_mis = False

    def __init__(self, dscene, settings):
        super().__init__(dscene, settings)
        opts = self.options
        w, h = dscene.width, dscene.height
        self.n_pixels = w * h
        # --photons N fixes the photons per pass (default one per pixel); auto follows the
        # effort balance (effort.py), starting from one per pixel.
        self.balanced = opts["photons"] == "auto"
        if opts["photons"] is not None and not self.balanced and not isinstance(opts["photons"], (int, np.integer)):
            raise SettingsError(f"--photons must be a number of photons or 'auto', got '{opts['photons']}'")
        self.photons_per_iteration = int(self.n_pixels if opts["photons"] in (None, "auto") else opts["photons"])
        self.alpha = float(opts["alpha"])
        if not isinstance(opts["effort_bias"], bool):
            raise SettingsError(f"effort_bias must be true or false, got {opts['effort_bias']!r}")
        self._set_camera_paths(opts["camera_paths"])
        if not 1 <= self.photons_per_iteration <= 1 << 28:
            raise SettingsError(f"--photons must be between 1 and 2^28, got {self.photons_per_iteration}")
        if not 0.0 < self.alpha < 1.0:
            raise SettingsError(f"--alpha must be in (0, 1), got {self.alpha}")
        if opts["radius"] is not None and not (0 < opts["radius"] < math.inf):
            raise SettingsError(f"--radius must be a positive length, got {opts['radius']}")
        # Initial radius: absolute if given, else this many pixel footprints at the MP.
        self.initial_radius = float(opts["radius"] or 0.0)
        self.radius_pixels = float(opts["radius_pixels"])
        self.tau_form = bool(opts["tau_form"])
        if opts["radius_rule"] not in self.RADIUS_RULES:
            raise SettingsError(f"--radius-rule must be one of {', '.join(self.RADIUS_RULES)}, "
                                f"got '{opts['radius_rule']}'")
        # balanced: every radius shrinks faster while the image's measured radius bias
        # outweighs its noise (docs/guiding.md, "A radius that balances its bias against the noise")
        self.balanced_radius = opts["radius_rule"] == "balanced"
        if opts["disc"] not in self.DISCS:
            raise SettingsError(f"--disc must be one of {', '.join(self.DISCS)}, got '{opts['disc']}'")
        # probed: the MPs' discs are probed with rays (kernels/disc_clip.py); clipped: each
        # estimate divides by its disc's share on the surface; sealed: by its share in front
        # of the walls in it, without the photons behind them
        self.probed_disc = opts["disc"] in ("clipped", "linear", "sealed")
        self.clipped_disc = opts["disc"] in ("clipped", "linear")
        self.sealed_disc = opts["disc"] == "sealed"
        self.divided_disc = self.clipped_disc or self.sealed_disc     # divides by a share of the disc
        # linear: clipped, each photon weighted so that a density linear across the disc is
        # read at its centre (kernels/disc_clip.py, _linear_fit)
        self.linear_disc = opts["disc"] == "linear"
        if opts["balance"] not in ("mse", "relmse"):
            raise SettingsError(f"--balance must be 'mse' or 'relmse', got '{opts['balance']}'")
        # relmse: the effort balance weighs each pixel's error by 1 / (m^2 + eps), as converge's
        # relMSE does (docs/guiding.md, "The closet's error, and two levers measured")
        self.relative_balance = opts["balance"] == "relmse"
        self.sobol_pixels = pixel_samples.uses_sobol(opts)
        if opts["camera_variance"] not in ("twins", "pairs", "auto"):
            raise SettingsError(f"--camera-variance must be 'twins', 'pairs' or 'auto', got "
                                f"'{opts['camera_variance']}'")
        # The effort balance's V_c from twin camera paths, the pixel positions held, where the
        # positions are stratified and the balance steers something (docs/effort.md, "Twin
        # camera paths"); else from consecutive passes. auto: twins, and the guided methods
        # read the pairs' instead in passes whose length their chains set (guided.py).
        self.held_camera = (self.sobol_pixels and opts["camera_variance"] in ("twins", "auto")
                            and (self.balanced or self.camera_paths_auto))
        self.camera_variance_auto = self.held_camera and opts["camera_variance"] == "auto"
        self.regeneration_bound = False
        self.pass_segments = self.pass_deposits = 0.0     # the last pass's photon work (_update_balanced)
        self.twins_now = False
        self.twin_passes = 0
        self.twin_pixels_unmatched = 0.0
        self.effort = self._new_effort()      # measured either way (stats)
        self.alpha_factor = 1.0       # its factor on alpha for this pass
        self.fast_passes = 0          # and the passes it shrank faster
        depth = dscene.max_depth if settings.max_depth is None else settings.max_depth
        self.max_depth = UNBOUNDED_DEPTH if depth == -1 else depth
        self.max_photon_segments = min(self.max_depth - 1, MAX_PHOTON_SEGMENTS)
        self.power_scale = dscene.total_power          # photon power is stored relative to this
        self.pixel_angle = 2.0 * dscene.tan_y / h      # pixel footprint per unit distance
        self.photons_emitted = 0
        self.photon_paths_used = 0
        self.pixel_passes = pixel_samples.PassSamples()     # the camera passes' place in the pixels' sequences

        self.n_acc = self.n_levels + (1 if self.uniform_accumulator else 0)
        f = FieldGroup(f"sppm-{self.n_levels}-levels")
        n = self.n_mp = self.n_pixels * self.max_camera_paths
        # This iteration's measurement points: MP j is camera path j // n_pixels of pixel
        # j % n_pixels (one per pixel where camera_paths is 1).
        self.mp_p = f.vector(3, ti.f32, n)
        self.mp_n = f.vector(3, ti.f32, n)
        self.mp_wo = f.vector(3, ti.f32, n)
        self.mp_W = f.vector(3, ti.f32, n)
        self.mp_bsdf = f.scalar(ti.i32, n)
        self.mp_depth = f.scalar(ti.i32, n)
        self.mp_valid = f.scalar(ti.i32, n)
        self.mp_radius = f.scalar(ti.f32, n)
        if self.divided_disc:
            self.mp_share = f.scalar(ti.f32, n)          # the part of the disc on the MP's surface
            self.mp_share_inner = f.scalar(ti.f32, n)    # and of the disc of half the area
        if self.clipped_disc:
            self.mp_tri = f.scalar(ti.i32, n)            # the MP's triangle (-1: a sphere), which spares probe rays
        if self.linear_disc:
            self.mp_slope = f.vector(3, ti.f32, n)       # a photon at x counts 1 + slope . (x - p)
            self.mp_slope_inner = f.vector(3, ti.f32, n)     # in the disc of half the area
            self.mp_ends = f.vector(2, ti.u32, n)        # the region a photon must lie in (disc_clip.in_region)
        if self.sealed_disc:
            self.mp_walls = f.vector(4, ti.u32, n)       # the walls in the disc (disc_clip.behind_wall)
        self.mp_direct = f.vector(3, ti.f64, n)        # the camera path's emission and direct light
        self.mp_twin_direct = f.vector(3, ti.f64, n)   # its twin's (at the same pixel position)
        self.mp_twin_matched = f.scalar(ti.i32, n)     # 1 where the twin reached the same MP
        # Per-pixel progressive statistics, float64.
        n = self.n_pixels
        self.R = f.scalar(ti.f64, n)
        if self.probed_disc:
            # per pixel, the passes left in which its MPs are probed (EDGE_MEMORY after one was
            # found cut by an edge; the others' every PROBE_ALL_EVERY passes, _clip_discs)
            self.edge_pixel = f.scalar(ti.i32, n)
            self.edge_seen = f.scalar(ti.i32, n)
        self.N = f.scalar(ti.f64, n)
        self.D = f.vector(3, ti.f64, n)
        self.tau = f.vector(3, ti.f64, n)
        self.Ld = f.vector(3, ti.f64, n)               # direct light summed over camera paths
        self.ld_pass = f.vector(3, ti.f64, n)           # this iteration's direct light
        # Per-iteration accumulators (fixed point), per MP, and counters.
        self.M = f.scalar(ti.i64, self.n_mp)
        self.phi = f.vector(3, ti.i64, (self.n_acc, self.n_mp))
        self.phi_odd = f.vector(3, ti.i64, (self.n_acc, self.n_mp))   # the odd half's part of phi (effort.py)
        if self.balanced_radius:
            # the photons that landed in the inner disc of half the area, per accumulator
            self.phi_inner = f.vector(3, ti.i64, (self.n_acc, self.n_mp))
            # per pixel: sums over passes of the outer-minus-inner difference and its
            # square, and the passes counted
            self.bias_sum = f.scalar(ti.f64, n)
            self.bias_sq = f.scalar(ti.f64, n)
            self.bias_passes = f.scalar(ti.f64, n)
            # and of the pixel's R^2 and R^-2 at those passes (the history's ratios)
            self.bias_radius_sq = f.scalar(ti.f64, n)
            self.bias_inverse_radius_sq = f.scalar(ti.f64, n)
        self.estimate_last = f.scalar(ti.f64, n)    # per pixel: the last iteration's own estimate
        self.spread = f.scalar(ti.f64, n)           # per pixel: (this estimate - the last one)^2
        self.half_difference = f.scalar(ti.f64, n)  # per pixel: n (t_a - t_b)^2 / 4
        self.half_difference_mp = f.scalar(ti.f64, n)   # the same per MP, averaged over the pixel's K
        self.photon_part = f.scalar(ti.f64, n)      # per pixel: this iteration's photon estimate alone
        self.deposits = f.scalar(ti.f64, n)         # per pixel: photons deposited into its MPs this pass
        # Twin camera paths (docs/effort.md): per pixel, V_c with its position held from its last
        # twin; 1 once a twin has reached another MP than its path (a delta choice: its V_c is
        # then read from consecutive passes, every pass); this pass's V_c estimate; and 1
        # where this pass's twin reached another MP.
        self.camera_held = f.scalar(ti.f64, n)
        self.camera_stochastic = f.scalar(ti.f64, n)
        self.camera_estimate = f.scalar(ti.f64, n)
        self.twin_unmatched = f.scalar(ti.f64, n)
        self.effort_sums = f.scalar(ti.f64, 14)     # their sums, and the pass's counted work
        self.level_scale = f.scalar(ti.f64, self.n_acc)     # fixed point -> flux, per accumulator
        if self.uniform_accumulator:
            # Each accumulator's scale as an estimate by itself (level_scale holds them weighted),
            # and per pixel the even-odd differences of the chains' and the uniform photons'
            # estimates (the halves the uniform photons' weight is chosen from).
            self.raw_scale = f.scalar(ti.f64, self.n_acc)
            self.last_counts = f.scalar(ti.f64, n)      # per pixel: the last chain pass's photons per MP
            self.half_chains = f.scalar(ti.f64, n)
            self.half_uniform = f.scalar(ti.f64, n)
        # 0: photon paths that deposited, 1: non-finite direct samples, 2: camera rays this
        # pass, 3: photon segments this pass (the work the effort balance counts)
        self.counters = f.scalar(ti.i64, 4)
        f.finalize()
        self.fields = f
        self.grid = HashGrid(self.n_mp)

    def _set_camera_paths(self, value):
        """--camera-paths: a number, or auto (chosen by the effort balance per pass, between 1
        and MAX_CAMERA_PATHS, within MP_BUDGET measurement points)."""
        value = self.default_camera_paths if value is None else value
        self.camera_paths_auto = value == "auto"
        self.camera_paths_last = 1
        if self.camera_paths_auto:
            self.max_camera_paths = max(1, min(MAX_CAMERA_PATHS, MP_BUDGET // self.n_pixels))
            self.camera_paths = 1
        else:
            if not isinstance(value, (int, np.integer)) or not 1 <= value <= MAX_CAMERA_PATHS:
                raise SettingsError(f"--camera-paths must be a number from 1 to {MAX_CAMERA_PATHS} or 'auto', "
                                    f"got '{value}'")
            self.max_camera_paths = self.camera_paths = int(value)

    def release(self):
        self.grid.release()
        self.fields.release()

    def _reset(self):
        fill_fields((f, 0) for f in (self.R, self.N, self.D, self.tau, self.Ld, self.M, self.phi, self.phi_odd,
                                     self.counters, self.mp_valid, self.camera_held, self.camera_stochastic))
        if self.probed_disc:
            fill_fields((f, 0) for f in (self.edge_pixel, self.edge_seen))
        if self.uniform_accumulator:
            self.last_counts.fill(0)
        if self.balanced_radius:
            fill_fields((f, 0) for f in (self.phi_inner, self.bias_sum, self.bias_sq, self.bias_passes,
                                         self.bias_radius_sq, self.bias_inverse_radius_sq))
        self.alpha_factor = 1.0       # balanced radius rule: this pass's factor on alpha
        self.fast_passes = 0          # and the passes it shrank faster
        self.photons_emitted = 0
        self.pixel_passes = pixel_samples.PassSamples()
        if self.camera_paths_auto:
            self.camera_paths = 1
        if self.balanced:
            self.photons_per_iteration = self.n_pixels
        self.twin_passes = 0
        self.twin_pixels_unmatched = 0.0
        if self.effort is not None:
            self.effort = self._new_effort()

    def _new_effort(self) -> EffortBalance:
        # trim_twin_variances above: how the twins' V_c estimates are averaged.
        return EffortBalance(self.n_pixels, self.photons_per_iteration, self.alpha, held_camera=self.held_camera,
                             trim_camera=not self.held_camera or self.trim_twin_variances)

    # -- the iteration -----------------------------------------------------------------
    def _iterate(self):
        it = self.iterations
        n_p = self.photons_per_iteration
        self._measurement_points(it)
        self._photon_pass(self.seed_u32, it, n_p, self.max_photon_segments)
        self.level_scale[0] = self.power_scale / FIXED_ONE
        self._update_balanced(n_p)
        self.photons_emitted += n_p
        self.work_done += n_p

    def _measurement_points(self, it):
        """The camera pass of iteration `it` (camera_paths paths per pixel) and the grid over its MPs."""
        k = self.camera_paths
        # MPs past this pass's are cleared up to the last pass's, which may have used more.
        in_use = max(k, self.camera_paths_last) * self.n_pixels
        self.twins_now = self._twins_due(it)
        self._camera_pass(self.seed_u32, it, self.max_depth, self.initial_radius, self.radius_pixels * self.pixel_angle,
                          k, in_use, *self.pixel_passes.take(k), int(self.twins_now))
        self._init_radii(k)
        if self.probed_disc:
            self._clip_discs(in_use, int(it % PROBE_ALL_EVERY == 0))
        self.grid.build(self.mp_p, self.mp_radius, self.mp_valid, in_use)
        self.camera_paths_last = k

    def _twins_due(self, it: int) -> bool:
        """Whether pass `it` traces twin camera paths: where the effort balance steers something
        and the pixel positions are stratified, in every pass of the first TWINS_FIRST after
        the first (which has no last pass to set against) and in one of TWINS_EVERY after
        that (docs/effort.md, "Twin camera paths")."""
        if not (self.held_camera and self.effort is not None and it >= 1):
            return False
        return it <= TWINS_FIRST or it % TWINS_EVERY == 0

    def _update_balanced(self, n_p: int):
        """The progressive update, and the effort balance's view of this iteration."""
        k = self.camera_paths
        effort = self.effort
        held = self.held_camera and effort is not None and self.iterations >= 1
        self._update(self.alpha * self.alpha_factor, n_p, k, int(held), int(self.twins_now),
                     float(effort.last_photons or n_p) if held else float(n_p),
                     int(effort.last_camera_paths or k) if held else k, int(self._measures_bias()),
                     int(self._radius_from_last_counts()))
        if self.balanced_radius:
            sums = self._balance_radius_sums()
            self.alpha_factor = ALPHA_FAST if bias_outweighs_noise(sums[0], sums[1], sums[2]) else 1.0
            self.fast_passes += int(self.alpha_factor < 1.0)
            if self.effort is not None and self.options["effort_bias"]:
                self.effort.observe_bias(float(sums[3]), float(sums[4]), float(sums[5]), BIAS_Z)
        if self.effort is None:
            return
        self._effort_sums(self.relative_balance, self.camera_paths_done(), self.photons_emitted + n_p)
        sums = self.effort_sums.to_numpy()
        spread, half, radius_sq, valid, camera_rays, segments, deposits = sums[:7]
        self.pass_segments, self.pass_deposits = float(segments), float(deposits)   # guided.py's pass choice
        self._observe_uniform_weight(*sums[7:10])
        n = float(self.n_pixels)
        if self.twins_now:
            self.twin_passes += 1
            self.twin_pixels_unmatched += float(sums[11])
        self.effort.observe(n_p, spread / n, half / n, radius_sq / max(valid, 1.0),
                            camera_rays + k * n, segments, camera_paths=k,   # rays, and the grid over the MPs
                            deposits=deposits, half_difference_mp=float(sums[12]) / n, keep=self._balance_keeps(),
                            camera_held=float(sums[10]) / n if self.held_camera and self.iterations >= 1 else None,
                            shared_variance=self._shared_photon_variance(float(sums[13]) / n, n_p))
        if self.balanced:
            self.photons_per_iteration = self.effort.next_photons()
        if self.camera_paths_auto:
            self.camera_paths = self.effort.next_camera_paths(n_p, self.max_camera_paths)

    def _shared_photon_variance(self, photon_sq: float, n_p: int) -> float:
        """The variance of this pass's photon estimate that its two halves share, given the
        mean over pixels of its square (guided.py: the chains' normalisation); plain photons
        share none."""
        return 0.0

    def _balance_keeps(self) -> bool:
        """Whether this pass's variances join the effort balance's estimates (guided.py: not a
        pass of the kind not being chosen, nor the pass after one)."""
        return True

    def _radius_from_last_counts(self) -> bool:
        """Whether the radius update counts the photons of the last pass that counted its own
        instead of this pass's (guided.py: a uniform pass among chain passes)."""
        return False

    def _measures_bias(self) -> bool:
        """Whether this pass's probes join the balanced radius rule's sums (guided.py: not a
        pass of the kind not being chosen)."""
        return True

    def _observe_uniform_weight(self, s_chains: float, s_uniform: float, s_product: float):
        """The guided methods choose the uniform photons' weight from these sums (guided.py)."""

    @ti.kernel
    def _camera_pass(self, seed: ti.u32, iteration: ti.u32, max_depth: ti.i32, r_abs: ti.f32, r_per_dist: ti.f32,
                     camera_paths: ti.i32, in_use: ti.i32, first_point: ti.u32, replicate: ti.u32, twins: ti.i32):
        sc = self.dscene
        for j in range(in_use):
            self.mp_valid[j] = 0
            self.mp_direct[j] = ti.Vector([0.0, 0.0, 0.0], ti.f64)
            if j < camera_paths * self.n_pixels:
                i = j % self.n_pixels
                state = rng.seed(seed, ti.u32(j), iteration * ti.u32(2))
                # slot j // pixels of K: the pass's next K points of its replicate (kernels/pixel_samples.py)
                u1, u2 = pixel_samples.pixel_sample(self.sobol_pixels, seed, ti.u32(i),
                                                    first_point + ti.u32(j // self.n_pixels), replicate, ti.u32(0),
                                                    state)
                o, d = sc.camera_ray(i % sc.width, i // sc.width, u1, u2)
                acc = CameraPath(direct=vec3(0.0), pixel=j, r_abs=r_abs, r_per_dist=r_per_dist, rays=1, twin=0,
                                 matched=0)
                camera_walk(sc, o, d, state, max_depth, self, acc)
                direct = acc.direct
                if (direct == direct).all() and direct.max() < ti.math.inf:
                    self.mp_direct[j] = ti.cast(direct, ti.f64)
                else:
                    ti.atomic_add(self.counters[1], 1)
                ti.atomic_add(self.counters[2], acc.rays)
                if twins:
                    # The same ray from the same pixel position, other random numbers; out of the
                    # image and of the counted work (docs/effort.md, "Twin camera paths").
                    twin_state = rng.seed(seed, ti.u32(j) ^ ti.u32(rng.TWIN_BIT), iteration * ti.u32(2))
                    twin = CameraPath(direct=vec3(0.0), pixel=j, r_abs=r_abs, r_per_dist=r_per_dist, rays=1, twin=1,
                                      matched=1 - self.mp_valid[j])
                    # the ray again: camera_walk advances the o and d it is handed
                    o_twin, d_twin = sc.camera_ray(i % sc.width, i // sc.width, u1, u2)
                    camera_walk(sc, o_twin, d_twin, twin_state, max_depth, self, twin)
                    self.mp_twin_direct[j] = self.mp_direct[j]
                    self.mp_twin_matched[j] = 0
                    if (twin.direct == twin.direct).all() and twin.direct.max() < ti.math.inf:
                        self.mp_twin_direct[j] = ti.cast(twin.direct, ti.f64)
                        self.mp_twin_matched[j] = twin.matched

    @ti.kernel
    def _init_radii(self, camera_paths: ti.i32):
        """A pixel's first MP sets its initial radius (its first valid camera path's, in path
        order, so that the choice does not depend on thread timing); every MP of a pixel
        gathers with the pixel's radius."""
        n = self.n_pixels
        for i in range(n):
            for s in range(camera_paths):
                j = s * n + i
                if self.mp_valid[j]:
                    if self.R[i] == 0.0:
                        self.R[i] = ti.max(ti.cast(self.mp_radius[j], ti.f64), 1e-30)
                    self.mp_radius[j] = ti.cast(self.R[i], ti.f32)

    @ti.kernel
    def _clip_discs(self, in_use: ti.i32, probe_all: ti.i32):
        """Each valid MP's share of its disc (and of the half-area disc) on its surface, probed
        (kernels/disc_clip.py) in the pixels where an edge was found before, and in every
        pixel every PROBE_ALL_EVERY passes; elsewhere the full disc (share 1, the plain
        estimator: an edge not yet found costs its bias until the next pass that probes all).
        The probes cost up to 16-48 rays per MP, several times its camera path (fewer where the
        MP's own flat triangle and the triangles near answer them: disc_clip._probe_setup),
        so a pixel whose MPs were found clear for EDGE_MEMORY passes (its radius has shrunk off
        the edge) is probed with the others again. (Probing clear pixels ever more rarely was
        measured and dropped: docs/guiding.md, "What the probes cost".) --disc sealed probes
        for walls alone (disc_walls, up to 8 rays), and its share is the disc's in front of them."""
        n = self.n_pixels
        for j in range(in_use):
            i = j % n
            if ti.static(self.divided_disc):
                self.mp_share[j] = 1.0
                self.mp_share_inner[j] = 1.0
            if ti.static(self.linear_disc):
                self.mp_slope[j] = ti.Vector([0.0, 0.0, 0.0])
                self.mp_slope_inner[j] = ti.Vector([0.0, 0.0, 0.0])
                self.mp_ends[j] = ti.Vector([ti.u32(WHOLE_DISC), ti.u32(WHOLE_DISC)])
            if ti.static(self.sealed_disc):
                self.mp_walls[j] = ti.Vector([ti.u32(NO_WALLS)] * 4)
            if self.mp_valid[j] and (probe_all or self.edge_pixel[i]):
                cut = 0
                if ti.static(self.linear_disc):
                    full, slope, inner, slope_inner, ends = disc_linear_fits(self.dscene, self.mp_p[j],
                                                                             self.mp_n[j], self.mp_radius[j],
                                                                             self.mp_tri[j], True)
                    self.mp_share[j] = full
                    self.mp_share_inner[j] = inner
                    self.mp_slope[j] = slope
                    self.mp_slope_inner[j] = slope_inner
                    self.mp_ends[j] = ends
                    cut = full < 0.999
                elif ti.static(self.clipped_disc):
                    full, inner = disc_shares(self.dscene, self.mp_p[j], self.mp_n[j], self.mp_radius[j],
                                              self.mp_tri[j], True)
                    self.mp_share[j] = full
                    self.mp_share_inner[j] = inner
                    cut = full < 0.999
                else:
                    walls = disc_walls(self.dscene, self.mp_p[j], self.mp_n[j], self.mp_radius[j])
                    self.mp_walls[j] = walls
                    cut = (walls != ti.u32(NO_WALLS)).any()
                    if cut:
                        full, inner = wall_shares(walls)
                        self.mp_share[j] = full
                        self.mp_share_inner[j] = inner
                if cut:
                    self.edge_seen[i] = 1
        for i in range(n):          # after every decision of this pass: deterministic
            if self.edge_seen[i]:
                self.edge_pixel[i] = EDGE_MEMORY
            elif self.edge_pixel[i] > 0:
                self.edge_pixel[i] -= 1
            self.edge_seen[i] = 0

    # -- the camera walk's visitor (kernels/camera_walk.py) ----------------------------
    roulette = THROUGHPUT_ROULETTE

    @ti.func
    def on_surface(self, acc: ti.template(), w, s, wo):
        # Only delta bounces come before the measurement point: emitters get weight 1.
        acc.direct += w.beta * self.dscene.emitted(s.emitter, s.ns, wo)

    @ti.func
    def at_vertex(self, acc: ti.template(), w, s, b: ti.i32, n, t1, t2, wo, wo_l, state: ti.template()) -> ti.i32:
        """The first non-delta vertex: next-event direct light, and the pixel's measurement point."""
        i = acc.pixel           # the MP's index
        acc.direct += w.beta * next_event(self.dscene, s.p, s.ng, b, wo_l, n, t1, t2, state, False)
        acc.rays = w.length + 1           # the segments to here and the shadow ray
        if acc.twin:
            # The same delta choices lead from the same ray to the same point (to the last
            # bits: the walk compiled twice rounds differently): then the MP's photons are the
            # path's too, and only the direct light differs.
            if self.mp_valid[i] == 1 and self.mp_depth[i] == w.length:
                if (ti.abs(s.p - self.mp_p[i])).max() <= 1e-5 * (1.0 + ti.abs(s.p).max()):
                    acc.matched = 1
        else:
            self.mp_p[i] = s.p
            self.mp_n[i] = n
            if ti.static(self.clipped_disc):
                self.mp_tri[i] = s.tri
            self.mp_wo[i] = wo
            self.mp_W[i] = w.beta
            self.mp_bsdf[i] = b
            self.mp_depth[i] = w.length
            self.mp_valid[i] = 1
            r0 = acc.r_abs            # the initial radius, should this be the pixel's first MP (_init_radii)
            if r0 <= 0.0:
                r0 = acc.r_per_dist * w.travelled
            self.mp_radius[i] = r0
        return STOP

    @ti.func
    def after_scatter(self, acc: ti.template(), w, bs, q: ti.f32):
        pass

    @ti.kernel
    def _photon_pass(self, seed: ti.u32, iteration: ti.u32, n_photons: ti.i32, max_segments: ti.i32):
        for p in range(n_photons):
            key = rng.seed(seed, ti.u32(p), iteration * ti.u32(2) + ti.u32(1))
            used, dims = trace_photon(self.dscene, HashSource, key, self, p & 1, max_segments)
            if used:
                ti.atomic_add(self.counters[0], 1)
            ti.atomic_add(self.counters[3], photon_segments(dims))

    @ti.func
    def accepts(self, j: ti.i32, x, n, wi, segments: ti.i32) -> ti.i32:
        """The one deposit predicate: counting, contributing and (later) MCMC targets use it."""
        ok = 0
        if self.mp_valid[j] and self.mp_depth[j] + segments <= ti.static(self.max_depth):
            r = self.mp_radius[j]
            offset = x - self.mp_p[j]
            if offset.norm_sqr() <= r * r:
                nj = self.mp_n[j]
                if wi.dot(nj) > 0.0 and n.dot(nj) >= NORMAL_COS_MIN:
                    ok = 1
                    if ti.static(self.linear_disc):
                        ends = self.mp_ends[j]
                        if ends[0] != ti.u32(WHOLE_DISC) or ends[1] != ti.u32(WHOLE_DISC):
                            t1, t2 = onb(nj)
                            ok = in_region(ends, offset.dot(t1) / r, offset.dot(t2) / r)
                    if ti.static(self.sealed_disc):
                        t1, t2 = onb(nj)
                        ok = not behind_wall(self.mp_walls[j], offset.dot(t1) / r, offset.dot(t2) / r)
        return ok

    @ti.func
    def visit(self, vkey: ti.i32, x, n, wi, beta, segments: ti.i32) -> ti.i32:
        """Deposit a photon vertex into every MP that accepts it."""
        used = 0
        first, end = self.grid.candidates(x)
        for e in range(first, end):
            j = self.grid.entries[e]
            if self.accepts(j, x, n, wi, segments):
                used |= self.deposit_at(j, x, wi, beta, ti.Vector([1.0]), vkey & 1)
        return used

    @ti.func
    def in_inner_disc(self, j: ti.i32, x) -> ti.i32:
        """Whether x lies in MP j's disc of half the area (the balanced radius rule's bias probe)."""
        inner = 0
        if ti.static(self.balanced_radius):
            r = self.mp_radius[j]
            if (x - self.mp_p[j]).norm_sqr() <= 0.5 * r * r:
                inner = 1
        return inner

    @ti.func
    def deposit_at(self, j, x, wi, beta, weights, odd: ti.i32) -> ti.i32:
        """Add the power beta of a photon at x arriving from wi to MP j, weight[l] of it to
        level l's accumulator, and count the photon. `odd`: the photon belongs to the odd half
        of the pass (effort.py). Returns 0 for a non-finite contribution (dropped)."""
        nj = self.mp_n[j]
        t1, t2 = onb(nj)
        f = self.dscene.bsdf_evaluate(self.mp_bsdf[j], to_local(self.mp_wo[j], t1, t2, nj), to_local(wi, t1, t2, nj)).f
        contrib = ti.cast(beta / self.power_scale * f, ti.f64)
        # the photon's weight in the disc and in the disc of half the area (0 outside it)
        disc_weight = ti.f64(1.0)
        inner_weight = ti.cast(self.in_inner_disc(j, x), ti.f64)
        if ti.static(self.linear_disc):
            offset = x - self.mp_p[j]
            disc_weight = 1.0 + ti.cast(self.mp_slope[j].dot(offset), ti.f64)
            inner_weight *= 1.0 + ti.cast(self.mp_slope_inner[j].dot(offset), ti.f64)
        ok = 0
        if (contrib == contrib).all() and contrib.max() * weights.max() < 1e9:
            ti.atomic_add(self.M[j], 1)
            for level in ti.static(range(self.n_acc)):
                if weights[level] > 0.0:
                    flux = contrib * ti.cast(weights[level], ti.f64) * FIXED_ONE
                    fixed = ti.cast(ti.floor(flux * disc_weight + 0.5), ti.i64)     # negative too (linear)
                    for c in ti.static(range(3)):
                        ti.atomic_add(self.phi[level, j][c], fixed[c])
                        if odd:
                            ti.atomic_add(self.phi_odd[level, j][c], fixed[c])
                    if ti.static(self.balanced_radius):
                        if inner_weight != 0.0:
                            fixed_inner = ti.cast(ti.floor(flux * inner_weight + 0.5), ti.i64)
                            for c in ti.static(range(3)):
                                ti.atomic_add(self.phi_inner[level, j][c], fixed_inner[c])
            ok = 1
        return ok

    @ti.kernel
    def _update(self, alpha: ti.f64, n_p: ti.f64, camera_paths: ti.i32, held: ti.i32, twins: ti.i32, n_last: ti.f64,
                camera_paths_last: ti.i32, measure_bias: ti.i32, use_last_counts: ti.i32):
        lum = ti.Vector([0.2126, 0.7152, 0.0722], ti.f64)
        n = self.n_pixels
        k = ti.cast(camera_paths, ti.f64)
        for i in range(n):
            # The pixel's camera paths, in path order (f64 sums in a fixed order): their direct
            # light, photons per valid MP, and W Phi.
            ld = ti.Vector([0.0, 0.0, 0.0], ti.f64)
            m = ti.f64(0.0)
            valid = 0
            w_phi = ti.Vector([0.0, 0.0, 0.0], ti.f64)
            w_phi_odd = ti.Vector([0.0, 0.0, 0.0], ti.f64)
            w_phi_inner = ti.Vector([0.0, 0.0, 0.0], ti.f64)
            # chains' and uniform photons' estimates apart, each at its own scale: even, odd
            w_sep = ti.Matrix([[0.0] * 3] * 4, ti.f64)
            twin_difference = ti.Vector([0.0, 0.0, 0.0], ti.f64)
            unmatched = 0
            halves_sq = ti.f64(0.0)       # sum over MPs of their own photon-half differences, squared
            for s in range(camera_paths):
                j = s * n + i
                ld += self.mp_direct[j]
                if twins:
                    twin_difference += self.mp_direct[j] - self.mp_twin_direct[j]
                    unmatched += 1 - self.mp_twin_matched[j]
                if self.mp_valid[j]:
                    valid += 1
                    m += ti.cast(self.M[j], ti.f64)
                    phi = ti.Vector([0.0, 0.0, 0.0], ti.f64)
                    phi_odd = ti.Vector([0.0, 0.0, 0.0], ti.f64)
                    for level in ti.static(range(self.n_acc)):
                        phi += ti.cast(self.phi[level, j], ti.f64) * self.level_scale[level]
                        phi_odd += ti.cast(self.phi_odd[level, j], ti.f64) * self.level_scale[level]
                    w = ti.cast(self.mp_W[j], ti.f64)
                    w_inner = w
                    if ti.static(self.divided_disc):
                        # the disc's area is pi R^2 x its share on the surface, for every use below
                        w = w / ti.cast(self.mp_share[j], ti.f64)
                        w_inner = w_inner / ti.cast(self.mp_share_inner[j], ti.f64)
                    w_phi += w * phi
                    w_phi_odd += w * phi_odd
                    halves_mp = lum.dot(2.0 * w * phi - 4.0 * w * phi_odd)
                    halves_sq += halves_mp * halves_mp
                    if ti.static(self.balanced_radius):
                        phi_inner = ti.Vector([0.0, 0.0, 0.0], ti.f64)
                        for level in ti.static(range(self.n_acc)):
                            phi_inner += ti.cast(self.phi_inner[level, j], ti.f64) * self.level_scale[level]
                            self.phi_inner[level, j] = ti.Vector([0, 0, 0], ti.i64)
                        w_phi_inner += w_inner * phi_inner
                    if ti.static(self.uniform_accumulator):
                        for level in ti.static(range(self.n_acc)):
                            row = 2 if level == self.n_levels else 0
                            odd = ti.cast(self.phi_odd[level, j], ti.f64)
                            even = ti.cast(self.phi[level, j], ti.f64) - odd
                            for c in ti.static(range(3)):
                                w_sep[row, c] += w[c] * even[c] * self.raw_scale[level]
                                w_sep[row + 1, c] += w[c] * odd[c] * self.raw_scale[level]
                self.M[j] = 0
                for level in ti.static(range(self.n_acc)):
                    self.phi[level, j] = ti.Vector([0, 0, 0], ti.i64)
                    self.phi_odd[level, j] = ti.Vector([0, 0, 0], ti.i64)
            self.deposits[i] = m
            self.Ld[i] += ld              # per camera path: divided by the paths so far (image)
            ld /= k
            self.ld_pass[i] = ld
            # This iteration's estimate of the pixel (direct + its photons alone) and of each
            # half of its photons, for the effort balance (effort.py), before the update.
            inc = ti.Vector([0.0, 0.0, 0.0], ti.f64)
            inc_odd = ti.Vector([0.0, 0.0, 0.0], ti.f64)
            chains, uniform = ti.f64(0.0), ti.f64(0.0)
            self.half_difference_mp[i] = 0.0
            if valid > 0:
                m /= ti.cast(valid, ti.f64)     # photons per MP: the radius follows photon density, not K
            if ti.static(self.balanced_radius):
                if measure_bias and valid > 0 and self.R[i] > 0.0:
                    self._measure_bias(i, lum, w_phi, w_phi_inner, k, n_p)
            # The photons the radius update counts: this pass's, or in a guided method's uniform
            # pass the last chain pass's (guided.py, _radius_from_last_counts).
            m_radius = m
            if ti.static(self.uniform_accumulator):
                if use_last_counts:
                    m_radius = self.last_counts[i] if valid > 0 else 0.0
                else:
                    self.last_counts[i] = m
            if m > 0.0 or m_radius > 0.0:
                r = self.R[i]
                n_old = self.N[i]
                n_new, r_new = n_old, r
                if m_radius > 0.0:
                    n_new = n_old + alpha * m_radius
                    r_new = r * ti.sqrt(n_new / (n_old + m_radius))
                w_phi /= k
                inc = w_phi / (ti.f64(PI) * r * r)
                inc_odd = w_phi_odd / k / (ti.f64(PI) * r * r)
                # half_difference (below) for each MP alone, averaged over the pixel's K: the
                # pixel's is the MPs' mean, so where their photon noises are independent (discs
                # apart) it is 1/K of this, where they share their photons it is this
                # (effort.py, EffortBalance.photon_correlation).
                self.half_difference_mp[i] = halves_sq / (k * n_p * 4.0) / (ti.f64(PI) * r * r) ** 2
                if ti.static(self.uniform_accumulator):
                    # the same even-odd differences for the chains and the uniform photons
                    # apart, each at its own scale (not weighted by its share)
                    area = k * ti.f64(PI) * r * r * n_p
                    d_c = ti.Vector([w_sep[0, 0] - w_sep[1, 0], w_sep[0, 1] - w_sep[1, 1], w_sep[0, 2] - w_sep[1, 2]])
                    d_u = ti.Vector([w_sep[2, 0] - w_sep[3, 0], w_sep[2, 1] - w_sep[3, 1], w_sep[2, 2] - w_sep[3, 2]])
                    chains = lum.dot(2.0 * d_c / area)
                    uniform = lum.dot(2.0 * d_u / area)
                self.D[i] += inc                                        # D form (algorithms.md §1.3)
                self.tau[i] = (self.tau[i] + w_phi) * (r_new * r_new) / (r * r)   # tau form, kept for the test
                self.N[i] = n_new
                self.R[i] = r_new
            estimate = lum.dot(self.ld_pass[i] + inc / n_p)
            self.photon_part[i] = lum.dot(inc / n_p)
            self.spread[i] = (estimate - self.estimate_last[i]) ** 2
            self.estimate_last[i] = estimate
            halves = lum.dot(2.0 * (inc - inc_odd) / n_p) - lum.dot(2.0 * inc_odd / n_p)
            self.half_difference[i] = n_p * halves * halves / 4.0
            if held:
                # V_c per camera path with the pixel positions held (docs/effort.md, "Twin
                # camera paths"). Where every twin reached its path's MP the two estimates
                # share their photons, and the mean of K differences has variance 2 V_c / K.
                # A pixel where a twin once reached another MP (a delta choice that went the
                # other way: glass) is read from consecutive passes instead, every pass, its
                # photons' part taken out: its rare paths (a lamp through glass) are camera
                # error that the positions' stratification does not remove.
                if twins:
                    if unmatched == 0:
                        self.camera_held[i] = lum.dot(twin_difference / k) ** 2 * k / 2.0
                    else:
                        self.camera_stochastic[i] = 1.0
                    self.twin_unmatched[i] = ti.cast(unmatched > 0, ti.f64)
                estimate_c = self.camera_held[i]
                if self.camera_stochastic[i] > 0.0:
                    photons_part = self.half_difference[i] * (1.0 / n_p + 1.0 / n_last)
                    estimate_c = (self.spread[i] - photons_part) / (1.0 / k + 1.0 / ti.cast(camera_paths_last, ti.f64))
                self.camera_estimate[i] = estimate_c
            if ti.static(self.uniform_accumulator):
                self.half_chains[i] = chains
                self.half_uniform[i] = uniform

    @ti.func
    def _measure_bias(self, i, lum, w_phi, w_phi_inner, k, n_p):
        """The balanced radius rule's probe, per pixel and pass: the photons within the disc of
        half the area give a second estimate whose radius bias is smaller. Where the bias
        goes as R^2 (a smooth neighbourhood), outer - inner is half the outer disc's bias;
        where an edge cuts the disc (bias ~ R), about 0.3 of it. Its variance is about that of
        the pixel's photon estimate (the inner disc's photons are in both)."""
        area = k * n_p * ti.f64(PI) * self.R[i] * self.R[i]
        d = (lum.dot(w_phi) - 2.0 * lum.dot(w_phi_inner)) / area
        self.bias_sum[i] += d
        self.bias_sq[i] += d * d
        self.bias_passes[i] += 1.0
        self.bias_radius_sq[i] += self.R[i] * self.R[i]
        self.bias_inverse_radius_sq[i] += 1.0 / (self.R[i] * self.R[i])

    @ti.kernel
    def _balance_radius_sums(self) -> ti.types.vector(6, ti.f64):
        """The balanced radius rule's sums over pixels (methods/merge_radius.py,
        bias_outweighs_noise decides; docs/guiding.md, "The balanced radius with the history's
        ratios").

        Per pixel, mean difference^2 - its squared standard error estimates the image's
        squared bias / 4 (bias ~ 2 x the difference where it goes as R^2, more near edges),
        and the squared standard error its photon variance. The image averages every pass
        (the D form), each at its own radius, so the next pass changes the bias by R^2 /
        mean(R_t^2) of the image's and adds noise as R^-2 / mean(R_t^-2) of the image's
        variance: rho_b and rho_v, each pixel's own, weigh its terms, and the early wide
        passes' bias, which no later pass can undo, does not keep the rule firing (the
        lesson of vcm's rule, docs/vcm.md). R here is the next pass's radius at this pass's
        step. Summing over the image, as the RMSE does, lets a bias show that no single
        pixel's noise lets through; the standard error (each pixel's term has variance about
        2 x 16 se^4 where it has no bias) keeps a few pixels' rare bright photons from
        passing for bias. Any mix of alpha and ALPHA_FAST x alpha steps keeps SPPM
        consistent: the radii still go to 0 and the photons to infinity. A serial loop: a
        fixed summation order keeps the image deterministic. The last three are the same
        sums at the pixels' radii now (the bias by rho_b^2: a pass at R has bias rho_b x the
        image's), for the effort balance (effort.py, observe_bias)."""
        bias_sq, variance, spread = ti.f64(0.0), ti.f64(0.0), ti.f64(0.0)
        now_bias_sq, now_variance, now_spread = ti.f64(0.0), ti.f64(0.0), ti.f64(0.0)
        ti.loop_config(serialize=True)
        for i in range(self.n_pixels):
            n = self.bias_passes[i]
            if n >= BIAS_MIN_PASSES and self.R[i] > 0.0:
                mean = self.bias_sum[i] / n
                se_sq = ti.max(self.bias_sq[i] / n - mean * mean, 0.0) / (n - 1.0)
                r_sq = self.R[i] * self.R[i]
                rho_b = r_sq * n / self.bias_radius_sq[i]
                rho_v = n / (r_sq * self.bias_inverse_radius_sq[i])
                bias_sq += rho_b * 4.0 * (mean * mean - se_sq)
                variance += rho_v * se_sq
                spread += rho_b * rho_b * 32.0 * se_sq * se_sq
                now_bias_sq += rho_b * rho_b * 4.0 * (mean * mean - se_sq)
                now_variance += rho_v * se_sq
                now_spread += rho_b ** 4 * 32.0 * se_sq * se_sq
        return ti.Vector([bias_sq, variance, spread, now_bias_sq, now_variance, now_spread], ti.f64)

    @ti.kernel
    def _effort_sums(self, relative: ti.template(), camera_paths: ti.f64, photons: ti.f64):
        """Sums over pixels for the effort balance, in one fixed order (a serial loop), so
        that the photon count it picks, and so the image, does not depend on thread timing.
        relative (--balance relmse): each pixel's terms weighted by 1 / (m^2 + eps), m its
        running estimate after `camera_paths` camera paths per pixel and `photons` photons in
        all, eps = (0.1 x the image's mean m)^2 (converge's relMSE)."""
        sums = ti.Vector([0.0] * 12, ti.f64)
        lum = ti.Vector([0.2126, 0.7152, 0.0722], ti.f64)
        eps = ti.f64(0.0)
        if ti.static(relative):
            ti.loop_config(serialize=True)
            for i in range(self.n_pixels):
                eps += lum.dot(self.Ld[i] / camera_paths + self.D[i] / photons)
            eps = ti.max((0.1 * eps / ti.static(self.n_pixels)) ** 2, 1e-30)
        ti.loop_config(serialize=True)
        for i in range(self.n_pixels):
            weight = ti.f64(1.0)
            if ti.static(relative):
                m = lum.dot(self.Ld[i] / camera_paths + self.D[i] / photons)
                weight = 1.0 / (m * m + eps)
            sums[0] += weight * self.spread[i]
            sums[1] += weight * self.half_difference[i]
            sums[10] += weight * self.half_difference_mp[i]
            sums[11] += weight * self.photon_part[i] ** 2
            sums[8] += weight * self.camera_estimate[i]
            sums[9] += self.twin_unmatched[i]
            sums[4] += self.deposits[i]
            if ti.static(self.uniform_accumulator):
                c, u = self.half_chains[i], self.half_uniform[i]
                sums[5] += c * c
                sums[6] += u * u
                sums[7] += c * u
            if self.mp_valid[i]:       # the pixel's first camera path stands for its radius
                r = ti.cast(self.mp_radius[i], ti.f64)
                sums[2] += r * r
                sums[3] += 1.0
        for k in ti.static(range(4)):
            self.effort_sums[k] = sums[k]
        self.effort_sums[4] = ti.cast(self.counters[2], ti.f64)
        self.effort_sums[5] = ti.cast(self.counters[3], ti.f64)
        self.effort_sums[6] = sums[4]
        for k in ti.static(range(3)):
            self.effort_sums[7 + k] = sums[5 + k]     # chains, uniform photons, product
        self.effort_sums[10] = sums[8]                # twins: V_c with positions held, pixels unmatched
        self.effort_sums[11] = sums[9]
        self.effort_sums[12] = sums[10]               # half_difference per MP
        self.effort_sums[13] = sums[11]               # the photon estimates squared
        self.counters[2] = 0
        self.counters[3] = 0

    # -- results ----------------------------------------------------------------------
    def camera_paths_done(self) -> int:
        """Camera paths per pixel traced so far (the pixel's points taken from its sequences)."""
        return self.pixel_passes.points_even + self.pixel_passes.points_odd

    def image(self):
        h, w = self.dscene.height, self.dscene.width
        ne = max(self.photons_emitted, 1)
        direct = self.Ld.to_numpy() / max(self.camera_paths_done(), 1)
        if self.tau_form:
            r = self.R.to_numpy()[:, None]
            area = np.where(r > 0, math.pi * r * r, 1.0)
            indirect = self.tau.to_numpy() / area / ne
        else:
            indirect = self.D.to_numpy() / ne
        return (direct + indirect).reshape(h, w, 3)

    def progress_fields(self) -> str:
        r = self.R.to_numpy()
        return f"radius {r[r > 0].mean():.3g}" if (r > 0).any() else ""

    def method_stats(self):
        c = self.counters.to_numpy()
        r = self.R.to_numpy()
        seen = r > 0
        return {"photons_per_iteration": self.photons_per_iteration, "photons_emitted": self.photons_emitted,
                "camera_paths_per_pixel": self.camera_paths,
                "camera_paths_per_pixel_auto": self.camera_paths_auto,
                "fraction_of_photon_paths_depositing": float(c[0]) / max(self.photons_emitted, 1),
                "mean_radius": float(r[seen].mean()) if seen.any() else None,
                "alpha": self.alpha, "nonfinite_samples_dropped": int(c[1]),
                "radius_rule": self.options["radius_rule"],
                **({"passes_shrunk_fast": self.fast_passes} if self.balanced_radius else {}),
                "effort": {"balanced": self.balanced and self.effort is not None,
                           **(self.effort.stats() if self.effort is not None else {}),
                           "camera_variance_from": ("auto" if self.camera_variance_auto else "twins")
                           if self.held_camera else "pairs",
                           **({"twin_passes": self.twin_passes,
                               "twin_pixels_unmatched_share": self.twin_pixels_unmatched
                               / max(self.twin_passes * self.n_pixels, 1)} if self.held_camera else {})}}

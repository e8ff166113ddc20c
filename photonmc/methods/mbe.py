"""Metropolised bidirectional estimators (Sik, Otsu, Hachisuka, Krivanek 2016; docs/mbe.md).

VCM whose light subpaths come from Markov chains in primary sample space, evaluated against
the iteration's stored camera subpaths. Each iteration:
1. camera pass: K stratified subpaths per pixel (vcm's camera walk; K chosen per pass by
   the effort balance of methods/effort.py with --camera-paths auto, the default) add the
   camera-only techniques straight to the frame (emitter hits, next-event estimation) and
   store every non-delta vertex, with its MIS partial sums, by pixel and in a hash grid of
   radius r_i;
2. chain pass: `--light-paths` steps of the chain ladders (kernels/mcmc.py). A state u is one
   light subpath plus one coordinate that picks the camera subpath it connects to; evaluating
   it traces the light subpath and, at each non-delta light vertex, traces it to the camera,
   connects it to every vertex of the paired camera subpath and merges it with every camera
   vertex within r_i. Its splat list F(u) is what it adds to the image;
3. two chains per ladder: level 0 targets T_V = 1[F(u) != 0] (uniform proposals, the H&J
   loop), level 1 targets T_C = luminance of F(u) (mutations only, started from its last
   state where that still contributes, the warm start, else by resampling the bootstrap's
   uniform proposals), replica exchange between them; the contribution chain
   records the second half of each pass only (start-up bias, BOOTSTRAP_FRACTION), the
   visibility chain, exact from its first visible uniform proposal, the whole pass, and the
   exchanges wait for the second half (option base_in_burn_in). Each record splats
   F(u) w / (b_l (T_V/b'_V + T_C/b'_C)) times b_l n / N_l (balance heuristic between the
   chains, b' the previous iteration's normalisations, N_l the level's recorded weight);
4. the chains' splats are kept per level, scaled by the pass's b_l at its end and added to
   the frame, which becomes one sample of every pixel (SplatFilm) of weight K, the pass's
   camera subpaths per pixel;
5. the chains' estimate of the light side is set against the uniform proposals' (plain Monte
   Carlo, unbiased): where the chains' start-up bias has come to outweigh the film's noise,
   the chain passes double in length (methods/chain_bias.py).

Pairing: the camera subpath comes from a coordinate of u, so T(u) is a function of the state
alone (what a Markov chain needs) and a uniform proposal pairs uniformly over the pixels; a
connection therefore counts n_pixels / N_L times (VCM pairs path i with pixel i, the same
estimator in expectation when N_L = pixels).

MIS: `--mis plain` (default) keeps VCM's weights; `--mis modified` counts the camera-only
techniques b_V times (kappa in kernels/vcm_mis.py): chain samples have density 1/b_V on the
support of T_V. Both are unbiased (the weights of each full path sum to one); plain measured
lower error on both gap-lit scenes (docs/mbe.md).

Effort balance (--camera-paths auto): the light side's variance from the even against the
odd ladders (light_frame per level and ladder parity), the camera side's from consecutive
iterations, work counted; K = N_L / n* (docs/mbe.md, "The defaults").

vcm passes: a pass may instead be one of vcm's (independent light subpaths, one camera
subpath per pixel, into a film of its own) where it removes more error per unit of work: by both
kinds' measured variance per pass (--vcm-passes measured, the default since stop 42), or as
the chain passes' measurements predict (auto); chain passes then keep a share of the work
(methods/pass_choice.py; docs/mbe.md, "vcm passes where the chains do not pay", "Measured
variances at the work they were measured at"). The image combines the chain passes' film
and the vcm passes' by their measured variances per pass (methods/film_weights.py).
"""
import math
import time

import numpy as np
import taichi as ti

from .. import runtime
from ..errors import SettingsError
from ..kernels import pixel_samples, rng, vcm_techniques
from ..kernels.camera_walk import CONTINUE
from ..kernels.batch import download_fields, fill_fields
from ..kernels.fields import FieldGroup
from ..kernels.mcmc import (
    ACCEPTED,
    DEPOSIT,
    MODE_BITS,
    MUTATIONS,
    N_COUNTERS,
    PROBE,
    SEEDED_COPIED,
    STATE_MODE,
    SEEDED_RESAMPLED,
    SWAPS_ACCEPTED,
    SWAPS_TRIED,
    UNIFORM,
    UNIFORM_MODE,
    UNIFORM_VISIBLE,
    ChainPool,
)
from ..kernels.photon import dimensions, photon_segments, trace_photon
from ..kernels.sampling import luminance, vec3
from ..kernels.subpath_store import BYTES_PER_STORED_VERTEX
from ..kernels.vcm_mis import PathVertex
from .base import MethodSettings
from .chain_bias import ChainBias
from .effort import EffortBalance, UniformWeight, uniform_weight_option
from .film_weights import count_weights, film_weights, shrunk_log_ratio
from .guided import LADDER_BURN_IN
from .light_balance import LightPathBalance
from .pass_choice import BatchMeansVariance, PassChoice, TwinVariance
from .pass_length import BalancedPassLength, recorded_share
from .vcm import DEFAULT_RADIUS_PIXELS, PI, Vcm
from ..taichi_frontend import data_oriented

PASS_KINDS = ("chain", "vcm", "exploring_vcm")     # the kinds of pass _iterate makes

LEVELS = ("visibility", "contribution")


@data_oriented
class _ChainModel:
    """What the chain pool and the light tracer see of mbe: the model interface of
    kernels/mcmc.py and the light-vertex visitor of kernels/photon.py, bound to one camera-
    vertex store and grid. Kernels specialise on this object, so a grown store gets a new one
    (and the chain kernels compile anew) instead of kernels that still read the old fields."""
    visits_from_segment = 1
    with_mis = True

    def __init__(self, mbe, store, grid):
        self.mbe, self.store, self.grid = mbe, store, grid

    @ti.func
    def mis_constants(self):
        return self.mbe.mis_constants()

    @ti.func
    def trace(self, source: ti.template(), key, vkey, mode, w, t):
        return self.mbe.trace_light_subpath(self, source, key, vkey, mode, w, t)

    @ti.func
    def visit_vertex(self, vkey: ti.i32, lv) -> ti.i32:
        return self.mbe.visit_light_vertex(self.store, self.grid, vkey, lv)

    @ti.func
    def adopt(self, ladder, slot):
        self.mbe.adopt(ladder, slot)
# Ladders run in parallel, one thread each. Every ladder must meet several visible uniform
# proposals per pass (its visibility chain is exact only from the first, its contribution
# chain starts from the bootstrap's), so more ladders mean longer passes where visibility is
# rare; 4 keep 2-4 CPU threads busy (the guided photon methods' choice, methods/guided.py).
DEFAULT_CHAINS = 4
REGENERATIONS = 16     # visible uniform proposals each ladder should meet per pass
# ... at most: with --pass-length balanced (the default) the effort balance shortens a chain
# pass toward MIN_REGENERATIONS where the camera side carries the error (methods/pass_length.py;
# docs/mbe.md, "Chain passes as long as the camera side allows"). The guided photon methods go
# down to 1/4 (methods/guided.py); for mbe that was mixed at 20 s (pinhole bay 0.96x, ceiling
# pinhole 1.10x, two-gap 0.99x, light bay 1.00x; docs/mbe.md, stop 67), so it keeps one.
MIN_REGENERATIONS = 1
MAX_PASS_FACTOR = 64   # a pass takes at most this many times --light-paths chain steps
MAX_CHAINS = 1 << 16
# One proposal per chain step, a uniform one (large step) with this probability: the value of
# both reference implementations (algorithms.md §4.2); 0 makes every move every step.
LARGE_STEP = 0.3
# --uniform-weight auto raises the large-step probability to beta (methods/effort.py's
# UniformWeight), at most to this.
MAX_LARGE_STEP = 0.95
BOOTSTRAP_HITS = 8       # visible uniform proposals a contribution chain's start is resampled from
# The contribution chain makes small steps only and mixes slowly from its resampled start:
# recorded from that start, the gap-lit room's contribution level came out 3 % low (whole
# image -3.3 % against vcm's -1.9 %; the bias shrank the later the recording began). So the
# ladders discard the first half of each pass, as spatial-tf's do (LADDER_BURN_IN), and the
# bootstrap ends by the first quarter, so that the chain mixes for a quarter of the pass or
# more before it records (whole image -1.9 %, -1.6 % for two seeds; docs/mbe.md, "Start-up").
BOOTSTRAP_FRACTION = 0.25
# The visibility chain needs no burn-in: it is exact from its first visible uniform proposal,
# and only exchanges with the burning-in contribution chain would disturb it. So it records
# the whole pass and the exchanges start with the second half (option base_in_burn_in):
# RMSE x0.90-0.95 at equal iterations on three gap-lit rooms, 1.00 on the attic and the
# slatted-window rooms (docs/mbe.md, "The visibility chain through the burn-in").
# Several camera subpaths per pixel may share one chain pass (--camera-paths), as several
# camera paths share one photon pass in the guided methods (docs/effort.md): a pass is long
# where few light subpaths contribute, and one camera subpath per pixel then leaves the
# camera-side error (emitter hits, next-event estimation) to few samples.
MAX_CAMERA_PATHS = 64
CAMERA_SUBPATH_BUDGET = 1 << 20
# --camera-paths auto: the effort balance (methods/effort.py) picks K per pass from the
# camera-side and light-side variances it measures, within fields sized for the most it may
# pick (allocated once, so that a rising K never recompiles the chain kernel mid-render):
# 16 at up to 128x128, 8 at 256x256 (the store then holds 2^21 vertices, 0.26 GB).
MAX_AUTO_CAMERA_PATHS = 16
AUTO_SUBPATH_BUDGET = 1 << 19
SPLAT_LIST_CAPACITY = 1024   # entries kept per splat list (16 bytes each); longer lists are traced again


@data_oriented
class Mbe(Vcm):
    name = "mbe"
    work_unit = "paths"
    default_iterations = 64
    balances_light_paths = False        # --light-paths: chain steps per pass
    measures_merging_bias = False       # its camera side merges nothing (its vcm passes' Vcm measures)
    independent_iterations = False      # the chains carry their states and mutation sizes on
    OPTIONS = {"light_paths": None, "alpha": 0.75, "radius": None, "radius_pixels": DEFAULT_RADIUS_PIXELS,
               "radius_rule": "balanced", "chains": None, "target_acceptance": 0.234, "mis": "plain", "large_step": LARGE_STEP,
               "base_in_burn_in": True, "camera_paths": "auto", "warm_start": True,
               "balance": "mse", "uniform_weight": "auto", "vcm_passes": "measured", "film_weights": "variance",
               "pixel_samples": "sobol", "pass_length": "balanced"}
    # The camera vertices live for one iteration; the chain model is bound to their store.
    TRANSIENT = ("store", "grid", "chain_model", "_models")
    n_levels = 2
    # A chain pass joins the film at the weight of its K camera subpaths per pixel (film.py;
    # docs/mbe.md, "Chain passes weighed by their camera subpaths")
    weighted_film = True

    def __init__(self, dscene, settings):
        # The camera subpaths per pixel size the vertex store, which Vcm.__init__ allocates.
        # auto (the default) needs two ladders or more; with one, K stays 1 unless asked for.
        camera_paths = settings.options.get("camera_paths")
        if camera_paths is None and settings.options.get("chains") == 1:
            camera_paths = 1
        self.camera_paths, self.camera_paths_auto, self.max_camera_paths = self._camera_paths_option(
            camera_paths, dscene.width * dscene.height)
        super().__init__(dscene, settings)
        opts = self.options
        if opts["mis"] not in ("modified", "plain"):
            raise SettingsError(f"--mis must be 'modified' or 'plain', got '{opts['mis']}'")
        self.modified_mis = opts["mis"] == "modified"
        self.n_chains = int(opts["chains"] if opts["chains"] is not None else DEFAULT_CHAINS)
        if not 1 <= self.n_chains <= MAX_CHAINS:
            raise SettingsError(f"--chains must be between 1 and {MAX_CHAINS}, got {self.n_chains}")
        if opts["balance"] not in ("mse", "relmse"):
            raise SettingsError(f"--balance must be 'mse' or 'relmse', got '{opts['balance']}'")
        self.relative_balance = opts["balance"] == "relmse"
        uniform_weight_option(opts["uniform_weight"])     # checked here, used from _reset_chains
        if self.camera_paths_auto and self.n_chains < 2:
            raise SettingsError("--camera-paths auto needs --chains 2 or more: the balance measures the light "
                                "side's variance from two independent halves of the ladders (docs/mbe.md)")
        if self.n_light < self.n_chains:
            raise SettingsError(f"--light-paths ({self.n_light}) must be at least --chains ({self.n_chains}): "
                                f"every chain takes steps")
        self.target_acceptance = float(opts["target_acceptance"])
        if not 0.0 < self.target_acceptance < 1.0:
            raise SettingsError(f"--target-acceptance must be in (0, 1), got {self.target_acceptance}")
        self.pair_dim = dimensions(self.max_light_segments)
        self.large_step = float(opts["large_step"])
        if not 0.0 <= self.large_step < 1.0:
            raise SettingsError(f"--large-step must be in [0, 1), got {self.large_step}")
        if opts["pass_length"] not in ("balanced", "regenerations"):
            raise SettingsError(f"--pass-length must be 'balanced' or 'regenerations', got '{opts['pass_length']}'")
        # The choice reads K = n / n* from the balance, so only where the balance chooses K.
        self.balanced_length = opts["pass_length"] == "balanced" and self.camera_paths_auto
        self.pool = ChainPool(self.n_chains, self.n_levels, self.pair_dim + 1, seeding="resample",
                              bootstrap=BOOTSTRAP_FRACTION, bootstrap_hits=BOOTSTRAP_HITS,
                              burn_in=LADDER_BURN_IN, large_step=self.large_step,
                              base_records_in_burn_in=bool(opts["base_in_burn_in"]),
                              warm_start=bool(opts["warm_start"]), store_read=True)
        w, h, c = dscene.width, dscene.height, self.n_chains
        f = FieldGroup("mbe-chains")
        self.visit_mode = f.scalar(ti.i32, c)
        self.pair = f.scalar(ti.i32, c)                  # the camera subpath a state connects to
        self.n_subpaths = f.scalar(ti.i32, ())           # camera subpaths this iteration (K x pixels)
        self.probe_sum = f.vector(3, ti.i64, c)          # F(u) in fixed point (order-independent)
        self.deposit_weight = f.vector(self.n_levels, ti.f32, c)
        # Per level and ladder parity (index 2 level + ladder % 2): the even and odd ladders'
        # halves of the light side, which the effort balance compares (methods/effort.py).
        self.light_frame = f.vector(3, ti.i64, (2 * self.n_levels, h, w))
        # The uniform proposals' own estimate of the light side (plain Monte Carlo: every
        # uniform proposal's splat list, visible or not), per ladder parity; it joins the
        # chains' with the weight beta (methods/effort.py's UniformWeight).
        self.uniform_frame = f.vector(3, ti.i64, (2, h, w))
        self.uniform_probe = f.scalar(ti.i32, c)         # 1 while ladder c probes a uniform proposal
        self.last_estimate = f.scalar(ti.f64, w * h)     # last iteration's luminance per pixel (effort)
        self.batch_sum = f.scalar(ti.f64, w * h)         # the same summed over a batch of chain passes
        self.row_sums = f.vector(7, ti.f64, h)            # _end_pass's sums per image row
        self.b_mis = f.scalar(ti.f32, self.n_levels)     # previous pass's normalisations (MIS only)
        self.pre_scale = f.scalar(ti.f32, self.n_levels)  # previous pass's level scales (see deposit)
        # light subpaths traced, their segments, their shadow rays, the camera vertices they
        # tried to merge with (the work the effort balance counts), and the shadow rays of
        # their connections alone (stats: tools/vcm_pass_split.py)
        self.light_counters = f.scalar(ti.i64, 5)
        self._norms = f.vector(3, ti.f32, ())            # merging, pairing, light-tracing normalisations
        # Splat lists: one per chain slot (the state's) and one per ladder (its last probe,
        # `adopt`ed by the slot that accepts it), so that a state deposits without being traced
        # again. count > SPLAT_LIST_CAPACITY: overflowed, traced again.
        n_lists = self.pool.n_slots + c
        self.list_pixel = f.scalar(ti.i32, (n_lists, SPLAT_LIST_CAPACITY))
        self.list_value = f.vector(3, ti.f32, (n_lists, SPLAT_LIST_CAPACITY))
        self.list_count = f.scalar(ti.i32, n_lists)
        self.list_stats = f.scalar(ti.i64, 4)           # deposits from a list, overflows, entries and lists adopted
        f.finalize()
        self.chain_fields = f
        if opts["vcm_passes"] not in ("auto", "measured", "off"):
            raise SettingsError(f"--vcm-passes must be 'auto', 'measured' or 'off', got '{opts['vcm_passes']}'")
        if opts["film_weights"] not in ("variance", "equal"):
            raise SettingsError(f"--film-weights must be 'variance' or 'equal', got '{opts['film_weights']}'")
        # vcm passes (methods/pass_choice.py): a Vcm with its own film (the image combines the
        # two, methods/film_weights.py), its light subpaths --light-paths, its radius set by
        # this method's index.
        self.independent = None
        if opts["vcm_passes"] in ("auto", "measured"):
            self.independent = Vcm(dscene, MethodSettings(settings.seed, settings.max_depth, {
                "light_paths": self.n_light, "alpha": self.alpha, "radius": opts["radius"],
                "radius_pixels": opts["radius_pixels"], "measure_passes": True,
                "pixel_samples": opts["pixel_samples"]}))
            # One radius schedule for both kinds of pass, indexed by this method's camera subpaths
            # per pixel; the balanced rule reads the bias from the vcm passes' film, the only one
            # that measures it (the chain passes merge on the light side).
            self.independent.radius_schedule = self.radius_schedule
        self._reset_chains()

    @staticmethod
    def _camera_paths_option(value, n_pixels: int) -> tuple[int, bool, int]:
        """--camera-paths K (camera subpaths per pixel per iteration, at most MAX_CAMERA_PATHS
        and CAMERA_SUBPATH_BUDGET subpaths in all) or auto, the default: (K to start with,
        auto, most)."""
        k = "auto" if value is None else value
        if k == "auto":
            return 1, True, max(1, min(MAX_AUTO_CAMERA_PATHS, AUTO_SUBPATH_BUDGET // n_pixels))
        most = max(1, min(MAX_CAMERA_PATHS, CAMERA_SUBPATH_BUDGET // n_pixels))
        if not isinstance(k, (int, np.integer)) or isinstance(k, bool) or not 1 <= k <= most:
            raise SettingsError(f"--camera-paths for mbe must be 'auto' or a number from 1 to {most} at this "
                                f"resolution (at most {CAMERA_SUBPATH_BUDGET} camera subpaths per iteration), "
                                f"got '{value}'")
        return int(k), False, int(k)

    def _stored_paths(self) -> int:
        """mbe stores the camera subpaths' vertices: as many subpaths per pixel as it may trace."""
        return self.n_pixels * self.max_camera_paths

    def _index_serial(self, n_paths: int) -> tuple[bool, bool]:
        """Whether the camera side's index_vertices loops run serially: decided by the most
        camera subpaths a pass may trace and the store's capacity, not by this pass's K (as
        vcm's rule would), so that one variant of _camera_side serves the render. Decided per
        pass, K's first moves (1 -> 4 -> 5 at 80x60) crossed runtime.SERIAL_ITEMS and compiled
        two more variants mid-render: 0.15-0.35 s each from the offline cache, about 1 s cold,
        inside converge's timed render (warm_up compiles the variant it runs)."""
        most = self._stored_paths()
        slots = self.grid.table_slots(max(self.store.capacity, most)) if self.grid is not None else 0
        return runtime.serial_loop(most), runtime.serial_loop(slots)

    def _allocate_store(self, capacity: int):
        super()._allocate_store(capacity)
        # Every model stays alive: a kernel specialised on a freed one must never match a new
        # object that happens to get its id.
        self._models = getattr(self, "_models", [])
        self.chain_model = _ChainModel(self, self.store, self.grid)
        self._models.append(self.chain_model)

    def release(self):
        self.pool.release()
        self.chain_fields.release()
        if self.independent is not None:
            self.independent.release()
        super().release()

    def _reset(self):
        super()._reset()
        self.pool.reset()
        if self.independent is not None:
            self.independent.reset()          # its film, counters and merging-bias sums; the schedule is this one's
        self._reset_chains()

    def _reset_chains(self):
        fill_fields([(self.b_mis, 1.0), (self.pre_scale, 1.0), (self.light_counters, 0), (self.light_frame, 0),
                     (self.uniform_frame, 0), (self.list_stats, 0), (self.last_estimate, 0.0),
                     (self.batch_sum, 0.0)])
        # beta, the uniform proposals' share of the light side (methods/effort.py)
        self.beta = UniformWeight(self.options["uniform_weight"])
        if self.camera_paths_auto:
            self.camera_paths = 1
        self.pool.large_step = self.large_step
        # Steers K with auto; stats. V_c untrimmed: see EffortBalance.shares.
        self.effort = EffortBalance(self.n_pixels, self.n_light, self.alpha, trim_camera=False)
        self.light_work_last = np.zeros(5)      # light_counters after the last pass
        self.measured_last = False              # the last chain pass was a measurement pass at K = 1
        self.pass_choice = PassChoice(self.n_light, self.independent is not None, self.n_pixels,
                                      measured=self.options["vcm_passes"] == "measured")
        self.chain_batches = BatchMeansVariance(self.n_pixels)
        self.batch_passes = 0
        self.batch_weight = 0           # the batch's camera subpaths per pixel, summed
        # the chains' own bias against the uniform proposals', and the pass length it asks for
        self.chain_bias = ChainBias()
        # the vcm passes' light subpaths, measured as vcm's own are (methods/light_balance.py)
        self.light_balance = LightPathBalance(self.n_light)
        # ... and their variance with the pixel positions held, where the films stratify them
        # (pass_choice.TwinVariance): what the kinds are compared and the films weighed by
        self.twins = TwinVariance() if self.independent is not None and self.independent.sobol_pixels else None
        self.totals = np.zeros((self.n_levels, N_COUNTERS), np.int64)
        # pre_scale's and b_mis's values, read without a kernel. Before a pass has measured
        # them, the contribution level's (a luminance, in radiance units) start at the
        # brightest emitter's radiance: a scene's image then scales with its emitters' radiance
        # from the first pass (tests/test_mbe.py), where a start of 1 weighted the first pass's
        # levels differently in watts than in kilowatts, and put its contribution splats at a
        # fixed-point precision relative to the emitters, not to their own size.
        start = np.array([1.0] + [self.film.radiance_scale] * (self.n_levels - 1))
        self.pre_scale_host = start.astype(np.float32)
        self.b_mis_host = start.astype(np.float32)
        self.steps_last = self.n_light
        self.steps_sum = 0
        self.pass_length = BalancedPassLength()     # the visible counts and recorded shares it goes by
        self.regeneration_steps = self.n_light     # the length the regeneration rule asked for (stats)
        self.planned_regenerations = 0.0           # visible uniform proposals per ladder the pass was sized for
        self.camera_paths_traced = 0        # camera subpaths per pixel so far: the radius's index
        # Each kind's passes (exploring ones included) in the pixels' sequences, one pair of
        # sequences per kind (kernels/pixel_samples.py)
        self.chain_pixel_passes = pixel_samples.PassSamples()
        self.vcm_pixel_passes = pixel_samples.PassSamples()
        self.b_last = np.zeros(self.n_levels)
        self.b_sum = np.zeros(self.n_levels)
        self.passes_with_b = 0
        self.vertices_sum = 0
        self.seconds_by_kind = np.zeros(len(PASS_KINDS))

    # -- the iteration -----------------------------------------------------------------
    def _steps_this_pass(self) -> int:
        """--light-paths chain steps (times ChainBias's factor, which doubles where the chains'
        start-up bias outweighs the film's noise), more where the last pass's visible fraction
        b_V would leave a ladder fewer than REGENERATIONS visible uniform proposals (twice the last
        length after a pass that found none), at most MAX_PASS_FACTOR x --light-paths. With
        --pass-length balanced the effort balance then shortens that, down to MIN_REGENERATIONS
        per ladder, where it expects a shorter pass to serve the image better
        (_balanced_pass_length). The pass's light subpath count N_L is this length: the MIS
        counts and normalisations follow it. (A pass that grew toward the balance's n* where K
        is 1 ran away on the caustic: 4096 -> 45k steps, RMSE 2.6x: V_p N_L grows with N_L,
        chains' records being correlated over a pass, and the radius, shrinking per pass,
        stayed large; a pass that shrank toward n* below --light-paths where the camera side
        dominates helped the caustic and the Cornell box and lost 4-13 % in four gap-lit rooms;
        docs/mbe.md.)"""
        n = min(self.n_light * self.chain_bias.factor, MAX_PASS_FACTOR * self.n_light)
        floor = n
        longest = n
        b_sized = 0.0
        if self.iterations > 0:
            b0 = b_sized = self.b_last[0]
            want = self.steps_last * 2 if b0 <= 0 else \
                math.ceil(REGENERATIONS / (b0 * self._uniform_per_step())) * self.n_chains
            n = max(n, min(int(want), MAX_PASS_FACTOR * self.n_light))
            longest = n
            b_fading = self.pass_length.visible_share()
            if self.balanced_length and b_fading > 0 and n > floor:
                shorter = self._balanced_pass_length(n, floor, b_fading)
                if shorter < n:
                    n, b_sized = shorter, b_fading
        self.regeneration_steps = longest
        self.planned_regenerations = b_sized * self._uniform_per_step() * n / self.n_chains
        self.pass_length.record(float(self._recorded_share([n], b_sized)[0]) if b_sized > 0 else 1.0)
        self.steps_last = n
        self.steps_sum += n
        return n

    def _uniform_per_step(self) -> float:
        """Uniform proposals per chain step: the large-step probability (every step with 0)."""
        return self.pool.large_step if self.pool.large_step > 0 else 1.0

    def _recorded_share(self, lengths, b0: float):
        """pass_length.recorded_share for chain passes of `lengths` steps: the visibility chain
        records from its first visible uniform proposal of the pass (through the contribution
        chain's burn-in: base_in_burn_in, the default), and the light side's variance per step
        is taken to follow its records."""
        regenerations = np.asarray(lengths, float) * b0 * self._uniform_per_step() / self.n_chains
        return recorded_share(regenerations, 0.0 if self.pool.base_records_in_burn_in else self.pool.burn_in)

    def _balanced_pass_length(self, longest: int, floor: int, b0: float) -> int:
        """The chain pass length between MIN_REGENERATIONS and REGENERATIONS visible uniform
        proposals per ladder (`longest`) that the effort balance expects to serve the image
        best (EffortBalance.chain_pass_length, as for the guided photon methods): where the
        camera side carries the error and K cannot rise to match a long pass (it is held at
        its most, or the merge candidates of a camera subpath grow with the pass), a shorter
        pass makes more camera subpaths per second and loses more of its chains' first steps
        (docs/mbe.md, "Chain passes as long as the camera side allows")."""
        shortest = max(floor, min(longest, math.ceil(MIN_REGENERATIONS / (b0 * self._uniform_per_step()))
                                  * self.n_chains))
        shares = self.effort.shares()
        if shares is None or not shares[0] > 0.0:
            # No camera-side variance measured yet: the shortest. The pass choice stops making
            # chain passes once vcm passes measure better, and the few long ones made before the
            # camera side could be measured judged the kind for the render (the pinhole bay: 5
            # passes of 209k steps at K = 1, then vcm passes only; docs/mbe.md).
            return shortest
        return self.pass_length.choose(self.effort, shortest, longest, lambda lengths: self._recorded_share(lengths, b0),
                                       self.steps_last, self.camera_paths, self.max_camera_paths)

    def _iterate(self):
        it = self.iteration_index
        start = time.perf_counter()
        kind = self._iterate_kind(it)
        if self.independent is not None:
            self.independent.balance_radius(self.camera_paths_traced, self.radius_schedule)
        # Wall time per kind of pass: statistics only (the choice counts work, not time, so
        # that a seed gives one image), to set the cost model against what the passes took.
        self.seconds_by_kind[PASS_KINDS.index(kind)] += time.perf_counter() - start

    def _iterate_kind(self, it: int) -> str:
        vcm_variance, vcm_error = self._vcm_pass_variance()
        if self.pass_choice.next_is_vcm(self.effort, self.camera_paths, self.max_camera_paths, self.steps_last,
                                        self.radius ** 2, self.light_balance.next_light_paths(),
                                        vcm_variance, self.chain_batches.pass_variance(),
                                        (vcm_error, self.chain_batches.relative_error())):
            exploring = self.pass_choice.exploring_now
            self._vcm_pass(it, keep=not exploring)
            return "exploring_vcm" if exploring else "vcm"
        self._chain_pass(it)
        return "chain"

    def warm_up(self):
        """A chain pass, then (unless --vcm-passes off) a vcm pass, whose kernels would
        otherwise compile at its first use, mid-render: 0.6-1.5 s at 64x64 with a cold cache,
        which converge's equal-time runs counted as render time."""
        self.iterate()
        if self.independent is not None:
            self._vcm_pass(self.iteration_index)

    def _vcm_pass(self, it: int, keep: bool = True):
        """A pass of vcm's (independent light subpaths, as many as vcm's light-path balance
        gives, measured on these passes, at most --light-paths; one camera subpath per pixel)
        into this film, with the radius of this method's next camera subpath. keep=False: a
        pass that only measures (pass_choice's exploration): it stays out of the film, whose
        passes it would join at the weight of a chain pass of K camera subpaths with about K
        times their variance (the held-out closet: by the per-pass variances, 32 such passes
        among 470 add about 20 % to the film's variance, docs/mbe.md, stop 42), and out of the
        radius's index."""
        v = self.independent
        v.r1 = self.r1
        n_light = self.light_balance.next_light_paths()
        points = self.vcm_pixel_passes.take(1)
        spread, segments, vertices, connections, merges = v.vcm_pass(
            it, self.camera_paths_traced, n_light, keep, points, pixel_samples.VCM_PASS_STREAM)
        work = LightPathBalance.work(self.n_pixels, vertices, connections, segments, v.vertices_last, merges)
        self.light_balance.observe(n_light, spread, self.n_pixels, work)
        if self.twins is not None and self.twins.due(exploring=not keep, settled=self.pass_choice.settled):
            # The same pixel positions, radius and light subpath count, other random numbers
            # (an index no pass uses), out of the film. The next pass's pair estimate for the
            # light-path balance is then read against the twin, whose positions are as
            # independent of that pass's as this pass's are.
            twin = v.vcm_pass(it ^ rng.TWIN_BIT, self.camera_paths_traced, n_light, False, points,
                              pixel_samples.VCM_PASS_STREAM)
            self.twins.observe(twin[0], self.n_pixels)
            self.pass_choice.count_twin(self.effort, self.camera_paths, self.steps_last, n_light)
        if not keep:
            return
        self.radius = v.radius
        self.camera_paths_traced += 1
        self.work_done += n_light + self.n_pixels

    def _chain_pass(self, it: int):
        k = self.pass_choice.chain_pass_k(self.camera_paths) if self.camera_paths_auto else self.camera_paths
        # The merging radius follows the camera subpaths per pixel traced so far, not the
        # passes: a pass of K subpaths per pixel shrinks it as K passes of one would, so that
        # the balance's K splits the work without slowing the radius (and its bias) down.
        # Counted by passes, the Cornell box's K = 14 left 123 passes in 15 s and a radius
        # 1.3x vcm's. Measured, 15 s, interleaved with vcm: Cornell box 0.89x -> 0.74x vcm's
        # RMSE, closet 0.96x -> 0.83x, attic 0.91x -> 0.86x, K = 1 unchanged (docs/mbe.md,
        # "The radius follows the camera subpaths"). r_i -> 0 and the variance still falls
        # as the passes accumulate, so merging stays consistent (Knaus & Zwicker 2011).
        self.radius = self._radius_at(self.camera_paths_traced + k - 1)
        self.camera_paths_traced += k
        steps = self._steps_this_pass()
        n_subpaths = k * self.n_pixels
        pixel_points = self.chain_pixel_passes.take(k)      # (first point, replicate): kernels/pixel_samples.py
        # Sample counts relative to the connections': a light subpath connects to one of the
        # K x pixels camera subpaths, so a pixel gets N_L / pixels connections whatever K;
        # the camera-only techniques (emitter hits, NEE) make K times as many independent
        # samples per pixel, light tracing as many as with one. Merging counts as with one
        # camera subpath: the K subpaths of a pixel merge with the same light vertices, so
        # they are not K independent samples of it, and counting them K times (as until
        # 2026-12-03) handed merging, the biased technique, a K times larger share: on the
        # held-out doorway room at K = 3 and 300 iterations RMSE 0.00165 -> 0.00135 and mean
        # -4.7 % -> -2.6 % (K = 1: -3.5 %), Cornell box at K = 8 0.0230 -> 0.0222
        # (docs/mbe.md, "Merging's count with K camera subpaths"). Any positive counts keep
        # the weights of every path summing to one (tests/test_vcm_mis.py).
        ratio = self.n_pixels / steps
        eta = PI * self.radius ** 2 * self.n_pixels
        kappa = (float(self.b_mis_host[0]) if self.modified_mis else 1.0) * ratio * k
        # A pixel's estimate is the mean over its K subpaths: merging at each is 1/K of it.
        vm_normalization = 1.0 / (PI * self.radius ** 2 * steps * k)
        while True:
            # One launch: the iteration's constants and the chain parameters the last pass
            # chose (held on the host), the camera subpaths, their vertices indexed. Compiled
            # without Taichi's whole-kernel CSE, like the chain kernel (kernels/mcmc.py): 0.6-1 s
            # less to the first image, about 0.5 % of an iteration (docs/performance.md).
            with runtime.advanced_optimization(False):
                n = int(self._camera_side(
                    self.store, self.grid, eta, 1.0 / eta, float(self.n_pixels), kappa, self.radius ** 2, n_subpaths,
                    vm_normalization, ratio, 1.0 / steps, *map(float, self.pool.theta_host),
                    *map(float, self.b_mis_host), *map(float, self.pre_scale_host), self.seed_u32, it,
                    self.max_depth, k, self.radius, *pixel_points, *self._index_serial(n_subpaths)))
            if n <= self.store.capacity:
                break
            self.film.clear_frame()        # counter-based random numbers: the redo is the same pass
            self._allocate_store(int(n * 1.25) + 1024)
            self.store_grown += 1
        self.vertices_last = n
        self.vertices_sum += n
        tallies = self.pool.run_pass(self.chain_model, self.seed_u32, it, steps, extra=(self.light_counters,))
        b = self.pool.normalisations(tallies)
        self.pass_length.observe_counts(tallies["counters"][0, UNIFORM_VISIBLE], tallies["counters"][0, UNIFORM])
        recorded = tallies["recorded"]
        scale = np.where(recorded > 0, b * steps / np.maximum(recorded, 1e-300), 0.0)
        # The light side: beta x the uniform proposals' estimate + (1 - beta) x the chains'.
        frame_scales, sum_scales, unweighted, uniform_halves, uniform_counts, beta = \
            self._pass_scales(steps, b, scale, tallies)
        # The pass joins the film at the weight of its K camera subpaths per pixel: weighed as
        # one sample whatever K, the passes of the balance's first K (1, 1, 2, 4, ...) and the
        # measurement pairs at K = 1 (pass_choice.MEASURE_BAND) weighed up to K times more per
        # camera subpath than the passes at the balance's K. For the camera side that costs
        # sum(1 / K) sum(K) / P^2 of the variance: 1.30x, 1.70x and 3.06x in the slit cabinet,
        # the Cornell box and the strip lights at 30 s (docs/mbe.md, "Chain passes weighed by
        # their camera subpaths"). Where a pass's variance is all light side the weights cost
        # sum(K^2) P / sum(K)^2 (a few per cent once K has settled).
        sums = self._end_pass(*frame_scales, *sum_scales, *unweighted, self.relative_balance,
                              max(self.film.film.samples_per_pixel, 0), float(k))
        self.film.count_flushed(k)
        # the chain passes' batch means (pass_choice.BatchMeansVariance), weighted as the film
        self.batch_passes += 1
        self.batch_weight += k
        if self.batch_passes == BatchMeansVariance.BATCH:
            self.chain_batches.observe_batch(self.batch_sum.to_numpy(), self.batch_weight)
            self.batch_sum.fill(0.0)
            self.batch_passes = 0
            self.batch_weight = 0
        if unweighted[2] > 0.0:         # the pass had uniform proposals
            self._judge_chain_bias(beta, sums)
        self._observe_effort(steps, k, n, sums, beta, uniform_halves, uniform_counts, tallies["extra"][0])
        # The next pass's MIS normalisations, level scales and mutation sizes stay on the host
        # until the next _camera_side writes them (one launch less per iteration).
        if (b > 0).all():
            self.b_mis_host = b.astype(np.float32)
        if (scale > 0).all():
            self.pre_scale_host = scale.astype(np.float32)
        self.pool.adapt(tallies, self.target_acceptance, upload=False)
        self.totals += tallies["counters"]
        self.b_last = b
        if b[0] > 0:
            self.b_sum += b
            self.passes_with_b += 1
        self.work_done += steps + n_subpaths

    def _judge_chain_bias(self, beta: float, sums):
        """The pass's chains against its uniform proposals (methods/chain_bias.py); where their
        bias has come to outweigh the film's noise, the chain passes double in length, and the
        measurements made of passes of the old length (the batch means, the work they are set
        against) start again."""
        self.chain_bias.observe(beta, float(sums[4]), float(sums[5]))
        variance = self._chain_film_pass_variance()
        if self.chain_bias.lengthen(self.film.film.passes,
                                    None if variance is None else variance * self.n_pixels, float(sums[6])):
            self.chain_batches = BatchMeansVariance(self.n_pixels)
            self.batch_sum.fill(0.0)
            self.batch_passes = 0
            self.batch_weight = 0
            self.pass_choice.restart_made_work()

    def _pass_scales(self, steps: int, b, scale, tallies):
        """The pass's scales: (the frame's: chain levels 0 and 1 and the uniform proposals'),
        (the effort sums': the same in radiance, then each ladder parity's half alone, for
        levels 0, 1 and the uniform proposals), each side at its full weight (the chains'
        levels and the uniform proposals', for ChainBias), the halves' uniform scales and
        uniform proposals, beta. Each half is
        scaled by its own recorded weight (or its own uniform proposals), so that it is an
        estimate of the whole light side by itself."""
        uniform_per_chain = tallies["uniform_per_chain"]
        n_uniform = float(uniform_per_chain.sum())
        beta = self.beta.value if n_uniform > 0 else 0.0
        uniform_scale = steps / n_uniform if n_uniform > 0 else 0.0
        frame = (*((1.0 - beta) * scale / self.pre_scale_host.astype(np.float64)), beta * uniform_scale)
        unit = self.film.unit / self.pre_scale_host.astype(np.float64)
        full = (1.0 - beta) * scale * unit
        halves, uniform_halves, uniform_counts = [], [], []
        for parity in (0, 1):
            w = tallies["recorded_per_chain"][parity::2].sum(axis=0)
            halves.append(np.where(w > 0, b * steps / np.maximum(w, 1e-300), 0.0) * unit)
            n_u = float(uniform_per_chain[parity::2].sum())
            uniform_counts.append(n_u)
            uniform_halves.append(steps / n_u * self.film.unit if n_u > 0 else 0.0)
        full_uniform = beta * uniform_scale * self.film.unit
        sums = (*full, full_uniform, *halves[0], uniform_halves[0], *halves[1], uniform_halves[1])
        unweighted = (*(scale * unit), uniform_scale * self.film.unit)
        return frame, sums, unweighted, uniform_halves, uniform_counts, beta

    def _observe_effort(self, steps: int, k: int, vertices: int, sums, beta: float, uniform_halves, uniform_counts,
                        light_counters):
        """The effort balance's view of this iteration (methods/effort.py), and with
        --camera-paths auto the next pass's K; then the uniform proposals' weight beta for the
        next pass. The light side's variance comes from the even and odd ladders
        (independent), the camera side's from consecutive iterations (sums from _end_pass);
        work is counted: camera rays (one per subpath, an extension and a shadow ray per
        stored vertex) and one grid entry per vertex, against light segments and shadow rays
        per chain step, with the merge candidates, which grow with K at a fixed pass length,
        as camera work."""
        # Squared even-odd differences summed over pixels: the chains', the uniform
        # proposals', their product; the light side's is that of the combination.
        s_chains, s_uniform, s_product = float(sums[1]), float(sums[2]), float(sums[3])
        s_light = (1.0 - beta) ** 2 * s_chains + beta ** 2 * s_uniform + 2.0 * beta * (1.0 - beta) * s_product
        light_work = light_counters.astype(np.float64)
        traced, segments, rays, merges, connections = light_work - self.light_work_last
        self.light_work_last = light_work
        n_even, n_odd = (self.n_chains + 1) // 2, self.n_chains // 2
        # Var(t_even - t_odd) = (V_p / n) (c / n_even + c / n_odd) for c ladders in all; with
        # one ladder there are no halves, and the balance has nothing to go by (stats only).
        v_p_times_n = 0.0 if n_odd == 0 else \
            steps * s_light / self.n_pixels / (self.n_chains / n_even + self.n_chains / n_odd)
        n_subpaths = k * self.n_pixels
        last_k = self.effort.last_camera_paths
        measuring = k != self.camera_paths
        # The balance's V_c and V_p only from pairs of passes at its K (both depend on K: a light
        # subpath merges with K camera subpaths); pairs at K = 1 measure the vcm passes' camera
        # side (methods/pass_choice.py, MEASURE_BAND).
        v_c = self.effort.observe(steps, sums[0] / self.n_pixels, v_p_times_n, self.radius ** 2,
                                  n_subpaths + 3.0 * vertices, segments + rays, camera_paths=k, deposits=merges,
                                  keep=not (measuring or self.measured_last))
        self.measured_last = measuring
        if k == 1 and last_k == 1 and v_c is not None:
            self.pass_choice.observe_camera_at_one(v_c)
        uniform_variance = None
        if min(uniform_counts) > 0:
            # one uniform proposal's variance: Var(U_even - U_odd) = V_u (1/n_even + 1/n_odd)
            uniform_variance = s_uniform / self.n_pixels / (1.0 / uniform_counts[0] + 1.0 / uniform_counts[1])
        self.pass_choice.observe_chain_pass(steps, k, traced, segments + rays, merges, uniform_variance,
                                            self.radius ** 2, connections)
        if self.camera_paths_auto and k == self.camera_paths:
            self.camera_paths = self.effort.next_camera_paths(steps, self.max_camera_paths)
        if n_odd > 0 and min(uniform_halves) > 0.0:
            # beta for the next pass. Where light subpaths rarely contribute U is noisy and
            # beta goes to 0 (the chains' estimate, Sik et al.'s); where most do, the chains'
            # correlated records are worth less than the independent proposals they started
            # from, and beta rises (docs/mbe.md, "The uniform proposals' estimate").
            self.beta.observe(s_uniform, s_chains, s_product)
            if self.beta.auto and self.large_step > 0.0:
                # Steps follow the weight: where the uniform proposals' estimate carries a
                # larger share than they have of the steps, they get that share (at least
                # --large-step).
                self.pool.large_step = float(min(max(self.large_step, self.beta.value), MAX_LARGE_STEP))

    @ti.kernel
    def _end_pass(self, s0: ti.f64, s1: ti.f64, su: ti.f64, full0: ti.f64, full1: ti.f64, full_u: ti.f64,
                  even0: ti.f64, even1: ti.f64, even_u: ti.f64, odd0: ti.f64, odd1: ti.f64, odd_u: ti.f64,
                  chains0: ti.f64, chains1: ti.f64, uniform: ti.f64,
                  relative: ti.template(), samples: ti.i32, pass_weight: ti.f64) -> ti.types.vector(7, ti.f64):
        """The pass's end in one launch and one sweep over the pixels (each launch costs
        0.1-0.3 ms on the host, a few per cent of a 64x64 iteration). At each pixel, first its
        terms of the effort sums, before the light frames join the frame: (this iteration's
        estimate - the last one's)^2, (t_even - t_odd)^2 for the chains and for the uniform
        proposals, and the product of the two differences, in luminance; then the chains'
        splats at their levels' final scales (s0, s1) and the uniform proposals' (su) join the
        frame, which joins the film as one sample of the pixel, of the pass's weight (its K;
        `samples` is the film's weight so far). The sums are added per row,
        then over rows in a fixed order, so that K and beta, and so the image, do not depend
        on thread timing. Then the chains' light side and the uniform proposals', each at its
        full weight (chains0, chains1, uniform), and the film's squared pixel values so far,
        for ChainBias (methods/chain_bias.py).
        relative (--balance relmse): each pixel weighted by 1 / (m^2 + eps), m its running
        mean over `samples` iterations, eps = (0.1 x the image's mean m)^2 (converge's relMSE)."""
        w = ti.static(self.dscene.width)
        y_weights = ti.Vector([0.2126, 0.7152, 0.0722], ti.f64)
        inv_samples = 1.0 / ti.cast(ti.max(samples, 1), ti.f64)
        eps = ti.f64(1e-30)
        if ti.static(relative):
            mean_all = ti.f64(0.0)
            ti.loop_config(serialize=True)
            for i in range(self.n_pixels):
                mean_all += self.film.film.sum[i // w, i % w].dot(y_weights) * inv_samples
            eps = ti.max((0.1 * mean_all / ti.static(self.n_pixels)) ** 2, 1e-30)
        ti.loop_config(serialize=ti.static(runtime.serial_loop(self.n_pixels)))
        for y in range(self.dscene.height):
            # spread, halves, halves_u, product; the chains' and the uniform proposals' light
            # sides at full weight; the film's squared pixel values (ChainBias)
            row = ti.Vector([0.0] * 7, ti.f64)
            for x in range(w):
                f0e = ti.cast(self.light_frame[0, y, x], ti.f64)
                f0o = ti.cast(self.light_frame[1, y, x], ti.f64)
                f1e = ti.cast(self.light_frame[2, y, x], ti.f64)
                f1o = ti.cast(self.light_frame[3, y, x], ti.f64)
                ue = ti.cast(self.uniform_frame[0, y, x], ti.f64)
                uo = ti.cast(self.uniform_frame[1, y, x], ti.f64)
                e = (ti.cast(self.film.frame[y, x], ti.f64) * ti.static(self.film.unit) + (f0e + f0o) * full0
                     + (f1e + f1o) * full1 + (ue + uo) * full_u).dot(y_weights)
                weight = ti.f64(1.0)
                if ti.static(relative):
                    if samples > 0:
                        m = self.film.film.sum[y, x].dot(y_weights) * inv_samples
                        weight = 1.0 / (m * m + eps)
                i = y * w + x
                d = e - self.last_estimate[i]
                self.last_estimate[i] = e
                self.batch_sum[i] += pass_weight * e
                h = (f0e * even0 + f1e * even1 - f0o * odd0 - f1o * odd1).dot(y_weights)
                hu = (ue * even_u - uo * odd_u).dot(y_weights)
                row += weight * ti.Vector([d * d, h * h, hu * hu, h * hu, 0.0, 0.0, 0.0], ti.f64)
                chains = ((f0e + f0o) * chains0 + (f1e + f1o) * chains1).dot(y_weights)
                so_far = self.film.film.sum[y, x].dot(y_weights) * inv_samples
                row += ti.Vector([0.0, 0.0, 0.0, 0.0, chains, (ue + uo).dot(y_weights) * uniform, so_far * so_far],
                                 ti.f64)
                # each level's two halves summed exactly (fixed point) before the scale
                total = ti.cast(self.light_frame[0, y, x] + self.light_frame[1, y, x], ti.f64) * s0 \
                    + ti.cast(self.light_frame[2, y, x] + self.light_frame[3, y, x], ti.f64) * s1 \
                    + ti.cast(self.uniform_frame[0, y, x] + self.uniform_frame[1, y, x], ti.f64) * su
                self.film.frame[y, x] += ti.cast(total + 0.5, ti.i64)
                for frame in ti.static(range(4)):
                    self.light_frame[frame, y, x] = ti.Vector([0, 0, 0], ti.i64)
                for frame in ti.static(range(2)):
                    self.uniform_frame[frame, y, x] = ti.Vector([0, 0, 0], ti.i64)
                self.film.flush_pixel_weighted(y, x, pass_weight)
            self.row_sums[y] = row
        sums = ti.Vector([0.0] * 7, ti.f64)
        ti.loop_config(serialize=True)
        for y in range(self.dscene.height):
            sums += self.row_sums[y]
        return sums

    @ti.kernel
    def _camera_side(self, store: ti.template(), grid: ti.template(), eta: ti.f32, inv_eta: ti.f32, pixels: ti.f32,
                     kappa: ti.f32, r2: ti.f32, n_subpaths: ti.i32, vm_normalization: ti.f32, pairing: ti.f32,
                     inv_steps: ti.f32, theta0: ti.f32, theta1: ti.f32, b_mis0: ti.f32, b_mis1: ti.f32,
                     pre_scale0: ti.f32, pre_scale1: ti.f32, seed: ti.u32, iteration: ti.u32, max_depth: ti.i32,
                     per_pixel: ti.i32, radius: ti.f32, first_point: ti.u32, replicate: ti.u32,
                     serial_paths: ti.template(),
                     serial_grid: ti.template()) -> ti.i32:
        """The iteration's camera side in one launch (each launch, and each field write from
        Python, costs host time; a scalar argument costs less than a vector one): its MIS
        constants, subpath count and normalisations, the chains' parameters from the last
        pass (mutation sizes, the MIS normalisations b', the level scales; two levels), the
        emptied store, the camera subpaths, their vertices indexed for the chains (path order,
        merging grid). Returns the vertices the subpaths tried to store."""
        store.clear_paths(n_subpaths, serial_paths)
        self.consts[None] = ti.Vector([eta, inv_eta, pixels, kappa, r2])
        self.n_subpaths[None] = n_subpaths
        self._norms[None] = ti.Vector([vm_normalization, pairing, inv_steps])
        self.pool.write_theta(ti.Vector([theta0, theta1]))
        self.b_mis[0], self.b_mis[1] = b_mis0, b_mis1
        self.pre_scale[0], self.pre_scale[1] = pre_scale0, pre_scale1
        self.camera_subpaths(store, grid, seed, iteration, max_depth, vm_normalization, per_pixel, first_point,
                             replicate, ti.u32(0))
        return self.index_vertices(store, grid, n_subpaths, radius, serial_paths, serial_grid)

    # -- camera side: vcm's camera walk, storing vertices instead of using light ones ----
    @ti.func
    def at_vertex(self, acc: ti.template(), w, s, b: ti.i32, n, t1, t2, wo, wo_l, state: ti.template()) -> ti.i32:
        """Next-event estimation at a non-delta camera vertex, and the vertex stored for the
        chains' connections and merging."""
        sc = self.dscene
        c = self.mis_constants()
        cv = PathVertex(p=s.p, ng=s.ng, n=n, wo=wo, beta=w.beta, length=w.length, bsdf=b, dvcm=acc.m.dvcm,
                        dvc=acc.m.dvc, dvm=acc.m.dvm)
        if w.length + 1 <= acc.max_depth:
            acc.L += w.beta * self._next_event(cv, wo_l, t1, t2, sc.bsdf_continuation(b), state, c)
        self.store.append(acc.subpath, cv)
        return CONTINUE

    # -- light side: the chains' model (kernels/mcmc.py) ------------------------------------
    @ti.func
    def trace_light_subpath(self, model: ti.template(), source: ti.template(), key, vkey, mode, w, t):
        """Trace the light subpath `key` names against the stored camera subpaths. PROBE:
        its targets (T_V, T_C); DEPOSIT: splat F(u) with weight w[l] recorded at level l."""
        self.visit_mode[vkey] = mode
        self.uniform_probe[vkey] = 1 if mode == PROBE and key[3] % MODE_BITS == UNIFORM_MODE else 0
        n_subpaths = self.n_subpaths[None]
        self.pair[vkey] = ti.min(ti.cast(source.get(key, ti.static(self.pair_dim)) * n_subpaths, ti.i32),
                                 n_subpaths - 1)
        self.probe_sum[vkey] = ti.Vector([0, 0, 0], ti.i64)
        slot = ti.cast(key[0], ti.i32)
        dims = 0
        if mode == DEPOSIT:
            self._set_deposit_weights(vkey, w, t)
        if mode == DEPOSIT and key[3] == STATE_MODE and self.pool.adopted[slot] and \
                self.list_count[slot] <= SPLAT_LIST_CAPACITY:
            for k in range(self.list_count[slot]):         # the state's splat list, kept
                pix = self.list_pixel[slot, k]
                y = pix // self.dscene.width
                self._deposit_entry(vkey, y, pix - y * self.dscene.width, self.list_value[slot, k])
            ti.atomic_add(self.list_stats[0], 1)
        else:
            if mode == PROBE:
                self.list_count[self._probe_list(vkey)] = 0
            _, dims = trace_photon(self.dscene, source, key, model, vkey, ti.static(self.max_light_segments))
            ti.atomic_add(self.light_counters[0], 1)
            ti.atomic_add(self.light_counters[1], photon_segments(dims))
        out = ti.Vector([0.0] * self.n_levels)
        if mode == PROBE:
            lum = luminance(ti.cast(self.probe_sum[vkey], ti.f32) * ti.static(self.film.unit))
            if lum > 0.0:
                out = ti.Vector([1.0, lum])
        return out, dims

    @ti.func
    def _set_deposit_weights(self, vkey, w, t):
        """m_l / T_l with the balance heuristic m_l = (T_l/b'_l) / sum_k T_k/b'_k, times the
        previous pass's level scale, so that splats land near their final size (fixed point)."""
        denom = 0.0
        for k in ti.static(range(self.n_levels)):
            if t[k] > 0.0:
                denom += t[k] / self.b_mis[k]
        dw = ti.Vector([0.0] * self.n_levels)
        if denom > 0.0:
            for level in ti.static(range(self.n_levels)):
                if w[level] > 0.0 and t[level] > 0.0:
                    dw[level] = w[level] / (self.b_mis[level] * denom) * self.pre_scale[level]
        self.deposit_weight[vkey] = dw

    @ti.func
    def _probe_list(self, vkey) -> ti.i32:
        """The splat list of ladder vkey's last probe."""
        return ti.static(self.pool.n_slots) + vkey

    @ti.func
    def adopt(self, vkey, slot):
        """ChainPool: slot accepted ladder vkey's last probe; its splat list becomes the slot's."""
        src = self._probe_list(vkey)
        n = self.list_count[src]
        ti.atomic_add(self.list_stats[2], n)
        ti.atomic_add(self.list_stats[3], 1)
        if n <= SPLAT_LIST_CAPACITY:
            for k in range(n):
                self.list_pixel[slot, k] = self.list_pixel[src, k]
                self.list_value[slot, k] = self.list_value[src, k]
        else:
            ti.atomic_add(self.list_stats[1], 1)
        self.list_count[slot] = n

    @ti.func
    def _emit(self, vkey, y: ti.i32, x: ti.i32, contrib):
        """One entry of the splat list: summed for the targets and kept, or deposited."""
        if self.visit_mode[vkey] == PROBE:
            v = self.film.fixed(contrib)
            self.probe_sum[vkey] += v
            if self.uniform_probe[vkey]:
                for k in ti.static(range(3)):
                    ti.atomic_add(self.uniform_frame[vkey % 2, y, x][k], v[k])
            lst = self._probe_list(vkey)
            k = self.list_count[lst]
            if k < SPLAT_LIST_CAPACITY:
                self.list_pixel[lst, k] = y * self.dscene.width + x
                self.list_value[lst, k] = contrib
            self.list_count[lst] = k + 1
        else:
            self._deposit_entry(vkey, y, x, contrib)

    @ti.func
    def _deposit_entry(self, vkey, y: ti.i32, x: ti.i32, contrib):
        dw = self.deposit_weight[vkey]
        parity = vkey % 2
        for level in ti.static(range(self.n_levels)):
            if dw[level] > 0.0:
                v = self.film.fixed(contrib * dw[level])
                for k in ti.static(range(3)):
                    ti.atomic_add(self.light_frame[2 * level + parity, y, x][k], v[k])

    @ti.func
    def visit_light_vertex(self, store: ti.template(), grid: ti.template(), vkey: ti.i32, lv) -> ti.i32:
        """A non-delta light vertex: light tracing, connections to the paired camera subpath,
        merging with the camera vertices in range."""
        sc = self.dscene
        c = self.mis_constants()
        norms = self._norms[None]
        used = 0
        rays, candidates, connections = 0, 0, 0      # work, counted for the effort balance
        # Light tracing (k = -1: the camera) and the connections to every vertex of the
        # paired camera subpath (k >= 0) in one loop, so that the light side's BSDF and the
        # shadow ray are inlined once: each copy of the BVH traversal costs compile time
        # (docs/performance.md, "Compile time"). Same rays, same order as the techniques'
        # own functions (kernels/vcm_techniques.py).
        subpath = self.pair[vkey]
        first = store.path_start[subpath]
        total = vec3(0.0)
        for k in range(-1, store.path_count[subpath]):
            target = sc.cam_origin
            px, py = 0, 0
            cv = store.vertex(0)                   # read for k >= 0 only
            if k >= 0:
                cv = store.vertex(store.order[first + k])
            reachable = 0
            if k < 0:
                if lv.length + 1 <= ti.static(self.max_depth):
                    ok, x, y = sc.camera_raster(lv.p)
                    if ok:
                        reachable = 1
                        px = ti.min(ti.cast(x, ti.i32), sc.width - 1)
                        py = ti.min(ti.cast(y, ti.i32), sc.height - 1)
            elif lv.length + 1 + cv.length <= ti.static(self.max_depth):
                reachable = 1
                target = cv.p
            if reachable:
                to_target = target - lv.p
                dist2 = to_target.dot(to_target)
                if dist2 > 0.0:
                    w = to_target / ti.sqrt(dist2)
                    w_l, el = vcm_techniques.light_side(sc, lv, w)
                    contrib = vec3(0.0)
                    if k < 0:
                        contrib = vcm_techniques.camera_technique(sc, lv, w, w_l, el, dist2, c, True, norms[2])
                    else:
                        t1, t2, wo_c, q = vcm_techniques.camera_frame(sc, cv)
                        contrib = cv.beta * vcm_techniques.connection_technique(sc, cv, wo_c, t1, t2, q, lv, w,
                                                                                  w_l, el, dist2, c)
                    if contrib.max() > 0.0:
                        # the shadow ray's ends in the order each technique uses
                        a, na, b, nb = cv.p, cv.ng, lv.p, lv.ng
                        if k < 0:
                            a, na, b, nb = lv.p, lv.ng, sc.cam_origin, w
                        rays += 1
                        if k >= 0:
                            connections += 1
                        if sc.visible(a, na, b, nb):
                            if k < 0:
                                self._emit(vkey, py, px, contrib)
                                used = 1
                            else:
                                total += contrib
        if total.max() > 0.0:
            pixel = subpath % ti.static(self.n_pixels)
            py0 = pixel // sc.width
            self._emit(vkey, py0, pixel - py0 * sc.width, total * norms[1])
            used = 1
        # Merging: the camera vertices within r of the light vertex, each to its own pixel.
        r2 = self.radius_sq()
        slots, n_slots = grid.slots_near(lv.p)
        for k in range(n_slots):
            start, end = grid.slot_range(slots[k])
            for e in range(start, end):
                if (grid.entry_pos[e] - lv.p).norm_sqr() <= r2:
                    slot = grid.entries[e]
                    if store.length[slot] + lv.length <= ti.static(self.max_depth) and \
                            vcm_techniques.can_merge(store.n[slot], lv.n, lv.wo):
                        candidates += 1
                        cv = store.vertex(slot)
                        t1, t2, wo_l, q = vcm_techniques.camera_frame(sc, cv)
                        contrib = vcm_techniques.merge(sc, cv, wo_l, t1, t2, q, lv, c, norms[0])
                        if contrib.max() > 0.0:
                            pix = store.path[slot] % ti.static(self.n_pixels)
                            y = pix // sc.width
                            self._emit(vkey, y, pix - y * sc.width, contrib)
                            used = 1
        ti.atomic_add(self.light_counters[2], rays)
        ti.atomic_add(self.light_counters[3], candidates)
        ti.atomic_add(self.light_counters[4], connections)
        return used

    # -- results ----------------------------------------------------------------------
    def _film_log_ratio(self) -> float:
        """log(v_vcm / v_chain), the two kinds' measured variances per pass, shrunk toward 0 by
        their errors (methods/film_weights.py); 0 under --film-weights equal."""
        if self.options["film_weights"] != "variance":
            return 0.0
        return shrunk_log_ratio(self._chain_film_pass_variance(), self.chain_batches.relative_error(),
                                *self._vcm_pass_variance())

    def _chain_film_pass_variance(self) -> float | None:
        """The variance of a chain pass of the film's mean K (batch means' sigma^2 / (sum K /
        passes)): the film's passes over it are its precision, sum K / sigma^2, which is what
        its weight against the vcm passes' film and ChainBias's bias are set against."""
        unit = self.chain_batches.unit_variance()
        film = self.film.film
        if unit is None or film.samples_per_pixel <= 0:
            return None
        return unit * film.passes / film.samples_per_pixel

    def _vcm_pass_variance(self) -> tuple[float | None, float | None]:
        """A vcm pass's variance as it counts in its film, and its relative standard error:
        with stratified pixel positions the twins' (positions held, pass_choice.TwinVariance),
        with independent ones the light-path balance's pairs of consecutive passes."""
        if self.twins is not None:
            return self.twins.pass_variance(), self.twins.relative_error()
        return self.light_balance.pass_variance(), self.light_balance.pass_variance_relative_error()

    def film_weights(self) -> tuple[float, float]:
        """The weights of the chain passes' film and the vcm passes' in the image."""
        if self.independent is None:
            return 1.0, 0.0
        return film_weights(self.film.film.passes, self.independent.film.film.passes, self._film_log_ratio())

    def _films(self):
        """(weight, film) of each film that has a weight in the image."""
        films = (self.film, None if self.independent is None else self.independent.film)
        return [(w, f) for w, f in zip(self.film_weights(), films) if w > 0.0]

    def image(self):
        return sum(w * f.mean() for w, f in self._films())

    def standard_error(self):
        return np.sqrt(sum((w * f.standard_error()) ** 2 for w, f in self._films()))

    def _film_stats(self) -> dict:
        n_c = self.film.film.passes
        n_v = self.independent.film.film.passes if self.independent is not None else 0
        return {"chain_passes": n_c, "chain_camera_paths_per_pixel": self.film.film.samples_per_pixel,
                "vcm_passes": n_v, "chain_weight": self.film_weights()[0],
                "chain_weight_by_count": count_weights(n_c, n_v)[0],
                "log_vcm_over_chain_variance_shrunk": self._film_log_ratio(), "weights": self.options["film_weights"],
                # the vcm passes' merging bias (docs/vcm.md, "Merging's bias, estimated"); the
                # chain passes merge on the light side and are not measured
                "vcm_passes_merging_bias": self.independent.merging_bias() if self.independent is not None else None}

    def progress_fields(self) -> str:
        t = self.totals
        acc = t[:, ACCEPTED] / np.maximum(t[:, MUTATIONS], 1)
        swap = t[0, SWAPS_ACCEPTED] / max(int(t[0, SWAPS_TRIED]), 1)
        return (f"radius {self.radius:.3g}  b_V {self.b_last[0]:.2g}  acc {acc[0]:.2f}/{acc[1]:.2f}  "
                f"swap {swap:.2f}  beta {self.beta.value:.2f}" +
                (f"  K {self.camera_paths}" if self.camera_paths_auto else "") +
                (f"  steps {self.steps_last}" if self.steps_last != self.n_light else "") +
                (f"  vcm passes {self.pass_choice.vcm_passes}" if self.pass_choice.vcm_passes else ""))

    def method_stats(self):
        t = self.totals
        theta = self.pool.theta_host
        levels = []
        for level, name in enumerate(LEVELS):
            mut = int(t[level, MUTATIONS])
            levels.append({
                "target": name, "mutations": mut,
                "acceptance": float(t[level, ACCEPTED]) / mut if mut else None,
                "theta": float(theta[level]),
                "normalisation_last": float(self.b_last[level]),
                "normalisation_mean": float(self.b_sum[level] / self.passes_with_b) if self.passes_with_b else None,
                "starts_resampled": int(t[level, SEEDED_RESAMPLED]),
                "starts_copied": int(t[level, SEEDED_COPIED]),
            })
        lc, ls = download_fields((self.light_counters, self.list_stats))     # one kernel for both
        vertices = self.store.capacity
        camera_bytes = vertices * BYTES_PER_STORED_VERTEX
        chain_bytes = self.pool.fields.nbytes + self.chain_fields.nbytes
        return {
            "light_paths_per_iteration": self.n_light, "chain_steps_last_iteration": self.steps_last,
            "chain_steps_mean": self.steps_sum / max(self.iterations, 1),
            "pass_length": self.options["pass_length"],
            "chain_steps_regeneration_rule_last": self.regeneration_steps,
            "regenerations_per_chain_last": self.planned_regenerations,
            "camera_paths_per_pixel": self.camera_paths,
            "camera_paths_per_pixel_auto": self.camera_paths_auto,
            "uniform_weight": self.beta.value, "uniform_weight_auto": self.beta.auto,
            "large_step_last_iteration": self.pool.large_step,
            "effort": self.effort.stats(),
            "chain_bias": self.chain_bias.stats(),
            "passes": {**self.pass_choice.stats(), "light_path_balance": self.light_balance.stats(),
                       "seconds_by_kind": dict(zip(PASS_KINDS, self.seconds_by_kind.tolist())),
                       "vcm_pass_variance_pairs": self.light_balance.variance.mean_after(1),
                       "vcm_pass_variance_twins": self.twins.variance.mean_after(1) if self.twins else None,
                       "twin_passes": self.twins.variance.count if self.twins else 0},
            "chains": self.n_chains,
            "mis": "modified" if self.modified_mis else "plain",
            "radius": self.radius, "initial_radius": self.r1, "alpha": self.alpha,
            "radius_schedule": self.radius_schedule.stats(),
            "uniform_visible_fraction": float(t[0, UNIFORM_VISIBLE]) / max(int(t[0, UNIFORM]), 1),
            "swap_acceptance": (float(t[0, SWAPS_ACCEPTED]) / t[0, SWAPS_TRIED] if t[0, SWAPS_TRIED] else None),
            "levels": levels,
            "light_subpaths_traced": int(lc[0]),
            "deposits_from_kept_splat_lists": int(ls[0]),
            "splat_lists_overflowed": int(ls[1]),
            "splat_list_mean_length": float(ls[2]) / max(int(ls[3]), 1),
            "light_segments_per_subpath": float(lc[1]) / max(int(lc[0]), 1),
            "light_shadow_rays_per_subpath": float(lc[2]) / max(int(lc[0]), 1),
            "light_connections_per_subpath": float(lc[4]) / max(int(lc[0]), 1),
            "merge_candidates_per_subpath": float(lc[3]) / max(int(lc[0]), 1),
            "camera_vertices_last_iteration": self.vertices_last,
            "camera_vertices_mean": self.vertices_sum / max(self.iterations, 1),
            "camera_vertex_capacity": vertices,
            "camera_vertex_store_grown": self.store_grown,
            "memory_bytes": {"camera_vertices_and_grid": camera_bytes, "chains_and_level_frames": chain_bytes,
                             "vcm_passes_light_vertices": (self.independent.store.capacity * BYTES_PER_STORED_VERTEX
                                                           if self.independent is not None else 0),
                             "vcm_passes_film": (self.independent.film.fields.nbytes
                                                 + self.independent.film.film.fields.nbytes
                                                 if self.independent is not None else 0)},
            "films": self._film_stats(),
            "nonfinite_samples_dropped": self.film.dropped() + (self.independent.film.dropped()
                                                                if self.independent is not None else 0),
        }

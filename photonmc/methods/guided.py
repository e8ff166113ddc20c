"""Photon paths guided by Markov chains in primary sample space, on SPPM's camera pass, grid
and progressive update (algorithms.md §2, §3).

visibility (Hachisuka & Jensen 2011): one chain level with target V(u) = 1 when the photon
path deposits into at least one current measurement point (MP), decided by exactly SPPM's
deposit predicate. Each step tries a uniform path first (kept if visible) and otherwise
mutates; the current state is deposited once per step. The pass's flux is scaled by b_V, the
fraction of its uniform paths that were visible.

spatial-tf (Gruson et al. 2016): three levels, visibility -> inverse MP area -> spatial
importance ~ 1/P(hit MP) from hit statistics in world-space clusters (clusters.py), with
replica exchange between neighbours, normalisations chained level by level
(b_{l+1} = b_l E_l[T_{l+1}/T_l]) and balance-heuristic MIS between the levels.

Estimator, per pass and MP j: Phi_j = sum_l (b_l / N_l) sum_{level-l records} m_l(u) phi_j(u) / T_l(u),
with N_l the level's recorded weight, m_l = (T_l/b'_l) / sum_k (T_k/b'_k) using the previous
pass's b' (so the weights do not depend on this pass's samples) and phi_j(u) the power the
path deposits at j. One pass counts as `photons` emitted photon paths, like SPPM.
"""
import math

import numpy as np
import taichi as ti

from ..errors import SettingsError
from ..kernels.batch import upload_fields
from ..kernels.fields import FieldGroup
from ..kernels.mcmc import (
    ACCEPTED,
    DEPOSIT,
    FAILURES,
    FAILURES_DROPPED,
    MUTATIONS,
    N_COUNTERS,
    PROBE,
    STATE_MODE,
    SUFFIX_ACCEPTED,
    SUFFIX_TRIED,
    SWAPS_ACCEPTED,
    SWAPS_TRIED,
    UNIFORM,
    UNIFORM_VISIBLE,
    ChainPool,
)
from ..kernels.photon import BOUNCE_DIMS, LIGHT_DIMS, dimensions, photon_segments, trace_photon
from ..kernels.pss_guide import PAIRS, PssGuide
from ..kernels.sampling import luminance
from .clusters import UNKNOWN, HitDensityClusters
from .effort import UniformWeight, uniform_weight_option
from .pass_length import BalancedPassLength, recorded_share
from .photon_passes import PhotonPassChoice
from .sppm import FIXED_ONE, Sppm
from ..taichi_frontend import data_oriented

REGENERATIONS = 10       # visible uniform proposals each chain should see per pass
# ... at most: where the effort balance expects a shorter pass to serve the image much better
# (the camera side carries the error, and its deposits grow with the pass), it shortens it,
# down to MIN_REGENERATIONS (methods/pass_length.py, GuidedPhotons._balanced_pass_length).
# Below one a pass expects most chains to meet no visible uniform proposal, and records only
# those that do (recorded_share models it); the balance goes there where the camera side
# starves, as in the pinhole rooms, where spatial-tf's passes at one regeneration each still
# held K at its most (64). With 1/4 at 20 s: spatial-tf 0.77x and 0.84x in the two pinhole
# rooms, 1.11x in two-gap (21 passes; at 60 s 0.57x sppm, as before), 0.98-1.01x in six
# more; visibility 0.97-1.07x over ten rooms; at 60 s spatial-tf 0.94x -> 0.75x and
# 1.10x -> 0.83x sppm's RMSE in the pinhole rooms (docs/guiding.md, "Passes shorter than one
# regeneration", stop 67).
MIN_REGENERATIONS = 0.25
MAX_STEPS_PER_PASS = 1 << 24
# A ladder's upper levels start each pass as copies of level 0's state and burn in within the
# pass; the exchanges pass their states down to level 0 too, so no level is exact until the
# ladder has mixed. Recorded from the start, this made spatial-tf several % dark on short
# passes (gap-lit room, 32x32, 256 steps per ladder and pass: -3.4 %; 64x64, 1024 steps:
# -3.1 %), which longer passes (a step per pixel per ladder) only reduced. Discarding the
# first half of each pass removes it (+0.2 % and -0.1 +- 0.2 %; docs/guiding.md, "Burn-in of
# the ladder"). visibility's single chain is exact from its first visible uniform proposal
# and discards nothing.
LADDER_BURN_IN = 0.5
MIN_STEPS_PER_LADDER = 256   # so that the burn-in spans some mixing even where --photons is tiny
DEFAULT_CHAINS = 4        # pass length grows with chains (10 regenerations each); on a CPU more ladders only cost camera passes
EPS_AREA = 1e-3          # regularisers of the spatial importance (bound its dynamic range)
EPS_DENSITY = 1e-3
MAX_CHAINS = 1 << 20
# Suffix moves (kernels/mcmc.py): a mutation redraws, with this probability, every coordinate
# from the scattering at bounce k on, k drawn uniformly from SUFFIX_BOUNCES (bounce 1 would
# keep only the emitted ray: 0.3-2 % of those stay visible in the gap-lit rooms). Off by
# default: at equal time they helped where the lamp is hidden from the room (-5 %, -8 %) and
# hurt where it shines through the gap (+7 %, +8-15 %); docs/guiding.md, "Why the mutations shrink".
SUFFIX_MUTATION = 0.0
SUFFIX_BOUNCES = (2, 3, 4)
# --mutation blocks: the light's coordinates, bounce 1's, bounce 2's and all later ones
# perturbed one block at a time, each with its own theta (kernels/mcmc.py).
MUTATION_BLOCKS = 4
# --uniform-weight auto: the chains' mutations are made with probability 1 - beta, at least this.
MIN_MUTATION = 0.05
# Vertex lists (GuidedPhotons.trace): each state keeps its path's photon vertices, so that it
# deposits without being traced again; at most this many vertices over all lists, else traced.
VERTEX_BUDGET = 1 << 21


@ti.func
def _inverse_area_and_importance(area_ratio, density_ratio, has_density):
    """The spatial target's two terms (docs/guiding.md, "The spatial importance"): the inverse
    area 1/(A/A_max + EPS_AREA), and the importance, that over (rho/rho_max + EPS_DENSITY)
    where any density is known (else the inverse area alone)."""
    ia = 1.0 / (area_ratio + EPS_AREA)
    imp = ia
    if has_density:
        imp = ia / (density_ratio + EPS_DENSITY)
    return ia, imp


@data_oriented
class GuidedPhotons(Sppm):
    """Shared by `visibility` (one level) and `spatial-tf` (three)."""
    work_unit = "photons"
    default_iterations = 100
    OPTIONS = {**Sppm.OPTIONS, "chains": None, "target_acceptance": 0.234, "proposal_failures": "keep",
               "expected_values": False, "suffix_mutation": SUFFIX_MUTATION,
               "mutation": "joint", "warm_start": False, "ladder_burn_in": LADDER_BURN_IN,
               "uniform_weight": "auto",
               # The balance's K also sets how many measurement points the chains' targets can
               # reach, so fewer points lengthen a pass; with twins K fell, and the held-out light
               # bay lost 14 % while the closet gained 11 % (15 s, seeds 0-3; docs/effort.md,
               # "Twin camera paths"). auto (twins only where K does not set the pass length)
               # wins the slatted window (noise 0.72x at 20 s) and leans 4-5 % the wrong way on
               # the Cornell box and light-gap (docs/effort.md, "Photon noise shared by a
               # pixel's points").
               "camera_variance": "pairs",
               # Pairs of primary-sample coordinates warped by a learned guide (0: none;
               # kernels/pss_guide.py, docs/guiding.md "A learned warp of the first coordinates").
               "pss_guide": 0,
               # auto: a pass traces its photons plainly, without the chains, where the chains'
               # lower photon variance does not pay for their work (methods/photon_passes.py,
               # docs/guiding.md "Uniform passes where the chains do not pay"); off: chain passes only.
               "uniform_passes": "auto",
               # balanced: a pass lasts REGENERATIONS visible uniform proposals per chain, or
               # fewer (down to MIN_REGENERATIONS) where the effort balance expects a shorter
               # pass to serve the image much better (_balanced_pass_length; docs/guiding.md,
               # "Guided passes as long as the camera side allows"); regenerations: always
               # REGENERATIONS.
               "pass_length": "balanced",
               # API only, for measurements: the visible uniform proposals a pass asks of each chain.
               "regenerations": REGENERATIONS}
    # Every step's uniform photon is also an estimate of its own, sppm's (an accumulator after
    # the levels'), joined to the chains' with the least-variance weight beta; the chains'
    # mutations are made with probability 1 - beta (at least MIN_MUTATION): where uniform
    # photons carry the pass they are work it does not need (docs/guiding.md, "The uniform
    # photons' estimate").
    uniform_accumulator = True
    path_target_sum = False
    # spatial-tf's --spatial-updates epochs (an option): upper levels' targets held fixed
    # within an epoch (SpatialTarget); visibility has no upper level.
    epochs = False
    # Passes last until every chain regenerates (_steps_this_pass), so where the error is
    # camera-side they would starve the camera passes: the effort balance chooses how many
    # camera paths per pixel share each photon pass (docs/effort.md).
    default_camera_paths = "auto"
    # With twins (--camera-variance auto or twins) V_c is their trimmed mean, as the pairs' is:
    # the plain mean kept the caustic's rare camera paths through glass and raised K, and auto
    # lost the caustic 1.07-1.30x against pairs; trimmed 0.96x (docs/effort.md, stop 55).
    trim_twin_variances = True

    def __init__(self, dscene, settings):
        if settings.options.get("photons") == "auto":
            raise SettingsError(f"--photons auto is for sppm; {self.name}'s passes last until every chain "
                                f"regenerates (docs/effort.md)")
        super().__init__(dscene, settings)
        opts = self.options
        self.n_chains = int(opts["chains"] if opts["chains"] is not None else DEFAULT_CHAINS)
        if not 1 <= self.n_chains <= MAX_CHAINS:
            raise SettingsError(f"--chains must be between 1 and {MAX_CHAINS}, got {self.n_chains}")
        self.target_acceptance = float(opts["target_acceptance"])
        if not 0.0 < self.target_acceptance < 1.0:
            raise SettingsError(f"--target-acceptance must be in (0, 1), got {self.target_acceptance}")
        if opts["proposal_failures"] not in ("keep", "drop"):
            raise SettingsError(f"--proposal-failures must be 'keep' or 'drop', got '{opts['proposal_failures']}'")
        self.drop_failures = opts["proposal_failures"] == "drop"
        self.expected_values = bool(opts["expected_values"])
        # The effort balance is measured (stats) but does not steer the guided methods: their
        # passes already lengthen until every chain regenerates, and steering them too made
        # visibility 7.5 % worse on the gap-lit close-up at equal time (docs/effort.md).
        if self.n_chains < 2:
            self.effort = None     # the balance splits a pass's chains in two halves (effort.py)
        self.suffix_mutation = float(opts["suffix_mutation"])
        if not 0.0 <= self.suffix_mutation < 1.0:
            raise SettingsError(f"--suffix-mutation is a probability in [0, 1), got {self.suffix_mutation}")
        dims = dimensions(self.max_photon_segments)
        starts = tuple(d for d in (LIGHT_DIMS + BOUNCE_DIMS * (k - 1) for k in SUFFIX_BOUNCES) if d < dims)
        if not starts:
            self.suffix_mutation = 0.0     # paths too short to keep a prefix (max_depth 1)
        if opts["mutation"] not in ("joint", "blocks"):
            raise SettingsError(f"--mutation must be 'joint' or 'blocks', got '{opts['mutation']}'")
        blocks = ()
        if opts["mutation"] == "blocks":
            blocks = tuple(d for d in (0,) + tuple(LIGHT_DIMS + BOUNCE_DIMS * k for k in range(MUTATION_BLOCKS - 1))
                           if d < dims)
        self.mutation_blocks = len(blocks)
        # API options, measured in docs/guiding.md ("Upper levels kept across passes"): the
        # upper levels start each pass from their last states where those still have a
        # non-zero target (warm_start), and the share of each pass the ladders discard.
        burn_in = float(opts["ladder_burn_in"])
        if not 0.0 <= burn_in < 1.0:
            raise SettingsError(f"ladder_burn_in is a fraction of each pass in [0, 1), got {burn_in}")
        if self.n_levels == 1 and (opts["warm_start"] or burn_in != LADDER_BURN_IN):
            raise SettingsError(f"{self.name} has one chain per ladder: --warm-start and ladder_burn_in are for "
                                f"the upper levels of spatial-tf's ladders (and mbe's --warm-start)")
        uniform_weight_option(opts["uniform_weight"])     # checked here, used from _reset_guided
        if opts["uniform_passes"] not in ("auto", "off"):
            raise SettingsError(f"--uniform-passes must be 'auto' or 'off', got '{opts['uniform_passes']}'")
        # The choice reads beta's even-odd sums and the balance's counted work: two ladders at least.
        self.uniform_passes_on = opts["uniform_passes"] == "auto" and self.effort is not None
        if opts["pass_length"] not in ("balanced", "regenerations"):
            raise SettingsError(f"--pass-length must be 'balanced' or 'regenerations', got '{opts['pass_length']}'")
        self.regenerations = opts["regenerations"]
        if isinstance(self.regenerations, bool) or not isinstance(self.regenerations, (int, float)) \
                or not 1 <= self.regenerations <= 1000:
            raise SettingsError(f"regenerations is the visible uniform proposals a pass asks of each chain, "
                                f"a number from 1 to 1000, got {self.regenerations!r}")
        # The choice reads K = n / n* from the balance, so only where the balance chooses K.
        self.balanced_length = (opts["pass_length"] == "balanced" and self.effort is not None
                                and self.camera_paths_auto)
        self.force_uniform = False      # warm_up: compile the uniform pass too
        n_pairs = opts["pss_guide"]
        if isinstance(n_pairs, bool) or str(n_pairs) not in [str(k) for k in range(len(PAIRS) + 1)]:
            raise SettingsError(f"--pss-guide is the number of coordinate pairs to warp, 0 to {len(PAIRS)}, "
                                f"got {n_pairs!r}")
        # trace_photon reads the warp through this attribute (None: plain primary samples).
        self.pss_guide = PssGuide(int(n_pairs), self.n_chains, self.name) if int(n_pairs) > 0 else None
        self.guided_pss = self.pss_guide is not None
        self.pool = ChainPool(self.n_chains, self.n_levels, dims, self.drop_failures, self.expected_values,
                              burn_in=burn_in if self.n_levels > 1 else 0.0,
                              suffix_mutation=self.suffix_mutation, suffix_starts=starts, block_starts=blocks,
                              warm_start=bool(opts["warm_start"]) or self.epochs, uniform_estimate=True,
                              adopted_across_passes=True)
        f = FieldGroup(f"guided-{self.name}")
        L, n, c = self.n_levels, self.n_mp, self.n_chains
        self.target_scratch = f.vector(L, ti.f32, c)
        self.visit_mode = f.scalar(ti.i32, c)
        self.flux_weight = f.vector(L + 1, ti.f32, c)     # the levels', then the uniform photons'
        self.hit_weight = f.vector(L, ti.f32, c)
        self.b_mis = f.scalar(ti.f32, L)              # previous pass's normalisations, for MIS only
        self.paths_traced = f.scalar(ti.i64, ())
        if self.guided_pss:
            self.guide_contribution = f.scalar(ti.f64, c)     # a uniform photon's deposits, for the guide
        # Vertex lists: a path's photon vertices (those trace_photon visits) depend on its
        # coordinates alone, not on the pass's MPs, so the list a proposal's probe records is
        # the one its deposits need, in this pass and later ones. List l of slot s is
        # list_of[s]; the ladder's probe records into list_of[n_slots + ladder]; adopting a
        # proposal swaps the two. A recording probe traces the whole path (visibility's
        # stops at its first hit otherwise); a list that overflowed would not be complete,
        # and its state would be traced again.
        n_lists = self.pool.n_slots + c
        self.vertex_capacity = self.max_photon_segments
        self.keep_vertices = n_lists * self.vertex_capacity <= VERTEX_BUDGET
        if self.keep_vertices:
            cap = self.vertex_capacity
            self.vertex_p = f.vector(3, ti.f32, (n_lists, cap))
            self.vertex_n = f.vector(3, ti.f32, (n_lists, cap))
            self.vertex_wi = f.vector(3, ti.f32, (n_lists, cap))
            self.vertex_beta = f.vector(3, ti.f32, (n_lists, cap))
            self.vertex_segments = f.scalar(ti.i32, (n_lists, cap))
            self.vertex_count = f.scalar(ti.i32, n_lists)
            self.vertex_complete = f.scalar(ti.i32, n_lists)
            self.list_of = f.scalar(ti.i32, n_lists)
            self.recording_list = f.scalar(ti.i32, c)      # the probe's list, or -1: not recording
            self.deposits_from_lists = f.scalar(ti.i64, ())
        if L > 1:
            self.inv_area = f.scalar(ti.f32, n)
            self.importance = f.scalar(ti.f32, n)
            self.hits = f.scalar(ti.i64, (L, self.n_pixels))   # the first camera path's MPs (_after_pass)
            self.rho = f.scalar(ti.f64, n)                # each MP's cluster density this pass
            self.mp_hit_stats = f.vector(2, ti.f64, self.n_pixels)   # hits and samples of the first path's MPs
            self.target_sums = f.vector(5, ti.f64, ())    # _spatial_targets' maxima and sums
            self.hit_scale = f.scalar(ti.f64, L)          # each level's hits -> uniform-path equivalents
            # --spatial-updates epochs: the epoch's A_max, rho_max and the two targets' scales
            self.epoch_norm = f.vector(4, ti.f64, ())
        f.finalize()
        self.guide_fields = f
        self._reset_guided()

    def release(self):
        self.pool.release()
        self.guide_fields.release()
        if self.pss_guide is not None:
            self.pss_guide.release()
        super().release()

    def _reset(self):
        super()._reset()
        self.pool.reset()
        if self.pss_guide is not None:
            self.pss_guide.reset()
        self._reset_guided()

    def _reset_guided(self):
        self.b_mis.fill(1.0)
        self.paths_traced[None] = 0
        if self.keep_vertices:
            self.list_of.from_numpy(np.arange(self.pool.n_slots + self.n_chains, dtype=np.int32))
            self.vertex_complete.fill(0)
            self.recording_list.fill(-1)
            self.deposits_from_lists[None] = 0
        L = self.n_levels
        self.totals = np.zeros((L, N_COUNTERS), np.int64)
        self.b_last = np.zeros(L)
        self.last_steps = self.photons_per_iteration
        self.b_sum = np.zeros(L)
        self.b_uniform_sum = np.zeros(L)
        self.b_difference_sq = np.zeros(L)      # sum over passes of (chained - uniform mean)^2
        self.passes_with_b = 0
        self.beta = UniformWeight(self.options["uniform_weight"])
        self.pool.mutation_probability = 1.0
        self.pass_choice = PhotonPassChoice()
        self.uniform_pass = False       # whether the pass being made is a uniform pass
        self.previous_uniform = False   # and the one before it
        self.chain_passes = 0
        self.pass_length = BalancedPassLength()     # the visible counts and recorded shares it goes by
        self.recorded_share_last = None
        self.planned_regenerations = 0.0
        self.regeneration_steps = self.photons_per_iteration
        self.b_pass = 0.0               # this pass's visible share of uniform proposals

    # -- the model interface of ChainPool -------------------------------------------------
    @ti.func
    def trace(self, source: ti.template(), key, vkey, mode, w, t):
        """Trace the path `key` names; PROBE: evaluate every level's target, DEPOSIT: deposit it
        with weight w[l] recorded at level l (t: its target values)."""
        self.visit_mode[vkey] = mode
        if mode == DEPOSIT:
            self._set_deposit_weights(vkey, w, t)
            if ti.static(self.guided_pss):
                self.guide_contribution[vkey] = 0.0
        self.target_scratch[vkey] = ti.Vector([0.0] * self.n_levels)
        dims = 0
        kept = -1
        if ti.static(self.keep_vertices):
            kept = self._kept_list(key, vkey, mode)
        if kept >= 0:
            if ti.static(self.keep_vertices):
                self._replay(kept, vkey, mode)
        else:
            if ti.static(self.keep_vertices):
                if mode == PROBE:
                    # record this proposal's vertices (adopt keeps them with the state)
                    lst = self.list_of[ti.static(self.pool.n_slots) + vkey]
                    self.vertex_count[lst] = 0
                    self.vertex_complete[lst] = 1
                    self.recording_list[vkey] = lst
            _, dims = trace_photon(self.dscene, source, key, self, vkey, ti.static(self.max_photon_segments))
            if ti.static(self.keep_vertices):
                self.recording_list[vkey] = -1
            ti.atomic_add(self.paths_traced[None], 1)
            ti.atomic_add(self.counters[3], photon_segments(dims))
        if ti.static(self.guided_pss):
            # A visible uniform proposal, deposited: a draw of the visible set in v, which the
            # guide learns from at what it brought to the image (its deposits' W Phi / R^2).
            if mode == DEPOSIT and w[ti.static(self.n_levels)] > 0.0:
                self.pss_guide.learn(source, key, vkey, self.guide_contribution[vkey])
        return self.target_scratch[vkey], dims

    @ti.func
    def _kept_list(self, key, vkey, mode) -> ti.i32:
        """The complete vertex list that stands for the path `key` names, or -1: a stored
        state's, once adopted (ChainPool clears `adopted` when the slot takes a state by other
        means), or, for a deposit of the proposal just probed (an expected-value share), the
        ladder's probe list."""
        kept = -1
        slot = ti.cast(key[0], ti.i32)
        if key[3] == STATE_MODE:
            if self.pool.adopted[slot]:
                lst = self.list_of[slot]
                if self.vertex_complete[lst]:
                    kept = lst
        elif mode == DEPOSIT:
            lst = self.list_of[ti.static(self.pool.n_slots) + vkey]
            if self.vertex_complete[lst]:
                kept = lst
        return kept

    @ti.func
    def _replay(self, lst, vkey, mode):
        """Visit list lst's vertices as trace_photon would have (PROBE may stop early)."""
        if mode == DEPOSIT:
            ti.atomic_add(self.deposits_from_lists[None], 1)
        for k in range(self.vertex_count[lst]):
            v = self.visit(vkey, self.vertex_p[lst, k], self.vertex_n[lst, k], self.vertex_wi[lst, k],
                           self.vertex_beta[lst, k], self.vertex_segments[lst, k])
            if v > 1:
                break

    @ti.func
    def adopt(self, vkey, slot):
        """ChainPool: slot accepted ladder vkey's last probe; its vertex list becomes the slot's
        (the lists swap owners: the slot's old one records the ladder's next probe)."""
        if ti.static(self.keep_vertices):
            probe = ti.static(self.pool.n_slots) + vkey
            lst = self.list_of[probe]
            self.list_of[probe] = self.list_of[slot]
            self.list_of[slot] = lst

    @ti.func
    def _set_deposit_weights(self, vkey, w, t):
        denom = 0.0
        for k in ti.static(range(self.n_levels)):
            if t[k] > 0.0:
                denom += t[k] / self.b_mis[k]
        fw = ti.Vector([0.0] * (self.n_levels + 1))
        hw = ti.Vector([0.0] * self.n_levels)
        fw[self.n_levels] = w[self.n_levels]       # a uniform photon: weight 1 in its own accumulator
        if denom > 0.0:
            for level in ti.static(range(self.n_levels)):
                if w[level] > 0.0 and t[level] > 0.0:
                    # m_l / T_l with the balance heuristic m_l = (T_l/b_l) / sum_k T_k/b_k
                    fw[level] = w[level] / (self.b_mis[level] * denom)
            if ti.static(self.n_levels > 1):
                # Hit statistics for the spatial importance come from the levels below the
                # spatial one only (MIS over those): the spatial level must not feed back on
                # itself.
                d = 0.0
                for level in ti.static(range(self.n_levels - 1)):
                    d += t[level] / self.b_mis[level]
                for level in ti.static(range(self.n_levels - 1)):
                    if w[level] > 0.0 and t[level] > 0.0:
                        hw[level] = w[level] / (self.b_mis[level] * d)
        self.flux_weight[vkey] = fw
        self.hit_weight[vkey] = hw

    @ti.func
    def _raise_upper_targets(self, t, inverse_area, importance):
        """A path's upper targets after it reaches one more point: the largest inverse area of
        the points it reaches, and the largest (--path-target sum: the summed) importance."""
        if ti.static(self.n_levels == 3):
            t[1] = ti.max(t[1], inverse_area)
        top = ti.static(self.n_levels - 1)        # the spatial level
        if ti.static(self.path_target_sum):
            t[top] += importance
        else:
            t[top] = ti.max(t[top], importance)
        return t

    @ti.func
    def visit(self, vkey: ti.i32, x, n, wi, beta, segments: ti.i32) -> ti.i32:
        """Photon-vertex visitor: evaluates the targets or deposits, per the trace mode."""
        if ti.static(self.keep_vertices):
            lst = self.recording_list[vkey]
            if lst >= 0:
                k = self.vertex_count[lst]
                if k < ti.static(self.vertex_capacity):
                    self.vertex_p[lst, k] = x
                    self.vertex_n[lst, k] = n
                    self.vertex_wi[lst, k] = wi
                    self.vertex_beta[lst, k] = beta
                    self.vertex_segments[lst, k] = segments
                    self.vertex_count[lst] = k + 1
                else:
                    self.vertex_complete[lst] = 0
        first, end = self.grid.candidates(x)
        hit = 0
        probing = self.visit_mode[vkey] == PROBE
        t = self.target_scratch[vkey]
        fw = self.flux_weight[vkey]
        hw = self.hit_weight[vkey]
        for e in range(first, end):
            j = self.grid.entries[e]
            if self.accepts(j, x, n, wi, segments):
                if probing:
                    hit = 1
                    if ti.static(self.n_levels == 1 or self.epochs):
                        break       # epochs: the upper levels read the vertex, below
                    if ti.static(self.n_levels > 1 and not self.epochs):
                        t = self._raise_upper_targets(t, self.inv_area[j], self.importance[j])
                elif self.deposit_at(j, x, wi, beta, fw, vkey & 1):
                    hit = 1
                    if ti.static(self.guided_pss):
                        if fw[ti.static(self.n_levels)] > 0.0:
                            r = self.mp_radius[j]
                            self.guide_contribution[vkey] += luminance(self.mp_W[j] * beta) / (r * r)
                    if ti.static(self.n_levels > 1):
                        if j < ti.static(self.n_pixels):     # the statistics read the first camera path's MPs only
                            for level in ti.static(range(self.n_levels)):
                                if hw[level] > 0.0:
                                    ti.atomic_add(self.hits[level, j],
                                                  ti.cast(ti.cast(hw[level], ti.f64) * FIXED_ONE + 0.5, ti.i64))
        if probing and hit:
            t[0] = 1.0
            if ti.static(self.epochs):
                w = self.world_targets(x)
                t = self._raise_upper_targets(t, w[0], w[1])
            self.target_scratch[vkey] = t
            if ti.static(self.n_levels == 1):
                hit = 2       # V(u) is known: the rest of the path does not matter...
                if ti.static(self.keep_vertices):
                    if self.recording_list[vkey] >= 0:
                        hit = 1   # ...but its deposits will need it: a visible proposal is accepted
        return hit

    # -- the iteration -----------------------------------------------------------------------
    def warm_up(self):
        """Compile both kinds of pass: a chain pass, then a uniform one (reset() follows)."""
        self.iterate()
        if self.uniform_passes_on:
            self.force_uniform = True
            self.iterate()
            self.force_uniform = False

    def _iterate(self):
        self.previous_uniform = self.uniform_pass
        self.uniform_pass = self.uniform_passes_on and (self.force_uniform or self.pass_choice.next_is_uniform())
        if self.uniform_pass:
            self._iterate_uniform()
        else:
            self._iterate_chains()
        if self.uniform_passes_on:
            self.pass_choice.observe(self.uniform_pass, self.last_steps, self.pass_segments, self.pass_deposits)
            self.pass_choice.observe_variances(self.beta.value, self.beta.sums)

    def _iterate_uniform(self):
        """A uniform pass (methods/photon_passes.py): the pass's photons traced plainly into the
        uniform photons' accumulator, sppm's photon pass at the same camera paths per pixel."""
        it = self.iterations
        n_p = self._steps_this_pass()
        self._measurement_points(it)
        self.flux_weight.fill(0.0)
        self.hit_weight.fill(0.0)
        self._set_uniform_visitors()
        # sppm's photon pass, deposited through this class's visitor (photon p by slot p & 1)
        self._photon_pass(self.seed_u32, it, n_p, self.max_photon_segments)
        self.paths_traced[None] += n_p
        raw = np.zeros(self.n_levels + 1)
        raw[-1] = self.power_scale / FIXED_ONE
        upload_fields([(self.level_scale, raw), (self.raw_scale, raw)])
        self._choose_camera_variance()
        self._update_balanced(n_p)
        self.photons_emitted += n_p
        self.work_done += n_p

    @ti.kernel
    def _set_uniform_visitors(self):
        """Visitor slots 0 and 1 (uniform passes need two ladders: uniform_passes_on) deposit
        with weight 1 into the uniform photons' accumulator and nothing into the levels'."""
        for v in range(2):
            self.visit_mode[v] = DEPOSIT
            self.flux_weight[v][self.n_levels] = 1.0

    def _iterate_chains(self):
        it = self.iterations
        n_p = self._steps_this_pass()
        self._measurement_points(it)
        self._prepare_targets()
        self.chain_passes += 1
        guide = self.pss_guide
        tallies = self.pool.run_pass(self, self.seed_u32, it, n_p, extra=guide.readable() if guide else ())
        b = self.pool.normalisations(tallies)
        self.b_pass = float(b[0])
        c = tallies["counters"][0]
        self.pass_length.observe_counts(c[UNIFORM_VISIBLE], c[UNIFORM])
        recorded = tallies["recorded"]
        self.recorded_share_last = float(recorded[0]) / n_p      # against _recorded_share's model (stats)
        scale = np.where(recorded > 0, b * n_p / np.maximum(recorded, 1e-300), 0.0)
        # The flux: (1 - beta) x the levels' (each at its normalisation) + beta x the uniform
        # photons' (sppm's estimator over this pass's n_U uniform photons, one per step).
        n_uniform = int(tallies["counters"][0, UNIFORM])
        raw = np.append(scale, n_p / n_uniform if n_uniform > 0 else 0.0) * (self.power_scale / FIXED_ONE)
        beta = self.beta.value if n_uniform > 0 else 0.0
        upload_fields([(self.level_scale, raw * np.append(np.full(self.n_levels, 1.0 - beta), beta)),
                       (self.raw_scale, raw)])
        self._after_pass(scale)
        self._choose_camera_variance()
        self._update_balanced(n_p)
        uploads = [(self.b_mis, b.astype(np.float32))] if (b > 0).all() else []
        if guide is not None:
            warp = guide.update(*tallies["extra"][:2])
            if warp and self.keep_vertices:
                # A kept vertex list is the path of its state's v under the old warp.
                warp.append((self.vertex_complete, np.zeros(self.vertex_complete.shape, np.int32)))
            uploads += warp
        self.pool.adapt(tallies, self.target_acceptance, uploads=uploads)
        self.totals += tallies["counters"]
        self.b_last = b
        if b[0] > 0:
            self.b_sum += b
            self.b_uniform_sum += tallies["uniform_mean"]
            self.b_difference_sq += (b - tallies["uniform_mean"]) ** 2
            self.passes_with_b += 1
        self.photons_emitted += n_p
        self.work_done += n_p

    def _shared_photon_variance(self, photon_sq: float, n_p: int) -> float:
        """A chain pass's flux is b x the chains' mean, b the share of its n_p uniform
        proposals that were visible, and both halves of the pass share that b: its relative
        variance (1 - b) / (n_p b) is photon noise the even-odd difference does not see and
        consecutive passes do. Times the mean squared photon estimate (the uniform photons'
        share, beta, taken as the chains' too: where beta is large b is, and this is small)."""
        b = self.b_pass
        if self.uniform_pass or not b > 0.0:
            return 0.0
        return photon_sq * (1.0 - b) / (n_p * b)

    def _balance_keeps(self) -> bool:
        """The effort balance models the kind of pass being chosen: a pass of the other kind (a
        uniform pass where chains win: 1/r times their photon variance) would pull its photon
        variance, and the pass after one its V_c (the pair's photon part is read from the later
        pass alone), toward passes it is not choosing between (docs/effort.md, "The balance
        under uniform passes")."""
        if not self.uniform_passes_on:
            return True
        wins = self.pass_choice.uniform_wins
        return self.uniform_pass == wins and self.previous_uniform == wins

    def _radius_from_last_counts(self) -> bool:
        """The radius follows the chain passes' counts: the chains' states all deposit
        (light-gap's chain passes make 19 times the deposits per photon of a uniform pass), so
        a uniform pass counting its own photons would shrink the radius far less than a chain
        pass in its place. A uniform pass updates each pixel's radius by the last chain pass's
        count instead, and the radius goes as a render of chain passes would. A rule fixed
        before the pass, it keeps the estimator as it was: each pass estimates the pixel at the
        radius it is given. (Scaling a uniform pass's counts to a chain pass's left the radius
        larger: SPPM's update shrinks a radius by at most sqrt(alpha) per pass, however many
        photons it counts. What kept light-gap's radius was photon_passes.MIN_RATIO;
        docs/guiding.md, "Uniform passes where the chains do not pay".)"""
        return self.uniform_passes_on and self.uniform_pass

    def _measures_bias(self) -> bool:
        """The balanced radius rule weighs the bias of the passes it expects against their
        noise: a uniform pass where the chains win has 1/r times their photon noise, and in the
        rule's sums it would hide the bias that the chain passes' radius leaves."""
        return not self.uniform_passes_on or self.uniform_pass == self.pass_choice.uniform_wins

    def _choose_camera_variance(self):
        """--camera-variance auto (an option): the twins' V_c (the pixel positions held) where
        this pass's length was its photon floor, so that K does not move it; the pairs' where
        the chains' regeneration set it. Fewer camera paths make fewer measurement points for
        the chains' targets to reach, fewer visible uniform proposals and so longer passes
        there, a cost the balance does not model (the twins' lower V_c lost the light bay 14 %
        by it); where K moves only the camera work the pairs' V_c, mostly where in its pixel a
        path starts (the slatted window's lit slats), chose K = 24-42. Measured, not the
        default: at 60 s it took the slatted window's noise from 2.1x sppm's to 1.4x and made
        the Cornell box's 1.44x the pairs' (docs/effort.md, "Twins where K does not set the
        pass length")."""
        if self.effort is not None and self.camera_variance_auto:
            self.effort.use_pairs = self.regeneration_bound

    def _observe_uniform_weight(self, s_chains: float, s_uniform: float, s_product: float):
        """The pass's even-odd sums of the chains' and the uniform photons' estimates
        (Sppm._update): beta for the next pass, and the mutation probability that follows it."""
        if self.uniform_pass or (s_chains <= 0.0 and s_uniform <= 0.0):
            return          # a uniform pass has no chains' estimate; nothing deposited: no evidence
        self.beta.observe(s_uniform, s_chains, s_product)
        if self.beta.auto:
            self.pool.mutation_probability = float(max(1.0 - self.beta.value, MIN_MUTATION))

    def _steps_this_pass(self) -> int:
        """At least --photons, and enough that every chain meets ~REGENERATIONS visible uniform
        proposals: the pass records a chain only after its first one (ChainPool.run_pass),
        so a pass too short for that wastes work. Uses the last pass's visible fraction (with
        --pass-length balanced, the passes' fading counts); after a pass that found nothing
        visible, the next one is twice as long. --pass-length balanced then shortens it where
        the effort balance says (_balanced_pass_length). Ladders, which discard
        their first half (LADDER_BURN_IN), run at least MIN_STEPS_PER_LADDER steps."""
        n = self.photons_per_iteration
        if self.n_levels > 1:
            n = max(n, MIN_STEPS_PER_LADDER * self.n_chains)
        floor = n
        b0 = b_sized = 0.0       # the visible share for the model, and the one that sized the pass
        longest = n
        if self.iterations > 0:
            b0 = b_sized = self.b_last[0]
            want = self.last_steps * 2 if b0 <= 0 else math.ceil(self.regenerations / b0) * self.n_chains
            n = max(n, min(int(want), MAX_STEPS_PER_PASS))
            longest = n
            if self.balanced_length and self.pass_length.visible_share() > 0 and n > floor:
                # A pass of few regenerations sees few visible uniform proposals: its own b is
                # too noisy to size a shorter one; the fading counts are steadier. (The longest
                # keeps the last pass's b, as with --pass-length regenerations: the smoothed b
                # there lost the doorway 7 %, docs/guiding.md.)
                b0 = self.pass_length.visible_share()
                shorter = self._balanced_pass_length(n, floor, b0)
                if shorter < n:
                    n, b_sized = shorter, b0
        self.last_steps = n
        self.regeneration_steps = longest         # the length the regeneration rule asked for
        self.regeneration_bound = n > floor
        self.planned_regenerations = b_sized * n / self.n_chains     # per chain, at the b that sized it
        # The balance's V_p is a mean over passes of their variance per step, which goes as
        # 1 / the share recorded: the shares' harmonic mean is the one it was measured at.
        share = float(self._recorded_share([n], b0)[0]) if b0 > 0 and not self.uniform_pass else 1.0
        self.pass_length.record(share)
        return n

    def _recorded_share(self, lengths, b0: float):
        """recorded_share for passes of `lengths` steps over this method's ladders."""
        return recorded_share(np.asarray(lengths, float) * b0 / self.n_chains, self.pool.burn_in)

    def _balanced_pass_length(self, longest: int, floor: int, b0: float) -> int:
        """The pass length between MIN_REGENERATIONS and REGENERATIONS per chain (`longest`)
        that the effort balance expects to serve the image best (EffortBalance.chain_pass_length):
        where the camera side carries the error and a camera path's work (its deposits) grows
        with the pass, or K would exceed what a pass allows, a shorter pass makes more camera
        passes and loses more of its chains' first steps (docs/guiding.md, "Guided passes as
        long as the camera side allows")."""
        shortest = max(floor, min(longest, math.ceil(min(MIN_REGENERATIONS, self.regenerations) / b0) * self.n_chains))
        return self.pass_length.choose(self.effort, shortest, longest, lambda lengths: self._recorded_share(lengths, b0),
                                       self.last_steps, self.camera_paths, self.max_camera_paths)

    def _prepare_targets(self):
        """Per-MP target factors for levels above visibility (none for `visibility`)."""

    def _after_pass(self, level_scale):
        """Use this pass's deposits before the update clears them (hit statistics)."""

    # -- results ---------------------------------------------------------------------------
    def method_stats(self):
        s = super().method_stats()
        s.pop("fraction_of_photon_paths_depositing", None)
        t = self.totals
        theta = self.pool.theta_host
        levels = []
        for level in range(self.n_levels):
            mut = int(t[level, MUTATIONS])
            levels.append({
                "target": self.level_names[level],
                "mutations": mut,
                "acceptance": float(t[level, ACCEPTED]) / mut if mut else None,
                "theta": float(theta[level]) if self.mutation_blocks <= 1 else None,   # blocks: block_theta
                "block_theta": (self.pool.block_theta_host[level].tolist() if self.mutation_blocks > 1 else None),
                "suffix_moves": int(t[level, SUFFIX_TRIED]),
                "suffix_acceptance": (float(t[level, SUFFIX_ACCEPTED]) / t[level, SUFFIX_TRIED]
                                      if t[level, SUFFIX_TRIED] else None),
                "proposal_failures": int(t[level, FAILURES]),
                "failures_dropped": int(t[level, FAILURES_DROPPED]),
                "normalisation_last": float(self.b_last[level]),
                "normalisation_mean": float(self.b_sum[level] / self.passes_with_b) if self.passes_with_b else None,
                # the standard error of (mean chained - mean uniform) / mean uniform, from the
                # passes' differences (independent passes)
                "normalisation_difference_se": self._normalisation_difference_se(level),
                "normalisation_uniform_mean": (float(self.b_uniform_sum[level] / self.passes_with_b)
                                               if self.passes_with_b else None),
            })
        swaps = {f"{self.level_names[k]}<->{self.level_names[k + 1]}":
                 (float(t[k, SWAPS_ACCEPTED]) / t[k, SWAPS_TRIED] if t[k, SWAPS_TRIED] else None)
                 for k in range(self.n_levels - 1)}
        s.update({
            "chains": self.n_chains,
            "photons_last_iteration": self.last_steps,
            "pass_length": self.options["pass_length"],
            "regenerations_per_chain_last": float(self.planned_regenerations),
            "recorded_share_last": self.recorded_share_last,
            "recorded_share_model_last": (float(self._recorded_share([self.last_steps], self.b_last[0])[0])
                                          if self.b_last[0] > 0 else None),
            "target_acceptance": self.target_acceptance,
            "proposal_failures": "drop" if self.drop_failures else "keep",
            "expected_values": self.expected_values,
            "suffix_mutation": self.suffix_mutation,
            "mutation": "blocks" if self.mutation_blocks > 1 else "joint",
            "uniform_visible_fraction": float(t[0, UNIFORM_VISIBLE]) / max(int(t[0, UNIFORM]), 1),
            "uniform_weight": self.beta.value, "uniform_weight_auto": self.beta.auto,
            "mutation_probability": self.pool.mutation_probability,
            "pss_guide_pairs": self.pss_guide.n_pairs if self.pss_guide else 0,
            "pss_guide_updates": self.pss_guide.updates if self.pss_guide else 0,
            "uniform_passes": self.options["uniform_passes"],
            **({"pass_choice": self.pass_choice.stats()} if self.uniform_passes_on else {}),
            "photon_paths_traced": int(self.paths_traced[None]),
            "deposits_from_kept_vertices": int(self.deposits_from_lists[None]) if self.keep_vertices else 0,
            "levels": levels,
        })
        if swaps:
            s["swap_acceptance"] = swaps
        return s

    def _normalisation_difference_se(self, level: int) -> float | None:
        p = self.passes_with_b
        if p < 2 or not self.b_uniform_sum[level] > 0.0:
            return None
        mean = (self.b_sum[level] - self.b_uniform_sum[level]) / p
        variance = max(self.b_difference_sq[level] / p - mean * mean, 0.0) * p / (p - 1)
        return float(math.sqrt(variance / p) / (self.b_uniform_sum[level] / p))

    def progress_fields(self) -> str:
        t = self.totals
        mut = max(int(t[0, MUTATIONS]), 1)
        theta = self.pool.theta_host
        b = "  ".join(f"b{k} {v:.2g}" for k, v in enumerate(self.b_last))
        moves = ""       # the alternative mutations' own figures, where they are on
        if self.mutation_blocks > 1:
            moves += "  block theta " + "/".join(f"{x:.2g}" for x in self.pool.block_theta_host[0])
        if t[0, SUFFIX_TRIED]:
            moves += f"  suffix acc {t[0, SUFFIX_ACCEPTED] / t[0, SUFFIX_TRIED]:.2f}"
        return (f"{super().progress_fields()}  visible {t[0, UNIFORM_VISIBLE] / max(int(t[0, UNIFORM]), 1):.2g}  "
                f"acc {t[0, ACCEPTED] / mut:.2f}  theta {theta[0]:.2g}{moves}  {b}  beta {self.beta.value:.2f}")


@data_oriented
class Visibility(GuidedPhotons):
    name = "visibility"
    n_levels = 1
    level_names = ("visibility",)


@data_oriented
class SpatialTarget(GuidedPhotons):
    name = "spatial-tf"
    n_levels = 3
    level_names = ("visibility", "inverse-area", "spatial")
    OPTIONS = {**GuidedPhotons.OPTIONS, "path_target": "max", "spatial_levels": 3, "spatial_updates": "pass"}
    # this pass's MPs and per-MP targets, set by _prepare_targets, and their hit counts
    TRANSIENT = Sppm.TRANSIENT + ("inv_area", "importance", "hits", "rho", "target_sums",
                                    "mp_hit_stats", "hit_scale")

    def __init__(self, dscene, settings):
        opts = {**self.OPTIONS, **{k: v for k, v in settings.options.items() if v is not None}}
        path_target = opts["path_target"]
        if path_target not in ("max", "sum"):
            raise SettingsError(f"--path-target must be 'max' or 'sum', got '{path_target}'")
        self.path_target_sum = path_target == "sum"
        # --spatial-levels 2 leaves out the inverse-area level: visibility -> spatial
        # importance (docs/guiding.md, "Two levels instead of three").
        levels = opts["spatial_levels"]
        if str(levels) not in ("2", "3"):
            raise SettingsError(f"--spatial-levels must be 2 or 3, got '{levels}'")
        if int(levels) == 2:
            self.n_levels = 2
            self.level_names = ("visibility", "spatial")
        # pass (the default): the upper levels' targets follow each pass's MPs and statistics,
        # and the ladders start again every pass, discarding its first half (LADDER_BURN_IN).
        # epochs (an option, measured): they are world-space functions of the photon's
        # depositing vertices, held fixed from one epoch start (after 0, 1, 2, 4, 8, ... chain
        # passes) to the next, so that the upper levels keep their states (the warm start, whatever
        # --warm-start says) and a ladder discards half a pass within an epoch only where an
        # upper level lost its state. docs/guiding.md, "Spatial targets held for an epoch".
        if opts["spatial_updates"] not in ("pass", "epochs"):
            raise SettingsError(f"--spatial-updates must be 'pass' or 'epochs', got '{opts['spatial_updates']}'")
        self.epochs = opts["spatial_updates"] == "epochs"
        super().__init__(dscene, settings)
        lo, hi = dscene.scene.bounds
        self.clusters = HitDensityClusters(lo, hi, self.n_pixels, frozen=self.epochs)
        self.epoch_burn_in = self.pool.burn_in

    def release(self):
        self.clusters.release()
        super().release()

    def _reset(self):
        super()._reset()
        self.clusters.reset()

    def _prepare_targets(self):
        n = self.camera_paths * self.n_pixels
        if not self.epochs:
            self._spatial_targets(n)
            return
        k = self.chain_passes
        if k & (k - 1) == 0:        # an epoch starts: new targets, the ladders burn in again
            self.clusters.freeze()
            self._epoch_norms(n)
            self.pool.burn_in = self.epoch_burn_in
        else:
            # within an epoch a ladder burns in only where an upper level lost its kept state
            # (it no longer deposits into any of the pass's MPs) and starts again from a copy
            self.pool.burn_in = 0.0
            self.pool.restart_burn_in = self.epoch_burn_in

    @ti.kernel
    def _epoch_norms(self, n: ti.i32):
        """The epoch's A_max and rho_max over this pass's valid MPs, from the frozen statistics,
        and the scales that make both world targets average 1 over those MPs (in a fixed order:
        determinism)."""
        self.epoch_norm[None] = ti.Vector([0.0, 0.0, 1.0, 1.0], ti.f64)
        ti.loop_config(serialize=True)
        for j in range(n):
            if self.mp_valid[j]:
                fz = self.clusters.frozen_at(self.mp_p[j])
                if fz[0] != UNKNOWN:
                    norm = self.epoch_norm[None]
                    self.epoch_norm[None][0] = ti.max(norm[0], ti.cast(fz[1], ti.f64))
                    self.epoch_norm[None][1] = ti.max(norm[1], ti.cast(fz[0], ti.f64))
        sums = ti.Vector([0.0, 0.0, 0.0], ti.f64)
        ti.loop_config(serialize=True)
        for j in range(n):
            if self.mp_valid[j]:
                ia, imp = self._world_value(self.clusters.frozen_at(self.mp_p[j]))
                sums += ti.Vector([ia, imp, 1.0], ti.f64)
        if sums[2] > 0.0:
            self.epoch_norm[None][2] = sums[2] / sums[0]
            self.epoch_norm[None][3] = sums[2] / sums[1]

    @ti.func
    def _world_value(self, fz):
        """_area_and_importance from a point's frozen (density, mean MP area) and the epoch's
        maxima; 1 where no MP has statistics yet."""
        norm = self.epoch_norm[None]
        ia, imp = ti.f64(1.0), ti.f64(1.0)
        if norm[0] > 0.0:
            area, rho = norm[0], norm[1]   # unknown: the largest area and density (lowest target)
            if fz[0] != UNKNOWN:
                area, rho = ti.cast(fz[1], ti.f64), ti.cast(fz[0], ti.f64)
            ia, imp = _inverse_area_and_importance(area / norm[0], rho / ti.max(norm[1], 1e-300), norm[1] > 0.0)
        return ia, imp

    @ti.func
    def world_targets(self, x):
        """(inverse-area target, spatial importance) of a depositing photon vertex at x, each
        scaled to mean 1 over the epoch's first MPs."""
        ia, imp = self._world_value(self.clusters.frozen_at(x))
        norm = self.epoch_norm[None]
        return ti.Vector([ia * norm[2], imp * norm[3]], ti.f32)

    def _after_pass(self, level_scale):
        # Only the first camera path's MPs (one per pixel) feed the statistics: a cell's
        # hits per area are estimated as well from any subset of its MPs chosen without
        # regard to the photons (more noisily; the importance need only be positive for the
        # estimate to stay unbiased), and a photon is then counted once per pixel whatever
        # K (clusters.py, min_samples). All K paths' MPs made the statistics cost a fifth of
        # a spatial-tf pass on the Cornell box at K = 21 (docs/performance.md).
        upload_fields([(self.hit_scale, np.asarray(level_scale, np.float64) / FIXED_ONE)])
        self._hit_statistics(self.n_pixels)

    @ti.kernel
    def _spatial_targets(self, n: ti.i32):
        """Per MP in use: the inverse-area target and the spatial importance
        I_j = 1/(A_j/A_max + EPS_AREA) / (rho_j/rho_max + EPS_DENSITY) (docs/guiding.md, "The
        spatial importance"), each normalised to mean 1 over the valid MPs. A point whose
        cells have too few samples gets rho_max (the lowest importance); with no statistics
        anywhere yet, I_j is the inverse-area term alone. Entries past n keep older values: no
        grid of this pass holds them, so none is read."""
        # A_max, rho_max, then the sums of both targets over the valid MPs and their count
        self.target_sums[None] = ti.Vector([0.0, UNKNOWN, 0.0, 0.0, 0.0], ti.f64)
        for j in range(n):
            if self.mp_valid[j]:
                self.rho[j] = self.clusters.density_at(self.mp_p[j])
        ti.loop_config(serialize=True)     # one thread: no atomics on the two maxima
        for j in range(n):
            if self.mp_valid[j]:
                r = ti.cast(self.mp_radius[j], ti.f64)
                sums = self.target_sums[None]
                self.target_sums[None][0] = ti.max(sums[0], math.pi * r * r)
                self.target_sums[None][1] = ti.max(sums[1], self.rho[j])
        ti.loop_config(serialize=True)     # float sums in a fixed order (determinism)
        for j in range(n):
            if self.mp_valid[j]:
                ia, imp = self._area_and_importance(j)
                self.target_sums[None] += ti.Vector([0.0, 0.0, ia, imp, 1.0], ti.f64)
        for j in range(n):
            ia, imp = ti.f64(0.0), ti.f64(0.0)
            if self.mp_valid[j]:
                sums = self.target_sums[None]
                ia, imp = self._area_and_importance(j)
                ia *= sums[4] / sums[2]
                imp *= sums[4] / sums[3]
            self.inv_area[j] = ti.cast(ia, ti.f32)
            self.importance[j] = ti.cast(imp, ti.f32)

    @ti.func
    def _area_and_importance(self, j):
        r = ti.cast(self.mp_radius[j], ti.f64)
        sums = self.target_sums[None]
        rho_max = sums[1]
        rho = self.rho[j]
        if rho == UNKNOWN:
            rho = rho_max          # no statistics yet: lowest importance
        return _inverse_area_and_importance(math.pi * r * r / sums[0], rho / ti.max(rho_max, 1e-300),
                                            rho_max != UNKNOWN)

    @ti.kernel
    def _hit_statistics(self, n: ti.i32):
        """This pass's hits into the clusters (uniform-path equivalents: each level's
        fixed-point hits times its scale) from the first camera path's n MPs (visit counts
        hits at those only), and their hit counts cleared for the next pass."""
        for j in range(n):
            hits = ti.f64(0.0)
            for level in ti.static(range(self.n_levels)):
                hits += ti.cast(self.hits[level, j], ti.f64) * self.hit_scale[level]
                self.hits[level, j] = 0
            self.mp_hit_stats[j] = ti.Vector([hits, ti.cast(self.M[j], ti.f64)], ti.f64)
        self.clusters.accumulate_points(self, n)
        self.clusters.close_pass()

    @ti.func
    def cluster_point(self, j):
        """MP j for the clusters (clusters.accumulate_points), after _hit_statistics' first loop."""
        r = ti.cast(self.mp_radius[j], ti.f64)
        h = self.mp_hit_stats[j]
        return self.mp_valid[j] != 0, self.mp_p[j], math.pi * r * r, h[0], h[1]

    def progress_fields(self) -> str:
        swaps = self.totals[:, SWAPS_ACCEPTED] / np.maximum(self.totals[:, SWAPS_TRIED], 1)
        return super().progress_fields() + "  swap " + "/".join(f"{x:.2f}" for x in swaps[:-1])

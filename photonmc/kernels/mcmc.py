"""Markov chains over primary sample space, shared by the guided photon methods and by the
toy-target tests (algorithms.md §2, §3, §5).

A pool runs `n_chains` independent ladders in parallel (one CPU thread per ladder at a time),
each ladder holding `n_levels` replicas:
  * level 0 starts each step with a uniform proposal (the exchange with an implicit uniform
    chain, H&J 2011). For a binary target (visibility, `binary_base`) a visible one always
    replaces the state and the state is mutated only otherwise (H&J's loop: whether it mutates
    does not depend on the current state, so the loop keeps the target). For any other
    non-negative target the uniform proposal is an independence Metropolis-Hastings move,
    accepted with min(1, T(u')/T(u)), and a mutation follows every time;
  * levels 1.. run Metropolis-Hastings on their own targets, and neighbouring levels exchange
    states (replica exchange, Gruson et al. 2016).
Every level's support must lie inside the one below (normalisations, `normalisations`).

Start of a pass (the targets changed, so every stored state is stale). A binary level 0 is
exact from its first visible uniform proposal: that proposal is an exact draw from V/b_V.
Any other level needs a start: `seeding="copy"` copies the state of the level below (then
the ladder burns in, `burn_in`); `seeding="resample"` runs a bootstrap in which each level
keeps one of the ladder's uniform proposals with probability proportional to its target
(weighted reservoir sampling, the classic MLT bootstrap) and starts from it once
`bootstrap_hits` proposals with a non-zero target have been offered, or, with at least one,
when the first `bootstrap` fraction of the pass is over (a level that found none records
nothing in this ladder and pass). A resampled start is exact as the bootstrap grows; its
bias at production lengths is measured in tests/test_mcmc.py and docs/mbe.md.
Replicas live in slots; the ladder's level->slot table is what an exchange permutes.

Slot state: u[slot, :] is the whole primary sample vector (ell = 0 marks an empty slot,
whose mutations draw fresh coordinates, i.e. are uniform proposals).
T[slot] holds the state's value under every level's target (exchanges then cost nothing);
pending[slot][l] is the weight recorded at level l and not yet deposited. Deposits are
deferred until a state is replaced or the pass ends, so a state that repeats is traced once.

Mutation (all three reference implementations of H&J): per coordinate u +- r^(1/theta + 1),
r uniform, sign uniform, wrapped to [0, 1). theta is per level (adaptation statistics stay
with the level, not the state) and adapted on the host between passes (`adapt_theta`).
With `suffix_mutation` p > 0, a mutation is instead, with probability p, a suffix move: every
coordinate from one of the model's `suffix_starts` on (chosen uniformly, whatever the state)
is drawn afresh and the prefix kept. Both kernels are symmetric, so their mixture is too and
the acceptance stays min(1, T'/T). Why: one theta for every coordinate makes the acceptance
the product of each coordinate group's, so the width shrinks until the sensitive prefix
(point on the light, emission, first bounces) barely moves, and the insensitive tail of the
path barely moves with it (docs/guiding.md, "Why the mutations shrink"). theta adapts on
the perturbations alone.
With `block_starts` (coordinate ranges [start_b, start_b+1), the last to the end), a
perturbation moves one block only, drawn uniformly whatever the state, with that block's own
theta, adapted on that block's acceptance (random-scan Metropolis within blocks: each block
move keeps the target, so their mixture does).

A model is any data-oriented object with
    trace(source, key, vkey, mode, weight, T) -> (T: ti.Vector(n_levels), dims read)
which, for mode PROBE, evaluates every level's target on the path whose coordinates
`source.get(key, dim)` yields, and for mode DEPOSIT deposits that path with weight[l] recorded
at level l (T: its target values). `vkey` (the ladder index) names the model's scratch space.
"""
import math

import numpy as np
import taichi as ti

from .. import runtime
from . import rng
from .batch import FieldReader, fill_fields, scalar_count, upload_fields
from .fields import FieldGroup
from ..taichi_frontend import data_oriented

# Per-level counters (int64, atomics, so they are exact and order-independent).
# MUTATIONS/ACCEPTED count the perturbations (theta's statistics), SUFFIX_* the suffix moves.
(MUTATIONS, ACCEPTED, UNIFORM, UNIFORM_VISIBLE, SWAPS_TRIED, SWAPS_ACCEPTED, FAILURES, FAILURES_DROPPED,
 SEEDED_RESAMPLED, SEEDED_COPIED, SUFFIX_TRIED, SUFFIX_ACCEPTED) = range(12)
N_COUNTERS = 12
SEEDINGS = ("copy", "resample")

THETA_MIN, THETA_MAX = 1e-4, 1.0        # clamps of the mutation-size parameter
THETA_START = 0.5
# Taichi's CPU backend hands a parallel loop to its threads in blocks of at least 512
# iterations (block_dim is chosen adaptively there; ti.loop_config's block_dim is for GPUs),
# so a loop over 4 ladders ran on one thread. On the CPU each ladder therefore owns a block of
# CPU_LADDER_STRIDE loop iterations and only the first does the work (docs/performance.md).
CPU_LADDER_STRIDE = 512
FRESH_SALT = 0x5BD1E995                 # separates fresh coordinates from mutation offsets


# What a source key asks for: key = (slot, proposal key, level, mode + MODE_BITS x k), k the suffix
# move's first redrawn coordinate or the block a perturbation moves (0 otherwise).
UNIFORM_MODE, MUTATION_MODE, STATE_MODE, SUFFIX_MODE = 0, 1, 2, 3
MODE_BITS = 4
# What a model's trace does with the path.
PROBE, DEPOSIT = 0, 1
# What a ladder's step in ChainPool._run does: re-evaluate every stored state (PROBE), deposit
# every pending weight (DEPOSIT), or a chain step (STEPS). A pass is all three in one launch,
# through one trace call site: each inlined copy of a model's tracer costs seconds of
# compilation (mbe's: 8 s of a 28 s first image), and each launch of a parallel loop a
# hand-off to the thread pool of 0.2-0.27 ms (docs/performance.md).
STEPS = 2


@data_oriented
class _ChainSource:
    """Coordinates of the path a key names: a fresh uniform proposal, a mutation of a slot's
    state (with its level's theta), or the slot's stored state. One source with a runtime mode,
    so that each kernel inlines the photon tracer once (each inlined copy costs compile time)."""

    def __init__(self, pool):
        self.pool = pool

    @ti.func
    def get(self, key, dim):
        slot = ti.cast(key[0], ti.i32)
        mode = ti.cast(key[3] % MODE_BITS, ti.i32)
        v = 0.0
        # Each branch hashes only what it returns (the fresh coordinate was hashed for every
        # read before, and overwritten in the other branches).
        if mode == UNIFORM_MODE or (mode == SUFFIX_MODE and dim >= ti.cast(key[3] // MODE_BITS, ti.i32)):
            v = rng.uniform(key[1], dim)
        elif not (dim < self.pool.ell[slot] or
                  (ti.static(self.pool.store_read) and dim == ti.static(self.pool.dims - 1))):
            v = rng.uniform(key[1] ^ ti.u32(FRESH_SALT), dim)     # a coordinate never read before
        else:
            v = self.pool.u[slot, dim]
            if mode == MUTATION_MODE:
                theta = 0.0
                if ti.static(self.pool.n_blocks > 1):
                    b = ti.cast(key[3] // MODE_BITS, ti.i32)
                    if self.pool.block_lo[b] <= dim < self.pool.block_hi[b]:
                        theta = self.pool.block_theta[ti.cast(key[2], ti.i32), b]
                else:
                    theta = self.pool.theta[ti.cast(key[2], ti.i32)]
                if theta > 0.0:
                    r = rng.uniform(key[1], 2 * dim)
                    delta = ti.pow(r, 1.0 / theta + 1.0)
                    if rng.uniform(key[1], 2 * dim + 1) < 0.5:
                        delta = -delta
                    v += delta
                    v -= ti.floor(v)
                    if v >= 1.0:          # float rounding of a tiny negative value
                        v = 0.0
        return v


@ti.func
def component(v: ti.template(), i):
    """v[i] for a runtime index i, without dynamic indexing (which the 1.7.4 compiler
    mishandles in these kernels)."""
    x = v[0]
    for k in ti.static(range(1, v.n)):
        if k == i:
            x = v[k]
    return x


ADAPT_GAIN = 4.0
ADAPT_DECAY = 0.6


def adapt_theta(theta: float, acceptance: float, target: float, k: int) -> float:
    """Diminishing adaptation after pass k = 1, 2, ...: log theta += 4 k^-0.6 (A - A*), A the
    pass's acceptance (Andrieu & Thoms 2008, Algorithm 4, on the log scale). The reference codes'
    per-mutation rule theta += (A - A*)/i moves theta by only (A - A*) ln 2 per doubling of the
    mutation count, which left the acceptance 0.26 instead of 0.234 after 600 k mutations on
    a toy target (docs/guiding.md); steps k^-0.6 still vanish, as ergodicity requires, and the
    log scale suits a width that must span 1e-4 to 1."""
    step = ADAPT_GAIN * k ** -ADAPT_DECAY * (acceptance - target)
    return float(min(max(theta * math.exp(step), THETA_MIN), THETA_MAX))


def _chain_kernel_compilation():
    """The chain kernel inlines the model's whole tracer (for mbe: connections, merging, light
    tracing), and Taichi's whole-kernel CSE, part of its advanced optimisation, took 5 of its
    15 s to compile. LLVM's own passes do that work on the generated code: without the pass
    the chain kernel compiles 2-5 s faster and runs as fast (within 1.3 % over 11 method/scene
    pairs, interleaved in one process; docs/performance.md, "Compile time")."""
    return runtime.advanced_optimization(False)


@data_oriented
class ChainPool:
    # Rebuilt, not saved: the fields each pass clears (saved through their own attributes) and
    # the prepared readers of the pass's tallies.
    TRANSIENT = ("pass_tallies", "_readers")

    def __init__(self, n_chains: int, n_levels: int, dims: int, drop_failures: bool = False,
                 expected_values: bool = False, burn_in: float = 0.0, binary_base: bool = True,
                 seeding: str = "copy", bootstrap: float = 0.5, bootstrap_hits: int = 8, large_step: float = 0.0,
                 suffix_mutation: float = 0.0, suffix_starts: tuple = (), block_starts: tuple = (),
                 base_records_in_burn_in: bool = False, warm_start: bool = False, uniform_estimate: bool = False,
                 store_read: bool = False, adopted_across_passes: bool = False):
        self.n_chains, self.n_levels, self.dims = n_chains, n_levels, dims
        # store_read: an accepted state keeps only the coordinates its evaluation read (the
        # trace's second result) and the last one, instead of all `dims`. For models whose
        # evaluation reads every coordinate any later trace of the state reads (mbe: the whole
        # light subpath, and its pairing coordinate last). Coordinates never read are
        # independent uniforms under the target, so a mutation draws them afresh when it first
        # reads them (lazy primary sample space, Kelemen et al. 2002): the same chain, at the
        # cost of the path's length instead of the longest path's (max_depth -1: 261
        # coordinates per state).
        self.store_read = bool(store_read)
        # uniform_estimate (a binary level 0 only): a state taken from a visible uniform
        # proposal carries one more pending weight, 1, after the levels' (index n_levels), so
        # that the model deposits the uniform proposals as an estimate of their own
        # (methods/guided.py; docs/guiding.md, "The uniform photons' estimate").
        if uniform_estimate and not binary_base:
            raise ValueError("the uniform proposals' estimate rides on a binary level 0's exchanges")
        self.uniform_estimate = bool(uniform_estimate)
        self.n_weights = n_levels + (1 if uniform_estimate else 0)
        # A step's mutations are made with this probability and otherwise skipped (the state
        # is recorded again, a lazy kernel that keeps every target): where the uniform
        # proposals' estimate carries the pass, the chains' mutations are work it does not
        # need. A kernel argument, so it may change between passes; 1 draws no random number.
        self.mutation_probability = 1.0
        # Upper levels whose last state still has a non-zero target after run_pass's
        # re-evaluation start from it (then burn in) instead of a resampled bootstrap: an
        # experiment on the start-up bias of short passes (docs/mbe.md, "Start-up").
        self.warm_start = bool(warm_start)
        if not 0.0 <= burn_in < 1.0:
            raise ValueError(f"burn_in is a fraction of each pass in [0, 1), got {burn_in}")
        if seeding not in SEEDINGS:
            raise ValueError(f"seeding must be one of {SEEDINGS}, got {seeding!r}")
        if not binary_base and (seeding != "resample" or expected_values):
            raise ValueError("a level 0 that is not binary has no exact start (it needs seeding='resample') "
                             "and no expected-value records")
        if not 0.0 < bootstrap < 1.0:
            raise ValueError(f"bootstrap is a fraction of each pass in (0, 1), got {bootstrap}")
        self.burn_in = float(burn_in)
        # With the warm start: the share of a pass a ladder discards when one of its upper
        # levels lost its kept state and starts again from a copy (set per pass by the caller;
        # spatial-tf's epochs, docs/guiding.md "Spatial targets held for an epoch").
        self.restart_burn_in = 0.0
        if base_records_in_burn_in and not binary_base:
            raise ValueError("only a binary level 0 is exact during the burn-in")
        # A binary level 0 is exact from its first visible uniform proposal; only exchanges with
        # the burning-in levels above disturb it. With this option it records during the burn-in
        # too, and the exchanges wait for the burn-in's end.
        self.base_records_in_burn_in = bool(base_records_in_burn_in)
        self.binary_base = bool(binary_base)
        self.resample = seeding == "resample"
        self.bootstrap = float(bootstrap) if self.resample else 0.0
        if bootstrap_hits < 1:
            raise ValueError(f"bootstrap_hits must be at least 1, got {bootstrap_hits}")
        self.bootstrap_hits = int(bootstrap_hits)
        if not 0.0 <= large_step < 1.0:
            raise ValueError(f"large_step is a probability in [0, 1), got {large_step}")
        if large_step > 0.0 and expected_values:
            raise ValueError("one move per step (large_step > 0) records no expected values")
        # One move per step is compiled in; its probability of a uniform proposal may change
        # between passes (mbe raises it where the uniform proposals' estimate carries the
        # light side, docs/mbe.md), so it is a kernel argument.
        self.large_step = float(large_step)
        self.one_move = large_step > 0.0
        if not 0.0 <= suffix_mutation < 1.0:
            raise ValueError(f"suffix_mutation is a probability in [0, 1), got {suffix_mutation}")
        if suffix_mutation > 0.0 and not (suffix_starts and all(0 < d < dims for d in suffix_starts)):
            raise ValueError(f"suffix moves need starts inside (0, {dims}), got {suffix_starts}")
        self.suffix_mutation = float(suffix_mutation)
        self.suffix_starts = tuple(int(d) for d in suffix_starts) if suffix_mutation > 0.0 else ()
        starts = [int(d) for d in block_starts]
        if starts and (starts[0] != 0 or any(b <= a for a, b in zip(starts, starts[1:])) or starts[-1] >= dims):
            raise ValueError(f"block_starts must rise from 0 and stay below {dims}, got {block_starts}")
        self.n_blocks = max(len(starts), 1)
        self.n_slots = n_chains * n_levels
        self.drop_failures = bool(drop_failures)
        self.expected_values = bool(expected_values)
        f = FieldGroup("chains")
        self.u = f.scalar(ti.f32, (self.n_slots, dims))
        self.ell = f.scalar(ti.i32, self.n_slots)
        self.T = f.vector(n_levels, ti.f32, self.n_slots)
        self.pending = f.vector(self.n_weights, ti.f32, self.n_slots)
        self.level_slot = f.scalar(ti.i32, (n_chains, n_levels))
        self.fresh = f.scalar(ti.i32, self.n_slots)      # 1: the state belongs to this pass's target
        self.theta = f.scalar(ti.f32, n_levels)
        if self.n_blocks > 1:
            self.block_lo = f.scalar(ti.i32, self.n_blocks, starts)
            self.block_hi = f.scalar(ti.i32, self.n_blocks, starts[1:] + [dims])
            self.block_theta = f.scalar(ti.f32, (n_levels, self.n_blocks))
            self.block_counters = f.scalar(ti.i64, (n_levels, self.n_blocks, 2))    # tried, accepted
        self.counters = f.scalar(ti.i64, (n_levels, N_COUNTERS))
        # Per-ladder float sums, added up on the host in a fixed order (determinism):
        # recorded weight per level, and sum of T[l+1]/T[l] over level-l records.
        self.recorded = f.scalar(ti.f64, (n_chains, n_levels))
        self.ratio = f.scalar(ti.f64, (n_chains, n_levels))
        self.uniform_T = f.scalar(ti.f64, (n_chains, n_levels))   # sum of T_l over uniform proposals
        self.uniform_n = f.scalar(ti.f64, n_chains)                # uniform proposals per ladder
        self.recording = f.scalar(ti.i32, n_chains)      # 0 while the ladder burns in (see run)
        self.seeding_phase = f.scalar(ti.i32, n_chains)  # 1 while the ladder's bootstrap runs (resample)
        # Weighted reservoirs of the bootstrap, per ladder and level: the kept uniform
        # proposal's key, its targets, and the running sum of the level's target.
        self.reservoir_key = f.scalar(ti.u32, (n_chains, n_levels))
        self.reservoir_T = f.vector(n_levels, ti.f32, (n_chains, n_levels))
        self.reservoir_sum = f.scalar(ti.f64, (n_chains, n_levels))
        self.reservoir_hits = f.scalar(ti.i32, (n_chains, n_levels))
        # 1 where the slot's state is the ladder's last probed proposal, accepted: a model
        # with `adopt(ladder, slot)` may then keep what it computed for it (mbe: the splat
        # list) instead of tracing the state again when it deposits. Cleared every pass
        # unless what the model keeps does not change between passes (adopted_across_passes:
        # the guided photons' vertex lists; mbe's splat lists follow the camera subpaths).
        self.adopted = f.scalar(ti.i32, self.n_slots)
        f.finalize()
        self.fields = f
        self._readers = {}          # FieldReaders of the tallies, by the caller's extra fields
        # Cleared at the start of every pass (_clear_pass_tallies).
        self.pass_tallies = (self.counters, self.recorded, self.ratio, self.fresh, self.uniform_T, self.uniform_n,
                             self.reservoir_sum, self.reservoir_hits) + \
            (() if adopted_across_passes else (self.adopted,)) + \
            ((self.block_counters,) if self.n_blocks > 1 else ())
        self.source = _ChainSource(self)
        self.stride = CPU_LADDER_STRIDE if ti.lang.impl.current_cfg().arch == ti.cpu else 1
        self.adapt_passes = np.zeros(n_levels, np.int64)
        self.reset()

    def release(self):
        self.fields.release()

    def reset(self):
        """Empty every chain (they restart from uniform proposals) and theta."""
        fill_fields([(f, 0) for f in (self.u, self.ell, self.T, self.pending, self.counters, self.recorded,
                                      self.ratio, self.fresh, self.uniform_T, self.uniform_n)] +
                    [(self.theta, THETA_START)] +
                    ([(self.block_theta, THETA_START), (self.block_counters, 0)] if self.n_blocks > 1 else []))
        self.level_slot.from_numpy(np.arange(self.n_slots, dtype=np.int32).reshape(self.n_chains, self.n_levels))
        self.adapt_passes[:] = 0
        # theta lives on the host too (float32, as the fields hold it), so that adapting it
        # reads nothing back: every small read or write of a field compiles a kernel of its
        # own with a cold cache (docs/performance.md, "Compile time").
        self.theta_host = np.full(self.n_levels, THETA_START, np.float32)
        self.block_theta_host = np.full((self.n_levels, max(self.n_blocks, 1)), THETA_START, np.float32)

    def set_theta(self, value: float) -> None:
        """Every level's (and block's) mutation size, on the host and in the fields."""
        self.theta_host[:] = value
        self.block_theta_host[:] = value
        upload_fields([(self.theta, self.theta_host)] +
                      ([(self.block_theta, self.block_theta_host)] if self.n_blocks > 1 else []))

    def run_pass(self, model, seed: int, iteration: int, steps: int, extra=()) -> dict:
        """One pass in one launch, each ladder on its own thread: its stored states re-evaluated
        (the target changed: new measurement points or camera subpaths, so every stored state
        is stale), `steps` chain steps in all spread over the ladders, then every pending
        weight deposited. The per-pass tallies are cleared first.

        A stale state is distributed by the old target (restricted to the new one), not by the
        new one: recording it biases the pass by about 1/(steps x b) (measured +2 % to +7 % on
        light-gap, docs/guiding.md). So a pass records level 0 only from its first visible
        uniform proposal on (an exact draw from the new target, after which Metropolis keeps
        the chain exact), and a higher level only once seeded from a fresh level below.

        The first `burn_in` fraction of each ladder's steps records nothing. A ladder's upper
        levels start each pass as copies of level 0's state, not as draws from their targets,
        and the exchanges pass these burning-in states down to level 0 too: the whole ladder is
        out of equilibrium until it has mixed, and recording it from the start biased
        spatial-tf by -3.4 % on the gap-lit room at 32x32 (256 steps per ladder and pass),
        +0.2 % with the first half discarded (docs/guiding.md). Level 0 alone (visibility)
        is exact from its first visible uniform proposal and needs none: with
        base_records_in_burn_in it records the whole pass and exchanges it with level 1 only
        after the burn-in (mbe, docs/mbe.md).

        Returns the pass's tallies (_tallies), read back by the same launch, with the
        caller's `extra` fields (out["extra"])."""
        extra = tuple(extra)
        key = tuple(id(f) for f in extra)
        reader = self._readers.get(key)
        if reader is None:
            reader = self._readers[key] = FieldReader(
                (self.counters, self.recorded, self.ratio, self.uniform_T, self.uniform_n) + extra +
                ((self.block_counters,) if self.n_blocks > 1 else ()))
        ints, floats = reader.arrays()
        with _chain_kernel_compilation():
            self._run(model, seed, iteration, steps, self.burn_in, self.restart_burn_in, self.bootstrap,
                      self.large_step, self.mutation_probability, reader, ints, floats)
        return self._tallies(reader.unpack(ints, floats), len(extra))

    def _tallies(self, values: list, n_extra: int) -> dict:
        """This pass's figures: counters per level, recorded weight and mean T[l+1]/T[l], and
        the caller's extra fields (out["extra"])."""
        c, rec, ratio, uniform_T, uniform_n, *rest = values
        more, blocks = rest[:n_extra], rest[n_extra:]
        rec_per_chain, rec = rec, rec.sum(axis=0)
        ratio = ratio.sum(axis=0)
        n_uniform = max(int(c[0, UNIFORM]), 1)
        out = {"counters": c, "recorded": rec, "recorded_per_chain": rec_per_chain,
               "mean_ratio": np.divide(ratio, rec, out=np.zeros_like(ratio), where=rec > 0),
               "uniform_mean": uniform_T.sum(axis=0) / n_uniform, "uniform_per_chain": uniform_n, "extra": more}
        if self.n_blocks > 1:
            out["block_counters"] = blocks[0]
        return out

    def normalisations(self, tallies: dict) -> np.ndarray:
        """b_0 = visible fraction of uniform proposals; b_{l+1} = b_l E_{T_l}[T_{l+1}/T_l]
        (valid because every level's support lies inside the one below, algorithms.md §3.6)."""
        c = tallies["counters"]
        b = np.zeros(self.n_levels)
        # Binary: the visible fraction, counted exactly; otherwise the mean target of the
        # uniform proposals (the same number for a 0/1 target).
        b[0] = c[0, UNIFORM_VISIBLE] / max(c[0, UNIFORM], 1) if self.binary_base else tallies["uniform_mean"][0]
        for level in range(1, self.n_levels):
            b[level] = b[level - 1] * tallies["mean_ratio"][level - 1]
        return b

    def adapt(self, tallies: dict, target_acceptance: float, uploads=(), upload: bool = True) -> None:
        """Adapt theta per level (and block) to this pass's acceptance. `uploads`: more
        (field, array) pairs the caller writes after the pass, sent in the same batch.
        upload=False (one mutation block only): theta_host changes and the caller writes it
        to `theta` from its own next kernel before the next pass (write_theta), one launch
        less per pass."""
        c = tallies["counters"]
        theta = self.theta_host
        for level in range(self.n_levels):
            n = int(c[level, MUTATIONS])
            if n > 0:
                self.adapt_passes[level] += 1
                theta[level] = adapt_theta(float(theta[level]), c[level, ACCEPTED] / n, target_acceptance,
                                           int(self.adapt_passes[level]))
        pairs = [(self.theta, theta)]
        if self.n_blocks > 1:
            bc = tallies["block_counters"]
            bt = self.block_theta_host
            for level in range(self.n_levels):
                k = int(self.adapt_passes[level])
                for b in range(self.n_blocks):
                    if bc[level, b, 0] > 0 and k > 0:
                        bt[level, b] = adapt_theta(float(bt[level, b]), bc[level, b, 1] / bc[level, b, 0],
                                                   target_acceptance, k)
            pairs.append((self.block_theta, bt))
        if upload:
            upload_fields(pairs + list(uploads))
        elif self.n_blocks > 1 or uploads:
            raise ValueError("adapt(upload=False) leaves one theta per level to the caller, and no other uploads")

    @ti.func
    def write_theta(self, theta: ti.template()):
        """theta (a vector of n_levels, theta_host's values) into the field, from a caller's
        kernel (adapt(upload=False))."""
        for level in ti.static(range(self.n_levels)):
            self.theta[level] = theta[level]

    # -- kernels ------------------------------------------------------------------------
    @ti.kernel
    def _run(self, model: ti.template(), seed: ti.u32, iteration: ti.u32, steps: ti.i32, burn_in: ti.f32,
             restart_burn: ti.f32, bootstrap: ti.f32, large_step: ti.f32, mutate: ti.f32, reader: ti.template(),
             ints: ti.types.ndarray(), floats: ti.types.ndarray()):
        """Per ladder: PROBE (visit every level's stored state once, _step) and the warm
        start, its share of `steps` chain steps (STEPS), DEPOSIT (visit every level's state
        again). large_step: this pass's probability of a uniform proposal (one move per
        step); mutate: the probability that a mutation is made (otherwise skipped, the state
        recorded again); restart_burn: with the warm start, the share a ladder discards when
        one of its upper levels lost its state (a copy starts it again, unmixed). The visits
        draw no random numbers."""
        self._clear_pass_tallies()
        base = steps // self.n_chains
        extra = steps % self.n_chains
        for item in range(self.n_chains * ti.static(self.stride)):
            if item % ti.static(self.stride) == 0:
                c = item // ti.static(self.stride)
                state = rng.seed(seed, ti.u32(c), iteration * ti.u32(2) + ti.u32(1))
                n = base + (1 if c < extra else 0)
                burn = ti.cast(burn_in * n, ti.i32)
                seeding_steps = ti.max(ti.cast(bootstrap * n, ti.i32), 1) if ti.static(self.resample) else 0
                # i = -1: the re-evaluation; 0 .. n-1: the steps; n: the deposits.
                for j in range(n + 2):
                    i = j - 1
                    task = STEPS
                    if i < 0:
                        task = PROBE
                    elif i == n:
                        task = DEPOSIT
                    if task == STEPS:
                        if ti.static(self.resample):
                            self._seed_from_reservoirs(c, i >= seeding_steps)
                            self.seeding_phase[c] = 1 if i < seeding_steps else 0
                        self.recording[c] = 1 if i >= burn else 0
                    self._step(model, c, state, task, large_step, mutate)
                    if ti.static(self.warm_start):
                        if task == PROBE:
                            self._warm_start(c)
                            if restart_burn > 0.0 and self._lost_upper_state(c):
                                burn = ti.max(burn, ti.cast(restart_burn * n, ti.i32))
        reader.copy(ints, floats)       # the tallies, back with this launch

    @ti.func
    def _clear_pass_tallies(self):
        """The pass's tallies zeroed, in the chain kernel's own launch (a separate fill was a
        launch and a batch of template arguments per pass, docs/performance.md): one loop
        per field, run before the ladders' loop, serially where short (runtime.serial_loop)."""
        for f in ti.static(self.pass_tallies):
            ti.loop_config(serialize=ti.static(runtime.serial_loop(scalar_count(f))))
            for i in ti.grouped(ti.ndrange(*f.shape)):
                f[i] = 0

    @ti.func
    def _lost_upper_state(self, c) -> ti.i32:
        """After the warm start: whether an upper level of ladder c has no kept state."""
        lost = 0
        for level in ti.static(range(1, self.n_levels)):
            if not self.fresh[self.level_slot[c, level]]:
                lost = 1
        return lost

    @ti.func
    def _warm_start(self, c):
        """After the re-evaluation (PROBE): each upper level of ladder c whose stored state
        still has a non-zero target under the new one starts from it: fresh, its reservoir
        spent."""
        for level in ti.static(range(1, self.n_levels)):
            s = self.level_slot[c, level]
            t = self.T[s]
            if t[level] > 0.0:
                self.fresh[s] = 1
                self.reservoir_hits[c, level] = -1 << 30

    # -- one step of one ladder ------------------------------------------------------------
    @ti.func
    def _step(self, model: ti.template(), c, state: ti.template(), task, large_step, mutate):
        """Move 0: a uniform proposal for level 0 (the exchange with the implicit uniform chain:
        a visible one is always taken, since the swap ratio is V(u_uniform) = 1). Move 1: if it
        was invisible, a mutation of level 0. Moves 2..: a mutation of each higher level.
        Then replica exchanges between neighbours.

        With `large_step` > 0 a step makes one move only, one proposal traced (as in MBE's
        reference implementations): move 0 with probability large_step, otherwise the
        mutation of a level drawn uniformly; every level that did not move records its
        state again. A random scan over moves that each keep their targets keeps them too.

        task PROBE / DEPOSIT instead visits each level's stored state through the same trace
        call site: PROBE re-evaluates its targets (they changed), DEPOSIT deposits its pending
        weight; nothing else happens and no random number is drawn."""
        zero = ti.Vector([0.0] * self.n_levels)
        zero_w = ti.Vector([0.0] * self.n_weights)
        visit = task != STEPS
        uniform_visible = 0
        chosen = -1
        if ti.static(self.one_move) and not visit:
            r = rng.next_float(state)
            chosen = 0
            if r >= large_step:
                pick = ti.cast((r - large_step) / (1.0 - large_step) * self.n_levels, ti.i32)
                chosen = 1 + ti.min(pick, self.n_levels - 1)
        for move in range(self.n_levels + 1):
            level = ti.max(move - 1, 0)
            s = self.level_slot[c, level]
            if visit:
                if move == 0:
                    continue      # a visit: moves 1.. name the levels' stored states
            else:
                if ti.static(self.one_move) and move != chosen:
                    continue
                if ti.static(self.binary_base) and move == 1 and uniform_visible:
                    continue      # H&J's loop: mutate only when the uniform proposal was invisible
                if move > 0 and not self.fresh[s]:
                    continue      # a stale state is not recorded, so mutating it is wasted work
            skipped = 0
            if not visit and move > 0 and mutate < 1.0:
                if rng.next_float(state) >= mutate:
                    skipped = 1       # no mutation: the state is recorded again below
            mode = MUTATION_MODE
            key = ti.math.uvec4(s, 0, 0, STATE_MODE)
            if not visit:
                if move == 0:
                    mode = UNIFORM_MODE
                elif ti.static(self.suffix_mutation > 0.0):
                    r = rng.next_float(state)
                    if r < ti.static(self.suffix_mutation):
                        n_starts = ti.static(len(self.suffix_starts))
                        pick = ti.min(ti.cast(r / ti.static(self.suffix_mutation) * n_starts, ti.i32), n_starts - 1)
                        start = 0
                        for k in ti.static(range(n_starts)):
                            if pick == k:
                                start = self.suffix_starts[k]
                        mode = SUFFIX_MODE + MODE_BITS * start
                if ti.static(self.n_blocks > 1):
                    if mode == MUTATION_MODE:
                        pick = ti.min(ti.cast(rng.next_float(state) * self.n_blocks, ti.i32), self.n_blocks - 1)
                        mode = MUTATION_MODE + MODE_BITS * pick
                key = ti.math.uvec4(s, rng.next_u32(state), level, mode)
            t_new = zero
            read = 0          # coordinates the proposal's evaluation read
            accept = 0
            a = 0.0
            deposit_key = key
            deposit_w = zero_w
            deposit_t = zero
            if visit and task == DEPOSIT:
                deposit_w = self.pending[s]
                deposit_t = self.T[s]
            # Phase 0 evaluates the proposal; phase 1 makes the deposit the decision calls for
            # (the replaced state's pending weight, or an expected-value share of a rejected
            # proposal). One trace call site for both, and for the visits.
            for phase in range(2):
                trace_key = key
                trace_mode = PROBE
                traced = phase == 0 and not skipped
                if visit:
                    trace_mode = task
                    traced = phase == 0 and ((task == PROBE and self.ell[s] > 0) or
                                             (task == DEPOSIT and deposit_w.max() > 0.0))
                elif phase == 1:
                    trace_key = deposit_key
                    trace_mode = DEPOSIT
                    traced = deposit_w.max() > 0.0
                if traced:
                    result, n_read = model.trace(self.source, trace_key, c, trace_mode, deposit_w, deposit_t)
                    if visit:
                        t_new = result
                    elif phase == 0:
                        t_new = result
                        read = n_read
                        accept, a = self._decide(c, level, move, mode % MODE_BITS == SUFFIX_MODE, s, t_new, state)
                        if ti.static(self.n_blocks > 1):
                            if move > 0 and mode % MODE_BITS == MUTATION_MODE:
                                b = mode // MODE_BITS
                                ti.atomic_add(self.block_counters[level, b, 0], 1)
                                ti.atomic_add(self.block_counters[level, b, 1], accept)
                        if move == 0:
                            uniform_visible = accept
                            if ti.static(self.binary_base) and accept:
                                self.fresh[s] = 1     # an exact draw from V / b_V
                            if ti.static(self.resample):
                                if self.seeding_phase[c]:
                                    self._offer_to_reservoirs(c, key[1], t_new, state)
                        if accept:
                            deposit_key = ti.math.uvec4(s, 0, 0, STATE_MODE)
                            deposit_w = self.pending[s]
                            deposit_t = self.T[s]
                        elif ti.static(self.expected_values) and a > 0.0 and self._recording(c, level):
                            for k in ti.static(range(self.n_levels)):
                                if k == level:
                                    deposit_w[k] = a
                            deposit_t = t_new
                            self._tally(c, level, t_new, a)
            if visit:
                if task == PROBE:
                    self.T[s] = t_new
                else:
                    self.pending[s] = zero_w
                continue
            if accept:
                self._store(s, key, t_new, read)
                if ti.static(self.uniform_estimate):
                    if move == 0:
                        p = self.pending[s]
                        p[self.n_levels] = 1.0      # one uniform photon, whatever the levels record
                        self.pending[s] = p
                if ti.static(hasattr(model, "adopt")):
                    model.adopt(c, s)
                    self.adopted[s] = 1
                w_new = 1.0
                if ti.static(self.expected_values) and move > 0:
                    w_new = a
                self._record(c, level, s, w_new)
            elif (move > 0 or ti.static(not self.binary_base or self.one_move)) and \
                    (skipped or not (ti.static(self.drop_failures) and component(t_new, level) <= 0.0)):
                # A rejected (or skipped) proposal repeats the current state. (A binary level 0
                # that rejects its uniform proposal records after the mutation that follows.)
                if (ti.static(not self.expected_values) or skipped) and component(self.T[s], level) > 0.0:
                    self._record(c, level, s, 1.0)
        if not visit:
            if ti.static(self.one_move):
                moved = ti.max(chosen - 1, 0)
                for level in range(self.n_levels):
                    s = self.level_slot[c, level]
                    if level != moved and component(self.T[s], level) > 0.0:
                        self._record(c, level, s, 1.0)
            for level in ti.static(range(self.n_levels - 1)):
                self._exchange(c, level, state)

    @ti.func
    def _decide(self, c, level, move, suffix, s, t_new, state: ti.template()):
        """Metropolis-Hastings decision for a proposal with target values t_new (a uniform
        proposal to level 0 is taken iff visible). Records the current state's expected-value
        share (1 - a) before it may be replaced."""
        a = 0.0
        accept = 0
        if move == 0:
            ti.atomic_add(self.counters[0, UNIFORM], 1)
            self.uniform_n[c] += 1.0
            for k in ti.static(range(self.n_levels)):
                self.uniform_T[c, k] += ti.cast(t_new[k], ti.f64)
            if t_new[0] > 0.0:
                ti.atomic_add(self.counters[0, UNIFORM_VISIBLE], 1)
                a = 1.0
                if ti.static(not self.binary_base):
                    # Independence Metropolis-Hastings (the uniform proposal density cancels).
                    t_cur0 = component(self.T[s], 0)
                    if t_cur0 > 0.0:
                        a = ti.min(1.0, t_new[0] / t_cur0)
                if ti.static(self.binary_base):
                    accept = 1
                elif rng.next_float(state) < a:
                    accept = 1
        else:
            ti.atomic_add(self.counters[level, SUFFIX_TRIED if suffix else MUTATIONS], 1)
            t_cur = component(self.T[s], level)
            if component(t_new, level) > 0.0:
                a = 1.0
                if t_cur > 0.0:
                    a = ti.min(1.0, component(t_new, level) / t_cur)
            else:
                ti.atomic_add(self.counters[level, FAILURES], 1)
                if ti.static(self.drop_failures):
                    # The proposal-failure remedy (Zeng & Wei 2019): a failed proposal records
                    # nothing. It samples T z instead of T (algorithms.md §5.2): an option.
                    ti.atomic_add(self.counters[level, FAILURES_DROPPED], 1)
            if rng.next_float(state) < a:
                accept = 1
                ti.atomic_add(self.counters[level, SUFFIX_ACCEPTED if suffix else ACCEPTED], 1)
            dropped = ti.static(self.drop_failures) and component(t_new, level) <= 0.0
            if ti.static(self.expected_values) and t_cur > 0.0 and a < 1.0 and not dropped:
                self._record(c, level, s, 1.0 - a)
        return accept, a

    @ti.func
    def _exchange(self, c, lo: ti.template(), state: ti.template()):
        hi = lo + 1
        sa = self.level_slot[c, lo]
        sb = self.level_slot[c, hi]
        # Read whole vectors: Taichi 1.7.4's compiler crashes on field[i][k] reads here.
        ta = self.T[sa]
        tb = self.T[sb]
        num = tb[lo] * ta[hi]
        den = ta[lo] * tb[hi]
        u = rng.next_float(state)
        swap = 0
        if den > 0.0:
            if u * den < num:
                swap = 1

        if self.fresh[sa] and not self.fresh[sb]:
            # Seed the upper level with a copy of the lower one's state (no exchange is
            # counted); resampled ladders wait for their bootstrap instead.
            if ti.static(not self.resample) and ta[hi] > 0.0:
                self._copy(sa, sb)
                ti.atomic_add(self.counters[hi, SEEDED_COPIED], 1)
        elif self.fresh[sa] and self.fresh[sb] and \
                (ti.static(not self.base_records_in_burn_in or lo > 0) or self.recording[c]):
            ti.atomic_add(self.counters[lo, SWAPS_TRIED], 1)
            if swap:
                ti.atomic_add(self.counters[lo, SWAPS_ACCEPTED], 1)
                self.level_slot[c, lo] = sb
                self.level_slot[c, hi] = sa

    @ti.func
    def _offer_to_reservoirs(self, c, proposal_key: ti.u32, t_new, state: ti.template()):
        """Bootstrap: each level that needs a start keeps this uniform proposal with probability
        T_l(u) / (sum of T_l over the proposals so far), so that the kept one is drawn in
        proportion to T_l among them."""
        for level in ti.static(range(self.n_levels)):
            if ti.static(level > 0 or not self.binary_base):
                t = t_new[level]
                if t > 0.0:
                    total = self.reservoir_sum[c, level] + ti.cast(t, ti.f64)
                    self.reservoir_sum[c, level] = total
                    self.reservoir_hits[c, level] += 1
                    if rng.next_float(state) * total < t:
                        self.reservoir_key[c, level] = proposal_key
                        self.reservoir_T[c, level] = t_new

    @ti.func
    def _seed_from_reservoirs(self, c, bootstrap_over):
        """Before each step: a level that is not yet exact starts from its reservoir's proposal
        once the reservoir has seen bootstrap_hits proposals, or any, when the bootstrap is
        over (stale slots hold nothing pending, so nothing is lost)."""
        for level in ti.static(range(self.n_levels)):
            if ti.static(level > 0 or not self.binary_base):
                s = self.level_slot[c, level]
                hits = self.reservoir_hits[c, level]
                ready = hits >= ti.static(self.bootstrap_hits) or (bootstrap_over and hits > 0)
                if not self.fresh[s] and ready:
                    self._store(s, ti.math.uvec4(s, self.reservoir_key[c, level], level, UNIFORM_MODE),
                                self.reservoir_T[c, level], self.dims)
                    self.fresh[s] = 1
                    self.reservoir_hits[c, level] = -1 << 30      # seeded: the reservoir is spent
                    ti.atomic_add(self.counters[level, SEEDED_RESAMPLED], 1)

    @ti.func
    def _copy(self, src, dst):
        """dst (stale, nothing pending) becomes a fresh copy of src's state."""
        n = self.ell[src]
        for d in range(n):
            self.u[dst, d] = self.u[src, d]
        if ti.static(self.store_read):
            self.u[dst, self.dims - 1] = self.u[src, self.dims - 1]      # stored beyond ell
        self.ell[dst] = n
        self.T[dst] = self.T[src]
        self.fresh[dst] = 1
        self.adopted[dst] = 0

    @ti.func
    def _tally(self, c, level, t, w):
        self.recorded[c, level] += ti.cast(w, ti.f64)
        if level + 1 < self.n_levels:
            self.ratio[c, level] += ti.cast(w * component(t, level + 1) / component(t, level), ti.f64)

    @ti.func
    def _recording(self, c, level) -> ti.i32:
        """Whether ladder c records `level` now: past the burn-in, or level 0 throughout where
        it is exact (base_records_in_burn_in)."""
        on = self.recording[c]
        if ti.static(self.base_records_in_burn_in):
            if level == 0:
                on = 1
        return on

    @ti.func
    def _record(self, c, level, s, w):
        """The state in slot s is a sample of `level` with weight w (deposited later); nothing
        while the ladder burns in."""
        if self._recording(c, level) and self.fresh[s]:
            self._tally(c, level, self.T[s], w)
            p = self.pending[s]
            for k in ti.static(range(self.n_levels)):
                if k == level:
                    p[k] += w
            self.pending[s] = p

    @ti.func
    def _store(self, s, key, t_new, read):
        """Slot s takes the proposal named by key (its pending weight was deposited), whose
        evaluation read `read` coordinates. Every coordinate is stored, so that a state's path
        is fixed even where its evaluation stopped early (the visibility probe stops at the
        first accepted vertex); with store_read the ones read and the last."""
        self.adopted[s] = 0
        n = self.dims
        if ti.static(self.store_read):
            n = ti.min(ti.max(read, 1), self.dims)     # ell > 0 marks a slot that holds a state
            self.u[s, self.dims - 1] = self.source.get(key, self.dims - 1)
        for d in range(n):
            self.u[s, d] = self.source.get(key, d)
        self.ell[s] = n
        self.T[s] = t_new
        self.pending[s] = ti.Vector([0.0] * self.n_weights)

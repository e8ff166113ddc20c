"""The Markov-chain machinery (photonmc/kernels/mcmc.py) on toy targets in [0,1)^2 whose
integrals and bin probabilities are known exactly.

Histogram checks use a chi-square over bins whose variances come from independent groups of
chains, so the autocorrelation of each chain is accounted for, not ignored."""
import numpy as np
import pytest
import taichi as ti
from scipy import stats as sps

from photonmc.kernels.fields import FieldGroup
from photonmc.kernels.mcmc import (ACCEPTED, DEPOSIT, MUTATIONS, SEEDED_RESAMPLED, SUFFIX_ACCEPTED, SUFFIX_TRIED,
                                   SWAPS_ACCEPTED, THETA_MAX, THETA_MIN, ChainPool, adapt_theta)

BINS = 8
GROUPS = 32
KINDS = {"strip": 0, "all": 1, "needle": 2, "disc": 3}
FINE = 800            # integration grid: aligned with every edge of the supports below


@ti.func
def in_support(x, y, kind: ti.template()):
    inside = 0
    if ti.static(kind == KINDS["all"]):
        inside = 1
    elif ti.static(kind == KINDS["needle"]):
        inside = 1 if (0.5 <= x < 0.51 and 0.5 <= y < 0.505) else 0
    elif ti.static(kind == KINDS["disc"]):
        inside = 1 if (x - 0.5) ** 2 + (y - 0.5) ** 2 < 0.015 else 0
    else:  # a square and a narrow strip: mutations often leave the strip (proposal failures)
        if (x < 0.5 and y < 0.5) or (x >= 0.5 and 0.2 <= y < 0.25):
            inside = 1
    return inside


def support_np(x, y, kind):
    if kind == "all":
        return np.ones_like(x)
    if kind == "disc":
        return ((x - 0.5) ** 2 + (y - 0.5) ** 2 < 0.015).astype(float)
    if kind == "needle":
        return ((0.5 <= x) & (x < 0.51) & (0.5 <= y) & (y < 0.505)).astype(float)
    return (((x < 0.5) & (y < 0.5)) | ((x >= 0.5) & (0.2 <= y) & (y < 0.25))).astype(float)


def targets_np(x, y, kind, levels, shift=0):
    v = support_np(x, y, kind)
    return [v, v * (0.1 + x), v * (0.05 + x * y * 4.0)][shift:shift + levels]


@ti.data_oriented
class ToyModel:
    """Targets: V (the support), V (0.1 + x), V (0.05 + 4xy); deposits into per-group histograms.

    lazy (a pool of 3 coordinates with store_read): y is the last coordinate, and a third, z,
    is read only where x < 0.5, where it multiplies the upper levels' targets by 2z (whose
    mean is 1, so each target's marginal over (x, y) is unchanged); the trace reports the
    coordinates it read, 1 or 2, as mbe's light subpaths of varying length do."""

    def __init__(self, levels, chains, kind="strip", shift=0, lazy=False):
        # shift 1: the levels are T1, T2 (a level 0 that is not binary)
        self.levels, self.kind_id, self.shift, self.lazy = levels, KINDS[kind], shift, lazy
        self.chains = chains
        f = FieldGroup("toy-model")
        self.hist = f.scalar(ti.f64, (levels, GROUPS, BINS, BINS))
        self.uniform_hist = f.scalar(ti.f64, (GROUPS, BINS, BINS))     # uniform_estimate's weights
        f.finalize()
        self.fields = f

    @ti.func
    def trace(self, source: ti.template(), key, vkey, mode, w, t):
        x = source.get(key, 0)
        y = source.get(key, ti.static(2 if self.lazy else 1))
        read = 2
        z_factor = 1.0
        if ti.static(self.lazy):
            read = 1
            if x < 0.5:
                z_factor = 2.0 * source.get(key, 1)
                read = 2
        v = ti.cast(in_support(x, y, self.kind_id), ti.f32)
        full = ti.Vector([v, v * (0.1 + x) * z_factor, v * (0.05 + x * y * 4.0) * z_factor])
        out = ti.Vector([0.0] * self.levels)
        for k in ti.static(range(self.levels)):
            out[k] = full[k + self.shift]
        if mode == DEPOSIT:
            g = vkey % GROUPS
            bx = ti.min(ti.cast(x * BINS, ti.i32), BINS - 1)
            by = ti.min(ti.cast(y * BINS, ti.i32), BINS - 1)
            for k in ti.static(range(self.levels)):
                self.hist[k, g, bx, by] += ti.cast(w[k], ti.f64)
            if ti.static(w.n > self.levels):
                self.uniform_hist[g, bx, by] += ti.cast(w[self.levels], ti.f64)
        return out, read


def exact_bins(kind, levels, shift=0):
    c = (np.arange(FINE) + 0.5) / FINE
    x, y = np.meshgrid(c, c, indexing="ij")
    out = []
    for t in targets_np(x, y, kind, levels, shift):
        b = t.reshape(BINS, FINE // BINS, BINS, FINE // BINS).sum(axis=(1, 3)) / FINE**2
        out.append(b)
    return out          # per level: integral of T over each bin


def run_toy(levels, chains=GROUPS * 16, passes=3, steps_per_chain=1600, kind="strip", drop=False, ev=False,
            adapt=True, theta=None, seed=3, target_acceptance=0.234, burn_in=0.0, seeding="copy", bootstrap=0.125,
            shift=0, large_step=0.0, suffix_mutation=0.0, block_starts=(), base_records_in_burn_in=False,
            mutation_probability=1.0, uniform_estimate=False, lazy=False, out=None):
    model = ToyModel(levels, chains, kind, shift, lazy)
    pool = ChainPool(chains, levels, 3 if lazy else 2, store_read=lazy, drop_failures=drop, expected_values=ev, burn_in=burn_in,
                     binary_base=shift == 0, seeding=seeding, bootstrap=bootstrap, large_step=large_step,
                     suffix_mutation=suffix_mutation, suffix_starts=(1,), block_starts=block_starts,
                     base_records_in_burn_in=base_records_in_burn_in, uniform_estimate=uniform_estimate)
    pool.mutation_probability = mutation_probability
    if theta is not None:
        pool.set_theta(theta)
    b_sum = np.zeros(levels)
    last = None
    sum_uniform = 0
    for it in range(passes):
        last = pool.run_pass(model, seed, it, chains * steps_per_chain)
        sum_uniform += int(last["counters"][0, 2])
        b_sum += pool.normalisations(last)
        if adapt:
            pool.adapt(last, target_acceptance)
    hist = model.hist.to_numpy()
    if out is not None:       # what else the caller asked for
        out["uniform_hist"] = model.uniform_hist.to_numpy()
        out["uniform_proposals"] = sum_uniform
        out["states"] = (pool.u.to_numpy(), pool.ell.to_numpy(), pool.T.to_numpy())
    theta = pool.theta.to_numpy() if not block_starts else pool.block_theta.to_numpy()
    model.fields.release()
    pool.release()
    return hist, b_sum / passes, last, theta


def chi_square(group_hist, expected_p):
    """group_hist: (GROUPS, bins...) recorded weights; expected_p: bin probabilities.
    Returns (chi2, dof) of the groups' mean frequencies against expected_p."""
    g = group_hist.reshape(GROUPS, -1)
    freq = g / g.sum(axis=1, keepdims=True)
    p = expected_p.reshape(-1) / expected_p.sum()
    keep = p > 0
    mean = freq.mean(axis=0)[keep]
    var = freq.var(axis=0, ddof=1)[keep] / GROUPS
    assert (freq[:, ~keep] == 0).all(), "samples outside the target's support"
    return float(((mean - p[keep]) ** 2 / np.maximum(var, 1e-30)).sum()), int(keep.sum())


def assert_every_level_samples_its_target(hist, b, exact, rtol=0.01):
    """Each level's recorded states pass the chi-square at the 0.1 % level and the chained
    normalisations match the exact integrals."""
    for level in range(len(exact)):
        chi2, dof = chi_square(hist[level], exact[level])
        print(f"level {level}: chi2 {chi2:.1f} on {dof} bins")
        assert chi2 < sps.chi2.ppf(0.999, dof), f"level {level} does not sample its target"
    np.testing.assert_allclose(b, [e.sum() for e in exact], rtol=rtol)


def test_adaptation_step_diminishes_and_clamps():
    assert adapt_theta(0.1, 0.234, 0.234, 1) == pytest.approx(0.1)
    big, late = adapt_theta(0.1, 0.5, 0.234, 1) / 0.1, adapt_theta(0.1, 0.5, 0.234, 1000) / 0.1
    assert big > late > 1.0 and late < 1.05
    assert adapt_theta(0.5, 0.0, 0.234, 1) < 0.5 and adapt_theta(1e-4, 0.0, 0.234, 1) == THETA_MIN
    assert adapt_theta(0.9, 1.0, 0.234, 1) == THETA_MAX


@pytest.mark.parametrize("ev", [False, True], ids=["splat-states", "expected-values"])
def test_every_level_samples_its_target_and_normalisations_chain(ev):
    """Three levels with replica exchange: each level's recorded states follow its own target
    (chi-square at the 0.1 % level over 64 bins), and b_0 = int V, b_1 = b_0 E_0[T1/T0],
    b_2 = b_1 E_1[T2/T1] match the exact integrals."""
    hist, b, last, _ = run_toy(3, ev=ev)
    exact = exact_bins("strip", 3)
    for level in range(3):
        chi2, dof = chi_square(hist[level], exact[level])
        print(f"level {level}: chi2 {chi2:.1f} on {dof} bins")
        assert chi2 < sps.chi2.ppf(0.999, dof), f"level {level} does not sample its target"
    integrals = np.array([e.sum() for e in exact])
    print("b", b, "exact", integrals)
    np.testing.assert_allclose(b, integrals, rtol=0.01)
    c = last["counters"]
    assert (c[:2, 4] > 0).all() and (c[:2, 5] > 0).all(), "replica exchanges were tried and accepted"


def test_burn_in_removes_the_ladders_start_up_bias():
    """Upper levels start each pass as copies of level 0's state, so on short passes the ladder
    records a distribution that has not reached its targets yet, and the exchanges hand that
    to level 0 as well. 50 steps per ladder and pass: the upper levels are rejected by the
    chi-square (measured 375 and 457 on 20 bins, 0.1 % level 45; level 0 53); discarding
    each pass's first half, every level passes (measured 16, 17, 19). At 20 steps level 0,
    which only ever receives the upper levels' states through exchanges, is far off (174)."""
    exact = exact_bins("strip", 3)

    def chi2s(**kw):
        hist, _, _, _ = run_toy(3, **kw)
        return [chi_square(hist[level], exact[level]) for level in range(3)]

    limit = sps.chi2.ppf(0.999, int((exact[0] > 0).sum()))      # every level has the same support
    recorded_from_start = chi2s(passes=16, steps_per_chain=50)
    burnt_in = chi2s(passes=16, steps_per_chain=50, burn_in=0.5)
    burnt_in_ev = chi2s(passes=16, steps_per_chain=50, burn_in=0.5, ev=True)     # expected values too
    level0_short = chi2s(passes=40, steps_per_chain=20)[0][0]
    print("chi2 without burn-in", recorded_from_start, "with", burnt_in, "with expected values", burnt_in_ev,
          "level 0 at 20 steps", level0_short)
    assert all(chi2 > limit for chi2, _ in recorded_from_start[1:])
    assert level0_short > limit
    assert all(chi2 < limit for chi2, _ in burnt_in + burnt_in_ev)


def test_resampled_starts_replace_most_of_the_burn_in():
    """seeding='resample': each upper level starts from one of the bootstrap's uniform proposals
    drawn in proportion to its target (once 8 proposals inside the support were offered, about
    the first 29 steps here), instead of a copy of the level below. 160 steps per ladder and
    pass: copies recorded from the start are rejected (measured chi-square 76 and 78 on 20
    bins, limit 45), resampled starts pass (21, 23) while the upper levels skip a fifth of the
    pass, not half. (At 50 steps per pass they do not: 173 and 223.)"""
    exact = exact_bins("strip", 3)
    limit = sps.chi2.ppf(0.999, int((exact[0] > 0).sum()))

    def chi2s(**kw):
        hist, b, last, _ = run_toy(3, passes=8, steps_per_chain=160, **kw)
        return [chi_square(hist[level], exact[level])[0] for level in range(3)], b, last["counters"]

    copied, _, _ = chi2s()
    resampled, b, counters = chi2s(seeding="resample")
    print("chi2 copied", copied, "resampled", resampled)
    assert max(copied[1:]) > limit
    assert max(resampled) < limit
    np.testing.assert_allclose(b, [e.sum() for e in exact], rtol=0.01)
    assert counters[1:, SEEDED_RESAMPLED].sum() > 0


def test_a_level_0_target_that_is_not_binary():
    """Level 0 with T = V (0.1 + x): independence Metropolis-Hastings for the uniform proposals,
    a mutation every step, a resampled start; both levels sample their targets and b_0 is the
    mean target of the uniform proposals."""
    hist, b, _, _ = run_toy(2, shift=1, passes=4, steps_per_chain=256, seeding="resample")
    exact = exact_bins("strip", 2, shift=1)
    for level in range(2):
        chi2, dof = chi_square(hist[level], exact[level])
        print(f"level {level}: chi2 {chi2:.1f} on {dof} bins")
        assert chi2 < sps.chi2.ppf(0.999, dof)
    np.testing.assert_allclose(b, [e.sum() for e in exact], rtol=0.01)
    with pytest.raises(ValueError, match="not binary"):
        ChainPool(4, 2, 2, binary_base=False)


def test_level_0_recording_through_the_burn_in_keeps_every_target():
    """mbe's ladder (two levels, one move per step, resampled starts, the first half of each
    pass burning in) with base_records_in_burn_in: level 0, exact from its first visible
    uniform proposal, records the whole pass and exchanges wait for the burn-in's end. Both
    levels still sample their targets, at short passes too, the normalisations hold, and
    level 0 records about twice the weight level 1 does."""
    exact = exact_bins("strip", 2)
    for steps in (160, 800):
        hist, b, last, _ = run_toy(2, passes=8, steps_per_chain=steps, seeding="resample", large_step=0.3,
                                   burn_in=0.5, bootstrap=0.25, base_records_in_burn_in=True)
        for level in range(2):
            chi2, dof = chi_square(hist[level], exact[level])
            print(f"{steps} steps, level {level}: chi2 {chi2:.1f} on {dof} bins")
            assert chi2 < sps.chi2.ppf(0.999, dof)
        np.testing.assert_allclose(b, [e.sum() for e in exact], rtol=0.015)
        assert 1.7 < last["recorded"][0] / last["recorded"][1] < 2.3
        assert last["counters"][0, SWAPS_ACCEPTED] > 0
    with pytest.raises(ValueError, match="only a binary level 0"):
        ChainPool(4, 2, 2, binary_base=False, seeding="resample", base_records_in_burn_in=True)


@pytest.mark.parametrize("levels", [2, 3])
def test_one_move_per_step_keeps_every_target(levels):
    """large_step 0.3 (mbe's scan: one proposal traced per step, a uniform one with probability
    0.3, else one level's mutation; levels that did not move record their state again), with
    resampled starts: every level samples its target and the normalisations hold."""
    hist, b, last, _ = run_toy(levels, passes=4, steps_per_chain=800, seeding="resample", large_step=0.3)
    exact = exact_bins("strip", levels)
    for level in range(levels):
        chi2, dof = chi_square(hist[level], exact[level])
        print(f"level {level}: chi2 {chi2:.1f} on {dof} bins")
        assert chi2 < sps.chi2.ppf(0.999, dof)
    np.testing.assert_allclose(b, [e.sum() for e in exact], rtol=0.015)
    c = last["counters"]
    uniform_share = c[0, 2] / (GROUPS * 16 * 800)      # uniform proposals per step, last pass
    assert abs(uniform_share - 0.3) < 0.005


@pytest.mark.parametrize("seeding", ["resample", "copy"])
def test_states_that_keep_only_the_coordinates_they_read_keep_every_target(seeding):
    """store_read (mbe's states keep the coordinates their light subpath read, and the pairing
    coordinate): the toy's z is stored only by states with x < 0.5, so a mutation from x >= 0.5
    into x < 0.5 draws z afresh, and the upper levels' targets depend on it. Every level must
    still sample its target (z's factor has mean 1, so the exact bins are the plain toy's),
    with one move per step and resampled starts as mbe runs them, or upper levels started as
    copies of the level below (then burnt in), which copy the stored coordinates."""
    out = {}
    hist, b, last, _ = run_toy(3, passes=4, steps_per_chain=800, seeding=seeding, large_step=0.3, lazy=True,
                               burn_in=0.5 if seeding == "copy" else 0.0, out=out)
    assert_every_level_samples_its_target(hist, b, exact_bins("strip", 3), rtol=0.02)
    assert last["counters"][1, ACCEPTED] > 0 and last["counters"][2, ACCEPTED] > 0
    # Each stored state is the path it was evaluated as: its targets from the stored
    # coordinates (z where it was read) equal the ones recorded when it was accepted.
    u, ell, t = out["states"]
    held = (ell > 0) & (t[:, 0] > 0)
    x, y = u[held, 0], u[held, 2]
    z_factor = np.where(x < 0.5, 2.0 * u[held, 1], 1.0)
    assert (ell[held] >= np.where(x < 0.5, 2, 1)).all()
    v = support_np(x, y, "strip")
    np.testing.assert_allclose(t[held], np.stack([v, v * (0.1 + x) * z_factor, v * (0.05 + 4 * x * y) * z_factor], 1),
                               rtol=1e-5)


@pytest.mark.parametrize("ev", [False, True], ids=["splat-states", "expected-values"])
def test_skipped_mutations_keep_every_target_and_uniform_weights_count_the_uniform_proposals(ev):
    """The guided photon methods' --uniform-weight machinery (docs/guiding.md): mutations
    made with probability 0.3 only (a skipped one records the state again, a lazy kernel),
    and each state taken from a visible uniform proposal carrying one more pending weight.
    Every level still samples its target, the normalisations hold, theta's statistics
    count the mutations made (0.3 of the steps whose uniform proposal was invisible, at
    level 0), and the uniform weights deposited are the visible uniform proposals, binned:
    a multinomial sample of the support, checked against its exact bins."""
    out = {}
    hist, b, last, _ = run_toy(3, ev=ev, mutation_probability=0.3, uniform_estimate=True, out=out)
    assert_every_level_samples_its_target(hist, b, exact_bins("strip", 3))
    c = last["counters"]
    steps = GROUPS * 16 * 1600
    invisible = steps - c[0, 3]          # UNIFORM_VISIBLE
    assert abs(c[0, MUTATIONS] / invisible - 0.3) < 0.01
    assert abs(c[1, MUTATIONS] / steps - 0.3) < 0.01
    counts = out["uniform_hist"]                      # (GROUPS, BINS, BINS)
    n_uniform = out["uniform_proposals"]
    expected = exact_bins("strip", 1)[0] * n_uniform   # visible uniform proposals per bin
    total = counts.sum(axis=0)
    inside = expected > 0
    assert (total[~inside] == 0).all()
    chi2 = float((((total - expected) ** 2)[inside] / expected[inside]).sum())
    print(f"uniform weights: chi2 {chi2:.1f} on {inside.sum()} bins, {total.sum():.0f} of {n_uniform}")
    assert chi2 < sps.chi2.ppf(0.999, inside.sum())
    with pytest.raises(ValueError, match="binary level 0"):
        ChainPool(4, 1, 2, binary_base=False, seeding="resample", uniform_estimate=True)


@pytest.mark.parametrize("ev", [False, True], ids=["splat-states", "expected-values"])
def test_suffix_moves_keep_every_target(ev):
    """Half the mutations redraw y and keep x (the toy's suffix move; the perturbation moves
    both): every level still samples its target, the normalisations hold, and theta's
    statistics count the perturbations only."""
    hist, b, last, _ = run_toy(3, ev=ev, suffix_mutation=0.5)
    assert_every_level_samples_its_target(hist, b, exact_bins("strip", 3))
    c = last["counters"]
    share = c[:, SUFFIX_TRIED] / (c[:, SUFFIX_TRIED] + c[:, MUTATIONS])
    assert np.all(np.abs(share - 0.5) < 0.01), share
    assert (c[:, SUFFIX_ACCEPTED] > 0).all() and (c[:, SUFFIX_ACCEPTED] <= c[:, SUFFIX_TRIED]).all()
    with pytest.raises(ValueError, match="suffix moves need starts"):
        ChainPool(4, 1, 2, suffix_mutation=0.5, suffix_starts=(2,))


def test_block_moves_keep_every_target_and_adapt_a_width_per_block():
    """Perturbations of x alone or y alone (two blocks, one drawn per mutation), each block
    with its own theta: every level samples its target, and on a needle half as wide in y as
    in x the two widths part."""
    hist, b, last, _ = run_toy(3, block_starts=(0, 1), passes=6)
    assert_every_level_samples_its_target(hist, b, exact_bins("strip", 3))
    bc = last["block_counters"]
    share = bc[:, 0, 0] / bc[:, :, 0].sum(axis=1)
    assert np.all(np.abs(share - 0.5) < 0.01)
    _, _, last, theta = run_toy(1, kind="needle", block_starts=(0, 1), passes=8)
    bc = last["block_counters"][0]
    print("needle: theta per block", theta[0], "acceptance", bc[:, 1] / bc[:, 0])
    assert theta.shape == (1, 2) and theta[0, 1] < theta[0, 0]
    with pytest.raises(ValueError, match="block_starts"):
        ChainPool(4, 1, 2, block_starts=(1,))


def test_adaptation_reaches_the_target_acceptance():
    """On a disc covering 4.7 % of the square (so that 0.234 lies between what tiny and
    independent steps achieve), every level's acceptance settles within 0.02 of 0.234."""
    _, _, last, theta = run_toy(3, passes=12, kind="disc")
    c = last["counters"]
    acceptance = c[:, ACCEPTED] / c[:, MUTATIONS]
    print("acceptance", acceptance, "theta", theta)
    assert np.all(np.abs(acceptance - 0.234) < 0.02)
    assert np.all((theta > THETA_MIN) & (theta < THETA_MAX))


@pytest.mark.parametrize("clamp", [THETA_MIN, THETA_MAX], ids=["lower", "upper"])
def test_theta_at_its_clamps_keeps_the_chains_right(clamp):
    """At either clamp (1e-4: steps so small that mutations barely move; 1: nearly independent
    proposals) the ladder still samples every level's target and the normalisations hold.
    An unreachable target acceptance drives theta to the upper clamp by adaptation; at the
    lower clamp acceptance tends to 1, so adaptation alone cannot get there and theta is set."""
    if clamp == THETA_MAX:
        hist, b, _, theta = run_toy(3, passes=8, target_acceptance=0.01)
        assert np.all(theta == np.float32(clamp))
    else:
        hist, b, _, theta = run_toy(3, adapt=False, theta=clamp)
    exact = exact_bins("strip", 3)
    for level in range(3):
        chi2, dof = chi_square(hist[level], exact[level])
        assert chi2 < sps.chi2.ppf(0.999, dof)
    np.testing.assert_allclose(b, [e.sum() for e in exact], rtol=0.01)


def test_a_needle_of_visibility_is_found_and_measured():
    """0.01 x 0.005 of the square is visible (b = 5e-5): the few uniform hits seed the chains,
    which then stay inside, and b is estimated within its binomial error."""
    hist, b, _, _ = run_toy(1, kind="needle", passes=4, steps_per_chain=4000)
    exact = 0.01 * 0.005
    print("needle b", b[0], "exact", exact)
    assert abs(b[0] - exact) < 4 * np.sqrt(exact / (GROUPS * 16 * 4000 * 4))
    assert hist[0].sum() > 0 and hist[0][:, 4, 4].sum() == hist[0].sum()


def mutation_success(theta, kind, n=400_000, seed=1):
    """z(x) per bin: the probability that a mutation from a point of the bin stays in the support."""
    rng = np.random.default_rng(seed)
    x = rng.random((n, 2))
    inside = support_np(x[:, 0], x[:, 1], kind) > 0
    x = x[inside]
    r = rng.random(x.shape)
    delta = r ** (1.0 / theta + 1.0) * np.where(rng.random(x.shape) < 0.5, -1.0, 1.0)
    y = (x + delta) % 1.0
    ok = support_np(y[:, 0], y[:, 1], kind)
    bx, by = (np.minimum((x * BINS).astype(int), BINS - 1)).T
    z = np.zeros((BINS, BINS))
    cnt = np.zeros((BINS, BINS))
    np.add.at(z, (bx, by), ok)
    np.add.at(cnt, (bx, by), 1)
    return np.divide(z, cnt, out=np.zeros_like(z), where=cnt > 0)


def test_dropping_proposal_failures_samples_f_times_z():
    """algorithms.md §5.2: with failures dropped, the visibility chain records states
    proportionally to f (b + (1 - b) z) (b: visible fraction of the uniform proposals tried
    first, z: mutation success probability), not f. Keeping failures samples f."""
    theta = 0.05
    exact = exact_bins("strip", 1)[0]
    b = exact.sum()
    keep, _, _, _ = run_toy(1, adapt=False, theta=theta)
    drop, _, last, _ = run_toy(1, adapt=False, theta=theta, drop=True)
    z = mutation_success(theta, "strip")
    predicted = exact * (b + (1 - b) * z)
    chi_keep, dof = chi_square(keep[0], exact)
    chi_drop_f, _ = chi_square(drop[0], exact)
    chi_drop_fz, _ = chi_square(drop[0], predicted)
    print(f"keep vs f: {chi_keep:.0f}; drop vs f: {chi_drop_f:.0f}; drop vs f(b+(1-b)z): {chi_drop_fz:.0f} ({dof} bins)")
    limit = sps.chi2.ppf(0.999, dof)
    assert chi_keep < limit
    assert chi_drop_fz < limit
    assert chi_drop_f > 3 * limit        # p < 1e-20: f itself is firmly rejected
    # where it shows: cells where mutations often fail lose weight; the strip most. The size is
    # small here (about -4 %) because b = 0.275: a quarter of the steps are exact uniform draws.
    observed = drop[0].sum(axis=0) / drop[0].sum()
    ratio = np.divide(observed, exact / b, out=np.ones_like(exact), where=exact > 0)
    lo = np.unravel_index(np.argmin(np.where(exact > 0, ratio, np.inf)), ratio.shape)
    print(f"dropped failures: weakest cell {lo} at {ratio[lo]:.3f} of its share, strongest {ratio.max():.3f}")
    assert lo[0] >= 4 and lo[1] == 1, "the narrow strip, where z is lowest, loses most"
    assert last["counters"][0, 7] > 0

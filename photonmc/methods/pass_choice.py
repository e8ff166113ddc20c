"""mbe's choice, pass by pass, between a chain pass and a vcm pass (docs/mbe.md, "vcm passes
where the chains do not pay").

mbe's chains pay where few light subpaths contribute. Where most do, their correlated
records are worth no more than as many independent light subpaths, and a chain pass costs
more than vcm's light pass (the chains' bookkeeping). Both kinds of pass are estimates of the
image with the same merging radius for a given index (mbe indexes it by camera subpaths per
pixel), and each joins the film as one sample of every pixel, so the kind may change from
pass to pass without changing what the film converges to. mbe takes the kind with the smaller
predicted variance x work, both predicted from what its chain passes measure:

    chain pass:  (V_c / K + V_p / n) W_chain(K),     vcm pass:  (V_c + V_u / N_L) W_vcm,

V_c the camera side's variance per camera subpath and V_p the chains' light side per step
(the effort balance's, methods/effort.py), V_u the variance of one uniform proposal's splat
list (the pass's uniform proposals, even ladders against odd: the light side of independent
light subpaths, which is what vcm traces), K the camera subpaths per pixel of a chain pass
(at the K that minimises its product), n its chain steps, N_L the vcm pass's light subpaths:
those that minimise its product, within [--light-paths / 16, --light-paths] (the effort
balance of methods/effort.py, for vcm's passes; docs/mbe.md, "Light subpaths of the vcm
passes by the effort balance"), and the kinds are compared at that N_L (stop 38). The vcm
passes themselves trace as many as vcm's light-path balance finds best, measured on them
(methods/light_balance.py; docs/mbe.md, stop 39): this model's N* errs high where VCM's
weights move to the connections, and stays the point at which the kinds are compared.
Work is counted,
not timed, so that a seed gives one image: the effort balance's counts (rays, segments, merge
candidates) in a cost model fitted to measured times (CAMERA_WORK_WEIGHT, CHAIN_STEP_WORK).
While vcm passes win, chain passes still take CHAIN_WORK_SHARE of the work, so that the
measurements, and the chains' states, stay current.

The camera side of a vcm pass is not a chain pass's at K > 1 (there the camera-only
techniques count K times); near the break-even, chain passes of one camera subpath per pixel,
run in pairs, measure it (MEASURE_BAND below).

--vcm-passes measured (the default since stop 42; stop 40's experiment) compares the kinds by
measured variances instead: a vcm pass's from twin passes where pixel positions are stratified
(TwinVariance, since stop 49), from vcm's light-path balance (the mean of its pair estimates)
where they are independent; a chain pass's by batch means of consecutive chain passes
(BatchMeansVariance: the warm start correlates them); each set against the mean counted work
of the passes it was measured on (made_work), the vcm pass's work with its connections counted
once per pixel.
Where chain passes are predicted to win, vcm passes take EXPLORE_SHARE of the work until they
are measured, at any K (since stop 47); those passes only measure and stay out of the film. The
measured ratio decides alone only beyond MEASURED_Z standard errors from 1, and chain passes
then keep CHAIN_WORK_SHARE / ratio^2 of the work (chain_share); nearer, it is combined with the
prediction, each estimate of log(ratio) weighted by its inverse squared error (stop 43; until
then the prediction decided alone there).
History: the first version lost 1.28x to the prediction in the held-out closet (its vcm passes'
rare fireflies read low); the guard brought that to 1.10x, and pairing each variance with its
passes' work (the closet's was judged at 2.3x its chain passes' work) and keeping the
exploring passes out of the film to about 1.07x, while the light shaft and the loft gain
4-5 % (docs/mbe.md, stops 40-42). --vcm-passes auto keeps the prediction alone.

A vcm pass traces one camera subpath per pixel. vcm passes of several (each camera subpath a
whole VCM estimator with the pass's light subpaths) were measured and dropped: chosen by the
same prediction they took over the held-out closet, where independent light subpaths rarely
contribute and V_u, estimated from few contributing proposals, comes out low in most passes
(its distribution is heavy-tailed), and mbe's RMSE there went from 0.97x vcm's to 1.7x.
"""
from __future__ import annotations

import math

import numpy as np

from .effort import DEPOSIT_WORK
from .light_balance import MEASURED_AFTER, RunningMean

# Time per pass ~ CAMERA_WORK_WEIGHT x camera work + light work + CHAIN_STEP_WORK x chain steps,
# in the effort balance's units (camera work: a ray per camera subpath, three per stored
# vertex; light work: segments, shadow rays, DEPOSIT_WORK per merge candidate). Fitted to the
# measured time per iteration of mbe's chain passes against vcm's, interleaved, on eight rooms
# at 64x64 with K from 1 to 16 (bundled and held out): the fit is within 20 % of every measured
# ratio, where counting camera work at full weight missed the rooms with K > 1 by 1.3-1.6x
# (docs/mbe.md, "vcm passes where the chains do not pay"). A chain step's own cost (proposal,
# acceptance, the splat list kept and deposited) is CHAIN_STEP_WORK segments.
CAMERA_WORK_WEIGHT = 0.2
CHAIN_STEP_WORK = 3.0
# While vcm passes win, chain passes still take this share of the work (counted as above).
# (At least every 8th pass instead spent about half of the caustic's time on chain passes,
# each 7x a vcm pass's cost at K = 5.)
CHAIN_WORK_SHARE = 0.1
MIN_CHAIN_PASSES = 4     # chain passes measured before the first vcm pass
# A vcm pass traces between --light-paths / MAX_FEWER_LIGHT_PATHS and --light-paths light
# subpaths (the store holds --light-paths'; fewer stand in where a pass's error is its camera side).
MAX_FEWER_LIGHT_PATHS = 16
# ... once this many chain passes of one camera subpath per pixel (the balance's, or the
# measurement pairs' below) have measured V_u. At K > 1
# V_u does not describe a vcm pass's light subpaths (they merge with K camera subpaths per
# pixel under weights that count the camera-only techniques K times), and measured, it is
# lower: balanced by it, the Cornell box (chain passes at K = 14) took vcm passes of 256
# light subpaths, predicted 5x better than chain passes, and mbe went from 0.75x vcm's RMSE
# to 0.90x (docs/mbe.md).
MIN_PASSES_FOR_BALANCE = 16
# Measurement pairs: V_c measured at K > 1 is not a vcm pass's camera side (the camera-only
# techniques count K times: in the held-out cellar 0.0096 per camera subpath at K = 2 against
# 0.0087 at K = 1, 0.0086 in vcm), and near the break-even that error decides the kind (the
# cellar's predicted 0.85 was 1.18 measured). Where the predicted ratio lies within
# MEASURE_BAND of 1 (the size of that error) and the balance's K > 1, chain passes run at
# K = 1 in pairs, whose consecutive spread measures V_c at K = 1 (and V_u at K = 1, which
# starts the balance of the vcm passes' light subpaths), until MEASURE_PAIRS estimates are
# in, then a pair every MEASURE_EVERY chain passes; while vcm passes win there, every chain
# pass does (they are a tenth of the work). The vcm prediction then uses the pairs' V_c and
# V_u (docs/mbe.md, "Measurement pairs at one camera subpath"). A pass joins the film at the
# weight of any other, so a pass at K = 1 among passes at K costs up to K times their
# variance: pairs only where the balance's K is at most MEASURE_MAX_K, and only after
# MEASURE_AFTER chain passes, once K has settled (it moves by at most 2x a pass). Measured
# without those two limits, the Cornell box (K 14) made 8 passes at K = 1 while its K rose,
# and mbe went from 0.75x vcm's RMSE to 0.86x. (Since stop 56 a chain pass joins the film
# at the weight of its K, so a pair at K = 1 no longer costs that; the limits were kept.)
# Until vcm passes are measured (light_balance.MEASURED_AFTER variance estimates, from twice
# as many passes), where chain passes are predicted to win at K <= MEASURE_MAX_K, vcm passes
# take this share of the work: the prediction of a vcm pass's variance from chain passes
# erred 1.3-2x high where the kinds mix (docs/mbe.md, stop 40), and without vcm passes there is
# nothing to correct it with (the light shaft made its first 340 passes chain passes, at
# 2.2-2.4x a vcm pass's time for the same variance per pass).
EXPLORE_SHARE = 0.25
# --vcm-passes measured: the measured ratio overrules the prediction only where it lies more
# than MEASURED_Z standard errors (of its logarithm, from both kinds' measured variances) from
# 1; nearer, it is combined with the prediction (_ratio). Without this the held-out closet,
# near the break-even, took vcm passes on a vcm variance that read low until a firefly
# (docs/mbe.md, stop 40/41).
MEASURED_Z = 1.0
# The prediction's error, as a standard error of log(ratio): its vcm pass variance erred
# 1.3-2x where the kinds mix, and its cost model up to 1.3-1.6x (docs/mbe.md, stops 38 and 40).
PREDICTION_LOG_ERROR = math.log(2.0)
# A trusted measured ratio at least SETTLED_Z standard errors of its logarithm from 1 is
# settled: vcm passes then get a twin in TwinVariance.SETTLED_EVERY instead of one in EVERY
# (the twins only follow the variance as the radius shrinks, and where the kinds are that far
# apart that cannot turn the choice: in the bundled scenes, where the measured ratio reads
# 3.5-14, one twin in 32 took about 3.5 % of mbe's time, docs/mbe.md). Where the chain side is
# predicted (batch means need 64 chain passes, which those scenes never make), its error is
# PREDICTION_LOG_ERROR's.
SETTLED_Z = 2.0
MEASURE_BAND = 0.7
MEASURE_PAIRS = 8
MEASURE_EVERY = 32
MEASURE_MAX_K = 4
MEASURE_AFTER = 16


class BatchMeansVariance:
    """The variance of one chain pass, as it counts in the film: the chains carry their states
    from pass to pass (the warm start), so consecutive passes are correlated, and neither the
    spread of two of them nor the even against the odd ladders of one sees it. The means of
    batches of BATCH consecutive chain passes are nearly independent: BATCH x their variance
    (per pixel, over batches; mean over pixels) is the variance per pass with the correlation
    included (the batch-means estimator of MCMC output analysis). Measured where the effort
    balance's prediction V_c / K + V_p / n was low: the caustic (docs/mbe.md, stop 40).

    The film weighs each pass by its K camera subpaths per pixel (film.py), and so does a
    batch: its mean is sum K F / sum K, of variance sigma^2 / W_b for W_b = sum K, where sigma^2
    is the variance per unit weight. Weighted by W_b, sum W_b (M_b - M)^2 / (B - 1) estimates
    sigma^2 (M the W-weighted mean over B batches); with every K alike it is BATCH K x the
    variance of the batch means."""
    BATCH = 8
    AFTER = 8           # batches before the variance is reported

    def __init__(self, n_pixels: int):
        self.batches = 0
        self.weight = 0.0                   # the batches' weights summed
        self.mean = np.zeros(n_pixels)      # per pixel, over batches (weighted Welford: West 1979)
        self.m2 = np.zeros(n_pixels)

    def observe_batch(self, batch_sum, weight: float = BATCH) -> None:
        """The per-pixel luminance summed over BATCH consecutive chain passes, each times its
        weight, and the weights summed (BATCH where every pass weighs 1)."""
        batch_mean = batch_sum / weight
        self.batches += 1
        self.weight += weight
        delta = batch_mean - self.mean
        self.mean += delta * (weight / self.weight)
        self.m2 += weight * delta * (batch_mean - self.mean)

    def unit_variance(self) -> float | None:
        """sigma^2: the variance of a pass of weight 1 (mean over pixels)."""
        if self.batches < self.AFTER:
            return None
        return float((self.m2 / (self.batches - 1)).mean())

    def pass_variance(self) -> float | None:
        """The variance of a pass of the mean weight of those measured: sigma^2 / mean K."""
        unit = self.unit_variance()
        return None if unit is None else unit * self.BATCH * self.batches / self.weight

    def relative_error(self) -> float | None:
        """The standard error of pass_variance() over its value, sqrt(2 / (batches - 1)):
        that of a variance from that many (near-Gaussian, independent) batch means."""
        if self.batches < self.AFTER:
            return None
        return math.sqrt(2.0 / (self.batches - 1))


class TwinVariance:
    """The variance of a vcm pass as its film sees it under stratified pixel positions, read
    from twin passes (docs/mbe.md, "Twin vcm passes", stop 49).

    vcm's light-path balance reads a pass's variance from two consecutive passes, whose camera
    subpaths start at independent points of the pixels (kernels/pixel_samples.py): it
    includes the variance of where in its pixel a camera subpath starts (a lamp's edge, a
    slit, seen by the camera). A film whose passes take stratified positions removes that part
    at a rate well above 1 / passes, so it is not what a vcm pass adds to the film; the chain
    passes' batch means, over 8 passes of K points per pixel each, hold almost none of it.
    In the held-out strip lights it is 99.8 % of the pair estimate (2.53 against 0.0060 with
    the positions held), and compared by it the chain passes read 5-10x better than vcm
    passes per unit of work where, rendered, they are 3.7x worse.

    A twin repeats a vcm pass with the same pixel positions, merging radius and number of light
    subpaths, and other random numbers (so other light subpaths), out of the film: half its
    squared difference to the pass is the pass's variance with the positions held. Every exploring vcm pass (out
    of the film already) gets one, and so does every vcm pass until MEASURED_AFTER twins are in
    (where the prediction takes vcm passes at once, there is no exploration); after that a vcm
    pass of the film gets one in EVERY, so that the estimate follows the radius as it
    shrinks, or one in SETTLED_EVERY while the pass choice is settled (PassChoice.settled)."""
    EVERY = 32
    SETTLED_EVERY = 128     # where the pass choice is settled (PassChoice.settled, SETTLED_Z)

    def __init__(self):
        self.variance = RunningMean()
        self.film_passes = 0        # vcm passes of the film since the last twin

    def due(self, exploring: bool, settled: bool = False) -> bool:
        """Whether the vcm pass just made gets a twin."""
        if exploring or self.variance.count < MEASURED_AFTER:
            return True
        self.film_passes += 1
        if self.film_passes >= (self.SETTLED_EVERY if settled else self.EVERY):
            self.film_passes = 0
            return True
        return False

    def observe(self, spread: float, n_pixels: int) -> None:
        """The twin's summed squared difference to its pass (luminance, over the pixels)."""
        if math.isfinite(spread):
            self.variance.add(0.5 * spread / n_pixels)

    def pass_variance(self) -> float | None:
        return self.variance.mean_after(MEASURED_AFTER)

    def relative_error(self) -> float | None:
        return self.variance.relative_error_after(MEASURED_AFTER)


class PassChoice:
    def __init__(self, n_light: int, enabled: bool, n_pixels: int | None = None, measured: bool = False):
        self.n_light, self.enabled = int(n_light), bool(enabled)
        # --vcm-passes measured: the kinds compared by their measured variances (vcm passes
        # measured first where needed, EXPLORE_SHARE), vcm work with the connections per pixel
        self.measured = bool(measured)
        self.n_pixels = int(n_light if n_pixels is None else n_pixels)
        self.uniform_r2_sum = 0.0       # V_u x r^2 summed over chain passes (V_u grows as 1/r^2)
        self.uniform_passes = 0
        self.uniform_r2_sum_k1 = 0.0    # the same, over chain passes of K = 1 only
        self.uniform_passes_k1 = 0
        self.traced = 0.0               # light subpaths traced by chain passes
        self.steps = 0.0                # chain steps
        self.k_sum = 0.0                # camera subpaths per pixel, and K x steps, summed over chain
        self.k_steps_sum = 0.0          # passes (the mean work of the passes a measured variance is of)
        self.light_work = 0.0           # their segments and shadow rays
        self.connections = 0.0          # of those shadow rays, the connections' (to a camera subpath)
        self.merges_per_k = 0.0         # merge candidates / K (they grow with the camera vertices)
        self.chain_passes = 0
        self.vcm_passes = 0
        self.vcm_work_since_chain = 0.0  # work of the vcm passes since the last chain pass
        self.ratio = None               # last predicted (chain variance x work) / (vcm's)
        self.ratio_at_k = None          # the same with the vcm pass's V_c and V_u taken at the chain passes' K
        self.vcm_measured = False       # the last ratio used the vcm passes' measured variance
        self.chain_measured = False     # ... and the chain passes' (batch means)
        self.explore_vcm_work = 0.0     # work of the vcm passes made to measure them, and of the
        self.explore_chain_work = 0.0   # chain passes made meanwhile (EXPLORE_SHARE)
        self.explored_passes = 0
        self.exploring_now = False      # the vcm pass just chosen only measures (not in the film)
        # N*: the light subpaths a vcm pass is judged at (the passes trace the light-path balance's)
        self.vcm_light_paths = self.n_light
        self.vcm_light_paths_sum = 0.0  # over the vcm passes made
        self.camera_k1_sum = 0.0        # V_c estimates from consecutive chain passes of K = 1
        self.camera_k1_count = 0
        self.measuring_left = 0         # chain passes of the current measurement pair still to run at K = 1
        self.last_pair_at = -MEASURE_EVERY
        self.measured_passes = 0
        self.measured_ratio = None      # --vcm-passes measured: the last measured ratio,
        self.measured_trusted = 0       # and how often it decided alone (MEASURED_Z) or with the prediction
        self.measured_untrusted = 0
        self.combined_ratio = None      # the last untrusted measured ratio combined with the prediction
        self.settled = False            # the last ratio trusted and SETTLED_Z standard errors from 1
        self.made_from = (0, 0.0, 0.0, 0.0)  # chain passes, K, steps, K x steps when their variance began

    def chain_pass_k(self, k: int) -> int:
        """The K of the next chain pass: the balance's K, or 1 in a measurement pair."""
        # "Near" by the prediction the pairs correct (V_c at K), so that one high estimate at
        # K = 1 (its spread is heavy-tailed) does not end the measuring that would average it out.
        near = (1 < k <= MEASURE_MAX_K and self.chain_passes >= MEASURE_AFTER and self.enabled
                and self.ratio_at_k is not None and MEASURE_BAND < self.ratio_at_k < 1.0 / MEASURE_BAND)
        if self.measuring_left > 0:
            self.measuring_left -= 1
        elif near and self.ratio is not None and self.ratio > 1.0:
            pass        # vcm passes win: the chain passes, a tenth of the work, measure
        elif near and (self.camera_k1_count < MEASURE_PAIRS or self.chain_passes - self.last_pair_at >= MEASURE_EVERY):
            self.measuring_left, self.last_pair_at = 1, self.chain_passes
        else:
            return k
        self.measured_passes += 1
        return 1

    def observe_camera_at_one(self, v_c: float) -> None:
        """V_c from two consecutive chain passes of one camera subpath per pixel."""
        self.camera_k1_sum += v_c
        self.camera_k1_count += 1

    def observe_chain_pass(self, steps: int, k: int, traced: float, light_work: float, merges: float,
                           uniform_variance: float | None, radius_sq: float, connections: float = 0.0) -> None:
        """A chain pass: its steps, K, light subpaths traced, their segments and shadow rays,
        merge candidates, the variance of one uniform proposal's splat list (mean over
        pixels, luminance), None where the pass had too few uniform proposals to tell, and
        the connections' shadow rays among light_work."""
        self.chain_passes += 1
        self.vcm_work_since_chain = 0.0
        self.steps += steps
        self.k_sum += k
        self.k_steps_sum += k * steps
        self.traced += traced
        self.light_work += light_work
        self.connections += connections
        self.merges_per_k += merges / k
        if uniform_variance is not None:
            self.uniform_r2_sum += uniform_variance * radius_sq
            self.uniform_passes += 1
            if k == 1:
                self.uniform_r2_sum_k1 += uniform_variance * radius_sq
                self.uniform_passes_k1 += 1

    def next_is_vcm(self, effort, k: int, most_k: int, steps: int, radius_sq: float, n_light: int,
                    vcm_variance: float | None = None, chain_variance: float | None = None,
                    relative_errors: tuple = (None, None)) -> bool:
        """Whether the next pass should be a vcm pass, against a chain pass of `steps` steps
        and K camera subpaths per pixel (at most `most_k`); a vcm pass would trace n_light
        light subpaths (vcm's light-path balance), and vcm_variance is the variance of a vcm
        pass measured on those made (None until enough are: the prediction, below);
        relative_errors: the standard errors of the vcm and chain variances over their values."""
        self.ratio = self._ratio(effort, most_k, steps, radius_sq, n_light, vcm_variance, chain_variance, k,
                                 relative_errors)
        self.exploring_now = False
        if self._exploring(k, vcm_variance):
            if self.explore_vcm_work >= EXPLORE_SHARE * (self.explore_vcm_work + self.explore_chain_work):
                self.explore_chain_work += self.work(effort, k, steps)[0]
                return False
            self.explore_vcm_work += self.work(effort, k, steps, n_light, connections_per_pixel=True)[1]
            self.explored_passes += 1
            self.exploring_now = True
            self.vcm_passes += 1
            self.vcm_light_paths_sum += n_light
            return True
        if not (self.enabled and self.ratio is not None and self.ratio > 1.0):
            return False
        # Measured (--vcm-passes measured), the share is kept in the cost model that counts a
        # vcm pass's connections per pixel (work_parts), the one that follows measured time.
        chain_work = self.work(effort, k, steps)[0]
        share = self.chain_share()
        if self.vcm_work_since_chain * share >= chain_work * (1.0 - share):
            return False
        self.vcm_passes += 1
        self.vcm_light_paths_sum += n_light
        self.vcm_work_since_chain += self.work(effort, k, steps, n_light, connections_per_pixel=self.measured)[1]
        return True

    def count_twin(self, effort, k: int, steps: int, n_light: int) -> None:
        """A twin of the vcm pass just chosen (TwinVariance): its work counts as that pass's
        does, toward the exploration's share or against the chain passes' share (once chain
        passes have measured the cost model's counts)."""
        if self.traced <= 0 or effort.sum_camera_paths <= 0:
            return
        work = self.work(effort, k, steps, n_light, connections_per_pixel=True)[1]
        if self.exploring_now:
            self.explore_vcm_work += work
        else:
            self.vcm_work_since_chain += work

    def chain_share(self) -> float:
        """The share of the work chain passes keep while vcm passes win: CHAIN_WORK_SHARE, and
        under --vcm-passes measured, once the measured ratio decides, CHAIN_WORK_SHARE / ratio^2.
        Chain passes that are r times worse per unit of work cost the film about share x (r - 1)
        of its efficiency, and a ratio measured far from 1 needs fewer of them to stay current:
        at a tenth, the light shaft's hundred chain passes among 1,300 vcm passes left mbe 1.2x
        vcm's RMSE, where vcm passes alone tie it (docs/mbe.md, stop 41)."""
        if self.measured and self.vcm_measured and self.ratio is not None and self.ratio > 1.0:
            return CHAIN_WORK_SHARE / self.ratio ** 2
        return CHAIN_WORK_SHARE

    def _exploring(self, k: int, vcm_variance: float | None) -> bool:
        """Whether vcm passes are still to be measured: until vcm's light-path balance has
        measured their variance, where the prediction is not already for them, at any K.
        Until stop 47 only at K <= MEASURE_MAX_K: an exploring pass then joined the one film at
        a chain pass's weight. Since stop 45 they stay out of the films, and with stratified
        pixel positions the prediction credits a chain pass's K camera subpaths with sharing
        its light subpaths where its light side is what limits it (the strip lights at K = 16:
        noise 2.0x vcm's). Measured at 15 s, seeds 0-3, mbe over vcm (docs/mbe.md, stop 47):
        light bay 1.15x -> 1.04x, strip lights 1.13 -> 1.11 (two seeds turn to vcm passes and
        tie), Cornell box 1.02x -> 1.01x, mitsuba-style 0.97x -> 1.00x, closet 0.82x -> 0.88x
        (within its seeds' spread), slit cabinet 1.09x both. (With independent positions the
        Cornell box lost: 0.81x -> 1.12x, stop 46.)"""
        return (self.enabled and self.measured and vcm_variance is None and self.chain_passes >= MIN_CHAIN_PASSES
                and self.ratio is not None and self.ratio <= 1.0)

    def _ratio(self, effort, most_k: int, steps: int, radius_sq: float, n_light: int | None = None,
               vcm_variance: float | None = None, chain_variance: float | None = None,
               k: int = 1, relative_errors: tuple = (None, None)) -> float | None:
        untrusted = None        # an untrusted measured ratio and its log error, to combine with the prediction
        self.settled = False
        shares = effort.shares()
        if (self.chain_passes < MIN_CHAIN_PASSES or shares is None or self.uniform_passes == 0
                or self.traced <= 0 or effort.sum_camera_paths <= 0 or not radius_sq > 0):
            return None
        v_c, v_p = max(shares[0], 0.0), max(shares[1], 0.0)
        v_u = self.uniform_r2_sum / self.uniform_passes / radius_sq
        # The chain pass at its best K: the balance moves K by at most a factor 2 per chain
        # pass, and chain passes are rare while vcm passes win, so judged at the current K the
        # chains could never earn back the K that makes them pay (the attic at 32x32: 4.9x at
        # K = 1 in its first passes, 1.1x at K = 8).
        chain = min((v_c / kk + v_p / steps) * self.work(effort, kk, steps)[0] for kk in range(1, most_k + 1))
        # A vcm pass traces one camera subpath per pixel: its V_c and V_u are K = 1's where
        # measured. It is judged at the model's N* (stop 38), though since stop 39 it traces
        # what vcm's light-path balance measures best (methods/light_balance.py). Both halves
        # of the prediction err as N falls, in opposite directions: the cost model counts
        # connections as light work, so a pass of fewer light subpaths looks cheaper than it
        # is (the cellar at 1,024 of 4,096: 0.37x the time predicted, 0.79x measured), and
        # V_u / N has its light side grow as 1 / N where VCM's weights move to the
        # connections, whose variance does not grow (measured: 1.4x for 4x fewer against 4x).
        # Together they err by about 30 % either way on three rooms measured (docs/mbe.md,
        # stop 38). Judged at N*, mbe beat the old vcm by 7-25 % where the measurement pairs
        # find the break-even at K = 2 to 4; against vcm with its own balance it does not
        # (docs/mbe.md, stop 39): comparing with the vcm passes' measured variance x work is
        # the lead.
        if self.measured and vcm_variance is not None and n_light is not None:
            # Measured (stop 40): the variance of the vcm passes made, from vcm's light-path
            # balance's pairs, at the light subpaths it traces, and their work with the
            # connections counted per pixel. Predicted from the chain passes, a vcm pass's
            # variance came out 1.3-2x high where the kinds mix (the light shaft: V_c at K = 1
            # alone 0.011-0.018, a vcm pass 0.009 measured), which the cost model's error the
            # other way hid (docs/mbe.md, "Each kind of pass measured").
            # The chain pass measured too where it can be (BatchMeansVariance).
            # Each measured variance is paired with the mean work of the passes it was measured
            # on (made_work): while vcm passes win, the effort balance's K and the steps drift
            # from those of the chain passes made (the held-out closet: measured at K 4-5 and
            # about 5,000 steps, judged at K 8-10 and 11,000 steps, so at 2.3x their work; its
            # measured ratio 2.0 chose vcm passes where chain passes win, docs/mbe.md, stop 42).
            chain_measured = chain_variance is not None
            chain_work, vcm_work = self.made_work(effort)
            measured_chain = chain_variance * chain_work if chain_measured else chain
            vcm = vcm_variance * (vcm_work if vcm_work is not None
                                  else self.work(effort, 1, steps, n_light, connections_per_pixel=True)[1])
            measured = measured_chain / vcm if vcm > 0.0 and math.isfinite(measured_chain) else None
            # Trusted only where it differs from 1 by more than MEASURED_Z standard errors: a
            # heavy-tailed vcm variance (the closet's fireflies) reads low in most renders, and
            # 8 batch means leave the chain side's variance uncertain by half.
            vcm_error, chain_error = relative_errors
            log_error = math.hypot(vcm_error or 0.0, (chain_error or 0.0) if chain_measured else 0.0)
            self.measured_ratio = measured
            if measured is not None and abs(math.log(max(measured, 1e-300))) > MEASURED_Z * log_error:
                self.vcm_measured, self.chain_measured = True, chain_measured
                self.measured_trusted += 1
                chain_log_error = (chain_error or 0.0) if chain_measured else PREDICTION_LOG_ERROR
                settle_error = SETTLED_Z * math.hypot(vcm_error or 0.0, chain_log_error)
                self.settled = abs(math.log(max(measured, 1e-300))) > settle_error
                return measured
            self.measured_untrusted += 1
            if measured is not None:
                untrusted = (measured, log_error)
        self.vcm_measured = self.chain_measured = False
        v_c1 = self.camera_k1_sum / self.camera_k1_count if self.camera_k1_count >= MEASURE_PAIRS else v_c
        v_u1 = self.uniform_r2_sum_k1 / self.uniform_passes_k1 / radius_sq if self.uniform_passes_k1 >= MEASURE_PAIRS else v_u
        vcm_at_k = (v_c + v_u / self.n_light) * self.work(effort, 1, steps)[1]
        self.ratio_at_k = chain / vcm_at_k if vcm_at_k > 0.0 and math.isfinite(chain) else None
        self.vcm_light_paths = self.n_light
        if self.uniform_passes_k1 >= MIN_PASSES_FOR_BALANCE:
            self.vcm_light_paths = self._balanced_light_paths(effort, steps, max(v_c1, 0.0), v_u1)
        n = self.vcm_light_paths
        vcm = (max(v_c1, 0.0) + v_u1 / n) * self.work(effort, 1, steps, n)[1]
        if not vcm > 0.0 or not math.isfinite(chain):
            return None
        predicted = chain / vcm
        if untrusted is not None and predicted > 0.0:
            # A measured ratio within MEASURED_Z standard errors of 1 still says which way the
            # kinds lean, and the prediction errs too: the two estimates of log(ratio) are
            # combined by their inverse squared errors (PREDICTION_LOG_ERROR for the
            # prediction's). Left to the prediction alone, the held-out light bay's untrusted
            # decisions (a measured 1.1-1.3 against a predicted 0.5-0.6) made chain passes,
            # about a third of a 60 s render where vcm passes win (docs/mbe.md, stop 43).
            measured, log_error = untrusted
            w_measured = 1.0 / max(log_error, 1e-3) ** 2
            w_predicted = 1.0 / PREDICTION_LOG_ERROR ** 2
            self.combined_ratio = math.exp((w_measured * math.log(max(measured, 1e-300))
                                            + w_predicted * math.log(predicted)) / (w_measured + w_predicted))
            return self.combined_ratio
        return predicted

    def _balanced_light_paths(self, effort, steps: int, v_c: float, v_u: float) -> int:
        """The light subpaths N of a vcm pass that minimise (V_c + V_u / N) (C + N c): the
        effort balance of methods/effort.py for vcm's passes, N* = sqrt(C V_u / (c V_c)), C
        the pass's camera work and c a light subpath's, in the fitted cost model. Where a
        pass's error is its camera side, fewer light subpaths cost less for the same variance
        (the held-out cellar: vcm with a quarter of them has the same variance per pass at
        0.77x the time, docs/mbe.md). The cost model overstates what fewer light subpaths
        save and V_u / N how fast their variance grows (_ratio; docs/mbe.md, stop 38)."""
        w = self.work_parts(effort, 1, steps, 1)
        camera, light = CAMERA_WORK_WEIGHT * w["vcm_camera"], w["vcm_light"]
        fewest = max(1, self.n_light // MAX_FEWER_LIGHT_PATHS)
        if not (v_c > 0.0 and light > 0.0):
            return self.n_light
        best = math.sqrt(camera * v_u / (light * v_c))
        return int(min(max(round(best), fewest), self.n_light))

    def restart_made_work(self) -> None:
        """The chain passes' variance is measured afresh (their length changed: ChainBias): from
        now on made_work means the chain passes made from here."""
        self.made_from = (self.chain_passes, self.k_sum, self.steps, self.k_steps_sum)

    def made_work(self, effort) -> tuple[float, float | None]:
        """The mean counted work of the chain passes made (since restart_made_work), and of the
        vcm passes made (None before any), under --vcm-passes measured's cost model
        (connections per pixel): the passes whose variances were measured. Work is linear in K,
        steps, K x steps and the light subpaths, so the work at their means is the mean work."""
        passes, k_sum, steps, k_steps = (a - b for a, b in zip(
            (self.chain_passes, self.k_sum, self.steps, self.k_steps_sum), self.made_from))
        n = max(passes, 1)
        chain = self.work(effort, k_sum / n, steps / n, k_steps=k_steps / n)[0]
        if self.vcm_passes == 0:
            return chain, None
        return chain, self.work(effort, 1, 1, self.vcm_light_paths_sum / self.vcm_passes,
                                connections_per_pixel=True)[1]

    def work_parts(self, effort, k: float, steps: float, n_light: float | None = None,
                   connections_per_pixel: bool = False, k_steps: float | None = None) -> dict:
        """The counted work of a chain pass with K camera subpaths per pixel and of a vcm pass,
        camera and light side apart, in the effort balance's units, from the chain passes'
        counts so far (tools/mbe_pass_costs.py sets them against measured time); the vcm pass
        with n_light light subpaths (--light-paths by default). k_steps: K x steps, or its
        mean where K and steps are means over passes."""
        n_light = self.n_light if n_light is None else n_light
        k_steps = k * steps if k_steps is None else k_steps
        camera = effort.sum_camera_work / effort.sum_camera_paths          # per camera subpath per pixel
        per_subpath = self.light_work / self.traced
        connecting = self.connections / self.traced                        # its connections' rays
        merges = DEPOSIT_WORK * self.merges_per_k / self.traced            # per light subpath, per unit K
        # In a vcm pass each pixel's camera subpath connects to one light subpath (the pixel's
        # index modulo N), so the connections are as many as a chain pass's light subpath
        # makes, once per pixel, whatever N (connections_per_pixel): counted per light subpath
        # they make a vcm pass of fewer light subpaths look cheaper than it is (docs/mbe.md,
        # "Each kind of pass measured": in the light shaft a chain pass takes 2.4x a vcm pass's
        # time and is counted 4.1x; counted per pixel the ratio comes within 10-17 % of measured
        # time in three rooms). The prediction keeps the count per light subpath: its variance
        # model errs the other way, and fixed alone the cost made mbe worse (stop 38).
        vcm_light = n_light * (per_subpath - connecting + merges) + self.n_pixels * connecting \
            if connections_per_pixel else n_light * (per_subpath + merges)
        return {"chain_camera": k * camera,
                "chain_light": self.traced / self.steps * (per_subpath * steps + merges * k_steps),
                "vcm_camera": camera, "vcm_light": vcm_light}

    def work(self, effort, k: float, steps: float, n_light: float | None = None,
             connections_per_pixel: bool = False, k_steps: float | None = None) -> tuple[float, float]:
        """(a chain pass's work with K camera subpaths per pixel, a vcm pass's with n_light
        light subpaths) in the fitted cost model."""
        w = self.work_parts(effort, k, steps, n_light, connections_per_pixel, k_steps)
        return (CAMERA_WORK_WEIGHT * w["chain_camera"] + w["chain_light"] + CHAIN_STEP_WORK * steps,
                CAMERA_WORK_WEIGHT * w["vcm_camera"] + w["vcm_light"])

    def stats(self) -> dict:
        return {"chain_passes": self.chain_passes, "vcm_passes": self.vcm_passes,
                "predicted_chain_over_vcm": self.ratio, "vcm_variance_measured": self.vcm_measured,
                "vcm_passes_to_measure": self.explored_passes, "chain_variance_measured": self.chain_measured,
                "measured_k1_passes": self.measured_passes,
                "measured_chain_over_vcm": self.measured_ratio,
                "measured_ratio_trusted": self.measured_trusted, "measured_ratio_untrusted": self.measured_untrusted,
                "settled": self.settled,
                "untrusted_combined_with_prediction": self.combined_ratio,
                "camera_variance_k1": self.camera_k1_sum / self.camera_k1_count if self.camera_k1_count else None,
                "vcm_pass_light_paths_mean": (self.vcm_light_paths_sum / self.vcm_passes if self.vcm_passes else None)}

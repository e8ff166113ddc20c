"""Photons per pass from the error they remove and the work they cost (photon mapping's
effort balance; docs/effort.md).

An SPPM-family iteration is a camera pass (one path per pixel, its measurement points and
their grid) and a photon pass of n photon paths. Per iteration a pixel's estimate has
variance  V(n) = V_c + V_p / n:  V_c from the camera side (direct light, the jittered
measurement point, the path to it), which more photons do not reduce, and V_p / n from the
photons. Work per iteration is  C_c + n c_p.  At a fixed budget the error after the budget is
proportional to (C_c + n c_p)(V_c + V_p / n), least at

    n* = sqrt( (C_c / c_p) (V_p / V_c) ).

V_p comes from splitting each pass's photons into two halves (even and odd photon paths,
or chains for the guided methods) whose estimates share the measurement point: their
difference has variance 4 V_p / n and no camera part. Two consecutive iterations are
independent, so their estimates differ with variance 2 V_c + V_p (1/n_i + 1/n_j), which
gives V_c (consecutive ones, because the expectation drifts as the radii shrink). Both are
averaged over the last WINDOW iterations: V_p grows as the radii shrink. Both are means over
pixels of luminance, so the balance minimises the image's MSE. Work is counted, not
timed, so that a seed still gives one image: C_c in rays cast by the camera pass plus one
per measurement point put in the grid, c_p in photon segments per path (each a ray cast
and a gather).

A pass may also trace K camera paths per pixel (sppm.py), which divides V_c by K at K times
the camera work; only the ratio n / K matters, so where the photon count is set otherwise
(the guided methods' passes last until their chains regenerate) the balance picks
K = n / n*, n* being the photons it would choose for one camera path. Each photon deposited
into a measurement point is work too (a BSDF evaluation and atomics, about DEPOSIT_WORK
segments), and at a fixed photon count it grows with K, so for that choice it counts as camera
work. The K points of a pixel gather the same photons but not into the same discs: where the
radius has shrunk below the pixel's footprint their photon noises are nearly independent and K
divides the photon side too. The balance measures how much of it they share (rho, from each
point's own even-odd difference beside the pixel's) and counts the rest as camera variance
for the choice of K (docs/effort.md, "Photon noise shared by a pixel's points").
"""
from __future__ import annotations

import math

import numpy as np

from ..errors import SettingsError

MAX_CHANGE = 2.0         # photons per pass change by at most this factor per iteration
MAX_PER_PIXEL = 64       # at most this many photons per pixel per pass (iteration granularity)
HISTORY = 256            # iterations the estimates look back over (bounded work per iteration)
TRIM = 32                # V_c leaves out the largest 1/TRIM of its history
# A scrambled net's mean over a pixel whose value jumps along curves (edges) has variance
# O(M^-1.5) after M points (Owen's scrambled nets; docs/effort.md, "Twin camera paths").
POSITION_EXPONENT = 1.5
# Cost of one deposit into a measurement point, in photon segments: 1.3 and 1.8 measured
# (visibility at 64x64 with 1, 4 and 16 camera paths per pixel on light-gap and the held-out
# closet: photon-pass time against segments and deposits; docs/effort.md).
DEPOSIT_WORK = 1.5
CANDIDATES = 512         # log-spaced candidates the bias-aware choice is searched over
# chain_pass_length shortens a chain pass (the guided methods', mbe's) only where it expects at
# most this share of the longest pass's error (docs/guiding.md, "Guided passes as long as the
# camera side allows").
PASS_LENGTH_MARGIN = 0.8


class EffortBalance:
    def __init__(self, n_pixels: int, initial: int, alpha: float, trim_camera: bool = True,
                 held_camera: bool = False):
        """trim_camera: V_c is the mean of the last HISTORY estimates without their largest
        1/TRIM (the photon methods' choice, see shares); False: the plain mean of every
        estimate since the start (mbe's, docs/mbe.md, "The radius follows the camera
        subpaths"). held_camera: V_c comes only from the passes that hand observe() a
        camera_held estimate (twin camera paths, docs/effort.md), not from consecutive passes."""
        self.n_pixels = n_pixels
        self.trim_camera = bool(trim_camera)
        self.held_camera = bool(held_camera)
        self.pair_sum = 0.0                  # held_camera: the pairs' V_c estimates, summed
        self.pair_samples = 0
        self.pair_variances = []             # held_camera: the pairs' last HISTORY estimates
        self.pair_scales = []                # and each one's photon-side scale (_pair_scale)
        # held_camera: read V_c from the pairs after all, as a pairs balance does (the guided
        # methods' --camera-variance auto sets it pass by pass: methods/guided.py).
        self.use_pairs = False
        self.camera_sum = 0.0                # every V_c estimate so far (trim_camera False)
        self.photons = int(initial)
        self.alpha = float(alpha)
        self.camera_variances = []           # per-iteration V_c estimates
        self.camera_scales = []              # and each one's photon-side scale (_pair_scale)
        self.photon_variances_r2 = []        # per-iteration V_p x mean R^2 (V_p grows as 1/R^2)
        self.photon_variances_mp_r2 = []     # the same for each measurement point alone
        self.correlation_terms = []          # passes of K >= 2: (K V_p - V_p,MP, (K - 1) V_p,MP)
        self.radius_sq = None                # mean R^2 of the last pass
        self.sum_camera_work = 0.0
        self.sum_camera_paths = 0.0          # camera paths per pixel, over all iterations
        self.sum_camera_photons = 0.0        # camera paths per pixel x photons, over all iterations
        self.sum_deposits = 0.0
        self.sum_photon_work = 0.0           # photon segments
        self.sum_photons = 0.0
        self.samples = 0                     # iterations with a previous one to compare with
        self.observed = 0                    # all iterations
        self.last_photons = None
        self.last_camera_paths = None
        self.bias_ratio = 0.0                # the image's squared radius bias / its photon variance
        self.last_shared = 0.0               # the last pass's shared photon variance (observe)
        self.pass_length_gain = None         # chain_pass_length's last expected error ratio
        self.shared_variances = []           # V_s: shared photon variance x photons, per pass

    def observe_bias(self, bias_sq: float, variance: float, spread: float, z: float) -> None:
        """The image's squared radius bias and its photon variance as the current radii would
        make them (summed over pixels, each pixel's passes rescaled to its radius now by
        rho_b^2 and rho_v: methods/sppm.py, the balanced radius rule's probes), and the
        variance of the bias_sq estimate; the bias counts only by what exceeds z standard
        errors of it, so that noise read as bias does not move the effort. The balance weighs
        the split the render would have had throughout, whose passes' radii shrink as
        t^((alpha-1)/2): over them the image's bias is 1/alpha and its photon variance
        1/(2-alpha) times that of a pass at the last radius. Taken from the current radii, not
        the image's history, the bias does not count the early wide passes, which no split
        can now undo (they made a simulated render choose too many photons: docs/effort.md)."""
        excess = bias_sq - z * math.sqrt(max(spread, 0.0))
        if excess > 0.0 and variance > 0.0:
            self.bias_ratio = (excess / self.alpha ** 2) / (variance / (2.0 - self.alpha))
        else:
            self.bias_ratio = 0.0

    def observe(self, photons: int, spread: float, half_difference: float, radius_sq: float,
                camera_work: float, photon_work: float, camera_paths: int = 1, deposits: float = 0.0,
                keep: bool = True, camera_held: float | None = None,
                half_difference_mp: float | None = None, shared_variance: float = 0.0) -> float | None:
        """One iteration of `photons` photon paths and `camera_paths` camera paths per pixel:
        `spread` = mean over pixels of (this iteration's estimate - the last one's)^2,
        `half_difference` = mean of n (t_a - t_b)^2 / 4, `radius_sq` = mean squared gather
        radius of the pass, `deposits` the photons deposited into its measurement points.
        Returns this pair's V_c estimate (None for the first iteration); keep=False leaves it
        and the V_p estimate out of the balance's estimates (mbe's measurement passes).
        camera_held: this pass's V_c per camera path with the pixel positions held (twins),
        which a held_camera balance takes instead of the pair's. half_difference_mp: the mean
        over measurement points of each one's own half_difference (photon_correlation).
        shared_variance: the variance of this pass's photon estimate that its halves share (the
        guided methods' normalisation, from its count of visible uniform proposals), left out
        of V_c and kept per photon (V_s) for the choice of the guided pass length."""
        self.observed += 1
        self.sum_deposits += deposits
        self.sum_camera_work += camera_work
        self.sum_camera_paths += camera_paths
        self.sum_camera_photons += camera_paths * photons
        self.sum_photon_work += photon_work
        self.sum_photons += photons
        last, self.last_photons = self.last_photons, photons
        last_k, self.last_camera_paths = self.last_camera_paths, camera_paths
        last_shared, self.last_shared = self.last_shared, shared_variance
        if keep and shared_variance > 0.0:
            self.shared_variances.append(shared_variance * photons)
            del self.shared_variances[:-HISTORY]
        if last is None or not radius_sq > 0:
            return None
        # Two iterations' estimates are independent:
        # E[(e_i - e_j)^2] = V_c (1/K_i + 1/K_j) + V_p (1/n_i + 1/n_j).
        v_p = half_difference
        v_c = (spread - v_p * (1.0 / photons + 1.0 / last) - shared_variance - last_shared) \
            / (1.0 / camera_paths + 1.0 / last_k)
        scale = self._pair_scale(photons, last, radius_sq)
        if self.held_camera:
            if keep:
                self.pair_sum += v_c
                self.pair_samples += 1
                self.pair_variances.append(v_c)
                self.pair_scales.append(scale)
                del self.pair_variances[:-HISTORY], self.pair_scales[:-HISTORY]
            v_c = camera_held
        if keep:
            self.photon_variances_r2.append(v_p * radius_sq)
            if half_difference_mp is not None and half_difference_mp > 0.0:
                self.photon_variances_mp_r2.append(half_difference_mp * radius_sq)
                if camera_paths >= 2:
                    self.correlation_terms.append((camera_paths * v_p - half_difference_mp,
                                                   (camera_paths - 1) * half_difference_mp))
                    del self.correlation_terms[:-HISTORY]
                del self.photon_variances_mp_r2[:-HISTORY]
            if v_c is not None:
                self.camera_variances.append(v_c)
                self.camera_scales.append(scale)
                self.camera_sum += v_c
                self.samples += 1
        del self.camera_variances[:-HISTORY], self.camera_scales[:-HISTORY], self.photon_variances_r2[:-HISTORY]
        self.radius_sq = radius_sq
        return v_c

    def shares(self) -> tuple[float, float] | None:
        """(V_c, V_p at the current radii), or None before there is an estimate."""
        if self.samples == 0:
            return None
        # V_c: the history's mean without its largest 1/32, each pair weighted by its photon
        # noise (_weighted_pairs).
        # V_p: a plain mean, since where photons are scarce most passes see none and the
        # signal is in the rare passes that do (a median or trimmed mean would be 0 there).
        # Without the trim (mbe), the plain mean since the start: such events are the error
        # there (on the caustic at 400 iterations ten pixels hold 91-97 % of the squared
        # error, two of the four largest lit by rare camera paths through the glass), and a
        # mean over the whole render keeps an event once it is seen instead of forgetting it
        # after HISTORY iterations.
        pairs = bool(self.held_camera and self.use_pairs and self.pair_variances)
        v_p_r2 = math.fsum(self.photon_variances_r2) / len(self.photon_variances_r2)
        if pairs or self.trim_camera:
            if pairs:
                v_c = self._weighted_pairs(self.pair_variances, self.pair_scales, v_p_r2)
            else:
                v_c = self._weighted_pairs(self.camera_variances, self.camera_scales, v_p_r2)
        else:
            v_c = self.camera_sum / self.samples
        if self.held_camera and self.pair_samples and not pairs:
            v_c += self._position_share(v_c)
        return v_c, v_p_r2 / self.radius_sq

    def _shared_variance(self) -> float | None:
        """V_s x photons: the shared photon variance's mean over the history, None before any."""
        return math.fsum(self.shared_variances) / len(self.shared_variances) if self.shared_variances else None

    @staticmethod
    def _pair_scale(photons: int, last: int, radius_sq: float):
        """What sizes a pair's photon noise: (1/n_i + 1/n_j) / 2, and the pass's mean R^2 (V_p
        goes as 1 / R^2). K is left out (_weighted_pairs)."""
        return (0.5 * (1.0 / photons + 1.0 / last), radius_sq)

    def _weighted_pairs(self, estimates, scales, v_p_r2: float) -> float:
        """V_c from the pairs' estimates, without the largest 1/TRIM (one camera path that finds
        the lamp through glass makes one iteration's spread ~100x the others', bundled caustic),
        each weighted by 1 / (V_c + P_i)^2, P_i = (V_p / R_i^2 + V_s) (1/n_i + 1/n_j) / 2 the
        photon noise the pair's estimate had to remove. A pair's estimate is its squared
        difference less that noise, so its spread goes as V_c + P_i (at one camera path per
        pixel): a pair of short passes, where the photon noise dwarfs the camera side, says
        next to nothing about it. A plain mean let the first pair of a scarce room (4,096 and
        8,192 photons: -0.0028 against later pairs' 2e-7 to 1e-5) hold V_c below zero for the
        whole render, and the guided passes then stayed at their longest (docs/guiding.md, "A
        first pair that hid the camera side"). The weights leave out K, which divides V_c but
        not V_p in a pair's spread: V_c per camera path falls as K grows (a pixel's K points
        are a net), and weights with K in them counted the many-K pairs less, raised V_c
        10-15 % in the closet and lost 8 % there. P_i comes from the history's mean V_p and
        V_s, not the pair's own half-difference, so that a weight does not correlate with its
        estimate."""
        order = sorted(range(len(estimates)), key=estimates.__getitem__)
        order = order[:len(order) - len(order) // TRIM]
        v_s = self._shared_variance() or 0.0
        noise = [(v_p_r2 / scales[i][1] + v_s) * scales[i][0] for i in order]
        values = [estimates[i] for i in order]
        v_c = math.fsum(values) / len(values)
        for _ in range(2):      # the weights depend on V_c: two fixed-point rounds from the plain mean
            spreads = [max(v_c, 0.0) + p for p in noise]
            if not min(spreads) > 0.0:
                break           # no photon noise and no V_c: the plain mean
            weights = [1.0 / x ** 2 for x in spreads]
            v_c = math.fsum(w * v for w, v in zip(weights, values)) / math.fsum(weights)
        return v_c

    def photon_correlation(self) -> float | None:
        """rho, the mean correlation of the photon noise of two measurement points of one pixel
        in one pass, or None before a pass of K >= 2 (docs/effort.md, "Photon noise shared by a
        pixel's points"). A pixel's photon variance in a pass of K points is
        V_MP (rho + (1 - rho) / K): their discs overlap (rho near 1) where the radius exceeds the
        pixel's footprint, and lie apart (rho near 0) where it has shrunk below it, so that K
        points then divide the photon side too. From E[K V_p - V_MP] = (K - 1) rho V_MP."""
        if not self.correlation_terms:
            return None
        numerator = math.fsum(t[0] for t in self.correlation_terms)
        denominator = math.fsum(t[1] for t in self.correlation_terms)
        if not denominator > 0.0:
            return None
        return min(max(numerator / denominator, 0.0), 1.0)

    def _split_photon_side(self, model, photons: float):
        """model (_model's) for a choice of K at `photons` per pass: the part (1 - rho) of each
        point's own photon variance that K points divide counts as camera variance per path,
        and only the part rho they share as photon variance. Unchanged before rho is measured
        (rho = 1: every point gathers the same photons, the model of the module's docstring)."""
        rho = self.photon_correlation()
        if model is None or rho is None or not self.photon_variances_mp_r2:
            return model
        v_c, v_p, camera_work, photon_work = model
        v_mp = math.fsum(self.photon_variances_mp_r2) / len(self.photon_variances_mp_r2) / self.radius_sq
        return v_c + (1.0 - rho) * v_mp / photons, rho * v_mp, camera_work, photon_work

    def _position_share(self, v_held: float) -> float:
        """What the pixel positions still add to V_c per camera path (held_camera): the pairs'
        V_c less the twins' is the positions' variance V_pos of one camera path; over M
        stratified points per pixel the film keeps V_pos M^-e of it (e = POSITION_EXPONENT)
        instead of V_pos / M, whose effect on the next paths is that of a variance
        e V_pos M^(1-e) falling as 1 / M. Early in a render it is most of V_c, late in it
        little."""
        v_pos = max(self.pair_sum / self.pair_samples - v_held, 0.0)
        m = max(self.sum_camera_paths, 1.0)
        return POSITION_EXPONENT * v_pos * m ** (1.0 - POSITION_EXPONENT)

    def _model(self, deposits_as_camera_work: bool):
        """(V_c, V_p, camera work per camera path, work per photon), or None where there is
        nothing to go by: no estimate yet, or no photon has reached a measurement point (that
        says the photons are scarce, not useless). Deposits count as camera work for the
        choice of K at a fixed photon count; sppm's choice of photons does not count them (not
        measured to help, docs/effort.md)."""
        shares = self.shares()
        if shares is None or self.sum_photons <= 0:
            return None
        v_c, v_p = shares
        camera_work = self.sum_camera_work      # per camera path per pixel below
        if deposits_as_camera_work:
            camera_work += DEPOSIT_WORK * self.sum_deposits
        camera_work /= self.sum_camera_paths
        photon_work = self.sum_photon_work / self.sum_photons
        if v_p <= 0.0 or photon_work <= 0.0:
            return None
        return v_c, v_p, camera_work, photon_work

    def _optimum(self, model):
        """n* for one camera path per pixel under `model` (_model's), inf where no camera-side
        error is measured yet, None where there is nothing to go by."""
        if model is None:
            return None
        v_c, v_p, camera_work, photon_work = model
        if v_c <= 0.0:
            return math.inf
        return math.sqrt(self.alpha * camera_work / photon_work * v_p / v_c)

    def _error_with_bias(self, model, photons, camera_paths, photons_now: float, camera_paths_now: float,
                         efficiency=1.0, efficiency_now: float = 1.0, camera_work_now: float | None = None,
                         shared: float = 0.0):
        """The image's error at a fixed budget for candidate splits (arrays of photons and
        camera paths per pass), in units of its photon variance now, had the render used each
        split throughout: camera variance V_c / K x passes^-1 (passes ~ 1 / work per pass);
        photon variance and squared bias fall with the photons per unit of work x, as
        x^-alpha (the radii shrink as the photons come, so a photon removes alpha of its share)
        and x^-2(1-alpha) (bias ~ R^2 ~ N^(alpha-1)). At bias_ratio 0 its least is the closed
        form's n* (K = n / n*). efficiency: the share of a pass's photons that carry its
        estimate (a guided pass's chain steps after their first regeneration), against the
        share in the passes V_p was measured on; camera_work_now: the work per camera path of
        the passes now, where the candidates' differs (their deposits). shared: V_s, the photon
        variance x photons that a pass's halves share (EffortBalance.observe), which falls as
        1 / the photons per unit of work whatever the radius."""
        v_c, v_p, camera_work, photon_work = model
        work = camera_work * camera_paths + photon_work * photons
        work_now = (camera_work if camera_work_now is None else camera_work_now) * camera_paths_now + photon_work * photons_now
        # photons that count per unit of work, relative
        gain = (photons * efficiency / work) / (photons_now * efficiency_now / work_now)
        photon_now = v_p / photons_now
        steps_gain = (photons / work) / (photons_now / work_now)
        return (v_c / camera_paths * work / work_now / photon_now
                + gain ** -self.alpha + self.bias_ratio * gain ** (-2.0 * (1.0 - self.alpha))
                + shared / v_p / steps_gain)

    def next_camera_paths(self, photons: int, most: int) -> int:
        """Camera paths per pixel for a pass of `photons` photon paths: photons / n*, within
        [1, most] and at most MAX_CHANGE times the last pass's. Held while nothing is measured."""
        k = self.last_camera_paths or 1
        model = self._split_photon_side(self._model(deposits_as_camera_work=True), float(photons))
        best = self._optimum(model)
        if best is None:
            return k
        target = photons / best if best > 0.0 else math.inf     # best 0: no photon variance shared
        if self.bias_ratio > 0.0 and 1.0 < target < math.inf:
            # The bias asks for more photons per unit of work, i.e. fewer camera paths.
            ks = np.geomspace(1.0, target, CANDIDATES)
            error = self._error_with_bias(model, float(photons), ks, float(photons), float(k))
            target = float(ks[int(np.argmin(error))])
        target = min(max(target, k / MAX_CHANGE), k * MAX_CHANGE)
        return int(min(max(round(target), 1), most))

    def chain_pass_length(self, lengths, efficiency, efficiency_now: float, steps_now: float,
                          camera_paths: int, most: int) -> int | None:
        """A chain pass's length (chain steps; the guided photon methods' and mbe's, through
        methods/pass_length.py) among `lengths`, each with the share
        `efficiency` of its steps that its chains record (those after a chain's first visible
        uniform proposal; the steps before it are lost, more of them the shorter the pass).
        Each candidate is scored as a render made of such passes throughout (_error_with_bias),
        at the camera paths per pixel next_camera_paths would give it, n / n* within
        [1, most] and within MAX_CHANGE of `camera_paths`, the pass's. Where K is free and a
        camera path's work does not grow with the pass, the longest candidate wins (it loses
        the fewest steps and K keeps the split); where K = n / n* would exceed `most`, or what
        K can grow to by the next pass, a long pass starves the camera side, and the least
        balances the steps a shorter pass loses against the camera passes it gains
        (docs/guiding.md, "Guided passes as long as the camera side allows"). A camera path's
        work includes the deposits into its measurement points, and those grow with the
        photons of the pass: a candidate's is its rays plus DEPOSIT_WORK x the deposits per
        camera path and recorded photon measured so far, times its recorded photons (at a
        fixed pass length, as in next_camera_paths, they are one constant); where they carry
        the work, shorter passes win with K free too. The normalisation's shared variance V_s
        counts against short passes. A candidate shorter than the longest is taken only where
        its expected error is at most PASS_LENGTH_MARGIN of the longest's.
        None where there is nothing to go by yet."""
        base = self._model(deposits_as_camera_work=False)
        if base is None or not self.sum_camera_photons > 0.0:
            return None
        v_c, v_p, rays, photon_work = base
        if not v_p > 0.0 or self._split_photon_side(base, float(steps_now))[1] <= 0.0:
            return None      # no photon variance yet (no MP has met a photon): the errors are in its units
        # A negative V_c (the pairs' difference, noisy while the photon side dominates them) is
        # no camera-side error measured: scored as such, not as a negative one, which made every
        # candidate's error negative and the longest look best by its sign alone.
        v_c = max(v_c, 0.0)
        deposit_work = DEPOSIT_WORK * self.sum_deposits / self.sum_camera_photons
        shared = self._shared_variance() or 0.0
        camera_work_now = rays + deposit_work * steps_now
        k_now = float(self.last_camera_paths or 1)
        k_low = max(camera_paths / MAX_CHANGE, 1.0)
        k_high = max(min(camera_paths * MAX_CHANGE, float(most)), k_low)
        errors = []
        for n, e in zip(lengths, efficiency):
            recorded = float(n) * e / efficiency_now         # photons at the efficiency now
            model = self._split_photon_side((v_c, v_p, rays + deposit_work * recorded, photon_work), recorded)
            best = self._optimum(model)
            if best is None or math.isinf(best):
                k = k_low                # no camera-side error measured: as few camera paths as allowed
            elif best > 0.0:
                k = min(max(n / best, k_low), k_high)
            else:
                k = k_high               # no photon variance shared: next_camera_paths' target is inf
            errors.append(self._error_with_bias(model, float(n), k, float(steps_now), k_now, e, efficiency_now,
                                                camera_work_now, shared))
        best = int(np.argmin(errors))
        self.pass_length_gain = errors[best] / errors[-1]     # the error expected against the longest (stats)
        # The model leaves out what the chains do between regenerations; where it expects
        # little, keep the longest (the held-out closet: expected 0.92-1.0, measured 1.09x).
        return int(lengths[best] if self.pass_length_gain <= PASS_LENGTH_MARGIN else lengths[-1])

    def next_photons(self) -> int:
        """Photons for the next pass: n*, at most MAX_CHANGE times the last pass's (so twice
        as many where no camera-side error is measured yet); held where there is nothing to
        go by, since fewer photons would only make a scarce deposit rarer."""
        model = self._model(deposits_as_camera_work=False)
        best = self._optimum(model)
        if best is None:
            return self.photons
        cap = float(min(MAX_PER_PIXEL * self.n_pixels, 1 << 28))
        if self.bias_ratio > 0.0 and best < cap:
            # The bias asks for more photons than the variance alone does.
            ns = np.geomspace(best, cap, CANDIDATES)
            k = float(self.last_camera_paths or 1)
            error = self._error_with_bias(model, ns, k, float(self.photons), k)
            best = float(ns[int(np.argmin(error))])
        target = min(max(best, self.photons / MAX_CHANGE), self.photons * MAX_CHANGE)
        self.photons = int(min(max(round(target), 1), MAX_PER_PIXEL * self.n_pixels, 1 << 28))
        return self.photons

    def stats(self) -> dict:
        shares = self.shares()
        return {"photons_next_pass": self.photons,
                "bias_ratio": self.bias_ratio,
                "camera_variance": shares[0] if shares else None,
                "photon_correlation": self.photon_correlation(),
                "shared_photon_variance": self._shared_variance(),
                "pass_length_gain": self.pass_length_gain,
                "photon_variance_per_photon": shares[1] if shares else None,
                "camera_work_per_pass": self.sum_camera_work / self.observed if self.observed else None,
                "segments_per_photon": self.sum_photon_work / self.sum_photons if self.sum_photons else None}


def least_variance_share(var_a: float, var_b: float, cov: float) -> float | None:
    """The weight w of estimate A in w A + (1 - w) B (two estimates of one quantity) that
    minimises its variance w^2 Var A + (1 - w)^2 Var B + 2 w (1 - w) Cov(A, B):
    w = (Var B - Cov) / (Var A + Var B - 2 Cov), clamped to [0, 1]. None where the two are
    indistinguishable (Var(A - B) = 0), so that the caller keeps its last weight."""
    denom = var_a + var_b - 2.0 * cov
    if not denom > 0.0:
        return None
    return float(min(max((var_b - cov) / denom, 0.0), 1.0))


def uniform_weight_option(value) -> tuple[bool, float]:
    """--uniform-weight (mbe, visibility, spatial-tf): 'auto' (the default: chosen by least
    variance from the even and odd ladders) or a fixed share in [0, 1] of the uniform
    proposals' own estimate (0: the chains' estimate alone; 1: the uniform proposals' alone).
    Returns (auto, the fixed share or 0)."""
    if value is None or value == "auto":
        return True, 0.0
    try:
        share = float(value)
    except (TypeError, ValueError):
        share = float("nan")
    if isinstance(value, bool) or not 0.0 <= share <= 1.0:
        raise SettingsError(f"--uniform-weight must be 'auto' or a number in [0, 1], got '{value}'")
    return False, share


class UniformWeight:
    """beta, the share of the uniform proposals' own estimate U in the combination
    beta U + (1 - beta) C with the chains' estimate C (mbe's light side, the guided photon
    methods' photon flux). Each pass reports the sums over pixels of the squared even-odd
    ladder differences of U and of C and of their product (4x each estimate's variance, and
    their covariance; the halves are independent); beta for the next pass is the least-
    variance share of those sums over the passes so far, each pass forgetting MEMORY of the
    earlier ones (so that beta follows what it steers, e.g. mbe's large-step probability).
    Chosen before the pass it weights, it does not depend on that pass's samples: any beta
    keeps the combination's expectation (docs/mbe.md, "The uniform proposals' estimate")."""
    MEMORY = 0.9

    def __init__(self, option):
        self.auto, fixed = uniform_weight_option(option)
        self.value = 0.0 if self.auto else fixed      # auto starts from the chains' estimate alone
        self.sums = np.zeros(3)                       # U, C, U x C

    def observe(self, s_uniform: float, s_chains: float, s_product: float) -> None:
        self.sums = self.MEMORY * self.sums + (s_uniform, s_chains, s_product)
        if self.auto:
            beta = least_variance_share(*self.sums)
            if beta is not None:
                self.value = beta


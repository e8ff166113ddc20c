"""The chains' own bias, measured pass by pass, and the chain pass length that keeps it below
the film's noise (mbe; docs/mbe.md, "The chains' own bias, pass by pass").

Each chain pass estimates its light side twice, from the same camera subpaths and the same
merging radius: the chains' estimate C (their records, scaled by the pass's normalisations)
and the uniform proposals' plain Monte Carlo estimate U, which is unbiased for what the
pass's techniques estimate. What the chains add to the film beyond U is (1 - beta)(C - U),
beta the uniform proposals' weight. Its mean over passes is the chains' own bias: their
contribution chains restart every pass (the camera subpaths, and so the targets, change),
and a restart from a resampled or carried state is not an exact draw, so every pass of a
fixed length carries the same start-up bias, which more passes do not average away. In the
held-out light bay it is -0.96 +- 0.25 % of the light side at the default pass length and
0.00 +- 0.37 % at four times that length (tools/mbe_chain_bias.py, 10,000 and 1,400 passes).

Lengthening every pass costs variance where the chains do not need it (the Cornell box: 4x
longer passes, 1.5x the RMSE at 15 s), so the length doubles only when the bias has shown
itself: when the mean of (1 - beta)(C - U), summed over pixels, lies more than Z standard
errors from 0 (judged as the passes at a length double) and the squared bias it implies for
the film outweighs the film's variance from the chain passes. The bias is then measured
afresh at the new length. So the start-up bias of new passes falls as the render goes on,
and the estimator stays consistent, while a short render keeps the short passes that are
cheapest for its noise. The film weighs every pass alike, so what the early passes put in
fades as 1 / passes (faster than the noise).
"""
from __future__ import annotations

import math

# Passes at one length before its bias is first judged, and how many standard errors from 0
# its mean must lie. It is judged again each time the passes at that length have doubled
# (64, 128, 256, ...): a test at every pass would, by the law of the iterated logarithm,
# sooner or later find any unbiased mean 3 standard errors from 0; at doublings it looks
# about 10 times in 65,000 passes, a false alarm in about 3 % of such renders (at 3 standard
# errors, 0.27 % a look), and a false alarm costs a longer pass, not a biased image.
MIN_PASSES = 64
Z = 3.0
# The pass length's factor at most (mbe's MAX_PASS_FACTOR bounds the pass itself).
MAX_FACTOR = 64


class ChainBias:
    def __init__(self):
        self.factor = 1
        self.doublings = []         # (chain passes, relative bias, its standard error) at each doubling
        self._restart()

    def _restart(self):
        self.passes = 0
        self.mean = 0.0             # (1 - beta)(C - U), luminance summed over pixels (Welford)
        self.m2 = 0.0
        self.uniform_sum = 0.0      # U, the same

    def observe(self, beta: float, chains: float, uniform: float) -> None:
        """A chain pass: its uniform weight and its two estimates of the light side (luminance
        summed over pixels). A pass without uniform proposals tells nothing."""
        if not (math.isfinite(chains) and math.isfinite(uniform)):
            return
        d = (1.0 - beta) * (chains - uniform)
        self.passes += 1
        delta = d - self.mean
        self.mean += delta / self.passes
        self.m2 += delta * (d - self.mean)
        self.uniform_sum += uniform

    def relative(self) -> tuple[float, float] | None:
        """The bias at the current length relative to the light side, and its standard error."""
        if self.passes < 2 or self.uniform_sum <= 0.0:
            return None
        light = self.uniform_sum / self.passes
        se = math.sqrt(self.m2 / (self.passes - 1) / self.passes)
        return self.mean / light, se / light

    def lengthen(self, chain_passes: int, pass_variance_sum: float | None, light_sq_sum: float) -> bool:
        """Whether to double the chain passes' length now. chain_passes: those in the film;
        pass_variance_sum: one chain pass's variance summed over pixels (batch means, so with
        the passes' correlation), None before it is known; light_sq_sum: the film's squared
        pixel values summed (luminance): the bias is taken as the same share of each pixel,
        camera side included (which overstates it where the camera side is a large share).
        The film's squared bias from the chain passes is about (P_c / P)^2 x bias^2, its
        variance from them P_c V_c / P^2: the bias outweighs it when P_c bias^2 > V_c."""
        judged_now = self.passes >= MIN_PASSES and self.passes & (self.passes - 1) == 0
        r = self.relative()
        if not judged_now or r is None or pass_variance_sum is None or self.factor >= MAX_FACTOR:
            return False
        rho, se = r
        if abs(rho) <= Z * se:
            return False
        bias_sq = (rho * rho - se * se) * light_sq_sum
        if chain_passes * bias_sq <= pass_variance_sum:
            return False
        self.doublings.append((chain_passes, rho, se))
        self.factor *= 2
        self._restart()
        return True

    def stats(self) -> dict:
        r = self.relative()
        return {"pass_length_factor": self.factor,
                "relative_bias": None if r is None else r[0], "relative_bias_error": None if r is None else r[1],
                "passes_at_this_length": self.passes,
                "doublings": [{"chain_passes": p, "relative_bias": b, "error": e} for p, b, e in self.doublings]}

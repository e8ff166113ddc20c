"""The merging radius of vcm and mbe, pass by pass (docs/vcm.md, "Radius").

`progressive` (Knaus & Zwicker 2011; VCM, Georgiev et al. 2012, sec. 5): r_i = r_1 i^((alpha-1)/2),
i counted from 1, a function of the index alone.

`balanced`: the same steps, except that a step taken while merging's measured bias outweighs
its noise uses alpha / 2 (r^2 shrinks as i^(alpha/2 - 1) there). The decision weighs what the
next pass changes in the film, which averages every pass so far (docs/vcm.md, "A radius that
weighs merging's bias"): with B the film's bias (the mean of the passes' biases b r_i^2) and
V its merging variance (the passes' c / r_i^2 over n^2), shrinking the next pass's r^2 lowers
the film's squared error where

    2 B b r^2 > c / (n r^2),   i.e.   B^2 rho_b > V rho_v / 2,

rho_b = r^2 / mean(r_i^2) and rho_v = r^-2 / mean(r_i^-2) over the passes measured. With one
radius throughout this is the balance bias^2 = variance / 2; the ratios keep the early passes'
large radii, whose bias no later pass can undo, from driving the radius down for ever. The
photon methods apply the same test with each pixel's own radius history (methods/sppm.py).
Any sequence of alpha and alpha / 2 steps still sends r to 0 with sum r_i^-2 / n^2 -> 0, so
merging stays consistent.

Plain values only: the state is saved with the render (state.py).
"""
from __future__ import annotations

import math

RULES = ("progressive", "balanced")
ALPHA_FAST = 0.5          # alpha's factor for a step taken while the bias dominates
BIAS_MIN_PASSES = 16      # passes measured before the bias counts
BIAS_Z = 3.0              # and by how many standard errors of its own estimate it must dominate


class MergeRadius:
    """r_i / r_1 for the pass of index i, and the balanced rule's choice of the next steps."""

    def __init__(self, alpha: float, rule: str = "progressive"):
        self.alpha = float(alpha)
        # alpha = 1 asks for a fixed radius, whatever the rule.
        self.balanced = rule == "balanced" and self.alpha < 1.0
        self.reset()

    def reset(self) -> None:
        self.fixed_index = 0          # log_scale is fixed up to this index,
        self.log_scale = 0.0          # log(r^2 / r_1^2) there,
        self.step_alpha = self.alpha  # and the steps beyond it use this alpha
        self.fast_steps = 0           # index steps taken with alpha / 2
        self.decisions = 0
        self.fast_decisions = 0

    def scale(self, index: int) -> float:
        """r_index / r_1 (index from 0, the first pass's radius r_1)."""
        if not self.balanced:
            return (index + 1.0) ** ((self.alpha - 1.0) / 2.0)
        i = max(int(index), self.fixed_index)
        log = self.log_scale + (self.step_alpha - 1.0) * math.log((i + 1.0) / (self.fixed_index + 1.0))
        return math.exp(0.5 * log)

    def advance(self, index: int, fast: bool) -> None:
        """Fix the schedule up to `index` (the next pass's) and take the steps after it with
        alpha / 2 if `fast`."""
        if not self.balanced:
            return
        index = int(index)
        if index > self.fixed_index:
            if self.step_alpha < self.alpha:
                self.fast_steps += index - self.fixed_index
            self.log_scale += (self.step_alpha - 1.0) * math.log((index + 1.0) / (self.fixed_index + 1.0))
            self.fixed_index = index
        self.step_alpha = self.alpha * (ALPHA_FAST if fast else 1.0)
        self.decisions += 1
        self.fast_decisions += int(fast)

    @staticmethod
    def bias_dominates(bias_sq: float, variance: float, spread: float, passes: int,
                       radius_sq: float, mean_radius_sq: float, mean_inverse_radius_sq: float) -> bool:
        """Whether the next pass should shrink faster: bias_sq (the film's squared merging bias
        summed over pixels, noise removed), variance (its merging variance, summed), spread
        (the variance of the bias_sq estimate), after `passes` measured passes whose r^2 and
        r^-2 average mean_radius_sq and mean_inverse_radius_sq; radius_sq the next pass's r^2
        at the ordinary step."""
        if passes < BIAS_MIN_PASSES or not (mean_radius_sq > 0.0 and mean_inverse_radius_sq > 0.0):
            return False
        rho_b = radius_sq / mean_radius_sq
        rho_v = (1.0 / radius_sq) / mean_inverse_radius_sq
        return bias_outweighs_noise(rho_b * bias_sq, rho_v * variance, rho_b * rho_b * spread)

    def stats(self) -> dict:
        return {"rule": "balanced" if self.balanced else "progressive",
                "fast_steps": self.fast_steps if self.balanced else 0,
                "fast_decisions": self.fast_decisions, "decisions": self.decisions}


def bias_outweighs_noise(bias_sq: float, variance: float, spread: float) -> bool:
    """The balanced rule's test on sums already scaled to the next pass (rho_b bias^2,
    rho_v variance, rho_b^2 x the variance of the bias^2 estimate): the bias term must exceed
    half the variance term by BIAS_Z standard errors of its own estimate. Shared by vcm's
    single radius and sppm's per-pixel radii (methods/sppm.py), which fold each pixel's own
    ratios into the sums."""
    return bias_sq - BIAS_Z * math.sqrt(max(spread, 0.0)) > 0.5 * variance

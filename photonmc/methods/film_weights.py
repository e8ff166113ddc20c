"""mbe's image from its two films: the chain passes' and the vcm passes', each the plain mean
of its passes, combined by their measured variances (docs/mbe.md, "Two films, combined by
their variances").

A chain pass and a vcm pass differ in variance by several times (in the held-out light bay a
chain pass has about a third of a vcm pass's, at three times its time). One film that takes
every pass as one sample weighs them alike, and where the pass choice mixes the kinds that
costs variance: with equal time in each kind there, 1.25x the variance of vcm passes alone,
although the kinds tie at equal time (arithmetic in docs/mbe.md, "Two films"). Weights set
pass by pass from earlier passes' estimates lost where those estimates erred (a firefly
raised the variance of the passes after it, so its own pass weighed more; docs/mbe.md,
"Passes weighed by their variance"). Measured against one film, the weights below tie within
resolution (0.95-1.03x at 15 s on eight rooms, 1.02x at 60 s in the light bay): at those
lengths the kinds seldom mix. Here each kind keeps its own film, and the image is

    w F_chain + (1 - w) F_vcm,   w = (n_c / v_c) / (n_c / v_c + n_v / v_v),

v the variance of one pass of the kind (of its luminance, mean over pixels: the chain
passes' by batch means, pass_choice.BatchMeansVariance, since consecutive chain passes are
correlated; the vcm passes' from twin passes at the same pixel positions where those are
stratified, pass_choice.TwinVariance, else from pairs of consecutive passes,
light_balance.LightPathBalance),
n the passes in each film: the inverse-variance combination of two independent estimates.
One weight serves every pixel: per-pixel weights would follow per-pixel variance estimates,
far noisier than these. It is decided when the image is read, from everything measured, so a
firefly that raises a film's variance estimate lowers that film's weight, its own pass
included. The weights depend on the passes they weigh, so the image is consistent (the
estimates converge) but not unbiased for a finite render; the merging radius already makes
mbe so.

The variance estimates are uncertain (8 batch means leave the chain passes' uncertain by
half; the vcm passes' is heavy-tailed), so the log of their ratio is moved toward 0, the
count weights w = n_c / (n_c + n_v) that one film gives, by SHRINK_Z of its standard errors
(soft thresholding): a weight leaves the count weights only as far as the estimates are sure.
Until both variances are measured the count weights stand.
"""
from __future__ import annotations

import math

# Standard errors of log(v_v / v_c) by which the weights stay nearer the count weights.
SHRINK_Z = 1.0


def count_weights(n_chain: int, n_vcm: int) -> tuple[float, float]:
    """The weights of one film that takes every pass as one sample."""
    total = n_chain + n_vcm
    if total <= 0:
        return 1.0, 0.0
    return n_chain / total, n_vcm / total


def shrunk_log_ratio(chain_variance: float | None, chain_error: float | None, vcm_variance: float | None,
                     vcm_error: float | None, z: float = SHRINK_Z) -> float:
    """log(v_v / v_c), moved toward 0 by z of its standard errors (hypot of the two relative
    errors), or 0 where either variance is not measured."""
    if not (chain_variance and vcm_variance and chain_variance > 0.0 and vcm_variance > 0.0
            and chain_error is not None and vcm_error is not None
            and math.isfinite(chain_variance) and math.isfinite(vcm_variance)):
        return 0.0
    log_ratio = math.log(vcm_variance / chain_variance)
    margin = z * math.hypot(chain_error, vcm_error)
    if not (margin < abs(log_ratio)):       # within its error, or an error that is not finite
        return 0.0
    return math.copysign(abs(log_ratio) - margin, log_ratio)


def film_weights(n_chain: int, n_vcm: int, log_ratio: float) -> tuple[float, float]:
    """(w_chain, w_vcm): the count weights' odds n_c / n_v times exp(log_ratio), the shrunk
    log(v_v / v_c). An empty film weighs nothing."""
    if n_chain <= 0 or n_vcm <= 0:
        return count_weights(n_chain, n_vcm)
    # odds = n_c v_v / (n_v v_c), kept in logs so that no ratio overflows
    log_odds = math.log(n_chain / n_vcm) + log_ratio
    if log_odds >= 0.0:
        e = math.exp(-log_odds)
        return 1.0 / (1.0 + e), e / (1.0 + e)
    e = math.exp(log_odds)
    return e / (1.0 + e), 1.0 / (1.0 + e)

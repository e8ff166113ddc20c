"""The merging radius's schedule (methods/merge_radius.py): the progressive rule's closed form,
the balanced rule's faster steps, and its decision, without Taichi."""
import math

import pytest

from photonmc.methods.merge_radius import ALPHA_FAST, BIAS_MIN_PASSES, MergeRadius


def test_alpha_one_keeps_the_radius_fixed_whatever_the_rule():
    s = MergeRadius(1.0, "balanced")
    s.advance(20, fast=True)
    assert not s.balanced and s.scale(100) == 1.0


@pytest.mark.parametrize("alpha", [0.75, 0.5, 0.99])
def test_progressive_is_the_closed_form_and_balanced_without_fast_steps_is_the_same(alpha):
    progressive, balanced = MergeRadius(alpha), MergeRadius(alpha, "balanced")
    for i in range(200):
        expected = (i + 1.0) ** ((alpha - 1.0) / 2.0)
        assert progressive.scale(i) == pytest.approx(expected, rel=1e-12)
        assert balanced.scale(i) == pytest.approx(expected, rel=1e-12)
        balanced.advance(i + 1, fast=False)
        progressive.advance(i + 1, fast=True)        # no effect on the progressive rule
    assert balanced.stats()["fast_steps"] == 0 and balanced.stats()["decisions"] == 200


def test_fast_steps_use_half_alpha_and_keep_the_radius_continuous():
    """Steps taken while the bias dominates shrink r^2 as i^(alpha/2 - 1); a decision changes
    only the steps after it, never a radius already used."""
    alpha = 0.75
    s = MergeRadius(alpha, "balanced")
    s.advance(10, fast=False)
    before = s.scale(10)
    s.advance(10, fast=True)
    assert s.scale(10) == pytest.approx(before, rel=1e-12)
    fast_exponent = (alpha * ALPHA_FAST - 1.0) / 2.0
    assert s.scale(40) / s.scale(10) == pytest.approx((41.0 / 11.0) ** fast_exponent, rel=1e-12)
    s.advance(40, fast=False)
    slow_exponent = (alpha - 1.0) / 2.0
    assert s.scale(90) / s.scale(40) == pytest.approx((91.0 / 41.0) ** slow_exponent, rel=1e-12)
    assert s.scale(90) < MergeRadius(alpha).scale(90)
    assert s.stats()["fast_steps"] == 30
    # monotone: r never grows
    s.advance(95, fast=True)
    assert all(s.scale(i + 1) <= s.scale(i) for i in range(95, 300))


def test_the_rule_is_the_balance_of_bias_and_variance_where_the_radius_has_not_moved():
    """With one radius throughout the rule is bias^2 > variance / 2 (the MSE-optimal balance
    for a bias linear in r^2 against a variance linear in 1 / r^2), past the bias estimate's
    own noise, and it waits for BIAS_MIN_PASSES passes."""
    r2 = 0.01
    one_radius = dict(radius_sq=r2, mean_radius_sq=r2, mean_inverse_radius_sq=1.0 / r2)
    assert MergeRadius.bias_dominates(1.0, 1.0, 0.0, 100, **one_radius)
    assert not MergeRadius.bias_dominates(0.4, 1.0, 0.0, 100, **one_radius)
    assert not MergeRadius.bias_dominates(1.0, 1.0, 0.04, 100, **one_radius)     # 3 sd of 0.2: 1 - 0.6 < 0.5
    assert not MergeRadius.bias_dominates(1.0, 1.0, 0.0, BIAS_MIN_PASSES - 1, **one_radius)


def test_the_rule_weighs_what_the_next_pass_changes_not_the_early_passes_bias():
    """The film's bias is the mean of its passes' biases: once the radius has shrunk well below
    the passes' mean, the next pass's r^2 moves that mean little and its 1 / r^2 adds much
    variance, so a bias the early, wide passes left does not keep the radius shrinking."""
    r2, mean_r2 = 0.01, 0.04
    mean_inverse = 0.5 / r2          # most passes were wider than this one
    assert MergeRadius.bias_dominates(1.0, 1.0, 0.0, 100, r2, r2, 1.0 / r2)
    assert not MergeRadius.bias_dominates(1.0, 1.0, 0.0, 100, r2, mean_r2, mean_inverse)
    rho_b, rho_v = r2 / mean_r2, (1.0 / r2) / mean_inverse
    assert MergeRadius.bias_dominates(1.01 * 0.5 * rho_v / rho_b, 1.0, 0.0, 100, r2, mean_r2, mean_inverse)
    assert math.isclose(rho_v / rho_b, 8.0)

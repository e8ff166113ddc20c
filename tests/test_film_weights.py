"""mbe's two films combined by their measured variances (methods/film_weights.py)."""
import math

import numpy as np
import pytest

from photonmc.methods.film_weights import count_weights, film_weights, shrunk_log_ratio


def test_count_weights_until_both_variances_are_measured():
    assert count_weights(30, 10) == (0.75, 0.25)
    assert count_weights(0, 0) == (1.0, 0.0)
    for unmeasured in [(None, None, 1.0, 0.1), (1.0, 0.1, None, None), (0.0, 0.1, 1.0, 0.1), (1.0, 0.1, math.nan, 0.1)]:
        assert shrunk_log_ratio(*unmeasured) == 0.0
    assert film_weights(30, 10, 0.0) == pytest.approx((0.75, 0.25))
    # an empty film weighs nothing, whatever the variances say
    assert film_weights(0, 10, 5.0) == (0.0, 1.0) and film_weights(10, 0, -5.0) == (1.0, 0.0)


def test_a_variance_ratio_within_its_error_keeps_the_count_weights():
    # log(4) = 1.386 against an error of hypot(0.5, 0.5) = 0.707: moved toward 0 by 0.707
    assert shrunk_log_ratio(1.0, 0.5, 4.0, 0.5) == pytest.approx(math.log(4.0) - math.hypot(0.5, 0.5))
    assert shrunk_log_ratio(4.0, 0.5, 1.0, 0.5) == pytest.approx(-(math.log(4.0) - math.hypot(0.5, 0.5)))
    assert shrunk_log_ratio(1.0, 1.0, 2.0, 1.0) == 0.0
    # an error that is not finite (a variance estimate overflowed) leaves the count weights
    assert shrunk_log_ratio(1.0, 0.1, 4.0, math.inf) == 0.0 and shrunk_log_ratio(1.0, math.nan, 4.0, 0.1) == 0.0
    assert shrunk_log_ratio(1.0, 0.0, 4.0, 0.0) == pytest.approx(math.log(4.0))
    # inverse-variance weights: chain passes a quarter of the variance count four times
    w_c, w_v = film_weights(10, 40, math.log(4.0))
    assert w_c == pytest.approx(0.5) and w_v == pytest.approx(0.5)
    # extreme odds neither overflow nor lose the small weight
    w_c, w_v = film_weights(1, 1, 800.0)
    assert w_c == 1.0 and 0.0 <= w_v < 1e-300
    assert film_weights(1, 1, -800.0)[0] < 1e-300


def test_weights_from_estimated_variances_remove_what_equal_weights_cost():
    """Two unbiased films, per-pass variances 1 (100 passes) and 9 (300 passes), weighed
    from the variances their own passes estimate: the combination stays centred on the
    truth and its MSE comes near the inverse-variance optimum, well below what count weights
    (one film of all 400 passes) give."""
    rng = np.random.default_rng(5)
    n_c, n_v, v_c, v_v, trials = 100, 300, 1.0, 9.0, 4000
    chain = rng.normal(0.0, math.sqrt(v_c), (trials, n_c))
    vcm = rng.normal(0.0, math.sqrt(v_v), (trials, n_v))
    combined, counted = [], []
    for a, b in zip(chain, vcm):
        ratio = shrunk_log_ratio(a.var(ddof=1), math.sqrt(2 / (n_c - 1)), b.var(ddof=1), math.sqrt(2 / (n_v - 1)))
        w_c, w_v = film_weights(n_c, n_v, ratio)
        combined.append(w_c * a.mean() + w_v * b.mean())
        counted.append((a.sum() + b.sum()) / (n_c + n_v))
    combined, counted = np.array(combined), np.array(counted)
    optimum = 1.0 / (n_c / v_c + n_v / v_v)              # 0.0075
    by_count = (n_c * v_c + n_v * v_v) / (n_c + n_v) ** 2  # 0.0175
    mse, mse_count = float(np.mean(combined ** 2)), float(np.mean(counted ** 2))
    print(mse, mse_count, optimum, by_count)
    assert mse_count == pytest.approx(by_count, rel=0.1)
    assert mse < 1.15 * optimum and mse < 0.5 * mse_count
    assert abs(combined.mean()) < 4 * combined.std() / math.sqrt(trials)

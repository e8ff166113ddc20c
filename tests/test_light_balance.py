"""vcm's light-path balance (methods/light_balance.py) on analytic passes: variance A + B / N
and work C + c N per pass, whose product is least at N* = sqrt(C B / (c A))."""
import math

import pytest

from photonmc.methods.light_balance import FEWEST, LightPathBalance

PIXELS = 4096


def settle(a, b, c_fixed, c_light, passes=6000):
    balance = LightPathBalance(PIXELS)
    for _ in range(passes):
        n = balance.next_light_paths()
        variance = a + b / n
        # the balance reads the variance of one pass from the spread of two: sum of (X1 - X2)^2
        balance.observe(n, 2.0 * variance * PIXELS, PIXELS, c_fixed + c_light * n)
    return balance


@pytest.mark.parametrize("a, b, c_fixed, c_light", [
    (1.0, 400.0, 4000.0, 1.0),        # N* = 1265
    (1.0, 20.0, 4000.0, 2.0),         # N* = 200
    (0.5, 3000.0, 2000.0, 1.5),       # N* = 2828
])
def test_the_centre_settles_next_to_the_best_light_paths(a, b, c_fixed, c_light):
    best = math.sqrt(c_fixed * b / (c_light * a))
    balance = settle(a, b, c_fixed, c_light)
    centre = balance.stats()["centre"]
    assert best / 2 ** 0.5 <= centre <= best * 2 ** 0.5, (centre, best)
    assert balance.stats()["reversals"] >= 2        # it crossed the optimum and came back


def test_the_centre_stays_within_its_range():
    # the light side costs nothing to lower: as few as allowed
    assert settle(1.0, 1e-9, 1000.0, 1.0).stats()["centre"] == PIXELS / FEWEST
    # the light side is all the variance: as many as the store holds
    assert settle(1e-9, 1e6, 1e6, 1.0).stats()["centre"] == PIXELS


def test_a_pass_that_measured_nothing_moves_nothing():
    balance = LightPathBalance(PIXELS)
    start = balance.stats()["centre"]
    for _ in range(400):
        balance.observe(balance.next_light_paths(), 0.0, PIXELS, 100.0)
    assert balance.stats()["centre"] == start and balance.stats()["moves"] == 0


def test_a_pass_variance_is_reported_once_measured():
    """mbe's pass choice reads the variance of a vcm pass from the balance (pass_variance):
    None until MEASURED_AFTER estimates (one per two passes) are in, then the running mean of
    the estimates, here the analytic A + B / N at the probes."""
    from photonmc.methods.light_balance import MEASURED_AFTER
    balance, a, b = LightPathBalance(PIXELS), 1.0, 400.0
    seen = []
    for _ in range(2 * MEASURED_AFTER):
        n = balance.next_light_paths()
        seen.append(a + b / n)
        assert balance.pass_variance() is None
        balance.observe(n, 2.0 * (a + b / n) * PIXELS, PIXELS, 4000.0 + n)
    assert min(seen) <= balance.pass_variance() <= max(seen)

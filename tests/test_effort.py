"""The effort balance (photonmc/methods/effort.py): its optimum on a known model, and its
variance estimates on real renders."""
import math
import sys
from pathlib import Path

import numpy as np

import pytest

from photonmc.loop import Job
from photonmc.methods.effort import PASS_LENGTH_MARGIN, EffortBalance, least_variance_share

from .conftest import SCENES


def test_balance_reaches_the_optimum_of_a_known_error_model():
    """Observations made exactly from V(n) = V_c + V_p/n and known work: the photons per pass
    settle at sqrt(alpha C_c/c_p V_p/V_c), from above and from below, moving at most 2x a
    step; V_p is followed as the radius shrinks (V_p R^2 constant)."""
    v_c, v_p_r2, camera_work, segments, alpha = 0.02, 50.0, 3000.0, 3.0, 2.0 / 3.0
    for start in (100, 40000):
        balance, last, seen = EffortBalance(1000, start, alpha), None, []
        for i in range(60):
            n = balance.photons
            radius_sq = 1.0 / (1 + 0.01 * i)
            v_p = v_p_r2 / radius_sq
            spread = 2 * v_c + v_p * (1 / n + 1 / (last or n))
            balance.observe(n, spread, v_p, radius_sq, camera_work, segments * n)
            last = n
            new = balance.next_photons()
            assert n / 2 <= new <= 2 * n
            seen.append(new)
        best = math.sqrt(alpha * camera_work / segments * v_p / v_c)
        assert abs(seen[-1] / best - 1) < 0.02, (start, best, seen)


def _simulated_render(strategy, bias, budget=3e7, v_c=0.02, v_p_r2=0.05, camera_work=3000.0, segments=3.0,
                      alpha=2.0 / 3.0):
    """An SPPM render on an exact error model: per pass V_c camera variance and V_p / n photon
    variance, V_p ~ 1 / R^2; R^2 ~ (1 + N / 1e5)^(alpha-1) after N photons; each pass's radius
    bias = bias x R^2; the image averages the passes. strategy 'balance' (the effort balance,
    told the bias as sppm tells it: at the current radius, rho_b^2 and rho_v), 'variance'
    (the balance without the bias) or a fixed photon count. Returns the image's MSE after
    the budget of work and the last pass's photons."""
    balance = EffortBalance(1000, 1000, alpha)
    n = 1000 if isinstance(strategy, str) else strategy
    spent = photons = passes = 0.0
    bias_sum = photon_var = camera_var = radius_sq_sum = inverse_radius_sq_sum = 0.0
    last = None
    while spent + camera_work + segments * n <= budget:
        spent += camera_work + segments * n
        radius_sq = 1e-2 * (1.0 + photons / 1e5) ** (alpha - 1.0)
        v_p = v_p_r2 / radius_sq
        photons += n
        passes += 1
        bias_sum += bias * radius_sq
        photon_var += v_p / n
        camera_var += v_c
        radius_sq_sum += radius_sq
        inverse_radius_sq_sum += 1.0 / radius_sq
        if isinstance(strategy, str):
            balance.observe(n, 2 * v_c + v_p * (1 / n + 1 / (last or n)), v_p, radius_sq, camera_work, segments * n)
            if strategy == "balance":
                rho_b = radius_sq * passes / radius_sq_sum
                rho_v = passes / (radius_sq * inverse_radius_sq_sum)
                balance.observe_bias((rho_b * bias_sum / passes) ** 2, rho_v * photon_var / passes ** 2, 0.0, 3.0)
            last, n = n, balance.next_photons()
    return (bias_sum / passes) ** 2 + (photon_var + camera_var) / passes ** 2, n


def test_camera_share_predicts_the_balanced_noise_of_better_photons():
    """tools/effective_photons.py's prediction: at the best split of a budget between camera
    paths (work c_c, variance V_c each) and photons (c_p, V_p), the noise is (a_c + a_p)^2 / W,
    a = sqrt(V c); photons worth g times as many (V_p / g) leave s_c + (1 - s_c) / sqrt(g) of
    it in RMSE, s_c = a_c / (a_c + a_p). Checked against the error minimised over the photons
    per camera path by brute force."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
    from effective_photons import camera_share       # a tool, not part of the package

    rng = np.random.default_rng(3)
    photons = np.geomspace(1e-7, 1e7, 300001)     # n* = sqrt(c_c V_p / (c_p V_c)) lies in 1e-6 .. 1e6
    for _ in range(20):
        v_c, v_p, c_c, c_p, g = 10.0 ** rng.uniform(-3, 3, 5)
        share = camera_share((v_c, v_p), c_c, c_p)
        least = [np.min((c_c + photons * c_p) * (v_c + v / photons)) for v in (v_p, v_p / g)]
        assert math.sqrt(least[1] / least[0]) == pytest.approx(share + (1 - share) / math.sqrt(g), rel=1e-4)
    assert math.isnan(camera_share(None, 1.0, 1.0))


def test_balance_weighs_the_radius_bias_on_a_known_model():
    """Where the radius bias is a large part of the error, the photons per pass follow it:
    the balance told the bias ends with less error than the balance without it (0.82x in this
    model) and within 1.2x of the best fixed photon count, found by trying 40 (1.18x: the
    early passes, where the bias is still small against the noise, hold few photons). Without
    bias both choose the same photons, pass by pass."""
    fixed = {n: _simulated_render(int(n), 2.0)[0] for n in np.geomspace(64, 65536, 40).astype(int)}
    with_bias, photons_with = _simulated_render("balance", 2.0)
    without, photons_without = _simulated_render("variance", 2.0)
    assert with_bias < 0.9 * without, (with_bias, without)
    assert with_bias < 1.2 * min(fixed.values()), (with_bias, min(fixed.values()))
    assert photons_with > 2 * photons_without
    assert _simulated_render("balance", 0.0) == _simulated_render("variance", 0.0)


def test_camera_paths_settle_at_the_photons_over_the_optimum_of_a_known_model():
    """A pass whose photon count is set elsewhere (the guided methods' passes last until
    their chains regenerate): observations made exactly from V = V_c/K + V_p/n, with K camera
    paths per pixel costing K C_c. K settles at n / n*, n* = sqrt(alpha C_c/c_p V_p/V_c) the
    photons the balance would pick for one camera path, moving at most 2x a step and held
    within the cap; from K = 1 and from the cap."""
    v_c, v_p, camera_work, segments, alpha, n = 0.02, 50.0, 3000.0, 3.0, 2.0 / 3.0, 40000
    best = n / math.sqrt(alpha * camera_work / segments * v_p / v_c)       # 31.0
    for start in (1, 64):
        balance, k, last_k = EffortBalance(1000, n, alpha), start, None
        for _ in range(30):
            spread = v_c * (1 / k + 1 / (last_k or k)) + v_p * 2 / n
            balance.observe(n, spread, v_p, 1.0, camera_work * k, segments * n, camera_paths=k)
            last_k, k = k, balance.next_camera_paths(n, 64)
            assert last_k / 2 <= k <= 2 * last_k and 1 <= k <= 64
        assert abs(k - best) <= 1, (start, best, k)
        assert balance.shares()[0] == pytest.approx(v_c)
    # A cap below the optimum holds K there; a pass of few photons gets one camera path.
    balance = EffortBalance(1000, n, alpha)
    for _ in range(10):
        balance.observe(n, 2 * v_c + v_p * 2 / n, v_p, 1.0, camera_work, segments * n)
    assert balance.next_camera_paths(n, 8) == 2 and balance.next_camera_paths(100, 64) == 1


def test_camera_paths_count_the_photon_noise_a_pixel_s_points_do_not_share():
    """Observations made exactly from a pass variance V_c/K + V_MP (rho + (1 - rho)/K)/n: a
    pixel's K points gather the same photons into discs that overlap only in part (docs/
    effort.md, "Photon noise shared by a pixel's points"). The balance reads rho from each
    point's own even-odd difference beside the pixel's, and K settles where the variance
    K divides, (V_c + (1 - rho) V_MP/n)/K, against the part shared, rho V_MP/n, is least for
    the work: 36 camera paths at rho = 0.2, where a balance that took the photon side as
    shared (rho = 1, the model before) stops at 16."""
    v_c, v_mp, camera_work, segments, alpha, n = 0.02, 50.0, 3000.0, 3.0, 2.0 / 3.0, 20000
    for rho in (0.2, 1.0):
        shared = rho * v_mp
        divided = v_c + (1.0 - rho) * v_mp / n
        best = n / math.sqrt(alpha * camera_work / segments * shared / divided)
        balance, k, last_k = EffortBalance(1000, n, alpha), 1, None
        for _ in range(30):
            v_p = v_mp * (rho + (1.0 - rho) / k)            # the pixel's, per photon, at this K
            v_p_last = v_mp * (rho + (1.0 - rho) / (last_k or k))
            spread = v_c * (1 / k + 1 / (last_k or k)) + (v_p + v_p_last) / n
            balance.observe(n, spread, v_p, 1.0, camera_work * k, segments * n, camera_paths=k,
                            half_difference_mp=v_mp)
            last_k, k = k, balance.next_camera_paths(n, 64)
        assert balance.photon_correlation() == pytest.approx(rho)
        assert abs(k - best) <= 1, (rho, best, k)
    assert EffortBalance(1000, n, alpha).photon_correlation() is None     # K = 1 says nothing of rho


def test_measurement_points_share_their_photon_noise_as_their_discs_overlap():
    """The sppm kernel's per-point even-odd differences (half_difference_mp): four points per
    pixel with discs of eight pixels' radius gather nearly the same photons (rho near 1); with
    discs of a quarter of a pixel they gather different ones (rho small). The Cornell box at
    16x16, the radii held (alpha near 1)."""
    rho = {}
    for radius_pixels in (8.0, 0.25):
        p = Job(scene=str(SCENES / "cornell-box" / "scene.xml"), params={"res": "16"}, method="sppm", seed=4,
                options={"photons": 4096, "alpha": 0.999, "radius_rule": "progressive", "camera_paths": 4,
                         "radius_pixels": radius_pixels}).prepare()
        try:
            for _ in range(30):
                p.method.iterate()
            rho[radius_pixels] = p.method.effort.photon_correlation()
        finally:
            p.release()
    assert rho[8.0] > 0.8 and rho[0.25] < 0.3, rho


@pytest.mark.parametrize("var_a,var_b,cov,share", [
    (1.0, 3.0, 0.0, 0.75),       # independent: inverse-variance weights
    (1.0, 1e6, 0.0, 1.0 - 1e-6),  # B useless
    (4.0, 1.0, 1.0, 0.0),        # B as good as A can make it: (Var B - Cov) = 0
    (4.0, 1.0, 2.0, 0.0),        # the optimum lies beyond B (w < 0): clamped
    (2.0, 3.0, 1.0, 2.0 / 3.0),  # correlated: (3 - 1) / (2 + 3 - 2)
    (1.0, 4.0, 1.5, 1.0),        # the optimum lies beyond A: clamped
])
def test_least_variance_share_of_two_estimates(var_a, var_b, cov, share):
    """mbe's weight of the uniform proposals' estimate against the chains' (methods/mbe.py):
    the w minimising Var(w A + (1 - w) B), clamped to [0, 1]; at it the combination is never
    worse than either estimate alone."""
    w = least_variance_share(var_a, var_b, cov)
    assert w == pytest.approx(share, abs=1e-9)
    combined = w * w * var_a + (1 - w) ** 2 * var_b + 2 * w * (1 - w) * cov
    assert combined <= min(var_a, var_b) + 1e-12
    for other in (0.0, 0.25, 0.5, 0.9, 1.0):          # and no other weight does better
        assert combined <= other ** 2 * var_a + (1 - other) ** 2 * var_b + 2 * other * (1 - other) * cov + 1e-12


def test_least_variance_share_of_indistinguishable_estimates_is_undefined():
    """Var(A - B) = 0: no weight is better than another, so the caller keeps its last one."""
    assert least_variance_share(2.0, 2.0, 2.0) is None
    assert least_variance_share(0.0, 0.0, 0.0) is None


def test_untrimmed_camera_variance_keeps_a_rare_event():
    """Consecutive iterations whose camera variance is 1e-3 (spread 2e-3 at one camera path
    each), and once in 300 iterations a spread 100x that (a camera path that finds a small
    lamp through glass): the trimmed estimate (the photon
    methods') leaves the event out, and forgets it after HISTORY iterations anyway; the
    untrimmed one (mbe's) is the plain mean of every estimate since the start, the event
    included, which is the variance the image's error shows (docs/mbe.md)."""
    spreads = [2e-3] * 300
    spreads[40] = 0.2
    trimmed, plain = EffortBalance(16, 100, 0.75), EffortBalance(16, 100, 0.75, trim_camera=False)
    for b in (trimmed, plain):
        for spread in spreads:
            b.observe(100, spread, 0.0, 1.0, 500, 300)
    assert trimmed.shares()[0] == pytest.approx(1e-3)
    assert plain.shares()[0] == pytest.approx(sum(spreads[1:]) / 2 / 299)      # the first has no predecessor
    assert plain.shares()[0] > 1.3e-3


def test_no_photon_seen_holds_photons_and_no_camera_error_raises_them():
    b = EffortBalance(100, 100, 0.7)
    for _ in range(3):
        b.observe(b.photons, 1.0, 0.0, 1.0, 500, 300)
        b.next_photons()
    assert b.photons == 100
    b = EffortBalance(100, 100, 0.7)
    for _ in range(3):
        b.observe(b.photons, 0.0, 1.0, 1.0, 500, 300)
        b.next_photons()
    assert b.photons > 100
    assert b.photons <= 64 * 100


def _estimates(params: dict, photons: int, iterations: int, seed: int, camera_paths: int = 1,
               pixel_samples: str = "independent"):
    # alpha near 1: the radii stay put, so V_p does not change with the photon count.
    job = Job(scene=str(SCENES / params.pop("scene") / "scene.xml"), params=params, method="sppm", seed=seed,
              options={"photons": photons, "alpha": 0.999, "radius_rule": "progressive",
                       "camera_paths": camera_paths,
                       "pixel_samples": pixel_samples})
    return shares_after(job.prepare(), iterations)


def shares_after(p, iterations: int):
    """(V_c, V_p) of a prepared render's effort balance after `iterations` (then released)."""
    try:
        for _ in range(iterations):
            p.method.iterate()
        return p.method.effort.shares()
    finally:
        p.release()


def test_split_estimates_agree_across_photon_counts():
    """The two variance estimates do not depend on the photon count they were measured at.
    Cornell box (camera error dominant): V_c and V_p at 64 and 4096 photons per pass agree.
    Gap-lit close-up (photons scarce, ~0.2 % visible): V_p at 64 photons, where most passes
    deposit nothing, agrees with V_p at 4096."""
    cornell = {"scene": "cornell-box", "res": "16"}
    few, many = _estimates(dict(cornell), 64, 300, 1), _estimates(dict(cornell), 4096, 300, 2)
    closeup = {"scene": "light-gap", "res": "16", "fov": "12", "target": "-1.1,0.4,-0.6"}
    scarce_few, scarce_many = _estimates(dict(closeup), 64, 300, 3), _estimates(dict(closeup), 4096, 300, 4)
    print(f"cornell V_c, V_p at 64 photons {few}, at 4096 {many}; close-up at 64 {scarce_few}, at 4096 {scarce_many}")
    assert few[0] == pytest.approx(many[0], rel=0.3)
    assert few[1] == pytest.approx(many[1], rel=0.3)
    assert scarce_few[1] == pytest.approx(scarce_many[1], rel=0.3)
    assert scarce_many[0] > 0


@pytest.mark.parametrize("pixel_samples", ["independent", "sobol"])
def test_camera_variance_is_per_camera_path_whatever_their_number(pixel_samples):
    """With K independent camera paths per pixel the camera side's variance per iteration is
    V_c / K, and the balance's estimate, which divides that out, agrees at K = 1 and K = 4 on
    the Cornell box (camera error dominant). With stratified pixel positions a pass's K
    samples are K consecutive points of a scrambled Sobol' sequence (kernels/pixel_samples.py),
    so the pass varies less than V_c / K and the estimate per path at K = 4 is below K = 1's
    (measured 0.67x): the balance reads the camera side at the K it runs."""
    cornell = {"scene": "cornell-box", "res": "16"}
    one = _estimates(dict(cornell), 1024, 300, 5, pixel_samples=pixel_samples)
    four = _estimates(dict(cornell), 1024, 300, 6, camera_paths=4, pixel_samples=pixel_samples)
    print(f"cornell V_c, V_p with 1 camera path per pixel {one}, with 4 {four}")
    if pixel_samples == "independent":
        assert four[0] == pytest.approx(one[0], rel=0.3)
    else:
        assert four[0] < 0.85 * one[0]


def test_balanced_sppm_gives_photons_to_a_photon_starved_view():
    """On the gap-lit close-up `--photons auto` raises the photons per pass far above one per
    pixel; with a number it keeps them. (With V_c from consecutive passes it ran to the cap of
    64 per pixel within 40 passes: the photons' part subtracted from their spread left V_c
    negative. Twin camera paths read the direct light through the gap, about 1.7e-4 at
    16x16, and the balance climbs more slowly, toward about 10 per pixel: 6.4 after 30
    passes, 10 after 80; docs/effort.md, "Twin camera paths".)"""
    from photonmc.loop import prepare
    from photonmc.scene import load_scene
    scene = load_scene(SCENES / "light-gap" / "scene.xml", {"res": 16, "fov": 12, "target": "-1.1,0.4,-0.6"})
    p = prepare(scene, method="sppm", options={"photons": "auto"})
    for _ in range(80):
        p.method.iterate()
    assert p.method.photons_per_iteration >= 8 * 256
    assert p.method.stats()["effort"]["balanced"] is True
    p.release()
    p = prepare(scene, method="sppm", options={"photons": 256})
    for _ in range(30):
        p.method.iterate()
    assert p.method.photons_per_iteration == 256 and p.method.stats()["effort"]["balanced"] is False
    p.release()


def test_photons_auto_is_refused_where_it_does_not_apply():
    from photonmc.errors import SettingsError
    from photonmc.loop import prepare
    from photonmc.scene import load_scene
    scene = load_scene(SCENES / "cornell-box" / "scene.xml", {"res": 8})
    with pytest.raises(SettingsError, match="--photons auto is for sppm"):
        prepare(scene, method="visibility", options={"photons": "auto"})
    with pytest.raises(SettingsError, match="a number of photons or 'auto'"):
        prepare(scene, method="sppm", options={"photons": "many"})


def test_effort_bias_gives_photons_where_the_radius_bias_shows():
    """With effort_bias (an option, off by default) the balanced radius rule's probes tell sppm's
    balance the image's squared bias against its photon variance (effort.py, observe_bias). In
    the attic, where that bias is measured, it then picks more photons per pass than the
    balance without it; unknown values are refused."""
    from photonmc.errors import SettingsError
    from photonmc.loop import Budget, prepare, run
    from photonmc.scene import load_scene
    scene = load_scene(SCENES / "attic-slit" / "scene.xml", {"res": 16})
    effort = {}
    for on in (False, True):
        p = prepare(scene, method="sppm", seed=1, options={"photons": "auto", "effort_bias": on})
        try:
            effort[on] = run(p, Budget(iterations=200), quiet=True).stats["effort"]
        finally:
            p.release()
    assert effort[False]["bias_ratio"] == 0.0
    assert effort[True]["bias_ratio"] > 0.1
    assert effort[True]["photons_next_pass"] > 1.1 * effort[False]["photons_next_pass"], effort
    with pytest.raises(SettingsError, match="effort_bias must be true or false"):
        prepare(scene, method="sppm", options={"effort_bias": "yes"})


def test_relative_balance_weighs_each_pixel_by_its_running_estimate():
    """--balance relmse (sppm and the guided methods): the effort sums are each pixel's
    squared differences weighted by 1 / (m^2 + eps), m the pixel's running estimate and eps
    (0.1 x the image's mean)^2, recomputed here from the render's own fields."""
    import numpy as np
    from photonmc.errors import SettingsError
    from photonmc.loop import prepare
    from photonmc.scene import load_scene
    scene = load_scene(SCENES / "cornell-box" / "scene.xml", {"res": 16})
    with pytest.raises(SettingsError, match="--balance must be"):
        prepare(scene, method="sppm", options={"balance": "rel"})
    p = prepare(scene, method="sppm", options={"balance": "relmse", "photons": 512})
    m = p.method
    for _ in range(12):
        m.iterate()
    passes, photons = m.iterations, m.photons_emitted
    m._effort_sums(True, passes, photons)
    relative = m.effort_sums.to_numpy()[:2]
    lum = np.array([0.2126, 0.7152, 0.0722], np.float32).astype(np.float64)   # the kernel's f32 literals
    mean = (m.Ld.to_numpy() / passes + m.D.to_numpy() / photons) @ lum
    weight = 1.0 / (mean ** 2 + (float(np.float32(0.1)) * mean.mean()) ** 2)
    spread, half = m.spread.to_numpy(), m.half_difference.to_numpy()
    assert relative == pytest.approx([(weight * spread).sum(), (weight * half).sum()], rel=1e-9)
    m._effort_sums(False, passes, photons)
    assert m.effort_sums.to_numpy()[:2] == pytest.approx([spread.sum(), half.sum()], rel=1e-9)
    # the weights move the balance: the dim pixels count more than in the plain sums
    assert relative[0] / relative[1] != pytest.approx(spread.sum() / half.sum(), rel=1e-3)
    p.release()


def test_held_camera_balance_reads_the_twins_not_the_pairs():
    """A held_camera balance (twin camera paths, docs/effort.md) takes V_c from the estimates
    handed to it as camera_held, and none from a pass without one. The pairs' spread (the
    pixel positions' variance besides) enters only as what stratified positions leave of it
    after M camera paths per pixel, 1.5 V_pos M^-0.5, V_pos the pairs' mean less the twins'."""
    balance = EffortBalance(100, 100, 2.0 / 3.0, trim_camera=False, held_camera=True)
    balance.observe(100, 0.0, 1.0, 1.0, 1000.0, 300.0)
    balance.observe(100, 50.02, 1.0, 1.0, 1000.0, 300.0)                   # no twins: no V_c
    assert balance.shares() is None
    balance.observe(100, 50.02, 1.0, 1.0, 1000.0, 300.0, camera_held=0.02)
    balance.observe(100, 80.02, 1.0, 1.0, 1000.0, 300.0, camera_held=0.04)
    pairs = (25.0 + 25.0 + 40.0) / 3           # (spread - V_p (1/n + 1/n)) / (1/K + 1/K)
    assert balance.shares()[0] == pytest.approx(0.03 + 1.5 * (pairs - 0.03) / math.sqrt(4))
    for _ in range(9996):                      # M = 10,000 camera paths per pixel
        balance.observe(100, 50.02, 1.0, 1.0, 1000.0, 300.0, camera_held=0.03)
    assert balance.shares()[0] == pytest.approx(0.03 + 1.5 * (25.0 - 0.03) / 100, rel=1e-3)


def _sppm_cornell(options: dict, seed: int):
    return Job(scene=str(SCENES / "cornell-box" / "scene.xml"), params={"res": "16"}, method="sppm", seed=seed,
               options=options).prepare()


def test_twin_camera_paths_leave_the_measurement_points_alone():
    """A twin retraces its camera path from the same pixel position with other random numbers
    and writes no measurement point: the pass's MPs and direct light are the same with and
    without twins. On the Cornell box (diffuse walls, no glass) nearly every twin reaches its
    path's MP, and its direct light is another sample (other random numbers)."""
    import numpy as np
    p = _sppm_cornell({"photons": "auto"}, 3)
    m = p.method
    try:
        m.iterate()
        args = (m.seed_u32, 5, m.max_depth, m.initial_radius, m.radius_pixels * m.pixel_angle, 1, m.n_pixels, 7, 1)
        names = ("mp_p", "mp_n", "mp_W", "mp_direct", "mp_valid", "mp_depth", "mp_radius")
        m._camera_pass(*args, 0)
        alone = {f: getattr(m, f).to_numpy()[:m.n_pixels] for f in names}
        m._camera_pass(*args, 1)
        for f in names:
            np.testing.assert_array_equal(getattr(m, f).to_numpy()[:m.n_pixels], alone[f], err_msg=f)
        matched = m.mp_twin_matched.to_numpy()[:m.n_pixels]
        assert matched.mean() > 0.9, matched.mean()
        twin_direct = m.mp_twin_direct.to_numpy()[:m.n_pixels]
        assert not np.array_equal(twin_direct, alone["mp_direct"])
    finally:
        p.release()


def test_twins_take_the_pixel_positions_out_of_the_camera_variance():
    """Under stratified pixel positions (the default) sppm's balance reads V_c from twins: the
    positions held, plus what the positions' stratification leaves after 60 passes. On the
    Cornell box, where a pixel's estimate changes most with where in the pixel its path
    starts (the walls' and the lamp's edges), that is a small part of the consecutive passes'
    V_c (measured 0.12 against 0.61 at 16x16). With independent positions there are no
    twins, and the pairs stand."""
    held = _sppm_cornell({"photons": "auto"}, 4)
    pairs = _sppm_cornell({"photons": "auto", "camera_variance": "pairs"}, 4)
    v_held, v_pairs = shares_after(held, 60)[0], shares_after(pairs, 60)[0]
    print(f"cornell 16x16 V_c: twins {v_held:.4g}, pairs {v_pairs:.4g}")
    assert 0 < v_held < 0.25 * v_pairs
    independent = _sppm_cornell({"photons": "auto", "pixel_samples": "independent"}, 4)
    try:
        for _ in range(5):
            independent.method.iterate()
        effort = independent.method.stats()["effort"]
        assert effort["camera_variance_from"] == "pairs" and "twin_passes" not in effort
    finally:
        independent.release()


def test_guided_methods_keep_the_pairs_by_default():
    """visibility's and spatial-tf's K also sets how many measurement points their chains'
    targets can reach; with twins K fell, and the passes lengthened (the held-out light bay
    1.14x, the closet 0.89x; docs/effort.md), so they read V_c from consecutive passes unless
    --camera-variance asks otherwise, and then they trace twins."""
    for options, expected in (({}, "pairs"), ({"camera_variance": "twins"}, "twins")):
        p = Job(scene=str(SCENES / "cornell-box" / "scene.xml"), params={"res": "16"}, method="visibility", seed=1,
                options=options).prepare()
        try:
            for _ in range(3):
                p.method.iterate()
            effort = p.method.stats()["effort"]
            assert effort["camera_variance_from"] == expected
            assert effort.get("twin_passes", 0) == (2 if expected == "twins" else 0)
        finally:
            p.release()


def test_guided_camera_variance_auto_follows_what_sets_the_pass_length():
    """--camera-variance auto (an option of the guided methods) traces twins and reads V_c
    from them where a pass is its photon floor, so that K does not move its length, and from
    consecutive passes where the chains' regeneration set it (docs/effort.md, "Twins where K
    does not set the pass length"): the attic at 16x16 (photons scarce, every pass past the
    first set by the regeneration) renders bit for bit as with pairs, the Cornell box (over
    half of the photons deposit, passes at the floor) as with twins."""
    def render(scene, options):
        p = Job(scene=str(SCENES / scene / "scene.xml"), params={"res": "16"}, method="visibility", seed=2,
                options=options).prepare()
        try:
            for _ in range(40):
                p.method.iterate()
            return p.method.image(), p.method.stats()["effort"], p.method.camera_paths
        finally:
            p.release()

    for scene, same_as, other in (("attic-slit", "pairs", "twins"), ("cornell-box", "twins", "pairs")):
        auto, effort, k = render(scene, {"camera_variance": "auto"})
        assert effort["camera_variance_from"] == "auto" and effort["twin_passes"] > 0
        same, _, _ = render(scene, {"camera_variance": same_as})
        different, _, k_other = render(scene, {"camera_variance": other})
        assert np.array_equal(auto, same), scene
        assert not np.array_equal(auto, different) and k != k_other, (scene, k, k_other)


def test_twins_variances_are_trimmed_where_they_steer_k():
    """sppm keeps the plain mean of the twins' V_c (rare camera paths through glass are error
    its photons cannot remove); the guided methods, whose K the twins steer, trim them as the
    pairs' are (a plain mean raised the caustic's K and lost it: docs/effort.md, stop 55)."""
    for method, trimmed in (("sppm", False), ("visibility", True), ("spatial-tf", True)):
        p = Job(scene=str(SCENES / "cornell-box" / "scene.xml"), params={"res": "8"}, method=method, seed=1,
                options={"camera_variance": "auto", **({"photons": "auto"} if method == "sppm" else {})}).prepare()
        try:
            assert p.method.effort.held_camera and p.method.effort.trim_camera == trimmed, method
        finally:
            p.release()


def test_film_variance_follows_the_twins_model():
    """The model behind the twins' V_c (docs/effort.md, "Twin camera paths"): under stratified
    positions the film's variance over seeds after M passes is V_held / M + c V_pos M^-1.5
    with c near 1 (V_held the twins' V_c, V_pos the consecutive passes' less the twins'), far
    below the V_pos / M that the pairs' V_c alone implies. Cornell box at 16x16, radii held,
    8 seeds (tools/position_variance.py does the same at any size): c = 1.08 at M = 8 and 0.86
    at M = 32."""
    import numpy as np
    luminance = np.array([0.2126, 0.7152, 0.0722])
    marks, films, held, pairs = (8, 32), {8: [], 32: []}, [], []
    for seed in range(8):
        p = _sppm_cornell({"photons": 4096, "alpha": 0.999, "radius_rule": "progressive"}, seed)
        m = p.method
        try:
            m.held_camera = True              # twins although nothing steers by them
            m.effort = m._new_effort()
            for it in range(1, marks[-1] + 1):
                m.iterate()
                if it in films:
                    films[it].append(m.image() @ luminance)
            held.append(m.effort.camera_sum / m.effort.samples)
            pairs.append(m.effort.pair_sum / m.effort.pair_samples)
        finally:
            p.release()
    v_held, v_pos = np.mean(held), np.mean(pairs) - np.mean(held)
    assert v_pos > 20 * v_held                # the positions dominate the pairs here
    for mark in marks:
        film = np.var(np.array(films[mark]), axis=0, ddof=1).mean()
        c = (film - v_held / mark) / (v_pos * mark ** -1.5)
        print(f"M = {mark}: film variance {film:.4g}, c = {c:.3g}, pairs' model {v_pos / mark:.4g}")
        assert 0.5 < c < 2.0
        assert film < 0.4 * v_pos / mark


def _observe_chain_passes(balance, n, k, v_c, v_p, rays, deposits_per_path_photon, shared=0.0, passes=12):
    """Passes of n photons and k camera paths per pixel, observed exactly from
    V = V_c/k + V_p/n + shared (shared: the variance both photon halves share), deposits
    growing as k x n."""
    for _ in range(passes):
        spread = 2 * v_c / k + 2 * v_p / n + 2 * shared
        balance.observe(n, spread, v_p, 1.0, rays * k, 3.0 * n, camera_paths=k,
                        deposits=deposits_per_path_photon * k * n, shared_variance=shared)


def test_shared_photon_variance_is_not_read_as_camera_variance():
    """The guided passes' normalisation is shared by both photon halves: consecutive passes see
    it and the even-odd difference does not. Given to observe(), it is left out of V_c."""
    balance = EffortBalance(1000, 10000, 2.0 / 3.0)
    _observe_chain_passes(balance, 10000, 8, v_c=0.02, v_p=5.0, rays=100.0, deposits_per_path_photon=0.0,
                          shared=0.001)
    assert balance.shares()[0] == pytest.approx(0.02)
    assert balance.shared_variances[-1] == pytest.approx(0.001 * 10000)


def test_guided_pass_length_follows_the_camera_side_and_its_deposits():
    """EffortBalance.chain_pass_length on known models (V = V_c/K + V_p/n + shared, K within 2x
    of the pass's): where the camera side wants more camera paths than a pass may have (64),
    the shortest pass wins; where it carries no error, the longest (it loses the fewest steps
    to the chains' start); where K is free, the longest unless a camera path's work is mostly
    the deposits a pass's photons make into its points (growing with the pass); a noisy
    normalisation (the shared variance), or chains that record little of a short pass, pull
    the choice back from the shortest; and it shortens only where it expects at most
    PASS_LENGTH_MARGIN of the longest pass's error."""
    lengths = np.geomspace(20000, 200000, 24).astype(np.int64)
    ones = np.ones(len(lengths))
    n = 200000

    def choose(v_c, k=64, shared=0.0, efficiency=ones, deposits=5e-4):
        balance = EffortBalance(4096, 4096, 2.0 / 3.0)
        _observe_chain_passes(balance, n, k, v_c, v_p=20.0, rays=9000.0, deposits_per_path_photon=deposits,
                              shared=shared / n)
        return balance.chain_pass_length(lengths, efficiency, 1.0, n, k, 64), balance.pass_length_gain

    length, gain = choose(v_c=0.1)                   # K wanted: 300
    assert length == lengths[0] and gain <= PASS_LENGTH_MARGIN
    assert choose(v_c=0.0)[0] == lengths[-1]
    # K wanted about 8-30, free within [8, 32]: deposits decide
    length, gain = choose(v_c=0.001, k=16, deposits=0.0)
    assert length == lengths[-1] and gain == pytest.approx(1.0, abs=1e-3)
    length, gain = choose(v_c=0.001, k=16, deposits=0.5)
    assert length < lengths[-1] and gain <= PASS_LENGTH_MARGIN
    assert choose(v_c=0.1, efficiency=lengths / lengths[-1])[0] > lengths[0]
    assert lengths[0] < choose(v_c=0.1, shared=20.0)[0] < lengths[-1]
    length, gain = choose(v_c=0.1, shared=50.0)
    assert length == lengths[-1] and PASS_LENGTH_MARGIN < gain < 1.0, gain
    # Without deposits a camera path's work does not grow with the pass, and where K = n / n*
    # is free (n* = 25,000 here, K from 4 to 8 within [8 / 2, 8 x 2]) it keeps the split at
    # every length: the one whose chains lose the least of it wins.
    free = EffortBalance(4096, 4096, 2.0 / 3.0)
    _observe_chain_passes(free, n, 8, 2.0 / 3.0 * 3000.0 * 20.0 / 25000.0 ** 2, 20.0, 9000.0, 0.0)
    longer = np.geomspace(100000, 200000, 12).astype(np.int64)
    share = 1.0 - (1.0 - np.exp(-longer / 20000.0)) / (longer / 20000.0)     # guided.recorded_share
    assert free.chain_pass_length(longer, share, share[-1], n, 8, 64) == longer[-1]


def test_camera_variance_weighs_each_pair_by_its_photon_noise():
    """A pair of short passes, where the photon noise dwarfs the camera side, says next to
    nothing about V_c: the estimate weighs each pair by the inverse square of its expected
    spread (docs/guiding.md, "A first pair that hid the camera side"). On an exact model with
    chi-square noise, passes of 4,096 and 8,192 photons then about 10^6 (a scarce room's guided
    passes): the weighted V_c is near the true one in every render and unbiased over renders,
    where the plain mean of the same pairs is ruled by the first one (negative in most renders)."""
    v_c, v_p, rng = 1e-5, 5.0, np.random.default_rng(7)
    weighted, plain = [], []
    for _ in range(200):
        balance, last = EffortBalance(1000, 4096, 2.0 / 3.0), None
        pairs = []
        for n in [4096, 8192] + [int(x) for x in rng.uniform(3e5, 2e6, 10)]:
            expected = 2 * v_c + v_p * (1 / n + 1 / (last or n))
            spread = expected * rng.chisquare(1)       # one pixel's squared difference: chi-square
            pair = balance.observe(n, spread, v_p, 1.0, 3000.0, 8.0 * n)
            if pair is not None:
                pairs.append(pair)
            last = n
        weighted.append(balance.shares()[0])
        plain.append(np.mean(pairs))
    weighted, plain = np.array(weighted), np.array(plain)
    assert abs(weighted.mean() / v_c - 1) < 0.15, weighted.mean()
    assert np.mean(weighted > 0) > 0.9
    assert np.mean(plain < 0) > 0.4                  # what the plain mean made of the same pairs
    assert weighted.std() < 0.1 * plain.std()


def test_camera_variance_weights_leave_camera_paths_out():
    """Pairs of equal photon counts weigh alike whatever their K: V_c per camera path falls as
    K grows (a pixel's K points are a net), and weights with K in them would count the many-K
    pairs less and so raise V_c (docs/guiding.md, "A first pair that hid the camera side")."""
    balance, rng, pairs = EffortBalance(1000, 4096, 2.0 / 3.0), np.random.default_rng(3), []
    for i in range(40):
        k = 1 + i % 8
        pair = balance.observe(4096, rng.uniform(1e-5, 1e-4), 0.02, 1.0, 3000.0 * k, 8.0 * 4096, camera_paths=k)
        if pair is not None:
            pairs.append(pair)
    kept = sorted(pairs)[:len(pairs) - len(pairs) // 32]
    assert balance.shares()[0] == pytest.approx(np.mean(kept), rel=1e-9)

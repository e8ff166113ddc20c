"""SPPM: the hash grid, the two update forms, convergence, and numerical extremes."""
import numpy as np
import pytest
import taichi as ti

from photonmc import load_scene
from photonmc.errors import SettingsError
from photonmc.imageio import read_image, read_metadata
from photonmc.kernels.fields import FieldGroup
from photonmc.kernels.hashgrid import HashGrid
from photonmc.metrics import downsample, luminance, mean_luminance
from photonmc.loop import Budget, prepare, run

from .conftest import (REFS, SCENE_REFERENCES, SCENES, assert_image_follows_the_units, camera_xml,
                       scaled_box_scene)
from .test_pt import furnace_expectation, furnace_xml


def render(scene, iterations, seed=0, **options):
    p = prepare(scene, method="sppm", seed=seed, options=options)
    r = run(p, Budget(iterations=iterations), quiet=True)
    p.release()
    return r


@ti.kernel
def query_all(grid: ti.template(), pos: ti.template(), rad: ti.template(), valid: ti.template(),
              x: ti.types.ndarray(dtype=ti.math.vec3, ndim=1), hits: ti.types.ndarray(dtype=ti.i32, ndim=2)):
    for q in range(x.shape[0]):
        first, end = grid.candidates(x[q])
        for e in range(first, end):
            j = grid.entries[e]
            if valid[j] and (x[q] - pos[j]).norm_sqr() <= rad[j] * rad[j]:
                hits[q, j] += 1


@pytest.mark.parametrize("n", [20, 2000])
def test_hash_grid_matches_brute_force(n):
    """With 20 points the table has 64 slots, so one point's 8 cells often share a slot."""
    rng = np.random.default_rng(4)
    p = rng.uniform(-3, 3, (n, 3)).astype(np.float32)
    r = rng.uniform(0.01, 0.4, n).astype(np.float32)
    v = (rng.random(n) < 0.9).astype(np.int32)
    f = FieldGroup("test-points")
    pos, rad, valid = f.vector(3, ti.f32, n, p), f.scalar(ti.f32, n, r), f.scalar(ti.i32, n, v)
    f.finalize()
    grid = HashGrid(n)
    grid.build(pos, rad, valid)
    near = p[rng.integers(0, n, 500)]
    x = np.concatenate([rng.uniform(-3.5, 3.5, (3000, 3)), near + rng.normal(size=(500, 3)) * 0.1]).astype(np.float32)
    hits = np.zeros((len(x), n), np.int32)
    query_all(grid, pos, rad, valid, x, hits)
    d2 = ((x[:, None, :] - p[None]) ** 2).sum(-1)
    expected = (d2 <= r[None] ** 2) & (v[None] == 1)
    # float32 boundary cases aside, the grid finds exactly the balls that contain each point,
    # each exactly once (a point listed twice under one hash slot would be deposited twice)
    boundary = np.abs(d2 - r[None] ** 2) < 1e-5
    assert hits.max() == 1
    assert np.array_equal(hits.astype(bool) | boundary, expected | boundary)
    assert expected.sum() > (30 if n == 20 else 1000)
    grid.release()
    f.release()


def test_d_form_and_tau_form_give_the_same_image():
    """Algebraically identical (algorithms.md §1.3); compared in float64, before output rounding."""
    scene = load_scene(SCENES / "cornell-box" / "scene.xml", {"res": 24})
    images = []
    for tau in (False, True):
        p = prepare(scene, method="sppm", seed=1, options={"tau_form": tau})
        run(p, Budget(iterations=30), quiet=True)
        images.append(p.method.image())
        p.release()
    assert images[0].mean() > 0
    np.testing.assert_allclose(images[0], images[1], rtol=1e-10, atol=1e-14)


def test_seed_determinism_with_atomics():
    scene = load_scene(SCENES / "cornell-box" / "scene.xml", {"res": 24})
    a = render(scene, 5, seed=3).image
    b = render(scene, 5, seed=3).image
    assert np.array_equal(a, b)


@pytest.mark.parametrize("depth", [3, -1])
def test_sphere_furnace(write_scene, depth):
    """Inside an emitting diffuse sphere the photon density is uniform, so SPPM's density
    estimate has no blur bias there: the analytic answer holds within noise."""
    scene = load_scene(write_scene(furnace_xml("sphere")))
    p = prepare(scene, method="sppm", max_depth=depth, options={"photons": 4096})
    r = run(p, Budget(iterations=200), quiet=True)
    p.release()
    lum = luminance(r.image)
    expected = furnace_expectation(depth)
    spread = lum.std()
    assert abs(lum.mean() - expected) < 5 * spread / np.sqrt(lum.size) + 0.002 * expected, lum.mean()
    assert np.abs(lum - expected).max() < 6 * spread


def test_several_camera_paths_per_pass(write_scene):
    """K camera paths per pixel share each photon pass (docs/effort.md): in the furnace the
    answer stays the analytic one, and the radius shrinks with photons per point, not with K.
    (The pixels' spread barely falls there: the K points of a pixel gather nearly the same
    photons, and the furnace's error is photon-side; the camera side's 1/K is tested in
    test_effort.py.)"""
    scene = load_scene(write_scene(furnace_xml("sphere")))
    expected = furnace_expectation(3)
    radius = {}
    for k in (1, 4):
        p = prepare(scene, method="sppm", max_depth=3, options={"photons": 4096, "camera_paths": k})
        r = run(p, Budget(iterations=60), quiet=True)
        p.release()
        lum = luminance(r.image)
        assert abs(lum.mean() - expected) < 5 * lum.std() / np.sqrt(lum.size) + 0.002 * expected, (k, lum.mean())
        assert r.stats["camera_paths_per_pixel"] == k
        radius[k] = r.stats["mean_radius"]
    assert radius[4] == pytest.approx(radius[1], rel=0.1)


# Largest acceptable log-log slope of RMSE against iterations. On the smooth Cornell box the
# error is variance-dominated (about -0.5 early, -1/3 asymptotically for alpha = 2/3). At the
# caustic's sharp edges density-estimation bias is proportional to R, which shrinks as
# N^(-(1-alpha)/2) = N^(-1/6): the slope there tends to -1/6 (measured -0.23).
MAX_SLOPE = {"cornell-box": -0.3, "caustic": -0.15}


@pytest.mark.parametrize("name", sorted(MAX_SLOPE))
def test_error_falls_and_converges_to_mitsuba(name):
    """SPPM is consistent: its error against the Mitsuba reference falls with iterations
    (slope measured and printed), and it ends within 1 % in mean luminance."""
    ref_path = REFS / f"{name}-64.exr"
    ref = read_image(ref_path)
    scene = load_scene(SCENES / name / "scene.xml", {"res": 64})
    p = prepare(scene, method="sppm", seed=2)
    checkpoints, errors = (25, 100, 400), []

    def record(method, iteration, elapsed):
        if iteration in checkpoints:
            errors.append(np.sqrt(np.mean((luminance(method.image()) - luminance(ref)) ** 2)))

    r = run(p, Budget(iterations=checkpoints[-1]), quiet=True, on_iteration=record)
    p.release()
    slope = np.polyfit(np.log(checkpoints), np.log(errors), 1)[0]
    print(f"sppm {name} RMSE {np.round(errors, 5).tolist()} at {checkpoints} iterations: slope {slope:.3f}")
    assert errors[0] > errors[1] > errors[2]
    assert slope < MAX_SLOPE[name]
    assert abs(mean_luminance(r.image) / mean_luminance(ref) - 1) < 0.01
    assert int(read_metadata(ref_path)["spp"]) >= 16384


def test_scene_scale_and_light_power_extremes(write_scene):
    assert_image_follows_the_units(lambda scene: render(scene, 40, seed=5).image, write_scene)


def test_many_iterations_on_a_tiny_image(write_scene):
    """10^4 iterations: radii keep shrinking without underflow, no NaN reaches the image."""
    scene = scaled_box_scene(write_scene)
    p = prepare(scene, method="sppm", seed=1, options={"photons": 64})
    r = run(p, Budget(iterations=10_000), quiet=True)
    radius = p.method.R.to_numpy()
    p.release()
    assert np.isfinite(r.image).all() and r.image.mean() > 0
    assert np.all(radius[radius > 0] > 0) and np.isfinite(radius).all()
    assert r.stats["nonfinite_samples_dropped"] == 0 and r.stats["nonfinite_pixels_zeroed"] == 0


def test_one_photon_per_iteration_and_iterations_without_deposits(write_scene):
    scene = scaled_box_scene(write_scene)
    r = render(scene, 50, photons=1)
    assert np.isfinite(r.image).all()
    # Most single-photon iterations deposit nothing into a 12x12 image's few MPs.
    assert r.stats["fraction_of_photon_paths_depositing"] < 1.0
    assert r.stats["photons_emitted"] == 50


@pytest.mark.parametrize("options,message", [
    ({"photons": 0}, "--photons"), ({"alpha": 1.5}, "--alpha"), ({"radius": -1.0}, "--radius"),
    ({"camera_paths": 0}, "--camera-paths must be a number from 1 to 64 or 'auto'"),
    ({"camera_paths": 65}, "--camera-paths"), ({"camera_paths": "many"}, "--camera-paths"),
    ({"radius_rule": "smallest"}, "--radius-rule must be one of progressive, balanced, got 'smallest'"),
])
def test_bad_options(options, message):
    scene = load_scene(SCENES / "cornell-box" / "scene.xml", {"res": 8})
    with pytest.raises(SettingsError, match=message):
        prepare(scene, method="sppm", options=options)


def test_pt_rejects_photon_options():
    scene = load_scene(SCENES / "cornell-box" / "scene.xml", {"res": 8})
    with pytest.raises(SettingsError, match="does not take --photons"):
        prepare(scene, method="pt", options={"photons": 10})


@pytest.mark.convergence
@pytest.mark.parametrize("name,ref_file,params", SCENE_REFERENCES, ids=[r[0] for r in SCENE_REFERENCES])
def test_sppm_matches_mitsuba_on_every_bundled_scene(name, ref_file, params):
    """Mean luminance within 1 % of Mitsuba's path-traced reference after 400 iterations
    (one photon path per pixel each). Per-pixel agreement depends on the remaining radius
    (blur at caustic edges) and is recorded in docs/convergence.md rather than bounded here."""
    ref = read_image(REFS / ref_file)
    scene = load_scene(SCENES / name / "scene.xml", params)
    img = render(scene, 400, seed=1).image
    bias = mean_luminance(img) / mean_luminance(ref) - 1
    print(f"sppm {name}: mean-luminance bias {100 * bias:+.2f} %")
    assert abs(bias) < 0.01


@pytest.mark.convergence
def test_sppm_boundary_bias_shrinks_on_the_light_gap():
    """The gap scene's light arrives on narrow surfaces (the slit's 10 cm inner faces) lit at
    grazing angles; gather discs that overhang them find too few photons, so SPPM starts
    several % dark there (boundary bias, algorithms.md §10). It must shrink as radii do:
    measured -8.6 % at 12, -6.4 % at 292, -3.7 % at 3200 iterations (64x64, docs/convergence.md).
    Tested: the bias at 800 iterations is smaller than at 50 and under 6 %."""
    ref = read_image(REFS / "light-gap-64.exr")
    scene = load_scene(SCENES / "light-gap" / "scene.xml", {"res": 64})
    p = prepare(scene, method="sppm", seed=1)
    biases = {}

    def record(method, iteration, elapsed):
        if iteration in (50, 800):
            biases[iteration] = mean_luminance(method.image()) / mean_luminance(ref) - 1

    run(p, Budget(iterations=800), quiet=True, on_iteration=record)
    p.release()
    print(f"sppm light-gap bias: {biases}")
    assert abs(biases[800]) < abs(biases[50])
    assert abs(biases[800]) < 0.06


def test_balanced_radius_rule_leaves_an_unbiased_furnace_alone(write_scene):
    """In the furnace the photon density is uniform, so the inner and outer discs agree: the
    balanced radius rule (docs/guiding.md, "A radius that balances its bias against the noise")
    finds no bias, shrinks faster in (nearly) no pass, and the answer stays the analytic one.
    Its test asks the summed squared bias to exceed the balance by three standard errors of
    that sum, which noise alone does in at most about 1 pass in 700 (0 of 120 measured); without the
    guard about 1 pass in 12 would (from the sum's spread), and a rule that took noise for
    bias most would."""
    scene = load_scene(write_scene(furnace_xml("sphere")))
    expected = furnace_expectation(3)
    p = prepare(scene, method="sppm", max_depth=3, options={"photons": 4096, "radius_rule": "balanced"})
    r = run(p, Budget(iterations=120), quiet=True)
    p.release()
    lum = luminance(r.image)
    assert abs(lum.mean() - expected) < 5 * lum.std() / np.sqrt(lum.size) + 0.002 * expected, lum.mean()
    print(f"furnace: {r.stats['passes_shrunk_fast']} of 120 passes shrank faster")
    assert r.stats["radius_rule"] == "balanced"
    assert r.stats["passes_shrunk_fast"] <= 2


@pytest.mark.convergence
def test_balanced_radius_rule_shrinks_where_the_bias_dominates():
    """The attic room's brightest pixels are its slit's 10 cm inner face, seen edge-on, where
    the gather discs overhang the face: there the photon estimate's bias, not its noise, is
    most of the error once photons are plentiful (docs/guiding.md). With 8 photons per pixel
    per pass the balanced rule must find that bias, shrink faster in part of the passes and
    end with smaller radii than the progressive rule at the same iterations. (Whether that
    lowers the error is measured, not asserted: at these radii it moved the band from +3 %
    to -1.5 % and raised the RMSE 7 %; docs/guiding.md.)"""
    scene = load_scene(SCENES / "attic-slit" / "scene.xml", {"res": 64})
    radius, fast = {}, {}
    for rule in ("progressive", "balanced"):
        p = prepare(scene, method="sppm", seed=1, options={"radius_rule": rule, "photons": 32768})
        r = run(p, Budget(iterations=300), quiet=True)
        p.release()
        assert np.isfinite(r.image).all()
        radius[rule] = r.stats["mean_radius"]
        fast[rule] = r.stats.get("passes_shrunk_fast")
    print(f"attic, 300 iterations: mean radius {radius}, passes shrunk faster {fast}")
    assert fast["progressive"] is None
    assert fast["balanced"] >= 25
    assert radius["balanced"] < 0.95 * radius["progressive"]


def test_balanced_radius_rule_weighs_each_pixels_history():
    """The rule's sums (Sppm._balance_radius_sums) weigh each pixel's bias by rho_b = R^2 /
    mean(R_t^2) and its variance by rho_v = R^-2 / mean(R_t^-2) (docs/guiding.md, "The
    balanced radius with the history's ratios"). Given passes measured at twice today's radius,
    the same bias and noise sums must be scaled by 1/4 and 4, and the rule must then not fire
    where it fires without that history."""
    from photonmc.methods.merge_radius import bias_outweighs_noise

    scene = load_scene(SCENES / "cornell-box" / "scene.xml", {"res": 8})
    p = prepare(scene, method="sppm", options={"radius_rule": "balanced"})
    m = p.method
    try:
        n_pix, passes, r = m.n_pixels, 20.0, 0.05
        rng = np.random.default_rng(0)
        mean_d = rng.uniform(0.5, 1.5, n_pix)
        var_d = rng.uniform(0.01, 0.02, n_pix)
        m.bias_passes.from_numpy(np.full(n_pix, passes))
        m.bias_sum.from_numpy(passes * mean_d)
        m.bias_sq.from_numpy(passes * (mean_d ** 2 + var_d * (passes - 1.0) / passes))
        m.R.from_numpy(np.full(n_pix, r))
        se_sq = var_d / passes
        bias_sq, variance, spread = 4.0 * (mean_d ** 2 - se_sq), se_sq, 32.0 * se_sq ** 2
        sums = {}
        for history in (r, 2.0 * r):
            m.bias_radius_sq.from_numpy(np.full(n_pix, passes * history ** 2))
            m.bias_inverse_radius_sq.from_numpy(np.full(n_pix, passes / history ** 2))
            sums[history] = np.array(m._balance_radius_sums())
        rho_b, rho_v = 0.25, 4.0
        image = [bias_sq.sum(), variance.sum(), spread.sum()]
        np.testing.assert_allclose(sums[r], image + image, rtol=1e-9)
        # The last three (for the effort balance) are the passes at today's radius: the bias
        # by rho_b^2, its spread by rho_b^4.
        np.testing.assert_allclose(sums[2.0 * r], [rho_b * bias_sq.sum(), rho_v * variance.sum(),
                                                   rho_b ** 2 * spread.sum(), rho_b ** 2 * bias_sq.sum(),
                                                   rho_v * variance.sum(), rho_b ** 4 * spread.sum()], rtol=1e-9)
        # With the noise scaled up, the bias term (about 280) exceeds half the noise term (about
        # 120) without history, and not once the wider passes are weighed in (70 against 480).
        assert bias_outweighs_noise(*(sums[r][:3] * [1.0, 5000.0, 1.0]))
        assert not bias_outweighs_noise(*(sums[2.0 * r][:3] * [1.0, 5000.0, 1.0]))
    finally:
        p.release()


def test_direct_light_weighs_every_camera_path_alike(write_scene):
    """The direct term is the mean over a pixel's camera paths whatever the K of their passes
    (docs/effort.md, "Camera paths weighed alike"): a pass's mean counted as one sample let
    passes of few paths outweigh the rest, and the pixel positions were no longer an equally
    weighted net. A lamp seen edge-on against nothing: every path gives its radiance or 0, so
    a pixel's direct sum is its radiance times a whole number of paths."""
    radiance = 2.0
    scene = load_scene(write_scene(camera_xml(res=8, fov=50) + f"""
        <shape type="rectangle"><transform name="to_world"><scale value="0.6"/><rotate z="1" angle="23"/>
            <translate x="0.25" y="-0.1" z="-2"/></transform>
            <emitter type="area"><rgb name="radiance" value="{radiance}"/></emitter></shape>"""))
    p = prepare(scene, method="sppm", seed=3, options={"photons": 256, "camera_paths": 8})
    try:
        m = p.method
        passes = (1, 3, 8, 2, 5)
        for k in passes:
            m.camera_paths = k
            m.iterate()
        paths = sum(passes)
        assert m.camera_paths_done() == paths
        hits = luminance(m.Ld.to_numpy().reshape(8, 8, 3)) / radiance
        assert np.abs(hits - np.round(hits)).max() < 1e-6, hits
        edge = (hits > 0.5) & (hits < paths - 0.5)
        assert edge.sum() >= 4, hits          # pixels the lamp's edges cross
        assert np.allclose(luminance(m.image()), hits * radiance / paths, atol=1e-9)
    finally:
        p.release()

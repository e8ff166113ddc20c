"""Vertex connection and merging: the camera for light tracing, each technique variant
against analytic answers and Mitsuba, the extremes, determinism and bad options.

The MIS recursion itself is tested in test_vcm_mis.py."""
import math

import numpy as np
import pytest
import taichi as ti

from photonmc import load_scene
from photonmc.errors import SettingsError
from photonmc.imageio import read_image
from photonmc.kernels.device_scene import DeviceScene
from photonmc.kernels.fields import FieldGroup
from photonmc.kernels.hashgrid import PointGrid
from photonmc.loop import Budget, prepare, run
from photonmc.metrics import luminance, mean_luminance

from .conftest import REFS, SCENE_REFERENCES, SCENES, assert_image_follows_the_units, slit_band
from .test_pt import furnace_expectation, furnace_xml

VARIANTS = ("vcm", "bpt", "bpm", "lt")


def render(scene, iterations, seed=0, max_depth=None, **options):
    p = prepare(scene, method="vcm", seed=seed, max_depth=max_depth, options=options)
    r = run(p, Budget(iterations=iterations), quiet=True)
    p.release()
    return r


@ti.kernel
def camera_round_trip(sc: ti.template(), px: ti.types.ndarray(dtype=ti.i32, ndim=1),
                      py: ti.types.ndarray(dtype=ti.i32, ndim=1), u: ti.types.ndarray(dtype=ti.math.vec2, ndim=1),
                      raster: ti.types.ndarray(dtype=ti.math.vec3, ndim=1), pdf: ti.types.ndarray(dtype=ti.f32, ndim=1),
                      corners: ti.types.ndarray(dtype=ti.math.vec3, ndim=2)):
    for i in range(px.shape[0]):
        o, d = sc.camera_ray(px[i], py[i], u[i][0], u[i][1])
        ok, x, y = sc.camera_raster(o + 3.7 * d)
        raster[i] = ti.math.vec3(ok, x, y)
        _, dm = sc.camera_ray(px[i], py[i], 0.5, 0.5)
        pdf[i] = sc.camera_pdf_w(dm)
        for k in ti.static(range(4)):
            _, dc = sc.camera_ray(px[i], py[i], float(k % 2), float(k // 2))
            corners[i, k] = dc


def _solid_angle_of_triangle(a, b, c):
    """Van Oosterom & Strackee: solid angle of the spherical triangle of unit vectors a, b, c."""
    num = abs(np.einsum("ij,ij->i", a, np.cross(b, c)))
    den = 1 + np.einsum("ij,ij->i", a, b) + np.einsum("ij,ij->i", b, c) + np.einsum("ij,ij->i", c, a)
    return 2 * np.arctan2(num, den)


@pytest.mark.parametrize("name,params", [("mitsuba-style", {"resx": 40, "resy": 30}), ("cornell-box", {"res": 16})])
def test_camera_raster_inverts_camera_ray_and_its_pdf_is_one_per_pixel(name, params):
    """camera_raster(camera_ray(x + u)) = x + u, and camera_pdf_w is the density of one sample
    per pixel: at the pixel's centre, 1 / (the pixel's solid angle, from its corner rays), up
    to the curvature of the density across one pixel (second order in its angular size)."""
    dscene = DeviceScene(load_scene(SCENES / name / "scene.xml", params))
    w, h = dscene.width, dscene.height
    rng = np.random.default_rng(3)
    n = 500
    px = rng.integers(0, w, n).astype(np.int32)
    py = rng.integers(0, h, n).astype(np.int32)
    u = rng.random((n, 2)).astype(np.float32)
    raster = np.zeros((n, 3), np.float32)
    pdf = np.zeros(n, np.float32)
    corners = np.zeros((n, 4, 3), np.float32)
    camera_round_trip(dscene, px, py, u, raster, pdf, corners)
    assert raster[:, 0].all()
    np.testing.assert_allclose(raster[:, 1], px + u[:, 0], atol=2e-3)
    np.testing.assert_allclose(raster[:, 2], py + u[:, 1], atol=2e-3)
    c = corners.astype(np.float64)
    omega = _solid_angle_of_triangle(c[:, 0], c[:, 1], c[:, 3]) + _solid_angle_of_triangle(c[:, 0], c[:, 3], c[:, 2])
    np.testing.assert_allclose(pdf * omega, 1.0, rtol=2e-3)
    dscene.release()


@ti.kernel
def ball_query(grid: ti.template(), pos: ti.template(), r: ti.f32, x: ti.types.ndarray(dtype=ti.math.vec3, ndim=1),
               hits: ti.types.ndarray(dtype=ti.i32, ndim=2)):
    for q in range(x.shape[0]):
        slots, n = grid.slots_near(x[q])
        for k in range(n):
            first, end = grid.slot_range(slots[k])
            for e in range(first, end):
                j = grid.entries[e]
                if (grid.entry_pos[e] - x[q]).norm_sqr() <= r * r:
                    hits[q, j] += 1


@pytest.mark.parametrize("n", [20, 3000])
def test_point_grid_finds_each_point_within_the_radius_once(n):
    """Merging's grid: every valid point within r of a query, each exactly once (a point seen
    under two of the query's cells that share a hash slot would be merged twice). With 20
    points the table has 64 slots, so a query's 8 cells often share slots."""
    rng = np.random.default_rng(5)
    p = rng.uniform(-2, 2, (n, 3)).astype(np.float32)
    v = (rng.random(n) < 0.9).astype(np.int32)
    r = 0.3
    f = FieldGroup("test-point-grid")
    pos, valid = f.vector(3, ti.f32, n, p), f.scalar(ti.i32, n, v)
    f.finalize()
    grid = PointGrid(n)
    grid.build(pos, r, valid)
    x = np.concatenate([rng.uniform(-2.5, 2.5, (2000, 3)), p[rng.integers(0, n, 500)]]).astype(np.float32)
    hits = np.zeros((len(x), n), np.int32)
    ball_query(grid, pos, r, x, hits)
    d2 = ((x[:, None, :] - p[None]) ** 2).sum(-1)
    expected = (d2 <= r * r) & (v[None] == 1)
    boundary = np.abs(d2 - r * r) < 1e-5
    assert hits.max() == 1
    assert np.array_equal(hits.astype(bool) | boundary, expected | boundary)
    assert expected.sum() > (20 if n == 20 else 5000)
    grid.release()
    f.release()


@pytest.mark.parametrize("techniques", VARIANTS)
@pytest.mark.parametrize("depth", [3, -1])
def test_sphere_furnace_analytic(write_scene, techniques, depth):
    """Inside an emitting diffuse sphere L = Le sum_{k<D} albedo^k: every variant, light
    tracing alone included, must reach it (merging has no blur bias where the density is
    uniform)."""
    scene = load_scene(write_scene(furnace_xml("sphere")))
    r = render(scene, 64, seed=2, max_depth=depth, techniques=techniques)
    lum = luminance(r.image)
    expected = furnace_expectation(depth)
    spread = lum.std()
    assert abs(lum.mean() - expected) < 5 * spread / math.sqrt(lum.size) + 2e-3 * expected, (techniques, lum.mean())
    assert np.abs(lum - expected).max() < 6 * spread + 1e-6
    assert r.stats["nonfinite_samples_dropped"] == 0


def test_merging_bias_estimate_reads_none_where_merging_has_none(write_scene):
    """Inside an emitting sphere the light vertices are uniform and the cap a merging sphere
    cuts from the surface has area pi r^2 exactly (Archimedes), so merging has no bias, and
    the estimate (docs/vcm.md, "Merging's bias, estimated") must read about none: 0.6 % of the
    image and an RMSE of 0 after 64 passes here. An inner disc normalised wrongly (its weight
    not doubled) would read half the merged light as bias."""
    scene = load_scene(write_scene(furnace_xml("sphere")))
    r = render(scene, 64, seed=2, max_depth=3, techniques="bpm", alpha=1.0, radius=0.3)
    bias = r.stats["merging_bias"]
    assert bias["passes"] == 64
    assert abs(bias["mean_relative"]) < 0.02
    assert bias["rmse_estimate"] < 0.03 * luminance(r.image).mean()


@pytest.fixture(scope="module")
def cornell_16_pt_mean():
    """pt's luminance of the Cornell box at 16x16 (4,000 iterations): the reference the merging
    tests set their bias against."""
    scene = load_scene(SCENES / "cornell-box" / "scene.xml", {"res": 16})
    p = prepare(scene, method="pt", seed=1)
    image = luminance(run(p, Budget(iterations=4000), quiet=True).image)
    p.release()
    return scene, image


def test_merging_bias_estimate_follows_the_bias_against_pt(cornell_16_pt_mean):
    """The Cornell box at 16x16, merging alone at a fixed radius of 0.2 (a tenth of the box):
    the image is 1.9 % dark against pt (corners, where the disc leaves its face, and the blur),
    and the estimate reads that bias with its sign and within a factor 2.5 (measured over
    seeds 2-4: 0.72-1.04x). At a radius of 0.05 the bias is within the estimate's noise."""
    scene, pt_image = cornell_16_pt_mean
    reference = pt_image.mean()
    r = render(scene, 400, seed=2, techniques="bpm", alpha=1.0, radius=0.2)
    actual = luminance(r.image).mean() / reference - 1.0
    estimated = r.stats["merging_bias"]["mean_relative"]
    assert actual < -0.01, actual
    assert 0.4 < estimated / actual < 2.5, (estimated, actual)
    assert r.stats["merging_bias"]["rmse_estimate"] > 0.02 * reference


def test_balanced_radius_shrinks_where_merging_bias_dominates(cornell_16_pt_mean):
    """--radius-rule balanced (methods/merge_radius.py): merging alone in the Cornell box at
    16x16 from a radius of 0.3 with 4,096 light subpaths per pass, where merging's bias
    outweighs its noise. The rule takes most steps fast, and the image is nearer pt's than the
    progressive radius's, in its mean and its RMSE (seeds 2 and 3: mean -1.8 -> -1.4 % and
    -2.1 -> -1.6 %, RMSE 11-12 % lower at 200 passes)."""
    scene, pt_image = cornell_16_pt_mean
    results = {}
    for rule in ("progressive", "balanced"):
        r = render(scene, 200, seed=2, techniques="bpm", radius=0.3, light_paths=4096, radius_rule=rule)
        lum = luminance(r.image)
        results[rule] = (abs(lum.mean() / pt_image.mean() - 1.0), np.sqrt(np.mean((lum - pt_image) ** 2)),
                         r.stats["radius"], r.stats["radius_schedule"])
    (bias_p, rmse_p, radius_p, _), (bias_b, rmse_b, radius_b, schedule) = results["progressive"], results["balanced"]
    assert schedule["fast_decisions"] > 100 and radius_b < 0.8 * radius_p, schedule
    assert bias_b < 0.9 * bias_p and rmse_b < 0.95 * rmse_p, results


def test_balanced_radius_keeps_the_progressive_one_where_merging_has_no_bias(write_scene):
    """Inside the emitting sphere merging has no bias (above): the balanced rule decides every
    pass and never shrinks faster, so the image is the progressive radius's, bit for bit."""
    scene = load_scene(write_scene(furnace_xml("sphere")))
    images = []
    for rule in ("progressive", "balanced"):
        r = render(scene, 48, seed=2, max_depth=3, techniques="bpm", radius=0.3, radius_rule=rule)
        images.append(r.image)
    assert r.stats["radius_schedule"]["decisions"] == 48 and r.stats["radius_schedule"]["fast_decisions"] == 0
    assert np.array_equal(images[0], images[1])


def test_growing_the_vertex_store_changes_nothing(write_scene):
    """A store too small for the iteration's light vertices grows and the pass is redone:
    the image is bit-identical to one rendered with room to spare."""
    scene = load_scene(write_scene(furnace_xml("sphere")))
    small = render(scene, 3, seed=4, max_depth=-1, light_vertex_capacity=64)
    large = render(scene, 3, seed=4, max_depth=-1, light_vertex_capacity=1 << 16)
    assert small.stats["light_vertex_store_grown"] >= 1 and large.stats["light_vertex_store_grown"] == 0
    assert np.array_equal(small.image, large.image)


def test_a_pass_with_fewer_light_subpaths_is_the_pass_of_a_vcm_with_that_many():
    """vcm_pass(n_light=N) on a store sized for more (mbe's vcm passes choose N,
    methods/pass_choice.py) renders what a vcm with --light-paths N renders: the same light
    subpaths, the pairing modulo N, the MIS counts of N."""
    scene = load_scene(SCENES / "cornell-box" / "scene.xml", {"res": 16})
    images = []
    for light_paths, per_pass in ((256, 64), (64, None)):
        p = prepare(scene, method="vcm", seed=3, options={"light_paths": light_paths})
        for it in range(3):
            p.method.vcm_pass(it, it, per_pass)
        images.append(p.method.image())
        with pytest.raises(ValueError, match="light subpaths"):
            p.method.vcm_pass(3, 3, light_paths + 1)
        p.release()
    assert images[0].mean() > 0 and np.array_equal(images[0], images[1])


def test_a_pass_that_only_measures_stays_out_of_the_film():
    """vcm_pass(keep=False) (mbe's passes that only measure a vcm pass's variance,
    methods/pass_choice.py): the pass is traced and measured (its spread against the last
    pass's estimate), and the film is what the other passes alone make."""
    scene = load_scene(SCENES / "cornell-box" / "scene.xml", {"res": 16})
    images = []
    for passes in (((0, True), (1, True), (2, False), (3, True)), ((0, True), (1, True), (3, True))):
        p = prepare(scene, method="vcm", seed=3)
        spreads = [p.method.vcm_pass(it, it, 64, keep)[0] for it, keep in passes]
        assert p.method.film.film.samples_per_pixel == 3 and min(spreads[1:]) > 0.0
        images.append(p.method.image())
        p.release()
    assert images[0].mean() > 0 and np.array_equal(images[0], images[1])


def test_seed_determinism():
    scene = load_scene(SCENES / "cornell-box" / "scene.xml", {"res": 16})
    a = render(scene, 3, seed=3).image
    b = render(scene, 3, seed=3).image
    c = render(scene, 3, seed=4).image
    assert np.array_equal(a, b) and not np.array_equal(a, c)


def test_scene_scale_and_light_power_extremes(write_scene):
    assert_image_follows_the_units(lambda scene: render(scene, 40, seed=5).image, write_scene)


def test_one_light_path_per_iteration(write_scene):
    scene = load_scene(write_scene(furnace_xml("sphere")))
    r = render(scene, 200, seed=1, max_depth=3, light_paths=1)
    lum = luminance(r.image)
    expected = furnace_expectation(3)
    assert np.isfinite(r.image).all() and r.stats["light_paths_per_iteration"] == 1
    assert abs(lum.mean() - expected) < 5 * lum.std() / math.sqrt(lum.size) + 2e-3 * expected


@pytest.mark.parametrize("options,message", [
    ({"radius": 0.0}, "--radius"), ({"radius": -1.0}, "--radius"), ({"alpha": 0.0}, "--alpha"),
    ({"alpha": 1.5}, "--alpha"), ({"light_paths": 0}, "--light-paths"), ({"techniques": "pm"}, "--techniques"),
    ({"light_paths": 1 << 26}, "GiB to store"), ({"radius_rule": "fast"}, "--radius-rule"),
])
def test_bad_options(options, message):
    scene = load_scene(SCENES / "cornell-box" / "scene.xml", {"res": 8})
    with pytest.raises(SettingsError, match=message):
        prepare(scene, method="vcm", options=options)


def test_alpha_one_keeps_the_radius():
    scene = load_scene(SCENES / "cornell-box" / "scene.xml", {"res": 8})
    r = render(scene, 5, alpha=1.0, radius=0.05)
    assert r.stats["radius"] == pytest.approx(0.05)


@pytest.mark.convergence
@pytest.mark.parametrize("name,ref_file,params", SCENE_REFERENCES, ids=[r[0] for r in SCENE_REFERENCES])
def test_vcm_matches_mitsuba_on_every_bundled_scene(name, ref_file, params):
    """Mean luminance within 1 % of Mitsuba's reference after 400 iterations at the reference's
    resolution (the merging radius, 2 pixel footprints, shrinks with the pixels)."""
    ref = read_image(REFS / ref_file)
    scene = load_scene(SCENES / name / "scene.xml", params)
    r = render(scene, 400, seed=1)
    bias = mean_luminance(r.image) / mean_luminance(ref) - 1
    print(f"vcm {name}: mean {100 * bias:+.2f} % against Mitsuba")
    assert np.isfinite(r.image).all()
    assert abs(bias) < 0.01


@pytest.mark.convergence
@pytest.mark.parametrize("techniques", ["bpt", "bpm"])
def test_each_variant_alone_matches_mitsuba_on_the_cornell_box(techniques):
    ref = read_image(REFS / "cornell-box-64.exr")
    scene = load_scene(SCENES / "cornell-box" / "scene.xml", {"res": 64})
    r = render(scene, 400, seed=1, techniques=techniques)
    bias = mean_luminance(r.image) / mean_luminance(ref) - 1
    print(f"{techniques} cornell-box: mean {100 * bias:+.2f} % against Mitsuba")
    assert abs(bias) < 0.01


@pytest.mark.convergence
@pytest.mark.parametrize("techniques", ["vcm", "lt"])
def test_error_falls_on_the_light_gap(techniques):
    """The room lit only through a slit (no mirror or glass, so light tracing alone can render
    it): against the Mitsuba reference RMSE falls at about the Monte Carlo rate (slope -0.5;
    merging's variance falls as N^-alpha). Light tracing is unbiased: its mean must agree
    within 4 standard errors (from the per-pixel spread over iterations) plus 0.5 % for the
    reference. vcm's merging keeps a boundary bias along the slit's grazing-lit faces that
    shrinks only with the radius (sppm: -9 % in that band at 400 iterations,
    docs/convergence.md); away from the band vcm's mean must be within 1 % plus 3 standard
    errors of its own noise there (about 0.3 %: one render, as for light tracing)."""
    ref = luminance(read_image(REFS / "light-gap-64.exr"))
    scene = load_scene(SCENES / "light-gap" / "scene.xml", {"res": 64})
    p = prepare(scene, method="vcm", seed=1, options={"techniques": techniques})
    checkpoints = [25, 100, 400]
    errors = []

    def record(m, iteration, elapsed):
        if iteration in checkpoints:
            errors.append(float(np.sqrt(np.mean((luminance(m.image()) - ref) ** 2))))

    r = run(p, Budget(iterations=checkpoints[-1]), quiet=True, on_iteration=record)
    se = p.method.standard_error()
    p.release()
    slope = np.polyfit(np.log(checkpoints), np.log(errors), 1)[0]
    img = luminance(r.image)
    mean = img.mean()
    bias = mean / ref.mean() - 1
    band = slit_band(ref)
    outside = img[:, ~band].mean() / ref[:, ~band].mean() - 1
    sigma = float(np.sqrt(np.sum(se ** 2)) / se.size / mean)
    se_out = se[:, ~band]
    sigma_outside = float(np.sqrt(np.sum(se_out ** 2)) / se_out.size / img[:, ~band].mean())
    print(f"{techniques} light-gap RMSE {np.round(errors, 5).tolist()} at {checkpoints}: slope {slope:.3f}, "
          f"mean {100 * bias:+.2f} % (standard error {100 * sigma:.2f} %), outside the slit band "
          f"{100 * outside:+.2f} % (standard error {100 * sigma_outside:.2f} %)")
    assert errors[0] > errors[1] > errors[2]
    assert slope < -0.3
    if techniques == "lt":
        assert abs(bias) < 4 * sigma + 0.005
    else:
        assert abs(outside) < 0.01 + 3 * sigma_outside

"""The reference path tracer against analytic answers and against Mitsuba 3."""
import numpy as np
import pytest

from photonmc import load_scene
from photonmc.imageio import read_image, read_metadata
from photonmc.metrics import downsample, luminance, mean_luminance
from photonmc.loop import Budget, prepare, run

from .conftest import REFS, SCENES, camera_xml

ALBEDO, RADIANCE = 0.5, 1.0


def furnace_xml(shape: str, scale: float = 1.0) -> str:
    """Camera inside a closed emitting diffuse shape (normals flipped inward). Every ray
    sees L = Le * sum_{k<D} albedo^k; for unbounded depth Le / (1 - albedo)."""
    return camera_xml(res=16, fov=100, origin="0,0,0", target="0,0.3,-1") + f"""
    <shape type="{shape}">
        <boolean name="flip_normals" value="true"/>
        <transform name="to_world"><scale value="{scale}"/></transform>
        <bsdf type="diffuse"><float name="reflectance" value="{ALBEDO}"/></bsdf>
        <emitter type="area"><float name="radiance" value="{RADIANCE}"/></emitter>
    </shape>"""


def furnace_expectation(depth):
    if depth == -1:
        return RADIANCE / (1 - ALBEDO)
    return RADIANCE * sum(ALBEDO ** k for k in range(depth))


def render_method(scene, iterations, seed=0, max_depth=None, method="pt", **options):
    """Render; returns (per-pixel standard error of luminance, RunResult) and frees the device memory."""
    p = prepare(scene, method=method, seed=seed, max_depth=max_depth, options=options)
    r = run(p, Budget(iterations=iterations), quiet=True)
    se = p.method.standard_error()
    p.release()
    return se, r


# Per-sample float32 rounding (about 10 ulps seen); a ray-offset bias found earlier was 1.1e-5.
F32_SLACK = 4e-6


def assert_matches_constant(se, image, expected, sigmas=5.0):
    """The image mean, and every pixel, agree with `expected`.

    All pixels share one expectation, so the spread across pixels measures each pixel's
    error honestly; a pixel's own sample variance can miss rare Russian-roulette survivors."""
    lum = luminance(image)
    spread = lum.std()
    assert np.all(np.abs(lum - expected) <= sigmas * np.maximum(se, 1.2 * spread) + F32_SLACK * expected)
    assert abs(lum.mean() - expected) <= sigmas * spread / np.sqrt(lum.size) + F32_SLACK * expected


@pytest.mark.parametrize("depth", [1, 2, 3, -1])
def test_sphere_furnace_analytic(write_scene, depth):
    scene = load_scene(write_scene(furnace_xml("sphere")))
    se, r = render_method(scene, 256, max_depth=depth)
    assert_matches_constant(se, r.image, furnace_expectation(depth))
    if depth == 1:        # only emission is seen: exact, no noise
        np.testing.assert_allclose(r.image, RADIANCE, rtol=1e-6)


@pytest.mark.parametrize("scale", [1e-3, 1.0, 1e3])
def test_cube_furnace_at_extreme_scales(write_scene, scale):
    """12 emitting triangles; ray offsets must work whether the scene is a millimetre or a kilometre."""
    scene = load_scene(write_scene(furnace_xml("cube", scale)))
    se, r = render_method(scene, 256, max_depth=-1)
    assert_matches_constant(se, r.image, furnace_expectation(-1))
    assert r.stats["nonfinite_samples_dropped"] == 0


def test_max_depth_one_shows_only_emitters():
    scene = load_scene(SCENES / "cornell-box" / "scene.xml", {"res": 32})
    _, r = render_method(scene, 4, max_depth=1)
    lit = luminance(r.image) > 0
    assert 0 < lit.sum() < lit.size * 0.1
    # Seen pixels are fully inside the light (box filter covers partial pixels with less).
    np.testing.assert_allclose(r.image[lit].max(0), [17, 12, 4], rtol=1e-5)


def test_seed_determinism():
    scene = load_scene(SCENES / "cornell-box" / "scene.xml", {"res": 32})
    a = render_method(scene, 3, seed=7)[1].image
    b = render_method(scene, 3, seed=7)[1].image
    c = render_method(scene, 3, seed=8)[1].image
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


REFERENCES = [
    ("cornell-box", "cornell-box-64.exr", {"res": 64}),
    ("mitsuba-style", "mitsuba-style-80x60.exr", {"resx": 80, "resy": 60}),
    ("mesh-room", "mesh-room-64.exr", {"res": 64}),
]


@pytest.mark.parametrize("name,ref_file,params", REFERENCES, ids=[r[0] for r in REFERENCES])
def test_pt_matches_mitsuba(name, ref_file, params):
    """Same XML, rendered by Mitsuba 3's path integrator (tests/refs/README.md has the commands).

    Per-pixel agreement is judged against our own noise measured empirically: two renders
    A, B with different seeds give MSE(A,B)/2 = our per-pixel variance, heavy tails included
    (per-pixel sample variances are unreliable where caustics make rare fireflies). Without
    bias MSE(A, ref) = var(A) + var(ref), with var(ref) ~ var(A) * n / n_ref. That holds for
    the same sampler at both sample counts: Mitsuba's references use independent pixel
    positions, so ours do here (with stratified positions var(A) falls faster than 1 / n,
    and the model would understate the reference's noise: ratio 2.1 on mitsuba-style)."""
    ref_path = REFS / ref_file
    ref = read_image(ref_path)
    ref_spp = int(read_metadata(ref_path)["spp"])
    scene = load_scene(SCENES / name / "scene.xml", params)
    n = 512
    a = render_method(scene, n, seed=1, pixel_samples="independent")[1].image
    b = render_method(scene, n, seed=2, pixel_samples="independent")[1].image
    assert a.shape == ref.shape
    for img in (a, b):                        # mean luminance within 1 % (the criterion)
        assert abs(mean_luminance(img) / mean_luminance(ref) - 1) < 0.01
    la, lb, lr = luminance(a), luminance(b), luminance(ref)
    noise = np.mean((la - lb) ** 2) / 2 * (1 + n / ref_spp)
    ratio = np.mean((la - lr) ** 2) / noise
    assert ratio < 1.5, ratio
    # The same on 2x2 blocks, where a bias confined to edges or small regions stands out more.
    da, db, dr = (downsample(x, 2) for x in (la, lb, lr))
    ratio2 = np.mean((da - dr) ** 2) / (np.mean((da - db) ** 2) / 2 * (1 + n / ref_spp))
    assert ratio2 < 1.5, ratio2


@pytest.mark.convergence
def test_pt_error_falls_as_one_over_sqrt_n():
    """RMSE against the Mitsuba reference along one progressive run: an unbiased estimator's
    error falls as N^-1/2 (slope -0.5 in log-log) until the reference's own noise shows."""
    ref = read_image(REFS / "cornell-box-64.exr")
    scene = load_scene(SCENES / "cornell-box" / "scene.xml", {"res": 64})
    p = prepare(scene, seed=3)
    checkpoints, errors = (16, 64, 256, 1024), []

    def record(method, iteration, elapsed):
        if iteration in checkpoints:
            errors.append(np.sqrt(np.mean((luminance(method.image()) - luminance(ref)) ** 2)))

    run(p, Budget(iterations=checkpoints[-1]), quiet=True, on_iteration=record)
    p.release()
    slope = np.polyfit(np.log(checkpoints), np.log(errors), 1)[0]
    print(f"pt RMSE {np.round(errors, 5).tolist()} at {checkpoints} iterations: slope {slope:.3f}")
    assert -0.6 < slope < -0.4

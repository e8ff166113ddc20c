"""Stratified pixel positions (kernels/pixel_samples.py): each of a pixel's two scrambled
replicates is a (0,2)-sequence, a sample is uniform on the pixel, consecutive samples are
uncorrelated, an edge is integrated faster than by independent points, and every method's
camera samples walk their pixel's sequence."""
import numpy as np
import pytest
import taichi as ti

from photonmc import load_scene
from photonmc.errors import SettingsError
from photonmc.kernels import pixel_samples
from photonmc.loop import Budget, prepare, run
from photonmc.metrics import luminance

from .conftest import SCENES


@ti.kernel
def _points(seed: ti.u32, first_index: ti.u32, stream: ti.u32, out: ti.types.ndarray(ndim=3)):
    """out[p, i] = sample first_index + i of pixel p's stream `stream`, where sample n is
    point n // 2 of replicate n % 2 (a pass of one sample per pixel, pt's and vcm's)."""
    for p, i in ti.ndrange(out.shape[0], out.shape[1]):
        n = first_index + ti.u32(i)
        u1, u2 = pixel_samples.pixel_position(seed, ti.u32(p), n >> ti.u32(1), n & ti.u32(1), stream)
        out[p, i, 0] = u1
        out[p, i, 1] = u2


def points(pixels: int, n: int, seed: int = 3, first_index: int = 0, stream: int = 0) -> np.ndarray:
    out = np.zeros((pixels, n, 2), np.float32)
    _points(seed, first_index, stream, out)
    return out


def is_net(pts: np.ndarray) -> bool:
    """Whether 2^m points put one point in every elementary box of area 2^-m (every shape)."""
    m = int(np.log2(len(pts)))
    for k in range(m + 1):
        bx = np.floor(pts[:, 0] * 2 ** k).astype(int)
        by = np.floor(pts[:, 1] * 2 ** (m - k)).astype(int)
        if not (np.bincount(bx * 2 ** (m - k) + by, minlength=2 ** m) == 1).all():
            return False
    return True


def test_every_aligned_block_of_each_replicate_is_a_net():
    pts = points(4, 4096)
    for p in range(4):
        for replicate in (pts[p, 0::2], pts[p, 1::2]):      # even and odd samples
            for m in range(1, 11):
                assert is_net(replicate[:2 ** m]), (p, m)
                assert is_net(replicate[2 ** m:2 ** (m + 1)]), (p, m)     # the next block too
    assert not np.array_equal(pts[0], pts[1])                      # each pixel its own scramble
    # independent points are not nets (a check that is_net can fail)
    assert not is_net(np.random.default_rng(0).random((256, 2)))


def test_a_sample_is_uniform_over_the_pixels_scrambles():
    """Sample 5 (any index) over 8,192 pixels: a chi-square over 8 x 8 cells (63 degrees of
    freedom; 110 is beyond its 0.9997 quantile), and another seed moves every point."""
    for index in (0, 5):
        u = points(8192, 1, first_index=index)[:, 0]
        assert (u >= 0).all() and (u < 1).all()
        counts = np.bincount((np.floor(u[:, 0] * 8) * 8 + np.floor(u[:, 1] * 8)).astype(int), minlength=64)
        expected = len(u) / 64
        assert ((counts - expected) ** 2 / expected).sum() < 110, index
    assert (points(64, 1, seed=4) != points(64, 1, seed=3)).all(axis=-1).all()


def test_consecutive_samples_are_uncorrelated():
    """Samples 2k and 2k + 1 come from independently scrambled replicates: over 8,192 pixels
    their correlation is within noise of 0 (one sequence's points 2k and 2k + 1 always lie in
    opposite halves of the pixel, a correlation of about -1/2 in x)."""
    pts = points(8192, 8)
    for k in range(0, 8, 2):
        for axis in (0, 1):
            r = np.corrcoef(pts[:, k, axis], pts[:, k + 1, axis])[0, 1]
            assert abs(r) < 4 / np.sqrt(8192), (k, axis, r)


def test_passes_take_the_next_points_of_alternate_replicates():
    """PassSamples: a pass of K samples per pixel takes the next K points of replicate
    (passes so far) % 2, so each replicate's points over the render are its sequence in order
    (a net in every aligned block) whatever K each pass had; K = 1 is pt's and vcm's
    iteration_points. mbe's vcm passes have a stream of their own, uncorrelated with the chain
    passes' at the same point (8,192 pixels)."""
    passes = pixel_samples.PassSamples()
    taken = [(k, passes.take(k)) for k in (4, 4, 2, 2, 8, 8, 1, 1, 1, 1)]
    assert [first for _, (first, _) in taken] == [0, 0, 4, 4, 6, 6, 14, 14, 15, 15]
    assert [replicate for _, (_, replicate) in taken] == [0, 1] * 5
    assert (passes.points_even, passes.points_odd) == (16, 16)
    ones = pixel_samples.PassSamples()
    assert [ones.take(1) for _ in range(5)] == [pixel_samples.iteration_points(i) for i in range(5)]
    a = points(8192, 4, stream=0)
    vcm = points(8192, 4, stream=pixel_samples.VCM_PASS_STREAM)
    assert not np.array_equal(a, vcm)
    for i in range(4):
        for axis in (0, 1):
            r = np.corrcoef(a[:, i, axis], vcm[:, i, axis])[0, 1]
            assert abs(r) < 4 / np.sqrt(8192), (i, axis, r)


def test_an_edge_across_the_pixel_converges_faster_and_without_bias():
    """The coverage of the half-plane x + 0.3 y < 0.6 (0.45 of the pixel) over 1,024 pixels'
    scrambles: unbiased at every n, an error below a third of independent points' at n = 256,
    and falling as about n^-3/4 (Owen's rate for a discontinuity, each replicate's), not
    n^-1/2."""
    exact = 0.45
    pts = points(1024, 256)
    inside = (pts[..., 0] + 0.3 * pts[..., 1] < 0.6).astype(float)
    ns = np.array([4, 16, 64, 256])
    rmse = []
    for n in ns:
        err = inside[:, :n].mean(axis=1) - exact
        assert abs(err.mean()) < 4 * err.std() / np.sqrt(len(err)) + 1e-7, n
        rmse.append(np.sqrt((err ** 2).mean()))
    independent = np.sqrt(exact * (1 - exact) / 256)
    assert rmse[-1] < independent / 3, (rmse, independent)
    slope = np.polyfit(np.log(ns), np.log(rmse), 1)[0]
    assert slope < -0.65, slope


def _edge_error(method: str, sampler: str, passes: int, reference: np.ndarray, edge: np.ndarray, **options):
    scene = load_scene(SCENES / "cornell-box" / "scene.xml", {"res": 32})
    p = prepare(scene, method=method, seed=5, max_depth=1, options={"pixel_samples": sampler, **options})
    run(p, Budget(iterations=passes), quiet=True)
    image = luminance(p.method.image())
    p.release()
    return float(np.sqrt(((image - reference)[edge] ** 2).mean()))


@pytest.fixture(scope="module")
def lamp_edges():
    """The Cornell box at depth 1 shows only its lamp: each pixel is the lamp's radiance times
    the share of the pixel it covers. The reference is pt's mean over 4,096 stratified samples
    per pixel;
    the pixels it measures are those the lamp's edge crosses."""
    scene = load_scene(SCENES / "cornell-box" / "scene.xml", {"res": 32})
    p = prepare(scene, method="pt", seed=99, max_depth=1, options={"pixel_samples": "sobol"})
    run(p, Budget(iterations=4096), quiet=True)
    reference = luminance(p.method.image())
    p.release()
    edge = (reference > 0.02 * reference.max()) & (reference < 0.98 * reference.max())
    assert edge.sum() >= 8
    return reference, edge


@pytest.mark.parametrize("method,options", [("pt", {}), ("sppm", {}), ("vcm", {}),
                                            ("mbe", {"camera_paths": 2, "vcm_passes": "off"})])
def test_every_methods_camera_samples_walk_their_pixels_sequence(lamp_edges, method, options):
    """64 samples per pixel of the lamp's edges: from the pixel's sequences the error is well
    below independent positions' (pt's, the same estimator of what the camera sees directly).
    A method whose sample index did not advance, or restarted each pass, would repeat one
    point and stay far above it. (mbe: chain passes only, K = 2, so that all 64 samples are
    traced; its vcm passes trace one per pixel.)"""
    reference, edge = lamp_edges
    independent = _edge_error("pt", "independent", 64, reference, edge)
    passes = 64 // options.get("camera_paths", 1)
    stratified = _edge_error(method, "sobol", passes, reference, edge, **options)
    assert stratified < 0.5 * independent, (stratified, independent)


def test_a_bad_pixel_sampler_is_an_error():
    scene = load_scene(SCENES / "cornell-box" / "scene.xml", {"res": 8})
    for method in ("pt", "sppm", "vcm", "mbe"):
        with pytest.raises(SettingsError, match="--pixel-samples"):
            prepare(scene, method=method, options={"pixel_samples": "halton"})

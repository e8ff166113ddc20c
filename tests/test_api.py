"""The Python API: same image as the command line for the same seed, progressive frames."""
import subprocess
import sys

import numpy as np
import pytest

import photonmc
from photonmc.imageio import read_image

from .conftest import SCENES

CORNELL = str(SCENES / "cornell-box" / "scene.xml")


@pytest.mark.parametrize("method", ["pt", "sppm"])
def test_api_returns_the_cli_image_for_the_same_seed(tmp_path, method):
    out = tmp_path / "cli.exr"
    r = subprocess.run([sys.executable, "-m", "photonmc", "render", CORNELL, "-D", "res=16", "--method", method,
                        "--iterations", "3", "--seed", "7", "--out", str(out), "--quiet"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    image = photonmc.render(CORNELL, method=method, iterations=3, seed=7, params={"res": 16})
    assert image.shape == (16, 16, 3) and image.dtype == np.float32
    assert image.mean() > 0
    np.testing.assert_array_equal(image, read_image(out))


def test_api_accepts_a_loaded_scene_and_method_options():
    scene = photonmc.load_scene(CORNELL, {"res": 8})
    a = photonmc.render(scene, method="sppm", iterations=2, seed=1, photons=100, alpha=0.5)
    b = photonmc.render(scene, method="sppm", iterations=2, seed=1, photons=100, alpha=0.5)
    c = photonmc.render(scene, method="sppm", iterations=2, seed=2, photons=100, alpha=0.5)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_iterate_yields_each_iteration_with_statistics():
    frames = []
    for frame in photonmc.iterate(CORNELL, method="sppm", iterations=4, seed=3, params={"res": 8}):
        frames.append((frame.iteration, frame.elapsed, frame.image.copy(), frame.stats, frame.live))
    assert [f[0] for f in frames] == [1, 2, 3, 4]
    assert all(b[1] >= a[1] for a, b in zip(frames, frames[1:], strict=False))
    assert frames[-1][3]["iterations"] == 4 and "mean_radius" in frames[-1][3]
    assert frames[-1][4].startswith("radius")
    final = photonmc.render(CORNELL, method="sppm", iterations=4, seed=3, params={"res": 8})
    np.testing.assert_array_equal(frames[-1][2], final)
    assert not np.array_equal(frames[0][2], final)


def test_api_rejects_bad_settings_by_name():
    with pytest.raises(photonmc.SettingsError, match="--bogus"):
        photonmc.render(CORNELL, method="sppm", iterations=1, params={"res": 8}, bogus=3)
    with pytest.raises(photonmc.SettingsError, match="iterations"):
        photonmc.render(CORNELL, iterations=0)

"""The command line as a user meets it: outputs, statistics, bad input, Ctrl-C."""
import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from photonmc.imageio import read_image, read_metadata

from .conftest import SCENES

CORNELL = str(SCENES / "cornell-box" / "scene.xml")
SMALL = [CORNELL, "-D", "res=16"]


def photonmc(*args, cwd=None, timeout=300):
    return subprocess.run([sys.executable, "-m", "photonmc", *args], capture_output=True, text=True,
                          cwd=cwd, timeout=timeout)


def test_render_writes_exr_png_and_stats(tmp_path):
    out, stats = tmp_path / "img.exr", tmp_path / "stats.json"
    r = photonmc("render", *SMALL, "--iterations", "3", "--seed", "5", "--out", str(out), "--stats", str(stats))
    assert r.returncode == 0, r.stderr
    img = read_image(out)
    assert img.shape == (16, 16, 3) and np.isfinite(img).all() and img.mean() > 0
    assert (tmp_path / "img.png").is_file()
    meta = read_metadata(out)
    assert meta["method"] == "pt" and meta["seed"] == "5" and meta["iterations"] == "3"
    s = json.loads(stats.read_text())
    for key in ("method", "scene", "seed", "resolution", "iterations", "samples", "nonfinite_samples_dropped"):
        assert key in s
    assert s["iterations"] == 3 and s["resolution"] == [16, 16] and s["samples"] == 3 * 256
    assert set(s["wall_seconds"]) >= {"load", "first_iteration_incl_compile", "steady_per_iteration"}
    assert "Traceback" not in r.stderr


def test_default_scene_with_no_arguments(tmp_path):
    r = photonmc("render", "--iterations", "1", "--quiet", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert read_image(tmp_path / "render.exr").shape == (256, 256, 3)
    assert (tmp_path / "render.png").is_file()


def test_sppm_from_the_command_line(tmp_path):
    out, stats = tmp_path / "s.exr", tmp_path / "s.json"
    r = photonmc("render", *SMALL, "--method", "sppm", "--iterations", "3", "--photons", "500", "--alpha", "0.7",
                 "--quiet", "--out", str(out), "--stats", str(stats))
    assert r.returncode == 0, r.stderr
    s = json.loads(stats.read_text())
    assert s["method"] == "sppm" and s["photons_emitted"] == 1500 and s["alpha"] == 0.7
    assert 0 <= s["fraction_of_photon_paths_depositing"] <= 1 and s["mean_radius"] > 0
    assert read_image(out).mean() > 0


def test_png_only_output(tmp_path):
    r = photonmc("render", *SMALL, "--iterations", "1", "--quiet", "--out", str(tmp_path / "a.png"))
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "a.png").is_file() and not (tmp_path / "a.exr").exists()


BAD = {
    "missing scene": (["render", "/nonexistent/scene.xml"], "cannot read scene file"),
    "bad out suffix": (["render", *SMALL, "--out", "x.jpg"], "--out must end in .exr or .png"),
    "missing out dir": (["render", *SMALL, "--out", "/nonexistent/dir/x.exr"], "does not exist"),
    "negative time": (["render", *SMALL, "--time", "-1"], "--time must be a positive"),
    "nan time": (["render", *SMALL, "--time", "nan"], "--time must be a positive"),
    "zero iterations": (["render", *SMALL, "--iterations", "0"], "--iterations must be at least 1"),
    "unknown method": (["render", *SMALL, "--method", "bogus"], "unknown method 'bogus'"),
    "mbe large step": (["render", *SMALL, "--method", "mbe", "--large-step", "1.5"], "--large-step must be in [0, 1)"),
    "photons for pt": (["render", *SMALL, "--photons", "10"], "does not take --photons"),
    "bad alpha": (["render", *SMALL, "--method", "sppm", "--alpha", "1"], "--alpha must be in (0, 1)"),
    "negative seed": (["render", *SMALL, "--seed", "-1"], "--seed must be"),
    "zero max depth": (["render", *SMALL, "--max-depth", "0"], "--max-depth must be"),
    "zero threads": (["render", *SMALL, "--threads", "0"], "--threads must be at least 1"),
    "vcm zero radius": (["render", *SMALL, "--method", "vcm", "--radius", "0"], "--radius must be a positive"),
    "vcm bad alpha": (["render", *SMALL, "--method", "vcm", "--alpha", "1.5"], "--alpha must be in (0, 1]"),
    "vcm no light paths": (["render", *SMALL, "--method", "vcm", "--light-paths", "0"], "--light-paths must be"),
    "vcm unknown technique": (["render", *SMALL, "--method", "vcm", "--techniques", "pm"], "unknown --techniques"),
    "light paths for sppm": (["render", *SMALL, "--method", "sppm", "--light-paths", "9"],
                             "does not take --light-paths"),
    "warm start for vcm": (["render", *SMALL, "--method", "vcm", "--warm-start"], "does not take --warm-start"),
    "warm start for visibility": (["render", *SMALL, "--method", "visibility", "--warm-start"],
                                  "has one chain per ladder"),
    "mbe camera paths auto on one ladder": (["render", *SMALL, "--method", "mbe", "--camera-paths", "auto",
                                             "--chains", "1"], "--camera-paths auto needs --chains 2 or more"),
    "mbe camera paths too many": (["render", *SMALL, "--method", "mbe", "--camera-paths", "65"],
                                  "--camera-paths for mbe must be 'auto' or a number"),
    "mbe uniform weight above one": (["render", *SMALL, "--method", "mbe", "--uniform-weight", "2"],
                                     "--uniform-weight must be 'auto' or a number in [0, 1]"),
    "uniform weight for vcm": (["render", *SMALL, "--method", "vcm", "--uniform-weight", "0.5"],
                               "does not take --uniform-weight"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_input_gives_one_line_error(case, tmp_path):
    args, message = BAD[case]
    r = photonmc(*args, cwd=tmp_path)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("photonmc: error:"), r.stderr
    assert message in lines[0]


def test_malformed_scene_gives_one_line_error(tmp_path):
    bad = tmp_path / "bad.xml"
    bad.write_text("<scene version='3.0.0'><shape type='cube'></scene>")
    r = photonmc("render", str(bad), cwd=tmp_path)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "malformed XML" in r.stderr


@pytest.mark.parametrize("method", ["pt", "spatial-tf", "vcm", "mbe"])
def test_same_seed_same_image_for_any_thread_count(tmp_path, method):
    """spatial-tf: its ladders run in parallel (kernels/mcmc.py), two per thread with 2.
    vcm: light vertices are appended in thread order, then put in path order; light tracing
    and merging add in fixed point (film.SplatFilm). mbe: both, with the camera vertices
    stored and the chains' targets summed in fixed point; its default --camera-paths auto
    sums over pixels in one fixed order, so K is the same too."""
    # Both renders at once: each process compiles every kernel for its thread count, and
    # compilation is mostly one thread, so on 2 cores this halves the test's time.
    runs = {}
    for threads in ("1", "2"):
        out = tmp_path / f"t{threads}.exr"
        runs[out] = subprocess.Popen([sys.executable, "-m", "photonmc", "render", *SMALL, "--method", *method.split(),
                                      "--iterations", "4", "--seed", "9", "--threads", threads, "--quiet",
                                      "--out", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    images = []
    for out, proc in runs.items():
        _, err = proc.communicate(timeout=600)
        assert proc.returncode == 0, err
        images.append(read_image(out))
    assert np.array_equal(images[0], images[1])


def test_ctrl_c_keeps_the_image_computed_so_far(tmp_path):
    out, stats = tmp_path / "long.exr", tmp_path / "s.json"
    p = subprocess.Popen([sys.executable, "-m", "photonmc", "render", *SMALL, "--time", "300", "--checkpoint", "0.2",
                          "--quiet", "--out", str(out), "--stats", str(stats)],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    while not out.exists() and time.time() < deadline and p.poll() is None:   # first checkpoint: loop running
        time.sleep(0.1)
    assert out.exists(), "no checkpoint was written"
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=60)
    assert p.returncode == 130, err
    s = json.loads(stats.read_text())
    assert s["interrupted"] is True and s["iterations"] >= 1
    assert read_metadata(out)["iterations"] == str(s["iterations"])
    assert read_image(out).mean() > 0
    assert "Traceback" not in err
    # The render state beside it holds the same iterations: resuming loses nothing.
    from photonmc.state import load
    [state] = load(out.with_suffix(".state"))
    assert state.iterations == s["iterations"]


@pytest.mark.skipif(os.name != "posix", reason="SIGTERM semantics")
def test_sigterm_also_stops_cleanly(tmp_path):
    out = tmp_path / "t.exr"
    p = subprocess.Popen([sys.executable, "-m", "photonmc", "render", *SMALL, "--time", "300", "--checkpoint", "0.2",
                          "--quiet", "--out", str(out)], stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    while not out.exists() and time.time() < deadline and p.poll() is None:
        time.sleep(0.1)
    p.send_signal(signal.SIGTERM)
    p.communicate(timeout=60)
    assert p.returncode == 130 and read_image(out).mean() > 0

"""Render states: resume equals straight, bad states are refused, merges are what they claim,
and a render on a local Ray cluster with a worker killed mid-render loses nothing."""
import json
import os
import signal
import zipfile

import numpy as np
import pytest

from photonmc import state
from photonmc.errors import PhotonmcError
from photonmc.loop import Budget, Job, resume
from photonmc.merge import check_mergeable, merged_image, worker_seed

from .conftest import SCENES

CORNELL = str(SCENES / "cornell-box" / "scene.xml")
SMALL = {"res": "16"}
OPTIONS = {"pt": {}, "sppm": {"photons": 512}, "visibility": {"photons": 512}, "spatial-tf": {"photons": 512},
           "vcm": {"light_paths": 256}, "mbe": {"light_paths": 256}}


def job(method, seed=3, **extra):
    return Job(scene=CORNELL, params=SMALL, method=method, seed=seed, options=OPTIONS[method], **extra)


def rendered(j: Job, iterations: int) -> state.RenderState:
    p = j.prepare()
    try:
        for _ in range(iterations):
            p.method.iterate()
        return state.state_of(p.method, j.identity(), p.scene, elapsed=0.0)
    finally:
        p.release()


@pytest.mark.parametrize("method", list(OPTIONS))
def test_resume_equals_straight_bit_for_bit(method, tmp_path):
    """N iterations, save, load, resume to 2N: the image of 2N straight, bit for bit."""
    straight = rendered(job(method), 6)
    path = state.save(tmp_path / "half.state", [rendered(job(method), 3)])
    [half] = state.load(path)
    assert half.iterations == 3
    p, _ = resume(half)
    try:
        for _ in range(3):
            p.method.iterate()
        assert p.method.iterations == 6
        resumed = p.method.image()
    finally:
        p.release()
    assert np.array_equal(resumed, straight.image), np.abs(resumed - straight.image).max()
    assert not np.array_equal(half.image, straight.image)


@pytest.mark.parametrize("method", ["pt", "sppm", "mbe"])
def test_resume_continues_the_pixels_sobol_sequences(method, tmp_path):
    """--pixel-samples sobol: the camera samples' index into each pixel's sequences (pt's and
    sppm's iteration, mbe's passes of each kind) is part of the state, so a
    resumed render continues the sequences: the image of 2N straight, bit for bit, and not
    that of the same render with independent positions."""
    def sobol_job(sampler="sobol"):
        return Job(scene=CORNELL, params=SMALL, method=method, seed=3,
                   options={**OPTIONS[method], "pixel_samples": sampler})
    straight = rendered(sobol_job(), 6)
    [half] = state.load(state.save(tmp_path / "half.state", [rendered(sobol_job(), 3)]))
    p, _ = resume(half)
    try:
        for _ in range(3):
            p.method.iterate()
        resumed = p.method.image()
    finally:
        p.release()
    assert np.array_equal(resumed, straight.image), np.abs(resumed - straight.image).max()
    assert not np.array_equal(rendered(sobol_job("independent"), 6).image, straight.image)


@pytest.mark.parametrize("method,options,chosen,half", [
    ("sppm", {"photons": "auto"}, "photons_per_iteration", 6),
    ("sppm", {"radius_rule": "balanced"}, "fast_passes", 24),
    ("mbe", {"light_paths": 256, "camera_paths": "auto"}, "camera_paths", 5),
    ("visibility", {"photons": 512}, "camera_paths", 8)])
def test_resume_of_a_balanced_render_equals_straight(tmp_path, method, options, chosen, half):
    """sppm --photons auto, mbe --camera-paths auto: the effort balance's history (and mbe's
    last estimate it compares with) is part of the state, as is sppm --radius-rule balanced's
    (its bias sums and the next pass's choice), so the resumed render makes the same
    choices (photons per pass, camera subpaths per pixel) and gives the same image. visibility:
    its K from the balance, which by then has measured how much photon noise a pixel's points
    share (effort.py, photon_correlation)."""
    j = Job(scene=CORNELL, params=SMALL, method=method, seed=3, options=options)
    straight = rendered(j, 2 * half)
    [saved] = state.load(state.save(tmp_path / "auto.state", [rendered(j, half)]))
    if method == "visibility":
        assert saved.plain["effort.correlation_terms"], "no pass of K >= 2 before the save"
    p, _ = resume(saved)
    for _ in range(half):
        p.method.iterate()
    assert np.array_equal(p.method.image(), straight.image)
    assert getattr(p.method, chosen) == straight.plain[chosen]
    p.release()


def test_resume_of_vcm_with_balanced_light_paths_equals_straight(tmp_path):
    """vcm --light-paths auto (the default): the light-path balance's sums, its centre and the
    last pass's estimate it differences against are part of the state, so a render saved after
    the balance has moved resumes to the same choices and the same image."""
    j = Job(scene=CORNELL, params=SMALL, method="vcm", seed=3, options={"light_paths": "auto"})
    half = 120
    straight = rendered(j, 2 * half)
    [saved] = state.load(state.save(tmp_path / "auto.state", [rendered(j, half)]))
    assert saved.plain["balance.moves"] > 0
    p, _ = resume(saved)
    for _ in range(half):
        p.method.iterate()
    assert p.method.balance.log2_centre == straight.plain["balance.log2_centre"]
    assert p.method.balance.moves == straight.plain["balance.moves"] > saved.plain["balance.moves"]
    assert np.array_equal(p.method.image(), straight.image)
    p.release()


def test_resume_of_vcm_with_the_balanced_radius_equals_straight(tmp_path):
    """The balanced radius (methods/merge_radius.py): its schedule and the sums of r^2 behind
    its decisions are part of the state, so a render saved after the rule has taken fast steps
    resumes to the same radii and the same image (merging alone from a wide radius, where the
    bias dominates: tests/test_vcm.py)."""
    j = Job(scene=CORNELL, params=SMALL, method="vcm", seed=3,
            options={"techniques": "bpm", "radius": 0.3, "light_paths": 1024})
    half = 40
    straight = rendered(j, 2 * half)
    [saved] = state.load(state.save(tmp_path / "radius.state", [rendered(j, half)]))
    assert saved.plain["radius_schedule.fast_steps"] > 0
    p, _ = resume(saved)
    for _ in range(half):
        p.method.iterate()
    assert p.method.radius_schedule.fast_steps == straight.plain["radius_schedule.fast_steps"] > \
        saved.plain["radius_schedule.fast_steps"]
    assert p.method.radius == straight.plain["radius"]
    assert np.array_equal(p.method.image(), straight.image)
    p.release()


def test_resume_across_mbe_vcm_passes_equals_straight(tmp_path):
    """mbe's vcm passes (methods/pass_choice.py) render into its film with a Vcm of their own:
    its fields and the choice's sums are part of the state, so a render saved while vcm passes
    win (mesh-room, 16x16: four chain passes, then vcm passes) resumes to the same image and
    the same sequence of pass kinds."""
    j = Job(scene=str(SCENES / "mesh-room" / "scene.xml"), params=SMALL, method="mbe", seed=3,
            options={"light_paths": 256})
    straight = rendered(j, 14)
    [saved] = state.load(state.save(tmp_path / "mbe.state", [rendered(j, 7)]))
    assert saved.plain["pass_choice.vcm_passes"] > 0
    p, _ = resume(saved)
    for _ in range(7):
        p.method.iterate()
    assert p.method.pass_choice.vcm_passes == straight.plain["pass_choice.vcm_passes"]
    assert np.array_equal(p.method.image(), straight.image)
    p.release()


def test_a_state_that_misses_part_of_the_method_does_not_resume_straight(monkeypatch, tmp_path):
    """The check above can fail: leave the chain pool out of visibility's state and the
    resumed image differs."""
    from photonmc.kernels.mcmc import ChainPool
    straight = rendered(job("visibility"), 6)
    monkeypatch.setattr(ChainPool, "TRANSIENT", ChainPool.TRANSIENT + ("u", "T", "theta"), raising=False)
    half = rendered(job("visibility"), 3)
    p, _ = resume(half)
    for _ in range(3):
        p.method.iterate()
    assert not np.array_equal(p.method.image(), straight.image)
    p.release()


def test_capture_refuses_state_it_cannot_save():
    p = job("pt").prepare()
    try:
        p.method.unsaveable = object()
        with pytest.raises(TypeError, match="unsaveable holds a object"):
            state.capture(p.method)
    finally:
        p.release()


def test_cli_resume_counts_the_whole_render(tmp_path):
    from photonmc.cli import main
    from photonmc.imageio import read_image
    args = [CORNELL, "-D", "res=16", "--method", "sppm", "--seed", "2", "--quiet"]
    assert main(["render", *args, "--iterations", "3", "--out", str(tmp_path / "a.exr")]) == 0
    assert (tmp_path / "a.state").is_file()
    assert main(["render", "--resume", str(tmp_path / "a.state"), "--iterations", "7", "--quiet"]) == 0
    assert main(["render", *args, "--iterations", "7", "--out", str(tmp_path / "b.exr")]) == 0
    assert np.array_equal(read_image(tmp_path / "a.exr"), read_image(tmp_path / "b.exr"))
    [a] = state.load(tmp_path / "a.state")
    assert a.iterations == 7
    # Already past the budget: nothing more is rendered, the image is written again.
    assert main(["render", "--resume", str(tmp_path / "a.state"), "--iterations", "5", "--quiet"]) == 0
    assert state.load(tmp_path / "a.state")[0].iterations == 7
    # --time counts the whole render too: a budget the saved render has spent adds nothing.
    spent = state.load(tmp_path / "a.state")[0].elapsed
    assert spent > 0
    assert main(["render", "--resume", str(tmp_path / "a.state"), "--time", str(spent / 2), "--quiet"]) == 0
    assert state.load(tmp_path / "a.state")[0].iterations == 7


def test_cli_resume_refuses_settings_of_its_own(tmp_path, capsys):
    from photonmc.cli import main
    path = state.save(tmp_path / "x.state", [rendered(job("pt"), 1)])
    assert main(["render", "--resume", str(path), "--method", "sppm", "--photons", "9"]) == 2
    assert "do not give --method, --photons" in capsys.readouterr().err


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    path = tmp_path_factory.mktemp("states") / "good.state"
    state.save(path, [rendered(job("pt"), 2)])
    return path


def _rewrite_header(src, dst, change):
    with np.load(src) as z:
        arrays = {k: z[k] for k in z.files}
    header = json.loads(bytes(arrays["header"]).decode())
    change(header)
    arrays["header"] = np.frombuffer(json.dumps(header).encode(), np.uint8)
    with open(dst, "wb") as f:
        np.savez(f, **arrays)
    return dst


@pytest.mark.parametrize("case, message", [
    ("truncated", "truncated or corrupt"),
    ("corrupt", "truncated or corrupt"),
    ("not-a-state", "truncated or corrupt"),
    ("missing", "not found"),
    ("version", "written by photonmc 0.0.1"),
    ("format", "is not a photonmc render state"),
])
def test_bad_state_files_are_refused_in_one_line(case, message, saved, tmp_path):
    bad = tmp_path / "bad.state"
    data = saved.read_bytes()
    if case == "truncated":
        bad.write_bytes(data[: len(data) * 2 // 3])
    elif case == "corrupt":
        # Flip bytes inside the largest stored array: the zip's CRC-32 catches it.
        with zipfile.ZipFile(saved) as z:
            info = max(z.infolist(), key=lambda i: i.compress_size)
        start = info.header_offset + 30 + len(info.filename) + len(info.extra) + info.compress_size // 2
        bad.write_bytes(data[:start] + bytes(b ^ 0xFF for b in data[start:start + 16]) + data[start + 16:])
    elif case == "not-a-state":
        bad.write_text("<scene/>")
    elif case == "version":
        _rewrite_header(saved, bad, lambda h: h.update(photonmc_version="0.0.1"))
    elif case == "format":
        _rewrite_header(saved, bad, lambda h: h.update(format="something-else"))
    with pytest.raises(state.StateError, match=message) as e:
        state.load(bad)
    assert "\n" not in str(e.value)


def test_state_of_another_scene_or_method_is_refused(saved):
    [member] = state.load(saved)
    other = dict(member.job, params={"res": "16", "max_depth": "3"})
    with pytest.raises(state.StateError, match="different scene"):
        resume(state.RenderState(**{**vars(member), "job": other}))
    with pytest.raises(state.StateError, match="a 'pt' render, not 'sppm'"):
        from photonmc.scene import load_scene
        state.check_fits(member, load_scene(CORNELL, SMALL), "sppm")


def test_an_interrupted_write_keeps_the_previous_state(saved, tmp_path, monkeypatch):
    path = tmp_path / "keep.state"
    path.write_bytes(saved.read_bytes())
    [member] = state.load(path)

    def dies_half_way(f, members):
        f.write(b"PK\x03\x04 partial")
        raise KeyboardInterrupt

    monkeypatch.setattr(state, "_write_npz", dies_half_way)
    with pytest.raises(KeyboardInterrupt):
        state.save(path, [member])
    monkeypatch.undo()
    assert state.load(path)[0].iterations == member.iterations
    assert [p.name for p in tmp_path.iterdir()] == ["keep.state"]     # no temporary left behind


# -- merging --------------------------------------------------------------------------------------
def test_merge_of_pt_renders_is_their_sample_average_and_error_falls_as_one_over_sqrt_k():
    """K independent pt renders of n iterations, merged: exactly the mean of all their
    samples, and the mean squared error against a long render falls like 1/K (RMSE like
    K^-1/2). The MSE for each K is averaged over the disjoint groups of K of 16 renders:
    one render's RMSE at 4 samples per pixel is dominated by a few bright pixels."""
    n, ks, count = 4, (1, 2, 4, 8), 16
    members = [rendered(job("pt", seed=worker_seed(11, k)), n) for k in range(count)]
    reference = rendered(job("pt", seed=99), 2048).image
    mse = []
    for k in ks:
        groups = [members[g:g + k] for g in range(0, count, k)]
        for group in groups:
            assert np.allclose(merged_image(group), sum(m.image for m in group) / k, rtol=1e-12, atol=0)
        mse.append(float(np.mean([np.mean((merged_image(group) - reference) ** 2) for group in groups])))
    slope = np.polyfit(np.log(ks), np.log(np.sqrt(mse)), 1)[0]
    print(f"merged pt RMSE {np.round(np.sqrt(mse), 5).tolist()} for K = {ks}: slope {slope:.2f}")
    assert -0.62 < slope < -0.38


def test_interleaved_vcm_slices_merge_into_the_single_render():
    """With a fixed --light-paths and the progressive radius, vcm's radius depends on the
    iteration index alone, so the iterations 0, 2, 4 and 1, 3, 5 rendered apart merge into the
    6-iteration render, bias and all; sppm refuses slices, and so does vcm's default radius
    rule, whose radius follows the bias measured before each pass."""
    progressive = {**OPTIONS["vcm"], "radius_rule": "progressive"}
    halves = [rendered(Job(scene=CORNELL, params=SMALL, method="vcm", seed=3, options=progressive,
                           iteration_slice=(k, 2)), 3) for k in range(2)]
    single = rendered(Job(scene=CORNELL, params=SMALL, method="vcm", seed=3, options=progressive), 6).image
    assert np.allclose(merged_image(halves), single, rtol=1e-12, atol=1e-15)
    for method in ("sppm", "vcm"):
        with pytest.raises(PhotonmcError, match="cannot render interleaved slices"):
            job(method, iteration_slice=(0, 2)).prepare()


def test_merge_refuses_renders_that_are_not_independent_or_not_alike():
    a = rendered(job("pt", seed=1), 1)
    b = rendered(job("pt", seed=2), 1)
    check_mergeable([a, b])
    with pytest.raises(state.StateError, match="both have seed 1"):
        check_mergeable([a, a])
    # Interleaved slices of one render share a seed; overlapping ones are refused.
    halves = [rendered(Job(scene=CORNELL, params=SMALL, method="pt", seed=1, iteration_slice=(k, 2)), 1)
              for k in range(2)]
    check_mergeable(halves)
    with pytest.raises(state.StateError, match="both have seed 1"):
        check_mergeable([a, halves[1]])
    with pytest.raises(state.StateError, match="other settings"):
        check_mergeable([a, state.RenderState(**{**vars(b), "job": {**b.job, "max_depth": 2}})])
    with pytest.raises(state.StateError, match="different scene"):
        check_mergeable([a, state.RenderState(**{**vars(b), "scene_hash": "0"})])
    s = rendered(job("sppm", seed=2), 1)
    with pytest.raises(state.StateError, match="cannot merge a 'sppm' render with a 'pt' render"):
        check_mergeable([a, s])


def test_cli_merge_writes_image_and_merged_state(tmp_path):
    from photonmc.cli import main
    from photonmc.imageio import read_image
    paths = [state.save(tmp_path / f"{k}.state", [rendered(job("sppm", seed=k), 2 + k)]) for k in range(2)]
    assert main(["merge", *map(str, paths), "--out", str(tmp_path / "m.exr")]) == 0
    members = state.load(tmp_path / "m.state")
    assert [m.iterations for m in members] == [2, 3]
    expected = (2 * members[0].image + 3 * members[1].image) / 5
    assert np.allclose(read_image(tmp_path / "m.exr"), expected, rtol=1e-6, atol=1e-7)


# -- a local Ray cluster ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def ray_cluster():
    """One local cluster for the module's distributed renders (render() joins a running one)."""
    import ray
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    yield
    ray.shutdown()


def _render_killing_worker_1(j: Job, iterations: int):
    from photonmc import distributed
    killed = None
    for progress in distributed.render(j, Budget(iterations=iterations)):
        counts = [w.iterations for w in progress.workers]
        if killed is None and counts[1] >= 3:
            killed = counts[1]
            os.kill(progress.workers[1].pid, signal.SIGKILL)
    assert killed is not None and killed < iterations // 2
    assert [w.restarts for w in progress.workers] == [0, 1]
    assert "worker 1 died" in progress.events[0]
    return progress


def test_pt_on_two_ray_workers_one_killed_is_the_single_render(ray_cluster):
    """pt's iterations are independent: 2 workers render the even and odd iterations of one
    render. Worker 1's process is killed (SIGKILL) mid-render; its replacement resumes from
    its last state, so the merge is still the single-process render of the same seed and
    total iterations (to float rounding)."""
    progress = _render_killing_worker_1(job("pt", seed=5, workers=2, sync_interval=0.0), 24)
    assert [w.iterations for w in progress.workers] == [12, 12]
    assert [m.job["iteration_slice"] for m in progress.members] == [[0, 2], [1, 2]]
    single = rendered(job("pt", seed=5), 24).image
    assert np.allclose(progress.image(), single, rtol=1e-12, atol=1e-15)


def test_sppm_on_two_ray_workers_one_killed_loses_nothing(ray_cluster):
    """sppm's radii carry over between iterations: each worker renders its own seed stream.
    With worker 1 killed mid-render, the merge is exactly that of both streams rendered
    undisturbed in this process: the kill cost the iteration in flight and nothing else."""
    progress = _render_killing_worker_1(job("sppm", seed=5, workers=2, sync_interval=0.0), 16)
    assert [w.iterations for w in progress.workers] == [8, 8]
    undisturbed = merged_image([rendered(job("sppm", seed=worker_seed(5, k)), 8) for k in range(2)])
    assert np.array_equal(progress.image(), undisturbed)


def test_distributed_bad_input_is_one_line(tmp_path, ray_cluster):
    """A bad scene is refused before any worker starts; a bad option by the workers."""
    from photonmc import distributed
    bad = tmp_path / "bad.xml"
    bad.write_text('<scene version="3.0.0"><shape type="teapot"/></scene>')
    with pytest.raises(PhotonmcError, match="teapot"):
        list(distributed.render(Job(scene=str(bad), workers=2), Budget(iterations=2)))
    with pytest.raises(PhotonmcError, match="--photons must be between 1 and 2"):
        list(distributed.render(Job(scene=CORNELL, params=SMALL, method="sppm", options={"photons": 0}, workers=2),
                                Budget(iterations=2)))


def test_cli_workers_then_resume_the_merged_state(tmp_path, capsys, ray_cluster):
    """`render --workers 2` writes the merged image and a state of both slices; resuming
    that state goes on with both (2 workers) to the new total, which is the single render."""
    from photonmc.cli import main
    from photonmc.imageio import read_image
    out = tmp_path / "w.exr"
    assert main(["render", CORNELL, "-D", "res=16", "--workers", "2", "--iterations", "5", "--seed", "4",
                 "--out", str(out), "--quiet"]) == 0
    members = state.load(tmp_path / "w.state")
    assert [m.iterations for m in members] == [3, 2] and [m.seed for m in members] == [4, 4]
    assert np.allclose(read_image(out), merged_image(members), rtol=1e-6, atol=1e-7)
    assert main(["render", "--resume", str(tmp_path / "w.state"), "--iterations", "8", "--quiet"]) == 0
    members = state.load(tmp_path / "w.state")
    assert [m.iterations for m in members] == [4, 4]
    single = rendered(Job(scene=CORNELL, params=SMALL, method="pt", seed=4), 8).image
    assert np.allclose(merged_image(members), single, rtol=1e-12, atol=1e-15)
    assert main(["render", "--resume", str(tmp_path / "w.state"), "--workers", "1", "--iterations", "9"]) == 2
    assert "the state holds 2 renders: resume it with --workers 2 or more" in capsys.readouterr().err


def test_api_iterate_on_workers_shows_the_merged_image(ray_cluster):
    import photonmc
    frames = list(photonmc.iterate(CORNELL, method="sppm", iterations=4, workers=2, params=SMALL, photons=512))
    assert [f.iteration for f in frames][-1] == 4
    assert frames[-1].stats["renders"] == 2 and frames[-1].stats["iterations_per_render"] == [2, 2]
    assert frames[-1].image.shape == (16, 16, 3) and frames[-1].image.mean() > 0


@pytest.mark.parametrize("options,half,learned", [
    ({"photons": 512, "pss_guide": 2}, 4, "pss_guide.updates"),
    ({"photons": 512}, 24, "pass_choice.uniform_passes")], ids=["learned-warp", "uniform-passes"])
def test_resume_of_what_visibility_learned_equals_straight(tmp_path, options, half, learned):
    """visibility --pss-guide 2: the warp's learned counts (per ladder) and its tables are part
    of the state; by default, its choice between chain and uniform passes (methods/
    photon_passes.py: the work and variance it has measured). A render saved after it has
    learned (`learned` > 0) resumes to the straight image, making the same choices."""
    j = Job(scene=CORNELL, params=SMALL, method="visibility", seed=3, options=options)
    straight = rendered(j, 2 * half)
    [saved] = state.load(state.save(tmp_path / "learned.state", [rendered(j, half)]))
    assert saved.plain[learned] > 0, f"nothing learned before the save ({learned})"
    p, _ = resume(saved)
    for _ in range(half):
        p.method.iterate()
    assert np.array_equal(p.method.image(), straight.image)
    assert p.method.pass_choice.uniform_passes == straight.plain["pass_choice.uniform_passes"]
    p.release()


def test_resume_across_a_spatial_epoch_equals_straight(tmp_path):
    """spatial-tf --spatial-updates epochs: the frozen statistics, the epoch's scales and the
    chain-pass count that sets the next epoch start are part of the state; saved after 6
    chain passes, the render resumes through the epoch start at pass 8 to the straight image."""
    j = Job(scene=CORNELL, params=SMALL, method="spatial-tf", seed=3,
            options={"photons": 512, "spatial_updates": "epochs", "uniform_passes": "off"})
    straight = rendered(j, 12)
    [saved] = state.load(state.save(tmp_path / "epochs.state", [rendered(j, 6)]))
    assert saved.plain["chain_passes"] == 6
    p, _ = resume(saved)
    for _ in range(6):
        p.method.iterate()
    assert np.array_equal(p.method.image(), straight.image)
    p.release()


def test_resume_with_clipped_discs_equals_straight(tmp_path):
    """sppm --disc clipped: which pixels have shown an edge (and so are probed every pass) is
    part of the state, so the resumed render probes the same points and gives the same image."""
    j = Job(scene=CORNELL, params=SMALL, method="sppm", seed=3, options={"photons": 512, "disc": "clipped"})
    straight = rendered(j, 12)
    [saved] = state.load(state.save(tmp_path / "clipped.state", [rendered(j, 5)]))
    assert saved.arrays["edge_pixel"].any(), "no edge found before the save"
    p, _ = resume(saved)
    for _ in range(7):
        p.method.iterate()
    assert np.array_equal(p.method.image(), straight.image)
    p.release()

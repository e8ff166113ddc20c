"""`photonmc converge`: CSV, plot and table for two methods."""
import csv

import numpy as np
import pytest

from photonmc import metrics
from photonmc.cli import main
from photonmc.imageio import read_image, write_image
from photonmc.loop import Budget, prepare, run

from .conftest import SCENES

CORNELL = str(SCENES / "cornell-box" / "scene.xml")


def test_converge_writes_csv_plot_and_table(tmp_path, capsys):
    from photonmc import load_scene
    p = prepare(load_scene(CORNELL, {"res": 16}), method="pt", seed=11)
    ref = run(p, Budget(iterations=512), quiet=True).image
    p.release()
    write_image(tmp_path / "ref.exr", ref)
    out = tmp_path / "conv"
    rc = main(["converge", CORNELL, "-D", "res=16", "--methods", "pt,sppm", "--reference", str(tmp_path / "ref.exr"),
               "--iterations", "16", "--out", str(out)])
    assert rc == 0
    rows = list(csv.DictReader(open(out / "convergence.csv")))
    assert {r["method"] for r in rows} == {"pt", "sppm"}
    for method in ("pt", "sppm"):
        mine = [r for r in rows if r["method"] == method]
        assert [int(r["iterations"]) for r in mine][-1] == 16
        assert all(float(r["rmse"]) > 0 and float(r["elapsed_s"]) > 0 for r in mine)
        errors = [float(r["rmse"]) for r in mine]
        assert errors[-1] < errors[0]             # more work, less error
        assert read_image(out / f"{method}.exr").shape == (16, 16, 3)
    assert (out / "convergence.png").stat().st_size > 1000
    table = (out / "convergence.md").read_text()
    assert "Equal-time ranking" in table and "| pt |" in table and "| sppm |" in table
    assert "Equal-time ranking" in capsys.readouterr().out


def test_interleaved_rounds_render_what_one_method_after_the_other_renders(tmp_path):
    """--interleave (methods rendered together in alternating rounds): with an iteration
    budget every method's images, iteration counts and errors at each checkpoint are those of
    the plain run, method by method (the rounds change when each method runs, not what)."""
    from photonmc import load_scene
    p = prepare(load_scene(CORNELL, {"res": 16}), method="pt", seed=11)
    ref = run(p, Budget(iterations=256), quiet=True).image
    p.release()
    write_image(tmp_path / "ref.exr", ref)
    rows = {}
    for mode in ("plain", "interleaved"):
        out = tmp_path / mode
        rc = main(["converge", CORNELL, "-D", "res=16", "--methods", "pt,sppm", "--reference", str(tmp_path / "ref.exr"),
                   "--iterations", "20", "--seeds", "1,2", "--out", str(out)] + (["--interleave"] if mode != "plain" else []))
        assert rc == 0
        rows[mode] = sorted((r["method"], int(r["seed"]), int(r["iterations"]), r["rmse"])
                            for r in csv.DictReader(open(out / "convergence.csv")))
        assert ("; interleaved" in (out / "convergence.md").read_text()) == (mode != "plain")
    assert rows["plain"] == rows["interleaved"] and len(rows["plain"]) > 8
    for name in ("pt-seed1", "sppm-seed2"):
        assert np.array_equal(read_image(tmp_path / "plain" / f"{name}.exr"),
                              read_image(tmp_path / "interleaved" / f"{name}.exr"))


def test_converge_rejects_a_reference_of_the_wrong_size(tmp_path, capsys):
    write_image(tmp_path / "ref.exr", np.zeros((8, 8, 3)))
    rc = main(["converge", CORNELL, "-D", "res=16", "--methods", "pt", "--reference", str(tmp_path / "ref.exr"),
               "--iterations", "2", "--out", str(tmp_path / "c")])
    assert rc == 2
    assert "reference is 8x8 but the scene renders 16x16" in capsys.readouterr().err


def test_converge_over_seeds_reports_means_and_the_spread(tmp_path):
    from photonmc import load_scene
    halves = []
    for seed in (11, 12):
        p = prepare(load_scene(CORNELL, {"res": 16}), method="pt", seed=seed)
        halves.append(run(p, Budget(iterations=256), quiet=True).image)
        p.release()
    ref = (halves[0] + halves[1]) / 2
    # the reference's own MSE, as tools/make_reference.py writes it: from its two halves
    noise_mse = float(np.mean((halves[0] - halves[1]) ** 2) / 4)
    write_image(tmp_path / "ref.exr", ref, {"noise_mse": noise_mse})
    out = tmp_path / "conv"
    rc = main(["converge", CORNELL, "-D", "res=16", "--methods", "pt", "--reference", str(tmp_path / "ref.exr"),
               "--iterations", "4", "--seeds", "3,4,5", "--out", str(out)])
    assert rc == 0
    rows = list(csv.DictReader(open(out / "convergence.csv")))
    assert {int(r["seed"]) for r in rows} == {3, 4, 5}
    finals = {int(r["seed"]): r for r in rows if int(r["iterations"]) == 4}
    images = [read_image(out / f"pt-seed{k}.exr") for k in (3, 4, 5)]
    assert not np.array_equal(images[0], images[1])            # independent seeds
    table = (out / "convergence.md").read_text()
    assert "seeds 3,4,5" in table and "per-pixel relMSE CV, seeds" in table
    rmses = [float(finals[k]["rmse"]) for k in (3, 4, 5)]
    assert f"| {np.mean(rmses):.4g} +- " in table
    denoised = np.mean([np.sqrt(e * e - noise_mse) for e in rmses])
    assert "RMSE, reference noise removed" in table and f"| {denoised:.4g} +- " in table
    # the split into noise and systematic error is the seeds' images' (what it means is
    # tests/test_metrics.py's). pt is unbiased, so the systematic part is what three seeds
    # of its heavy-tailed 4-sample images leave: 0 to 0.95x the noise over seed triples 3-26
    # against a reference whose noise was understated, so below the noise with its own
    # recorded; a bias as large as the noise (a wrong reference, a split that forgot the
    # reference's noise) fails it
    noise, systematic = metrics.noise_and_systematic_error(images, read_image(tmp_path / "ref.exr"), noise_mse)
    assert f"| {noise:.4g}, {systematic:.4g} |" in table
    assert systematic < noise


def test_converge_refuses_repeated_seeds(tmp_path, capsys):
    write_image(tmp_path / "ref.exr", np.zeros((16, 16, 3)))
    with pytest.raises(SystemExit) as e:
        main(["converge", CORNELL, "-D", "res=16", "--methods", "pt", "--reference", str(tmp_path / "ref.exr"),
              "--iterations", "2", "--seeds", "1,1"])
    assert e.value.code == 2
    assert "give distinct seeds" in capsys.readouterr().err

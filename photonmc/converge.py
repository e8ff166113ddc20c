"""Error against time for several methods on one scene: `photonmc converge`.

Each method runs in this process after a warm-up iteration (then reset), so kernel
compilation is excluded. At checkpoints spaced geometrically in time (or iterations) the
current image is compared with the reference; the comparison's own cost is excluded from
the clock. Writes convergence.csv, convergence.png (log-log error against time) and
convergence.md (final figures and the equal-time ranking), plus each method's final image.

With several seeds (`--seeds 0,1,2,3`) every method renders once per seed: the table gives
the mean and spread over seeds, and the per-pixel relative-error spread is estimated from
the seeds with the single-render noise removed (`metrics.relmse_spread_over_seeds`), and
each method's RMSE is split into noise (what the seeds average away) and systematic error
(what they share at this budget, e.g. photon mapping's radius bias;
`metrics.noise_and_systematic_error`).

The methods run one after the other, or with `--interleave` together in alternating rounds
of a sixteenth of the budget each: on a shared machine whose speed drifts by 10-40 % within
minutes (a virtual machine's steal time), one after the other gives each method different
machine time for its budget, and the equal-time ranking inherits that (docs/convergence.md).
"""
from __future__ import annotations

import csv
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import imageio, metrics
from .errors import PhotonmcError
from .methods import method_class
from .loop import Budget, prepare

CHECKPOINT_GROWTH = 1.5
INTERLEAVE_ROUNDS = 16     # --interleave: rounds of budget / 16 per method, alternating


@dataclass
class Checkpoint:
    method: str
    seed: int
    elapsed: float
    iterations: int
    rmse: float
    relmse: float
    bias: float
    relmse_cv: float          # spread of per-pixel relMSE (std / mean)


def _schedule(total: float, first: float):
    """Geometric checkpoints from `first` up to `total` (inclusive)."""
    points, t = [], first
    while t < total:
        points.append(t)
        t *= CHECKPOINT_GROWTH
    return points + [total]


class _Run:
    """One method and seed rendering against the reference: prepared and compiled on
    creation (a warm-up iteration, then reset), then advanced to a point of its own clock
    (seconds of its iterations, compilation and comparisons excluded) or iteration count."""

    def __init__(self, scene, method: str, reference: np.ndarray, budget: Budget, seed: int, options, max_depth):
        self.method, self.seed, self.reference = method, seed, reference
        self.eps = metrics.relmse_epsilon(reference)
        self.p = prepare(scene, method=method, seed=seed, options=options, max_depth=max_depth)
        try:
            h, w = self.p.dscene.height, self.p.dscene.width
            if reference.shape[:2] != (h, w):
                raise PhotonmcError(f"reference is {reference.shape[1]}x{reference.shape[0]} but the scene renders "
                                    f"{w}x{h} (set the resolution with -D, e.g. -D res={reference.shape[1]})")
            self.p.method.warm_up()          # compiles every kernel
            self.p.method.reset()
        except BaseException:
            self.p.release()
            raise
        self.by_time = budget.time is not None
        self.total = budget.time if self.by_time else float(budget.iterations)
        self.pending = _schedule(self.total, self.total / 64 if self.by_time else 1.0)
        self.points, self.clock = [], 0.0

    def advance(self, until: float) -> None:
        """Iterate until the budget's measure (seconds or iterations) reaches `until` or the
        budget ends, comparing with the reference at each checkpoint passed."""
        m = self.p.method
        while self.pending:
            progress = self.clock if self.by_time else m.iterations
            if progress >= until - 1e-12:
                return
            t = time.perf_counter()
            m.iterate()
            self.clock += time.perf_counter() - t
            progress = self.clock if self.by_time else m.iterations
            if progress >= self.pending[0] - 1e-12:
                while self.pending and progress >= self.pending[0] - 1e-12:
                    self.pending.pop(0)
                img, ref = m.image(), self.reference
                self.points.append(Checkpoint(self.method, self.seed, self.clock, m.iterations,
                                              metrics.rmse(img, ref), metrics.relmse(img, ref, self.eps),
                                              metrics.mean_luminance_bias(img, ref),
                                              metrics.relmse_spread(img, ref, self.eps)))

    def finish(self) -> tuple[list[Checkpoint], np.ndarray, dict]:
        """(checkpoints, final image, statistics); releases the method."""
        try:
            return self.points, self.p.method.image().astype(np.float32), self.p.method.stats()
        finally:
            self.p.release()


def measure(scene, method: str, reference: np.ndarray, budget: Budget, seed: int = 0, options=None,
            max_depth=None) -> tuple[list[Checkpoint], np.ndarray, dict]:
    run = _Run(scene, method, reference, budget, seed, options, max_depth)
    try:
        run.advance(math.inf)
    except BaseException:
        run.p.release()
        raise
    return run.finish()


def measure_interleaved(scene, methods: list[str], reference: np.ndarray, budget: Budget, seed: int, options: dict,
                        max_depth=None, rounds: int = INTERLEAVE_ROUNDS) -> list:
    """measure() for every method at once, in `rounds` alternating rounds of an equal share of
    the budget each (the order reversed every other round), so that a machine whose speed
    drifts (a shared host's steal time) drifts for every method alike. Every method is
    prepared and compiled first, and all stay in memory together. Returns measure()'s
    results in `methods` order."""
    runs = []
    try:
        for name in methods:
            runs.append(_Run(scene, name, reference, budget, seed, options[name], max_depth))
        total = runs[0].total
        for r in range(1, rounds + 1):
            for run in (runs if r % 2 else runs[::-1]):
                run.advance(total * r / rounds if r < rounds else math.inf)
    except BaseException:
        for run in runs:
            run.p.release()
        raise
    return [run.finish() for run in runs]


def slope(points: list[Checkpoint], key="rmse") -> float | None:
    """Log-log slope of error against time over the second half of the checkpoints."""
    pts = [p for p in points if getattr(p, key) > 0 and p.elapsed > 0]
    pts = pts[len(pts) // 2:]
    if len(pts) < 2:
        return None
    x = np.log([p.elapsed for p in pts])
    y = np.log([getattr(p, key) for p in pts])
    return float(np.polyfit(x, y, 1)[0])


def write_csv(path: Path, points: list[Checkpoint]):
    with open(path, "w", newline="") as f:
        out = csv.writer(f)
        out.writerow(["method", "seed", "elapsed_s", "iterations", "rmse", "relmse", "mean_luminance_bias",
                      "relmse_cv"])
        for p in points:
            out.writerow([p.method, p.seed, f"{p.elapsed:.6g}", p.iterations, f"{p.rmse:.6g}", f"{p.relmse:.6g}",
                          f"{p.bias:.6g}", f"{p.relmse_cv:.6g}"])


def write_plot(path: Path, by_method: dict, title: str, eps: float):
    """by_method: name -> one list of checkpoints per seed (one curve each, one colour per method)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for i, (name, runs) in enumerate(by_method.items()):
        for k, pts in enumerate(runs):
            t = [p.elapsed for p in pts]
            style = dict(color=f"C{i}", markersize=3, label=name if k == 0 else None)
            axes[0].loglog(t, [p.rmse for p in pts], "o-", **style)
            axes[1].loglog(t, [p.relmse for p in pts], "o-", **style)
    axes[0].set_ylabel("RMSE")
    axes[1].set_ylabel(f"relMSE (eps={eps:.3g})")
    for ax in axes:
        ax.set_xlabel("render time [s] (compilation excluded)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _mean_spread(values) -> str:
    """'m' for one value, 'm +- s' (sample std over seeds) for several."""
    v = np.asarray(values, np.float64)
    return f"{v.mean():.4g}" if len(v) < 2 else f"{v.mean():.4g} +- {v.std(ddof=1):.2g}"


def write_table(path: Path, by_method: dict, header: str, seeds_spread: dict | None = None,
                reference_noise_mse: float = 0.0, error_split: dict | None = None) -> str:
    """by_method: name -> one list of checkpoints per seed; seeds_spread: name -> the per-pixel
    relMSE spread over seeds (None with one seed); reference_noise_mse: the reference's own
    expected squared error (from its header), removed from the RMSE in quadrature in an extra
    column, since an image equal to the truth would still show it; error_split: name -> (noise,
    systematic) RMSE over seeds (metrics.noise_and_systematic_error; None with one seed)."""
    finals = {name: [pts[-1] for pts in runs if pts] for name, runs in by_method.items()}
    finals = {name: f for name, f in finals.items() if f}
    # Equal-time ranking: every run's error interpolated (log-log) at the shortest final time,
    # averaged over seeds.
    t_eq = min(p.elapsed for f in finals.values() for p in f)
    at_eq = {name: float(np.mean([_interpolate(pts, t_eq) for pts in runs if pts]))
             for name, runs in by_method.items()}
    n_seeds = max(len(f) for f in finals.values())
    lines = [header, ""]
    if n_seeds > 1:
        lines += [f"Mean +- standard deviation over {n_seeds} seeds. \"per-pixel relMSE CV, seeds\": the spread over "
                  "pixels of each pixel's expected relMSE, single-render noise removed. \"RMSE: noise, "
                  "systematic\": one render's RMSE split into what the seeds average away and what they "
                  "share (their mean image's error, its noise and the reference's removed).", ""]
    cv_head = " per-pixel relMSE CV, seeds | RMSE: noise, systematic |" if n_seeds > 1 else ""
    noise_head = " RMSE, reference noise removed |" if reference_noise_mse > 0 else ""
    lines += ["| method | time [s] | iterations | RMSE |" + noise_head + " relMSE | per-pixel relMSE CV, one render |"
              + cv_head + " mean-luminance bias | RMSE slope vs time |",
              "|---|---|---|---|" + ("---|" if noise_head else "") + "---|---|" + ("---|---|" if n_seeds > 1 else "")
              + "---|---|"]
    for name, f in finals.items():
        slopes = [s for s in (slope(pts) for pts in by_method[name]) if s is not None]
        cv = ""
        if n_seeds > 1:
            c = (seeds_spread or {}).get(name)
            split = (error_split or {}).get(name)
            cv = (f" {'n/a' if c is None else f'{c:.2f}'} |"
                  f" {'n/a' if split is None else f'{split[0]:.4g}, {split[1]:.4g}'} |")
        denoised = ""
        if reference_noise_mse > 0:
            denoised = f" {_mean_spread([math.sqrt(max(0.0, p.rmse ** 2 - reference_noise_mse)) for p in f])} |"
        lines.append(f"| {name} | {np.mean([p.elapsed for p in f]):.2f} | {_mean_spread([p.iterations for p in f])} "
                     f"| {_mean_spread([p.rmse for p in f])} |{denoised} {_mean_spread([p.relmse for p in f])} "
                     f"| {np.mean([p.relmse_cv for p in f]):.2f} |{cv} "
                     f"{100 * np.mean([p.bias for p in f]):+.2f} % | "
                     f"{'n/a' if not slopes else f'{np.mean(slopes):.2f}'} |")
    lines += ["", f"Equal-time ranking at {t_eq:.2f} s (RMSE, lower is better):", ""]
    for rank, (name, e) in enumerate(sorted(at_eq.items(), key=lambda kv: kv[1]), 1):
        lines.append(f"{rank}. {name}: RMSE {e:.4g}")
    text = "\n".join(lines) + "\n"
    path.write_text(text)
    return text


def _interpolate(points: list[Checkpoint], t: float) -> float:
    ts = np.array([p.elapsed for p in points])
    es = np.array([p.rmse for p in points])
    if t <= ts[0]:
        return float(es[0])
    return float(math.exp(np.interp(math.log(t), np.log(ts), np.log(np.maximum(es, 1e-300)))))


def converge(scene, scene_label: str, methods: list[str], reference_path, budget: Budget, out_dir, seeds=(0,),
             options=None, max_depth=None, log=print, interleave: bool = False):
    reference = imageio.read_image(reference_path)
    reference_noise = float(imageio.read_metadata(reference_path).get("noise_mse", 0.0))
    eps = metrics.relmse_epsilon(reference)
    seeds = list(seeds)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    # each method takes the options it knows (e.g. --chains goes to the guided methods only)
    opts = {name: {k: v for k, v in (options or {}).items() if v is not None and k in method_class(name).OPTIONS}
            for name in methods}
    results = {name: {} for name in methods}        # name -> seed -> (points, image, stats)
    if interleave:
        for seed in seeds:
            log(f"converge: {', '.join(methods)} interleaved, seed {seed} ...")
            for name, result in zip(methods, measure_interleaved(scene, methods, reference, budget, seed, opts,
                                                                 max_depth)):
                results[name][seed] = result
    else:
        for name in methods:
            for seed in seeds:
                log(f"converge: {name}, seed {seed} ...")
                results[name][seed] = measure(scene, name, reference, budget, seed=seed, options=opts[name],
                                              max_depth=max_depth)
    by_method, spread, split, all_points = {}, {}, {}, []
    for name in methods:
        runs, images = [], []
        for seed in seeds:
            points, image, stats = results[name][seed]
            runs.append(points)
            images.append(image)
            all_points += points
            suffix = "" if len(seeds) == 1 else f"-seed{seed}"
            imageio.write_image(out_dir / f"{name}{suffix}.exr", image, {"method": name, "seed": seed,
                                                                         "iterations": stats["iterations"]})
            # the run's statistics (what --stats writes): e.g. what an automatic setting chose
            (out_dir / f"{name}{suffix}.json").write_text(json.dumps(stats, indent=1, default=str))
        by_method[name] = runs
        spread[name] = metrics.relmse_spread_over_seeds(images, reference, eps)
        split[name] = metrics.noise_and_systematic_error(images, reference, reference_noise)
    write_csv(out_dir / "convergence.csv", all_points)
    write_plot(out_dir / "convergence.png", by_method, f"{scene_label} vs {Path(reference_path).name}", eps)
    budget_text = f"{budget.time:g} s" if budget.time is not None else f"{budget.iterations} iterations"
    seed_text = f"seed {seeds[0]}" if len(seeds) == 1 else f"seeds {','.join(map(str, seeds))}"
    text = write_table(out_dir / "convergence.md", by_method,
                       f"## {scene_label}: {', '.join(methods)} ({budget_text} each, {seed_text}"
                       + ("; interleaved" if interleave else "") + "; "
                       f"relMSE eps = ({metrics.RELMSE_FLOOR:g} x reference mean luminance)^2 = {eps:.3g}"
                       + (f"; the reference's own RMSE {math.sqrt(reference_noise):.3g}" if reference_noise > 0 else "")
                       + ")", spread, reference_noise, split)
    return by_method, text

"""The Python API: render a scene into a NumPy array, or watch it refine iteration by iteration.

    import photonmc
    image = photonmc.render("scenes/caustic/scene.xml", method="sppm", iterations=32, seed=1)
    for frame in photonmc.iterate(method="spatial-tf", time=30):
        print(frame.iteration, frame.elapsed, frame.stats["levels"][0]["acceptance"])

Both go through render.prepare() and the same progressive loop as `photonmc render`, so
the same scene, method, options and seed give the same image as the command line.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator

import numpy as np

from .loop import Budget, StopRequest, prepare, progressive, run, safe_image
from .scene import Scene


@dataclass
class Frame:
    """One progressive step: the image after `iteration` iterations and its statistics."""
    iteration: int
    elapsed: float             # seconds since the first iteration began (compilation included)
    image: np.ndarray          # (H, W, 3) float32 linear radiance, non-finite pixels set to 0
    stats: dict                # the method's statistics (as in `photonmc render --stats`)
    live: str                  # the method's live figures, as on the progress line


def _prepared(scene, method, seed, max_depth, threads, params, options):
    return prepare(scene, method=method, seed=seed, max_depth=max_depth, threads=threads,
                   options=options, params=params)


def _distributed_job(scene, method, seed, max_depth, threads, params, options, workers, address):
    from .loop import Job
    if scene is not None and not isinstance(scene, (str, bytes)) and not hasattr(scene, "__fspath__"):
        raise TypeError("a render on several workers takes the scene as a path: each worker loads it")
    return Job(scene=None if scene is None else str(scene), params=params or {}, method=method, seed=seed,
               max_depth=max_depth, threads=threads, options=options, workers=workers, address=address)


def render(scene: Scene | str | None = None, method: str = "pt", *, time: float | None = None,
           iterations: int | None = None, seed: int = 0, max_depth: int | None = None,
           threads: int | None = None, params: dict | None = None, workers: int | None = None,
           address: str | None = None, **options) -> np.ndarray:
    """Render and return the image as an (H, W, 3) float32 array of linear radiance.

    `scene` is a Scene from load_scene(), a path to a Mitsuba 3 XML file, or None for the
    bundled Cornell box; `params` sets its $parameters when it is a path. With neither
    `time` nor `iterations`, the method's default number of iterations. `options` are the
    method's options by their command-line names with underscores (photons, alpha, radius,
    chains, target_acceptance, proposal_failures, expected_values, path_target, light_paths,
    techniques). `workers`: that many independent renders on a Ray cluster (`address`, or one
    started on this machine), merged (docs/resume.md); `iterations` is then their total.
    """
    budget = Budget(time=time, iterations=iterations)
    if workers is not None:
        from . import distributed
        job = _distributed_job(scene, method, seed, max_depth, threads, params, options, workers, address)
        return safe_image(distributed.run(job, budget, quiet=True).image)
    p = _prepared(scene, method, seed, max_depth, threads, params, options)
    try:
        return run(p, budget, quiet=True).image
    finally:
        p.release()


def iterate(scene: Scene | str | None = None, method: str = "pt", *, time: float | None = None,
            iterations: int | None = None, seed: int = 0, max_depth: int | None = None,
            threads: int | None = None, params: dict | None = None, workers: int | None = None,
            address: str | None = None, **options) -> Iterator[Frame]:
    """Yield a Frame after every iteration until the budget is spent (the method's default
    number of iterations when neither `time` nor `iterations` is given). Stop early by
    leaving the loop; the device memory is freed when the generator is closed. With
    `workers`, a Frame after every state a worker sends, showing the merged image (its
    iteration is the total over the workers)."""
    budget = Budget(time=time, iterations=iterations)
    if workers is not None:
        yield from _iterate_distributed(_distributed_job(scene, method, seed, max_depth, threads, params, options,
                                                         workers, address), budget)
        return
    p = _prepared(scene, method, seed, max_depth, threads, params, options)
    m = p.method
    budget = budget.or_default(m.default_iterations)
    try:
        for iteration, elapsed, _ in progressive(m, budget, StopRequest()):
            yield Frame(iteration, elapsed, safe_image(m.image()), m.stats(), m.progress_fields().strip())
    finally:
        p.release()


def _iterate_distributed(job, budget: Budget) -> Iterator[Frame]:
    from . import distributed
    from .merge import summary
    from .methods import method_class
    budget = budget.or_default(method_class(job.method).default_iterations)
    for progress in distributed.render(job, budget):
        if progress.members:
            yield Frame(progress.iterations, progress.elapsed, safe_image(progress.image()),
                        {**summary(progress.members), "events": list(progress.events)}, "")

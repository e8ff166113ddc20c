"""The progressive loop shared by the CLI, the Python API, the preview and the tools.

prepare() loads the scene, uploads it and builds a method; progressive() runs iterations
until the budget is spent or a stop is requested, yielding after each one; run() adds
the progress bar, Ctrl-C handling and the final statistics. An interrupted render stops
after the iteration in flight, so the image it keeps is a whole number of iterations.
"""
from __future__ import annotations

import math
import signal
import sys
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import runtime
from .errors import SettingsError
from .methods import MethodSettings, create, method_class
from .scene import Scene, load_scene


@dataclass
class Budget:
    time: float | None = None          # wall seconds; stop after the first iteration past it
    iterations: int | None = None
    until_stopped: bool = False        # no limit at all (the preview runs until the user quits)

    def __post_init__(self):
        if self.time is not None and not (self.time > 0 and math.isfinite(self.time)):
            raise SettingsError(f"--time must be a positive number of seconds, got {self.time}")
        if self.iterations is not None and self.iterations < 1:
            raise SettingsError(f"--iterations must be at least 1, got {self.iterations}")

    def or_default(self, iterations: int) -> "Budget":
        """This budget, or `iterations` iterations when it sets no limit."""
        unlimited = self.time is None and self.iterations is None and not self.until_stopped
        return Budget(iterations=iterations) if unlimited else self

    def done(self, iterations: int, elapsed: float) -> bool:
        if self.iterations is not None and iterations >= self.iterations:
            return True
        return self.time is not None and elapsed >= self.time


@dataclass
class Prepared:
    scene: Scene
    dscene: object
    method: object
    timings: dict = field(default_factory=dict)

    def release(self):
        """Free device memory. Long-lived processes that render many scenes (tests, tools)
        call this: Taichi holds a limited number of field trees per process."""
        self.method.release()
        self.dscene.release()


def default_scene_path() -> Path:
    """The bundled Cornell box, installed as package data or found in the source tree."""
    try:
        from importlib.resources import files
        p = Path(str(files("photonmc.scenes") / "cornell-box" / "scene.xml"))
        if p.is_file():
            return p
    except (ModuleNotFoundError, TypeError):
        pass
    return Path(__file__).resolve().parent.parent / "scenes" / "cornell-box" / "scene.xml"


@dataclass
class Job:
    """A render as asked for: what `photonmc render`, the preview, a resumed state and every
    distributed worker build their method from (picklable, and saved in render states)."""
    scene: str | None = None           # Mitsuba XML path; None: the bundled Cornell box
    params: dict = field(default_factory=dict)
    method: str = "pt"
    seed: int = 0
    max_depth: int | None = None
    arch: str = "cpu"
    threads: int | None = None
    options: dict = field(default_factory=dict)
    budget: Budget = field(default_factory=Budget)
    workers: int | None = None         # several processes (distributed.py); None: this one
    address: str | None = None         # Ray cluster to join
    sync_interval: float = 1.0         # s between a worker's states
    # (offset, stride): render only iterations offset, offset+stride, ... (Method.interleave)
    iteration_slice: tuple = (0, 1)

    def __post_init__(self):
        self.params = dict(self.params or {})
        self.options = dict(self.options or {})

    def identity(self) -> dict:
        """What decides the image (saved in a render state): not the budget, arch or threads."""
        scene = Path(self.scene if self.scene is not None else default_scene_path()).resolve()
        identity = {"scene": str(scene), "params": dict(self.params), "method": self.method, "seed": int(self.seed),
                    "max_depth": self.max_depth, "options": {k: v for k, v in self.options.items() if v is not None}}
        if tuple(self.iteration_slice) != (0, 1):
            identity["iteration_slice"] = list(self.iteration_slice)
        return identity

    @classmethod
    def from_identity(cls, identity: dict, **rest) -> "Job":
        return cls(scene=identity["scene"], params=dict(identity["params"]), method=identity["method"],
                   seed=int(identity["seed"]), max_depth=identity["max_depth"], options=dict(identity["options"]),
                   iteration_slice=tuple(identity.get("iteration_slice", (0, 1))), **rest)

    def prepare(self) -> "Prepared":
        prepared = prepare(self.scene, method=self.method, seed=self.seed, max_depth=self.max_depth, arch=self.arch,
                           threads=self.threads, options=self.options, params=self.params)
        if tuple(self.iteration_slice) != (0, 1):
            try:
                prepared.method.interleave(*self.iteration_slice)
            except BaseException:
                prepared.release()
                raise
        return prepared


def resume(state, arch: str = "cpu", threads: int | None = None) -> tuple["Prepared", Job]:
    """Rebuild the render a state (state.RenderState) was saved from, with its accumulators:
    iterating it goes on exactly where the saved render stopped."""
    from . import state as render_state
    job = Job.from_identity(state.job, arch=arch, threads=threads)
    if not Path(job.scene).is_file():
        raise render_state.StateError(f"the state's scene '{job.scene}' is not there any more")
    prepared = job.prepare()
    try:
        render_state.check_fits(state, prepared.scene, job.method)
        render_state.restore(prepared.method, state.plain, state.arrays)
    except BaseException:
        prepared.release()
        raise
    prepared.timings["resumed_elapsed"] = state.elapsed
    return prepared, job


def prepare(scene, method: str = "pt", seed: int = 0, max_depth: int | None = None,
            arch: str = "cpu", threads: int | None = None, options: dict | None = None,
            params: dict | None = None) -> Prepared:
    """Load (if given a path), initialise Taichi, upload the scene and build the method."""
    method_class(method)                       # reject unknown methods before any work
    settings = MethodSettings(seed=seed, max_depth=max_depth, options=options or {})
    t0 = time.perf_counter()
    if not isinstance(scene, Scene):
        scene = load_scene(default_scene_path() if scene is None else scene, params)
    runtime.init(arch, threads)
    from .kernels.device_scene import DeviceScene
    dscene = DeviceScene(scene)
    m = create(method, dscene, settings)
    return Prepared(scene, dscene, m, {"load_s": time.perf_counter() - t0})


class StopRequest:
    """Set by Ctrl-C / SIGTERM: the loop finishes the iteration in flight and stops.
    A second Ctrl-C aborts at once. Subclasses (the preview) also pause the loop."""

    def __init__(self):
        self.requested = False

    def hold(self) -> float:
        """Called between iterations; waits while paused and returns the seconds it waited
        (excluded from the elapsed time and the --time budget). Never pauses here."""
        return 0.0

    @contextmanager
    def installed(self):
        if threading.current_thread() is not threading.main_thread():
            yield self
            return

        def handler(signum, frame):
            if self.requested and signum == signal.SIGINT:
                raise KeyboardInterrupt
            self.requested = True

        old_int = signal.signal(signal.SIGINT, handler)
        old_term = signal.signal(signal.SIGTERM, handler)
        try:
            yield self
        finally:
            signal.signal(signal.SIGINT, old_int)
            signal.signal(signal.SIGTERM, old_term)


def progressive(method, budget: Budget, stop: StopRequest | None = None, elapsed_before: float = 0.0):
    """Run iterations until the budget is spent (never, for an unlimited one) or a stop is
    requested; yields (iteration, elapsed, iteration_time). Paused time is not elapsed.
    A resumed render counts its iterations and `elapsed_before` seconds in the budget."""
    if budget.done(method.iterations, elapsed_before):
        return
    start = time.perf_counter() - elapsed_before
    paused = 0.0
    while True:
        t = time.perf_counter()
        method.iterate()
        now = time.perf_counter()
        elapsed = now - start - paused
        yield method.iterations, elapsed, now - t
        if budget.done(method.iterations, elapsed) or (stop is not None and stop.requested):
            return
        if stop is not None:
            paused += stop.hold()
            if stop.requested:
                return


class RateMeter:
    """Work per second (method.work_unit), counted from the end of the first iteration so
    that kernel compilation does not count."""

    def __init__(self, method):
        self.method = method
        self.first = None
        self.rate = 0.0

    def update(self, elapsed: float) -> float:
        if self.first is None:
            self.first = (elapsed, self.method.work_done)
        span = elapsed - self.first[0]
        self.rate = (self.method.work_done - self.first[1]) / span if span > 0 else 0.0
        return self.rate


class ProgressBar:
    """One status line on stderr, only when it is a terminal."""

    def __init__(self, method, budget: Budget, enabled: bool):
        self.method, self.budget = method, budget
        self.enabled = enabled and sys.stderr.isatty()
        self.last = 0.0
        self.meter = RateMeter(method)

    def update(self, iteration, elapsed, force=False):
        if not self.enabled or (not force and time.perf_counter() - self.last < 0.2):
            return
        self.last = time.perf_counter()
        rate = self.meter.update(elapsed)
        eta = ""
        if self.budget.iterations is not None and iteration > 0:
            eta = f"  ETA {elapsed / iteration * (self.budget.iterations - iteration):.1f} s"
        elif self.budget.time is not None:
            eta = f"  ETA {max(self.budget.time - elapsed, 0):.1f} s"
        total = f"/{self.budget.iterations}" if self.budget.iterations else ""
        live = self.method.progress_fields()
        live = f"  {live}" if live else ""
        sys.stderr.write(f"\r[{self.method.name}] iteration {iteration}{total}  {elapsed:.1f} s  "
                         f"{si(rate)} {self.method.work_unit}/s{live}{eta}   ")
        sys.stderr.flush()

    def close(self):
        if self.enabled:
            sys.stderr.write("\n")


def si(x: float) -> str:
    """A rate with an SI prefix: 1.23 M."""
    for unit, scale in (("G", 1e9), ("M", 1e6), ("k", 1e3)):
        if x >= scale:
            return f"{x / scale:.2f} {unit}"
    return f"{x:.0f}"


def safe_image(image: np.ndarray) -> np.ndarray:
    """float32 image with non-finite pixels set to 0 (callers report how many)."""
    return np.where(np.isfinite(image), image, 0.0).astype(np.float32)


@dataclass
class RunResult:
    image: np.ndarray          # (H,W,3) float32 linear
    stats: dict
    interrupted: bool


def run(prepared: Prepared, budget: Budget, quiet: bool = False, on_iteration=None,
        stop: StopRequest | None = None) -> RunResult:
    """The whole progressive render with progress, interrupt handling and statistics.
    A budget with no limit means the method's default number of iterations. `stop` lets a
    caller (the preview) stop and pause the loop besides Ctrl-C."""
    m = prepared.method
    budget = budget.or_default(m.default_iterations)
    stop = stop or StopRequest()
    bar = ProgressBar(m, budget, enabled=not quiet)
    iteration_times = []
    elapsed = elapsed_before = prepared.timings.get("resumed_elapsed", 0.0)
    work_before = m.work_done
    with stop.installed():
        for iteration, elapsed, dt in progressive(m, budget, stop, elapsed_before):
            iteration_times.append(dt)
            bar.update(iteration, elapsed)
            if on_iteration is not None:
                on_iteration(m, iteration, elapsed)
    bar.update(m.iterations, elapsed, force=True)
    bar.close()
    image = m.image()
    nonfinite_pixels = int((~np.isfinite(image)).any(axis=2).sum())
    image = safe_image(image)   # never let NaN/Inf reach the film silently: counted above
    steady = iteration_times[1:]
    stats = {
        **m.stats(),
        "scene": str(prepared.scene.path),
        "seed": m.settings.seed,
        "resolution": [prepared.dscene.width, prepared.dscene.height],
        "max_depth": prepared.scene.max_depth if m.settings.max_depth is None else m.settings.max_depth,
        "wall_seconds": {
            "load": prepared.timings.get("load_s", 0.0),
            "first_iteration_incl_compile": iteration_times[0] if iteration_times else 0.0,
            "steady_per_iteration": float(np.mean(steady)) if steady else None,
            "render": elapsed,
            "render_this_run": elapsed - elapsed_before,
        },
        "interrupted": stop.requested,
        "nonfinite_pixels_zeroed": nonfinite_pixels,
        "threads": runtime._current[1] if runtime._current else None,
        "arch": runtime._current[0] if runtime._current else None,
    }
    if steady:
        stats[f"{m.work_unit}_per_second"] = (m.work_done - work_before) / len(iteration_times) / float(np.mean(steady))
    return RunResult(image.astype(np.float32), stats, stop.requested)

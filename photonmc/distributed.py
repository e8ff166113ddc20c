"""One image from several processes, on one machine or a Ray cluster (`--workers N`,
`--address ADDR`; docs/resume.md).

Each worker is a Ray actor holding one render. Where a method's iterations depend only
on their index (pt, vcm), worker k of W renders the iterations k, k+W, ... of the one render
the seed names, so the merged image is that render's (bias included), whatever W. For the
others (sppm and the guided methods carry per-pixel radii and chains from iteration to
iteration) each worker renders a whole render with its own seed stream (merge.worker_seed:
worker 0 renders what a single-process render would); docs/resume.md says what their
merge means. The driver asks
each worker to advance; a worker iterates until --sync-interval seconds have passed (at
least one iteration) and answers with its render state (state.py). The driver keeps the
latest state of every worker and merges them (merge.py) into the image it shows, writes
and checkpoints. Because a state resumes exactly, a worker that dies is replaced by a new
one resumed from its last state: the render loses the iterations since that state and
nothing else, and with --iterations the final image is the one an undisturbed run gives.
A worker that cannot be replaced keeps its last state in the merge; the others go on.

Budgets count the whole render: --iterations N is the total over all workers (spread
evenly), --time T the driver's wall clock.
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass, field

import numpy as np

from .errors import PhotonmcError, SettingsError
from .loop import Budget, Job, StopRequest
from .merge import merged_image, worker_seed
from .state import RenderState, from_bytes, save

MAX_RESTARTS = 2          # replacements per worker before its render is left as it is
WAIT_POLL = 0.25          # s between checks of the stop request while waiting on workers


def _ray():
    try:
        import ray
    except ImportError:
        raise PhotonmcError("--workers needs Ray: pip install 'photonmc[distributed]'") from None
    return ray


def _worker_actor(ray):
    class RenderWorker:
        """One render in a Ray worker process: built fresh or resumed from a state."""

        def __init__(self, identity: dict, state: bytes | None, arch: str, threads: int | None):
            from .loop import Job, resume
            self.error = None
            try:
                if state is not None:
                    [member] = from_bytes(state, "the worker's state")
                    self.prepared, self.job = resume(member, arch=arch, threads=threads)
                    self.elapsed = member.elapsed
                else:
                    self.job = Job.from_identity(identity, arch=arch, threads=threads)
                    self.prepared = self.job.prepare()
                    self.elapsed = 0.0
            except PhotonmcError as e:       # bad scene or settings: the driver reports it
                self.error = str(e)

        def ready(self) -> tuple[str | None, int]:
            """(the error that stopped this render from being built, or None; the process id)."""
            return self.error, os.getpid()

        def advance(self, target_iterations: int | None, seconds_left: float | None, sync_interval: float) -> bytes:
            from .state import state_of, to_bytes
            m = self.prepared.method
            t0 = time.perf_counter()
            while target_iterations is None or m.iterations < target_iterations:
                m.iterate()
                spent = time.perf_counter() - t0
                if spent >= sync_interval or (seconds_left is not None and spent >= seconds_left):
                    break
            self.elapsed += time.perf_counter() - t0
            return to_bytes([state_of(m, self.job.identity(), self.prepared.scene, self.elapsed)])

    return ray.remote(RenderWorker)


@dataclass
class Worker:
    index: int
    identity: dict
    state: RenderState | None = None     # the latest state it sent (or was resumed from)
    actor: object = None
    pid: int | None = None               # of the worker process (tests kill it)
    restarts: int = 0
    lost: bool = False                   # could not be replaced: its last state stays in the merge
    target: int | None = None            # iterations this worker's render should reach

    @property
    def iterations(self) -> int:
        return self.state.iterations if self.state is not None else 0


@dataclass
class Progress:
    """What the driver knows after each merge (the loop yields it)."""
    workers: list
    elapsed: float
    events: list = field(default_factory=list)     # one line per worker lost or replaced

    @property
    def members(self) -> list[RenderState]:
        return [w.state for w in self.workers if w.state is not None and w.state.iterations > 0]

    @property
    def iterations(self) -> int:
        return sum(w.iterations for w in self.workers)

    def image(self) -> np.ndarray:
        return merged_image(self.members)


def spread_iterations(done: list[int], total: int) -> list[int]:
    """Per-worker iteration targets summing to `total` (at least what each has done), as
    even as possible: the worker with the fewest gets the next one, lowest index first."""
    targets = list(done)
    for _ in range(max(total - sum(targets), 0)):
        k = min(range(len(targets)), key=lambda i: (targets[i], i))
        targets[k] += 1
    return targets


def render(job: Job, budget: Budget, resumed: list[RenderState] | None = None, stop: StopRequest | None = None):
    """Run the distributed render on job.workers workers; yields a Progress after every state a
    worker sends. `resumed`: member states to continue (a merged state); workers beyond them
    start fresh."""
    resumed = list(resumed or [])
    workers = job.workers or max(len(resumed), 1)
    address, sync_interval = job.address, job.sync_interval
    if not 1 <= workers <= 4096:
        raise SettingsError(f"--workers must be between 1 and 4096, got {workers}")
    if len(resumed) > workers:
        raise SettingsError(f"the state holds {len(resumed)} renders: resume it with --workers {len(resumed)} or more")
    if not (sync_interval >= 0 and np.isfinite(sync_interval)):
        raise SettingsError(f"--sync-interval must be >= 0 seconds, got {sync_interval}")
    # Refuse a bad scene here, before a cluster starts (bad options: the workers say, see ready()).
    from .loop import default_scene_path
    from .methods import method_class
    from .scene import load_scene
    method_class(job.method)
    load_scene(job.scene if job.scene is not None else default_scene_path(), job.params)
    ray = _ray()
    started_here = not ray.is_initialized()
    cpus = os.cpu_count() or 1
    threads = job.threads or (max(1, cpus // workers) if address is None else None)
    if started_here:
        if address is None:
            ray.init(num_cpus=max(cpus, workers * (threads or 1)), include_dashboard=False,
                     log_to_driver=False, configure_logging=False)
        else:
            try:
                ray.init(address=address, log_to_driver=False, configure_logging=False)
            except (ConnectionError, RuntimeError, ValueError) as e:
                raise PhotonmcError(f"cannot join the Ray cluster at '{address}': {e}") from None
    actor_class = _worker_actor(ray).options(num_cpus=threads or 1)
    identity = job.identity()
    pool = [Worker(k, m.job, state=m) for k, m in enumerate(resumed)]
    if not resumed and workers > 1 and method_class(job.method).iterations_independent(job.options):
        # Interleaved slices of one render: the merge is the render one process would make.
        pool = [Worker(k, {**identity, "iteration_slice": [k, workers]}) for k in range(workers)]
    used = {m.seed for m in resumed}
    j = len(pool)
    while len(pool) < workers:          # fresh workers: the next seed streams not yet in use
        seed = worker_seed(job.seed, j)
        j += 1
        if seed not in used:
            used.add(seed)
            pool.append(Worker(len(pool), {**identity, "seed": seed}))
    # Workers run side by side: a resumed render has run as long as its longest member.
    progress = Progress(pool, max((w.state.elapsed for w in pool if w.state is not None), default=0.0))
    if budget.iterations is not None:
        for w, t in zip(pool, spread_iterations([w.iterations for w in pool], budget.iterations)):
            w.target = t
    stop = stop or StopRequest()
    start = time.perf_counter() - progress.elapsed

    def spawn(w: Worker):
        from .state import to_bytes
        state = to_bytes([w.state]) if w.state is not None else None
        w.actor = actor_class.remote(w.identity, state, job.arch, threads)

    def submit(w: Worker):
        if w.target is not None and w.iterations >= w.target:
            return None
        left = None if budget.time is None else budget.time - (time.perf_counter() - start)
        if left is not None and left <= 0:
            return None
        return w.actor.advance.remote(w.target, left, sync_interval)

    pending = {}
    try:
        for w in pool:
            spawn(w)
        try:
            answers = ray.get([w.actor.ready.remote() for w in pool])
        except _actor_errors(ray) as e:
            raise PhotonmcError(f"a worker could not start: {e}") from None
        for w, (error, pid) in zip(pool, answers):
            if error is not None:
                raise PhotonmcError(error)
            w.pid = pid
        for w in pool:
            ref = submit(w)
            if ref is not None:
                pending[ref] = w
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1, timeout=WAIT_POLL)
            progress.elapsed = time.perf_counter() - start
            if not ready:
                continue
            ref = ready[0]
            w = pending.pop(ref)
            try:
                [w.state] = from_bytes(ray.get(ref), f"worker {w.index}'s state")
            except _actor_errors(ray) as e:
                _replace_or_lose(ray, w, pool, budget, progress, spawn, e)
            if not (w.lost or stop.requested):
                ref = submit(w)
                if ref is not None:
                    pending[ref] = w
            yield progress
    finally:
        for w in pool:
            if w.actor is not None:
                ray.kill(w.actor)
        if started_here:
            ray.shutdown()


def _actor_errors(ray) -> tuple:
    """What Ray raises when a worker process or its node has gone."""
    e = ray.exceptions
    return (e.RayActorError, e.WorkerCrashedError, e.ActorUnavailableError, e.NodeDiedError)


def _replace_or_lose(ray, w: Worker, pool, budget, progress, spawn, error):
    if w.restarts < MAX_RESTARTS:
        w.restarts += 1
        progress.events.append(f"worker {w.index} died ({type(error).__name__}); resumed on a new worker "
                               f"from its state after {w.iterations} iterations")
        try:
            spawn(w)
            error, w.pid = ray.get(w.actor.ready.remote())
            if error is None:
                return
        except _actor_errors(ray):
            pass
    w.lost = True
    progress.events.append(f"worker {w.index} died again; its {w.iterations} iterations stay in the image")
    if budget.iterations is not None:
        alive = [x for x in pool if not x.lost]
        if alive:
            given = sum(x.iterations for x in pool if x.lost)
            for x, t in zip(alive, spread_iterations([x.iterations for x in alive], budget.iterations - given)):
                x.target = t


@dataclass
class Result:
    image: np.ndarray
    members: list
    stats: dict
    written: list
    events: list
    interrupted: bool


def run(job: Job, budget: Budget, resumed: list[RenderState] | None = None, out=None, checkpoint: float = 0.0,
        quiet: bool = False, on_progress=None, stop: StopRequest | None = None) -> Result:
    """The distributed render with a progress line, Ctrl-C handling and checkpoints of the
    merged image and state (out: the .exr; its .state beside it)."""
    import sys

    from . import imageio
    from .loop import safe_image
    from .merge import summary
    from .methods import method_class

    budget = budget.or_default(method_class(job.method).default_iterations)
    stop = stop or StopRequest()
    show = not quiet and sys.stderr.isatty()
    last_write = time.perf_counter()
    progress = None

    def write(progress) -> list:
        if not progress.members or out is None:
            return []
        s = summary(progress.members)
        written = imageio.write_image(out, safe_image(progress.image()),
                                      {"method": job.method, "seeds": s["seeds"], "iterations": s["iterations"],
                                       "scene": progress.members[0].job["scene"]})
        return written + [save(out.with_suffix(".state"), progress.members)]

    with stop.installed():
        for progress in render(job, budget, resumed, stop):
            if show:
                total = f"/{budget.iterations}" if budget.iterations else ""
                sys.stderr.write(f"\r[{job.method}] {len(progress.workers)} workers  iteration "
                                 f"{progress.iterations}{total}  {progress.elapsed:.1f} s   ")
                sys.stderr.flush()
            if on_progress is not None:
                on_progress(progress)
            if checkpoint > 0 and time.perf_counter() - last_write >= checkpoint:
                write(progress)
                last_write = time.perf_counter()
    if show:
        sys.stderr.write("\n")
    if progress is None and resumed:          # the resumed render had already met the budget
        progress = Progress([Worker(k, m.job, state=m) for k, m in enumerate(resumed)], max(m.elapsed for m in resumed))
    if progress is None or not progress.members:
        raise PhotonmcError("no worker finished an iteration")
    written = write(progress)
    s = summary(progress.members)
    stats = {**s, "workers": len(progress.workers), "scene": progress.members[0].job["scene"],
             "resolution": list(progress.members[0].resolution),
             "wall_seconds": {"render": progress.elapsed},
             "worker_restarts": sum(w.restarts for w in progress.workers),
             "workers_lost": sum(w.lost for w in progress.workers), "events": progress.events,
             "interrupted": stop.requested}
    return Result(progress.image(), progress.members, stats, written, progress.events, stop.requested)

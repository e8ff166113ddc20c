"""Taichi initialisation, once per process.

A second ti.init() would throw away every compiled kernel, so all callers (CLI, API,
tests) go through init(); asking again with the same settings is a no-op.
"""
from __future__ import annotations

import contextlib
import io
import os

os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "False")   # keep Taichi's banner out of user output

import taichi as ti

from . import taichi_frontend
from .errors import SettingsError

_current: tuple | None = None
ARCHES = {"cpu": "cpu", "cuda": "cuda", "vulkan": "vulkan"}


def init(arch: str = "cpu", threads: int | None = None, debug: bool = False, kernel_profiler: bool = False) -> None:
    """kernel_profiler: Taichi times every kernel launch (tools/profile_kernels.py); a later
    call without it keeps the profiler on."""
    global _current
    key = (arch, threads, debug)
    if _current is not None:
        if kernel_profiler and not ti.lang.impl.current_cfg().kernel_profiler:
            raise SettingsError("Taichi is already initialised without the kernel profiler")
        if _current != key:
            raise SettingsError(f"Taichi is already initialised with arch/threads/debug {_current}; "
                                f"cannot switch to {key} in the same process")
        return
    if arch not in ARCHES:
        raise SettingsError(f"unknown --arch '{arch}' (choose cpu, cuda or vulkan)")
    if threads is not None and threads < 1:
        raise SettingsError(f"--threads must be at least 1, got {threads}")
    # cfg_optimization off: Taichi's control-flow-graph passes (store-to-load forwarding, dead
    # store elimination) scale superlinearly with kernel size (taichi-dev/taichi#1785) and were
    # 75-85 % of every method's compile time: mbe's first image 143 s -> 28 s, spatial-tf's
    # 41 s -> 16 s, and no iteration slower, since LLVM's own passes do the same work on the
    # generated code. Images differ from those of the passes in the last float bits only
    # (tests/test_compile_settings.py; docs/performance.md, "Compile time").
    # fast_math off: with it LLVM may reorder or contract float operations differently
    # depending on where a kernel's fields live, and pooled fields (kernels/fields.py) put the
    # same render's fields in other trees after another scene's render: an mbe render then
    # differed from the same seed's in the last bits (tests/test_mbe.py). Measured free:
    # pt and vcm at 128² within 1 % per iteration (docs/performance.md, "Fast math").
    kwargs = dict(arch=getattr(ti, ARCHES[arch]), default_fp=ti.f32, default_ip=ti.i32,
                  log_level=ti.WARN, debug=debug, offline_cache=True, kernel_profiler=kernel_profiler,
                  cfg_optimization=False, fast_math=False)
    if threads is not None and arch == "cpu":
        kwargs["cpu_max_num_threads"] = threads
    # Taichi's front end re-reads and re-formats the same source at every inlined call; the
    # memo hands it the same strings sooner (mbe's cold first image 9.4 -> 7.4 s; module doc).
    taichi_frontend.install()
    with contextlib.redirect_stdout(io.StringIO()):   # ti.init prints "Starting on arch=..."
        ti.init(**kwargs)
    if arch != "cpu" and ti.lang.impl.current_cfg().arch == ti.cpu:
        raise SettingsError(f"--arch {arch} is not available on this machine")
    _current = key


@contextlib.contextmanager
def advanced_optimization(enabled: bool):
    """Compile the kernels first launched inside this block with Taichi's advanced
    optimisation on or off. Taichi reads the setting from its live config when a kernel
    compiles (and hashes it into the offline-cache key), so launching a kernel inside the
    same block every time keeps it on one setting, cold or cached."""
    cfg = ti.lang.impl.current_cfg()
    saved = cfg.advanced_optimization
    cfg.advanced_optimization = bool(enabled) and saved
    try:
        yield
    finally:
        cfg.advanced_optimization = saved


# Every parallel loop of a kernel is handed to Taichi's CPU thread pool, and the hand-off costs
# 0.2-0.27 ms on the 2-core machines measured, whatever the loop's length and thread count
# (an empty 16-item loop: 0.26 ms parallel, 0.06 ms serial; 2^16 cheap items: 0.34 against
# 0.17 ms; docs/performance.md, "Parallel loops that cost more than they do"). A 64x64
# iteration runs ten or more such loops besides its few long ones, so the short ones run
# serially: cheap per-item loops up to SERIAL_ITEMS iterations (a fixed count, not a timing,
# so that an image never depends on how fast the machine was that day).
SERIAL_ITEMS = 1 << 14


def serial_loop(items: int) -> bool:
    """Whether a loop of `items` cheap iterations (copies, clears, a few atomics each) should
    run serially: on the CPU backend up to SERIAL_ITEMS; never on a GPU, where one thread is
    slow and a launch is cheap."""
    return ti.lang.impl.current_cfg().arch == ti.cpu and int(items) <= SERIAL_ITEMS


def is_initialised() -> bool:
    return _current is not None

"""`photonmc preview`: a Taichi GUI window (or, offscreen, a folder of frames) showing the
image refine iteration by iteration.

The render runs in a child process through loop.run(), the same progressive loop as
`photonmc render`. A separate process, not a thread, because Taichi holds the GIL for the
whole of a kernel launch (measured: a 4 s kernel in a worker thread froze the main thread for
4 s), so a window driven from the rendering process could not answer keys during a long
iteration. The child sends each new image through a pipe (at most every FRAME_INTERVAL
seconds, and always the last); the window redraws at ~30 Hz whatever the child is doing.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import multiprocessing as mp
import os
import sys
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import imageio
from .errors import PhotonmcError
from .loop import Job, RateMeter, StopRequest

FRAME_INTERVAL = 0.1        # s between images sent by the render process
REDRAW_INTERVAL = 1 / 30    # s between window redraws
MIN_WINDOW_WIDTH = 512      # small renders are shown enlarged by an integer factor
STATUS_LINES = 3
LINE_HEIGHT = 18
STATUS_HEIGHT = STATUS_LINES * LINE_HEIGHT + 6
QUIT_WAIT = 2.0             # s to wait for the iteration in flight before saving on quit
EXPOSURE_STEP = 0.5         # stops per key press
WINDOW_TITLE = "photonmc preview"
KEYS_HELP = "s: save   +/-: exposure   0: reset exposure   space: pause   q/Esc: quit (saves)"


# -- headless detection ----------------------------------------------------------------------
def display_problem() -> str | None:
    """Why no window can be opened here, or None. Checked before Taichi tries (it aborts
    with a long log message when the X server is missing)."""
    if sys.platform.startswith("linux"):
        name = os.environ.get("DISPLAY")
        if not name:
            return "no display ($DISPLAY is not set)"
        lib = ctypes.util.find_library("X11")
        if lib is None:
            return "no X11 client library (libX11) to open a window with"
        x11 = ctypes.CDLL(lib)
        x11.XOpenDisplay.restype = ctypes.c_void_p
        x11.XOpenDisplay.argtypes = [ctypes.c_char_p]
        x11.XCloseDisplay.argtypes = [ctypes.c_void_p]
        handle = x11.XOpenDisplay(name.encode())
        if not handle:
            return f"cannot connect to the X display '{name}'"
        x11.XCloseDisplay(handle)
    return None


# -- the render process ----------------------------------------------------------------------
class PreviewControl(StopRequest):
    """Stop and pause set by the window process, besides Ctrl-C in the render process."""

    def __init__(self, stop_event, pause_event):
        self._stop, self._pause = stop_event, pause_event
        super().__init__()

    @property
    def requested(self) -> bool:
        return self._signalled or self._stop.is_set()

    @requested.setter
    def requested(self, value: bool):
        self._signalled = value

    def hold(self) -> float:
        t = time.perf_counter()
        while self._pause.is_set() and not self.requested:
            time.sleep(0.02)
        return time.perf_counter() - t


def _render_process(job: Job, conn, stop_event, pause_event):
    """Child process: prepare, then run the shared loop, sending images as they come."""
    try:
        if job.workers is not None:
            _render_distributed(job, conn, stop_event, pause_event)
            return
        from .loop import run, safe_image
        prepared = job.prepare()
        m = prepared.method
        conn.send(("ready", {"method": m.name, "work_unit": m.work_unit,
                             "total": job.budget.or_default(m.default_iterations).iterations}))
        meter = RateMeter(m)
        last = [0.0]

        def publish(method, iteration, elapsed):
            rate = meter.update(elapsed)
            if time.perf_counter() - last[0] >= FRAME_INTERVAL:
                conn.send(("frame", iteration, elapsed, safe_image(method.image()), rate,
                           method.progress_fields().strip()))
                last[0] = time.perf_counter()

        result = run(prepared, job.budget, quiet=True, on_iteration=publish,
                     stop=PreviewControl(stop_event, pause_event))
        conn.send(("frame", m.iterations, result.stats["wall_seconds"]["render"], result.image,
                   meter.rate, m.progress_fields().strip()))
        conn.send(("done", result.stats))
    except (BrokenPipeError, EOFError):
        pass                # the window process has gone: nobody to render for
    except PhotonmcError as e:
        conn.send(("error", str(e)))
    except Exception:   # noqa: BLE001 - reported in the window process, with the traceback
        conn.send(("error", "render process failed:\n" + traceback.format_exc()))
    finally:
        conn.close()


def _render_distributed(job: Job, conn, stop_event, pause_event):
    """The render process of a preview on several workers: shows their merged image
    (distributed.py). Pausing stops handing out work until resumed."""
    from . import distributed
    from .loop import safe_image
    from .methods import method_class
    budget = job.budget.or_default(method_class(job.method).default_iterations)
    conn.send(("ready", {"method": f"{job.method} x{job.workers}", "work_unit": "iterations",
                         "total": budget.iterations}))
    control = PreviewControl(stop_event, pause_event)
    progress, last = None, 0.0
    for progress in distributed.render(job, budget, stop=control):
        control.hold()
        if progress.members and time.perf_counter() - last >= FRAME_INTERVAL:
            rate = progress.iterations / max(progress.elapsed, 1e-9)
            conn.send(("frame", progress.iterations, progress.elapsed, safe_image(progress.image()), rate,
                       f"{len(progress.workers)} workers  " + "; ".join(progress.events[-1:])))
            last = time.perf_counter()
    if progress is not None and progress.members:
        conn.send(("frame", progress.iterations, progress.elapsed, safe_image(progress.image()),
                   progress.iterations / max(progress.elapsed, 1e-9), f"{len(progress.workers)} workers"))
    conn.send(("done", {"iterations": progress.iterations if progress else 0}))


# -- what is shown ---------------------------------------------------------------------------
@dataclass
class Status:
    method: str = ""
    work_unit: str = ""
    total: int | None = None
    iteration: int = 0
    elapsed: float = 0.0
    rate: float = 0.0
    live: str = ""
    state: str = "compiling"     # compiling, rendering, paused, finished, stopping
    exposure: float = 0.0
    received_at: float = 0.0

    def lines(self, now: float) -> list[str]:
        from .loop import si
        elapsed = self.elapsed
        if self.state == "rendering":      # the clock keeps running during a long iteration
            elapsed += now - self.received_at
        total = f"/{self.total}" if self.total else ""
        first = (f"{self.method}  iteration {self.iteration}{total}  {elapsed:.1f} s  "
                 f"{si(self.rate)} {self.work_unit}/s  EV {self.exposure:+.1f}  [{self.state}]")
        return [first, self.live or "-", KEYS_HELP]


def display_scale(width: int) -> int:
    return max(1, MIN_WINDOW_WIDTH // width)


def compose(image: np.ndarray | None, shape: tuple[int, int], exposure: float) -> np.ndarray:
    """The window's pixels in Taichi's GUI layout, (x, y) with y up: the tonemapped image
    (sRGB, as the PNGs are written) enlarged by display_scale(), above a status strip."""
    h, w = shape
    s = display_scale(w)
    canvas = np.full((w * s, h * s + STATUS_HEIGHT, 3), 40, np.uint8)
    if image is not None:
        shown = imageio.srgb_encode(image * 2.0 ** exposure)
        shown = np.repeat(np.repeat(shown, s, axis=0), s, axis=1)
        canvas[:, STATUS_HEIGHT:] = shown[::-1].transpose(1, 0, 2)
    return canvas


class Screen:
    """A Taichi GUI, on screen or offscreen (then each shown frame goes to a PNG)."""

    def __init__(self, shape: tuple[int, int], frames_dir: Path | None):
        from . import runtime  # noqa: F401 - keeps Taichi's banner out of the output
        import taichi as ti
        self.ti = ti
        h, w = shape
        s = display_scale(w)
        self.res = (w * s, h * s + STATUS_HEIGHT)
        self.frames_dir = frames_dir
        self.frames_written = 0
        self.gui = ti.GUI(WINDOW_TITLE, res=self.res, background_color=0x282828,
                          show_gui=frames_dir is None)

    def show(self, canvas: np.ndarray, lines: list[str]):
        self.gui.set_image(canvas)
        for k, line in enumerate(lines):
            y = (STATUS_HEIGHT - 3 - k * LINE_HEIGHT) / self.res[1]
            self.gui.text(line, (4 / self.res[0], y), font_size=14, color=0xE0E0E0)
        if self.frames_dir is None:
            self.gui.show()
        else:
            self.frames_written += 1
            self.gui.show(str(self.frames_dir / f"frame-{self.frames_written:05d}.png"))

    def keys(self) -> list[str]:
        if self.frames_dir is not None:
            return []
        keys = [e.key for e in self.gui.get_events(self.ti.GUI.PRESS)]
        if not self.gui.running:
            keys.append("q")
        return keys

    def close(self):
        self.gui.close()


# -- the window process ----------------------------------------------------------------------
class Preview:
    def __init__(self, job: Job, out: Path, frames_dir: Path | None, shape: tuple[int, int],
                 log=lambda msg: print(f"photonmc: {msg}", file=sys.stderr)):
        self.job, self.out, self.frames_dir, self.shape, self.log = job, out, frames_dir, shape, log
        self.status = Status(method=job.method)
        self.image: np.ndarray | None = None
        self.stats: dict | None = None
        self.changed = True

    def run(self) -> int:
        ctx = mp.get_context("spawn")     # a fresh interpreter: no forked Taichi runtime
        receive, send = ctx.Pipe(duplex=False)
        stop, pause = ctx.Event(), ctx.Event()
        child = ctx.Process(target=_render_process, args=(self.job, send, stop, pause), daemon=True)
        child.start()
        send.close()
        screen = Screen(self.shape, self.frames_dir)
        try:
            self._loop(screen, receive, child, stop, pause)
        except KeyboardInterrupt:
            stop.set()
            self._drain_until_done(receive, QUIT_WAIT)
        finally:
            screen.close()
            child.join(QUIT_WAIT)
            if child.is_alive():      # SIGKILL: the render process takes SIGTERM as "finish the iteration"
                child.kill()
                child.join()
        self.save()
        return 0

    def _loop(self, screen, receive, child, stop, pause):
        next_draw = 0.0
        while True:
            if not self._receive(receive, child):
                if self.frames_dir is not None:       # offscreen: the run ends with the render
                    self.status.state = "finished"
                    screen.show(compose(self.image, self.shape, self.status.exposure),
                                self.status.lines(time.perf_counter()))
                    return
                if self.status.state != "finished":
                    self.status.state = "finished"
                    self.log(f"finished {self.status.iteration} iterations; the window stays open (q to quit)")
            for key in screen.keys():
                if key in ("q", "Escape", "WMClose"):
                    self.status.state = "stopping"
                    stop.set()
                    self._drain_until_done(receive, QUIT_WAIT)
                    return
                if key == "s":
                    self.save()
                elif key in ("+", "=", "Up"):
                    self.status.exposure += EXPOSURE_STEP
                elif key in ("-", "Down"):
                    self.status.exposure -= EXPOSURE_STEP
                elif key == "0":
                    self.status.exposure = 0.0
                elif key == " " and self.status.state in ("rendering", "paused"):
                    if pause.is_set():
                        pause.clear()
                        self.status.state = "rendering"
                        self.status.received_at = time.perf_counter()
                    else:
                        pause.set()
                        self.status.state = "paused"
                self.changed = True
            now = time.perf_counter()
            offscreen_frame = self.frames_dir is not None and self.changed
            if (self.frames_dir is None and now >= next_draw) or offscreen_frame:
                screen.show(compose(self.image, self.shape, self.status.exposure), self.status.lines(now))
                self.changed = False
                next_draw = now + REDRAW_INTERVAL
            time.sleep(0.005 if self.frames_dir is None else 0.02)

    def _receive(self, receive, child) -> bool:
        """Take every message waiting; False once the render process has finished."""
        if self.stats is not None:
            return False
        try:
            while receive.poll():
                self._handle(receive.recv())
                if self.stats is not None:
                    return False
        except EOFError:
            if self.stats is None:
                child.join(1.0)
                raise PhotonmcError(f"the render process ended unexpectedly (exit code {child.exitcode})") from None
        return True

    def _drain_until_done(self, receive, timeout: float):
        end = time.perf_counter() + timeout
        try:
            while self.stats is None and time.perf_counter() < end:
                if receive.poll(0.05):
                    self._handle(receive.recv())
        except EOFError:
            pass

    def _handle(self, msg):
        kind = msg[0]
        if kind == "ready":
            info = msg[1]
            self.status.method, self.status.work_unit, self.status.total = info["method"], info["work_unit"], info["total"]
            self.status.state = "rendering"
            self.status.received_at = time.perf_counter()
        elif kind == "frame":
            _, iteration, elapsed, image, rate, live = msg
            self.image = image
            st = self.status
            st.iteration, st.elapsed, st.rate, st.live = iteration, elapsed, rate, live
            st.received_at = time.perf_counter()
            self.changed = True
        elif kind == "done":
            self.stats = msg[1]
            self.changed = True
        elif kind == "error":
            raise PhotonmcError(msg[1])

    def save(self):
        if self.image is None:
            self.log("nothing rendered yet; no image saved")
            return
        meta = {"method": self.job.method, "seed": self.job.seed, "iterations": self.status.iteration,
                "scene": self.job.scene}
        written = imageio.write_image(self.out, self.image, meta)
        self.log(f"saved {', '.join(str(p) for p in written)} ({self.status.iteration} iterations)")


def preview(job: Job, out, frames_dir=None, shape: tuple[int, int] | None = None) -> int:
    """Open the window (or write frames to `frames_dir`); returns the exit status."""
    if frames_dir is None:
        problem = display_problem()
        if problem:
            raise PhotonmcError(f"{problem}: no window can be shown here; use `photonmc render` "
                                f"or `photonmc preview --frames DIR` to write the frames instead")
    else:
        if not job.budget.time and not job.budget.iterations:
            raise PhotonmcError("--frames needs --time or --iterations (there is no window to quit)")
        frames_dir = Path(frames_dir)
        frames_dir.mkdir(parents=True, exist_ok=True)
    out = imageio.check_output_path(out)
    return Preview(job, out, frames_dir, shape).run()


__all__ = ["Job", "Preview", "compose", "display_problem", "display_scale", "preview"]

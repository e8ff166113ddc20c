"""Per-pixel accumulators in float64, with an account of samples that were not finite.

Progressive runs add millions of samples per pixel; float32 sums would stop growing.
A sample that is NaN or infinite is dropped and counted, never added to the image.

A weighted film (mbe's chain passes) takes each pass with a weight w, its camera subpaths per
pixel: the image is sum w F / sum w, and samples_per_pixel counts the weight (docs/mbe.md,
"Chain passes weighed by their camera subpaths").
"""
import numpy as np
import taichi as ti

from .kernels.batch import fill_fields
from .kernels.fields import FieldGroup
from .kernels.sampling import luminance
from .runtime import serial_loop
from .taichi_frontend import data_oriented


@data_oriented
class Film:
    def __init__(self, width: int, height: int, weighted: bool = False):
        self.width, self.height = width, height
        self.weighted = weighted
        self.fields = FieldGroup("film")
        self.sum = self.fields.vector(3, ti.f64, (height, width))       # of w x radiance
        self.sum_sq = self.fields.scalar(ti.f64, (height, width))    # of (w x luminance)^2, for error bars
        if weighted:
            self.sum_w2 = self.fields.scalar(ti.f64, (height, width))   # of w^2 x luminance, for error bars
        self.nonfinite = self.fields.scalar(ti.i64)
        self.fields.finalize()
        self.samples_per_pixel = 0      # the weight summed (the samples, unweighted)
        self.passes = 0                 # samples taken, whatever their weight
        self.weight_sq_sum = 0          # their weights squared, summed

    def release(self):
        self.fields.release()

    def reset(self):
        fill_fields([(self.sum, 0), (self.sum_sq, 0), (self.nonfinite, 0)]
                    + ([(self.sum_w2, 0)] if self.weighted else []))
        self.samples_per_pixel = 0
        self.passes = 0
        self.weight_sq_sum = 0

    @ti.func
    def add(self, y: ti.i32, x: ti.i32, rgb):
        self.add_weighted(y, x, rgb, 1.0)

    @ti.func
    def add_weighted(self, y: ti.i32, x: ti.i32, rgb, w: ti.f64):
        """A sample of weight w (1 unless the film is weighted); count_samples(w) once per pass."""
        finite = True
        for k in ti.static(range(3)):
            if not (rgb[k] == rgb[k] and ti.abs(rgb[k]) < ti.math.inf):
                finite = False
        if finite:
            lum = ti.cast(luminance(rgb), ti.f64)
            if ti.static(self.weighted):
                self.sum[y, x] += w * ti.cast(rgb, ti.f64)
                self.sum_sq[y, x] += (w * lum) ** 2
                self.sum_w2[y, x] += w * w * lum
            else:
                self.sum[y, x] += ti.cast(rgb, ti.f64)
                self.sum_sq[y, x] += lum * lum
        else:
            ti.atomic_add(self.nonfinite[None], 1)

    def count_samples(self, weight: int = 1):
        """Every pixel took one more sample, of this weight."""
        if weight != 1 and not self.weighted:
            raise ValueError("an unweighted film takes samples of weight 1")
        self.samples_per_pixel += weight
        self.passes += 1
        self.weight_sq_sum += weight * weight

    def mean(self) -> np.ndarray:
        """Mean radiance per pixel, (H, W, 3) float64."""
        n = max(self.samples_per_pixel, 1)
        return self.sum.to_numpy() / n

    def standard_error(self) -> np.ndarray:
        """Standard error of each pixel's mean luminance, (H, W): of a weighted mean m = sum w F /
        sum w, sum w^2 (F - m)^2 / (sum w)^2 x P / (P - 1) for P samples (with w = 1 the
        sample variance over n)."""
        n, passes = self.samples_per_pixel, self.passes
        if passes < 2:
            return np.full((self.height, self.width), np.inf)
        m = (self.sum.to_numpy() @ np.array([0.2126, 0.7152, 0.0722])) / n
        w2_lum = self.sum_w2.to_numpy() if self.weighted else m * n
        spread = self.sum_sq.to_numpy() - 2.0 * m * w2_lum + m * m * self.weight_sq_sum
        return np.sqrt(np.maximum(spread, 0.0) / (n * n) * passes / (passes - 1))

    def dropped(self) -> int:
        return int(self.nonfinite[None])


FIXED_STEPS = 4294967296.0      # 2^32 fixed-point steps per radiance_scale
FIXED_LIMIT = 2.0e9             # in radiance_scale units: i64 holds 2^31 of them with room to sum


@data_oriented
class SplatFilm:
    """A film that samples may reach at any pixel (light tracing, merging), deterministically.

    Within an iteration contributions are summed in 64-bit integer fixed point (one step is
    radiance_scale / 2^32): integer atomics do not depend on the order in which threads add,
    so a seed gives the same image for any thread count. flush() adds the iteration's frame
    to the float64 Film as one sample per pixel. A contribution that is not finite, or beyond
    2e9 x radiance_scale, is dropped and counted."""

    def __init__(self, width: int, height: int, radiance_scale: float, weighted: bool = False):
        self.width, self.height = width, height
        self.film = Film(width, height, weighted)
        self.radiance_scale = float(radiance_scale)
        self.unit = self.radiance_scale / FIXED_STEPS
        self.fields = FieldGroup("splat-film")
        self.frame = self.fields.vector(3, ti.i64, (height, width))
        self.nonfinite = self.fields.scalar(ti.i64)
        self.fields.finalize()

    def release(self):
        self.fields.release()
        self.film.release()

    def reset(self):
        self.frame.fill(0)
        self.nonfinite.fill(0)
        self.film.reset()

    @ti.func
    def fixed(self, rgb):
        """rgb in fixed point (rounded to the nearest step), or zero and counted if unusable."""
        out = ti.Vector([0, 0, 0], ti.i64)
        scaled = ti.cast(rgb, ti.f64) * ti.f64(1.0 / self.unit)
        if (scaled == scaled).all() and scaled.max() < ti.static(FIXED_LIMIT * FIXED_STEPS) and scaled.min() >= 0.0:
            out = ti.cast(ti.cast(scaled, ti.f64) + 0.5, ti.i64)
        else:
            ti.atomic_add(self.nonfinite[None], 1)
        return out

    @ti.func
    def add_fixed(self, y: ti.i32, x: ti.i32, value):
        for c in ti.static(range(3)):
            ti.atomic_add(self.frame[y, x][c], value[c])

    @ti.func
    def splat(self, y: ti.i32, x: ti.i32, rgb):
        self.add_fixed(y, x, self.fixed(rgb))

    @ti.func
    def flush_pixel(self, y: ti.i32, x: ti.i32):
        """The pixel's frame joins the film and is cleared (a method's own end-of-iteration
        kernel may call this for every pixel, then count_flushed(), to save a launch)."""
        self.flush_pixel_weighted(y, x, 1.0)

    @ti.func
    def flush_pixel_weighted(self, y: ti.i32, x: ti.i32, weight: ti.f64):
        """flush_pixel with the pass's weight, in a weighted film."""
        self.film.add_weighted(y, x, ti.cast(self.frame[y, x], ti.f64) * ti.f64(self.unit), weight)
        self.frame[y, x] = ti.Vector([0, 0, 0], ti.i64)

    @ti.kernel
    def _flush(self):
        ti.loop_config(serialize=ti.static(serial_loop(self.width * self.height)))
        for y, x in ti.ndrange(self.height, self.width):
            self.flush_pixel(y, x)

    def flush(self):
        """End of an iteration: its frame becomes one sample of every pixel."""
        self._flush()
        self.count_flushed()

    def count_flushed(self, weight: int = 1):
        """Every pixel's frame was flushed (flush_pixel): one more sample per pixel, of this weight."""
        self.film.count_samples(weight)

    def clear_frame(self):
        self.frame.fill(0)

    def mean(self) -> np.ndarray:
        return self.film.mean()

    def standard_error(self) -> np.ndarray:
        return self.film.standard_error()

    def dropped(self) -> int:
        return int(self.nonfinite[None]) + self.film.dropped()

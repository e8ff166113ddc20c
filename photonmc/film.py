"""Per-pixel accumulators in float64, with an account of samples that were not finite.

Progressive runs add millions of samples per pixel; float32 sums would stop growing.
A sample that is NaN or infinite is dropped and counted, never added to the image.
"""
import numpy as np
import taichi as ti

from .kernels.fields import FieldGroup
from .kernels.sampling import luminance


@ti.data_oriented
class Film:
    def __init__(self, width: int, height: int):
        self.width, self.height = width, height
        self.fields = FieldGroup("film")
        self.sum = self.fields.vector(3, ti.f64, (height, width))
        self.sum_sq = self.fields.scalar(ti.f64, (height, width))    # of luminance, for error bars
        self.nonfinite = self.fields.scalar(ti.i64)
        self.fields.finalize()
        self.samples_per_pixel = 0

    def release(self):
        self.fields.release()

    def reset(self):
        self.sum.fill(0)
        self.sum_sq.fill(0)
        self.nonfinite.fill(0)
        self.samples_per_pixel = 0

    @ti.func
    def add(self, y: ti.i32, x: ti.i32, rgb):
        finite = True
        for k in ti.static(range(3)):
            if not (rgb[k] == rgb[k] and ti.abs(rgb[k]) < ti.math.inf):
                finite = False
        if finite:
            self.sum[y, x] += ti.cast(rgb, ti.f64)
            lum = ti.cast(luminance(rgb), ti.f64)
            self.sum_sq[y, x] += lum * lum
        else:
            ti.atomic_add(self.nonfinite[None], 1)

    def mean(self) -> np.ndarray:
        """Mean radiance per pixel, (H, W, 3) float64."""
        n = max(self.samples_per_pixel, 1)
        return self.sum.to_numpy() / n

    def standard_error(self) -> np.ndarray:
        """Standard error of each pixel's mean luminance, (H, W)."""
        n = self.samples_per_pixel
        if n < 2:
            return np.full((self.height, self.width), np.inf)
        s = self.sum.to_numpy() @ np.array([0.2126, 0.7152, 0.0722])
        var = np.maximum(self.sum_sq.to_numpy() / n - (s / n) ** 2, 0.0) * n / (n - 1)
        return np.sqrt(var / n)

    def dropped(self) -> int:
        return int(self.nonfinite[None])

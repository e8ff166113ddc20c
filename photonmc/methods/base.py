"""The interface every rendering method implements, so that the progressive loop, the
preview and the convergence tools treat them alike."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import SettingsError


@dataclass
class MethodSettings:
    seed: int = 0
    max_depth: int | None = None          # None: the scene's integrator max_depth
    options: dict = field(default_factory=dict)   # method-specific (e.g. photons, alpha)

    def __post_init__(self):
        if not 0 <= self.seed < 2**32:
            raise SettingsError(f"--seed must be in [0, 2^32), got {self.seed}")
        if self.max_depth is not None and not (self.max_depth == -1 or 1 <= self.max_depth <= 1 << 20):
            raise SettingsError(f"--max-depth must be -1 (unbounded) or between 1 and 2^20, got {self.max_depth}")


class Method:
    """One progressive estimator. Subclasses implement _iterate(), image(), method_stats()."""
    name = "?"
    work_unit = "paths"              # what work_done counts, for rates in progress and stats
    default_iterations = 64
    OPTIONS: dict = {}               # method-specific options and their defaults
    # True where an iteration depends on nothing but its index (the seed, and for vcm the
    # radius schedule r_i): several workers can then render interleaved slices of one render
    # (worker k of W takes indices k, k+W, ...), and their merge is that render
    # (distributed.py, docs/resume.md). Progressive per-pixel statistics (sppm's radii) and
    # Markov chains carry state from one iteration to the next, so not for those.
    independent_iterations = False

    def __init__(self, dscene, settings: MethodSettings):
        self.dscene = dscene
        self.settings = settings
        self.seed_u32 = settings.seed & 0xFFFFFFFF
        self.iterations = 0
        self.work_done = 0
        self.slice_offset, self.slice_stride = 0, 1
        given = {k: v for k, v in settings.options.items() if v is not None}
        unknown = set(given) - set(self.OPTIONS)
        if unknown:
            names = ", ".join("--" + k.replace("_", "-") for k in sorted(unknown))
            raise SettingsError(f"method '{self.name}' does not take {names}")
        self.options = {**self.OPTIONS, **given}

    @classmethod
    def iterations_independent(cls, options: dict) -> bool:
        """Whether a render with these options may be split into interleaved slices of its
        iterations (distributed.py): independent_iterations, unless an option makes a pass
        depend on the ones before (vcm's --light-paths auto)."""
        return cls.independent_iterations

    def interleave(self, offset: int, stride: int) -> None:
        """Render only the iteration indices offset, offset + stride, ... of the render."""
        if not self.independent_iterations and stride != 1:
            raise SettingsError(f"method '{self.name}' cannot render interleaved slices of its iterations")
        if not (0 <= offset < stride) or self.iterations:
            raise SettingsError(f"bad iteration slice {offset}/{stride}")
        self.slice_offset, self.slice_stride = int(offset), int(stride)

    @property
    def iteration_index(self) -> int:
        """The index of the next iteration within the whole render (its random numbers, and
        vcm's radius, are drawn for this index)."""
        return self.slice_offset + self.slice_stride * self.iterations

    def iterate(self) -> None:
        self._iterate()
        self.iterations += 1

    def _iterate(self) -> None:
        raise NotImplementedError

    def warm_up(self) -> None:
        """Compile what the method's iterations may launch (an iteration; a method whose
        passes come in kinds compiles each), before a reset() that forgets the work; used to
        keep compilation out of measured time."""
        self.iterate()

    def image(self) -> np.ndarray:
        """Current estimate, (H, W, 3) float64 linear radiance."""
        raise NotImplementedError

    def method_stats(self) -> dict:
        return {}

    def progress_fields(self) -> str:
        """A few live figures for the progress line (e.g. acceptance rate, mutation size)."""
        return ""

    def reset(self) -> None:
        """Forget all accumulated work but keep compiled kernels (used to exclude compile
        time from measurements: iterate once, reset, then time)."""
        self.iterations = 0
        self.work_done = 0
        self._reset()

    def _reset(self) -> None:
        raise NotImplementedError

    def release(self) -> None:
        """Free the method's device memory; override when the method owns fields."""

    def stats(self) -> dict:
        return {"method": self.name, "iterations": self.iterations, self.work_unit: self.work_done,
                **self.method_stats()}

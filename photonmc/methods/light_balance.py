"""vcm's light subpaths per pass, found by measuring (docs/vcm.md, "Light subpaths per pass").

A vcm pass traces N light subpaths and one camera subpath per pixel. Its variance has a part
that N does not touch (next-event estimation, emitter hits, the connections to the one light
subpath a pixel is paired with) and a part that falls with N (merging, light tracing), but not
as 1 / N: as N falls VCM's own weights move the light side's share from merging to the
connections (measured: a vcm pass's light side grows 1.6-4.8x for 16x fewer light subpaths,
docs/mbe.md, stop 38), so a model of the split predicts N badly. Its time, too, is not split
the way the techniques are: the connections are camera work.

So the balance measures the thing it minimises, variance x work per pass, at two N a factor
sqrt(2) apart (PROBE), and moves between them:
- passes run in blocks of two at the same N, alternating the upper and the lower probe; the
  second pass of a block against the first estimates the variance of one pass at that N
  (Var(X1 - X2) = 2 V, summed over the pixels in luminance);
- work is counted (so that a seed gives one image): camera rays, connections, light segments
  and light-tracing rays, merge candidates, in the cost model fitted to measured time per
  pass at three N on seven rooms (tools/vcm_pass_split.py; docs/mbe.md, stop 38);
- once each probe has BLOCKS estimates, the centre moves a factor sqrt(2) toward the probe
  with the smaller variance x work, and the sums start again (the variance changes as the
  radius shrinks; both probes are interleaved, so they see the same radius); each move
  against the one before lengthens that window by BLOCKS, so the centre settles near the
  optimum, where the product is flat (a probe a factor 2^(1/4) off costs under 2 %), instead
  of dithering on noise.
vcm uses it for --light-paths auto (its default), mbe for its vcm passes. The balance sees
variance, not the merging radius's bias, which falls with the number of passes: where that
bias dominates (the caustic, the attic at 15 s) a fixed quarter of the pixels did better
(docs/vcm.md). tools/vcm_pass_work.py sets the counted work against measured time.
"""
from __future__ import annotations

import math

# The fitted cost model (tools/vcm_pass_split.py): time per pass ~ CAMERA_WEIGHT x (a ray per
# camera subpath, three per non-delta camera vertex) + connections + light segments +
# light-tracing rays + MERGE_WEIGHT x merge candidates.
CAMERA_WEIGHT = 0.78
MERGE_WEIGHT = 0.225
PROBE = 2.0 ** 0.25       # the probes lie this factor above and below the centre
BLOCKS = 12               # variance estimates per probe before the centre moves
# The variance of a pass, as mbe's pass choice reads it (methods/pass_choice.py): the mean of
# all estimates so far, reported once MEASURED_AFTER are in. The spread of two passes is
# heavy-tailed (the caustic: 0.005 for 300 estimates, then one of 40), so a mean over a recent
# window forgets the rare large ones that make the variance (docs/mbe.md, stop 40).
MEASURED_AFTER = 16
FEWEST = 64               # the centre's range: [most / FEWEST, most]
START = 4                 # the centre starts at most / START, two octaves from the top, four from the bottom


class RunningMean:
    """The mean of a stream of estimates and its standard error (Welford's update): a pass's
    variance from many pair estimates, whose spread is heavy-tailed, so that the standard
    error comes from their own spread, not from a Gaussian model."""

    def __init__(self):
        self.count = 0
        self.mean = 0.0
        self.m2 = 0.0

    def add(self, x: float) -> None:
        self.count += 1
        delta = x - self.mean
        self.mean += delta / self.count
        self.m2 += delta * (x - self.mean)

    def mean_after(self, least: int) -> float | None:
        """The mean, once `least` estimates are in."""
        return self.mean if self.count >= least else None

    def relative_error_after(self, least: int) -> float | None:
        """The standard error of the mean over the mean (the spread over the root of the
        count), once `least` (at least 2) estimates are in and the mean is positive."""
        if self.count < max(least, 2) or not self.mean > 0.0:
            return None
        return math.sqrt(self.m2 / (self.count - 1)) / math.sqrt(self.count) / self.mean


class LightPathBalance:
    """The light subpaths of each vcm pass, between most / FEWEST and `most` (the store's)."""

    def __init__(self, most: int):
        self.most = int(most)
        self.fewest = max(1, self.most // FEWEST)
        self.log2_centre = math.log2(max(self.most / START, self.fewest))
        self.phase = 0                 # 0, 1: upper probe; 2, 3: lower probe
        self.sums = [0.0, 0.0, 0.0, 0.0]   # variance, work of the upper probe; of the lower
        self.blocks = [0, 0]
        self.moves = 0
        self.reversals = 0             # moves against the one before: each lengthens the window
        self.last_step = 0.0
        self.passes = 0
        self.light_paths_sum = 0.0
        self.last_ratio = 0.0          # lower probe's variance x work over the upper's, at the last move
        self.variance = RunningMean()  # a pass's variance, mean over all estimates (pass_variance)

    def probe(self, side: int) -> int:
        n = 2.0 ** self.log2_centre * (PROBE if side == 0 else 1.0 / PROBE)
        return int(min(max(round(n), self.fewest), self.most))

    def next_light_paths(self) -> int:
        """The light subpaths of the next pass."""
        return self.probe(self.phase // 2)

    def observe(self, n_light: int, spread: float, n_pixels: int, work: float) -> None:
        """The pass just made: its light subpaths, the sum over pixels of (its estimate - the
        last pass's)^2 in luminance, and its counted work."""
        self.passes += 1
        self.light_paths_sum += n_light
        side, second = self.phase // 2, self.phase % 2 == 1
        self.phase = (self.phase + 1) % 4
        if not second or not (math.isfinite(spread) and math.isfinite(work)):
            return
        variance = 0.5 * spread / n_pixels
        self.variance.add(variance)
        self.sums[2 * side] += variance
        self.sums[2 * side + 1] += work
        self.blocks[side] += 1
        if min(self.blocks) >= BLOCKS * (1 + self.reversals):
            upper = self.sums[0] * self.sums[1]
            lower = self.sums[2] * self.sums[3]
            if upper + lower > 0.0:
                # (stats only) a side that measured no variance at all: a dim room's first blocks
                self.last_ratio = lower / upper if upper > 0.0 else math.inf
                step = -0.5 if lower < upper else 0.5
                self.reversals += int(step * self.last_step < 0.0)
                self.last_step = step
                self.log2_centre = min(max(self.log2_centre + step, math.log2(self.fewest)), math.log2(self.most))
                self.moves += 1
            self.sums = [0.0, 0.0, 0.0, 0.0]
            self.blocks = [0, 0]

    def pass_variance(self) -> float | None:
        """The variance of one pass (luminance, mean over pixels) at about the centre's light
        subpaths, once MEASURED_AFTER estimates are in."""
        return self.variance.mean_after(MEASURED_AFTER)

    def pass_variance_relative_error(self) -> float | None:
        """The standard error of pass_variance() over its value. A rare large estimate raises
        it, so that mbe's pass choice does not trust a mean that one event decides
        (methods/pass_choice.py)."""
        return self.variance.relative_error_after(MEASURED_AFTER)

    @staticmethod
    def work(n_pixels: int, camera_vertices: float, connections: float, segments: float, light_rays: float,
             merges: float) -> float:
        """A pass's work in the fitted cost model, from its counts."""
        return (CAMERA_WEIGHT * (n_pixels + 3.0 * camera_vertices) + connections + segments + light_rays
                + MERGE_WEIGHT * merges)

    def stats(self) -> dict:
        return {"centre": 2.0 ** self.log2_centre, "moves": self.moves, "reversals": self.reversals,
                "light_paths_mean": self.light_paths_sum / self.passes if self.passes else None,
                "last_lower_over_upper": self.last_ratio or None}

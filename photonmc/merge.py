"""Merging independent renders of one scene (`photonmc merge`, and the driver of a render on
several workers, distributed.py). docs/resume.md says what a merge means for each method.

Every member of a merge is a whole render with its own seed stream, or, for methods whose
iterations are independent (pt, vcm: Method.independent_iterations), an interleaved slice
of one render (iterations k, k+W, ...). The merged image is the iteration-weighted mean of
the members' images; the slices of one render merge into that render (to float rounding),
bias included. For independent seed streams:
- pt: iteration k of a render is one sample per pixel, so this is the mean of all samples
  of all members, the same estimator as one render with their total samples (only the
  order of float additions differs);
- the consistent methods (sppm, the guided ones, vcm): each member is a progressive
  estimate whose bias falls with its own iteration count (its radius shrinks with it), so
  the merged image has the variance of the members' total work but the bias of a member,
  not of one render that long. tests/test_state.py measures it.
"""
from __future__ import annotations

import numpy as np

from .state import RenderState, StateError

WORKER_SEED_STEP = 0x9E3779B9      # odd: seeds of workers 0..2^32-1 are all distinct


def worker_seed(seed: int, worker: int) -> int:
    """The seed stream of worker `worker` of a distributed render: worker 0 renders exactly
    what a single `photonmc render --seed SEED` would."""
    return (int(seed) + int(worker) * WORKER_SEED_STEP) & 0xFFFFFFFF


def _identity_without_seed(member: RenderState) -> dict:
    return {k: v for k, v in member.job.items() if k not in ("seed", "iteration_slice")}


def iteration_slice(member: RenderState) -> tuple[int, int]:
    return tuple(member.job.get("iteration_slice", (0, 1)))


def check_mergeable(members: list[RenderState]) -> None:
    """Members must render the same scene with the same method and settings, from
    different seeds (the same seed would repeat the same samples, not add new ones)."""
    if not members:
        raise StateError("nothing to merge")
    first = members[0]
    seeds = {}
    for k, m in enumerate(members):
        if m.method != first.method:
            raise StateError(f"cannot merge a '{m.method}' render with a '{first.method}' render")
        if m.scene_hash != first.scene_hash or tuple(m.resolution) != tuple(first.resolution):
            raise StateError(f"render {k + 1} is of a different scene (or resolution) than render 1")
        if _identity_without_seed(m) != _identity_without_seed(first):
            raise StateError(f"render {k + 1} has other settings than render 1 "
                             f"({_difference(_identity_without_seed(first), _identity_without_seed(m))})")
        # Same seed: only disjoint interleaved slices of one render (same stride, other offsets).
        for j in seeds.get(m.seed, []):
            (o1, s1), (o2, s2) = iteration_slice(members[j]), iteration_slice(m)
            if s1 == 1 or s1 != s2 or o1 == o2:
                raise StateError(f"renders {j + 1} and {k + 1} both have seed {m.seed}: they are the same samples, "
                                 f"not independent ones (render them with different --seed)")
        seeds.setdefault(m.seed, []).append(k)


def _difference(a: dict, b: dict) -> str:
    keys = sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))
    return ", ".join(f"{k}: {a.get(k)!r} vs {b.get(k)!r}" for k in keys)


def merged_image(members: list[RenderState]) -> np.ndarray:
    """Iteration-weighted mean of the members' images, (H, W, 3) float64."""
    weights = np.array([m.iterations for m in members], np.float64)
    if not (weights > 0).any():
        raise StateError("none of the renders to merge has finished an iteration")
    total = np.zeros_like(np.asarray(members[0].image, np.float64))
    for w, m in zip(weights, members):
        if w > 0:
            total += w * np.asarray(m.image, np.float64)
    return total / weights.sum()


def summary(members: list[RenderState]) -> dict:
    return {"method": members[0].method, "renders": len(members),
            "iterations": int(sum(m.iterations for m in members)),
            "work_done": int(sum(m.work_done for m in members)),
            "seeds": [m.seed for m in members],
            "iterations_per_render": [m.iterations for m in members]}

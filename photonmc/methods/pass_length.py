"""A chain pass's length between a few tens of visible uniform proposals per chain and the
fewest each method allows (MIN_REGENERATIONS: a quarter for the guided photon methods, one for
mbe), chosen by the effort balance (EffortBalance.chain_pass_length). Shared by the guided photon
methods (docs/guiding.md, "Guided passes as long as the camera side allows") and mbe's chain
passes (docs/mbe.md, "Chain passes as long as the camera side allows").

A chain records from its first visible uniform proposal of the pass (an exact draw from the
pass's target: ChainPool.run_pass), so a pass must be long enough for its chains to meet
some; the regeneration rule asks for R of them per chain. Where the camera side carries the
error, a long pass buys light-side variance nobody needs and starves the camera side; fewer
regenerations lose more of each chain's first steps but make more camera passes.
"""
from __future__ import annotations

import math

import numpy as np

from .effort import HISTORY

CANDIDATES = 48           # lengths scored between the fewest and the regeneration rule's
B_MEMORY = 0.9            # the visible share that sizes a shortened pass: each pass's counts fade by this


def recorded_share(regenerations, burn_in: float):
    """The expected share of a pass's steps that a ladder records, where it expects
    `regenerations` visible uniform proposals in the pass (R = b x its steps): it records from
    its first one, whose step is near exponential with rate b, and only after the burn-in
    share beta, so f = (1 - beta) - (e^(-beta R) - e^(-R)) / R  (beta 0: 1 - (1 - e^(-R)) / R)."""
    r = np.maximum(np.asarray(regenerations, float), 1e-12)
    return (1.0 - burn_in) - (np.exp(-burn_in * r) - np.exp(-r)) / r


class BalancedPassLength:
    """What the choice keeps between passes: the visible uniform proposals' fading counts
    (a pass of few regenerations sees few of them, so its own visible share is too noisy to
    size the next one) and the recorded shares of the last HISTORY passes (the balance's V_p
    is a mean of their variance per step, which goes as 1 / the share recorded: their
    harmonic mean is the share it was measured at)."""

    def __init__(self):
        self.visible_counts = np.zeros(2)     # visible and all uniform proposals, fading by B_MEMORY
        self.inverse_shares = []              # 1 / the recorded share of the last HISTORY passes

    def observe_counts(self, visible: float, uniform: float) -> None:
        self.visible_counts = B_MEMORY * self.visible_counts + (float(visible), float(uniform))

    def visible_share(self) -> float:
        """The fading visible share of uniform proposals (0 before any was visible)."""
        return float(self.visible_counts[0] / self.visible_counts[1]) if self.visible_counts[0] > 0 else 0.0

    def record(self, share: float) -> None:
        """The recorded share the model expects of the pass being made."""
        self.inverse_shares.append(1.0 / max(share, 1e-6))
        del self.inverse_shares[:-HISTORY]

    def choose(self, effort, shortest: int, longest: int, share_of, steps_now: int, camera_paths: int,
               most: int) -> int:
        """The length in [shortest, longest] (chain steps) the effort balance expects to serve
        the image best; share_of(lengths) gives each length's recorded share. `longest` where
        there is nothing to go by yet."""
        if shortest >= longest or not self.inverse_shares:
            return longest
        lengths = np.unique(np.geomspace(shortest, longest, CANDIDATES).astype(np.int64))
        efficiency_now = len(self.inverse_shares) / math.fsum(self.inverse_shares)
        best = effort.chain_pass_length(lengths, share_of(lengths), efficiency_now, steps_now, camera_paths, most)
        return longest if best is None else best

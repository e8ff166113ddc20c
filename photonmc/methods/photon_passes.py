"""visibility's and spatial-tf's choice, pass by pass, between a chain pass and a uniform pass
(docs/guiding.md, "Uniform passes where the chains do not pay").

Each step of a chain pass starts with a uniform photon, and those photons are an estimate of
their own, sppm's (U), joined to the chains' (C) as beta U + (1 - beta) C with beta of least
variance (effort.UniformWeight). Where photons are plentiful beta is large: the chains add
little to what the uniform photons give, and a chain pass costs more than as many photons
traced plainly (the proposal, the mutation, the kept vertex lists, the adaptation). A uniform
pass traces the pass's photons plainly, at the same camera paths per pixel, into U's
accumulator alone: an sppm photon pass. Both kinds estimate each pixel at its radius and the
film weighs a pass by its photons, so the kind may change from pass to pass without changing
what the image converges to (mbe's vcm passes rest on the same argument, pass_choice.py).

At the same camera pass and n photons the kinds differ only on the photon side:

    chain pass:  r V_U / n  at photon work  w_chain n,      uniform pass:  V_U / n  at  w_uniform n,

r = Var(beta U + (1 - beta) C) / Var(U), read from UniformWeight's sums (r <= 1 at the
least-variance beta). The uniform pass is taken where r w_chain > w_uniform. Work is counted,
not timed, so that a seed gives one image: segments traced, DEPOSIT_WORK per deposit, and
CHAIN_STEP_WORK per chain step for its own bookkeeping.

Uniform passes are considered only where r > MIN_RATIO (below). Measurements: beta needs chain
passes, so while uniform passes win, every CHAIN_EVERY-th pass is still a chain pass (at r <= 1
such a pass never adds variance, only work). w_uniform needs uniform passes; where chains win one
is made at passes 2^k (k >= 4) only, since a uniform pass adds 1/r times a chain pass's photon
variance (the film weighs it by its photons alone).

The rest of the render follows the kind being chosen: the effort balance and the balanced
radius rule take their measurements from passes of that kind only, and the radius shrinks by
the chain passes' counts in either kind (guided.py).
"""
from __future__ import annotations

from .effort import DEPOSIT_WORK

# A chain step's own cost in photon segments, besides the segments it traces and its deposits
# (proposal and acceptance, the pending weights, replaying a kept vertex list): fitted to the
# time per pass of both kinds at one camera path per pixel on four rooms (the balustrade, the
# Cornell box, light-gap, the transom slot: 2.3-2.5; docs/guiding.md, "Uniform passes where
# the chains do not pay").
CHAIN_STEP_WORK = 2.4
FIRST_CHOICE = 16        # passes before the first uniform pass: beta settles (UniformWeight.MEMORY)
CHAIN_EVERY = 8          # while uniform passes win, every this-many-th pass is a chain pass
MEMORY = 0.9             # the work per photon of each kind: exponentially weighted, per pass
# Uniform passes only where the chains at most halve the photon variance (r > MIN_RATIO, about
# beta > 1/2: the uniform photons already carry most of a chain pass's estimate). Below it a
# chain pass's lower noise also lets the balanced radius rule shrink the radius, which the
# variance x work comparison does not see: in light-gap (r 0.24-0.36, a chain pass 2.8-3.1x a
# uniform pass's work) the comparison chose uniform passes early, the radius ended 27 % larger
# and the RMSE 10-20 % higher (docs/guiding.md).
MIN_RATIO = 0.5


class PhotonPassChoice:
    def __init__(self):
        self.passes = 0
        self.uniform_passes = 0
        self.work_chain = 0.0        # photon work per step, weighted sums and their weights
        self.weight_chain = 0.0
        self.work_uniform = 0.0
        self.weight_uniform = 0.0
        self.ratio = 1.0             # r: the chain pass's photon variance over the uniform pass's
        self.uniform_wins = False

    def next_is_uniform(self) -> bool:
        """Whether the next pass is a uniform pass (the pass index is self.passes)."""
        k = self.passes
        if k < FIRST_CHOICE:
            return False
        if self.ratio <= MIN_RATIO:
            self.uniform_wins = False
            return False
        if k & (k - 1) == 0:             # at 16, 32, 64, ...: w_uniform measured again
            return True
        if not self.weight_uniform or not self.weight_chain:
            return False
        self.uniform_wins = self.ratio * self.work_chain / self.weight_chain > self.work_uniform / self.weight_uniform
        return self.uniform_wins and k % CHAIN_EVERY != 0

    def observe(self, uniform: bool, steps: int, segments: float, deposits: float) -> None:
        """The pass just made: its kind, its photons (steps), the segments it traced and the
        photons it deposited into measurement points."""
        self.passes += 1
        work = segments + DEPOSIT_WORK * deposits + (0.0 if uniform else CHAIN_STEP_WORK * steps)
        if uniform:
            self.uniform_passes += 1
            self.work_uniform = MEMORY * self.work_uniform + work / max(steps, 1)
            self.weight_uniform = MEMORY * self.weight_uniform + 1.0
        else:
            self.work_chain = MEMORY * self.work_chain + work / max(steps, 1)
            self.weight_chain = MEMORY * self.weight_chain + 1.0

    def observe_variances(self, beta: float, sums) -> None:
        """r from UniformWeight's sums (U's, C's, their product), at the beta in use."""
        s_u, s_c, s_uc = (float(x) for x in sums)
        if s_u > 0.0:
            combined = beta * beta * s_u + (1.0 - beta) ** 2 * s_c + 2.0 * beta * (1.0 - beta) * s_uc
            self.ratio = max(combined, 0.0) / s_u

    def stats(self) -> dict:
        return {"uniform_passes": self.uniform_passes, "chain_passes": self.passes - self.uniform_passes,
                "chain_variance_ratio": self.ratio, "uniform_wins": self.uniform_wins,
                "photon_work_per_step_chain": self.work_chain / self.weight_chain if self.weight_chain else None,
                "photon_work_per_step_uniform": (self.work_uniform / self.weight_uniform
                                                 if self.weight_uniform else None)}

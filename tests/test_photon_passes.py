"""The guided photon methods' choice between chain passes and uniform passes
(methods/photon_passes.py): what it compares, and when it measures."""
import pytest

from photonmc.methods.photon_passes import CHAIN_EVERY, CHAIN_STEP_WORK, FIRST_CHOICE, MIN_RATIO, PhotonPassChoice


def run(choice: PhotonPassChoice, passes: int, ratio: float, chain_work: float, uniform_work: float) -> list[bool]:
    """`passes` passes whose chains have variance ratio r = `ratio` and whose photon work per
    step (segments, no deposits) is as given; returns each pass's kind (True: uniform)."""
    kinds = []
    for _ in range(passes):
        uniform = choice.next_is_uniform()
        kinds.append(uniform)
        segments = uniform_work if uniform else chain_work - CHAIN_STEP_WORK
        choice.observe(uniform, 1000, segments * 1000, 0.0)
        choice.ratio = ratio
    return kinds


def test_the_variance_ratio_is_that_of_the_combined_estimate():
    """U and C independent, of variances 1 and 3 (UniformWeight's sums are 4x these): at
    beta = 3/4, Var(beta U + (1 - beta) C) = 9/16 + 3/16 = 3/4 of Var(U)."""
    choice = PhotonPassChoice()
    choice.observe_variances(0.75, (4.0, 12.0, 0.0))
    assert choice.ratio == pytest.approx(0.75)
    choice.observe_variances(1.0, (4.0, 12.0, 0.0))
    assert choice.ratio == pytest.approx(1.0)
    choice.observe_variances(0.0, (4.0, 2.0, 1.0))     # the chains' estimate alone
    assert choice.ratio == pytest.approx(0.5)


def test_uniform_passes_where_the_chains_do_not_pay():
    """r = 0.9 at a chain step's work 7 against a uniform photon's 4: r x 7 > 4, so uniform
    passes win once both are measured, and every CHAIN_EVERY-th pass stays a chain pass."""
    kinds = run(PhotonPassChoice(), 200, 0.9, 7.0, 4.0)
    assert not any(kinds[:FIRST_CHOICE])
    assert kinds[FIRST_CHOICE]                       # the first uniform pass measures its work
    later = kinds[FIRST_CHOICE + 2:]
    assert sum(later) > 0.8 * len(later)
    assert all(not kinds[k] for k in range(FIRST_CHOICE + 2, 200) if k % CHAIN_EVERY == 0 and k & (k - 1))


def test_chain_passes_where_the_chains_pay_for_their_work():
    """r = 0.6 at work 7 against 4: 0.6 x 7 > 4 is false, so only the measuring passes (at
    passes 2^k) are uniform."""
    kinds = run(PhotonPassChoice(), 300, 0.6, 6.0, 4.0)
    assert [k for k, u in enumerate(kinds) if u] == [16, 32, 64, 128, 256]


def test_no_uniform_pass_where_the_chains_halve_the_photon_variance():
    """r <= MIN_RATIO: not even a measuring pass, whatever the work (a uniform pass adds 1/r
    times a chain pass's variance, and the radius rule gains from the chains' lower noise)."""
    kinds = run(PhotonPassChoice(), 300, MIN_RATIO * 0.9, 100.0, 1.0)
    assert not any(kinds)

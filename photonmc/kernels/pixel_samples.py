"""Where in its pixel a camera sample starts: per-pixel scrambled Sobol' (0,2)-sequences.

Pixel p's camera samples over the whole render take their positions in the pixel from the
first two dimensions of Sobol's sequence, each Owen-scrambled by a hash of (seed, p) (nested
uniform scrambling done with one hash, Burley 2020, "Practical Hash-based Owen Scrambling",
JCGT 9(4)). Any 2^m consecutive points from a multiple of 2^m put one point in each
elementary box of area 2^-m, so an edge crossing the pixel is integrated with an error
falling as about n^-3/4 instead of n^-1/2 (Owen 1997): the aliasing noise of the pixels where
the camera sees a lamp's edge or a slit goes away faster. A scrambled point is uniform on the
pixel, so every estimator stays unbiased; the rest of a path keeps its independent random
numbers (kernels/rng.py).

Two replicates, even and odd passes: a pixel has two sequences, scrambled independently, and
a pass takes the next points of one of them in turn (PassSamples). Points 2k and 2k + 1 of
one sequence always lie in opposite halves of the pixel; had consecutive passes taken
consecutive points, every estimate that reads a pass's variance from its difference to the
pass before (vcm's light-path balance, the effort balance) would be inflated by up to 2x
where an edge crosses the pixel. Consecutive passes come from independent replicates, so
those estimates read the variance of independent passes, and each replicate alone keeps the
n^-3/4 rate (two half-length nets: in theory about 1.2x one sequence's error where an edge
decides; on the Cornell box no cost was measurable).

A pass of K samples per pixel takes K consecutive points of its replicate, so its K samples
are stratified too: a pass's camera variance is below V_c / K, which the effort balance, which
measures V_c at the K it runs, reads as a smaller camera side per path (docs/effort.md).
(K streams indexed by the pass, each slot its own sequence, keep V_c / K exact but stratify a
pixel's samples only slot by slot: mbe's chain passes at K = 13 lost 12 % against vcm on the
Cornell box that way.) mbe's chain passes and vcm passes fill films of their own, and each
kind has its own pair of sequences (VCM_PASS_STREAM), so that neither film is a gappy part
of one sequence. Resumed renders continue the sequences: the counts are saved with the
state; pt and vcm derive theirs from the iteration, so that sliced renders share them.
Measured in docs/convergence.md, "Stratified pixel positions".
"""
import taichi as ti

from ..errors import SettingsError
from . import rng

PIXEL_SAMPLERS = ("sobol", "independent")
_SALT = 0x5EED0000        # + 4 x stream + 2 x replicate + axis: a scramble per stream, replicate and axis
VCM_PASS_STREAM = 1       # mbe's vcm passes: sequences of their own, apart from its chain passes'


@ti.func
def reverse_bits(x: ti.u32) -> ti.u32:
    x = ((x >> 1) & ti.u32(0x55555555)) | ((x & ti.u32(0x55555555)) << 1)
    x = ((x >> 2) & ti.u32(0x33333333)) | ((x & ti.u32(0x33333333)) << 2)
    x = ((x >> 4) & ti.u32(0x0F0F0F0F)) | ((x & ti.u32(0x0F0F0F0F)) << 4)
    x = ((x >> 8) & ti.u32(0x00FF00FF)) | ((x & ti.u32(0x00FF00FF)) << 8)
    return (x >> 16) | (x << 16)


@ti.func
def _lower_bits_permutation(x: ti.u32, seed: ti.u32) -> ti.u32:
    """A seeded bijection of u32 in which each bit changes only as a function of the bits
    below it (adding, and xor with the product by an even constant): reversed, that is a
    nested scramble, each digit permuted by the digits above it (Burley 2020, after Laine and
    Karras 2011)."""
    x += seed
    x ^= x * ti.u32(0x6C50B47C)
    x ^= x * ti.u32(0xB82F1E52)
    x ^= x * ti.u32(0xC7AFE638)
    x ^= x * ti.u32(0x8D22F6E6)
    return x


@ti.func
def owen_scramble(x: ti.u32, seed: ti.u32) -> ti.u32:
    """Owen scrambling of the binary fraction x (its most significant bit is 1/2)."""
    return reverse_bits(_lower_bits_permutation(reverse_bits(x), seed))


@ti.func
def sobol_dim1(index: ti.u32) -> ti.u32:
    """The second dimension of Sobol's sequence (generator matrix: Pascal's triangle mod 2;
    its direction numbers v_0 = 1/2, v_j = v_(j-1) xor v_(j-1) / 2)."""
    v = ti.u32(0x80000000)
    x = ti.u32(0)
    i = index
    while i != 0:
        if i & ti.u32(1):
            x ^= v
        i >>= 1
        v ^= v >> 1
    return x


@ti.func
def to_unit(x: ti.u32) -> ti.f32:
    return ti.cast(x >> 8, ti.f32) * (1.0 / 16777216.0)


@ti.func
def pixel_position(seed: ti.u32, pixel: ti.u32, point: ti.u32, replicate: ti.u32, stream: ti.u32):
    """(u1, u2) in [0, 1)^2: point `point` of pixel `pixel`'s replicate `replicate` (0 or 1)
    in stream `stream`. The first dimension of Sobol's sequence is the point's index with its
    bits reversed, so its scramble skips the reversal twice."""
    salt = ti.u32(_SALT) + ti.u32(4) * stream + ti.u32(2) * replicate
    ux = reverse_bits(_lower_bits_permutation(point, rng.seed(seed, pixel, salt)))
    uy = owen_scramble(sobol_dim1(point), rng.seed(seed, pixel, salt + ti.u32(1)))
    return to_unit(ux), to_unit(uy)


@ti.func
def pixel_sample(sobol: ti.template(), seed: ti.u32, pixel: ti.u32, point: ti.u32, replicate: ti.u32,
                 stream: ti.u32, state: ti.template()):
    """The camera sample's (u1, u2) in its pixel: point `point` of the pixel's replicate
    `replicate` in stream `stream` (sobol), or the next two numbers of the path's own random
    numbers (--pixel-samples independent)."""
    u1, u2 = 0.0, 0.0
    if ti.static(sobol):
        u1, u2 = pixel_position(seed, pixel, point, replicate, stream)
    else:
        u1 = rng.next_float(state)
        u2 = rng.next_float(state)
    return u1, u2


def iteration_points(iteration: int) -> tuple[int, int]:
    """(first point, replicate) of a pass of one sample per pixel that is the render's
    iteration `iteration` (pt, vcm): what PassSamples would give, derived from the iteration
    alone, so that interleaved slices of a render walk its sequences."""
    return iteration // 2, iteration % 2


class PassSamples:
    """Where each pass's K samples per pixel lie in the pixels' two replicates: the next K
    points of replicate (passes so far) % 2. The counts are part of a render's state."""

    def __init__(self):
        self.passes = 0
        self.points_even = 0          # points taken from replicate 0 so far, and from 1
        self.points_odd = 0

    def take(self, k: int) -> tuple[int, int]:
        """(first point, replicate) of the next pass of k samples per pixel."""
        replicate = self.passes % 2
        first = self.points_odd if replicate else self.points_even
        if replicate:
            self.points_odd += k
        else:
            self.points_even += k
        self.passes += 1
        return first, replicate


def uses_sobol(options: dict) -> bool:
    """--pixel-samples, checked: whether the camera samples' positions come from the pixel's
    sequences (the default since stop 47; docs/convergence.md, "Stratified pixel
    positions")."""
    value = options["pixel_samples"]
    if value not in PIXEL_SAMPLERS:
        raise SettingsError(f"--pixel-samples must be one of {', '.join(PIXEL_SAMPLERS)}, got '{value}'")
    return value == "sobol"

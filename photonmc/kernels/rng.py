"""Counter-based random numbers kept in registers.

ti.random() does not scale across CPU threads and cannot be replayed; instead each work
item hashes (seed, stream, index) into a 32-bit state and steps a PCG-RXS-M-XS generator.
"""
import taichi as ti

# A twin's index (docs/mbe.md, "Twin vcm passes"; docs/effort.md, "Twin camera paths"): the
# index of the pass or path it repeats with this bit flipped, which no pass or path has.
TWIN_BIT = 1 << 30


@ti.func
def hash_u32(x: ti.u32) -> ti.u32:
    """PCG output permutation used as an integer hash (Jarzynski & Olano 2020)."""
    state = x * ti.u32(747796405) + ti.u32(2891336453)
    word = ((state >> ((state >> 28) + ti.u32(4))) ^ state) * ti.u32(277803737)
    return (word >> 22) ^ word


@ti.func
def seed(a: ti.u32, b: ti.u32, c: ti.u32) -> ti.u32:
    """Independent stream for the triple (a, b, c), e.g. (seed, pixel, iteration)."""
    return hash_u32(hash_u32(hash_u32(a) ^ b) + c * ti.u32(0x9E3779B9))


@ti.func
def next_u32(state: ti.template()) -> ti.u32:
    """Uniform 32-bit integer; advances `state` in place."""
    state = state * ti.u32(747796405) + ti.u32(2891336453)
    word = ((state >> ((state >> 28) + ti.u32(4))) ^ state) * ti.u32(277803737)
    return (word >> 22) ^ word


@ti.func
def next_float(state: ti.template()) -> ti.f32:
    """Uniform float in [0, 1); advances `state` in place."""
    return ti.cast(next_u32(state) >> 8, ti.f32) * (1.0 / 16777216.0)


@ti.func
def uniform(key: ti.u32, dim: ti.i32) -> ti.f32:
    """Random access to coordinate `dim` of the primary sample vector identified by `key`
    (stateless: the same key and dim always give the same number)."""
    x = hash_u32(key ^ hash_u32(ti.u32(dim) * ti.u32(0x9E3779B9) + ti.u32(0x7F4A7C15)))
    return ti.cast(x >> 8, ti.f32) * (1.0 / 16777216.0)

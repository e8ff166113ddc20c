"""The compiler settings of photonmc/runtime.py change how long kernels take to compile, not
what they compute beyond float rounding (docs/performance.md, "Compile time")."""
import contextlib
import json
import subprocess
import sys

import numpy as np
from taichi.lang import impl

import photonmc

from .conftest import REPO

RENDER = dict(method="pt", iterations=2, seed=5, params={"res": "16"})

# A second process, since Taichi is initialised once per process: the same render with
# Taichi's CFG optimisation passes on, as before runtime.py turned them off.
WITH_CFG_OPTIMISATION = f"""
import json, sys
import numpy as np
import taichi as ti
sys.path.insert(0, {str(REPO)!r})
original = ti.init
ti.init = lambda **kwargs: original(**{{**kwargs, "cfg_optimization": True}})
import photonmc
image = photonmc.render(**json.loads(sys.argv[1]))
assert ti.lang.impl.current_cfg().cfg_optimization
np.save(sys.argv[2], image)
"""


def test_runtime_turns_the_cfg_passes_off():
    assert impl.current_cfg().cfg_optimization is False


def test_cfg_optimisation_changes_rounding_only(tmp_path):
    """The passes forward stores to loads before LLVM sees the code; with fast math, LLVM may
    then contract or reorder float operations differently, so images may differ in the last
    bits (and a Markov chain whose acceptance test falls on such a bit then takes another,
    equally valid, path). pt has no such decision at these settings: its images must agree
    to float rounding."""
    out = tmp_path / "with_cfg.npy"
    subprocess.run([sys.executable, "-c", WITH_CFG_OPTIMISATION, json.dumps(RENDER), str(out)], check=True,
                   capture_output=True, timeout=600)
    with_passes = np.load(out)
    without = photonmc.render(**RENDER)
    assert with_passes.shape == without.shape
    scale = float(np.abs(with_passes).max())
    assert scale > 0.0
    np.testing.assert_allclose(without, with_passes, rtol=0, atol=1e-5 * scale)


def test_advanced_optimisation_is_turned_off_for_one_block_only():
    """runtime.advanced_optimization (used for the chain kernel and mbe's camera pass): the
    setting holds inside the block, is restored after it even when the block raises, and
    a kernel compiled inside computes what the same kernel compiled outside does."""
    import pytest
    import taichi as ti

    from photonmc import runtime

    before = impl.current_cfg().advanced_optimization
    assert before is True
    with runtime.advanced_optimization(False):
        assert impl.current_cfg().advanced_optimization is False
    assert impl.current_cfg().advanced_optimization is True
    with pytest.raises(RuntimeError):
        with runtime.advanced_optimization(False):
            raise RuntimeError
    assert impl.current_cfg().advanced_optimization is True

    def make_kernel():
        @ti.kernel
        def series(out: ti.types.ndarray()):
            for i in range(out.shape[0]):
                x = ti.cast(i, ti.f32) * 0.01
                s = 0.0
                for k in range(1, 20):
                    s += ti.sin(x * k) / k + ti.sin(x * k) * ti.cos(x)   # a common subexpression
                out[i] = s
        return series
    plain, lean = np.zeros(256, np.float32), np.zeros(256, np.float32)
    make_kernel()(plain)
    with runtime.advanced_optimization(False):
        make_kernel()(lean)
    np.testing.assert_allclose(lean, plain, rtol=0, atol=1e-6 * float(np.abs(plain).max()))


def _kernel_with_inlined_calls():
    """A kernel whose function is inlined at several call sites, with statements over several
    lines, loops and branches: the nodes whose position messages Taichi formats."""
    import taichi as ti

    @ti.func
    def shade(x, k: ti.template()):
        s = 0.0
        for j in range(k):
            if x > j:
                s += ti.sin(x * j) + \
                    ti.cos(x)
            else:
                s -= (x
                      * 0.5)
        while s > 10.0:
            s -= 10.0
        return s

    @ti.kernel
    def run(out: ti.types.ndarray()):
        for i in range(out.shape[0]):
            x = ti.cast(i, ti.f32) * 0.1
            out[i] = shade(x, 3) + shade(x * 2.0, 4) - shade(
                x, 3)
    return run


def test_frontend_memo_gives_taichis_own_strings():
    """photonmc/taichi_frontend.py: every position message and source read the caches answer
    equals what Taichi's own functions give for the same node or function, and a kernel
    compiled with the caches computes what it computes without them."""
    from taichi.lang import kernel_impl
    from taichi.lang.ast import ast_transformer_utils as utils

    from photonmc import taichi_frontend

    assert taichi_frontend.installed()
    original = taichi_frontend.ORIGINALS["get_pos_info"]
    memo = utils.ASTTransformerContext.get_pos_info
    assert memo is not original
    compared = []

    def checked(self, node):
        got = memo(self, node)
        assert got == original(self, node)
        compared.append(got)
        return got

    utils.ASTTransformerContext.get_pos_info = checked
    try:
        with_memo = np.zeros(64, np.float32)
        _kernel_with_inlined_calls()(with_memo)
    finally:
        utils.ASTTransformerContext.get_pos_info = memo
    assert len(compared) > 100 and len(set(compared)) < len(compared)   # repeats were served from the cache

    lines, _ = kernel_impl.getsourcelines(_kernel_with_inlined_calls)
    lines.append("mutated")       # a caller's list is its own: the next read is unchanged
    assert kernel_impl.getsourcelines(_kernel_with_inlined_calls) == \
        taichi_frontend.ORIGINALS["getsourcelines"](_kernel_with_inlined_calls)
    assert kernel_impl.getsourcefile(_kernel_with_inlined_calls) == \
        taichi_frontend.ORIGINALS["getsourcefile"](_kernel_with_inlined_calls)
    assert kernel_impl.textwrap.fill("\tx = 1\n", tabsize=4, width=9999) == \
        taichi_frontend.ORIGINALS["textwrap"].fill("\tx = 1\n", tabsize=4, width=9999)

    with taichi_frontend.original_front_end():
        without = np.zeros(64, np.float32)
        _kernel_with_inlined_calls()(without)
    assert utils.ASTTransformerContext.get_pos_info is memo
    np.testing.assert_array_equal(with_memo, without)


def test_compile_errors_name_the_same_line_with_the_memo():
    """A user's (or a developer's) error inside an inlined function is reported at the same
    file and line, in the same words, with and without the caches."""
    import pytest
    import taichi as ti

    from photonmc import taichi_frontend

    def broken():
        @ti.func
        def helper(x):
            return x + undefined_name        # noqa: F821 -- the error under test

        @ti.kernel
        def run() -> ti.f32:
            return helper(1.0) + helper(2.0)
        return run

    messages = []
    for context in (contextlib.nullcontext(), taichi_frontend.original_front_end()):
        with context, pytest.raises(ti.TaichiCompilationError) as raised:
            broken()()
        messages.append(str(raised.value))
    assert messages[0] == messages[1]
    assert "undefined_name" in messages[0] and "test_compile_settings.py" in messages[0]


def test_data_oriented_lookup_returns_what_taichis_returns():
    """photonmc/taichi_frontend.py's data_oriented: for plain attributes (fields, numbers,
    host methods, ti.funcs, class constants, inherited ones) Python's own lookup, the same
    object Taichi's lookup gives; kernels, properties and static methods through Taichi's own
    lookup, so that kernels (also inherited and overridden ones) still launch as methods."""
    import taichi as ti

    from photonmc.taichi_frontend import _plain_lookup, data_oriented

    @data_oriented
    class Base:
        CONSTANT = 3

        def __init__(self):
            self.values = ti.field(ti.f32, 4)
            self.scale = 2.0

        def host(self):
            return self.scale

        @ti.func
        def twice(self, x):
            return 2.0 * x

        @ti.kernel
        def fill(self, v: ti.f32):
            for i in self.values:
                self.values[i] = self.twice(v) * self.scale

        @property
        def total(self):
            return float(self.values.to_numpy().sum())

        @staticmethod
        def helper():
            return "static"

    @data_oriented
    class Derived(Base):
        @ti.kernel
        def fill_more(self, v: ti.f32):
            for i in self.values:
                self.values[i] = v + self.CONSTANT

    d = Derived()
    taichi_lookup = Derived._taichi_getattribute
    for name in ("values", "scale", "CONSTANT", "host", "twice", "__init__"):
        assert _plain_lookup(Derived, name)
        ours, theirs = getattr(d, name), taichi_lookup(d, name)
        assert ours is theirs or ours == theirs
    for name in ("fill", "fill_more", "total", "helper"):
        assert not _plain_lookup(Derived, name)
    d.fill(1.5)
    assert d.total == 4 * 2 * 1.5 * 2.0
    d.fill_more(1.0)
    assert d.total == 4 * 4.0 and d.helper() == "static" and d.host() == 2.0

"""Memoised source lookups in Taichi's Python front end: the same compiled code, sooner.

Taichi turns every `ti.kernel` and every inlined `ti.func` call into IR by walking the
function's Python AST. For each call it reads the function's source again (`inspect`
tokenises the whole file region, then `textwrap.fill` runs on every line), and for every
AST node it formats a source-position message (file, line, a caret line wrapped by a new
`TextWrapper`) that C++ keeps for error messages. A method's tracer is inlined hundreds of
times per kernel, so mbe's first iteration made 991 source reads and 47,014 messages (104,634
line wraps, 8,239 distinct messages). Caching them took the front end of mbe's chain kernel
from 2.8 to 1.5 s, and its cold first image at 128² from 9.2-9.6 to 7.3-7.4 s
(docs/performance.md, "Compile time").

Both results depend only on the function and the node's position, so this module caches
them: the source lines per function object, the message per (function, position). What
Taichi builds from them is unchanged, character for character (tests/test_compile_settings.py
compares both against Taichi's own functions), so the IR, the offline-cache keys and the
images are the same. `PHOTONMC_TAICHI_FRONTEND_MEMO=0` turns it off.

Written against Taichi 1.7 (pyproject pins taichi<1.8); `install()` checks that the
functions it wraps are there and leaves Taichi alone otherwise.
"""
from __future__ import annotations

import contextlib
import os

_installed = False


def _memo_source(getsourcefile, getsourcelines):
    """Per-function caches of Taichi's source lookups (a function's source does not change
    while the process runs). getsourcelines hands out a fresh list each time, as inspect does."""
    files, lines = {}, {}

    def cached_file(func):
        if func not in files:
            files[func] = getsourcefile(func)
        return files[func]

    def cached_lines(func):
        if func not in lines:
            src, start = getsourcelines(func)
            lines[func] = (tuple(src), start)
        src, start = lines[func]
        return list(src), start
    return cached_file, cached_lines


class _MemoTextwrap:
    """kernel_impl's `textwrap`: fill() memoised (a pure function of its arguments), the rest
    passed through."""
    def __init__(self, module):
        self._module = module
        self._fills = {}

    def fill(self, text, **kwargs):
        key = (text, tuple(sorted(kwargs.items())))
        out = self._fills.get(key)
        if out is None:
            out = self._fills[key] = self._module.fill(text, **kwargs)
        return out

    def __getattr__(self, name):
        return getattr(self._module, name)


def _memo_pos_info(original):
    cache = {}

    def get_pos_info(self, node):
        lineno, end_lineno = node.lineno, node.end_lineno
        body = getattr(node, "body", None)
        body_line = body[0].lineno if isinstance(body, list) and body else None
        # Everything the message is made of: the lines from the node's first to its last (or
        # to its body's first), the columns, the indent, the line offset and the names.
        last = max(end_lineno, body_line or 0)
        key = (self.file, self.func.func.__name__, self.lineno_offset, self.indent, type(node).__name__,
               lineno, end_lineno, node.col_offset, node.end_col_offset, body_line,
               tuple(self.src[lineno - 1:last]))
        msg = cache.get(key)
        if msg is None:
            msg = cache[key] = original(self, node)
        return msg
    return get_pos_info


# -- attribute lookups on data-oriented objects ----------------------------------------------
# ti.data_oriented replaces the class's __getattribute__ with a Python function that, for
# every attribute read (host code's `self.store`, `self.pool.theta_host`...), looks the name
# up in the class, tests it for a kernel, and calls itself again through each data-oriented
# base class. An mbe iteration at 64x64 made about 450 such reads, 0.3-0.5 ms of its 7 ms
# (docs/performance.md, "Host time between launches"). Whether Taichi's lookup differs from
# Python's depends only on the class and the name, so it is decided once per (class, name).
_PLAIN_NAMES: dict = {}


def _plain_lookup(cls, item: str) -> bool:
    """Whether Taichi's data-oriented lookup returns what Python's own returns: for anything
    but a kernel (Taichi binds it as a kernel method) and a property or static or class
    method (Taichi may launch or wrap what it holds)."""
    for klass in cls.__mro__:
        if item in klass.__dict__:
            attr = klass.__dict__[item]
            if isinstance(attr, (property, staticmethod, classmethod)):
                return False
            return not hasattr(attr, "_is_wrapped_kernel")
    return True      # an instance attribute (a field, an array, a number, an object)


def data_oriented(cls):
    """`ti.data_oriented`, with Taichi's attribute lookup kept for the names where it differs
    from Python's (kernels, properties) and Python's own used for every other name."""
    import taichi as ti
    cls = ti.data_oriented(cls)
    taichi_lookup = cls.__getattribute__
    plain_names = _PLAIN_NAMES

    def __getattribute__(self, item):
        key = (type(self), item)
        plain = plain_names.get(key)
        if plain is None:
            plain = plain_names[key] = _plain_lookup(type(self), item)
        if plain:
            return object.__getattribute__(self, item)
        return taichi_lookup(self, item)

    cls.__getattribute__ = __getattribute__
    cls._taichi_getattribute = taichi_lookup        # for the tests
    return cls


ORIGINALS: dict = {}     # Taichi's own functions, for the tests and for `original_front_end`


def install() -> None:
    """Put the caches above into Taichi's front end (once per process)."""
    global _installed
    if _installed or os.environ.get("PHOTONMC_TAICHI_FRONTEND_MEMO", "1") == "0":
        return
    try:
        from taichi.lang import kernel_impl
        from taichi.lang.ast import ast_transformer_utils as utils
        ORIGINALS.update(get_pos_info=utils.ASTTransformerContext.get_pos_info,
                         getsourcefile=kernel_impl.getsourcefile, getsourcelines=kernel_impl.getsourcelines,
                         textwrap=kernel_impl.textwrap)
    except (ImportError, AttributeError):       # another Taichi: keep its own front end
        ORIGINALS.clear()
        return
    _set(_memo_pos_info(ORIGINALS["get_pos_info"]),
         *_memo_source(ORIGINALS["getsourcefile"], ORIGINALS["getsourcelines"]), _MemoTextwrap(ORIGINALS["textwrap"]))
    _installed = True


def _set(get_pos_info, getsourcefile, getsourcelines, wrap) -> None:
    from taichi.lang import kernel_impl
    from taichi.lang.ast import ast_transformer_utils as utils
    utils.ASTTransformerContext.get_pos_info = get_pos_info
    kernel_impl.getsourcefile, kernel_impl.getsourcelines, kernel_impl.textwrap = getsourcefile, getsourcelines, wrap


@contextlib.contextmanager
def original_front_end():
    """Taichi's own functions inside the block (kernels first compiled there compile without
    the caches), the caches again after it."""
    if not _installed:
        yield
        return
    from taichi.lang import kernel_impl
    from taichi.lang.ast import ast_transformer_utils as utils
    memo = (utils.ASTTransformerContext.get_pos_info, kernel_impl.getsourcefile, kernel_impl.getsourcelines,
            kernel_impl.textwrap)
    _set(ORIGINALS["get_pos_info"], ORIGINALS["getsourcefile"], ORIGINALS["getsourcelines"], ORIGINALS["textwrap"])
    try:
        yield
    finally:
        _set(*memo)


def installed() -> bool:
    return _installed

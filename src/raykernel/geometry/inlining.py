"""numba's inlining of raykernel's `inline="always"` functions without its two defensive copies.

    from .inlining import skip_inline_copies
    skip_inline_copies()      # cachekey.py, before a kernel compiles: for raykernel's callees only

Why: a kernel that inlines many small functions (the walk's box and triangle
tests, the shading) spends much of its first compile copying numba IR. For
each call site numba builds the callee's IR afresh (its untyped passes), then
`InlineWorker.inline_ir` deep-copies it block by block, each block's copy
taking a copy of the whole function's scope with it, and copies that copy
again to return an untouched original that the inlining pass throws away
(numba issues 8989 and 9204; numba-cuda pull request 689 drops the same
copies). Here `inline_function`, the pass's only way into `inline_ir`,
hands the fresh IR of a raykernel function over without copying it. The
compiled code is the same: only copies of objects nothing else holds are
skipped (bench/startup.py measures the first compiles).

It is set up when a raykernel kernel is about to compile (a miss in the
kernel cache), not at import: a process that only loads cached kernels
never imports numba's inliner module (part of every warm start). Only
raykernel's own callees take this path: any other function, in any other
numba code of the process, is inlined by numba's own method, called as it
is. The change is made only where numba's code has the shape it was
written against (checked on its source); anywhere else numba runs as
shipped. RAYKERNEL_NUMBA_AS_SHIPPED=1 leaves numba alone as well.
"""

from __future__ import annotations

import copy
import inspect
import os

from numba.core import ir

_applied = False
OURS = __name__.split(".", 1)[0] + "."     # raykernel.: the modules whose functions take the short path


class _BlocksAsGiven:
    """Stands in for the `copy` module inside inline_ir: an IR block is used as given."""

    @staticmethod
    def deepcopy(x, memo=None):
        return x if isinstance(x, ir.Block) else copy.deepcopy(x, memo)


def _expected_shape(module) -> bool:
    """True when numba's inliner copies the callee's blocks in inline_ir, with the `copy` module,
    and inline_function only builds the callee's IR and calls inline_ir."""
    try:
        worker = module.InlineWorker
        copying = inspect.getsource(worker.inline_ir)
        calling = inspect.getsource(worker.inline_function)
    except (AttributeError, OSError, TypeError):
        return False
    return (module.copy is copy and "copy.deepcopy(the_ir.blocks[block_label])" in copying
            and "self.run_untyped_passes(function)" in calling and "return self.inline_ir(" in calling)


def skip_inline_copies() -> bool:
    """Make numba's inlining pass hand each callee's fresh IR to inline_ir uncopied, once per
    process. Returns whether that is in effect."""
    global _applied
    if _applied:
        return True
    if os.environ.get("RAYKERNEL_NUMBA_AS_SHIPPED"):
        return False
    from numba.core import inline_closurecall as module
    if not _expected_shape(module):
        return False

    shipped = module.InlineWorker.inline_function

    def inline_function(self, caller_ir, block, i, function, arg_typs=None):
        if not getattr(function, "__module__", "").startswith(OURS):
            return shipped(self, caller_ir, block, i, function, arg_typs)
        callee_ir = self.run_untyped_passes(function)      # built for this call site alone
        # numba compiles under one global lock, so no other compile sees the stand-in
        module.copy = _BlocksAsGiven
        try:
            return self.inline_ir(caller_ir, block, i, callee_ir, function.__code__.co_freevars,
                                  arg_typs=arg_typs)
        finally:
            module.copy = copy

    inline_function.__doc__ = module.InlineWorker.inline_function.__doc__
    module.InlineWorker.inline_function = inline_function
    _applied = True
    return True

"""numba's inlining of `inline="always"` functions without its two defensive copies of the callee.

    from .inlining import skip_inline_copies_when_compiling
    skip_inline_copies_when_compiling()     # config.py: from numba's first compile on (not on cache loads)

Why: a kernel that inlines many small functions (the walk's box and triangle
tests, the shading) spends much of its first compile copying numba IR. For
each call site numba builds the callee's IR afresh (its untyped passes), then
`InlineWorker.inline_ir` deep-copies it block by block, each block's copy
taking a copy of the whole function's scope with it, and copies that copy
again to return an untouched original that the inlining pass throws away
(numba issues 8989 and 9204; numba-cuda pull request 689 drops the same
copies). Here `inline_function`, the pass's only way into `inline_ir`,
hands over the fresh IR without copying it. The compiled code is the same:
only copies of objects nothing else holds are skipped. A first render
compiled in 29.6 s instead of 36.4 s, a first mesh query in 12.3 s instead
of 17.5 s (bench/startup.py measures it).

The change is made at numba's first compile in the process (a start that
loads every kernel from the cache never reads numba's inliner), only where
numba's code has the shape it was written against (checked on its source);
anywhere else numba runs as shipped. RAYKERNEL_NUMBA_AS_SHIPPED=1 leaves
numba alone as well.
"""

from __future__ import annotations

import copy
import inspect
import os

from numba.core import event, ir

_applied = False
_listening = False


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

    def inline_function(self, caller_ir, block, i, function, arg_typs=None):
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


class _FirstCompile(event.Listener):
    """Makes the change as a compile starts (under numba's compile lock)."""

    def on_start(self, ev):
        skip_inline_copies()

    def on_end(self, ev):
        pass


def skip_inline_copies_when_compiling() -> None:
    """skip_inline_copies as numba starts its first compile in this process."""
    global _listening
    if not _listening:
        event.register("numba:compile", _FirstCompile())
        _listening = True

"""How every compiled kernel is built: `from .config import njit`.

All kernels share one decorator so that caching, the GIL and fast-math are
the same everywhere. fastmath stays off: the tests compare structures to
1e-9 relative, and the counts must not depend on reassociation.

How the cache is keyed: every kernel is cached on disk, in CACHE_DIR, by
numba, with a locator of raykernel's own (cachekey.py): a cached kernel is
stale when its *code*, or the code of what it calls, has changed (constants
a kernel freezes when it compiles included), and never for a docstring, a
comment or a blank line. The key is made when a kernel is first compiled or
loaded, so importing costs nothing of it. CACHE_DIR is
`$NUMBA_CACHE_DIR/raykernel` when that variable is set, else
`<user cache>/raykernel/numba`, so an installed, read-only package caches
too; numba keeps each checkout's kernels in a folder of their own below it.
Nothing here deletes a folder: `raykernel cache --clear` does, when asked.
"""

import os
import sys
import threading
from pathlib import Path

import numba

from . import cachekey

# no_cfunc_wrapper: nothing calls a kernel through a C function pointer, and numba otherwise builds one
# for every kernel, converting each argument; for a kernel given the scene's Geometry that wrapper is
# a large part of the module LLVM optimises and turns into machine code on a first compile
KERNEL_OPTIONS = dict(cache=True, nogil=True, fastmath=False, error_model="numpy", no_cfunc_wrapper=True)
PACKAGE = cachekey.PACKAGE


def cache_root() -> Path:
    """The folder that holds raykernel's kernel caches (see the module docstring)."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return Path(os.environ["NUMBA_CACHE_DIR"]) / "raykernel"
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "raykernel" / "numba"


def cache_folders() -> list[Path]:
    """Every folder of raykernel's kernel caches on this machine's usual places: this version's
    (cache_root) and those of earlier versions (numba-<hash> and raykernel-<hash> folders)."""
    user = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "raykernel"
    found = [cache_root(), user / "numba", *user.glob("numba-*")]
    if os.environ.get("NUMBA_CACHE_DIR"):
        found += Path(os.environ["NUMBA_CACHE_DIR"]).glob("raykernel-*")
    return sorted({f for f in found if f.is_dir()})


CACHE_DIR = str(cache_root())
cachekey._CodeLocator.cache_dir = staticmethod(lambda: CACHE_DIR)


def njit(func=None, *, private=False, borrows=False, **kwargs):
    """numba.njit with the project's options; extra keywords override them.
    Use as @njit or @njit(parallel=True). private=True: called only from other
    kernels, so numba builds no Python wrapper for it; a wrapper unboxes every
    array of its arguments, and for the scene's Geometry (dozens of arrays)
    that costs a noticeable part of a second of compile time per function. A
    private kernel also borrows its arguments: without reference counting, a call does not touch
    each array's shared count (atomics that threads fight over), so a walk
    step compiled apart costs about what it cost inlined. Such a kernel may
    not allocate: numba refuses to compile one that does. borrows=True: borrows its
    arguments but keeps the Python wrapper (a test or a Python caller may call it too);
    for small functions that kernels call in their inner loops with arrays."""
    options = dict(KERNEL_OPTIONS, **kwargs)
    if private:
        options.update(no_cpython_wrapper=True, _nrt=False)
    elif borrows:
        options.update(_nrt=False)
    caching = options.pop("cache")

    def decorate(f):
        kernel = numba.njit(**options)(f)
        if caching:
            kernel._cache = cachekey.KernelCache(kernel.py_func)
        return kernel

    return decorate(func) if func is not None else decorate


def compiled(kernel) -> bool:
    """True once a compiled function has a specialisation in this process (compiled or loaded
    from the cache); anything else (a Python stand-in, as tests use) counts as ready."""
    return bool(getattr(kernel, "signatures", True))


def cached(kernel) -> bool:
    """True when the kernel cache holds an entry of `kernel` (a dispatcher made by njit) for its
    current code."""
    cache = getattr(kernel, "_cache", None)
    return isinstance(cache, cachekey.KernelCache) and cache.has_entries()


_told = set()
_told_lock = threading.Lock()


def tell_once(key: str, message: str | None) -> None:
    """Print `message` on stderr, once per process for each key: a first call that is about to
    compile says so instead of waiting in silence. message None: only mark the key told (the
    command line says it its own way)."""
    with _told_lock:
        if key in _told:
            return
        _told.add(key)
    if message is not None:
        print(message, file=sys.stderr, flush=True)

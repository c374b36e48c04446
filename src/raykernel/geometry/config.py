"""How every compiled kernel is built: `from .config import njit`.

All kernels share one decorator so that caching, the GIL and fast-math are
the same everywhere. fastmath stays off: the tests compare structures to
1e-9 relative, and the counts must not depend on reassociation.

The on-disk cache lives in a directory named after a hash of every kernel
source file of the package and of every module they import from (whose
constants, such as the counter columns, a kernel freezes when it compiles).
numba checks only the file of the function it compiles, so without this a
kernel would keep running an old copy of a helper it inlines from another
module (primitives into the traversal).
The directory is `$NUMBA_CACHE_DIR/raykernel-<hash>` when that variable is
set, else `<user cache>/raykernel/numba-<hash>`, so an installed,
read-only package caches too.
"""

import contextlib
import hashlib
import os
import re
import shutil
import sys
import threading
import time
from pathlib import Path

import numba

from .inlining import skip_inline_copies_when_compiling

KERNEL_OPTIONS = dict(cache=True, nogil=True, fastmath=False, error_model="numpy")
PACKAGE = Path(__file__).resolve().parents[1]   # raykernel/


# `from .a.b import c, d` and `from . import c`: the modules a kernel file takes names from
_RELATIVE_IMPORT = re.compile(rb"^from (\.+)([\w.]*) import (?:\(([^)]*)\)|([^\n#]*))", re.M)


def _imported(path: Path, package: Path) -> set:
    """The package's files that `path` imports from (relative imports), modules named in the
    import list included."""
    found = set()
    for dots, name, listed, names in _RELATIVE_IMPORT.findall(path.read_bytes()):
        names = re.sub(rb"#[^\n]*", b"", listed or names)
        base = path.parent
        for _ in range(len(dots) - 1):
            base = base.parent
        target = base.joinpath(*name.decode().split(".")) if name else base
        candidates = [target.with_suffix(".py"), target / "__init__.py"]
        candidates += [target / f"{n.split()[0]}.py" for n in names.decode().split(",") if n.strip()]
        found.update(c for c in candidates if c.is_file() and package in c.parents)
    return found


def kernel_source_hash(package: Path = PACKAGE) -> str:
    """Hash of the package's source files that define compiled kernels or feed them: every
    file with `njit`, and every file those import from, directly or not (constants such as
    the counter columns are frozen into a kernel when it compiles)."""
    files = {p for p in package.rglob("*.py") if b"njit" in p.read_bytes()}
    todo = list(files)
    while todo:
        for dep in _imported(todo.pop(), package) - files:
            files.add(dep)
            todo.append(dep)
    digest = hashlib.sha256()
    for path in sorted(files):
        digest.update(str(path.relative_to(package)).encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()[:16]


def _cache_dir() -> Path:
    key = kernel_source_hash()
    if os.environ.get("NUMBA_CACHE_DIR"):
        return Path(os.environ["NUMBA_CACHE_DIR"]) / f"raykernel-{key}"
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "raykernel"
    # caches of other source versions are never read again; drop those
    # unused for a day (a younger one may belong to a process still running)
    with contextlib.suppress(OSError):
        for old in base.glob("numba-*"):
            if old.name != f"numba-{key}" and time.time() - old.stat().st_mtime > 86400:
                shutil.rmtree(old, ignore_errors=True)
    return base / f"numba-{key}"


CACHE_DIR = str(_cache_dir())
skip_inline_copies_when_compiling()


def njit(func=None, *, private=False, borrows=False, **kwargs):
    """numba.njit with the project's options; extra keywords override them.
    Use as @njit or @njit(parallel=True). private=True: called only from other
    kernels, so numba builds no Python wrapper for it; a wrapper unboxes every
    array of its arguments, and for the scene's Geometry (about 70 arrays)
    that costs about 0.6 s of compile time per function. A private kernel also
    borrows its arguments: without reference counting, a call does not touch
    each array's shared count (atomics that threads fight over), so a walk
    step compiled apart costs about what it cost inlined. Such a kernel may
    not allocate: numba refuses to compile one that does. borrows=True: borrows its
    arguments but keeps the Python wrapper (a test or a Python caller may call it too);
    for small functions that kernels call in their inner loops with arrays."""
    options = dict(KERNEL_OPTIONS, **kwargs)
    if private:
        options.update(no_cpython_wrapper=True, no_cfunc_wrapper=True, _nrt=False)
    elif borrows:
        options.update(_nrt=False)

    def decorate(f):
        # numba picks the cache location when a function is decorated; point it
        # at ours for that moment only, leaving other numba users alone
        saved = numba.config.CACHE_DIR
        numba.config.CACHE_DIR = CACHE_DIR
        try:
            return numba.njit(**options)(f)
        finally:
            numba.config.CACHE_DIR = saved

    return decorate(func) if func is not None else decorate


def compiled(kernel) -> bool:
    """True once a compiled function has a specialisation in this process (compiled or loaded
    from the cache); anything else (a Python stand-in, as tests use) counts as ready."""
    return bool(getattr(kernel, "signatures", True))


def cached(package: str, kernel: str) -> bool:
    """True when the kernel cache holds `kernel` (e.g. "render._render_tiles") of the
    subpackage `package` ("rendering") of this checkout (numba keeps a checkout's kernels in
    <directory name>_<sha1 of its path>)."""
    folder = Path(__file__).resolve().parents[1] / package
    where = Path(CACHE_DIR) / f"{package}_{hashlib.sha1(str(folder).encode()).hexdigest()}"
    return any(where.glob(f"{kernel}-*.nbc"))


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

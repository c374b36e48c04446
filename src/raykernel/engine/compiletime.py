"""Compile time, measured apart from the work: numba's compile events on this thread.

    with CompileClock() as clock:
        kernel(...)                     # may compile first, or load from the cache
    clock.seconds                       # of the time inside, spent compiling
    clock.loading                       # spent loading compiled kernels from the cache
    first_run()                         # True when this install's kernels are not yet in the cache
    typing_setup()                      # seconds numba's first argument typing took (0 after the first call)

A render or query subtracts both from its trace time and reports them as
time.compile and time.load, so that no figure mixes start-up with work.
Loading is the time under numba's compiler lock (which a kernel's first call
takes to compile or to load it) less the compiling inside it; it includes
numba's own set-up on the first kernel a process calls. The compiles of the
thread that entered the clock count, and those of the worker threads of
parallel.for_ranges and on_threads (one of which compiles while the others
wait on the lock); a compile of another of the caller's own threads does not.
"""

from __future__ import annotations

import threading
import time

import numba
import numpy as np
from numba.core import event

from ..geometry.config import cached
from .parallel import WORKER_PREFIX

FIRST_RUN_SECONDS = 60      # about how long the first render compiles on a 2-core machine (bench/startup.py)
FIRST_QUERY_SECONDS = 45    # the same for a first RayScene query on a general scene
FIRST_MESH_SECONDS = 13     # and on a mesh (the mesh kernel)


class _Span(event.Listener):
    """Seconds inside the outermost events of one kind, on the clock's threads."""

    def __init__(self, ours):
        super().__init__()
        self.seconds = 0.0
        self._ours = ours
        self._depth = 0
        self._start = 0.0

    def on_start(self, ev):
        if not self._ours():
            return
        if self._depth == 0:
            self._start = time.perf_counter()
        self._depth += 1

    def on_end(self, ev):
        if not self._ours():
            return
        self._depth -= 1
        if self._depth == 0:
            self.seconds += time.perf_counter() - self._start


class CompileClock:
    def __init__(self):
        self._thread = threading.get_ident()
        self._compile = _Span(self._ours)
        self._lock = _Span(self._ours)

    def _ours(self) -> bool:
        # the thread that entered the clock, or a worker of parallel.for_ranges or on_threads
        return threading.get_ident() == self._thread or threading.current_thread().name.startswith(WORKER_PREFIX)

    @property
    def seconds(self) -> float:
        return self._compile.seconds

    @property
    def loading(self) -> float:
        return max(0.0, self._lock.seconds - self._compile.seconds)

    def __enter__(self):
        event.register("numba:compile", self._compile)
        event.register("numba:compiler_lock", self._lock)
        return self

    def __exit__(self, *exc):
        event.unregister("numba:compile", self._compile)
        event.unregister("numba:compiler_lock", self._lock)
        return False


_typing_ready = threading.Event()


def typing_setup() -> float:
    """Seconds numba took to set up its typing of arguments, when this is the first call in
    the process (0 afterwards): the first typeof of an array loads that machinery, about
    20 ms, which would otherwise fall into whatever kernel's call came first (a render's
    BVH build). Start-up, reported with time.load."""
    if _typing_ready.is_set():
        return 0.0
    start = time.perf_counter()
    numba.typeof(np.zeros((1, 3)))
    _typing_ready.set()
    return time.perf_counter() - start


def first_run() -> bool:
    """True when the kernel cache holds no render kernel of this source version and checkout yet."""
    return not cached("rendering", "render._render_tiles")

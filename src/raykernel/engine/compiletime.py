"""Compile time, measured apart from the work: numba's compile events on this thread.

    with CompileClock() as clock:
        kernel(...)                     # may compile first
    clock.seconds                       # of the time inside, spent compiling
    first_run()                         # True when this install's kernels are not yet in the cache

A render or query subtracts clock.seconds from its trace time and reports
it as time.compile, so that no figure mixes the two. The compiles of the
thread that entered the clock count, and those of the worker threads of
parallel.for_ranges (one of which compiles while the others wait on numba's
compiler lock); a compile of another of the caller's own threads does not.
"""

from __future__ import annotations

import threading
import time

from numba.core import event

from ..geometry.config import cached
from .parallel import WORKER_PREFIX

FIRST_RUN_SECONDS = 40      # about how long the first render compiles on a 2-core machine (bench/startup.py)
FIRST_QUERY_SECONDS = 45    # the same for a first RayScene query on a general scene
FIRST_MESH_SECONDS = 13     # and on a mesh (the mesh kernel)


class CompileClock(event.Listener):
    def __init__(self):
        super().__init__()
        self.seconds = 0.0
        self._thread = threading.get_ident()
        self._depth = 0
        self._start = 0.0

    def _ours(self) -> bool:
        # the thread that entered the clock, or a worker of parallel.for_ranges
        return threading.get_ident() == self._thread or threading.current_thread().name.startswith(WORKER_PREFIX)

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

    def __enter__(self):
        event.register("numba:compile", self)
        return self

    def __exit__(self, *exc):
        event.unregister("numba:compile", self)
        return False


def first_run() -> bool:
    """True when the kernel cache holds no render kernel of this source version and checkout yet."""
    return not cached("rendering", "render._render_tiles")

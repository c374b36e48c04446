"""Compile time, measured apart from the work: numba's compile events on this thread.

    with CompileClock(notice=say) as clock:
        kernel(...)                     # may compile first, or load from the cache
    clock.seconds                       # of the time inside, spent compiling (say() ran if over a second)
    clock.loading                       # spent loading compiled kernels from the cache
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
from numba.core import entrypoints, event

from .config import tell_once

# the name of the threads parallel.for_ranges and on_threads run kernels on: their compiles are the caller's
WORKER_PREFIX = "raykernel-worker"

# the notices say "tens of seconds" for a first compile; bench/startup.py measures it (BENCHMARKS.md, "Start-up")
# how the other kinds of render compare, after the first render's estimate in every notice
OTHER_RENDERS = ("other structures take longer, and Heckbert's or Hall's shading, antialiasing or "
                 "filtered shadows may too")
NOTICE_AFTER = 1.0          # seconds of compiling before CompileClock's notice


class _Span(event.Listener):
    """Seconds inside the outermost events of one kind, on the clock's threads; notice(), if
    given, is called once when one of them has lasted `after` seconds (at its start if 0)."""

    def __init__(self, ours, notice=None, after=0.0):
        super().__init__()
        self.seconds = 0.0
        self._ours = ours
        self._depth = 0
        self._start = 0.0
        self._notice, self._after = notice, after
        self._timer = None

    def _tell(self):
        notice, self._notice = self._notice, None
        if notice is not None:
            notice()

    def on_start(self, ev):
        if not self._ours():
            return
        if self._depth == 0:
            self._start = time.perf_counter()
            if self._notice is not None:
                if self._after <= 0.0:
                    self._tell()
                else:
                    self._timer = threading.Timer(self._after, self._tell)
                    self._timer.daemon = True
                    self._timer.start()
        self._depth += 1

    def on_end(self, ev):
        if not self._ours():
            return
        self._depth -= 1
        if self._depth == 0:
            self.seconds += time.perf_counter() - self._start
            if self._timer is not None:
                self._timer.cancel()
                self._timer = None


class CompileClock:
    """notice: called once, on a timer thread, when a compile inside the clock has lasted
    `after` seconds: a first call that compiles says so, and one that loads from the cache
    or compiles a moment does not (whichever kernel and specialisation it is)."""

    def __init__(self, notice=None, after=NOTICE_AFTER):
        self._thread = threading.get_ident()
        self._compile = _Span(self._ours, notice, after)
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


_notices: dict = {}
_notices_lock = threading.Lock()


def compile_notice(key: str, message: str):
    """A CompileClock notice that prints `message` on stderr. Its first firing in a process is
    said under `key`, once (a caller that said it its own way marks it: tell_once(key, None));
    every later one is said again: another specialisation is compiling."""
    def fire():
        with _notices_lock:
            n = _notices[key] = _notices.get(key, -1) + 1
        tell_once(key if n == 0 else f"{key} {n}", message)
    return fire


_typing_ready = threading.Event()


def typing_setup() -> float:
    """Seconds numba took to set up its typing of arguments, when this is the first call in
    the process (0 afterwards): the first typeof of an array loads that machinery (tens
    of milliseconds), and the first dispatch scans the installed packages for numba extensions
    (a few more); both would otherwise fall into whatever kernel's call came first (a render's BVH
    build). Start-up, reported with time.load."""
    if _typing_ready.is_set():
        return 0.0
    start = time.perf_counter()
    entrypoints.init_all()
    numba.typeof(np.zeros((1, 3)))
    _typing_ready.set()
    return time.perf_counter() - start

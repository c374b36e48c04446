"""Work items spread over threads, each thread running a compiled kernel (which releases the GIL).

    for_ranges(lambda lo, hi: kernel(..., lo, hi, ...), n_items, threads=2)

    counter = np.array([first, 0])              # next item to claim, items finished
    on_threads(lambda: kernel(..., counter, last, ...), threads=2, poll=lambda: report(counter[1]))
    # in the kernel:  item = claim(counter)  until item >= last;  finished(counter) after each

Why not numba's prange: a parallel=True kernel is compiled twice over (the
loop body as a gufunc, then the kernel around it), with everything it calls
optimised again each time; on the render and the ray queries that was a
large share of the first call's compile time. Threads over a serial kernel
cost one call per range instead (a few microseconds, plus unboxing the
arguments). Ranges are handed out as threads become free, so uneven work
balances; each item's results have their own place (a tile's counter row),
so results do not depend on the thread count or the order.
"""

from __future__ import annotations

import threading
import time
from concurrent.futures import FIRST_EXCEPTION, ThreadPoolExecutor, wait

import numba
import numpy as np
from numba.core import cgutils, types
from numba.extending import intrinsic

from .compiletime import WORKER_PREFIX
from .config import compiled, njit


def default_threads() -> int:
    """Threads a call uses unless told: numba's thread count for this thread (every core,
    NUMBA_NUM_THREADS, or numba.set_num_threads), so one setting governs every kernel."""
    return numba.get_num_threads()


_pools: dict[int, ThreadPoolExecutor] = {}
_pools_lock = threading.Lock()


def _pool(threads: int) -> ThreadPoolExecutor:
    # one pool per thread count, kept: starting threads for every call would cost more than small calls take
    with _pools_lock:
        if threads not in _pools:
            pool = ThreadPoolExecutor(max_workers=threads, thread_name_prefix=WORKER_PREFIX)
            # start every thread now, all waiting for each other: a pool starts a thread per call
            # of submit, and a thread started while another already runs a kernel call waits for
            # the GIL that call holds while it unboxes its arguments (milliseconds on a first render)
            barrier = threading.Barrier(threads)
            for future in [pool.submit(barrier.wait) for _ in range(threads)]:
                future.result()
            _pools[threads] = pool
        return _pools[threads]


def for_ranges(fn, n: int, threads: int | None = None, kernel=None, min_size: int = 1) -> None:
    """Call fn(lo, hi) over ranges covering 0..n, on up to `threads` threads at once.
    kernel: the compiled function fn calls; until it has been compiled (or loaded from the
    cache) the first range runs alone on this thread, since threads calling an uncompiled
    kernel at once compile it once each (a first render took markedly longer).
    min_size: items a range holds at least, so that small work (a lazy render's first
    passes, a few rays each) runs on this thread instead of paying a hand-over per range.
    Each thread takes ranges one after another, sized to take about RANGE_SECONDS (from one
    item, four times as many each time while they are quick; never more than half an equal share
    of what is left), so that uneven work balances and Ctrl-C is answered after the ranges being
    worked on: it raises KeyboardInterrupt."""
    threads = max(1, int(threads or default_threads()))
    if n <= 0:
        return
    ranges = _Ranges(n, max(1, min_size), threads)
    alone = threads == 1 or n < 2 * max(1, min_size) or threading.current_thread().name.startswith(WORKER_PREFIX)
    if alone or (kernel is not None and not compiled(kernel)):
        ranges.run(fn, once=not alone)      # on this thread: Ctrl-C is raised between ranges
        if alone:
            return
    futures = [_pool(threads).submit(ranges.run, fn) for _ in range(threads)]
    _wait(futures, stop=ranges.stop)
    ranges.stop()       # one call failed: no more ranges for the others (nothing left otherwise)
    wait(futures)
    for future in futures:
        future.result()


def interrupted(error: BaseException) -> bool:
    """Whether a KeyboardInterrupt is among the causes of error: Ctrl-C met while numba ran Python
    code (loading a kernel from the cache) comes back wrapped in SystemErrors."""
    while error is not None:
        if isinstance(error, KeyboardInterrupt):
            return True
        error = error.__cause__ or error.__context__
    return False


RANGE_SECONDS = 0.05


class _Ranges:
    """The ranges of 0..n handed out to for_ranges' threads, each sized to its thread's last pace
    and to at most half of an equal share of what is left (so the threads end together)."""

    def __init__(self, n: int, first: int, threads: int = 1):
        self.n, self.first, self.threads, self.next = n, first, threads, 0
        self.lock = threading.Lock()

    def stop(self) -> None:
        with self.lock:
            self.next = self.n

    def run(self, fn, once: bool = False) -> None:
        size = self.first
        while True:
            with self.lock:
                lo = self.next
                share = max(self.first, (self.n - lo) // (2 * self.threads))
                hi = self.next = min(self.n, lo + min(size, share))
            if lo >= hi:
                return
            start = time.perf_counter()
            fn(lo, hi)
            if once:
                return
            pace = (time.perf_counter() - start) / (hi - lo)
            size = max(self.first, min(4 * size, int(RANGE_SECONDS / max(pace, 1e-9))))


def on_threads(fn, threads: int | None = None, poll=None, interval: float = 0.1, counter=None) -> None:
    """Call fn() once on each of `threads` threads at once, the calls sharing their work
    through a counter the kernel claims items from (claim below): one call per thread, so
    the hand-over is paid once however many items there are, and a thread that finishes
    early takes the items another has not reached. poll: called every `interval` seconds
    while they run, and once at the end (a progress report). counter: that counter; given,
    the calls run on the pool even for one thread, and Ctrl-C on this thread ends the work
    after the items being worked on (no item is claimed after it) and raises KeyboardInterrupt."""
    threads = max(1, int(threads or default_threads()))
    if (threads == 1 and counter is None) or threading.current_thread().name.startswith(WORKER_PREFIX):
        fn()
    else:
        pool = _pool(threads) if threads > 1 else _own_thread()
        futures = [pool.submit(fn) for _ in range(threads)]
        _wait(futures, poll, interval, stop=None if counter is None else lambda: stop_claims(counter))
        for future in futures:
            future.result()
    if poll is not None:
        poll()


_own = threading.local()


def _own_thread() -> ThreadPoolExecutor:
    """The calling thread's own worker thread (kept for its later calls): one-thread work runs
    there, not on the shared pool, so that calls from several threads of the user's still run
    side by side while each caller waits where Ctrl-C can reach it."""
    if getattr(_own, "pool", None) is None:
        _own.pool = ThreadPoolExecutor(1, thread_name_prefix=WORKER_PREFIX)
    return _own.pool


def stop_claims(counter) -> None:
    """No item of the work counter is claimed after this (every claim gets one past the last)."""
    counter[0] = NO_MORE


NO_MORE = np.int64(1) << 62


def _wait(futures, poll=None, interval: float = 0.1, stop=None) -> None:
    """Wait for the futures (calling poll every interval) until all are done or one has failed.
    Ctrl-C meanwhile: stop() (no more work handed out), wait for what runs, raise KeyboardInterrupt."""
    try:
        while True:
            done, pending = wait(futures, timeout=interval, return_when=FIRST_EXCEPTION)
            if not pending or any(f.exception() is not None for f in done if not f.cancelled()):
                return
            if poll is not None:
                poll()
    except KeyboardInterrupt:
        if stop is not None:
            stop()
        while True:
            try:
                wait(futures)
                break
            except KeyboardInterrupt:       # pressed again: the running items still end first
                continue
        raise


@intrinsic
def _fetch_add(typingctx, counter, index, value):
    """counter[index] += value as one atomic step; the value before."""
    if not (isinstance(counter, types.Array) and counter.dtype == types.int64 and counter.ndim == 1):
        return None
    sig = types.int64(counter, types.intp, types.int64)

    def codegen(context, builder, signature, args):
        array = context.make_array(signature.args[0])(context, builder, args[0])
        pointer = cgutils.get_item_pointer(context, builder, signature.args[0], array, [args[1]])
        return builder.atomic_rmw("add", pointer, args[2], "monotonic")

    return sig, codegen


@njit(inline="always")
def claim(counter):
    """The next item of the work counter (counter[0], shared by on_threads' calls): each item
    goes to exactly one thread."""
    return _fetch_add(counter, 0, np.int64(1))


@njit(inline="always")
def finished(counter):
    """Count one more item done in counter[1] (what on_threads' poll reports)."""
    _fetch_add(counter, 1, np.int64(1))

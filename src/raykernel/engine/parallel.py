"""Work items spread over threads, each thread running a compiled kernel (which releases the GIL).

    for_ranges(lambda lo, hi: kernel(..., lo, hi, ...), n_items, threads=2)

    counter = np.array([first, 0])              # next item to claim, items finished
    on_threads(lambda: kernel(..., counter, last, ...), threads=2, poll=lambda: report(counter[1]))
    # in the kernel:  item = claim(counter)  until item >= last;  finished(counter) after each

Why not numba's prange: a parallel=True kernel is compiled twice over (the
loop body as a gufunc, then the kernel around it), with everything it calls
optimised again each time; on the render and the ray queries that was about
a third of the first call's compile time. Threads over a serial kernel
cost one call per range instead (a few microseconds, plus unboxing the
arguments). Ranges are handed out as threads become free, so uneven work
balances; each item's results have their own place (a tile's counter row),
so results do not depend on the thread count or the order.
"""

from __future__ import annotations

import threading
from concurrent.futures import FIRST_EXCEPTION, ThreadPoolExecutor, wait

import numba
import numpy as np
from numba.core import cgutils, types
from numba.extending import intrinsic

from ..geometry.compiletime import WORKER_PREFIX
from ..geometry.config import compiled, njit

CHUNKS_PER_THREAD = 8       # ranges per thread: enough for balance, few enough to keep the call overhead small


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
            # the GIL that call holds while it unboxes its arguments (1-7 ms on a first render)
            barrier = threading.Barrier(threads)
            for future in [pool.submit(barrier.wait) for _ in range(threads)]:
                future.result()
            _pools[threads] = pool
        return _pools[threads]


def for_ranges(fn, n: int, threads: int | None = None, kernel=None, min_size: int = 1) -> None:
    """Call fn(lo, hi) over ranges covering 0..n, on up to `threads` threads at once.
    kernel: the compiled function fn calls; until it has been compiled (or loaded from the
    cache) the first range runs alone on this thread, since threads calling an uncompiled
    kernel at once compile it once each (a first render took 52 s instead of 30).
    min_size: items a range holds at least, so that small work (a lazy render's first
    passes, a few rays each) runs on this thread instead of paying a hand-over per range."""
    threads = max(1, int(threads or default_threads()))
    if n <= 0:
        return
    n_ranges = min(n // max(1, min_size), threads * CHUNKS_PER_THREAD)
    if threads == 1 or n_ranges <= 1 or threading.current_thread().name.startswith(WORKER_PREFIX):
        fn(0, n)            # (a worker never waits on its own pool)
        return
    size = -(-n // n_ranges)
    start = 0
    if kernel is not None and not compiled(kernel):
        fn(0, size)
        start = size
    futures = [_pool(threads).submit(fn, lo, min(n, lo + size)) for lo in range(start, n, size)]
    for future in futures:
        future.result()


def on_threads(fn, threads: int | None = None, poll=None, interval: float = 0.1) -> None:
    """Call fn() once on each of `threads` threads at once, the calls sharing their work
    through a counter the kernel claims items from (claim below): one call per thread, so
    the hand-over is paid once however many items there are, and a thread that finishes
    early takes the items another has not reached. poll: called every `interval` seconds
    while they run, and once at the end (a progress report)."""
    threads = max(1, int(threads or default_threads()))
    if threads == 1 or threading.current_thread().name.startswith(WORKER_PREFIX):
        fn()
    else:
        futures = [_pool(threads).submit(fn) for _ in range(threads)]
        while True:
            done, pending = wait(futures, timeout=interval if poll is not None else None, return_when=FIRST_EXCEPTION)
            if not pending or any(f.exception() is not None for f in done):
                break
            poll()
        for future in futures:
            future.result()
    if poll is not None:
        poll()


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

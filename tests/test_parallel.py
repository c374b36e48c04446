"""for_ranges: every item once, in ranges of at least min_size, small work on the calling thread."""

import threading

import pytest

from raykernel.engine.parallel import for_ranges


def _record(calls):
    lock = threading.Lock()

    def fn(lo, hi):
        with lock:
            calls.append((lo, hi, threading.current_thread().name))
    return fn


@pytest.mark.parametrize("n, threads, min_size", [(1, 2, 1), (7, 2, 1), (100, 2, 1), (100, 3, 30), (1000, 2, 7),
                                                  (5, 4, 100), (64, 1, 1)])
def test_ranges_cover_every_item_once(n, threads, min_size):
    calls = []
    for_ranges(_record(calls), n, threads, min_size=min_size)
    covered = sorted(i for lo, hi, _ in calls for i in range(lo, hi))
    assert covered == list(range(n))
    ranges = sorted((lo, hi) for lo, hi, _ in calls)
    assert all(hi - lo >= min_size for lo, hi in ranges[:-1])     # (the last one takes the rest)


def test_small_work_runs_on_the_calling_thread():
    calls = []
    for_ranges(_record(calls), 40, 2, min_size=64)
    assert calls == [(0, 40, threading.current_thread().name)]
    calls = []
    for_ranges(_record(calls), 400, 2, min_size=64)
    assert len(calls) > 1 and any(name.startswith("raykernel-worker") for _, _, name in calls)


def test_no_items_no_calls():
    calls = []
    for_ranges(_record(calls), 0, 2)
    assert calls == []

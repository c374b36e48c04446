"""for_ranges: every item once, in ranges of at least min_size, small work on the calling thread;
on_threads with claim: every item to exactly one thread, progress polled, errors raised."""

import threading

import numpy as np
import pytest

from raykernel.geometry.parallel import claim, finished, for_ranges, on_threads
from raykernel.geometry.config import njit


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


# ---------------------------------------------------------------- on_threads and claim: one call per thread

@njit
def _claim_items(counter, last, owner, thread_id):
    """Claim items below `last` one at a time, marking each with the claiming call's id."""
    while True:
        item = claim(counter)
        if item >= last:
            break
        owner[item] += thread_id + 1      # += : an item claimed twice would show as a sum
        finished(counter)


@pytest.mark.parametrize("threads, first, last", [(1, 0, 100), (2, 0, 5000), (3, 17, 4000), (2, 5, 5), (4, 0, 1)])
def test_claims_give_every_item_to_exactly_one_thread(threads, first, last):
    owner = np.zeros(max(last, 1), np.int64)
    counter = np.array([first, 0], np.int64)
    ids = iter(range(threads))
    lock = threading.Lock()
    polls = []

    def run():
        with lock:
            me = next(ids)
        _claim_items(counter, last, owner, me)

    on_threads(run, threads, poll=lambda: polls.append(int(counter[1])))
    assert np.all(owner[:first] == 0)
    assert np.all((owner[first:last] >= 1) & (owner[first:last] <= threads))
    assert counter[1] == last - first
    assert polls[-1] == last - first and polls == sorted(polls)      # the last poll sees them all


def test_on_threads_uses_the_pool_and_raises_a_worker_error():
    names = []
    lock = threading.Lock()

    def run():
        with lock:
            names.append(threading.current_thread().name)
    on_threads(run, 3)
    assert len(names) == 3 and all(name.startswith("raykernel-worker") for name in names)

    def fail():
        raise ValueError("a tile failed")
    with pytest.raises(ValueError, match="a tile failed"):
        on_threads(fail, 2, poll=lambda: None)

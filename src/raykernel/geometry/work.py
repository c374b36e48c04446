"""What a render asked for work layers keeps per sample, in the workspace (ws.work): the counter
row at the sample's start, and the sample's work split by ray type and by nesting level.

    work = sample_work(layer, levels, None, x0, y0, TILE)   # a tile's: layer (h, w, columns(levels)) int32
    ws = workspace(0, work)                      # ws.work is None when no layers are asked for
    figures = work_figures(ws.work, cnt)         # (tests, bounds, visited) now: around a search
    charge_type(ws.work, ray_kind, figures, cnt) # what the search did, to its ray type
    record_sample(ws.work, j, i, cnt)            # the sample's record into layer[j, i]
    note(ws.work, STEP, ...)                     # an event of the probed sample (Probe), if any,
                                                 # or what it tells of the structure's use (Use)

Every helper is an overload that does nothing when ws.work is None (and every `note` nothing
without a probe): a render without layers compiles none of this and runs as before.

A sample's record (one row of the layer, int32):
  [0, N_COUNTERS)           every counter of the counter row: what the sample's ray tree counted
  SPLIT + 3 * type + f      for each ray type (eye, reflect, refract, shadow) the figure f (tests,
                            bounds.tests, cells.visited) of that type's searches: an eye, reflection
                            or refraction ray's own search, and the shadow rays of its hit
  SPLIT + 12 + 3 * level + f  the same by nesting level: the work the driver did in frames that
                            deep (level 0 the root aggregate, and whatever was counted outside a
                            driver's frame: the rest of the sample's figures)
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba.core import types
from numba.core.types import NamedTuple as NamedTupleType
from numba.extending import overload

from . import counters as C
from .config import njit

SPLIT = C.N_COUNTERS                 # the first column of the splits
RAY_TYPES = ("eye", "reflect", "refract", "shadow")
SHADOW = 3
FIGURES = ("tests.total", "bounds.tests", "cells.visited")
BY_LEVEL = SPLIT + 3 * len(RAY_TYPES)


def columns(levels: int) -> int:
    """A record's columns for a scene whose aggregates nest `levels` deep (1: no level split)."""
    return BY_LEVEL + (3 * levels if levels > 1 else 0)


class SampleWork(NamedTuple):
    layer: np.ndarray    # (h, w, columns) int32: the samples' records
    mark: np.ndarray     # (N_COUNTERS,) int64: the counter row when the sample began
    split: np.ndarray    # (columns - SPLIT,) int64: the sample's splits so far
    level_mark: np.ndarray   # (3,) int64: the figures at the driver's last change of frame
    levels: int          # nesting levels split (0: none)
    probe: object        # None, or the event log of one probed sample (Probe; explain.py)
    use: object          # None, or every cell's and node's use (Use; rendering/structure.py)


# A probe logs the events of one sample (rendering/explain.py): one float64 row an event, its
# first column the event's code. The log of every other sample of the probed sample's tile is
# dropped when that sample is recorded; tiles without the probed sample log nothing.
SEARCH, FOUND, STEP, ENTER, TEST, TYPE, CULLED = range(7)
LOG_COLUMNS = 10
EVENTS, OVERFLOW, TARGET_ROW, TARGET_COL, DONE, MARKS = 0, 1, 2, 3, 4, 5      # Probe.state
STATE = MARKS + 3


class Probe(NamedTuple):
    log: np.ndarray      # (capacity, LOG_COLUMNS) float64; (0, LOG_COLUMNS) in the tiles not probed
    state: np.ndarray    # (STATE,) int64: events, overflow, the sample's row and column, done, figure marks


def probe(row: int, col: int, capacity: int) -> Probe:
    """A probe of the sample at (row, col), room for `capacity` events."""
    state = np.zeros(STATE, np.int64)
    state[TARGET_ROW], state[TARGET_COL] = row, col
    return Probe(np.zeros((capacity, LOG_COLUMNS)), state)


# A render that measures how rays use its structures (rendering/structure.py, one thread) counts,
# for every cell and node a walk enters (walk.note_visit) and for every aggregate whose walk notes
# none (a list, an operator, ray classification: its box), its visits, the primitive tests made in
# its references, the visits in which some test hit (the rest entered and found nothing) and, for
# an aggregate's box, the steps that reached its references. A row of `counts` is
# offset[code] + key for a walk of code `code` that notes its cells, and offset[AGGREGATES] + the
# aggregate's index for the others. `state` holds the row noted last (-1: none since the last
# step), whether counting is paused (during a search whose work the render does not count), then
# for each frame of the driver the row its tests are made in and whether one of them has hit since.
COUNTS = ("visits", "tests", "hits", "entries")
VISITS, TESTS, HITS, ENTRIES = range(len(COUNTS))
NOTED, PAUSED, FRAMES = 0, 1, 2       # Use.state
AGGREGATES = C.MAX_WALKS


class Use(NamedTuple):
    counts: np.ndarray   # (rows, 4) int64: COUNTS
    offset: np.ndarray   # (MAX_WALKS + 1,) int64: each walk's first row; [AGGREGATES] the aggregates' boxes
    keyed: np.ndarray    # (MAX_WALKS,) int64: 1 for a walk that notes its cells itself
    state: np.ndarray    # (FRAMES + 2 * frames,) int64: the row noted last, paused, then per frame (row, hit since)


def _is_use(probe) -> bool:
    return isinstance(probe, NamedTupleType) and "counts" in probe.fields


def sample_work(layer, levels, probe, x0, y0, size):
    """A tile's per-sample work over `layer` (None: no layers, and so None), `levels` nesting
    levels split (geometry/work.columns); `probe` (None or a Probe) logs the events of its sample
    if the tile at column x0, row y0, `size` samples square, holds it; a Use in its place counts
    how every sample's rays use the structures."""


@overload(sample_work)
def _sample_work(layer, levels, probe, x0, y0, size):
    if isinstance(layer, types.NoneType):
        return lambda layer, levels, probe, x0, y0, size: None
    if isinstance(probe, types.NoneType):
        def no_probe(layer, levels, probe, x0, y0, size):
            return SampleWork(layer, np.zeros(C.N_COUNTERS, np.int64), np.zeros(layer.shape[2] - SPLIT, np.int64),
                              np.zeros(3, np.int64), np.int64(levels if levels > 1 else 0), None, None)
        return no_probe
    if _is_use(probe):
        def using(layer, levels, probe, x0, y0, size):
            return SampleWork(layer, np.zeros(C.N_COUNTERS, np.int64), np.zeros(layer.shape[2] - SPLIT, np.int64),
                              np.zeros(3, np.int64), np.int64(levels if levels > 1 else 0), None, probe)
        return using

    def probed(layer, levels, probe, x0, y0, size):
        j, i = probe.state[TARGET_ROW], probe.state[TARGET_COL]
        mine = y0 <= j < y0 + size and x0 <= i < x0 + size
        p = probe if mine else Probe(np.zeros((0, LOG_COLUMNS)), probe.state.copy())
        return SampleWork(layer, np.zeros(C.N_COUNTERS, np.int64), np.zeros(layer.shape[2] - SPLIT, np.int64),
                          np.zeros(3, np.int64), np.int64(levels if levels > 1 else 0), p, None)
    return probed


def _probed(work) -> bool:
    """Whether a kernel's `work` (its numba type) carries a probe: no log code compiles otherwise."""
    return isinstance(work, NamedTupleType) and not isinstance(work.types[work.fields.index("probe")],
                                                                   types.NoneType)


def note(work, code, a, b, c, d, e, f, g, h, i):
    """Log an event (code, then up to nine numbers) for the probed sample; nothing otherwise."""


@overload(note, inline="always")
def _note(work, code, a, b, c, d, e, f, g, h, i):
    if _using(work):
        def count(work, code, a, b, c, d, e, f, g, h, i):
            if code == STEP:        # frame a, aggregate b, walk c, cells visited d
                _use_step(work.use, a, b, c, d)
            elif code == TEST:      # frame a, t e
                _use_test(work.use, a, e)
        return count
    if not _probed(work):
        return lambda work, code, a, b, c, d, e, f, g, h, i: None

    def log(work, code, a, b, c, d, e, f, g, h, i):
        _log(work.probe, code, a, b, c, d, e, f, g, h, i)
    return log


def _using(work) -> bool:
    """Whether a kernel's `work` carries a Use: no counting code compiles otherwise."""
    return isinstance(work, NamedTupleType) and not isinstance(work.types[work.fields.index("use")], types.NoneType)


@njit
def _use_step(use, f, agg, kind, visited):
    # the step of frame f's walk ends where its references are tested: the cell it noted last,
    # or for a walk that notes none the aggregate's box, which takes the step's visits
    state = use.state
    row = state[NOTED]
    if state[PAUSED]:
        row = -1
    elif use.keyed[kind] == 0:
        row = use.offset[AGGREGATES] + agg
        use.counts[row, VISITS] += visited
        use.counts[row, ENTRIES] += 1
    state[NOTED] = -1
    state[FRAMES + 2 * f], state[FRAMES + 1 + 2 * f] = row, 0


@njit
def _use_test(use, f, t):
    # a test in frame f's cell; a hit there is a hit in the cells of the frames above, which
    # hold the aggregate it was found in
    state = use.state
    row = state[FRAMES + 2 * f]
    if row >= 0:
        use.counts[row, TESTS] += 1
    if t < np.inf and t > -np.inf:
        for g in range(f + 1):
            row = state[FRAMES + 2 * g]
            if row >= 0 and state[FRAMES + 1 + 2 * g] == 0:
                use.counts[row, HITS] += 1
                state[FRAMES + 1 + 2 * g] = 1


@njit(inline="always")
def _log(probe, code, a, b, c, d, e, f, g, h, i):
    log, state = probe.log, probe.state
    if log.shape[0] == 0 or state[DONE]:
        return
    n = state[EVENTS]
    if n == log.shape[0]:
        state[OVERFLOW] = 1
        return
    row = log[n]
    row[0], row[1], row[2], row[3], row[4], row[5], row[6], row[7], row[8], row[9] = code, a, b, c, d, e, f, g, h, i
    state[EVENTS] = n + 1


def note_search(work, mode, ox, oy, oz, dx, dy, dz, tmin, tmax, cnt):
    """A search begins (traverse.intersect): logged with the figures counted so far."""


@overload(note_search, inline="always")
def _note_search(work, mode, ox, oy, oz, dx, dy, dz, tmin, tmax, cnt):
    if _using(work):
        def begin(work, mode, ox, oy, oz, dx, dy, dz, tmin, tmax, cnt):
            state = work.use.state
            state[NOTED] = -1
            state[FRAMES:] = -1         # no frame has a cell yet
        return begin
    if not _probed(work):
        return lambda work, mode, ox, oy, oz, dx, dy, dz, tmin, tmax, cnt: None

    def log(work, mode, ox, oy, oz, dx, dy, dz, tmin, tmax, cnt):
        _log_search(work.probe, mode, ox, oy, oz, dx, dy, dz, tmin, tmax, cnt)
    return log


@njit
def _log_search(probe, mode, ox, oy, oz, dx, dy, dz, tmin, tmax, cnt):
    # a call, not inlined: only a probed render makes it, and inlining a loop that writes the
    # probe's state into the sampling kernels gives numba's IR checks variables out of scope
    tests, bounds, visited = _figures(cnt)
    state = probe.state
    state[MARKS], state[MARKS + 1], state[MARKS + 2] = tests, bounds, visited
    _log(probe, SEARCH, mode, ox, oy, oz, dx, dy, dz, tmin, tmax)


def note_found(work, found, hit_f, hit_i, cnt):
    """The search ends: whether it found a hit, the hit, and what it counted."""


@overload(note_found, inline="always")
def _note_found(work, found, hit_f, hit_i, cnt):
    if not _probed(work):
        return lambda work, found, hit_f, hit_i, cnt: None

    def log(work, found, hit_f, hit_i, cnt):
        _log_found(work.probe, found, hit_f, hit_i, cnt)
    return log


@njit
def _log_found(probe, found, hit_f, hit_i, cnt):
    now = _figures(cnt)
    marks = probe.state[MARKS:MARKS + 3]
    t, kind, idx, inst = np.inf, -1, -1, -1
    if found:
        t, kind, idx, inst = hit_f[0], hit_i[0], hit_i[1], hit_i[2]
    _log(probe, FOUND, found, t, kind, idx, inst, now[0] - marks[0], now[1] - marks[1], now[2] - marks[2], 0)


@njit(inline="always")
def _figures(cnt):
    tests = cnt[C.TESTS] + cnt[C.TESTS + 1] + cnt[C.TESTS + 2] + cnt[C.TESTS + 3] + cnt[C.TESTS + 4]
    return tests, cnt[C.BOUNDS_TESTS], cnt[C.CELLS_VISITED]


def work_figures(work, cnt):
    """(tests, bounds.tests, cells.visited) of the counter row now; zeros without layers."""


@overload(work_figures, inline="always")
def _work_figures(work, cnt):
    if isinstance(work, types.NoneType):
        return lambda work, cnt: (np.int64(0), np.int64(0), np.int64(0))
    return lambda work, cnt: _figures(cnt)


def charge_type(work, ray_type, before, cnt):
    """Charge what was counted since `before` (work_figures) to ray type `ray_type`."""


@overload(charge_type, inline="always")
def _charge_type(work, ray_type, before, cnt):
    if isinstance(work, types.NoneType):
        return lambda work, ray_type, before, cnt: None

    def charge(work, ray_type, before, cnt):
        now = _figures(cnt)
        for k in range(3):
            work.split[3 * ray_type + k] += now[k] - before[k]
        note(work, TYPE, ray_type, 0, 0, 0, 0, 0, 0, 0, 0)
    return charge


def level_mark(work, cnt):
    """The driver starts a walk: its frame changes are charged from here."""


@overload(level_mark, inline="always")
def _level_mark(work, cnt):
    if isinstance(work, types.NoneType):
        return lambda work, cnt: None

    def mark(work, cnt):
        if work.levels:
            now = _figures(cnt)
            for k in range(3):
                work.level_mark[k] = now[k]
    return mark


def level_charge(work, level, cnt):
    """The driver leaves frame depth `level` (for a child, its parent or the caller): what it
    counted there since the last change is charged to that level (level 0: left to the rest)."""


@overload(level_charge, inline="always")
def _level_charge(work, level, cnt):
    if isinstance(work, types.NoneType):
        return lambda work, level, cnt: None

    def charge(work, level, cnt):
        if work.levels:
            now = _figures(cnt)
            for k in range(3):
                if 0 < level < work.levels:
                    work.split[BY_LEVEL - SPLIT + 3 * level + k] += now[k] - work.level_mark[k]
                work.level_mark[k] = now[k]
    return charge


def start_samples(work, cnt):
    """The samples that follow begin from the counter row as it is now."""


@overload(start_samples, inline="always")
def _start_samples(work, cnt):
    if isinstance(work, types.NoneType):
        return lambda work, cnt: None

    def start(work, cnt):
        for k in range(C.N_COUNTERS):
            work.mark[k] = cnt[k]
        for k in range(work.split.shape[0]):
            work.split[k] = 0
        _drop_log(work)
    return start


def _drop_log(work):
    """The events logged since the last sample are not the probed sample's: forget them."""


@overload(_drop_log, inline="always")
def _drop_log_impl(work):
    if not _probed(work):
        return lambda work: None

    def drop(work):
        state = work.probe.state
        if not state[DONE]:
            state[EVENTS], state[OVERFLOW] = 0, 0
    return drop


def _end_log(work, j, i):
    """The sample at row j, column i is recorded: its log is kept if it is the probed one."""


@overload(_end_log, inline="always")
def _end_log_impl(work, j, i):
    if not _probed(work):
        return lambda work, j, i: None

    def end(work, j, i):
        state = work.probe.state
        if work.probe.log.shape[0] and not state[DONE]:
            if j == state[TARGET_ROW] and i == state[TARGET_COL]:
                state[DONE] = 1
            else:
                state[EVENTS], state[OVERFLOW] = 0, 0
    return end


def record_sample(work, j, i, cnt):
    """Write the sample's record at row j, column i of the layer; the next sample begins now."""


@overload(record_sample, inline="always")
def _record_sample(work, j, i, cnt):
    if isinstance(work, types.NoneType):
        return lambda work, j, i, cnt: None

    def record(work, j, i, cnt):
        row = work.layer[j, i]
        for k in range(C.N_COUNTERS):
            row[k] = cnt[k] - work.mark[k]
            work.mark[k] = cnt[k]
        for k in range(work.split.shape[0]):
            row[SPLIT + k] = work.split[k]
            work.split[k] = 0
        if work.levels:     # level 0: the sample's figures the deeper levels do not hold
            total = (np.int64(row[C.TESTS]) + row[C.TESTS + 1] + row[C.TESTS + 2] + row[C.TESTS + 3]
                     + row[C.TESTS + 4], np.int64(row[C.BOUNDS_TESTS]), np.int64(row[C.CELLS_VISITED]))
            for k in range(3):
                deeper = 0
                for level in range(1, work.levels):
                    deeper += row[BY_LEVEL + 3 * level + k]
                row[BY_LEVEL + k] = total[k] - deeper
        _end_log(work, j, i)
    return record


def names(levels: int) -> list[str]:
    """The names of a record's split columns, in order."""
    out = [f"{figure}.{t}" for t in RAY_TYPES for figure in FIGURES]
    if levels > 1:
        out += [f"{figure}.level{level}" for level in range(levels) for figure in FIGURES]
    return out


def pause_use(work, paused):
    """Searches from here on until unpaused are not the render's work (an uncounted search of
    Haines's tricks): a Use does not count them."""


@overload(pause_use, inline="always")
def _pause_use(work, paused):
    if not _using(work):
        return lambda work, paused: None

    def pause(work, paused):
        _set_paused(work.use.state, paused)
    return pause


@njit
def _set_paused(state, paused):
    # a call, not inlined: inlined into the tricks' kernels numba's IR checks find a variable out of scope
    state[PAUSED] = 1 if paused else 0

"""geometry/boxrows.py: box rows in two vector halves, against the same arithmetic in numpy, lane by lane."""

import numpy as np
import pytest
from numba import njit
from numba.core.errors import TypingError

from raykernel.geometry.boxrows import HI, ROW, bin3, empty, grow, grow_centre, swap


def _rows(lo, hi, weight):
    rows = np.zeros((len(lo), ROW))
    rows[:, :3], rows[:, 3], rows[:, HI:HI + 3] = lo, weight, hi
    return rows


def _random_rows(n, seed, scale=1.0):
    rng = np.random.default_rng(seed)
    lo = (rng.random((n, 3)) - 0.5) * scale
    return _rows(lo, lo + rng.random((n, 3)) * scale, rng.random(n) + 0.5)


@njit
def _union(data, at):
    box, cbox = np.empty(ROW), np.empty(ROW)
    empty(box, 0)
    empty(cbox, 0)
    for p in at:
        grow(box, 0, data, p * ROW)
        grow_centre(cbox, 0, data, p * ROW)
    return box, cbox


@njit
def _bins(data, cmin, scale, last):
    out = np.empty((data.shape[0], 3), np.int64)
    for p in range(data.shape[0]):
        b = bin3(data, p * ROW, cmin, scale, last)
        for a in range(3):
            out[p, a] = b[a]
    return out


@njit
def _swap_all(data, pairs):
    for k in range(pairs.shape[0]):
        swap(data, pairs[k, 0] * ROW, pairs[k, 1] * ROW)


@njit
def _grow_into(boxes, k, data, p):
    grow(boxes, k * ROW, data, p * ROW)


@pytest.mark.parametrize("scale", [1e-6, 1.0, 1e7, 1e300])
def test_a_union_is_numpys_min_and_max_and_the_centre_its_half_sums(scale):
    data = _random_rows(37, 1, scale)
    at = np.array([3, 0, 36, 17, 17, 9])
    box, cbox = _union(data, at)
    lo, hi = data[at, :3], data[at, HI:HI + 3]
    assert np.array_equal(box[:3], lo.min(0)) and np.array_equal(box[HI:HI + 3], hi.max(0))
    centre = 0.5 * lo + 0.5 * hi        # the scalar formula: no overflow at 1e300, unlike (lo + hi) / 2
    assert np.array_equal(cbox[:3], centre.min(0)) and np.array_equal(cbox[HI:HI + 3], centre.max(0))


def test_nothing_united_leaves_the_empty_box():
    box, cbox = _union(_random_rows(4, 2), np.zeros(0, np.int64))
    for b in (box, cbox):
        assert np.all(b[:4] == np.inf) and np.all(b[HI:] == -np.inf)


def test_grow_touches_only_its_own_row_of_a_larger_array():
    data = _random_rows(5, 3)
    boxes = np.full((4, ROW), 7.0)
    _grow_into(boxes, 2, data, 4)
    expected = np.full((4, ROW), 7.0)
    expected[2, :HI] = np.minimum(7.0, data[4, :HI])
    expected[2, HI:] = np.maximum(7.0, data[4, HI:])
    assert np.array_equal(boxes, expected)


@pytest.mark.parametrize("bins", [2, 6, 16, 1024])
def test_bins_are_the_scalar_formulas_truncation_clamped_to_the_last(bins):
    data = _random_rows(500, 4, 3.0)
    centre = 0.5 * data[:, :3] + 0.5 * data[:, HI:HI + 3]
    cmin = np.r_[centre.min(0), 0.0]
    # the third axis not binned (scale 0: bin 0), the first scaled past its range (clamped to the last)
    scale = np.array([2 * bins / np.ptp(centre[:, 0]), bins / np.ptp(centre[:, 1]), 0.0, 0.0])
    got = _bins(data, cmin, scale, bins - 1)
    expected = np.empty_like(got)
    for p in range(len(data)):
        for a in range(3):
            f = (centre[p, a] - cmin[a]) * scale[a]
            expected[p, a] = int(f) if f < bins - 1 else bins - 1
    assert np.array_equal(got, expected)
    assert got[:, 0].max() == bins - 1 and np.all(got[:, 2] == 0)


def test_a_centre_that_is_not_a_number_goes_to_the_last_bin():
    data = _rows(np.array([[0.0, 0.0, 0.0]]), np.array([[np.nan, 1.0, np.inf]]), 1.0)
    got = _bins(data, np.zeros(4), np.array([1.0, 1.0, 1.0, 0.0]), 5)
    assert list(got[0]) == [5, 0, 5]


def test_swap_exchanges_whole_rows_and_twice_restores():
    data = _random_rows(6, 5)
    before = data.copy()
    _swap_all(data, np.array([[0, 5], [2, 2]]))
    expected = before.copy()
    expected[[0, 5]] = before[[5, 0]]
    assert np.array_equal(data, expected)
    _swap_all(data, np.array([[5, 0]]))
    assert np.array_equal(data, before)


def test_only_c_contiguous_float64_arrays_are_taken():
    with pytest.raises(TypingError):
        _union(np.asfortranarray(_random_rows(4, 6)), np.arange(2))
    with pytest.raises(TypingError):
        _union(_random_rows(4, 6).astype(np.float32), np.arange(2))

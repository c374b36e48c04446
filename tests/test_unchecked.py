"""geometry/unchecked.py: load and store by flat index, against numpy's own indexing."""

import numpy as np
import pytest
from numba import njit

from raykernel.geometry.unchecked import load, prefetch, store


@njit
def _read_all(a):
    out = np.empty(a.size, a.dtype)
    for i in range(a.size):
        out[i] = load(a, i)
    return out


@njit
def _write_all(a, values):
    for i in range(values.size):
        store(a, i, values[i])


@njit
def _prefetched_sum(a):
    s = a.dtype.type(0)
    for i in range(a.size):
        prefetch(a, min(i + 16, a.size - 1))      # a hint only: what is read is unchanged
        s += load(a, i)
    return s


@njit
def _read_at(a, i):
    return load(a, i)


@pytest.mark.parametrize("dtype", [np.int32, np.int64, np.float32, np.float64])
@pytest.mark.parametrize("shape", [(7,), (5, 32), (2, 3, 4)])
def test_load_reads_the_flat_element(dtype, shape):
    a = np.arange(np.prod(shape)).astype(dtype).reshape(shape) * 3 - 5
    assert np.array_equal(_read_all(a), a.ravel())


@pytest.mark.parametrize("dtype", [np.int32, np.int64, np.float64])
def test_store_writes_the_flat_element_in_the_arrays_type(dtype):
    a = np.zeros((4, 8), dtype)
    values = np.arange(32, dtype=np.float64) * 1.5 if dtype == np.float64 else np.arange(32, dtype=np.int64) - 7
    _write_all(a, values)
    assert np.array_equal(a.ravel(), values.astype(dtype))


def test_an_index_of_any_integer_type_reads_the_same_element():
    a = np.arange(100.0)
    for index in (np.int32(42), np.int64(42), np.uint32(42), np.uint64(42), 42):
        assert _read_at(a, index) == 42.0


def test_a_non_contiguous_array_or_a_float_index_is_refused():
    with pytest.raises(Exception, match="load"):
        _read_at(np.arange(10.0)[::2], 1)
    with pytest.raises(Exception, match="load"):
        _read_at(np.arange(10.0), 1.0)


@pytest.mark.parametrize("dtype", [np.int32, np.float32, np.float64])
def test_prefetch_is_a_hint_that_changes_nothing(dtype):
    a = np.arange(1000).astype(dtype).reshape(10, 100)
    before = a.copy()
    assert _prefetched_sum(a) == a.sum()
    assert np.array_equal(a, before)

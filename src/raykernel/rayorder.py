"""Ordering a batch of rays so that neighbours in the batch walk the same nodes.

    order = coherent_order(origins, directions, lo, hi)   # a permutation of the rays, or None

Incoherent batches (origins scattered, directions random) touch a different
part of the tree with every ray, and most node visits miss the cache. Sorting
the rays by the Morton code of their origin (quantised in the box lo..hi,
7 bits per axis) and the octant of their direction puts rays that start near
each other and head the same way next to each other; the kernels then visit
the rays in that order and write each result back to its own row, so the
output does not change, only the time. Batches smaller than MIN_RAYS, and
batches where most rays already share their key with the one before (the
rays of one camera), are left as they are: sorting them would cost more than
it saves.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from .config import njit

BITS = 7                 # Morton bits per axis: 2^21 origin cells
MIN_RAYS = 1 << 15


@njit(inline="always")
def _spread(x):
    """The low 7 bits of x moved to every third bit."""
    out = np.int64(0)
    for b in range(BITS):
        out |= ((x >> b) & 1) << (3 * b)
    return out


@njit(parallel=True)
def _keys(origins, directions, lo, scale):
    n = origins.shape[0]
    keys = np.empty(n, np.int64)
    top = (1 << BITS) - 1
    for i in prange(n):
        code = np.int64(0)
        for a in range(3):
            q = (origins[i, a] - lo[a]) * scale[a]
            c = np.int64(0) if not q > 0.0 else (np.int64(top) if q >= top else np.int64(q))
            code |= _spread(c) << a
        octant = (directions[i, 0] < 0.0) + 2 * (directions[i, 1] < 0.0) + 4 * (directions[i, 2] < 0.0)
        keys[i] = (np.int64(octant) << (3 * BITS)) | code
    return keys


@njit
def _radix_argsort(keys, bits):
    """Stable argsort of non-negative keys below 2^bits, 11 bits per pass; the keys
    travel with the indices so every pass reads them in order."""
    n = keys.shape[0]
    order = np.arange(n)
    k_in = keys.copy()
    k_out = np.empty(n, np.int64)
    o_out = np.empty(n, np.int64)
    shift = 0
    while shift < bits:
        count = np.zeros(2049, np.int64)
        for i in range(n):
            count[((k_in[i] >> shift) & 2047) + 1] += 1
        for b in range(2048):
            count[b + 1] += count[b]
        for i in range(n):
            k = (k_in[i] >> shift) & 2047
            j = count[k]
            o_out[j] = order[i]
            k_out[j] = k_in[i]
            count[k] = j + 1
        order, o_out = o_out, order
        k_in, k_out = k_out, k_in
        shift += 11
    return order


@njit(parallel=True)
def _neighbours_alike(keys):
    """How many rays share their key with the ray before them."""
    same = 0
    for i in prange(1, keys.shape[0]):
        same += keys[i] == keys[i - 1]
    return same


def coherent_order(origins: np.ndarray, directions: np.ndarray, lo: np.ndarray, hi: np.ndarray):
    """A permutation of the rays by (direction octant, Morton code of the origin in the box
    lo..hi); None for small batches and for batches already in such an order (most
    neighbours alike, as the rays of a camera)."""
    n = len(origins)
    if n < MIN_RAYS:
        return None
    extent = np.where(hi > lo, hi - lo, 1.0)
    scale = (1 << BITS) / extent
    keys = _keys(origins, directions, np.asarray(lo, np.float64), scale)
    if _neighbours_alike(keys) * 2 > n:
        return None
    return _radix_argsort(keys, 3 * BITS + 3)

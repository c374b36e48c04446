"""A binary BVH as flat arrays, what every BVH builder makes (bvh.py's layout).

    tree = BVHArrays(bounds, first, count, order)     # node boxes, children or items, leaf sizes
    leaves = is_leaf(tree)                            # boolean mask over the nodes
    items = as_item_bounds(bounds)                    # (n, 6) float64 item boxes, checked

The SAH builder (bvh.py), Goldsmith-Salmon insertion (gsbvh.py), the optimiser
(bvhopt.py) and early split clipping (presplit.py) all make or take it.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class BVHArrays(NamedTuple):
    """A BVH as flat arrays; bvh.py's docstring gives the layout."""

    bounds: np.ndarray  # (N, 6) float64 node boxes
    first: np.ndarray  # (N,) int64: inner -> left child index; leaf -> first position in order
    count: np.ndarray  # (N,) int64: 0 for an inner node, else items in the leaf
    order: np.ndarray  # (n,) int64: permutation of item indices


def is_leaf(bvh: BVHArrays) -> np.ndarray:
    """Boolean mask over the nodes: True for leaves (including an empty root)."""
    idx = np.arange(bvh.count.shape[0], dtype=np.int64)
    return (bvh.count > 0) | (bvh.first <= idx)


def as_item_bounds(bounds, what: str = "bounds") -> np.ndarray:
    """`bounds` as a contiguous (n, 6) float64 array of finite boxes (min <= max), else ValueError."""
    arr = np.asarray(bounds)
    if arr.dtype.kind not in "fiu":
        raise ValueError(f"{what} must be numeric, got dtype {arr.dtype}")
    arr = np.ascontiguousarray(arr, dtype=np.float64)
    if arr.ndim == 1 and arr.size == 0:
        arr = arr.reshape(0, 6)
    if arr.ndim != 2 or arr.shape[1] != 6:
        raise ValueError(f"{what} must have shape (n, 6), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{what} must be finite")
    if np.any(arr[:, :3] > arr[:, 3:]):
        bad = int(np.nonzero(np.any(arr[:, :3] > arr[:, 3:], axis=1))[0][0])
        raise ValueError(f"{what}[{bad}] has a minimum above its maximum: {arr[bad].tolist()}")
    return arr

"""A binary BVH as flat arrays, what every BVH builder makes (the layout below).

    tree = BVHArrays(bounds, first, count, order)     # node boxes, children or items, leaf sizes
    leaves = is_leaf(tree)                            # boolean mask over the nodes
    items = as_item_bounds(bounds)                    # (n, 6) float64 item boxes, checked

The SAH and Morton builders (bvhbuild.py), Goldsmith-Salmon insertion (gsbvh.py), the optimiser
(bvhopt.py) and early split clipping (presplit.py) all make or take it; bvh.py stores it in
the flat arrays.

Layout
------
Node 0 is the root. A box is stored as xmin, ymin, zmin, xmax, ymax, zmax.
An inner node has ``count == 0`` and its two children at ``first`` (left) and
``first + 1`` (right), so siblings sit next to each other. A leaf has
``count > 0`` and holds the items ``order[first:first + count]``. Children are
always stored after their parent (``first > parent index``), so one reverse
loop over the nodes visits every child before its parent (see `bvhbuild.refit`).

Every node box is tight: a leaf box is the union of its items' boxes and an
inner box is exactly the union of its children's boxes.

Empty input
-----------
With no items the tree is a single empty leaf: ``count[0] == 0``,
``first[0] == 0`` and the box is (+inf, +inf, +inf, -inf, -inf, -inf), the
empty box, which a slab test that orders the slab planes by the sign of the
ray direction never hits. It is the only leaf with no items; in general node
``i`` is a leaf exactly when ``count[i] > 0 or first[i] <= i`` (`is_leaf`).
Traversal code may also return early when ``order.size == 0``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class BVHArrays(NamedTuple):
    """A BVH as flat arrays; the module docstring gives the layout."""

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

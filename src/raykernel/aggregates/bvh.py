"""Binned surface-area-heuristic BVH over axis-aligned item boxes, as flat arrays.

    bvh, stats = build_bvh(item_bounds, leaf_size=4, bins=16)
    # bvh.bounds (N, 6), bvh.first (N,), bvh.count (N,), bvh.order (n,)
    refit(bvh, moved_item_bounds)   # same topology, new node boxes

Flat layout (the Geometry fields it owns)
-----------------------------------------
N nodes of all BVHs:
  node_bounds  (N, 6) float64  node box, widened by flatten's culling margin   48 B a node
  node_first   (N,)   int64    inner: left child (right = left + 1, global); leaf: first ref   8 B
  node_count   (N,)   int64    0 for an inner node, else refs in the leaf       8 B
The aggregate's agg_start is its root node. Every stack entry of a BVH is a
node to visit (step START), entered at stack_t.

Layout
------
Node 0 is the root. A box is stored as xmin, ymin, zmin, xmax, ymax, zmax.
An inner node has ``count == 0`` and its two children at ``first`` (left) and
``first + 1`` (right), so siblings sit next to each other. A leaf has
``count > 0`` and holds the items ``order[first:first + count]``. Children are
always stored after their parent (``first > parent index``), so one reverse
loop over the nodes visits every child before its parent (see `refit`).

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

Splitting rules
---------------
Centroids are binned into ``bins`` equal bins along each axis whose centroid
extent is non-zero, and every boundary between bins is scored with

    cost = traversal_cost + (M_left * N_left + M_right * N_right) / M_parent * intersection_cost

where M is the surface area of a box and N the items on each side, each
counted by its weight (1 unless given: a polygon of many corners costs the
corners its test walks, sah_weights), in blocks of ``block`` (rounded up: 1
by default; 4 prices a leaf as a 4-lane test takes its triangles, as Embree does).
When the parent box has zero area (all
items lie on one line or are one point) M is the half-perimeter instead,
which still favours splits into short, balanced pieces. Measures are taken on
boxes scaled by the parent's largest extent, so neither 1e-200 nor 1e200
coordinates underflow or overflow the areas.

A node becomes a leaf when it has at most ``leaf_size`` items and its leaf
cost ``blocks(weight) * intersection_cost`` is not worse than the best split;
otherwise it is split at the best boundary. So no leaf ever holds more than
``leaf_size`` items: ``leaf_size`` is also the maximum leaf size. When all
centroids of a node coincide there is no boundary to score: the node is a
leaf if it has at most ``leaf_size`` items, and otherwise it is split in the
middle of its range of ``order`` by count (the halves have the same box, but
the leaves stay small and the depth grows only logarithmically).

The build is deterministic: the same input gives bit-identical arrays.
"""

from __future__ import annotations

import math
import time
from typing import NamedTuple

import numpy as np

from ..errors import OptionError, SceneError
from ..geometry import counters as C
from ..geometry.boxes import INF, box_entry, cull_margin
from ..geometry.compiletime import CompileClock, compile_notice
from ..geometry.config import njit
from ..scene.accel import Kind, Param
from .walk import MAX_TREE_DEPTH, START, Field, entry_tag, push

__all__ = ["BVHArrays", "build_bvh", "refit", "refit_moved", "is_leaf"]

_MAX_BINS = 1024
_COMPILING = "raykernel: compiling the BVH builder (first use after install, a few seconds)"
# corners a polygon's inside test walks in the time of one whole primitive test (reference
# costs: about 1 ns per corner walked against 5-15 ns per test)
CORNERS_PER_TEST = 8


class BVHArrays(NamedTuple):
    """A BVH as flat arrays; see the module docstring for the layout."""

    bounds: np.ndarray  # (N, 6) float64 node boxes
    first: np.ndarray  # (N,) int64: inner -> left child index; leaf -> first position in order
    count: np.ndarray  # (N,) int64: 0 for an inner node, else items in the leaf
    order: np.ndarray  # (n,) int64: permutation of item indices


def is_leaf(bvh: BVHArrays) -> np.ndarray:
    """Boolean mask over the nodes: True for leaves (including an empty root)."""
    idx = np.arange(bvh.count.shape[0], dtype=np.int64)
    return (bvh.count > 0) | (bvh.first <= idx)


@njit
def _range_bounds(data, start, end, box, cbox):
    """Union of the item boxes (into box) and centroids (into cbox) of data[start:end]."""
    for k in range(3):
        box[k] = np.inf
        box[k + 3] = -np.inf
        cbox[k] = np.inf
        cbox[k + 3] = -np.inf
    for p in range(start, end):
        for k in range(3):
            lo = data[p, k]
            hi = data[p, k + 3]
            c = data[p, k + 6]
            box[k] = min(box[k], lo)
            box[k + 3] = max(box[k + 3], hi)
            cbox[k] = min(cbox[k], c)
            cbox[k + 3] = max(cbox[k + 3], c)


@njit(inline="always")
def _priced(weight, block):
    """Items of total `weight` priced in blocks of `block` (rounded up); weight itself for 1."""
    return weight if block == 1 else float(math.ceil(weight / block))


@njit
def _build_kernel(items, weights, leaf_size, bins, traversal_cost, intersection_cost, block):
    """Build the tree; returns (bounds, first, count, order, node count, max depth)."""
    n = items.shape[0]
    cap = 2 * n - 1 if n > 0 else 1
    bounds = np.empty((cap, 6), dtype=np.float64)
    first = np.empty(cap, dtype=np.int64)  # every created node sets both
    count = np.empty(cap, dtype=np.int64)
    order = np.arange(n, dtype=np.int64)
    if n == 0:
        first[0] = 0
        count[0] = 0
        for k in range(3):
            bounds[0, k] = np.inf
            bounds[0, k + 3] = -np.inf
        return bounds, first, count, order, 1, 0

    # per position in order: item box and centroid, permuted along with order so
    # that every pass over a node's range reads memory sequentially
    data = np.empty((n, 10), dtype=np.float64)
    for i in range(n):
        for k in range(3):
            data[i, k] = items[i, k]
            data[i, k + 3] = items[i, k + 3]
            data[i, k + 6] = 0.5 * items[i, k] + 0.5 * items[i, k + 3]
        data[i, 9] = weights[i]

    # work items: node, start, end, depth and the centroid box of the range
    st_node = np.empty(n + 1, dtype=np.int64)
    st_start = np.empty(n + 1, dtype=np.int64)
    st_end = np.empty(n + 1, dtype=np.int64)
    st_depth = np.empty(n + 1, dtype=np.int64)
    st_cb = np.empty((n + 1, 6), dtype=np.float64)

    bin_count = np.zeros((3, bins), dtype=np.int64)
    bin_weight = np.zeros((3, bins), dtype=np.float64)
    bin_box = np.empty((3, bins, 6), dtype=np.float64)
    for a in range(3):
        for b in range(bins):
            for k in range(3):
                bin_box[a, b, k] = np.inf
                bin_box[a, b, k + 3] = -np.inf
    nonempty = np.empty(bins, dtype=np.int64)
    left_measure = np.empty(bins, dtype=np.float64)
    box = np.empty(6, dtype=np.float64)
    cbox = np.empty(6, dtype=np.float64)
    lbox = np.empty(6, dtype=np.float64)
    rbox = np.empty(6, dtype=np.float64)
    lcb = np.empty(6, dtype=np.float64)
    rcb = np.empty(6, dtype=np.float64)
    scale = np.zeros(3, dtype=np.float64)
    cmin = np.zeros(3, dtype=np.float64)

    _range_bounds(data, np.int64(0), n, box, cbox)
    for k in range(6):
        bounds[0, k] = box[k]
        st_cb[0, k] = cbox[k]
    st_node[0] = 0
    st_start[0] = 0
    st_end[0] = n
    st_depth[0] = 0
    top = 1
    next_node = 1
    max_depth = 0

    while top > 0:
        top -= 1
        node = st_node[top]
        s = st_start[top]
        e = st_end[top]
        depth = st_depth[top]
        cnt = e - s
        if depth > max_depth:
            max_depth = depth

        # axes that can be binned: positive, finite centroid extent and finite bins/extent
        any_axis = False
        for k in range(3):
            cmin[k] = st_cb[top, k]
            ext = st_cb[top, k + 3] - st_cb[top, k]
            scale[k] = 0.0
            if ext > 0.0 and ext < np.inf:
                sc = bins / ext
                if sc < np.inf:
                    scale[k] = sc
                    any_axis = True

        split_axis = -1
        split_bin = 0
        mid = s + cnt // 2
        if cnt == 1:
            pass
        elif not any_axis:
            # all centroids coincide: a leaf, or a middle split by count when too many
            if cnt > leaf_size:
                split_axis = 3
        else:
            weight = 0.0
            for p in range(s, e):
                weight += data[p, 9]
                for a in range(3):
                    if scale[a] == 0.0:
                        continue
                    f = (data[p, a + 6] - cmin[a]) * scale[a]
                    b = bins - 1
                    if f < bins - 1:
                        b = int(f)
                    bin_count[a, b] += 1
                    bin_weight[a, b] += data[p, 9]
                    for k in range(3):
                        bin_box[a, b, k] = min(bin_box[a, b, k], data[p, k])
                        bin_box[a, b, k + 3] = max(bin_box[a, b, k + 3], data[p, k + 3])

            # measures on boxes scaled by the parent's largest extent
            dx = bounds[node, 3] - bounds[node, 0]
            dy = bounds[node, 4] - bounds[node, 1]
            dz = bounds[node, 5] - bounds[node, 2]
            big = max(dx, max(dy, dz))
            inv = 1.0 / big if big > 0.0 else 1.0
            dx *= inv
            dy *= inv
            dz *= inv
            parent_measure = 2.0 * (dx * dy + dy * dz + dz * dx)
            use_area = parent_measure > 0.0
            if not use_area:
                parent_measure = dx + dy + dz

            # sweep the non-empty bins only: boundaries between empty bins give
            # the same partition as the boundary just left of the next non-empty bin
            best = np.inf
            for a in range(3):
                if scale[a] == 0.0:
                    continue
                nn = 0
                for b in range(bins):
                    if bin_count[a, b] > 0:
                        nonempty[nn] = b
                        nn += 1
                for k in range(3):
                    lbox[k] = np.inf
                    lbox[k + 3] = -np.inf
                lc = 0.0
                for j in range(nn - 1):
                    b = nonempty[j]
                    lc += bin_weight[a, b]
                    for k in range(3):
                        if bin_box[a, b, k] < lbox[k]:
                            lbox[k] = bin_box[a, b, k]
                        if bin_box[a, b, k + 3] > lbox[k + 3]:
                            lbox[k + 3] = bin_box[a, b, k + 3]
                    ex = (lbox[3] - lbox[0]) * inv
                    ey = (lbox[4] - lbox[1]) * inv
                    ez = (lbox[5] - lbox[2]) * inv
                    lcost = _priced(lc, block)
                    if use_area:
                        left_measure[j] = 2.0 * (ex * ey + ey * ez + ez * ex) * lcost
                    else:
                        left_measure[j] = (ex + ey + ez) * lcost
                for k in range(3):
                    rbox[k] = np.inf
                    rbox[k + 3] = -np.inf
                rc = 0.0
                for j in range(nn - 1, 0, -1):
                    b = nonempty[j]
                    rc += bin_weight[a, b]
                    for k in range(3):
                        if bin_box[a, b, k] < rbox[k]:
                            rbox[k] = bin_box[a, b, k]
                        if bin_box[a, b, k + 3] > rbox[k + 3]:
                            rbox[k + 3] = bin_box[a, b, k + 3]
                    ex = (rbox[3] - rbox[0]) * inv
                    ey = (rbox[4] - rbox[1]) * inv
                    ez = (rbox[5] - rbox[2]) * inv
                    rcost = _priced(rc, block)
                    if use_area:
                        c = left_measure[j - 1] + 2.0 * (ex * ey + ey * ez + ez * ex) * rcost
                    else:
                        c = left_measure[j - 1] + (ex + ey + ez) * rcost
                    if c < best:
                        best = c
                        split_axis = a
                        split_bin = b

            if split_axis >= 0:
                split_cost = traversal_cost + best / parent_measure * intersection_cost
                leaf_cost = _priced(weight, block) * intersection_cost
                if cnt <= leaf_size and leaf_cost <= split_cost:
                    split_axis = -1
            elif cnt > leaf_size:
                split_axis = 3  # no usable boundary (non-finite measures): middle split

            if 0 <= split_axis < 3:
                a = split_axis
                for k in range(3):
                    lbox[k] = np.inf
                    lbox[k + 3] = -np.inf
                    rbox[k] = np.inf
                    rbox[k + 3] = -np.inf
                for b in range(bins):
                    if bin_count[a, b] == 0:
                        continue
                    if b < split_bin:
                        for k in range(3):
                            lbox[k] = min(lbox[k], bin_box[a, b, k])
                            lbox[k + 3] = max(lbox[k + 3], bin_box[a, b, k + 3])
                    else:
                        for k in range(3):
                            rbox[k] = min(rbox[k], bin_box[a, b, k])
                            rbox[k + 3] = max(rbox[k + 3], bin_box[a, b, k + 3])
            # leave every bin empty for the next node
            for a in range(3):
                if scale[a] == 0.0:
                    continue
                for b in range(bins):
                    if bin_count[a, b] > 0:
                        bin_count[a, b] = 0
                        bin_weight[a, b] = 0.0
                        for k in range(3):
                            bin_box[a, b, k] = np.inf
                            bin_box[a, b, k + 3] = -np.inf

        if split_axis < 0:
            first[node] = s
            count[node] = cnt
            continue

        if split_axis == 3:
            _range_bounds(data, s, mid, lbox, lcb)
            _range_bounds(data, mid, e, rbox, rcb)
        else:
            a = split_axis
            for k in range(3):
                lcb[k] = np.inf
                lcb[k + 3] = -np.inf
                rcb[k] = np.inf
                rcb[k + 3] = -np.inf
            i = s
            j = e - 1
            while i <= j:
                f = (data[i, a + 6] - cmin[a]) * scale[a]
                b = bins - 1
                if f < bins - 1:
                    b = int(f)
                if b < split_bin:
                    for k in range(3):
                        c = data[i, k + 6]
                        lcb[k] = min(lcb[k], c)
                        lcb[k + 3] = max(lcb[k + 3], c)
                    i += 1
                else:
                    for k in range(3):
                        c = data[i, k + 6]
                        rcb[k] = min(rcb[k], c)
                        rcb[k + 3] = max(rcb[k + 3], c)
                    it = order[i]
                    order[i] = order[j]
                    order[j] = it
                    for k in range(10):
                        x = data[i, k]
                        data[i, k] = data[j, k]
                        data[j, k] = x
                    j -= 1
            mid = i

        left = next_node
        next_node += 2
        first[node] = left
        count[node] = 0
        for k in range(6):
            bounds[left, k] = lbox[k]
            bounds[left + 1, k] = rbox[k]
        # right child below left on the stack: the left subtree is built first
        st_node[top] = left + 1
        st_start[top] = mid
        st_end[top] = e
        st_depth[top] = depth + 1
        for k in range(6):
            st_cb[top, k] = rcb[k]
        top += 1
        st_node[top] = left
        st_start[top] = s
        st_end[top] = mid
        st_depth[top] = depth + 1
        for k in range(6):
            st_cb[top, k] = lcb[k]
        top += 1

    return bounds, first, count, order, next_node, max_depth


@njit
def refit_moved(bounds, first, count, order, items, moved, margin):
    """Recompute in place the boxes of the nodes above the items at `moved` positions of
    order (all True: every node), widened by margin, children before parents. Returns the
    nodes recomputed and how much the SAH sum of areas (inner areas plus leaf areas times
    their items) grew."""
    n = bounds.shape[0]
    dirty = np.zeros(n, np.bool_)
    touched = 0
    grown = 0.0
    for node in range(n - 1, -1, -1):
        f = first[node]
        c = count[node]
        leaf = c > 0 or f <= node
        if leaf:
            for p in range(f, f + c):
                if moved[p]:
                    dirty[node] = True
                    break
        else:
            dirty[node] = dirty[f] or dirty[f + 1]
        if not dirty[node]:
            continue
        touched += 1
        old = _node_area(bounds, node)
        if leaf:
            for k in range(3):
                bounds[node, k] = np.inf
                bounds[node, k + 3] = -np.inf
            for p in range(f, f + c):
                it = order[p]
                for k in range(3):
                    bounds[node, k] = min(bounds[node, k], items[it, k] - margin)
                    bounds[node, k + 3] = max(bounds[node, k + 3], items[it, k + 3] + margin)
        else:
            for k in range(3):
                bounds[node, k] = min(bounds[f, k], bounds[f + 1, k])
                bounds[node, k + 3] = max(bounds[f, k + 3], bounds[f + 1, k + 3])
        grown += (c if leaf else 1) * (_node_area(bounds, node) - old)
    return touched, grown


@njit(borrows=True)
def _node_area(b, i):
    dx = max(b[i, 3] - b[i, 0], 0.0)
    dy = max(b[i, 4] - b[i, 1], 0.0)
    dz = max(b[i, 5] - b[i, 2], 0.0)
    return dx * dy + dy * dz + dz * dx


def _as_item_bounds(bounds, what: str = "bounds") -> np.ndarray:
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


def _int_option(value, name: str, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise OptionError(f"{name} must be an integer, got {value!r}")
    if not lo <= int(value) <= hi:
        raise OptionError(f"{name} must be in [{lo}, {hi}], got {value}")
    return int(value)


def _cost_option(value, name: str, positive: bool) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise OptionError(f"{name} must be a number, got {value!r}") from None
    if not np.isfinite(v) or v < 0.0 or (positive and v == 0.0):
        need = "positive" if positive else "non-negative"
        raise OptionError(f"{name} must be finite and {need}, got {value!r}")
    return v


def build_bvh(bounds, *, leaf_size=4, bins=16, traversal_cost=1.0, intersection_cost=1.0, block=1, weights=None):
    """Build a binned-SAH BVH over item boxes.

    bounds: (n, 6) array of item boxes (xmin, ymin, zmin, xmax, ymax, zmax),
    any real dtype (converted to float64), finite, with min <= max; zero
    thickness and n = 0 are allowed. leaf_size: most items in a leaf (>= 1).
    bins: centroid bins per axis (2..1024). traversal_cost (>= 0) and
    intersection_cost (> 0) weigh the SAH. block: items that cost one intersection_cost
    together (4: a leaf is priced in blocks of four, as a 4-lane test takes them).
    weights: (n,) positive test costs of the items in units of intersection_cost (None: 1
    each); the SAH counts a side's items by their weights (sah_weights gives a polygon of
    many corners the weight of the corners its test walks).

    Returns (BVHArrays, stats) with stats = {"nodes", "inner", "leaves",
    "empty_leaves", "refs", "bytes", "seconds", "max_depth"}; "refs" is the
    number of item references in leaves, "bytes" the size of the four
    arrays, "seconds" the wall time of the build (including the kernel's
    compilation when no cached copy exists yet), "max_depth" the number of
    edges from the root to the deepest leaf (0 for a lone root).
    """
    t0 = time.perf_counter()
    items = _as_item_bounds(bounds)
    leaf_size = _int_option(leaf_size, "leaf_size", 1, 1 << 30)
    bins = _int_option(bins, "bins", 2, _MAX_BINS)
    tc = _cost_option(traversal_cost, "traversal_cost", positive=False)
    ic = _cost_option(intersection_cost, "intersection_cost", positive=True)

    block = _int_option(block, "block", 1, 64)
    if weights is None:
        weights = np.ones(len(items))
    weights = np.ascontiguousarray(weights, np.float64)
    if weights.shape != (len(items),) or not np.all(np.isfinite(weights) & (weights > 0)):
        raise OptionError(f"weights must be {len(items)} finite positive numbers, one per item box")
    # said when it compiles (first use after install), not when it loads from the cache
    with CompileClock(notice=compile_notice("bvh", _COMPILING), after=0.0):
        nb, first, count, order, n_nodes, max_depth = _build_kernel(items, weights, leaf_size, bins, tc, ic,
                                                                    np.int64(block))
    if n_nodes < count.shape[0]:  # give back the unused part of the 2n - 1 node allocation
        nb, first, count = nb[:n_nodes].copy(), first[:n_nodes].copy(), count[:n_nodes].copy()
    bvh = BVHArrays(nb, first, count, order)
    seconds = time.perf_counter() - t0
    leaves = is_leaf(bvh)
    n_leaves = int(np.count_nonzero(leaves))
    stats = {
        "nodes": int(n_nodes),
        "inner": int(n_nodes) - n_leaves,
        "leaves": n_leaves,
        "empty_leaves": int(np.count_nonzero(leaves & (bvh.count == 0))),
        "refs": int(bvh.count[leaves].sum()),
        "bytes": int(sum(a.nbytes for a in bvh)),
        "seconds": seconds,
        "max_depth": int(max_depth),
    }
    return bvh, stats


def refit(bvh: BVHArrays, item_bounds) -> None:
    """Recompute bvh.bounds in place from new item boxes, keeping the topology.

    item_bounds is (n, 6) like the input of `build_bvh`, with n == len(bvh.order).
    """
    items = _as_item_bounds(item_bounds, "item_bounds")
    if items.shape[0] != bvh.order.shape[0]:
        raise ValueError(f"item_bounds has {items.shape[0]} items, the BVH has {bvh.order.shape[0]}")
    b = bvh.bounds
    if b.dtype != np.float64 or not b.flags.c_contiguous or not b.flags.writeable:
        raise ValueError("bvh.bounds must be a writeable C-contiguous float64 array")
    refit_moved(b, bvh.first, bvh.count, bvh.order, items, np.ones(len(bvh.order), np.bool_), 0.0)


# ----------------------------------------------------------------- flat layout (see the module docstring) and walk


CODE = 1
FIELDS = (Field("node_bounds", np.float64, (6,)), Field("node_first", np.int64, ()),
          Field("node_count", np.int64, ()))


def append_bvh(flat, tree: BVHArrays, refs, box, margin: float) -> int:
    """Store a built BVH over refs as the next aggregate; its node boxes grow by `margin`."""
    first_node = flat.size("node_count")
    first_ref = flat.add_refs(refs[tree.order])
    inner = tree.count == 0
    bounds = tree.bounds.copy()
    bounds[:, :3] -= margin
    bounds[:, 3:] += margin
    flat.append(node_bounds=bounds, node_first=np.where(inner, tree.first + first_node, tree.first + first_ref),
                node_count=tree.count)
    return flat.add_aggregate(CODE, first_node, len(tree.count), box)


@njit(private=True)
def step(node_bounds, node_first, node_count, node, ox, oy, oz, ix, iy, iz, tmin, best_t, stack_a, stack_b, stack_t,
         sp, cnt):
    """Descend from `node` to the nearest leaf the ray enters, pushing the farther child
    of every inner node passed; returns (sp, s, e): the leaf's references (none: s == e)."""
    while True:
        cnt[C.CELLS_VISITED] += 1
        n_items = node_count[node]
        if n_items > 0:
            cnt[C.CELLS_LEAVES] += 1
            s = node_first[node]
            return sp, s, s + n_items
        # inner node: test both children, go on with the nearer
        left = node_first[node]
        right = left + 1
        cnt[C.BOUNDS_TESTS] += 2
        tl = box_entry(node_bounds, left, ox, oy, oz, ix, iy, iz, tmin, best_t)
        tr = box_entry(node_bounds, right, ox, oy, oz, ix, iy, iz, tmin, best_t)
        if tl <= tr:
            if tl == INF:
                return sp, 0, 0
            if tr != INF:
                sp = push(stack_a, stack_b, stack_t, sp, right, entry_tag(CODE, START), tr)
            node = left
        else:
            if tl != INF:
                sp = push(stack_a, stack_b, stack_t, sp, left, entry_tag(CODE, START), tl)
            node = right


def sah_weights(corners) -> np.ndarray | None:
    """SAH weights of items whose tests walk `corners` corners each (1 for items of at most
    CORNERS_PER_TEST, corners / CORNERS_PER_TEST above); None when every item weighs 1."""
    corners = np.asarray(corners, np.float64)
    return np.maximum(1.0, corners / CORNERS_PER_TEST) if np.any(corners > CORNERS_PER_TEST) else None


def flatten(builder, params, refs, bounds, name, box):
    split = params.get("split", 1)
    sah = params.get("build", "sah") == "sah"
    weights = None
    if sah and params.get("corners", 1):
        weights = sah_weights(builder.vertex_weights(np.asarray(refs, np.int64)))
    if split > 1:       # the tree is built over pieces of the flat primitives (presplit.py)
        from .presplit import split_boxes
        piece_item, bounds = split_boxes(*builder.outlines(refs), bounds, split)
        weights = None if weights is None else weights[piece_item]
    if not sah:
        from .gsbvh import build_gs
        tree, stats = build_gs(bounds, order=params["order"], seed=params["seed"])
    else:
        tree, stats = build_bvh(bounds, leaf_size=params["leaf"], bins=params["bins"], block=params["block"],
                                weights=weights)
    if split > 1:
        from .presplit import leaves_of_items
        tree = leaves_of_items(tree, piece_item)
        stats.update(pieces=len(piece_item), refs=len(tree.order), bytes=int(sum(a.nbytes for a in tree)))
    if params.get("optimize", "none") != "none":
        from .bvhopt import optimize
        tree, info = optimize(tree, params["optimize"])
        stats.update(max_depth=info["max_depth"], sah_before=info["sah_before"], sah_after=info["sah_after"],
                     optimize_seconds=info["seconds"], optimize_steps=info["steps"])
    if stats.get("max_depth", 0) > MAX_TREE_DEPTH:
        raise SceneError(f"group {name or '(unnamed)'}: BVH depth {stats['max_depth']} exceeds {MAX_TREE_DEPTH}")
    return append_bvh(builder.flat, tree, refs, box, cull_margin(box)), dict(stats, width=params["width"])


KIND = Kind("bvh", "bounding volume hierarchy: binned surface-area heuristic (build=sah) or "
              "Goldsmith-Salmon insertion (build=gs)", (
    Param("leaf", 4, "maximum items in a leaf the SAH may keep (sah only; gs leaves hold one item)", int, 1, 64),
    Param("bins", 16, "SAH bins per axis (sah only)", int, 2, 256),
    Param("block", 1, "items the SAH prices as one intersection (sah only): 4 prices leaves in blocks of four, "
          "as RayScene's mesh kernel tests triangles four at a time (casting/triangles4.py)", int, 1, 16),
    Param("build", "sah", "sah: top-down binned SAH; gs: Goldsmith-Salmon 1987 incremental insertion",
          str, choices=("sah", "gs")),
    Param("order", "file", "gs insertion order: file (as given), shuffle (seeded permutation) or curve "
          "(Morton order of the box centres); ignored by sah", str, choices=("file", "shuffle", "curve")),
    Param("seed", 1, "seed of order=shuffle (gs only)", int, 0, 2 ** 31 - 1),
    Param("optimize", "none", "after the build, lower the SAH cost keeping the leaves (bvhopt.py): rotations "
          "(Kensler 2008) or reinsertion (Bittner, Hapala and Havran 2013)", str,
          choices=("none", "rotations", "reinsertion")),
    Param("corners", 1, "1: the SAH weighs a polygon of more than 8 corners as corners / 8 items, since its "
          "test walks them all (about a nanosecond each against some 8 for a whole test; sah only); 0: every "
          "item weighs one", int, 0, 1),
    Param("split", 1, "early split clipping (Ernst and Greiner 2007): each polygon or triangle is cut across "
          "its box's longest axis, again and again while that shrinks its boxes' surface by a quarter, into at "
          "most this many pieces, and the tree is built over the pieces' tighter boxes; a leaf refers to a "
          "primitive once, but a primitive may sit in several leaves (aggregates/presplit.py); 1: off",
          int, 1, 64),
    Param("width", 4, "children per node where the ray is cast: 4 collapses the binary tree into 4-wide "
          "nodes tested with one vector slab test (widebvh.py), 2 walks the binary tree; RayScene's mesh "
          "kernel and the fast walk of a scene that is one BVH over primitives (engine/widewalk.py) use it, "
          "a BVH nested with other aggregates is walked binary", int, choices=(2, 4)),
), flatten=flatten)

"""Binned surface-area-heuristic BVH over axis-aligned item boxes, as flat arrays (bvhtree.py's layout).

    bvh, stats = build_bvh(item_bounds, leaf_size=4, bins=16)     # method="morton": a linear BVH
    # bvh.bounds (N, 6), bvh.first (N,), bvh.count (N,), bvh.order (n,)
    refit(bvh, moved_item_bounds)   # same topology, new node boxes
    bounds, first, count, order, n_nodes, depth = build_rows(data)   # over rows made already (meshbuild.py)

The builders of the bvh kind (bvh.py): the SAH's binning, sweep and partitions, the parallel
build (a head split from the calling thread, its largest partitions in chunks on the threads,
then the subtrees on the threads, the node blocks compacted), the Morton build and the refit.
The tree is laid out as bvhtree.py describes.

Splitting rules
---------------
Centroids are binned into ``bins`` equal bins along each axis whose centroid
extent is non-zero (a node of n >= 2 SAMPLE_ITEMS items bins a sample: every
(n // SAMPLE_ITEMS)-th item, its children's boxes then gathered from all its
items as they are partitioned: a split as good by the SAH for a fraction of
the binning), and every boundary between bins is scored with

    cost = traversal_cost + (M_left * N_left + M_right * N_right) / M_parent * intersection_cost

where M is the surface area of a box and N the items on each side, each
counted by its weight (1 unless given: a polygon of many corners costs the
corners its test walks, bvh.sah_weights), in blocks of ``block`` (rounded up: 1
by default; 4 prices a leaf as a 4-lane test takes its triangles, as Embree does).
When the parent box has zero area (all
items lie on one line or are one point) M is the half-perimeter instead,
which still favours splits into short, balanced pieces. Measures are taken on
boxes scaled by the parent's largest extent, so neither 1e-200 nor 1e200
coordinates underflow or overflow the areas. A node of at most FEW_BINS_ITEMS
items bins into at most FEW_BINS bins, one of at most FEWEST_BINS_ITEMS into
FEWEST_BINS (the sweeps over 16 bins were much of a small node's work; the
trees are as good by the SAH and the casts' counted work the same; the exact
SAH split over sorted centroids, tried at these sizes, built no faster and
took longer to compile).

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

import numpy as np

from ..errors import OptionError
from ..geometry.boxrows import HI, ROW, bin3, empty, grow, grow_centre, swap
from ..geometry.compiletime import CompileClock, compile_notice
from ..geometry.config import njit
from ..geometry.parallel import for_ranges
from ..options import number
from .bvhtree import BVHArrays, as_item_bounds, is_leaf

__all__ = ["build_bvh", "build_rows", "refit", "refit_moved"]

_MAX_BINS = 1024
# the bins of small nodes (the module's splitting rules)
FEW_BINS, FEW_BINS_ITEMS, FEWEST_BINS, FEWEST_BINS_ITEMS = 8, 64, 6, 16
SAMPLE_ITEMS = 1 << 10      # a node of n items bins every (n // SAMPLE_ITEMS)-th: about this many to 2x as many
# a build's row of an item (boxrows.py): its box's low corner and weight, its high corner (from column
# HI) and a zero; the centre the SAH bins is computed from the box as it is needed (_centre), which
# reads less memory a pass than storing it
ROW_COLUMNS = ROW
WEIGHT = 3
_COMPILING = "raykernel: compiling the BVH builder (first use after install, a few seconds)"


@njit(inline="always")
def _centre(lo, hi):
    """An item box's centre on one axis, the centroid the SAH bins (not stored: a row stays lean)."""
    return 0.5 * lo + 0.5 * hi


@njit
def _range_bounds(data, start, end, box, cbox):
    """Union of the item boxes (into box) and centroids (into cbox) of data[start:end], as rows."""
    empty(box, 0)
    empty(cbox, 0)
    for p in range(start, end):
        grow(box, 0, data, p * ROW)
        grow_centre(cbox, 0, data, p * ROW)


@njit(inline="always")
def _put_box(bounds, node, box):
    """bounds[node] (six columns) = the box row `box`."""
    for k in range(3):
        bounds[node, k] = box[k]
        bounds[node, k + 3] = box[k + HI]


@njit(inline="always")
def _priced(weight, block):
    """Items of total `weight` priced in blocks of `block` (rounded up); weight itself for 1.
    A power of two divides as a product by its inverse (the same number, and no division in a
    sweep: the inverse is taken once, outside the loop)."""
    if block == 1:
        return weight
    if block & (block - 1) == 0:
        return float(math.ceil(weight * (1.0 / block)))
    return float(math.ceil(weight / block))


@njit(private=True)
def _bin_range(data, s, e, stride, cmin, scale, bins, bin_count, bin_weight, bin_box):
    """Drop the centroids of every stride-th item of data[s:e] into the bins of every axis with a
    scale (0: not binned); returns the binned items' total weight. bin_box: (3, bins, ROW) rows."""
    weight = 0.0
    last = bins - 1
    held = bin_box.shape[1]     # the bins an axis holds (this node may use fewer)
    for p in range(s, e, stride):
        w = data[p, WEIGHT]
        weight += w
        axis_bins = bin3(data, p * ROW, cmin, scale, last)
        for a in range(3):
            if scale[a] == 0.0:
                continue
            b = axis_bins[a]
            bin_count[a, b] += 1
            bin_weight[a, b] += w
            grow(bin_box, (a * held + b) * ROW, data, p * ROW)
    return weight


@njit(inline="always")
def _measure(box, inv, use_area):
    """The measure of a box row scaled by inv: its surface area, or its half-perimeter (a flat parent)."""
    ex = (box[HI] - box[0]) * inv
    ey = (box[HI + 1] - box[1]) * inv
    ez = (box[HI + 2] - box[2]) * inv
    return 2.0 * (ex * ey + ey * ez + ez * ex) if use_area else ex + ey + ez


@njit(inline="always")
def _best_split(bin_count, bin_box, bin_weight, scale, bins, inv, use_area, block, nonempty, right, box):
    """The cheapest boundary over the binned axes: (summed child cost, axis, first bin of the
    right side), axis -1 when no axis has two non-empty bins. A side's cost is the measure of its
    bins' box (scaled by inv) times their priced weight. Boundaries between empty bins give the
    same partition as the one just left of the next non-empty bin, so only those are priced;
    ties go to the earlier axis and, on one axis, to the right-most boundary."""
    best = np.inf
    split_axis = -1
    split_bin = np.int64(0)
    held = bin_box.shape[1]
    for a in range(3):
        if scale[a] == 0.0:
            continue
        nn = 0
        for b in range(bins):
            if bin_count[a, b] > 0:
                nonempty[nn] = b
                nn += 1
        # right[j]: the cost of the bins nonempty[j:], swept backwards; then the left side's forwards
        empty(box, 0)
        weight = 0.0
        for j in range(nn - 1, 0, -1):
            b = nonempty[j]
            weight += bin_weight[a, b]
            grow(box, 0, bin_box, (a * held + b) * ROW)
            right[j] = _measure(box, inv, use_area) * _priced(weight, block)
        empty(box, 0)
        weight = 0.0
        axis_best = np.inf
        axis_j = 0
        for j in range(1, nn):
            b = nonempty[j - 1]
            weight += bin_weight[a, b]
            grow(box, 0, bin_box, (a * held + b) * ROW)
            c = _measure(box, inv, use_area) * _priced(weight, block) + right[j]
            if c <= axis_best:
                axis_best = c
                axis_j = j
        if axis_best < best:
            best = axis_best
            split_axis = a
            split_bin = nonempty[axis_j]
    return best, split_axis, split_bin


@njit(private=True)
def _child_boxes(bin_count, bin_box, a, bins, split_bin, lbox, rbox):
    """The boxes of the bins left of split_bin and from it on, on axis a."""
    empty(lbox, 0)
    empty(rbox, 0)
    held = bin_box.shape[1]
    for b in range(bins):
        if bin_count[a, b] > 0:
            grow(lbox if b < split_bin else rbox, 0, bin_box, (a * held + b) * ROW)


@njit(inline="always")
def _clear_bins(bin_count, bin_weight, bin_box, scale, bins):
    """Leave every bin empty for the next node."""
    for a in range(3):
        if scale[a] == 0.0:
            continue
        for b in range(bins):
            if bin_count[a, b] > 0:
                bin_count[a, b] = 0
                bin_weight[a, b] = 0.0
                empty(bin_box, (a * bin_box.shape[1] + b) * ROW)


@njit(private=True)
def _partition(data, order, s, e, a, cmin, scale, bins, split_bin, lcb, rcb, boxes, lbox, rbox):
    """Move the items of data[s:e] (and order) whose centroid falls left of split_bin on axis a
    before the others, gathering each side's centroid box, and with `boxes` each side's box
    (lbox, rbox); returns the first of the right side."""
    empty(lcb, 0)
    empty(rcb, 0)
    if boxes:
        empty(lbox, 0)
        empty(rbox, 0)
    i = s
    j = e - 1
    while i <= j:
        f = (_centre(data[i, a], data[i, a + HI]) - cmin[a]) * scale[a]
        b = bins - 1
        if f < bins - 1:
            b = int(f)
        left = b < split_bin
        grow_centre(lcb if left else rcb, 0, data, i * ROW)
        if boxes:
            grow(lbox if left else rbox, 0, data, i * ROW)
        if left:
            i += 1
            continue
        it = order[i]
        order[i] = order[j]
        order[j] = it
        swap(data, i * ROW, j * ROW)
        j -= 1
    return i


@njit(inline="always")
def _leaf_is_cheapest(data, s, e, block, traversal_cost, intersection_cost):
    """A leaf of data[s:e] costs no more than the traversal of a split alone (which every split
    costs at least): a leaf with no need to bin."""
    weight = 0.0
    for p in range(s, e):
        weight += data[p, WEIGHT]
    return _priced(weight, block) * intersection_cost <= traversal_cost


@njit(private=True)
def _scaled_measure(bounds, node):
    """(1 / the node box's largest extent (1 if none), its measure on the box so scaled, whether
    that measure is a surface area (else the half-perimeter: a flat box))."""
    dx = bounds[node, 3] - bounds[node, 0]
    dy = bounds[node, 4] - bounds[node, 1]
    dz = bounds[node, 5] - bounds[node, 2]
    big = max(dx, max(dy, dz))
    inv = 1.0 / big if big > 0.0 else 1.0
    dx *= inv
    dy *= inv
    dz *= inv
    area = 2.0 * (dx * dy + dy * dz + dz * dx)
    return inv, (area if area > 0.0 else dx + dy + dz), area > 0.0


@njit(private=True)
def _push_work(st_node, st_start, st_end, st_depth, st_cb, top, node, s, e, depth, cb):
    """Push the work item (node over data[s:e], at depth, centroid box cb); returns the new top."""
    st_node[top] = node
    st_start[top] = s
    st_end[top] = e
    st_depth[top] = depth
    for k in range(ROW):
        st_cb[top, k] = cb[k]
    return top + 1


@njit
def _item_data(items, weights, data, i0, i1):
    """Rows i0..i1-1 of the build's per-item data: the item box and its weight."""
    for i in range(i0, i1):
        for k in range(3):
            data[i, k] = items[i, k]
            data[i, k + HI] = items[i, k + 3]
        data[i, WEIGHT] = weights[i]
        data[i, ROW - 1] = 0.0


@njit
def _build_loop(data, order, bounds, first, count, st_node, st_start, st_end, st_depth, st_cb, top, next_node,
                leaf_size, bins, traversal_cost, intersection_cost, block, defer, node_cap, tasks, task_cb, n_tasks,
                work, wide, split):
    """Split the work items on the stack (node over data[s:e], depth, centroid box) until every
    node is a leaf, or until the items split add up to `work` (0: no limit; the caller calls
    again, between calls Python answers Ctrl-C); returns (stack top, next free node, deepest
    depth, tasks deferred). With defer > 0, a work item of fewer than `defer` items, or met when
    the nodes up to node_cap or the stack are used up, is not split here but written to tasks[n_tasks]
    (node, start, end, depth) and task_cb, for _build_tasks. With wide > 0, the loop stops before
    the partition of a node of `wide` items or more that bins a sample, the node left on top of the
    stack and its split in `split` (axis, bin, bins, cmin xyz, scale xyz; split[0] is -1 otherwise),
    for the caller to partition on every thread (_partition_on_threads)."""
    split[0] = -1.0
    bin_count = np.zeros((3, bins), dtype=np.int64)
    bin_weight = np.zeros((3, bins), dtype=np.float64)
    bin_box = np.empty((3, bins, ROW), dtype=np.float64)
    for b in range(3 * bins):
        empty(bin_box, b * ROW)
    nonempty = np.empty(bins, dtype=np.int64)
    right_measure = np.empty(bins, dtype=np.float64)
    box = np.empty(ROW, dtype=np.float64)
    lbox = np.empty(ROW, dtype=np.float64)
    rbox = np.empty(ROW, dtype=np.float64)
    lcb = np.empty(ROW, dtype=np.float64)
    rcb = np.empty(ROW, dtype=np.float64)
    scale = np.zeros(4, dtype=np.float64)      # boxrows.bin3's: a fourth lane, unused
    cmin = np.zeros(4, dtype=np.float64)
    max_depth = 0
    done = 0

    while top > 0 and (work == 0 or done < work):
        top -= 1
        node = st_node[top]
        s = st_start[top]
        e = st_end[top]
        depth = st_depth[top]
        cnt = e - s
        if defer > 0 and cnt > leaf_size and (cnt < defer or next_node + 2 > node_cap or top + 2 > st_node.shape[0]):
            tasks[n_tasks, 0] = node
            tasks[n_tasks, 1] = s
            tasks[n_tasks, 2] = e
            tasks[n_tasks, 3] = depth
            for k in range(ROW):
                task_cb[n_tasks, k] = st_cb[top, k]
            n_tasks += 1
            continue
        if depth > max_depth:
            max_depth = depth
        done += cnt

        # axes that can be binned: positive, finite centroid extent and finite bins/extent (every
        # such axis, however thin: skipping the thin ones cost the teapot in a stadium a fifth of
        # its SAH cost, the split between the teapot and the ground being across the thin axis)
        any_axis = False
        nb = bins if cnt > FEW_BINS_ITEMS else min(bins, FEW_BINS if cnt > FEWEST_BINS_ITEMS else FEWEST_BINS)
        for k in range(3):
            cmin[k] = st_cb[top, k]
            ext = st_cb[top, k + HI] - st_cb[top, k]
            scale[k] = 0.0
            if ext > 0.0 and ext < np.inf:
                sc = nb / ext
                if sc < np.inf:
                    scale[k] = sc
                    any_axis = True

        split_axis = -1
        split_bin = np.int64(0)     # (a literal 0, in builds that never bin, had numba compile _partition for it)
        stride = np.int64(1)
        mid = s + cnt // 2
        if cnt == 1 or cnt <= leaf_size and _leaf_is_cheapest(data, s, e, block, traversal_cost, intersection_cost):
            pass
        elif not any_axis:
            # all centroids coincide: a leaf, or a middle split by count when too many
            if cnt > leaf_size:
                split_axis = 3
        else:
            # a large node bins a sample of its items (every stride-th): its split is as good, for
            # far less work; its children's boxes then come from the items themselves
            stride = max(stride, cnt // SAMPLE_ITEMS)
            weight = _bin_range(data, s, e, stride, cmin, scale, nb, bin_count, bin_weight, bin_box)
            # measures on boxes scaled by the parent's largest extent
            inv, parent_measure, use_area = _scaled_measure(bounds, node)
            best, split_axis, split_bin = _best_split(bin_count, bin_box, bin_weight, scale, nb, inv, use_area,
                                                      block, nonempty, right_measure, box)
            if split_axis >= 0:
                split_cost = traversal_cost + best / parent_measure * intersection_cost
                leaf_cost = _priced(weight, block) * intersection_cost
                if cnt <= leaf_size and leaf_cost <= split_cost:
                    split_axis = -1
            elif cnt > leaf_size:
                split_axis = 3  # no usable boundary (non-finite measures): middle split
            if 0 <= split_axis < 3 and stride == 1:
                _child_boxes(bin_count, bin_box, split_axis, nb, split_bin, lbox, rbox)
            _clear_bins(bin_count, bin_weight, bin_box, scale, nb)

        if split_axis < 0:
            first[node] = s
            count[node] = cnt
            continue

        if split_axis == 3:
            _range_bounds(data, s, mid, lbox, lcb)
            _range_bounds(data, mid, e, rbox, rcb)
        elif wide > 0 and cnt >= wide and stride > 1:
            split[0] = split_axis
            split[1] = split_bin
            split[2] = nb
            for k in range(3):
                split[3 + k] = cmin[k]
                split[6 + k] = scale[k]
            return top + 1, next_node, max_depth, n_tasks
        else:
            mid = _partition(data, order, s, e, split_axis, cmin, scale, nb, split_bin, lcb, rcb, stride > 1,
                             lbox, rbox)
        top, next_node = _split_node(bounds, first, count, st_node, st_start, st_end, st_depth, st_cb, top, next_node,
                                     node, s, mid, e, depth, lbox, rbox, lcb, rcb)
    return top, next_node, max_depth, n_tasks


@njit(inline="always")
def _split_node(bounds, first, count, st_node, st_start, st_end, st_depth, st_cb, top, next_node, node, s, mid, e,
                depth, lbox, rbox, lcb, rcb):
    """Make node (over data[s:e], partitioned at mid) the parent of two new nodes with the boxes lbox
    and rbox, and push their work items (centroid boxes lcb and rcb); returns (top, next free node)."""
    left = next_node
    first[node] = left
    count[node] = 0
    _put_box(bounds, left, lbox)
    _put_box(bounds, left + 1, rbox)
    # right child below left on the stack: the left subtree is built first
    top = _push_work(st_node, st_start, st_end, st_depth, st_cb, top, left + 1, mid, e, depth + 1, rcb)
    top = _push_work(st_node, st_start, st_end, st_depth, st_cb, top, left, s, mid, depth + 1, lcb)
    return top, next_node + 2


@njit
def _work_stack(n):
    """An empty stack of work items for ranges of at most n items."""
    return (np.empty(n + 1, dtype=np.int64), np.empty(n + 1, dtype=np.int64), np.empty(n + 1, dtype=np.int64),
            np.empty(n + 1, dtype=np.int64), np.empty((n + 1, ROW), dtype=np.float64))


@njit
def _push_root(bounds, n, box, cbox, st_node, st_start, st_end, st_depth, st_cb):
    """The root's box (box), and the root over all n items (centroid box cbox) as the stack's one
    work item; returns the top."""
    _put_box(bounds, 0, box)
    zero = np.int64(0)      # not the literal 0: numba would compile _push_work again for it
    return _push_work(st_node, st_start, st_end, st_depth, st_cb, zero, zero, zero, n, zero, cbox)


def _build_top(data, order, bounds, first, count, args, defer, node_cap, tasks, task_cb, threads=None):
    """The root over all of data, split down to the tasks (_build_loop with defer) in calls of
    about TOP_WORK items each; its box and, when deferring, the partitions of its nodes of
    WIDE_ITEMS items or more made on `threads` threads. Returns (next free node, deepest depth, tasks)."""
    stack = _work_stack(len(data) if defer == 0 else min(len(data), TOP_STACK))
    box, cbox = np.empty(ROW), np.empty(ROW)
    if len(data) > CHUNK_ITEMS:     # the root's box on the threads (its kernels compiled only for such builds)
        starts, ends = _chunks(0, len(data))
        boxes = np.empty((len(starts), 2, ROW))
        for_ranges(lambda c0, c1: _chunk_bounds(data, starts, ends, boxes, np.int64(c0), np.int64(c1)), len(starts),
                   threads, kernel=_chunk_bounds)
        box[:], cbox[:] = _united(boxes)
    else:
        _range_bounds(data, np.int64(0), np.int64(len(data)), box, cbox)
    top = _push_root(bounds, np.int64(len(data)), box, cbox, *stack)
    next_node, deepest, n_tasks = np.int64(1), 0, np.int64(0)
    split = np.empty(9)
    wide = np.int64(WIDE_ITEMS if defer else 0)
    while top > 0:
        top, next_node, depth, n_tasks = _build_loop(data, order, bounds, first, count, *stack, top, next_node, *args,
                                                     np.int64(defer), np.int64(node_cap), tasks, task_cb, n_tasks,
                                                     np.int64(TOP_WORK), wide, split)
        deepest = max(deepest, depth)
        if split[0] >= 0:
            _, st_start, st_end, _, _ = stack
            mid, boxes = _partition_on_threads(data, order, st_start[top - 1], st_end[top - 1], split, threads)
            top, next_node = _split_top(bounds, first, count, *stack, top, next_node, np.int64(mid), boxes)
    return next_node, deepest, n_tasks


def _chunks(s, e):
    """The chunks of CHUNK_ITEMS items that data[s:e] is worked on in, on the threads: (starts,
    ends). They depend on s and e alone, so what is made of them does not depend on the thread count."""
    starts = np.arange(s, e, CHUNK_ITEMS, dtype=np.int64)
    return starts, np.append(starts[1:], e).astype(np.int64)


# the chunks' rows are passed on as rows of 3-d arrays (boxes[c, k]), not as slices: a slice is
# an array type of its own, for which numba would compile the callees again (seconds, with _partition)
@njit
def _chunk_bounds(data, starts, ends, boxes, c0, c1):
    """_range_bounds of chunks c0..c1-1: boxes[c] = (the chunk's box row, its centroid box row)."""
    for c in range(c0, c1):
        _range_bounds(data, starts[c], ends[c], boxes[c, 0], boxes[c, 1])


@njit
def _united(boxes):
    """The union of the chunks' box rows, row by row: (C, m, ROW) -> (m, ROW)."""
    united = np.empty(boxes.shape[1:])
    for k in range(boxes.shape[1]):
        empty(united, k * ROW)
        for c in range(boxes.shape[0]):
            grow(united, k * ROW, boxes[c], k * ROW)
    return united


def _partition_on_threads(data, order, s, e, split, threads):
    """_partition of data[s:e] (its boxes gathered) by `split` (as _build_loop leaves it) on
    `threads` threads: each chunk partitioned in place on its own, then the right-side items left
    of the middle exchanged with the left-side items right of it, the k-th of one with the k-th of
    the other. The items end in the same order for any thread count. Returns (the middle, each
    chunk's rows lcb, rcb, lbox, rbox)."""
    starts, ends = _chunks(s, e)
    lefts = np.empty(len(starts), np.int64)
    boxes = np.empty((len(starts), 4, ROW))
    axis, split_bin, bins = (np.int64(x) for x in split[:3])
    cmin, scale = np.append(split[3:6], 0.0), np.append(split[6:9], 0.0)
    for_ranges(lambda c0, c1: _partition_chunks(data, order, starts, ends, axis, cmin, scale, bins, split_bin, lefts,
                                                boxes, np.int64(c0), np.int64(c1)),
               len(starts), threads, kernel=_partition_chunks)
    # the misplaced runs: each chunk's right side before mid, and its left side from mid on; run
    # r of a kind starts at *_at[r] and ends that kind's k-th item at *_end[r]
    mid = s + int(lefts.sum())
    right_at = starts + lefts
    right_end = np.cumsum(np.clip(np.minimum(ends, mid) - right_at, 0, None))
    left_at = np.maximum(starts, mid)
    left_end = np.cumsum(np.clip(right_at - left_at, 0, None))
    for_ranges(lambda k0, k1: _exchange_runs(data, order, right_at, right_end, left_at, left_end, np.int64(k0),
                                             np.int64(k1)),
               int(right_end[-1]), threads, kernel=_exchange_runs, min_size=CHUNK_ITEMS)
    return mid, boxes


@njit
def _partition_chunks(data, order, starts, ends, axis, cmin, scale, bins, split_bin, lefts, boxes, c0, c1):
    """_partition of chunks c0..c1-1 (data[starts[c]:ends[c]]) each on its own: the items of its left
    side into lefts[c], its boxes into boxes[c] (lcb, rcb, lbox, rbox, rows of ROW)."""
    gather = np.bool_(True)
    row = np.empty((4, ROW))
    for c in range(c0, c1):
        lefts[c] = _partition(data, order, starts[c], ends[c], axis, cmin, scale, bins, split_bin, row[0], row[1],
                              gather, row[2], row[3]) - starts[c]
        for k in range(4):
            for j in range(ROW):
                boxes[c, k, j] = row[k, j]


@njit
def _exchange_runs(data, order, right_at, right_end, left_at, left_end, k0, k1):
    """Exchange the k-th misplaced right-side item with the k-th misplaced left-side item, k in
    k0..k1-1 (the runs as _partition_on_threads makes them)."""
    r = 0
    q = 0
    for k in range(k0, k1):
        while right_end[r] <= k:
            r += 1
        while left_end[q] <= k:
            q += 1
        i = right_at[r] + k - (right_end[r - 1] if r > 0 else 0)
        j = left_at[q] + k - (left_end[q - 1] if q > 0 else 0)
        it = order[i]
        order[i] = order[j]
        order[j] = it
        swap(data, i * ROW, j * ROW)


@njit
def _split_top(bounds, first, count, st_node, st_start, st_end, st_depth, st_cb, top, next_node, mid, boxes):
    """_split_node for the work item on top of the stack, partitioned at mid on the threads with
    the chunks' boxes `boxes` (_partition_on_threads); returns (top, next free node)."""
    united = _united(boxes)
    top -= 1
    return _split_node(bounds, first, count, st_node, st_start, st_end, st_depth, st_cb, top, next_node,
                       st_node[top], st_start[top], mid, st_end[top], st_depth[top], united[2], united[3], united[0],
                       united[1])


@njit
def _build_tasks(data, order, bounds, first, count, tasks, task_cb, base, k0, k1, leaf_size, bins,
                 traversal_cost, intersection_cost, block):
    """Build the subtrees of tasks k0..k1-1; the task over data[s:e] takes its nodes from
    base + 2 s on (at most 2 (e - s) of them), so tasks never share a node. Returns the deepest depth."""
    deepest = 0
    split = np.empty(9)     # unused: these stages never stop for a partition on the threads
    for k in range(k0, k1):
        s = tasks[k, 1]
        e = tasks[k, 2]
        st_node, st_start, st_end, st_depth, st_cb = _work_stack(e - s)
        top = _push_work(st_node, st_start, st_end, st_depth, st_cb, np.int64(0), tasks[k, 0], s, e, tasks[k, 3],
                         task_cb[k])
        _, _, depth, _ = _build_loop(data, order, bounds, first, count, st_node, st_start, st_end, st_depth, st_cb,
                                     top, base + 2 * s, leaf_size, bins, traversal_cost, intersection_cost, block,
                                     np.int64(0), np.int64(0), tasks, task_cb, np.int64(0), np.int64(0), np.int64(0),
                                     split)
        deepest = max(deepest, depth)
    return deepest


@njit
def _build_middle(data, order, bounds, first, count, tasks, task_cb, block_start, block_cap, small_offset, small,
                  small_cb, small_count, defer, stack, k0, k1, leaf_size, bins, traversal_cost, intersection_cost,
                  block):
    """Split the head's tasks k0..k1-1 down to `defer` items, with a stack of `stack` work items:
    task k's nodes from block_start[k] on (at most block_cap[k]), the tasks it defers into small[o:]
    and small_cb[o:], o = block_start[k] - small_offset, their number into small_count[k].
    Returns the deepest depth."""
    deepest = 0
    split = np.empty(9)     # unused: these stages never stop for a partition on the threads
    for k in range(k0, k1):
        s = tasks[k, 1]
        e = tasks[k, 2]
        st_node, st_start, st_end, st_depth, st_cb = _work_stack(min(e - s, stack))
        top = _push_work(st_node, st_start, st_end, st_depth, st_cb, np.int64(0), tasks[k, 0], s, e, tasks[k, 3],
                         task_cb[k])
        offset = block_start[k] - small_offset
        _, _, depth, n_small = _build_loop(data, order, bounds, first, count, st_node, st_start, st_end, st_depth,
                                           st_cb, top, block_start[k], leaf_size, bins, traversal_cost,
                                           intersection_cost, block, defer, block_start[k] + block_cap[k], small,
                                           small_cb, offset, np.int64(0), np.int64(0), split)
        small_count[k] = n_small - offset
        deepest = max(deepest, depth)
    return deepest


@njit
def _compact(bounds, first, count):
    """Close the gaps the tasks' node blocks leave, in place, keeping the nodes' order (children
    after parents, siblings side by side); returns the node count."""
    cap = bounds.shape[0]
    index = np.full(cap, -1, dtype=np.int64)       # 0 for a node in use, then its new index
    index[0] = 0
    for i in range(cap):
        if index[i] == 0 and count[i] == 0 and first[i] > i:
            index[first[i]] = 0
            index[first[i] + 1] = 0
    used = 0
    for i in range(cap):
        if index[i] == 0:
            index[i] = used
            used += 1
    for i in range(cap):
        j = index[i]
        if j < 0:
            continue
        inner = count[i] == 0 and first[i] > i
        for k in range(6):
            bounds[j, k] = bounds[i, k]
        first[j] = index[first[i]] if inner else first[i]
        count[j] = count[i]
    return used


@njit(inline="always")
def _spread(x):
    """The 21 low bits of x spread to every third bit (bit i to bit 3 i)."""
    x &= 0x1FFFFF
    x = (x | x << 32) & 0x1F00000000FFFF
    x = (x | x << 16) & 0x1F0000FF0000FF
    x = (x | x << 8) & 0x100F00F00F00F00F
    x = (x | x << 4) & 0x10C30C30C30C30C3
    x = (x | x << 2) & 0x1249249249249249
    return x


@njit
def _morton_codes(data, grid, codes, i0, i1):
    """The 63-bit Morton codes of the centroids of data[i0:i1], on a 2**21 grid over all centroids'
    box (grid: that box's low corner, then 2**21 / its extent, 0 on a flat axis)."""
    for i in range(i0, i1):
        code = np.uint64(0)
        for a in range(3):
            q = np.int64(min(2097151.0, max(0.0, (_centre(data[i, a], data[i, a + HI]) - grid[a]) * grid[a + 3])))
            code |= np.uint64(_spread(q)) << np.uint64(a)
        codes[i] = code


@njit
def _centre_box(data):
    """The box of data's centroids: (low corner, high corner)."""
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for i in range(data.shape[0]):
        for a in range(3):
            c = _centre(data[i, a], data[i, a + HI])
            lo[a] = min(lo[a], c)
            hi[a] = max(hi[a], c)
    return lo, hi


@njit
def _morton_build(data, order, codes, leaf_size):
    """The tree over data[order], sorted by Morton code: every range of more than leaf_size items split
    where its codes' highest differing bit turns (in the middle where all codes agree), node
    boxes from the leaves up; returns (bounds, first, count, node count, max depth)."""
    n = data.shape[0]
    cap = 2 * n - 1
    bounds = np.empty((cap, 6), dtype=np.float64)
    first = np.empty(cap, dtype=np.int64)
    count = np.empty(cap, dtype=np.int64)
    st_node = np.empty(130, dtype=np.int64)       # a split halves the codes' differing bits or the range
    st_start = np.empty(130, dtype=np.int64)
    st_end = np.empty(130, dtype=np.int64)
    st_depth = np.empty(130, dtype=np.int64)
    st_node[0], st_start[0], st_end[0], st_depth[0] = 0, 0, n, 0
    top = 1
    next_node = 1
    max_depth = 0
    while top > 0:
        top -= 1
        node, s, e, depth = st_node[top], st_start[top], st_end[top], st_depth[top]
        max_depth = max(max_depth, depth)
        if e - s <= leaf_size:
            first[node] = s
            count[node] = e - s
            continue
        diff = codes[s] ^ codes[e - 1]
        mid = (s + e) // 2
        if diff != 0:
            bit = np.uint64(1) << np.uint64(63 - _leading_zeros(diff))
            lo, hi = s, e - 1           # the first item with the bit set: codes are sorted
            while lo < hi:
                m = (lo + hi) // 2
                if codes[m] & bit:
                    hi = m
                else:
                    lo = m + 1
            mid = lo
        left = next_node
        next_node += 2
        first[node] = left
        count[node] = 0
        st_node[top], st_start[top], st_end[top], st_depth[top] = left + 1, mid, e, depth + 1
        st_node[top + 1], st_start[top + 1], st_end[top + 1], st_depth[top + 1] = left, s, mid, depth + 1
        top += 2
    for i in range(next_node - 1, -1, -1):     # children after parents: boxes from the leaves up
        for k in range(3):
            bounds[i, k] = np.inf
            bounds[i, k + 3] = -np.inf
        if count[i] > 0:
            for p in range(first[i], first[i] + count[i]):
                item = order[p]
                for k in range(3):
                    bounds[i, k] = min(bounds[i, k], data[item, k])
                    bounds[i, k + 3] = max(bounds[i, k + 3], data[item, k + HI])
        else:
            c = first[i]
            for k in range(3):
                bounds[i, k] = min(bounds[c, k], bounds[c + 1, k])
                bounds[i, k + 3] = max(bounds[c, k + 3], bounds[c + 1, k + 3])
    return bounds, first, count, next_node, max_depth


@njit(inline="always")
def _leading_zeros(x):
    """Leading zero bits of a non-zero uint64."""
    k = 0
    while not x & (np.uint64(1) << np.uint64(63 - k)):
        k += 1
    return k


def _morton(data, leaf_size, threads=None):
    """_build_sah's result by Morton order (Lauterbach et al. 2009's linear BVH, split top-down):
    a sort and a binary search a node instead of binning every level; data stays as it is."""
    n = len(data)
    if n == 0:
        return _build_sah(data, leaf_size, 2, 1.0, 1.0, 1)
    lo, hi = _centre_box(data)
    extent = hi - lo
    with np.errstate(divide="ignore", over="ignore"):
        scale = np.where((extent > 0) & np.isfinite(2.0 ** 21 / extent), 2.0 ** 21 / extent, 0.0)
    grid = np.r_[lo, scale]
    codes = np.empty(n, np.uint64)
    for_ranges(lambda i0, i1: _morton_codes(data, grid, codes, np.int64(i0), np.int64(i1)), n, threads,
               kernel=_morton_codes, min_size=1 << 14)
    order = np.argsort(codes, kind="stable")
    bounds, first, count, n_nodes, depth = _morton_build(data, order, codes[order], np.int64(leaf_size))
    return bounds, first, count, order, n_nodes, depth


def build_rows(data, method="sah", leaf_size=4, bins=16, traversal_cost=1.0, intersection_cost=1.0, block=1,
               threads=None, compact=True):
    """build_bvh's tree over rows already made ((n, ROW_COLUMNS) float64: box, weight;
    the SAH permutes them): (bounds, first, count, order, node count, max depth), the node arrays
    possibly longer than the node count. For builders that make the rows themselves, faster than
    boxes (casting/meshbuild.py makes a mesh's from its vertices). compact=False: the parallel
    build's node arrays keep the unused rows between its tasks' nodes (the node count is then
    their length), for a caller that follows the tree from its root (widebvh.collapse) and so
    need not pay for closing them."""
    if method == "morton":
        return _morton(data, leaf_size, threads)
    return _build_sah(data, leaf_size, bins, traversal_cost, intersection_cost, block, threads, compact)


# items from which a build is split over threads (a mesh of some ten thousand triangles already builds
# sooner on two), and the largest subtree built by one thread's call
PARALLEL_ITEMS = 1 << 13
DEFER_ITEMS = 1 << 12
HEAD_PARTS = 8              # the head, from the calling thread, splits nodes of more than 1/8 of the items
TOP_STACK = 1 << 16         # work items the top's stack holds (a deeper top defers the rest as tasks)
TOP_WORK = 1 << 22          # items the top of a build splits in one call (well under the second Ctrl-C may wait)
WIDE_ITEMS = 1 << 16        # the head partitions its nodes of this many items or more on every thread,
CHUNK_ITEMS = 1 << 14       # in chunks of this many items


def _build_sah(data, leaf_size, bins, tc, ic, block, threads=None, compact=True):
    """Build the tree over `data` (_item_data's rows, permuted in place); returns (bounds,
    first, count, order, node count, max depth). From PARALLEL_ITEMS items on, the nodes of
    more than n / HEAD_PARTS items are split from the calling thread (their partitions, and the
    root's box, made on `threads` threads), and the subtrees below them built on the threads
    (split down to DEFER_ITEMS items, then those); the tree is the same (the same splits) with
    one thread or many, its nodes numbered the same for any thread count."""
    n = data.shape[0]
    order = np.arange(n, dtype=np.int64)
    if n == 0:
        bounds = np.empty((1, 6))
        bounds[0, :3], bounds[0, 3:] = np.inf, -np.inf
        return bounds, np.zeros(1, np.int64), np.zeros(1, np.int64), order, 1, 0
    args = (np.int64(leaf_size), np.int64(bins), float(tc), float(ic), np.int64(block))
    if n < PARALLEL_ITEMS:
        cap = 2 * n - 1
        bounds, first, count = np.empty((cap, 6)), np.empty(cap, np.int64), np.empty(cap, np.int64)
        none = np.empty((0, 4), np.int64), np.empty((0, ROW))
        n_nodes, depth, _ = _build_top(data, order, bounds, first, count, args, 0, cap, *none, threads)
        return bounds, first, count, order, n_nodes, depth
    # three stages, each node where any thread count puts it, so the tree and its numbering are
    # the same with one thread or many: the head splits the nodes of more than n / HEAD_PARTS items
    # from this thread (partitioning its largest on the threads); the middle splits the head's tasks
    # down to DEFER_ITEMS items on the threads, each in a block of nodes of its own; the small tasks
    # below, on the threads too, take their nodes from small_base + 2 s on. At most 8 nodes for every
    # `defer` items in a stage's blocks (beyond, the rest is deferred as it is).
    head_defer = max(DEFER_ITEMS, n // HEAD_PARTS)
    head_cap = min(2 * n - 1, 8 * (n // head_defer) + 64)
    head = np.empty((head_cap, 6)), np.empty(head_cap, np.int64), np.empty(head_cap, np.int64)
    tasks, task_cb = np.empty((head_cap, 4), np.int64), np.empty((head_cap, ROW))
    _, depth, n_tasks = _build_top(data, order, *head, args, head_defer, head_cap, tasks, task_cb, threads)
    tasks, task_cb = _largest_first(tasks[:n_tasks], task_cb[:n_tasks])
    # the middle: task k's nodes in block_start[k] .. + block_cap[k], its own tasks at the same offsets
    block_cap = 8 * ((tasks[:, 2] - tasks[:, 1]) // DEFER_ITEMS) + 64
    block_start = head_cap + np.concatenate([[0], np.cumsum(block_cap)[:-1]]).astype(np.int64)
    small_base = head_cap + int(block_cap.sum())
    cap = small_base + 2 * n
    bounds, first, count = np.empty((cap, 6)), np.empty(cap, np.int64), np.empty(cap, np.int64)
    bounds[:head_cap], first[:head_cap], count[:head_cap] = head
    head = None
    small, small_cb = np.empty((int(block_cap.sum()), 4), np.int64), np.empty((int(block_cap.sum()), ROW))
    small_count = np.zeros(n_tasks, np.int64)
    depths = [depth]
    for_ranges(lambda k0, k1: depths.append(_build_middle(data, order, bounds, first, count, tasks, task_cb, block_start,
                                                          block_cap, np.int64(head_cap), small, small_cb, small_count,
                                                          np.int64(DEFER_ITEMS), np.int64(TOP_STACK), np.int64(k0),
                                                          np.int64(k1), *args)),
               n_tasks, threads, kernel=_build_middle)
    keep = np.concatenate([np.arange(o - head_cap, o - head_cap + c) for o, c in zip(block_start, small_count)]
                          + [np.zeros(0, np.int64)]).astype(np.int64)
    small, small_cb = _largest_first(small[keep], small_cb[keep])
    for_ranges(lambda k0, k1: depths.append(_build_tasks(data, order, bounds, first, count, small, small_cb,
                                                         np.int64(small_base), np.int64(k0), np.int64(k1), *args)),
               len(small), threads, kernel=_build_tasks)
    n_nodes = _compact(bounds, first, count) if compact else len(count)
    return bounds, first, count, order, n_nodes, max(depths)


def _largest_first(tasks, task_cb):
    """The tasks (and their centroid boxes) by size, largest first, so that threads finish together."""
    big = np.argsort(tasks[:, 1] - tasks[:, 2], kind="stable")
    return np.ascontiguousarray(tasks[big]), np.ascontiguousarray(task_cb[big])


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


def build_bvh(bounds, *, leaf_size=4, bins=16, traversal_cost=1.0, intersection_cost=1.0, block=1, weights=None,
              method="sah", threads=None):
    """Build a binned-SAH BVH over item boxes.

    bounds: (n, 6) array of item boxes (xmin, ymin, zmin, xmax, ymax, zmax),
    any real dtype (converted to float64), finite, with min <= max; zero
    thickness and n = 0 are allowed. leaf_size: most items in a leaf (>= 1).
    bins: centroid bins per axis (2..1024). traversal_cost (>= 0) and
    intersection_cost (> 0) weigh the SAH. block: items that cost one intersection_cost
    together (4: a leaf is priced in blocks of four, as a 4-lane test takes them).
    weights: (n,) positive test costs of the items in units of intersection_cost (None: 1
    each); the SAH counts a side's items by their weights (bvh.sah_weights gives a polygon of
    many corners the weight of the corners its test walks). method: "sah" (binned SAH) or
    "morton" (splits by the Morton order of the centroids, leaves of leaf_size items: several
    times faster, a tree of higher SAH cost). threads: the build's threads (default: all).

    Returns (BVHArrays, stats) with stats = {"nodes", "inner", "leaves",
    "empty_leaves", "refs", "bytes", "seconds", "max_depth"}; "refs" is the
    number of item references in leaves, "bytes" the size of the four
    arrays, "seconds" the wall time of the build (including the kernel's
    compilation when no cached copy exists yet), "max_depth" the number of
    edges from the root to the deepest leaf (0 for a lone root).
    """
    t0 = time.perf_counter()
    items = as_item_bounds(bounds)
    leaf_size = int(number(leaf_size, "leaf_size", 1, 1 << 30, integer=True))
    bins = int(number(bins, "bins", 2, _MAX_BINS, integer=True))
    tc = float(number(traversal_cost, "traversal_cost", 0.0, math.inf))
    ic = float(number(intersection_cost, "intersection_cost", 0.0, math.inf, above=True))

    block = int(number(block, "block", 1, 64, integer=True))
    if weights is None:
        weights = np.ones(len(items))
    weights = np.ascontiguousarray(weights, np.float64)
    if weights.shape != (len(items),) or not np.all(np.isfinite(weights) & (weights > 0)):
        raise OptionError(f"weights must be {len(items)} finite positive numbers, one per item box")
    # said when it compiles (first use after install), not when it loads from the cache
    with CompileClock(notice=compile_notice("bvh", _COMPILING), after=0.0):
        if method not in ("sah", "morton"):
            raise OptionError(f"method must be sah or morton, got {method!r}")
        data = np.empty((len(items), ROW_COLUMNS))
        _item_data(items, weights, data, np.int64(0), np.int64(len(items)))
        nb, first, count, order, n_nodes, max_depth = build_rows(data, method, leaf_size, bins, tc, ic, block, threads)
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
    items = as_item_bounds(item_bounds, "item_bounds")
    if items.shape[0] != bvh.order.shape[0]:
        raise ValueError(f"item_bounds has {items.shape[0]} items, the BVH has {bvh.order.shape[0]}")
    b = bvh.bounds
    if b.dtype != np.float64 or not b.flags.c_contiguous or not b.flags.writeable:
        raise ValueError("bvh.bounds must be a writeable C-contiguous float64 array")
    refit_moved(b, bvh.first, bvh.count, bvh.order, items, np.ones(len(bvh.order), np.bool_), 0.0)

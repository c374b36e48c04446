"""k-d tree: space cut by axis-aligned planes placed by the surface-area heuristic, walked by
Havran's recursive traversal; and Octree-R, an octree with planes placed by a cost estimate, stored
and walked as a k-d tree.

    tree, stats = build_kdtree(item_bounds)          # the defaults: leaf=1, depth=0 (automatic)
    spec "kdtree(leaf=1, depth=0, isect=80, traversal=1, empty_bonus=0.5, mailbox=on)"
    tree, stats = build_octree_r(item_bounds, depth=6, split="cost")     # or split="centre"
    spec "octree-r(depth=6, leaf=1, split=cost, candidates=10, mailbox=on)"

The other subdivision scheme of the 1988 literature beside the octree (Kaplan's
BSP trees, GOLEM's and pbrt's k-d trees): each inner node cuts its box in two
along one axis, anywhere, not at the centre.

Build (after pbrt-v3's k-d tree)
--------------------------------
Item boxes are widened by a small margin (as the octree's are), clipped to the
node's box, and every side of every clipped box strictly inside the node is a
candidate plane, on each of the three axes. An item goes into every child its
closed box meets (`lo <= s` below, `hi >= s` above), so a ray that meets an item
at the plane, or lies in the plane, finds it in whichever child it visits. A
plane s on axis k costs

    traversal + isect * (1 - bonus) * (A_below / A * N_below + A_above / A * N_above)

(A: surface areas; bonus = empty_bonus when a side holds no item), against
isect * N for a leaf; the cheapest plane over the three axes is taken (ties to
the lower axis, then the lower plane). A node is a leaf when it holds at most
`leaf` items, is `depth` levels down (0: 8 + 1.3 log2 N), has no candidate, or
its best plane costs more than four times a leaf with fewer than 16 items; a
plane dearer than a leaf is still taken, up to twice along a path (the third
makes a leaf), as later cuts may pay for it.

Octree-R (Whang et al. 1995, as Havran's 1999 octree tables state it)
---------------------------------------------------------------------
An octree node that holds more than `leaf` items above level `depth` is cut
by three planes, one per axis, each placed independently: of `candidates`
places from the node's centre (the spatial median) towards the mean of its
items' centres (the object median), in steps of 1 / candidates of the way,
the one of least (left + cut) * A_lower + (right + cut) * A_upper (A: half a
child's surface area; left and right: items wholly on one side, cut: the
others; items clipped to the node), ties to the place nearer the centre.
Havran leaves the object median and the places' spacing open; this reading
is the one nearest his counts (bench/havran.py). As a k-d tree the node is
three levels of planes: x, then the same y plane in both halves, then the
same z plane in all four, so the leaves are the octree's eight octants
(every octant of a split node a leaf of its own or a node). split=centre
places the planes at the centre: the octree's leaves (octree.py, with
collapse and the budget off). Items go into every child their closed box
meets, as above.

Traversal (Havran 2000, TA_B^rec)
---------------------------------
The ray's segment through a node is known by its entry and exit distances;
which children it visits follows from the entry and exit coordinates on the
node's axis, a and b, against the plane s: both at or below it, the lower child
(cases N1-N3, P5, Z2-Z3); a on the plane and b above, the upper one (Z1); both
above, the upper one (P1-P3, N5); a below and b above, the lower child and then
the upper one (N4); a above and b at or below, the upper and then the lower
(P4). Only N4 and P4 divide, to find where the ray crosses the plane, so a ray
parallel to a plane never divides by zero. The child visited second is pushed
on the driver's stack with its entry distance (stack_t) and its exit (stack_u);
a leaf's references go to the driver, which drops pushed children entered beyond
the closest hit. A leaf's items are tested over the whole ray, not its segment
alone, so a hit found in one leaf that lies in a later one still counts.

Counting: one cells.visited per node, cells.leaves per leaf, cells.empty per
empty leaf, one bounds.tests per ray entering the tree (its box).

Flat layout (the Geometry fields it owns)
-----------------------------------------
K nodes of all k-d trees, T trees:
  kd_split    (K,)   float64  the plane's coordinate (inner nodes)                  8 B a node
  kd_child    (K,)   int64    inner: the upper child (global; the lower is the next node); leaf: first ref   8 B
  kd_count    (K,)   int64    leaf: its references; inner: -1 - axis                 8 B
  kd_root     (T,)   int64    root node                                             8 B a tree
  kd_box      (T, 6) float64  the tree's box                                        48 B
  kd_mailbox  (T,)   int64    1: skip references already tested in an earlier leaf   8 B
The aggregate's agg_start is its tree.
"""

from __future__ import annotations

import math
import time
from typing import NamedTuple

import numpy as np

from ..errors import OptionError
from ..geometry import counters as C
from ..geometry.boxes import CONSERVATIVE, INF, slab
from ..geometry.config import njit
from ..options import number
from .memory import check, grown, memory_limit
from .spec import Kind, Param, Search
from .walk import MAX_TREE_DEPTH, START, Cells, Field, Walk, answer, entry_tag, mailbox_reset, note_visit, push

__all__ = ["KdArrays", "build_kdtree"]

CODE = 6
FAR = 1                 # step: the child a ray visits second: stack_a the node, entered at stack_t, left at stack_u
MAX_BAD_REFINES = 3     # planes dearer than a leaf along a path: the third makes a leaf
NODE_BYTES = 24
PEAK_BYTES = 160        # a node's and its references' working memory at the peak of a build, for the budget


class KdArrays(NamedTuple):
    split: np.ndarray   # (K,) float64 plane coordinates
    child: np.ndarray   # (K,) int64 inner: upper child; leaf: first position in order
    count: np.ndarray   # (K,) int64 leaf: items; inner: -1 - axis
    order: np.ndarray   # (R,) int64 the leaves' items, leaf after leaf
    box: np.ndarray     # (6,) float64 the root box


# ----------------------------------------------------------------- building

@njit(inline="always")
def _area(box):
    dx, dy, dz = box[3] - box[0], box[4] - box[1], box[5] - box[2]
    return 2.0 * (dx * dy + dy * dz + dz * dx)


@njit
def _best_plane(items, lists, s, n, box, lo, hi, isect, traversal, empty_bonus):
    """The cheapest plane for the n items lists[s:s + n] in `box`: (cost, axis, position),
    axis -1 when no item side lies strictly inside the box. lo and hi: scratch for n clipped
    sides."""
    area = _area(box)
    best, best_axis, best_pos = INF, np.int64(-1), 0.0
    if area <= 0.0:
        return best, best_axis, best_pos
    inv = 1.0 / area
    for k in range(3):
        k1, k2 = (k + 1) % 3, (k + 2) % 3
        e1, e2 = box[k1 + 3] - box[k1], box[k2 + 3] - box[k2]
        cross = 2.0 * e1 * e2
        perimeter = 2.0 * (e1 + e2)
        for j in range(n):
            it = lists[s + j]
            lo[j] = max(items[it, k], box[k])
            hi[j] = min(items[it, k + 3], box[k + 3])
        los = np.sort(lo[:n])
        his = np.sort(hi[:n])
        planes = np.sort(np.concatenate((los, his)))
        below = before = 0      # items with lo <= x, with hi < x
        for q in range(2 * n):
            x = planes[q]
            if q > 0 and x == planes[q - 1]:
                continue
            while below < n and los[below] <= x:
                below += 1
            while before < n and his[before] < x:
                before += 1
            if not box[k] < x < box[k + 3]:
                continue
            above = n - before
            a_below = (cross + (x - box[k]) * perimeter) * inv
            a_above = (cross + (box[k + 3] - x) * perimeter) * inv
            bonus = empty_bonus if below == 0 or above == 0 else 0.0
            cost = traversal + isect * (1.0 - bonus) * (a_below * below + a_above * above)
            if cost < best:
                best, best_axis, best_pos = cost, np.int64(k), x
    return best, best_axis, best_pos


@njit
def _append_leaf(order, refs, lists, s, m):
    """A leaf's items lists[s:s + m] appended to order at refs (grown as needed); returns (order,
    refs after them)."""
    if refs + m > order.shape[0]:
        order = grown(order, refs + m, refs)
    for j in range(m):
        order[refs + j] = lists[s + j]
    return order, refs + m


@njit
def _lists_with_room(lists, used, m, nodes, refs, max_bytes):
    """lists grown to hold two children's lists of m items after its `used` part; returns (lists,
    bytes needed: > 0 when growing would pass max_bytes, lists then as they were)."""
    while used + 2 * m > lists.shape[0]:
        need = (nodes * NODE_BYTES + 2 * lists.shape[0] * 8) * 2 + refs * 8
        if need > max_bytes:
            return lists, need
        lists = grown(lists, 2 * lists.shape[0], used)
    return lists, 0


@njit
def _split_lists(items, lists, s, m, box, axis, pos, used):
    """The children's lists of the items lists[s:s + m] cut at pos on axis, written after the used
    part: below (every item whose box clipped to `box` starts at or below pos), then above (ends at
    or above it); returns (below, above) counts."""
    n_below = n_above = 0
    for j in range(m):
        it = lists[s + j]
        if max(items[it, axis], box[axis]) <= pos:
            lists[used + n_below] = it
            n_below += 1
    for j in range(m):
        it = lists[s + j]
        if min(items[it, axis + 3], box[axis + 3]) >= pos:
            lists[used + n_below + n_above] = it
            n_above += 1
    return n_below, n_above


@njit
def _build_kernel(items, leaf, max_depth, isect, traversal, empty_bonus, root_box, max_bytes):
    """The tree over item boxes: (split, child, count, order, nodes, max depth, bytes needed), the
    arrays cut at `nodes`; bytes needed > 0 when the budget stopped the build."""
    n = items.shape[0]
    cap = 64
    split = np.zeros(cap)
    child = np.zeros(cap, np.int64)
    count = np.zeros(cap, np.int64)
    lists = np.empty(max(16, 4 * n), np.int64)     # every node's items, children's after their parent's
    order = np.empty(max(16, 2 * n), np.int64)
    for i in range(n):
        lists[i] = i
    lo = np.empty(max(1, n))
    hi = np.empty(max(1, n))
    # work items: list start, count, box, depth, bad refines, the parent to point at this node (-1: none)
    w_start = np.empty(2 * max_depth + 4, np.int64)
    w_n = np.empty(2 * max_depth + 4, np.int64)
    w_box = np.empty((2 * max_depth + 4, 6))
    w_depth = np.empty(2 * max_depth + 4, np.int64)
    w_bad = np.empty(2 * max_depth + 4, np.int64)
    w_parent = np.empty(2 * max_depth + 4, np.int64)
    w_start[0], w_n[0], w_depth[0], w_bad[0], w_parent[0] = 0, n, 0, 0, -1
    for k in range(6):
        w_box[0, k] = root_box[k]
    top = 1
    used = n            # lists used
    nodes = 0
    refs = 0
    deepest = 0
    while top > 0:
        top -= 1
        s, m, depth, bad, parent = w_start[top], w_n[top], w_depth[top], w_bad[top], w_parent[top]
        box = w_box[top].copy()
        node = nodes
        nodes += 1
        if nodes > split.shape[0]:
            split, child, count = grown(split, nodes, node), grown(child, nodes, node), grown(count, nodes, node)
        if parent >= 0:
            child[parent] = node        # an upper child: the lower one is its parent's next node
        deepest = max(deepest, depth)
        cost, axis, pos = INF, np.int64(-1), 0.0
        if m > leaf and depth < max_depth:
            cost, axis, pos = _best_plane(items, lists, s, m, box, lo, hi, isect, traversal, empty_bonus)
        leaf_cost = isect * m
        if axis >= 0 and cost > leaf_cost:
            bad += 1
        if axis < 0 or (cost > 4.0 * leaf_cost and m < 16) or bad >= MAX_BAD_REFINES:
            child[node] = refs
            count[node] = m
            order, refs = _append_leaf(order, refs, lists, s, m)
            continue
        lists, need = _lists_with_room(lists, used, m, nodes, refs, max_bytes)
        if need > 0:
            return split[:nodes], child[:nodes], count[:nodes], order[:refs], nodes, deepest, need
        n_below, n_above = _split_lists(items, lists, s, m, box, axis, pos, used)
        split[node] = pos
        count[node] = -1 - axis
        # the upper child below the lower on the stack: the lower is built first, as node + 1
        w_start[top], w_n[top], w_depth[top], w_bad[top], w_parent[top] = used + n_below, n_above, depth + 1, bad, node
        for k in range(6):
            w_box[top, k] = box[k]
        w_box[top, axis] = pos
        top += 1
        w_start[top], w_n[top], w_depth[top], w_bad[top], w_parent[top] = used, n_below, depth + 1, bad, -1
        for k in range(6):
            w_box[top, k] = box[k]
        w_box[top, axis + 3] = pos
        top += 1
        used += n_below + n_above
    return split[:nodes], child[:nodes], count[:nodes], order[:refs], nodes, deepest, 0


def build_kdtree(bounds, *, leaf=1, depth=0, isect=80.0, traversal=1.0, empty_bonus=0.5, name=None,
                 max_bytes=None):
    """Build a k-d tree over item boxes (n, 6); items without a box (the empty box) are in no leaf.
    Returns (KdArrays, stats) with stats = {"nodes", "inner", "leaves", "empty_leaves", "refs",
    "bytes", "seconds", "max_depth", "depth_limit"}. max_bytes: the memory budget
    (memory.memory_limit() when None); a tree that would need more is a MemoryBudgetError."""
    t0 = time.perf_counter()
    leaf = int(number(leaf, "kdtree leaf", 1, 1 << 20, integer=True))
    depth = int(number(depth, "kdtree depth", 0, MAX_TREE_DEPTH - 2, integer=True))
    isect = float(number(isect, "kdtree isect", 0.0, 1e9, above=True))
    traversal = float(number(traversal, "kdtree traversal", 0.0, 1e9))
    empty_bonus = float(number(empty_bonus, "kdtree empty_bonus", 0.0, 1.0))
    widened, keep, box = _widened_items(bounds, "a k-d tree")
    limit = depth if depth else min(MAX_TREE_DEPTH - 2, round(8 + 1.3 * math.floor(math.log2(max(1, len(keep))))))
    budget = memory_limit() if max_bytes is None else int(max_bytes)
    split, child, count, order, nodes, deepest, need = _build_kernel(
        widened, np.int64(leaf), np.int64(limit), isect, traversal, empty_bonus, box, np.int64(budget))
    check(need, budget, f"the k-d tree of group {name or '(unnamed)'}", "lower depth or raise leaf")
    tree = KdArrays(split.copy(), child.copy(), count.copy(), keep[order], box)
    return tree, _build_stats(tree, nodes, deepest, limit, t0)


def _widened_items(bounds, what: str):
    """The item boxes (n, 6) that have a box, widened by a small margin (contiguous), their indices
    among bounds, and the tree's box around them; ValueError naming `what` when none has a box."""
    items = np.ascontiguousarray(np.asarray(bounds, np.float64)).reshape(-1, 6)
    solid = np.all(items[:, :3] <= items[:, 3:], axis=1) & np.all(np.isfinite(items), axis=1)
    if not solid.any():
        raise ValueError(f"{what} needs at least one item with a box")
    lo, hi = items[solid, :3].min(axis=0), items[solid, 3:].max(axis=0)
    margin = 1e-9 * max(float((hi - lo).max()), float(np.abs(np.concatenate([lo, hi])).max()))
    keep = np.flatnonzero(solid)
    widened = np.hstack([items[keep, :3] - margin, items[keep, 3:] + margin])
    return np.ascontiguousarray(widened), keep, np.concatenate([lo - margin, hi + margin])


def _build_stats(tree: KdArrays, nodes, deepest, limit, t0) -> dict:
    leaves = tree.count >= 0
    return {
        "nodes": int(nodes), "inner": int(np.count_nonzero(~leaves)), "leaves": int(np.count_nonzero(leaves)),
        "empty_leaves": int(np.count_nonzero(tree.count == 0)), "refs": int(len(tree.order)),
        "bytes": int(nodes * NODE_BYTES + 8 * len(tree.order) + 64), "seconds": time.perf_counter() - t0,
        "max_depth": int(deepest), "depth_limit": int(limit),
    }


# ----------------------------------------------------------------- Octree-R: an octree's planes, stored as a k-d tree

CENTRE, COST = 0, 1     # octree-r's split rules


@njit
def _octree_plane(items, lists, s, m, box, axis, candidates, rule):
    """The plane on `axis` of an octree node over the m items lists[s:s + m] in `box`: its centre
    (CENTRE), or (COST) the cheapest of `candidates` positions from the centre (the spatial median)
    towards the mean of the items' centres (the object median) in steps of 1 / candidates of the
    way, by Octree-R's estimate as Havran states it,
        (left + cut) * A(lower child) + (right + cut) * A(upper child),
    left and right the items wholly on one side, cut the others, A half a child's surface area;
    ties to the position nearer the centre. Items are clipped to the box first."""
    centre = 0.5 * (box[axis] + box[axis + 3])
    if rule == CENTRE or m == 0:
        return centre
    k1, k2 = (axis + 1) % 3, (axis + 2) % 3
    b, c = box[k1 + 3] - box[k1], box[k2 + 3] - box[k2]
    mean = 0.0
    for j in range(m):
        it = lists[s + j]
        mean += 0.5 * (max(items[it, axis], box[axis]) + min(items[it, axis + 3], box[axis + 3]))
    mean /= m
    best, best_x = INF, centre
    for i in range(candidates):
        x = centre + (mean - centre) * (i / candidates)
        left = right = 0
        for j in range(m):
            it = lists[s + j]
            if min(items[it, axis + 3], box[axis + 3]) < x:
                left += 1
            elif max(items[it, axis], box[axis]) > x:
                right += 1
        cut = m - left - right
        t = x - box[axis]
        cost = ((left + cut) * (t * 2.0 * (b + c) + b * c)
                + (right + cut) * ((box[axis + 3] - x) * 2.0 * (b + c) + b * c))
        if cost < best:
            best, best_x = cost, x
    return best_x


@njit
def _octree_kernel(items, leaf, max_depth, candidates, rule, root_box, max_bytes):
    """An octree over item boxes as a k-d tree: each split node cut by its three planes, x, then y,
    then z, into eight octant leaves or nodes (the same plane across both halves, as an octree
    cuts). Returns what _build_kernel does; max depth in octree levels."""
    n = items.shape[0]
    cap = 64
    split = np.zeros(cap)
    child = np.zeros(cap, np.int64)
    count = np.zeros(cap, np.int64)
    lists = np.empty(max(16, 4 * n), np.int64)
    order = np.empty(max(16, 2 * n), np.int64)
    for i in range(n):
        lists[i] = i
    size = 3 * (2 * max_depth + 4)
    w_start = np.empty(size, np.int64)
    w_n = np.empty(size, np.int64)
    w_box = np.empty((size, 6))
    w_level = np.empty(size, np.int64)      # 3 x octree level + the axis cut next
    w_planes = np.empty((size, 3))          # the octree node's planes
    w_parent = np.empty(size, np.int64)
    w_start[0], w_n[0], w_level[0], w_parent[0] = 0, n, 0, -1
    for k in range(6):
        w_box[0, k] = root_box[k]
    top = 1
    used = n
    nodes = refs = deepest = 0
    while top > 0:
        top -= 1
        s, m, level, parent = w_start[top], w_n[top], w_level[top], w_parent[top]
        box = w_box[top].copy()
        planes = w_planes[top].copy()
        node = nodes
        nodes += 1
        if nodes > split.shape[0]:
            split, child, count = grown(split, nodes, node), grown(child, nodes, node), grown(count, nodes, node)
        if parent >= 0:
            child[parent] = node
        axis = level % 3
        if axis == 0:               # an octree node: a leaf, or cut by its three planes
            deepest = max(deepest, level // 3)
            if m <= leaf or level // 3 >= max_depth:
                child[node] = refs
                count[node] = m
                order, refs = _append_leaf(order, refs, lists, s, m)
                continue
            for k in range(3):
                planes[k] = _octree_plane(items, lists, s, m, box, k, candidates, rule)
        pos = planes[axis]
        lists, need = _lists_with_room(lists, used, m, nodes, refs, max_bytes)
        if need > 0:
            return split[:nodes], child[:nodes], count[:nodes], order[:refs], nodes, deepest, need
        n_below, n_above = _split_lists(items, lists, s, m, box, axis, pos, used)
        split[node] = pos
        count[node] = -1 - axis
        for half in range(2):       # the upper half under the lower on the stack: the lower is node + 1
            w_start[top] = used + n_below if half == 0 else used
            w_n[top] = n_above if half == 0 else n_below
            w_level[top] = level + 1
            w_parent[top] = node if half == 0 else -1
            for k in range(6):
                w_box[top, k] = box[k]
            w_box[top, axis if half == 0 else axis + 3] = pos
            for k in range(3):
                w_planes[top, k] = planes[k]
            top += 1
        used += n_below + n_above
    return split[:nodes], child[:nodes], count[:nodes], order[:refs], nodes, deepest, 0


def build_octree_r(bounds, *, depth=6, leaf=1, split="cost", candidates=10, name=None, max_bytes=None):
    """Build an octree whose planes are placed by Octree-R's cost estimate (split="cost"; Whang et
    al. 1995, as Havran's 1999 tables state it) or at the centre (split="centre", Glassner's planes),
    stored as a k-d tree, over item boxes (n, 6). Returns (KdArrays, stats) with build_kdtree's
    stats plus "octree_inner", the octree's split nodes (a k-d tree's inner nodes / 7)."""
    t0 = time.perf_counter()
    depth = int(number(depth, "octree-r depth", 1, (MAX_TREE_DEPTH - 2) // 3, integer=True))
    leaf = int(number(leaf, "octree-r leaf", 1, 1 << 20, integer=True))
    candidates = int(number(candidates, "octree-r candidates", 1, 1000, integer=True))
    if split not in ("cost", "centre"):
        raise OptionError(f"octree-r split must be cost or centre, got {split!r}")
    widened, keep, box = _widened_items(bounds, "an octree")
    budget = memory_limit() if max_bytes is None else int(max_bytes)
    planes, child, count, order, nodes, deepest, need = _octree_kernel(
        widened, np.int64(leaf), np.int64(depth), np.int64(candidates), np.int64(COST if split == "cost" else CENTRE),
        box, np.int64(budget))
    check(need, budget, f"the octree-r of group {name or '(unnamed)'}", "lower depth or raise leaf")
    tree = KdArrays(planes.copy(), child.copy(), count.copy(), keep[order], box)
    stats = _build_stats(tree, nodes, deepest, depth, t0)
    stats["octree_inner"] = stats["inner"] // 7
    return tree, stats


# ----------------------------------------------------------------- flat layout (see the module docstring) and walk

FIELDS = (Field("kd_split", np.float64), Field("kd_child", np.int64), Field("kd_count", np.int64),
          Field("kd_root", np.int64), Field("kd_box", np.float64, (6,)), Field("kd_mailbox", np.int64))


def append_kdtree(flat, tree: KdArrays, refs, mailbox: bool, box) -> int:
    """Store a built k-d tree whose leaves hold refs[tree.order] as the next aggregate."""
    n0 = flat.size("kd_count")
    first_ref = flat.add_refs(refs[tree.order])
    t = flat.size("kd_root")
    inner = tree.count < 0
    flat.append(kd_split=tree.split, kd_child=np.where(inner, tree.child + n0, tree.child + first_ref),
                kd_count=tree.count, kd_root=[n0], kd_box=tree.box[None], kd_mailbox=[int(mailbox)])
    return flat.add_aggregate(CODE, t, len(tree.count), box)


def flatten(builder, params, refs, bounds, name, box):
    tree, stats = build_kdtree(bounds, leaf=params["leaf"], depth=params["depth"], isect=params["isect"],
                               traversal=params["traversal"], empty_bonus=params["empty_bonus"], name=name,
                               max_bytes=builder.max_bytes)
    return append_kdtree(builder.flat, tree, refs, params["mailbox"], box), stats


@njit(private=True)
def kd_step(kd_split, kd_child, kd_count, kd_root, kd_box, kd_mailbox, step, a, te, ray, lo, best_t, frame_f, f,
            stack_a, stack_b, stack_t, stack_u, sp, cnt, work):
    """Down the tree from the root (START: tree a) or a child visited second (FAR: node a, its
    segment from te to stack_u[sp]) to the next leaf the ray's segment reaches; returns (sp, s,
    e): the leaf's references (none: s == e)."""
    ox, oy, oz, dx, dy, dz, ix, iy, iz = ray
    if step == START:
        cnt[C.BOUNDS_TESTS] += 1
        t0, t1 = slab(kd_box[a, 0], kd_box[a, 3], ox, ix)
        t2, t3 = slab(kd_box[a, 1], kd_box[a, 4], oy, iy)
        t4, t5 = slab(kd_box[a, 2], kd_box[a, 5], oz, iz)
        t_in = max(max(t0, t2), max(t4, lo))
        t_out = min(min(t1, t3), min(t5, best_t))
        if t_out > 0.0:
            t_out *= CONSERVATIVE
        if t_in > t_out:
            return sp, 0, 0
        node = kd_root[a]
        if kd_mailbox[a] != 0:
            mailbox_reset(frame_f, f)
    else:
        node, t_in, t_out = a, te, stack_u[sp]
    tag = entry_tag(CODE, FAR)
    while True:
        cnt[C.CELLS_VISITED] += 1
        note_visit(work, CODE, node)
        m = kd_count[node]
        if m >= 0:
            cnt[C.CELLS_LEAVES] += 1
            if m == 0:
                cnt[C.CELLS_EMPTY] += 1
                return sp, 0, 0
            s = kd_child[node]
            return sp, s, s + m
        axis = -1 - m
        plane = kd_split[node]
        o = ox if axis == 0 else (oy if axis == 1 else oz)
        d = dx if axis == 0 else (dy if axis == 1 else dz)
        entry, leave = o + t_in * d, o + t_out * d
        if entry <= plane:
            if leave <= plane:
                node += 1                   # N1-N3, P5, Z2-Z3: the lower child
                continue
            if entry == plane:
                node = kd_child[node]       # Z1: from the plane upwards
                continue
            first, second = node + 1, kd_child[node]       # N4: lower, then upper
        else:
            if leave > plane:
                node = kd_child[node]       # P1-P3, N5: the upper child
                continue
            first, second = kd_child[node], node + 1       # P4: upper, then lower
        t_plane = (plane - o) / d       # d is not 0: the segment crosses the plane
        sp = push(stack_a, stack_b, stack_t, sp, second, tag, t_plane)
        stack_u[sp - 1] = t_out
        node, t_out = first, t_plane


@njit(inline="always")
def walk_step(geo, step, a, te, ray, lo, best_t, f, sp, ws, cnt):
    """walk.py's step contract: the next leaf of the tree (START) or of a child visited second (FAR)."""
    sp, s, e = kd_step(geo.kd_split, geo.kd_child, geo.kd_count, geo.kd_root, geo.kd_box, geo.kd_mailbox, step, a,
                       te, ray, lo, best_t, ws.frame_f, f, ws.stack_a, ws.stack_b, ws.stack_t, ws.stack_u, sp, cnt,
                       ws.work)
    return answer(sp, s, e, ray, best_t)


def cells(geo, a) -> Cells:
    """The tree's nodes, each with the box its planes cut out of the tree's (Walk.cells)."""
    t = geo.agg_start[a]
    todo, rows = [(int(geo.kd_root[t]), geo.kd_box[t].copy(), 0)], []
    while todo:
        node, box, depth = todo.pop()
        count = int(geo.kd_count[node])
        rows.append((box, depth, int(geo.kd_child[node]) if count >= 0 else 0, count if count >= 0 else -1, node))
        if count < 0:
            axis, split = -1 - count, geo.kd_split[node]
            below, above = box.copy(), box.copy()
            below[3 + axis] = split
            above[axis] = split
            todo += [(int(geo.kd_child[node]), above, depth + 1), (node + 1, below, depth + 1)]
    boxes = np.array([r[0] for r in rows])
    return Cells(boxes[:, :3], boxes[:, 3:], np.array([r[1] for r in rows], np.int64),
                 np.array([r[2] for r in rows], np.int64), np.array([r[3] for r in rows], np.int64),
                 np.array([r[4] for r in rows], np.int64))


def flatten_octree_r(builder, params, refs, bounds, name, box):
    tree, stats = build_octree_r(bounds, depth=params["depth"], leaf=params["leaf"], split=params["split"],
                                 candidates=params["candidates"], name=name, max_bytes=builder.max_bytes)
    return append_kdtree(builder.flat, tree, refs, params["mailbox"], box), stats


WALK = Walk(code=CODE, name="kdtree", fields=FIELDS, step=walk_step, cells=cells, keys="kd_count")
KIND = Kind("kdtree", "k-d tree: axis-aligned planes placed by the surface-area heuristic on the items' sides "
            "(pbrt's build), walked by Havran's recursive traversal (TA_B^rec)", (
    Param("leaf", 1, "a node holding at most this many items is a leaf", int, 1, 1 << 20),
    Param("depth", 0, "most levels below the root, 0: 8 + 1.3 log2(items)", int, 0, MAX_TREE_DEPTH - 2),
    Param("isect", 80.0, "the SAH's cost of a ray/item test, against traversal's of a node", float, 1e-6, 1e9),
    Param("traversal", 1.0, "the SAH's cost of a node visited", float, 0.0, 1e9),
    Param("empty_bonus", 0.5, "the share of a plane's cost forgiven when one side holds no item", float, 0.0, 1.0),
    Param("mailbox", True, "skip items already tested against the ray in an earlier leaf", bool),
), flatten=flatten, walk=WALK, search=Search(start=True, candidates=("kdtree", "kdtree(leaf=4)")))
OCTREE_R = Kind("octree-r", "Octree-R (Whang et al. 1995): an octree whose three planes a node sit at the cheapest of "
                "`candidates` places from its centre towards its items' mean centre, stored and walked as a k-d tree", (
    Param("depth", 6, "most octree levels below the root", int, 1, (MAX_TREE_DEPTH - 2) // 3),
    Param("leaf", 1, "a node holding at most this many items is a leaf", int, 1, 1 << 20),
    Param("split", "cost", "cost: Octree-R's planes; centre: Glassner's (an octree's leaves)", str,
          choices=("cost", "centre")),
    Param("candidates", 10, "places tried per axis, from the centre towards the items' mean centre", int, 1, 1000),
    Param("mailbox", True, "skip items already tested against the ray in an earlier leaf", bool),
), flatten=flatten_octree_r, walk=WALK)
KINDS = (KIND, OCTREE_R)

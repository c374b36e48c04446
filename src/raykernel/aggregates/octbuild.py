"""The octree's construction: centre subdivision over item boxes, collapse, the node layout and the wall quadtrees.

    tree, stats = build_octree(item_bounds)            # the defaults: depth=16, leaf=3, budget=16
    items_of_leaf = tree.order[tree.first[n]:tree.first[n] + tree.count[n]]
    walls, quads = wall_quadtrees(tree.first, tree.count, tree.nbr)   # walk=wall's nbr and quad nodes
    items, solid, origin, unit, widened = octree_frame(bounds, depth, "an octree")   # lazyoctree builds in it too

octree.py's docstring describes the root box and addresses, the subdivision
criteria and their defaults, collapse, neighbours and walls; octree.py stores
the tree as flat arrays (append_octree), octwalk.py and octpoint.py walk it.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np

from ..errors import SceneError
from ..geometry.config import njit
from ..options import number
from .grid import grid_box
from .memory import check, grown, memory_limit

__all__ = ["OctreeArrays", "build_octree", "wall_quadtrees", "octree_frame", "cell_margin", "overlaps",
           "ADDRESS_BITS", "MAX_DEPTH", "MAX_NODES", "BUDGET_SLACK"]

ADDRESS_BITS = 28
MAX_DEPTH = 24             # the parametric walk keeps up to 3 siblings per level on the kernel's stack
MAX_NODES = 20_000_000
BUDGET_SLACK = 4096        # references a budget allows on top of budget * items (small scenes stay free)
PEAK_NODE_BYTES = 512      # memory a node takes at the peak of a build: the builder's arrays, the flat ones, copies
PEAK_REF_BYTES = 32        # the same for a reference


class OctreeArrays(NamedTuple):
    """An octree as flat arrays; see octree.py's docstring. Node 0 is the root;
    the 8 children of an inner node are stored together in octant order."""

    origin: np.ndarray   # (3,) float64 lower corner of the root box
    unit: np.ndarray     # (3,) float64 side of one address unit (root side / 2**28)
    first: np.ndarray    # (N,) int64 inner: first child; leaf: first position in order
    count: np.ndarray    # (N,) int64 items in a leaf; -1 for an inner node
    loc: np.ndarray      # (N, 3) int64 lower address of the node's box
    level: np.ndarray    # (N,) int64 level of the node's box (its side is 2**(28 - level) units)
    slot: np.ndarray     # (N,) int64 level of the octant the node occupies in its parent (root: 0)
    nbr: np.ndarray      # (N, 6) int64 neighbour across each wall (-x, +x, -y, +y, -z, +z), -1: none
    bounds: np.ndarray   # (N, 6) float64 node boxes, origin + unit * address
    order: np.ndarray    # (R,) int64 item indices, leaf after leaf


@njit
def _before(key_a, node_a, key_b, node_b):
    """Split order: the larger key (items times surface area) first, then the smaller node."""
    return key_a > key_b or (key_a == key_b and node_a < node_b)


@njit(inline="always")
def overlaps(boxes, it, clo, chi, c):
    """Whether item it's box (closed) meets child octant c's, clo[c]..chi[c]."""
    for a in range(3):
        if boxes[it, a] > chi[c, a] or boxes[it, a + 3] < clo[c, a]:
            return False
    return True


@njit
def _heap_push(keys, nodes, size, key, node):
    """Add (key, node) to the binary heap keys[:size], nodes[:size]; returns the new size."""
    i = size
    while i > 0:
        up = (i - 1) // 2
        if not _before(key, node, keys[up], nodes[up]):
            break
        keys[i], nodes[i] = keys[up], nodes[up]
        i = up
    keys[i], nodes[i] = key, node
    return size + 1


@njit
def _heap_pop(keys, nodes, size):
    """Remove the first node of the heap; returns (node, new size)."""
    top = nodes[0]
    size -= 1
    key, node = keys[size], nodes[size]
    i = 0
    while True:
        c = 2 * i + 1
        if c >= size:
            break
        if c + 1 < size and _before(keys[c + 1], nodes[c + 1], keys[c], nodes[c]):
            c += 1
        if not _before(keys[c], nodes[c], key, node):
            break
        keys[i], nodes[i] = keys[c], nodes[c]
        i = c
    keys[i], nodes[i] = key, node
    return top, size


@njit
def _subdivide(items, vols, weights, origin, unit, depth, leaf, rule60, density, max_refs, max_bytes):
    """Centre subdivision, most items times area first (a heap); returns the raw tree and 0, or,
    when its arrays would grow past max_bytes (estimated at PEAK_NODE_BYTES a node and
    PEAK_REF_BYTES a reference, the flat copies included), the part built and the bytes needed.
    max_refs > 0 caps the references all leaves hold together."""
    n = items.shape[0]
    cap = 1024
    first = np.empty(cap, np.int64)
    count = np.empty(cap, np.int64)
    loc = np.empty((cap, 3), np.int64)
    level = np.empty(cap, np.int64)
    heap_key = np.empty(cap)
    heap_node = np.empty(cap, np.int64)
    lists = np.empty(max(16, 4 * n), np.int64)
    top_list = n
    for i in range(n):
        lists[i] = i
    # node 0: the root over every item
    first[0] = 0
    count[0] = n
    loc[0, 0] = loc[0, 1] = loc[0, 2] = 0
    level[0] = 0
    n_nodes = 1
    refs = n
    queued = _heap_push(heap_key, heap_node, 0, float(n), 0)
    child_n = np.zeros(8, np.int64)
    clo = np.empty((8, 3))
    chi = np.empty((8, 3))
    while queued > 0:
        node, queued = _heap_pop(heap_key, heap_node, queued)
        s = first[node]
        m = count[node]
        lv = level[node]
        if lv >= depth:
            continue
        w = 0
        for p in range(s, s + m):
            w += weights[lists[p]]
        if w <= leaf:
            continue
        half = np.int64(1) << (ADDRESS_BITS - 1 - lv)
        if density > 0.0:
            cell_vol = 1.0
            lo3 = np.empty(3)
            hi3 = np.empty(3)
            for a in range(3):
                lo3[a] = origin[a] + unit[a] * loc[node, a]
                hi3[a] = origin[a] + unit[a] * (loc[node, a] + 2 * half)
                cell_vol *= hi3[a] - lo3[a]
            filled = 0.0
            for p in range(s, s + m):
                it = lists[p]
                v = 1.0
                for a in range(3):
                    v *= max(0.0, min(hi3[a], vols[it, a + 3]) - max(lo3[a], vols[it, a]))
                filled += v
            if filled >= density * cell_vol:
                continue
        for c in range(8):
            for a in range(3):
                bit = (c >> a) & 1
                lo = loc[node, a] + bit * half
                clo[c, a] = origin[a] + unit[a] * lo
                chi[c, a] = origin[a] + unit[a] * (lo + half)
        # child lists after the used part of the list buffer, m slots each, packed below
        while top_list + 8 * m > lists.shape[0]:
            need = first.shape[0] * PEAK_NODE_BYTES + 2 * lists.shape[0] * PEAK_REF_BYTES
            if need > max_bytes:
                return first[:n_nodes], count[:n_nodes], loc[:n_nodes], level[:n_nodes], lists, need
            lists = grown(lists, 2 * lists.shape[0], top_list)
        for c in range(8):
            child_n[c] = 0
        for p in range(s, s + m):
            it = lists[p]
            for c in range(8):
                if overlaps(items, it, clo, chi, c):
                    lists[top_list + c * m + child_n[c]] = it
                    child_n[c] += 1
        held = 0
        biggest = 0
        occupied = 0
        for c in range(8):
            held += child_n[c]
            biggest = max(biggest, child_n[c])
            occupied += child_n[c] > 0
        if rule60 and biggest * 10 >= 6 * m and occupied > 1:
            continue
        if max_refs > 0 and refs + held - m > max_refs:
            continue            # the budget cannot pay for this split; a cheaper one may follow
        refs += held - m
        # pack the child lists (moving left never overwrites a list not yet moved)
        pos = top_list
        for c in range(8):
            src = top_list + c * m
            if src != pos:
                for j in range(child_n[c]):
                    lists[pos + j] = lists[src + j]
            pos += child_n[c]
        if n_nodes + 8 > first.shape[0]:
            new_cap = 2 * first.shape[0]
            need = new_cap * PEAK_NODE_BYTES + lists.shape[0] * PEAK_REF_BYTES
            if need > max_bytes:
                return first[:n_nodes], count[:n_nodes], loc[:n_nodes], level[:n_nodes], lists, need
            first, count = grown(first, new_cap, n_nodes), grown(count, new_cap, n_nodes)
            loc, level = grown(loc, new_cap, n_nodes), grown(level, new_cap, n_nodes)
            heap_key, heap_node = grown(heap_key, new_cap, queued), grown(heap_node, new_cap, queued)
        base = n_nodes
        n_nodes += 8
        pos = top_list
        for c in range(8):
            k = base + c
            first[k] = pos
            count[k] = child_n[c]
            pos += child_n[c]
            for a in range(3):
                loc[k, a] = loc[node, a] + ((c >> a) & 1) * half
            level[k] = lv + 1
            if child_n[c] > 0 and lv + 1 < depth:
                # a random ray crosses a child's box a quarter as often as its parent's
                queued = _heap_push(heap_key, heap_node, queued, child_n[c] * 0.25 ** (lv + 1), k)
        top_list = pos
        first[node] = base
        count[node] = -1
    return first[:n_nodes], count[:n_nodes], loc[:n_nodes], level[:n_nodes], lists, np.int64(0)


@njit
def _finish(first, count, loc, level, lists, collapse, origin, unit):
    """Collapse single-child chains, renumber the reachable nodes breadth first
    (children of a node together), gather the leaf lists, find the neighbours."""
    n = first.shape[0]
    if collapse:
        for node in range(n):
            while count[node] < 0:
                only = -1
                solid = 0
                for c in range(8):
                    k = first[node] + c
                    if count[k] != 0:
                        solid += 1
                        only = k
                if solid != 1:
                    break
                first[node] = first[only]
                count[node] = count[only]
                level[node] = level[only]
                for a in range(3):
                    loc[node, a] = loc[only, a]
    new_id = np.full(n, -1, np.int64)
    old = np.empty(n, np.int64)
    slot = np.zeros(n, np.int64)
    old[0] = 0
    new_id[0] = 0
    m = 1
    q = 0
    while q < m:
        node = old[q]
        q += 1
        if count[node] < 0:
            for c in range(8):
                k = first[node] + c
                new_id[k] = m
                old[m] = k
                slot[m] = level[node] + 1
                m += 1
    n_first = np.empty(m, np.int64)
    n_count = np.empty(m, np.int64)
    n_loc = np.empty((m, 3), np.int64)
    n_level = np.empty(m, np.int64)
    n_slot = slot[:m].copy()
    n_refs = 0
    for j in range(m):
        if count[old[j]] > 0:
            n_refs += count[old[j]]
    order = np.empty(n_refs, np.int64)
    r = 0
    for j in range(m):
        node = old[j]
        n_level[j] = level[node]
        for a in range(3):
            n_loc[j, a] = loc[node, a]
        if count[node] < 0:
            n_first[j] = new_id[first[node]]
            n_count[j] = -1
        else:
            n_first[j] = r
            n_count[j] = count[node]
            for p in range(first[node], first[node] + count[node]):
                order[r] = lists[p]
                r += 1
    bounds = np.empty((m, 6))
    for j in range(m):
        side = np.int64(1) << (ADDRESS_BITS - n_level[j])
        for a in range(3):
            bounds[j, a] = origin[a] + unit[a] * n_loc[j, a]
            bounds[j, a + 3] = origin[a] + unit[a] * (n_loc[j, a] + side)
    # neighbours: descend from the root to the adjacent slot of the same size
    nbr = np.full((m, 6), -1, np.int64)
    full = np.int64(1) << ADDRESS_BITS
    q3 = np.empty(3, np.int64)
    for j in range(1, m):
        sh = ADDRESS_BITS - n_slot[j]
        side = np.int64(1) << sh
        for wall in range(6):
            a = wall >> 1
            for k in range(3):
                q3[k] = (n_loc[j, k] >> sh) << sh
            q3[a] += side if wall & 1 else -side
            if q3[a] < 0 or q3[a] >= full:
                continue
            node = 0
            while n_count[node] < 0 and n_level[node] < n_slot[j]:
                bsh = ADDRESS_BITS - n_level[node]
                if ((q3[0] ^ n_loc[node, 0]) | (q3[1] ^ n_loc[node, 1]) | (q3[2] ^ n_loc[node, 2])) >> bsh != 0:
                    break
                bit = bsh - 1
                node = n_first[node] + ((q3[0] >> bit) & 1) + 2 * ((q3[1] >> bit) & 1) + 4 * ((q3[2] >> bit) & 1)
            nbr[j, wall] = node
    return n_first, n_count, n_loc, n_level, n_slot, nbr, bounds, order


@njit
def wall_quadtrees(first, count, nbr):
    """The walls of an octree built without collapse (see Walls): (walls (N, 6): nbr with every
    subdivided neighbour replaced by its wall quadtree's root, -2 - q; quads (Q, 4))."""
    walls = nbr.copy()
    quads = np.empty((64, 4), np.int64)
    todo_node = np.empty(64, np.int64)
    todo_quad = np.empty(64, np.int64)
    nq = 0
    for leaf in range(first.shape[0]):
        if count[leaf] < 0:
            continue
        for wall in range(6):
            s = nbr[leaf, wall]
            if s < 0 or count[s] >= 0:
                continue
            axis = wall >> 1
            near = 0 if wall & 1 else 1         # the half of the neighbour that faces the leaf
            u = 1 if axis == 0 else 0
            v = 1 if axis == 2 else 2
            quads = grown(quads, nq + 1, nq)
            walls[leaf, wall] = -2 - nq
            todo_node[0], todo_quad[0] = s, nq
            nq += 1
            top = 1
            while top > 0:
                top -= 1
                x, q = todo_node[top], todo_quad[top]
                for j in range(4):
                    y = first[x] + ((near << axis) | ((j & 1) << u) | ((j >> 1) << v))
                    if count[y] >= 0:
                        quads[q, j] = y
                        continue
                    quads = grown(quads, nq + 1, nq)
                    quads[q, j] = -2 - nq
                    todo_node = grown(todo_node, top + 1, top)
                    todo_quad = grown(todo_quad, top + 1, top)
                    todo_node[top], todo_quad[top] = y, nq
                    nq += 1
                    top += 1
    return walls, quads[:nq].copy()


def cell_margin(origin, extent, depth) -> np.ndarray:
    """(3,) how much item boxes grow when they are put in the cells of an octree over the box at
    `origin` of `extent`, `depth` levels deep (the parametric walk widens a node's box by the
    margin of its own level, no less: octwalk._node_margins)."""
    return 1e-9 * max(float(extent.max()), float(np.abs(origin).max())) + 1e-7 * (extent / float(1 << depth))


def octree_frame(bounds, depth, what):
    """The frame every octree (and lazy octree) builds in: item boxes as (n, 6), which of them
    are solid (finite, lo <= hi), the root's origin and 28-bit address unit, and the boxes
    widened by the margin cells get (an item without a box overlaps nothing)."""
    items = np.ascontiguousarray(np.asarray(bounds, np.float64)).reshape(-1, 6)
    solid = np.all(items[:, :3] <= items[:, 3:], axis=1) & np.all(np.isfinite(items), axis=1)
    if not solid.any():
        raise ValueError(f"{what} needs at least one item with a box")
    origin, extent = grid_box(items[solid])
    unit = extent / float(1 << ADDRESS_BITS)
    margin = cell_margin(origin, extent, depth)
    widened = np.hstack([items[:, :3] - margin, items[:, 3:] + margin])
    widened[~solid] = np.array([np.inf] * 3 + [-np.inf] * 3)
    return items, solid, origin, unit, widened


def build_octree(bounds, *, depth=16, leaf=3, rule60=False, density=0.0, vertexcount=False, weights=None,
                 collapse=True, budget=16.0, name=None, max_bytes=None):
    """Build an octree over item boxes (n >= 1 finite boxes; the empty box
    +inf..-inf is in no leaf). weights: per-item vertex counts, used against
    `leaf` when vertexcount is on. budget: the leaves hold at most budget * n
    + BUDGET_SLACK references (0: no limit). Returns (OctreeArrays, stats) with
    stats = {"nodes", "inner", "leaves", "empty_leaves", "refs", "bytes",
    "seconds", "max_depth", "budget_refs"} (budget_refs: the cap, 0 for none). max_bytes:
    the memory budget (memory.memory_limit() when None); a tree that would need more is a
    MemoryBudgetError."""
    t0 = time.perf_counter()
    number(depth, "octree depth", 0, MAX_DEPTH, integer=True)
    number(leaf, "octree leaf", 1, 1 << 30, integer=True)
    number(density, "octree density", 0.0, 1e6)
    number(budget, "octree budget", 0.0, 1e6)
    items, solid, origin, unit, widened = octree_frame(bounds, depth, "an octree")
    vols = np.where(solid[:, None], items, 0.0)
    if vertexcount and weights is not None:
        w = np.asarray(weights, np.int64)
    else:
        w = np.ones(len(items), np.int64)
    max_refs = int(float(budget) * len(items)) + BUDGET_SLACK if budget > 0 else 0
    limit = memory_limit() if max_bytes is None else int(max_bytes)
    first, count, loc, level, lists, need = _subdivide(widened, vols, w, origin, unit, int(depth), int(leaf),
                                                       bool(rule60), float(density), max_refs, limit)
    check(need, limit, f"the octree of group {name or '(unnamed)'}",
          "lower depth, raise leaf or give it a reference budget (budget=16)")
    if len(first) > MAX_NODES:
        raise SceneError(f"group {name or '(unnamed)'}: the octree has {len(first)} nodes, more than the limit "
                         f"of {MAX_NODES}; lower depth or raise leaf")
    first, count, loc, level, slot, nbr, nb, order = _finish(first, count, loc, level, lists, bool(collapse),
                                                             origin, unit)
    tree = OctreeArrays(origin, unit, first, count, loc, level, slot, nbr, nb, order)
    leaves = count >= 0
    stats = {
        "nodes": int(len(count)),
        "inner": int(np.count_nonzero(~leaves)),
        "leaves": int(np.count_nonzero(leaves)),
        "empty_leaves": int(np.count_nonzero(count == 0)),
        "refs": int(len(order)),
        "bytes": int(sum(a.nbytes for a in tree)),
        "seconds": time.perf_counter() - t0,
        "max_depth": int(level.max()),
        "budget_refs": int(max_refs),
    }
    return tree, stats

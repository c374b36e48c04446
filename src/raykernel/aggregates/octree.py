"""Octree (Glassner 1984) over axis-aligned item boxes, as flat arrays.

    tree, stats = build_octree(item_bounds)            # the defaults: depth=16, leaf=3, budget=16
    # tree.first, tree.count, tree.loc, tree.level, tree.slot, tree.nbr, tree.bounds, tree.order
    items_of_leaf = tree.order[tree.first[n]:tree.first[n] + tree.count[n]]

Flat layout (the Geometry fields it owns)
-----------------------------------------
ON nodes of all octrees, O octrees:
  oct_bounds   (ON, 6) float64  node box                                        48 B a node
  oct_first    (ON,)   int64    inner: first of 8 children (global); leaf: first ref   8 B
  oct_count    (ON,)   int64    refs in a leaf; -1 for an inner node            8 B
  oct_loc      (ON, 3) int64    lower 28-bit address of the node's box         24 B
  oct_level    (ON,)   int64    level of the node's box                         8 B
  oct_slot     (ON,)   int64    level of the octant the node occupies in its parent   8 B
  oct_nbr      (ON, 6) int64    neighbour across -x, +x, -y, +y, -z, +z (global), -1: none   48 B
  oct_pass     (ON,)   int64    lazy octree leaf that may split: its pass counter column, else -1   8 B
  oct_root     (O,)    int64    root node                                       8 B an octree
  oct_origin   (O, 3)  float64  lower corner of the root box                   24 B
  oct_unit     (O, 3)  float64  side of one address unit                       24 B
  oct_scale    (O, 3)  float64  1 / oct_unit                                   24 B
  oct_walk     (O,)    int64    0 point, 1 neighbor, 2 parametric, 3 wall       8 B
  oct_quad     (Q, 4)  int64    wall quadtree nodes (walk=wall; see Walls)     32 B a quad node
  oct_mailbox  (O,)    int64    1: skip refs already tested in an earlier leaf  8 B
The aggregate's agg_start is its octree index. The point and neighbor walks
keep the address of the point they go on from in their frame (POINT).

Root box and addresses
----------------------
The root box is the union of the item boxes, with flat axes padded as the
uniform grid pads them (grid.grid_box). It is not made cubic: every cell is a
scaled copy of the root box, so a flat or long scene is not wrapped in mostly
empty space, and Lathrop's integer addressing works per axis anyway. Each
axis of the root box is mapped to integer addresses [0, 2**28); a node at
level L spans 2**(28 - L) addresses per axis, and bit 27 - L of a point's
address picks the child octant (bit 0 of the octant: x, bit 1: y, bit 2: z).
Every box coordinate is computed as ``origin + unit * address`` (unit =
side / 2**28), so neighbouring cells share bit-identical walls.

Subdivision (centre split, objects go into every child their box overlaps,
closed intervals, boxes widened by a tiny margin as in the grid)
------------------------------------------------------------------------------
A node is a leaf when any of these holds:
  * its level is ``depth``;
  * it holds at most ``leaf`` items, counting polygon/patch vertices and 3 per
    triangle instead of 1 when ``vertexcount`` is on (Glassner's measure);
  * ``density`` > 0 and the summed volume of its items' boxes clipped to the
    cell, over the cell volume, is at least ``density`` (Glassner's criterion:
    subdivide only while the cell is sparsely filled);
  * ``rule60`` is on and the largest child list would still hold at least 60%
    of the node's items (Haines's problem-voxel rule), unless that child is
    the only occupied one: items that all fall into one octant are separated
    by splitting further (a small cluster in a big box, the teapot in a
    stadium), and collapse removes the chain this makes;
  * ``budget`` > 0 and splitting it would take the references held by all
    leaves past ``budget`` times the item count, plus 4096.

Nodes are split in order of items times the surface area of their box (the
number of items a random ray crossing the box would meet), the largest
first, ties by node number. Without a budget the order changes nothing (each
criterion looks at one node only); with one, the references go where rays
meet the most items: a crowded cell near the root before the neighbourhood
of a shared vertex deep down. A split the budget cannot pay for is skipped
and cheaper ones may still follow, so the result is deterministic.

Defaults, and why
-----------------
depth=16, leaf=3, budget=16, rule60 off, density off, collapse on. Items that
no split separates (the triangles around a shared mesh vertex, spheres that
overlap each other) keep a node above ``leaf`` at every level, so depth and
leaf alone let the tree grow as 8**depth around them: at the old defaults
(depth 8, no budget) SPD shells (overlapping spheres) took gigabytes and
minutes to build, and meshes such as tetra and sample hundreds to thousands
of references per item. The budget keeps memory proportional to the item
count (fewer nodes than references), so the depth limit can be deep enough
for a small cluster in a big box: at the stadium's default ratio the teapot
is resolved many levels down, with far fewer tests per ray than the old
defaults made (the tree scene gains too). The price is paid on meshes, whose
finest cells the old octree could afford only by the hundreds of references
per item: tetra, sample and gears test more items per ray; budget=32
narrows the gap for up to twice the memory. At a ratio of 10**6 the
teapot lies in one deep cell with the field; no budget or depth fixes that,
a BVH nested around the teapot does (see pathological.stadium, teapot_bvh).
rule60 stays off: wherever a large floor or backdrop polygon reaches into
the other octants it stops the subdivision within a few levels (SPD balls
and teapot stay shallow trees that test many times more items per ray).
bench/structures.py measures these variants (docs/benchmarks/structures.md,
"Octree criteria and traversals").

Collapse
--------
With ``collapse`` on, an inner node with exactly one non-empty child takes
that child's subtree, and its box shrinks to the child's box; repeated, this
removes whole chains. Each node keeps its *slot* (the octant of its parent
it occupies, level ``slot``) next to its own box (level ``level``, lower
address ``loc``). A point inside a slot but outside the node's box lies in an
empty octant the collapse removed: the walks find it from the address bits
and step through it as an empty leaf (see traverse.py).

Neighbours
----------
``nbr[n, 2 * axis + (1 if towards +axis else 0)]`` is the node whose slot is
adjacent to n's slot across that wall and of equal or larger size (the
deepest such node), or -1 on the root's boundary.

Walls (walk=wall)
-----------------
Glassner's answer to a ray leaving a cell into smaller ones (Haines reports it
in RTN 1(2), 1988: "quadtree-like structures on the cube faces of the octree
cubes"; Kaplan's faces "immediately access the next voxel"): across a wall
whose neighbour of the leaf's size is subdivided, a quadtree of the cells
behind that wall. Its nodes are the neighbour's inner nodes that touch the
wall, each with the four children on the wall's side, in order of their bits
on the wall's two axes (lower axis first); a child is a leaf (its node) or the
next quad node (tagged -2 - q). A wall-walk octree keeps these in nbr itself:
the leaf's node when the neighbour is a leaf, -2 - q when it is subdivided,
-1 at the root's boundary. The walk leaves a leaf across its nearest wall and
reaches the next leaf from that wall alone: no descent from the root (point)
and no descent in three dimensions from the neighbour (neighbor), two address
bits of the exit point a quad level, counted as octree.wall_steps (the leaves
themselves count as cells.visited). Built without collapse: the quadtrees
index the octants themselves.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np

from ..errors import SceneError
from ..geometry import counters as C
from ..geometry.boxes import CONSERVATIVE, INF, STILL, slab
from ..geometry.config import njit
from ..geometry.counters import own_columns
from ..options import number
from .grid import grid_box
from .memory import check, grown, memory_limit
from .spec import Kind, Param, Search
from .walk import F_STATE, FI_AGG, START, Cells, Field, Walk, answer, entry_tag, mailbox_reset, note_visit, push

__all__ = ["OctreeArrays", "build_octree", "ADDRESS_BITS", "MAX_DEPTH"]

ADDRESS_BITS = 28
TRAVERSALS = ("point", "neighbor", "parametric", "wall")   # oct_walk codes 0, 1, 2, 3
POINT_WALK, NEIGHBOR_WALK, PARAMETRIC_WALK, WALL_WALK = 0, 1, 2, 3
MAX_DEPTH = 24             # the parametric walk keeps up to 3 siblings per level on the kernel's stack
MAX_NODES = 20_000_000
BUDGET_SLACK = 4096        # references a budget allows on top of budget * items (small scenes stay free)
PEAK_NODE_BYTES = 512      # memory a node takes at the peak of a build: the builder's arrays, the flat ones, copies
PEAK_REF_BYTES = 32        # the same for a reference


class OctreeArrays(NamedTuple):
    """An octree as flat arrays; see the module docstring. Node 0 is the root;
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
    margin of its own level, no less: _node_margins)."""
    return 1e-9 * max(float(extent.max()), float(np.abs(origin).max())) + 1e-7 * (extent / float(1 << depth))


@njit(inline="always")
def _node_margins(oct_origin, oct_unit, oi, level):
    """cell_margin on each axis for a node at `level` of octree oi: at least the items' margin,
    whose depth is the node's or deeper."""
    big = 0.0
    for k in range(3):
        big = max(big, max(oct_unit[oi, k] * float(1 << ADDRESS_BITS), abs(oct_origin[oi, k])))
    size = float(np.int64(1) << (ADDRESS_BITS - level))
    return (1e-9 * big + 1e-7 * oct_unit[oi, 0] * size, 1e-9 * big + 1e-7 * oct_unit[oi, 1] * size,
            1e-9 * big + 1e-7 * oct_unit[oi, 2] * size)


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


# ----------------------------------------------------------------- flat layout (see the module docstring) and walk


CODE = 3
FIELDS = (
    Field("oct_bounds", np.float64, (6,)), Field("oct_first", np.int64, ()), Field("oct_count", np.int64, ()),
    Field("oct_loc", np.int64, (3,)), Field("oct_level", np.int64, ()), Field("oct_slot", np.int64, ()),
    Field("oct_nbr", np.int64, (6,)), Field("oct_pass", np.int64, ()), Field("oct_root", np.int64, ()),
    Field("oct_origin", np.float64, (3,)), Field("oct_unit", np.float64, (3,)), Field("oct_scale", np.float64, (3,)),
    Field("oct_walk", np.int64, ()), Field("oct_mailbox", np.int64, ()), Field("oct_quad", np.int64, (4,)),
)
# its own counter: the wall quadtrees' nodes the wall walk went through (cost model: not priced)
COUNTERS = (("octree.wall_steps", None),)
WALL_STEPS, = own_columns(CODE, len(COUNTERS))
NEXT = 1        # step: go on with the point/neighbor walk by descending from node stack_a
PARAM = 2       # step: the parametric walk visits node stack_a, entered at stack_t
PASS = 3        # step: a lazy octree leaf left at stack_t without a closer hit: count a pass in
#                 cnt[N_COUNTERS + stack_a] (aggregates/lazyoctree.py)
POINT = F_STATE
FULL = 1 << ADDRESS_BITS


def append_octree(flat, tree: OctreeArrays, refs, walk: str, mailbox: bool, box) -> int:
    """Store a built octree whose leaves hold refs[tree.order] as the next aggregate."""
    n0 = flat.size("oct_count")
    first_ref = flat.add_refs(refs[tree.order])
    inner = tree.count < 0
    o = flat.size("oct_root")
    nbr = tree.nbr
    if walk == TRAVERSALS[WALL_WALK]:
        nbr, quads = wall_quadtrees(tree.first, tree.count, tree.nbr)
        q0 = flat.size("oct_quad")
        flat.append(oct_quad=np.where(quads >= 0, quads + n0, quads - q0))
        nbr = np.where(nbr >= 0, nbr + n0, np.where(nbr <= -2, nbr - q0, -1))
    else:
        nbr = np.where(nbr >= 0, nbr + n0, -1)
    flat.append(oct_bounds=tree.bounds, oct_first=np.where(inner, tree.first + n0, tree.first + first_ref),
                oct_count=tree.count, oct_loc=tree.loc, oct_level=tree.level, oct_slot=tree.slot, oct_nbr=nbr,
                oct_pass=np.full(len(tree.count), -1), oct_root=[n0], oct_origin=tree.origin[None],
                oct_unit=tree.unit[None], oct_scale=1.0 / tree.unit[None], oct_walk=[TRAVERSALS.index(walk)],
                oct_mailbox=[int(mailbox)])
    return flat.add_aggregate(CODE, o, len(tree.count), box)


@njit(inline="always")
def _cell_slab(lo, hi, o, inv, top):
    """slab for an octree cell: a still ray on the wall between two cells is in the upper
    one only, as a point's address puts it (the items there are in both), unless the wall is
    the octree's upper wall `top`."""
    if inv == STILL:
        if lo <= o and (o < hi or o == top):
            return -INF, INF
        return INF, -INF
    return slab(lo, hi, o, inv)


@njit(inline="always")
def _address(x, origin, scale, lo, hi):
    """The octree address of coordinate x, clamped to [lo, hi]."""
    u = (x - origin) * scale
    q = np.int64(u) if u >= 0.0 and u < FULL else (np.int64(FULL - 1) if u >= FULL else np.int64(0))
    return min(max(q, lo), hi)


@njit(inline="always")
def walk_step(geo, step, a, te, ray, lo, best_t, f, sp, ws, cnt):
    """walk.py's step contract: the octree's walk (oct_walk) from its START, NEXT or PARAM entries."""
    sp, s, e = octree_step(geo.oct_bounds, geo.oct_count, geo.oct_first, geo.oct_level, geo.oct_loc, geo.oct_mailbox,
                           geo.oct_nbr, geo.oct_origin, geo.oct_pass, geo.oct_quad, geo.oct_root, geo.oct_scale,
                           geo.oct_slot, geo.oct_unit, geo.oct_walk, step, a, te, geo.agg_start[ws.frame_i[f, FI_AGG]],
                           ray, lo, best_t, ws.frame_f, f, ws, sp, cnt)
    return answer(sp, s, e, ray, best_t)


@njit(inline="always")   # the choice of walk only: the walks are compiled apart (their IR inlined would add a lot of compile time)
def octree_step(oct_bounds, oct_count, oct_first, oct_level, oct_loc, oct_mailbox, oct_nbr, oct_origin, oct_pass,
                oct_quad, oct_root, oct_scale, oct_slot, oct_unit, oct_walk, kind_step, a, te, oi, ray, tmin, best_t,
                frame_f, f, ws, sp, cnt):
    """One step of octree `oi`'s walk (ws: the workspace, its stack and work); returns (sp, s, e), the references of the next
    non-empty leaf (none: s == e).

    point (Lathrop): the leaf holding a point is found from the root by the point's
    28-bit address, its exit distance computed, and the point moved just past the exit
    wall. neighbor: the same, but the next descent starts from the neighbour across the
    exit wall (Glassner's pointers). wall: the next leaf is found from the exit wall alone, down
    its wall quadtree (Walls, above). All three put a NEXT entry back before a non-empty leaf's
    references. A point outside a collapsed node's shrunk box lies in an empty octant the
    collapse removed; its address bits give that octant, visited as an empty leaf.
    parametric (Revelles et al. 2000): PARAM entries with their entry distance, the
    children a ray crosses pushed farthest first. A lazy octree's candidate leaf gets a
    PASS entry at its exit distance above the walk's continuation. ray: (ox, oy, oz, dx, dy,
    dz, ix, iy, iz), one argument so that the call stays under 30 (CPython passes longer
    calls as *args, which numba cannot inline)."""
    if kind_step == PASS:
        if te <= best_t:
            cnt[C.N_COUNTERS + a] += 1
        return sp, 0, 0
    if te > best_t:
        return sp, 0, 0
    if kind_step == START and oct_mailbox[oi] != 0:
        mailbox_reset(frame_f, f)
    if kind_step == PARAM or (kind_step == START and oct_walk[oi] == PARAMETRIC_WALK):
        return _parametric(oct_bounds, oct_count, oct_first, oct_level, oct_loc, oct_origin, oct_pass, oct_root,
                           oct_unit, a if kind_step == PARAM else oct_root[oi], oi,
                           ray, tmin, best_t, ws.stack_a, ws.stack_b, ws.stack_t, sp, cnt, ws.work)
    return _point_walk(oct_count, oct_first, oct_level, oct_loc, oct_nbr, oct_origin, oct_pass, oct_quad, oct_root,
                       oct_scale, oct_slot, oct_unit, oct_walk, kind_step, a, te, oi,
                       ray, best_t, frame_f, f, ws.stack_a, ws.stack_b, ws.stack_t, sp, cnt, ws.work)


@njit(private=True)
def _parametric(oct_bounds, oct_count, oct_first, oct_level, oct_loc, oct_origin, oct_pass, oct_root, oct_unit,
                node, oi, ray, tmin, best_t,
                stack_a, stack_b, stack_t, sp, cnt, work):
    ox, oy, oz, _, _, _, ix, iy, iz = ray
    # Revelles, Urena and Lastra 2000: node parameters with the ray reflected
    # onto positive directions (amask: the reflected axes)
    while True:
        cnt[C.CELLS_VISITED] += 1
        note_visit(work, CODE, node)
        cnt[C.BOUNDS_TESTS] += 1
        nb = oct_bounds
        top = oct_root[oi]
        amask = 0
        # the node's box widened by the margin its items got, so that a ray meeting an item within
        # it (through an edge on the node's wall, rounded by an instance's map) meets the node too
        mx, my, mz = _node_margins(oct_origin, oct_unit, oi, oct_level[node])
        if ix >= 0.0:
            tx0, tx1 = _cell_slab(nb[node, 0] - mx, nb[node, 3] + mx, ox, ix, nb[top, 3] + mx)
        else:
            tx0, tx1 = (nb[node, 3] + mx - ox) * ix, (nb[node, 0] - mx - ox) * ix
            amask |= 1
        if iy >= 0.0:
            ty0, ty1 = _cell_slab(nb[node, 1] - my, nb[node, 4] + my, oy, iy, nb[top, 4] + my)
        else:
            ty0, ty1 = (nb[node, 4] + my - oy) * iy, (nb[node, 1] - my - oy) * iy
            amask |= 2
        if iz >= 0.0:
            tz0, tz1 = _cell_slab(nb[node, 2] - mz, nb[node, 5] + mz, oz, iz, nb[top, 5] + mz)
        else:
            tz0, tz1 = (nb[node, 5] + mz - oz) * iz, (nb[node, 2] - mz - oz) * iz
            amask |= 4
        ot0 = max(max(tx0, ty0), tz0)
        ot1 = min(min(tx1, ty1), tz1)
        if ot0 > (ot1 * CONSERVATIVE if ot1 > 0.0 else ot1) or ot1 < tmin or ot0 > best_t:
            return sp, 0, 0     # a collapsed node's shrunk box the ray misses
        n_items = oct_count[node]
        if n_items >= 0:
            cnt[C.CELLS_LEAVES] += 1
            if n_items == 0:
                cnt[C.CELLS_EMPTY] += 1
                return sp, 0, 0
            s = oct_first[node]
            col = oct_pass[node]
            if col >= 0 and C.N_COUNTERS + col < cnt.shape[0]:
                sp = push(stack_a, stack_b, stack_t, sp, col, entry_tag(CODE, PASS), ot1)
            return sp, s, s + n_items
        # the centre planes
        half = np.int64(1) << (ADDRESS_BITS - 1 - oct_level[node])
        txm = (oct_origin[oi, 0] + oct_unit[oi, 0] * (oct_loc[node, 0] + half) - ox) * ix
        tym = (oct_origin[oi, 1] + oct_unit[oi, 1] * (oct_loc[node, 1] + half) - oy) * iy
        tzm = (oct_origin[oi, 2] + oct_unit[oi, 2] * (oct_loc[node, 2] + half) - oz) * iz
        # first child (their table 1): entry plane, then the centre planes crossed before it
        cur = 0
        if tx0 >= ty0 and tx0 >= tz0:
            cur = (2 if tym < tx0 else 0) | (4 if tzm < tx0 else 0)
        elif ty0 >= tz0:
            cur = (1 if txm < ty0 else 0) | (4 if tzm < ty0 else 0)
        else:
            cur = (1 if txm < tz0 else 0) | (2 if tym < tz0 else 0)
        child0 = oct_first[node]
        sp0 = sp
        tag = entry_tag(CODE, PARAM)
        while True:
            # child interval per axis: [t0, tm] below the centre plane, [tm, t1] above
            cx0, cx1 = (txm, tx1) if cur & 1 else (tx0, txm)
            cy0, cy1 = (tym, ty1) if cur & 2 else (ty0, tym)
            cz0, cz1 = (tzm, tz1) if cur & 4 else (tz0, tzm)
            centry = max(max(cx0, cy0), cz0)
            if centry > best_t:
                break
            if min(min(cx1, cy1), cz1) >= tmin:
                sp = push(stack_a, stack_b, stack_t, sp, child0 + (cur ^ amask), tag, centry)
            # next child (their table 3): across the nearest exit plane; the node's own wall ends it
            if cx1 <= cy1 and cx1 <= cz1:
                if cur & 1:
                    break
                cur |= 1
            elif cy1 <= cz1:
                if cur & 2:
                    break
                cur |= 2
            else:
                if cur & 4:
                    break
                cur |= 4
        # nearest child on top
        lo_i, hi_i = sp0, sp - 1
        while lo_i < hi_i:
            stack_a[lo_i], stack_a[hi_i] = stack_a[hi_i], stack_a[lo_i]
            stack_t[lo_i], stack_t[hi_i] = stack_t[hi_i], stack_t[lo_i]
            lo_i += 1
            hi_i -= 1
        if sp == sp0:
            return sp, 0, 0
        # go on with the nearest child at once (its entry is within best_t), as the driver would
        sp -= 1
        node = stack_a[sp]


@njit(inline="always")
def _across_wall(oct_nbr, oct_quad, leaf, axis, up, level, px, py, pz):
    """The leaf behind `leaf`'s wall on `axis` (towards +axis if up), where the point p (its
    address, just past the wall) lies: down the wall's quadtree by p's two address bits on the
    wall's axes a level; -1 at the root's boundary. Returns (node, quad levels gone down)."""
    entry = oct_nbr[leaf, 2 * axis + (1 if up else 0)]
    pu = py if axis == 0 else px
    pv = pz if axis != 2 else py
    steps = 0
    while entry <= -2:
        bit = ADDRESS_BITS - 1 - level
        entry = oct_quad[-2 - entry, ((pu >> bit) & 1) + 2 * ((pv >> bit) & 1)]
        level += 1
        steps += 1
    return entry, steps


@njit(private=True)
def _point_walk(oct_count, oct_first, oct_level, oct_loc, oct_nbr, oct_origin, oct_pass, oct_quad, oct_root,
                oct_scale, oct_slot, oct_unit, oct_walk, kind_step, a, te, oi, ray, best_t, frame_f, f, stack_a,
                stack_b, stack_t, sp, cnt, work):
    ox, oy, oz, dx, dy, dz, ix, iy, iz = ray
    # point (Lathrop) or neighbor (Glassner): find the leaf holding the point p
    # by its 28-bit address, leave it across its nearest wall, repeat
    walk = oct_walk[oi]
    gox, goy, goz = oct_origin[oi, 0], oct_origin[oi, 1], oct_origin[oi, 2]
    gux, guy, guz = oct_unit[oi, 0], oct_unit[oi, 1], oct_unit[oi, 2]
    gsx, gsy, gsz = oct_scale[oi, 0], oct_scale[oi, 1], oct_scale[oi, 2]
    top = np.int64(FULL - 1)
    if kind_step == START:
        px = _address(ox + te * dx, gox, gsx, 0, top)
        py = _address(oy + te * dy, goy, gsy, 0, top)
        pz = _address(oz + te * dz, goz, gsz, 0, top)
        node = oct_root[oi]
    else:
        px = np.int64(frame_f[f, POINT])
        py = np.int64(frame_f[f, POINT + 1])
        pz = np.int64(frame_f[f, POINT + 2])
        node = a
    while True:
        # descend from node; it stays the container of the cell found
        leaf = np.int64(-1)
        while True:
            cnt[C.CELLS_VISITED] += 1
            note_visit(work, CODE, node)
            sh = ADDRESS_BITS - oct_level[node]
            lx, ly, lz = oct_loc[node, 0], oct_loc[node, 1], oct_loc[node, 2]
            diff = (px ^ lx) | (py ^ ly) | (pz ^ lz)
            if diff >> sh != 0:
                # p lies in an empty octant a collapse removed: the one its highest
                # differing address bit selects
                sh = 0
                while diff >> (sh + 1) != 0:
                    sh += 1
                break
            if oct_count[node] >= 0:
                leaf = node
                break
            bit = sh - 1
            node = oct_first[node] + ((px >> bit) & 1) + 2 * ((py >> bit) & 1) + 4 * ((pz >> bit) & 1)
        side = np.int64(1) << sh
        clx, cly, clz = (px >> sh) << sh, (py >> sh) << sh, (pz >> sh) << sh
        cnt[C.CELLS_LEAVES] += 1
        if leaf >= 0 and oct_count[leaf] > 0:
            s = oct_first[leaf]
            e = s + oct_count[leaf]
        else:
            s = e = 0
            cnt[C.CELLS_EMPTY] += 1
        # leave the cell across its nearest wall
        cnt[C.BOUNDS_TESTS] += 1
        tx = (gox + gux * (clx + side) - ox) * ix if dx > 0.0 else \
            ((gox + gux * clx - ox) * ix if dx < 0.0 else INF)
        ty = (goy + guy * (cly + side) - oy) * iy if dy > 0.0 else \
            ((goy + guy * cly - oy) * iy if dy < 0.0 else INF)
        tz = (goz + guz * (clz + side) - oz) * iz if dz > 0.0 else \
            ((goz + guz * clz - oz) * iz if dz < 0.0 else INF)
        axis = 0 if tx <= ty and tx <= tz else (1 if ty <= tz else 2)
        texit = min(min(tx, ty), tz)
        out = texit == INF
        # the point just past the exit: across the wall on the exit axis, in the cell on the others
        px = _address(ox + texit * dx, gox, gsx, clx, clx + side - 1)
        py = _address(oy + texit * dy, goy, gsy, cly, cly + side - 1)
        pz = _address(oz + texit * dz, goz, gsz, clz, clz + side - 1)
        if axis == 0:
            px = clx + side if dx > 0.0 else clx - 1
            out = out or px < 0 or px > top
            pa = px
        elif axis == 1:
            py = cly + side if dy > 0.0 else cly - 1
            out = out or py < 0 or py > top
            pa = py
        else:
            pz = clz + side if dz > 0.0 else clz - 1
            out = out or pz < 0 or pz > top
            pa = pz
        if walk == POINT_WALK:
            node = oct_root[oi]
        elif walk == WALL_WALK:
            if not out:
                up = (dx > 0.0) if axis == 0 else ((dy > 0.0) if axis == 1 else (dz > 0.0))
                node, steps = _across_wall(oct_nbr, oct_quad, leaf, axis, up, oct_level[leaf], px, py, pz)
                cnt[WALL_STEPS] += steps
                out = node < 0
        elif not out:
            # still inside the container's slot, or across its wall to the neighbour
            ssh = ADDRESS_BITS - oct_slot[node]
            if pa >> ssh != oct_loc[node, axis] >> ssh:
                up = (dx > 0.0) if axis == 0 else ((dy > 0.0) if axis == 1 else (dz > 0.0))
                node = oct_nbr[node, 2 * axis + (1 if up else 0)]
                out = node < 0
        if s == e:
            if out or texit > best_t:
                return sp, 0, 0
            continue
        if not out:
            # come back for the next leaf after this one's references
            frame_f[f, POINT], frame_f[f, POINT + 1], frame_f[f, POINT + 2] = px, py, pz
            sp = push(stack_a, stack_b, stack_t, sp, node, entry_tag(CODE, NEXT), texit)
        col = oct_pass[leaf]
        if col >= 0 and C.N_COUNTERS + col < cnt.shape[0]:
            # a lazy octree's candidate leaf: see whether the ray leaves it without a hit
            sp = push(stack_a, stack_b, stack_t, sp, col, entry_tag(CODE, PASS), texit)
        return sp, s, e


def flatten(builder, params, refs, bounds, name, box):
    weights = builder.vertex_weights(refs) if params["vertexcount"] else None
    collapse = params["collapse"] and params["walk"] != TRAVERSALS[WALL_WALK]     # walls index the octants
    tree, stats = build_octree(bounds, depth=params["depth"], leaf=params["leaf"], rule60=params["rule60"],
                               density=params["density"], vertexcount=params["vertexcount"], weights=weights,
                               collapse=collapse, budget=params["budget"], name=name,
                               max_bytes=builder.max_bytes)
    return append_octree(builder.flat, tree, refs, params["walk"], params["mailbox"], box), dict(stats)


def stats_rows(stats) -> list:
    """Its rows of the statistics table (rendering/stats.py): the wall walk's quadtree steps."""
    n = stats.get("octree.wall_steps", 0)
    if not n:
        return []
    leaves = max(1, stats.get("cells.leaves", 0))
    return [("octree", "wall steps", f"{n:,}", f"{n / leaves:.2f} wall quadtree levels per leaf reached")]


def cells(geo, a) -> Cells:
    """The tree's nodes, level by level from the root (Walk.cells)."""
    level, found, depths = np.array([geo.oct_root[geo.agg_start[a]]], np.int64), [], []
    depth = 0
    while len(level):
        found.append(level)
        depths.append(np.full(len(level), depth, np.int64))
        first = geo.oct_first[level[geo.oct_count[level] < 0]]
        level = (first[:, None] + np.arange(8)).ravel()
        depth += 1
    nodes = np.concatenate(found)
    leaf = geo.oct_count[nodes] >= 0
    b = geo.oct_bounds[nodes]
    return Cells(b[:, :3], b[:, 3:], np.concatenate(depths), np.where(leaf, geo.oct_first[nodes], 0),
                 np.where(leaf, geo.oct_count[nodes], -1), nodes)


WALK = Walk(code=CODE, name="octree", fields=FIELDS, step=walk_step, counters=COUNTERS, stats_rows=stats_rows,
            cells=cells, keys="oct_count")
KIND = Kind("octree", "octree (Glassner 1984): centre subdivision of the scene box (not made cubic), "
              "objects in every child their box overlaps; nodes with the most items times box area are split "
              "first, until depth, leaf, the criteria or the reference budget stop them. Defaults: depth 16 and "
              "budget 16 keep memory proportional to the items (without a budget, items no split separates grow "
              "the tree as 8^depth: gigabytes on SPD shells at depth 8) "
              "while small clusters in big boxes still get resolved; rule60 stays off, as it stops subdivision "
              "early wherever a large floor polygon reaches into the other octants", (
    Param("depth", 16, "maximum subdivision depth (the root is level 0)", int, 0, 24),
    Param("leaf", 3, "a node holding at most this many items (or vertices, see vertexcount) is a leaf", int, 1,
          1 << 20),
    Param("rule60", False, "Haines's problem-voxel rule: keep a node a leaf when its largest child would "
          "still hold >= 60% of its items (unless it is the only occupied child)", bool),
    Param("density", 0.0, "Glassner's density criterion: subdivide only while the items' volume clipped to "
          "the cell, over the cell volume, is under this ratio (0: off)", float, 0.0, 1e6),
    Param("vertexcount", False, "count polygon/patch vertices and 3 per triangle instead of items against "
          "leaf (Glassner's measure)", bool),
    Param("collapse", True, "a node with one non-empty child takes that child's subtree and box; the walks "
          "step through the removed empty octants using the address bits", bool),
    Param("walk", "neighbor", "traversal: point (top-down point location with Lathrop's 28-bit addresses), "
          "neighbor (Glassner's 6 neighbour pointers per node, then descent), parametric (Revelles, Urena and "
          "Lastra 2000), wall (Glassner's wall quadtrees: the next leaf found from the exit wall alone; builds "
          "without collapse)", str, choices=TRAVERSALS),
    Param("mailbox", True, "skip items already tested against the ray in an earlier leaf", bool),
    Param("budget", 16.0, "the leaves together hold at most budget * items + 4096 references; a split that "
          "would exceed it is skipped (0: no limit)", float, 0.0, 1e6),
), flatten=flatten, walk=WALK, search=Search(start=True, candidates=("octree", "octree(depth=8)", "octree(leaf=8)")))

"""Haines's trick 6: start lists for rays that leave an object, from the object's place in its BVH.

    starts = prepare(geo)                   # once per render: every BVH's parents, each primitive's leaf
    row = start_list(ref, starts, geo, table, tick, cnt)   # in a kernel: the list, from the LRU table

A reflection, refraction or shadow ray leaving primitive O most often meets, if anything, O's
neighbours. O's start list holds up to LIST_SIZE primitives: the others in O's leaf, then those
of the sibling subtree of each ancestor in turn, walking up the tree (near the leaf first).
Lists are built when first asked for and kept in a per-tile table of TABLE_SETS x TABLE_WAYS
lists (the budget, 44 KB): a set-associative cache keyed by the primitive, the least recently
used list of a set making room for a new one. A ray leaving O tests its list first (through the
map of the frame O was hit in, which its neighbours share); the nearest hit bounds the ray's
search, and any opaque hit well inside a shadow ray settles it (tricks.py). Only primitives
referenced from exactly one BVH leaf have a list (not those of other kinds of aggregate, or
below CSG nodes, whose primitives alone are not the solid). Counted: start_lists.used (rays
that tested a list), start_lists.hits (searches it bounded or shadow rays it settled),
start_lists.built (lists built, evictions included).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..aggregates import bvhwalk
from ..geometry import counters as C
from ..geometry.config import njit
from ..geometry.primitives import AGGREGATE, INDEX_MASK, KIND_SHIFT

LIST_SIZE = 8
TABLE_SETS, TABLE_WAYS = 128, 4
TABLE_COLUMNS = 3 + LIST_SIZE       # key (the primitive's ref, -1: empty), last use, length, refs
WALK_STACK = 64


class Starts(NamedTuple):
    prim_offset: np.ndarray     # (6,) int64: where each primitive kind's rows begin in prim_leaf
    prim_leaf: np.ndarray       # (P,) int64: the BVH leaf that holds each primitive, -1: none (or several)
    node_parent: np.ndarray     # (N,) int64: each BVH node's parent, -1 for roots and non-BVH nodes


def prepare(geo, used: bool = True) -> Starts:
    """The arrays start_list reads; used False: empty ones (no primitive has a list)."""
    counts = [len(geo.sph_radius), len(geo.poly_count), len(geo.poly_count), len(geo.cone_length),
              len(geo.tri_faces)]
    offset = np.zeros(6, np.int64)
    offset[1:] = np.cumsum(counts)
    leaf = np.full(max(1, int(offset[-1])), -1, np.int64)
    parent = np.full(max(1, len(geo.node_count)), -1, np.int64)
    if not used:
        return Starts(offset, leaf, parent)
    for a in np.flatnonzero(geo.agg_kind == bvhwalk.CODE):
        root, size = int(geo.agg_start[a]), int(geo.agg_count[a])
        nodes = np.arange(root, root + size)
        first, count = geo.node_first[nodes], geo.node_count[nodes]
        inner = (count == 0) & (first > nodes) & (first < root + size)
        parent[first[inner]] = nodes[inner]
        parent[first[inner] + 1] = nodes[inner]
        # every reference slot of every leaf, with its leaf
        leaves, n = nodes[count > 0], count[count > 0]
        slots = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n) + np.repeat(geo.node_first[leaves], n)
        refs, owner = geo.refs[slots], np.repeat(leaves, n)
        prim = (refs >> KIND_SHIFT) < AGGREGATE
        rows = offset[refs[prim] >> KIND_SHIFT] + (refs[prim] & INDEX_MASK)
        leaf[rows] = np.where(leaf[rows] == -1, owner[prim], -2)
        # a primitive in two leaves (two BVHs over it) gets no list: which one it was hit in is unknown
        seen, times = np.unique(rows, return_counts=True)
        leaf[seen[times > 1]] = -2
    leaf[leaf == -2] = -1
    return Starts(offset, leaf, parent)


@njit
def table():
    """An empty start-list table for one tile."""
    out = np.zeros((TABLE_SETS * TABLE_WAYS, TABLE_COLUMNS), np.int64)
    out[:, 0] = -1
    return out


@njit(inline="always")
def _collect(geo, node, skip, table, row, n, stack):
    """Append the primitives of the subtree at `node` (not `skip`) to table[row] from entry n; the new n."""
    stack[0] = node
    top = 1
    while top > 0 and n < LIST_SIZE:
        top -= 1
        node = stack[top]
        count = geo.node_count[node]
        if count == 0:
            if top + 2 <= WALK_STACK:
                stack[top] = geo.node_first[node] + 1
                stack[top + 1] = geo.node_first[node]
                top += 2
            continue
        first = geo.node_first[node]
        for slot in range(first, first + count):
            ref = geo.refs[slot]
            if ref >> KIND_SHIFT < AGGREGATE and ref != skip and n < LIST_SIZE:
                table[row, 3 + n] = ref
                n += 1
    return n


@njit(private=True)
def start_list(ref, starts, geo, table, tick, stack, cnt):
    """The row of table holding the start list of primitive `ref` (built now if it is not there),
    -1 when the primitive has none."""
    kind, idx = ref >> KIND_SHIFT, ref & INDEX_MASK
    leaf = starts.prim_leaf[starts.prim_offset[kind] + idx]
    if leaf < 0:
        return np.int64(-1)
    base = ((ref * np.int64(0x9E3779B1)) & np.int64(0x7FFFFFFF)) % TABLE_SETS * TABLE_WAYS
    victim = base
    for way in range(base, base + TABLE_WAYS):
        if table[way, 0] == ref:
            table[way, 1] = tick
            return np.int64(way)
        if table[way, 1] < table[victim, 1] or table[way, 0] < 0 <= table[victim, 0]:
            victim = way
    cnt[C.START_LISTS_BUILT] += 1
    table[victim, 0], table[victim, 1] = ref, tick
    n = _collect(geo, leaf, ref, table, victim, 0, stack)
    node = leaf
    while n < LIST_SIZE and starts.node_parent[node] >= 0:
        parent = starts.node_parent[node]
        left = geo.node_first[parent]
        sibling = left + 1 if node == left else left
        n = _collect(geo, sibling, ref, table, victim, n, stack)
        node = parent
    table[victim, 2] = n
    return np.int64(victim)

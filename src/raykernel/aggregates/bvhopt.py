"""Optimisers of a built binary BVH: the same leaves, a tree of lower SAH cost.

    tree, stats = bvhbuild.build_bvh(bounds)
    tree, info = optimize(tree, "rotations")      # or "reinsertion"
    info["sah_before"], info["sah_after"], info["seconds"]

Both keep every leaf (its items and its place in `order`) and rebuild only the inner nodes
above them, then lay the tree out again as bvhtree.py's arrays (siblings adjacent, children
after their parents, tight boxes). The SAH cost is bvh.py's with traversal and
intersection cost 1: inner areas plus leaf areas times their items, over the root's area.

rotations    Kensler 2008, "Tree rotations for improving bounding volume hierarchies":
             passes over the nodes, children before parents; at each node the four
             rotations that swap a child with a grandchild on the other side, the one that
             shrinks the changed node's area the most applied; until a pass changes
             nothing or MAX_PASSES.
reinsertion  Bittner, Hapala and Havran 2013, "Fast insertion-based optimization of bounding
             volume hierarchies": a batch of the inner nodes of largest inefficiency (area
             times area over the children's summed and smallest areas) is taken out one by
             one with its parent (the sibling takes the parent's place), and its two
             subtrees are put back apart, each where the induced cost (the area the
             ancestors grow by plus the new parent's) is least, found by branch and bound
             from the root; a node is not taken out in two batches in a row; batches go on while the cost falls by more than 0.1 %
             within PATIENCE batches, and the cheapest tree seen is kept.
"""

from __future__ import annotations

import time

import numpy as np

from ..geometry.config import njit

MAX_PASSES = 16
BATCH = 0.01            # reinsertion: the share of the nodes taken out per batch
MAX_BATCHES = 64
PATIENCE = 3
METHODS = ("none", "rotations", "reinsertion")


@njit(inline="always")
def _area6(x0, y0, z0, x1, y1, z1):
    dx = max(x1 - x0, 0.0)
    dy = max(y1 - y0, 0.0)
    dz = max(z1 - z0, 0.0)
    return dx * dy + dy * dz + dz * dx


@njit(inline="always")
def _area(b, i):
    return _area6(b[i, 0], b[i, 1], b[i, 2], b[i, 3], b[i, 4], b[i, 5])


@njit(inline="always")
def _union_area(b, i, j):
    return _area6(min(b[i, 0], b[j, 0]), min(b[i, 1], b[j, 1]), min(b[i, 2], b[j, 2]),
                  max(b[i, 3], b[j, 3]), max(b[i, 4], b[j, 4]), max(b[i, 5], b[j, 5]))


@njit(inline="always")
def _set_union(b, out, i, j):
    for k in range(3):
        b[out, k] = min(b[i, k], b[j, k])
        b[out, k + 3] = max(b[i, k + 3], b[j, k + 3])


@njit
def _cost(b, left, right, items, root):
    """The tree's SAH sum of areas (not yet over the root's area)."""
    total = 0.0
    stack = np.empty(left.shape[0], np.int64)
    sp = 1
    stack[0] = root
    while sp:
        sp -= 1
        n = stack[sp]
        if left[n] < 0:
            total += _area(b, n) * items[n]
        else:
            total += _area(b, n)
            stack[sp] = left[n]
            stack[sp + 1] = right[n]
            sp += 2
    return total


@njit
def _refit_up(b, left, right, parent, n):
    while n >= 0:
        _set_union(b, n, left[n], right[n])
        n = parent[n]


@njit
def _rotate(b, left, right, parent, root):
    """Kensler's rotations; returns the number applied."""
    n_nodes = left.shape[0]
    applied = 0
    order = np.empty(n_nodes, np.int64)     # post-order: children before parents
    for _ in range(MAX_PASSES):
        # a post-order of the current tree
        k = 0
        stack = np.empty(n_nodes, np.int64)
        sp = 1
        stack[0] = root
        while sp:
            sp -= 1
            n = stack[sp]
            order[k] = n
            k += 1
            if left[n] >= 0:
                stack[sp] = left[n]
                stack[sp + 1] = right[n]
                sp += 2
        changed = 0
        for q in range(k - 1, -1, -1):
            n = order[q]
            if left[n] < 0:
                continue
            best = 0.0
            which = -1
            for side in range(2):
                child = left[n] if side == 0 else right[n]         # the node whose box changes
                other = right[n] if side == 0 else left[n]         # the child swapped in
                if left[child] < 0:
                    continue
                base = _area(b, child)
                # swap `other` with child's left (child keeps its right) or its right
                d0 = _union_area(b, other, right[child]) - base
                d1 = _union_area(b, left[child], other) - base
                if d0 < best:
                    best, which = d0, 2 * side
                if d1 < best:
                    best, which = d1, 2 * side + 1
            if which < 0 or best > -1e-12 * _area(b, n):
                continue
            side, grand = which // 2, which % 2
            child = left[n] if side == 0 else right[n]
            other = right[n] if side == 0 else left[n]
            g = left[child] if grand == 0 else right[child]
            # other moves down into child's place of g; g moves up into other's place
            if grand == 0:
                left[child] = other
            else:
                right[child] = other
            parent[other] = child
            if side == 0:
                right[n] = g
            else:
                left[n] = g
            parent[g] = n
            _set_union(b, child, left[child], right[child])
            changed += 1
        applied += changed
        if changed == 0:
            break
    return applied


@njit
def _heap_push(hk, hv, size, key, value):
    i = size
    hk[i] = key
    hv[i] = value
    while i > 0:
        p = (i - 1) // 2
        if hk[p] <= hk[i]:
            break
        hk[p], hk[i] = hk[i], hk[p]
        hv[p], hv[i] = hv[i], hv[p]
        i = p
    return size + 1


@njit
def _heap_pop(hk, hv, size):
    key, value = hk[0], hv[0]
    size -= 1
    hk[0], hv[0] = hk[size], hv[size]
    i = 0
    while True:
        a, c = 2 * i + 1, 2 * i + 2
        m = i
        if a < size and hk[a] < hk[m]:
            m = a
        if c < size and hk[c] < hk[m]:
            m = c
        if m == i:
            break
        hk[m], hk[i] = hk[i], hk[m]
        hv[m], hv[i] = hv[i], hv[m]
        i = m
    return key, value, size


@njit
def _best_place(b, left, right, parent, root, node):
    """Bittner's branch and bound: the node whose sibling `node` should become."""
    n_nodes = left.shape[0]
    hk = np.empty(2 * n_nodes + 2)
    hv = np.empty(2 * n_nodes + 2, np.int64)
    ind = np.empty(n_nodes)          # the induced cost of reaching each node
    size = _heap_push(hk, hv, 0, 0.0, root)
    ind[root] = 0.0
    a_node = _area(b, node)
    best, best_x = np.inf, root
    while size:
        key, x, size = _heap_pop(hk, hv, size)
        if key + a_node >= best:
            break
        direct = _union_area(b, x, node)
        if ind[x] + direct < best:
            best, best_x = ind[x] + direct, x
        if left[x] >= 0:
            below = ind[x] + direct - _area(b, x)
            if below + a_node < best:
                for c in (left[x], right[x]):
                    ind[c] = below
                    size = _heap_push(hk, hv, size, below, c)
    return best_x


@njit
def _insert(b, left, right, parent, root, c, free):
    """Put subtree c back where its induced cost is least, under the free inner node `free`;
    returns the root."""
    x = _best_place(b, left, right, parent, root, c)
    q = parent[x]
    if q >= 0:
        if left[q] == x:
            left[q] = free
        else:
            right[q] = free
    else:
        root = free
    parent[free] = q
    left[free], right[free] = x, c
    parent[x] = free
    parent[c] = free
    _refit_up(b, left, right, parent, free)
    return root


@njit
def _reinsert(b, left, right, parent, items, root, batch, max_batches, patience):
    """Bittner's insertion-based optimisation; returns (root, batches run) with the best tree
    seen in left/right/parent/b."""
    n_nodes = left.shape[0]
    best_cost = _cost(b, left, right, items, root)
    best = (b.copy(), left.copy(), right.copy(), parent.copy(), root)
    stale = 0
    runs = 0
    last = np.zeros(n_nodes, np.bool_)      # taken out in the batch before: not again at once
    for _ in range(max_batches):
        runs += 1
        # Bittner's inefficiency of an inner node: its area times how much larger it is than its
        # children (M_area * M_sum * M_min), over the nodes whose parent is not the root
        score = np.full(n_nodes, -1.0)
        for n in range(n_nodes):
            if n != root and parent[n] >= 0 and parent[n] != root and left[n] >= 0 and not last[n]:
                a = _area(b, n)
                al, ar = _area(b, left[n]), _area(b, right[n])
                score[n] = a * a / max(al + ar, 1e-300) * a / max(min(al, ar), 1e-300)
        picks = np.argsort(-score)[:batch]
        last[:] = False
        for n in picks:
            if score[n] < 0:
                continue
            last[n] = True
            p = parent[n]
            if p < 0 or p == root or parent[p] < 0 or left[n] < 0:
                continue
            g = parent[p]
            s = right[p] if left[p] == n else left[p]
            # take n and its parent out: the sibling takes the parent's place; n's two subtrees
            # are put back one by one, the larger first, with p and n as their new parents
            if left[g] == p:
                left[g] = s
            else:
                right[g] = s
            parent[s] = g
            _refit_up(b, left, right, parent, g)
            kids = (left[n], right[n]) if _area(b, left[n]) >= _area(b, right[n]) else (right[n], left[n])
            for c, free in ((kids[0], p), (kids[1], n)):
                root = _insert(b, left, right, parent, root, c, free)
        cost = _cost(b, left, right, items, root)
        if cost < best_cost * (1.0 - 1e-3):
            best_cost = cost
            best = (b.copy(), left.copy(), right.copy(), parent.copy(), root)
            stale = 0
        else:
            if cost < best_cost:
                best_cost = cost
                best = (b.copy(), left.copy(), right.copy(), parent.copy(), root)
            stale += 1
            if stale >= patience:
                break
    b[:] = best[0]
    left[:] = best[1]
    right[:] = best[2]
    parent[:] = best[3]
    return best[4], runs


@njit
def _layout(b, left, right, first_leaf, count_leaf, root):
    """bvhtree.py's arrays from the pointer tree: breadth first, siblings adjacent."""
    n = left.shape[0]
    nb = np.empty((n, 6))
    first = np.empty(n, np.int64)
    count = np.empty(n, np.int64)
    src = np.empty(n, np.int64)
    src[0] = root
    k = 1
    for i in range(n):
        s = src[i]
        nb[i] = b[s]
        if left[s] < 0:
            first[i] = first_leaf[s]
            count[i] = count_leaf[s]
        else:
            first[i] = k
            count[i] = 0
            src[k] = left[s]
            src[k + 1] = right[s]
            k += 2
    return nb, first, count


def _depth(first, count) -> int:
    depth = np.zeros(len(first), np.int64)
    for i in range(len(first)):
        if count[i] == 0 and first[i] > i:
            depth[first[i]] = depth[first[i] + 1] = depth[i] + 1
    return int(depth.max()) if len(depth) else 0


def sah(tree) -> float:
    """bvh.py's SAH cost of a tree (1 for a lone leaf of one item)."""
    from .bvhtree import is_leaf
    leaves = is_leaf(tree)
    b = tree.bounds
    area = _area_rows(b)
    root = area[0] if len(area) and area[0] > 0 else 1.0
    return float((area[~leaves].sum() + (area[leaves] * tree.count[leaves]).sum()) / root)


def _area_rows(b):
    d = np.maximum(b[:, 3:] - b[:, :3], 0.0)
    return d[:, 0] * d[:, 1] + d[:, 1] * d[:, 2] + d[:, 2] * d[:, 0]


def optimize(tree, method: str):
    """(optimised BVHArrays, info) for method in METHODS; "none" returns the tree as it is."""
    from .bvhtree import BVHArrays, is_leaf
    if method not in METHODS:
        raise ValueError(f"unknown BVH optimisation {method!r}; choose from {', '.join(METHODS)}")
    before = sah(tree)
    n = len(tree.count)
    info = {"method": method, "sah_before": before, "sah_after": before, "seconds": 0.0, "steps": 0,
            "max_depth": _depth(tree.first, tree.count)}
    if method == "none" or n < 5:
        return tree, info
    t0 = time.perf_counter()
    leaves = is_leaf(tree)
    left = np.where(leaves, -1, tree.first).astype(np.int64)
    right = np.where(leaves, -1, tree.first + 1).astype(np.int64)
    parent = np.full(n, -1, np.int64)
    inner = np.nonzero(~leaves)[0]
    parent[tree.first[inner]] = inner
    parent[tree.first[inner] + 1] = inner
    b = tree.bounds.copy()
    items = np.where(leaves, tree.count, 0).astype(np.int64)
    if method == "rotations":
        root, steps = 0, _rotate(b, left, right, parent, 0)
    else:
        root, steps = _reinsert(b, left, right, parent, items, 0, max(1, int(BATCH * n)), MAX_BATCHES, PATIENCE)
    nb, first, count = _layout(b, left, right, tree.first, tree.count, root)
    out = BVHArrays(nb, first, count, tree.order)
    info.update(sah_after=sah(out), seconds=time.perf_counter() - t0, steps=int(steps),
                max_depth=_depth(first, count))
    return out, info

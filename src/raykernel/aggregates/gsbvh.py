"""Goldsmith-Salmon BVH (1987): items inserted one at a time, each where it adds least surface area.

    bvh, stats = build_gs(item_bounds, order="shuffle", seed=1)
    # the same BVHArrays layout as bvhbuild.build_bvh: node 0 the root, children
    # adjacent (first, first + 1) and after their parent, leaves order[first:first + count]

Insertion
---------
Goldsmith and Salmon estimate the cost of a hierarchy as the sum, over its
inner nodes, of (surface area of the node) x (number of children), relative
to the root's area: the expected number of bounding-volume tests a random
ray makes. Items are inserted one after the other into a growing pointer
tree; each new item with box B walks down from the root, and at every inner
node N it compares

* making B a sibling of N: a new inner node over N and B replaces N,
  costing 2 * A(N u B) (two children tested with probability A(N u B));
* going into child C: N grows, which costs 2 * (A(N u B) - A(N)) (both of
  N's children are tested more often), plus what C costs: a leaf C is
  paired with the item under a new node, 2 * A(C u B); an inner C grows,
  2 * (A(C u B) - A(C)), and somewhere below it a new node of two children
  at least as large as B appears, 2 * A(B);

and takes the cheapest. Areas the ancestors gain are the same for every
choice at one node, so they drop out of the comparison. At a leaf the only
choice is to pair the item with the leaf's item.

Binary tree. The paper's tree has any number of children per node and its
third choice is "add B as one more child of N". Kept binary (so the BVH
kernel, which expects exactly two children, traverses it), that choice
becomes the sibling choice above, as in the binary insertion builders that
followed (Omohundro 1989; Bittner et al. 2012). Every leaf holds exactly
one item, as in the paper; the SAH build's ``leaf`` and ``bins`` do not
apply.

Ties (equal costs, e.g. identical boxes, or points and segments whose
areas are all zero) go to a child rather than a new sibling, and between the
children to the one with fewer items, so degenerate input still gives
balanced trees. A depth guard that the paper does not have keeps every leaf
within MAX_DEPTH edges of the root: a choice that would push a leaf below
it is not taken (each node keeps its height and the depth of its shallowest
leaf). It never binds on ordinary input; it stops nested boxes inserted
from small to large from becoming a chain deeper than the traversal stack.

Areas are measured on boxes scaled by a power of two chosen from the largest
coordinate, so 1e-300 and 1e300 scenes neither underflow nor overflow.

Insertion order
---------------
The result depends on the order of insertion (the paper shuffles the list
before building). ``file``: the order given; ``shuffle``: a permutation
from numpy's default_rng(seed); ``curve``: sorted along the Morton
(Z-order) curve of the box centres quantised to 21 bits per axis over the
centres' box (ties keep the given order).

The build is O(n * depth): each insertion walks one path down and back up.
"""

from __future__ import annotations

import time

import numpy as np

from ..errors import OptionError
from ..geometry.config import njit
from ..options import number
from .bvhtree import BVHArrays, as_item_bounds, is_leaf

__all__ = ["build_gs", "insertion_order", "morton_codes", "ORDERS", "MAX_DEPTH"]

ORDERS = ("file", "shuffle", "curve")
MAX_DEPTH = 64


def _part1by2(v: np.ndarray) -> np.ndarray:
    """Spread the low 21 bits of v so that two zero bits follow each bit."""
    v = v.astype(np.uint64) & np.uint64(0x1FFFFF)
    v = (v | (v << np.uint64(32))) & np.uint64(0x1F00000000FFFF)
    v = (v | (v << np.uint64(16))) & np.uint64(0x1F0000FF0000FF)
    v = (v | (v << np.uint64(8))) & np.uint64(0x100F00F00F00F00F)
    v = (v | (v << np.uint64(4))) & np.uint64(0x10C30C30C30C30C3)
    v = (v | (v << np.uint64(2))) & np.uint64(0x1249249249249249)
    return v


def morton_codes(items: np.ndarray) -> np.ndarray:
    """63-bit Morton codes of the box centres, quantised over the centres' box."""
    if len(items) == 0:
        return np.zeros(0, np.uint64)
    c = 0.5 * items[:, :3] + 0.5 * items[:, 3:]
    lo = c.min(axis=0)
    ext = c.max(axis=0) - lo
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        scale = np.where((ext > 0) & np.isfinite(ext), (2 ** 21 - 1) / ext, 0.0)
        q = np.floor((c - lo) * scale)
    q = np.clip(np.nan_to_num(q, nan=0.0, posinf=2 ** 21 - 1, neginf=0.0), 0, 2 ** 21 - 1).astype(np.uint64)
    return _part1by2(q[:, 0]) | (_part1by2(q[:, 1]) << np.uint64(1)) | (_part1by2(q[:, 2]) << np.uint64(2))


def insertion_order(items: np.ndarray, order: str, seed: int) -> np.ndarray:
    """The item indices in the order they are inserted."""
    n = len(items)
    if order == "file":
        return np.arange(n, dtype=np.int64)
    if order == "shuffle":
        return np.random.default_rng(seed).permutation(n).astype(np.int64)
    if order == "curve":
        return np.argsort(morton_codes(items), kind="stable").astype(np.int64)
    raise OptionError(f"insertion order must be one of {', '.join(ORDERS)}, got {order!r}")


@njit(inline="always")
def _area(b, i, u, s):
    """Surface area (up to a constant) of box i of b united with box u, coordinates times s."""
    ex = max(b[i, 3], u[3]) * s - min(b[i, 0], u[0]) * s
    ey = max(b[i, 4], u[4]) * s - min(b[i, 1], u[1]) * s
    ez = max(b[i, 5], u[5]) * s - min(b[i, 2], u[2]) * s
    return ex * ey + ey * ez + ez * ex


@njit
def _insert_kernel(items, seq, s, max_depth):
    """Build the pointer tree by insertion; returns (box, left, right, item, root, node count)."""
    n = items.shape[0]
    cap = max(1, 2 * n - 1)
    box = np.empty((cap, 6), np.float64)
    left = np.full(cap, -1, np.int64)
    right = np.full(cap, -1, np.int64)
    parent = np.full(cap, -1, np.int64)
    item = np.full(cap, -1, np.int64)
    size = np.zeros(cap, np.int64)       # leaves in the subtree
    height = np.zeros(cap, np.int64)     # edges to the deepest leaf
    shallow = np.zeros(cap, np.int64)    # edges to the shallowest leaf
    u = np.empty(6, np.float64)
    root = -1
    nodes = 0
    for k in range(seq.shape[0]):
        it = seq[k]
        for j in range(6):
            u[j] = items[it, j]
        leaf = nodes
        nodes += 1
        for j in range(6):
            box[leaf, j] = u[j]
        item[leaf] = it
        size[leaf] = 1
        if root < 0:
            root = leaf
            continue

        # walk down: sibling of the node, or into the cheaper child
        a_item = 2.0 * _area(box, leaf, u, s)
        node = root
        depth = 0
        while item[node] < 0:
            a_node = _area(box, node, box[node], s)
            a_union = _area(box, node, u, s)
            sib_ok = depth + height[node] + 1 <= max_depth
            grow = 2.0 * (a_union - a_node)
            best = -1
            best_cost = np.inf
            if sib_ok:
                best_cost = 2.0 * a_union
            for side in range(2):
                c = left[node] if side == 0 else right[node]
                if depth + 2 + shallow[c] > max_depth:
                    continue
                if item[c] >= 0:
                    cost = grow + 2.0 * _area(box, c, u, s)
                else:
                    cost = grow + 2.0 * (_area(box, c, u, s) - _area(box, c, box[c], s)) + a_item
                if best < 0:
                    take = cost <= best_cost
                else:
                    take = cost < best_cost or (cost == best_cost and size[c] < size[best])
                if take:
                    best = c
                    best_cost = cost
            if best < 0:
                break
            node = best
            depth += 1

        # a new inner node over `node` and the new leaf takes node's place
        inner = nodes
        nodes += 1
        up = parent[node]
        for j in range(3):
            box[inner, j] = min(box[node, j], u[j])
            box[inner, j + 3] = max(box[node, j + 3], u[j + 3])
        left[inner] = node
        right[inner] = leaf
        parent[inner] = up
        parent[node] = inner
        parent[leaf] = inner
        size[inner] = size[node] + 1
        height[inner] = height[node] + 1
        shallow[inner] = 1
        if up < 0:
            root = inner
        elif left[up] == node:
            left[up] = inner
        else:
            right[up] = inner

        # walk up: grow the boxes, recount
        while up >= 0:
            for j in range(3):
                box[up, j] = min(box[up, j], u[j])
                box[up, j + 3] = max(box[up, j + 3], u[j + 3])
            size[up] += 1
            a = left[up]
            b = right[up]
            height[up] = 1 + max(height[a], height[b])
            shallow[up] = 1 + min(shallow[a], shallow[b])
            up = parent[up]
    return box, left, right, item, root, nodes


@njit
def _flatten_kernel(box, left, right, item, root, nodes):
    """Pointer tree -> BVHArrays layout, depth first; returns (bounds, first, count, order, max depth)."""
    bounds = np.empty((nodes, 6), np.float64)
    first = np.zeros(nodes, np.int64)
    count = np.zeros(nodes, np.int64)
    n_items = (nodes + 1) // 2
    order = np.empty(n_items, np.int64)
    st_ptr = np.empty(nodes + 1, np.int64)
    st_out = np.empty(nodes + 1, np.int64)
    st_depth = np.empty(nodes + 1, np.int64)
    st_ptr[0] = root
    st_out[0] = 0
    st_depth[0] = 0
    top = 1
    next_node = 1
    pos = 0
    max_depth = 0
    while top > 0:
        top -= 1
        p = st_ptr[top]
        o = st_out[top]
        d = st_depth[top]
        if d > max_depth:
            max_depth = d
        for j in range(6):
            bounds[o, j] = box[p, j]
        if item[p] >= 0:
            first[o] = pos
            count[o] = 1
            order[pos] = item[p]
            pos += 1
            continue
        c = next_node
        next_node += 2
        first[o] = c
        count[o] = 0
        # right below left on the stack: the left subtree's leaves come first in order
        st_ptr[top] = right[p]
        st_out[top] = c + 1
        st_depth[top] = d + 1
        top += 1
        st_ptr[top] = left[p]
        st_out[top] = c
        st_depth[top] = d + 1
        top += 1
    return bounds, first, count, order, max_depth


def _area_scale(items: np.ndarray) -> float:
    """A power of two that brings the largest coordinate near 1 (kept finite)."""
    big = float(np.abs(items).max()) if items.size else 0.0
    if big == 0.0:
        return 1.0
    _, e = np.frexp(big)
    return float(np.ldexp(1.0, int(np.clip(-e, -1000, 1000))))


def build_gs(bounds, order="file", *, seed=1, max_depth=MAX_DEPTH):
    """Build a Goldsmith-Salmon BVH over item boxes (see the module docstring).

    bounds: (n, 6) item boxes as for bvhbuild.build_bvh (finite, min <= max, n = 0
    allowed). order: one of ORDERS. seed: for order="shuffle". max_depth:
    the depth guard (>= 1; with n items it must allow log2(n) levels).

    Returns (BVHArrays, stats) with the statistics of build_bvh ("nodes",
    "inner", "leaves", "empty_leaves", "refs", "bytes", "seconds",
    "max_depth") and "order", the insertion order's name.
    """
    t0 = time.perf_counter()
    items = as_item_bounds(bounds)
    if order not in ORDERS:
        raise OptionError(f"insertion order must be one of {', '.join(ORDERS)}, got {order!r}")
    seed = int(number(seed, "seed", 0, 2 ** 63 - 1, integer=True))
    max_depth = int(number(max_depth, "max_depth", 1, 1 << 20, integer=True))
    n = items.shape[0]
    if n > 1 and (n - 1).bit_length() > max_depth:
        raise OptionError(f"max_depth {max_depth} is too small for {n} items")
    if n == 0:
        bvh = BVHArrays(np.array([[np.inf] * 3 + [-np.inf] * 3]), np.zeros(1, np.int64), np.zeros(1, np.int64),
                        np.zeros(0, np.int64))
        depth = 0
    else:
        seq = insertion_order(items, order, seed)
        box, left, right, item, root, nodes = _insert_kernel(items, seq, _area_scale(items), max_depth)
        nb, first, count, perm, depth = _flatten_kernel(box, left, right, item, root, nodes)
        bvh = BVHArrays(nb, first, count, perm)
    leaves = is_leaf(bvh)
    n_leaves = int(np.count_nonzero(leaves))
    stats = {
        "nodes": int(len(bvh.count)),
        "inner": int(len(bvh.count)) - n_leaves,
        "leaves": n_leaves,
        "empty_leaves": int(np.count_nonzero(leaves & (bvh.count == 0))),
        "refs": int(bvh.count[leaves].sum()),
        "bytes": int(sum(a.nbytes for a in bvh)),
        "seconds": time.perf_counter() - t0,
        "max_depth": int(depth),
        "order": order,
    }
    return bvh, stats

"""Ray classification (Arvo and Kirk 1987) over axis-aligned item boxes, as flat arrays.

    tree, stats = build_rc(item_bounds, leaf=8, depth=20, budget_mb=256)
    node = tree.face_root[face_of(dx, dy, dz)]     # then descend with node_b / split
    items, keys = tree.items[s:s + n], tree.keys[s:s + n]   # leaf: s = node_a, n = node_b

Rays as points in 5D
--------------------
A ray is classified by its origin (x, y, z) and its direction. The direction
picks a face of the direction cube: its dominant axis a (largest |d_a|,
ties to the lower axis) and the sign s of d_a, face = 2 * a + (s < 0). On
that face the direction is (u, v) = (d_b, d_c) / |d_a| in [-1, 1]^2 with
b = (a + 1) % 3, c = (a + 2) % 3. A ray that starts outside the aggregate's
box is first moved to its entry point (the traversal does this with the
box's entry distance), so the origin always lies in the box.

The tree
--------
Each of the six faces has its own 5D bisection tree over (x, y, z, u, v).
Its root is the whole hypercube (the aggregate's box, flat axes padded as in
the uniform grid, times [-1, 1]^2). A hypercube is split in the middle of its
longest dimension, measured in units of the root's side along that
dimension (ties: x, y, z, u, v in that order). A node is stored in three
flat entries:

    node_a[i]  int64   inner: first child (second child = node_a + 1); leaf: first entry in items/keys
    node_b[i]  int64   inner: -(dimension + 1); leaf: number of candidates (0: empty)
    split[i]   float64 inner: the split coordinate; a point below it goes to the first child

so a node costs 24 bytes and a candidate 16 (an item index and its key).

Candidate lists
---------------
A hypercube's candidates are the items whose box meets its beam: every
point p + t * w with p in the xyz box, w = s * e_a + u * e_b + v * e_c for
(u, v) in the cell and t >= 0. The beam is the Minkowski sum of the origin
box and the polyhedral cone spanned by the cell's four corner directions,
so it is convex, and "item box A meets the beam" is the same as "the box
A - B (A minus the origin box, itself a box) meets the cone". With
h = s * w_a the cone is h >= 0, u0 h <= w_b <= u1 h, v0 h <= w_c <= v1 h;
intersected with the box that is a system of linear inequalities in the
one unknown h, solved exactly as an interval. This is the paper's convex
hull of the beam without approximating it by a bounding cone; every item
box is widened by 1e-8 of the aggregate's size and every cell by 1e-9 in
u and v, so rounding in the classification can only add candidates.

Every list is sorted by the key of its items along the face's dominant
axis: the near face of the item's box (s * box_min_a for s > 0, -box_max_a
for s < 0, widened by the margin). For a ray of this face no hit with the
item can lie before t = (key - s * o_a) / |d_a|, and the keys rise along the
list, so the traversal stops the list once that bound passes the closest
hit so far.

Subdivision and the memory budget
---------------------------------
A hypercube is split while it holds more than `leaf` candidates, lies less
than `depth` splits below its face root, and splitting still helps: a child
that keeps more than KEEP (3/4) of its parent's candidates is a split without
progress, and after five such splits in a row (one round over the five
dimensions) a hypercube is not split further. Without that rule a 5D tree
of depth 20 grows to about a million hypercubes per face for a few hundred
items. The paper subdivides
lazily, as rays arrive; here the tree is built eagerly, before any ray is
cast, breadth first over all six faces together, so that the result does not
depend on the rays, the thread count or the timing. The size of the finished
tree (24 bytes a node, 16 a candidate) is kept under `budget_mb` MiB: the
first split that would pass it stops all further subdivision, the remaining
hypercubes become leaves with their (longer, still complete) candidate lists,
and `build_rc` warns once (RcBudgetWarning) and sets stats["budget_exceeded"].
Results stay exact; only the speed suffers. The six roots are always kept,
even when they alone exceed the budget.
"""

from __future__ import annotations

import math
import time
import warnings
from typing import NamedTuple

import numpy as np

from ..config import njit
from ..errors import OptionError
from .grid import grid_box

__all__ = ["RcArrays", "RcBudgetWarning", "build_rc", "face_of", "NODE_BYTES", "CANDIDATE_BYTES"]

NODE_BYTES = 24
CANDIDATE_BYTES = 16
KEEP = 0.75                 # a child keeping more than this share of its parent's list made no progress
STALE_SPLITS = 5            # splits in a row that removed nothing before a hypercube stops splitting
BOX_MARGIN = 1e-8           # item boxes widened by this fraction of the aggregate's size
UV_MARGIN = 1e-9            # direction cells widened by this much in u and v


class RcBudgetWarning(UserWarning):
    """A ray-classification build reached its memory budget and stopped subdividing."""


class RcArrays(NamedTuple):
    """Six 5D bisection trees and their candidate lists; see the module docstring."""

    box: np.ndarray         # (6,) the padded xyz box of every face root
    face_root: np.ndarray   # (6,) int64 root node of each face
    node_a: np.ndarray      # (N,) int64 inner: first child; leaf: first candidate
    node_b: np.ndarray      # (N,) int64 inner: -(dimension + 1); leaf: candidate count
    split: np.ndarray       # (N,) float64 inner: split coordinate
    items: np.ndarray       # (R,) int64 item index of each candidate
    keys: np.ndarray        # (R,) float64 near-face key of each candidate, rising within a leaf


def face_of(d) -> tuple[int, float, float]:
    """(face, u, v) of a direction, as the traversal classifies it."""
    d = np.asarray(d, np.float64)
    ad = np.abs(d)
    a = 0 if ad[0] >= ad[1] and ad[0] >= ad[2] else (1 if ad[1] >= ad[2] else 2)
    return 2 * a + (1 if d[a] < 0.0 else 0), d[(a + 1) % 3] / ad[a], d[(a + 2) % 3] / ad[a]


@njit(inline="always")
def _le(k, r, h0, h1):
    """Restrict [h0, h1] to k * h <= r."""
    if k > 0.0:
        h1 = min(h1, r / k)
    elif k < 0.0:
        h0 = max(h0, r / k)
    elif r < 0.0:
        h1 = -1.0
        h0 = 1.0
    return h0, h1


@njit
def meets_beam(bx, i, lo, hi, face):
    """Does item box i of `bx` meet the beam of the hypercube lo..hi (x, y, z, u, v) of `face`?"""
    a = face // 2
    b = (a + 1) % 3
    c = (a + 2) % 3
    # the box of q - p over q in the item, p in the origin box
    wa0 = bx[i, a] - hi[a]
    wa1 = bx[i, a + 3] - lo[a]
    if face % 2 == 0:
        h0, h1 = wa0, wa1
    else:
        h0, h1 = -wa1, -wa0
    h0 = max(h0, 0.0)
    if h0 > h1:
        return False
    wb0 = bx[i, b] - hi[b]
    wb1 = bx[i, b + 3] - lo[b]
    wc0 = bx[i, c] - hi[c]
    wc1 = bx[i, c + 3] - lo[c]
    u0, u1 = lo[3] - UV_MARGIN, hi[3] + UV_MARGIN
    v0, v1 = lo[4] - UV_MARGIN, hi[4] + UV_MARGIN
    # the cone's w_b range [u0 h, u1 h] meets [wb0, wb1]; the same for w_c
    h0, h1 = _le(u0, wb1, h0, h1)
    h0, h1 = _le(-u1, -wb0, h0, h1)
    h0, h1 = _le(v0, wc1, h0, h1)
    h0, h1 = _le(-v1, -wc0, h0, h1)
    return h0 <= h1


@njit
def _grow_i(a, n):
    if n <= a.shape[0]:
        return a
    out = np.empty(max(n, 2 * a.shape[0]), a.dtype)
    out[:a.shape[0]] = a
    return out


@njit
def _grow_f(a, n):
    if n <= a.shape[0]:
        return a
    out = np.empty(max(n, 2 * a.shape[0]), a.dtype)
    out[:a.shape[0]] = a
    return out


@njit
def _grow_rows(a, n):
    if n <= a.shape[0]:
        return a
    out = np.empty((max(n, 2 * a.shape[0]), a.shape[1]), a.dtype)
    out[:a.shape[0]] = a
    return out


@njit
def _build_kernel(bx, keys, orders, root_lo, root_hi, leaf, max_depth, budget, keep):
    """Breadth-first build of the six face trees; see the module docstring.
    keys: (n, 6) key of each item per face; orders: (6, n) items of each face root, by key.
    Returns node_a, node_b, split, items, keys, n_nodes, n_cands, max_depth, exceeded."""
    n = orders.shape[1]
    norm = np.empty(5)
    for k in range(5):
        norm[k] = 1.0 / (root_hi[k] - root_lo[k])
    node_a = np.empty(64, np.int64)
    node_b = np.empty(64, np.int64)
    split = np.zeros(64)
    out_items = np.empty(max(16, 6 * n), np.int64)
    out_keys = np.empty(max(16, 6 * n))
    n_out = 0
    # the current level: node, face, depth, stale count, cell, list in buf
    lv_node = np.empty(6, np.int64)
    lv_info = np.empty((6, 5), np.int64)   # face, depth, stale, start, count
    lv_lo = np.empty((6, 5))
    lv_hi = np.empty((6, 5))
    buf = np.empty(6 * n, np.int64)
    for f in range(6):
        lv_node[f] = f
        lv_info[f, 0] = f
        lv_info[f, 1] = 0
        lv_info[f, 2] = 0
        lv_info[f, 3] = f * n
        lv_info[f, 4] = n
        lv_lo[f] = root_lo
        lv_hi[f] = root_hi
        for j in range(n):
            buf[f * n + j] = orders[f, j]
    m = 6
    n_nodes = 6
    used = NODE_BYTES * 6 + CANDIDATE_BYTES * 6 * n
    exceeded = used > budget
    deepest = 0
    lo = np.empty(5)
    hi = np.empty(5)
    while m > 0:
        nx_node = np.empty(2 * m, np.int64)
        nx_info = np.empty((2 * m, 5), np.int64)
        nx_lo = np.empty((2 * m, 5))
        nx_hi = np.empty((2 * m, 5))
        nx_buf = np.empty(max(16, buf.shape[0]), np.int64)
        nm = 0
        nb = 0
        for j in range(m):
            nd = lv_node[j]
            face, dep, stale, st, cnt = lv_info[j, 0], lv_info[j, 1], lv_info[j, 2], lv_info[j, 3], lv_info[j, 4]
            done = True
            if not exceeded and cnt > leaf and dep < max_depth and stale < STALE_SPLITS:
                # split the longest side, in units of the root's sides
                dim = 0
                best = -1.0
                for k in range(5):
                    side = (lv_hi[j, k] - lv_lo[j, k]) * norm[k]
                    if side > best:
                        best = side
                        dim = k
                mid = 0.5 * (lv_lo[j, dim] + lv_hi[j, dim])
                nx_buf = _grow_i(nx_buf, nb + 2 * cnt)
                counts = np.zeros(2, np.int64)
                start0 = nb
                for side in range(2):
                    for k in range(5):
                        lo[k] = lv_lo[j, k]
                        hi[k] = lv_hi[j, k]
                    if side == 0:
                        hi[dim] = mid
                    else:
                        lo[dim] = mid
                    for q in range(st, st + cnt):
                        item = buf[q]
                        if meets_beam(bx, item, lo, hi, face):
                            nx_buf[nb] = item
                            nb += 1
                            counts[side] += 1
                delta = 2 * NODE_BYTES + CANDIDATE_BYTES * (counts[0] + counts[1] - cnt)
                if used + delta > budget:
                    exceeded = True
                    nb = start0
                else:
                    done = False
                    used += delta
                    node_a = _grow_i(node_a, n_nodes + 2)
                    node_b = _grow_i(node_b, n_nodes + 2)
                    split = _grow_f(split, n_nodes + 2)
                    node_a[nd] = n_nodes
                    node_b[nd] = -(dim + 1)
                    split[nd] = mid
                    nx_node = _grow_i(nx_node, nm + 2)
                    nx_info = _grow_rows(nx_info, nm + 2)
                    nx_lo = _grow_rows(nx_lo, nm + 2)
                    nx_hi = _grow_rows(nx_hi, nm + 2)
                    pos = start0
                    for side in range(2):
                        nx_node[nm] = n_nodes
                        nx_info[nm, 0] = face
                        nx_info[nm, 1] = dep + 1
                        nx_info[nm, 2] = stale + 1 if counts[side] > keep * cnt else 0
                        nx_info[nm, 3] = pos
                        nx_info[nm, 4] = counts[side]
                        for k in range(5):
                            nx_lo[nm, k] = lv_lo[j, k]
                            nx_hi[nm, k] = lv_hi[j, k]
                        if side == 0:
                            nx_hi[nm, dim] = mid
                        else:
                            nx_lo[nm, dim] = mid
                        pos += counts[side]
                        nm += 1
                        n_nodes += 1
                    if dep + 1 > deepest:
                        deepest = dep + 1
            if done:
                # a leaf: its list, already in key order, goes to the output
                node_a = _grow_i(node_a, n_nodes)
                node_b = _grow_i(node_b, n_nodes)
                split = _grow_f(split, n_nodes)
                node_a[nd] = n_out
                node_b[nd] = cnt
                split[nd] = 0.0
                out_items = _grow_i(out_items, n_out + cnt)
                out_keys = _grow_f(out_keys, n_out + cnt)
                for q in range(st, st + cnt):
                    out_items[n_out] = buf[q]
                    out_keys[n_out] = keys[buf[q], face]
                    n_out += 1
        lv_node, lv_info, lv_lo, lv_hi, buf = nx_node, nx_info, nx_lo, nx_hi, nx_buf
        m = nm
    return (node_a[:n_nodes].copy(), node_b[:n_nodes].copy(), split[:n_nodes].copy(),
            out_items[:n_out].copy(), out_keys[:n_out].copy(), deepest, exceeded)


def _check(value, name, low, high, kind):
    if isinstance(value, bool) or not isinstance(value, kind) or not (low <= value <= high) or (
            isinstance(value, float) and not math.isfinite(value)):
        raise OptionError(f"rc {name} must be a number in [{low}, {high}], got {value!r}")


def build_rc(bounds, *, leaf=8, depth=20, budget_mb=256.0, name=None):
    """Build the ray-classification trees over item boxes.

    bounds: (n, 6) item boxes, finite (or the empty box +inf..-inf, which no
    list holds), n >= 1. leaf >= 1: most candidates a hypercube keeps
    without splitting; depth >= 0: most splits below a face root; budget_mb
    >= 0: MiB the finished tree may take (see the module docstring).

    Returns (RcArrays, stats) with stats = {"nodes" (hypercubes), "inner",
    "leaves", "empty_leaves", "refs" (candidates in all lists), "bytes",
    "seconds", "max_depth", "budget_exceeded"}.
    """
    t0 = time.perf_counter()
    _check(leaf, "leaf", 1, 1 << 20, (int, np.integer))
    _check(depth, "depth", 0, 200, (int, np.integer))
    _check(budget_mb, "budget_mb", 0.0, 1 << 20, (int, float, np.integer, np.floating))
    items = np.ascontiguousarray(np.asarray(bounds, np.float64))
    if items.ndim != 2 or items.shape[1] != 6 or len(items) == 0:
        raise ValueError(f"bounds must have shape (n, 6) with n >= 1, got {items.shape}")
    solid = np.all(items[:, :3] <= items[:, 3:], axis=1)
    if not np.all(np.isfinite(items[solid])):
        raise ValueError("bounds must be finite (or the empty box +inf..-inf)")
    if solid.any():
        origin, extent = grid_box(items[solid])
    else:
        origin, extent = np.zeros(3), np.ones(3)
    box = np.concatenate([origin, origin + extent])
    margin = BOX_MARGIN * max(float(extent.max()), float(np.abs(box).max()))
    bx = np.where(solid[:, None], items + np.array([-margin] * 3 + [margin] * 3), 0.0)
    keys = np.empty((len(items), 6))
    for a in range(3):
        keys[:, 2 * a] = bx[:, a]
        keys[:, 2 * a + 1] = -bx[:, a + 3]
    live = np.flatnonzero(solid)
    orders = np.empty((6, len(live)), np.int64)
    for f in range(6):
        orders[f] = live[np.argsort(keys[live, f], kind="stable")]
    root_lo = np.concatenate([box[:3], [-1.0, -1.0]])
    root_hi = np.concatenate([box[3:], [1.0, 1.0]])
    budget = int(float(budget_mb) * (1 << 20))
    node_a, node_b, split, cand, ckeys, deepest, exceeded = _build_kernel(
        np.ascontiguousarray(bx), np.ascontiguousarray(keys), orders, root_lo, root_hi, int(leaf), int(depth),
        budget, KEEP)
    tree = RcArrays(box, np.arange(6, dtype=np.int64), node_a, node_b, split, cand, ckeys)
    leaves = node_b >= 0
    nbytes = NODE_BYTES * len(node_a) + CANDIDATE_BYTES * len(cand)
    if exceeded:
        warnings.warn(f"rc aggregate {name or '(unnamed)'}: the memory budget of {budget_mb} MiB is reached; "
                      f"subdivision stopped at {len(node_a)} hypercubes and {len(cand)} candidates "
                      f"({nbytes / (1 << 20):.3g} MiB). Hits stay exact but tracing is slower; raise budget_mb "
                      f"or lower depth", RcBudgetWarning, stacklevel=2)
    stats = {
        "nodes": int(len(node_a)),
        "inner": int(np.count_nonzero(~leaves)),
        "leaves": int(np.count_nonzero(leaves)),
        "empty_leaves": int(np.count_nonzero(node_b == 0)),
        "refs": int(len(cand)),
        "bytes": int(nbytes),
        "seconds": time.perf_counter() - t0,
        "max_depth": int(deepest),
        "budget_exceeded": bool(exceeded),
    }
    return tree, stats

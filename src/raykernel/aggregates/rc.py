"""Ray classification (Arvo and Kirk 1987) over axis-aligned item boxes, as flat arrays.

    tree, stats = build_rc(item_bounds, leaf=8, depth=40, budget_mb=256)   # eager: the whole trees now
    node = tree.face_root[face_of(dx, dy, dz)[0]]  # then descend with node_b / split
    items, keys = tree.items[s:s + n], tree.keys[s:s + n]   # leaf: s = node_a, n = node_b
    geo, build = flatten(scene, "rc")              # lazy (the default): six root leaves, grown by
    geo = build["lazy"].refine(geo, pass_counts)   # LazyRC between passes of rays (render, RayScene)

Flat layout (the Geometry fields it owns)
-----------------------------------------
RC aggregates, RN nodes, RK candidates of all of them:
  rc_face_root  (RC, 6) int64    root hypercube of each direction-cube face    48 B an aggregate
  rc_node_a     (RN,)   int64    inner: first child (global); leaf: first candidate in keyed_ref   8 B a node
  rc_node_b     (RN,)   int64    inner: -(split dimension + 1) of x, y, z, u, v; leaf: candidates   8 B
  rc_split      (RN,)   float64  inner: split coordinate                        8 B
  rc_pass       (RN,)   int64    lazy leaf that may split: its row of rc_vinfo, else -1   8 B
  keyed_key        (RK,)   float64  near-face key of each candidate, rising within a leaf   8 B a candidate
  keyed_ref        (RK,)   int64    tagged reference of each candidate             8 B
  rc_vinfo      (RP, 3) int64    lazy candidate: first pass counter column, levels K, first entry
                                 in rc_vdim/rc_vsplit
  rc_vdim       (RS,)   int64    split dimension of each inner node of the virtual subtrees
  rc_vsplit     (RS,)   float64  split coordinate of each inner node of those subtrees
The aggregate's agg_start is its row of rc_face_root. A leaf's candidates are a
keyed list (aggregates/walk.py): the driver stops it once the next key puts the
earliest possible hit past the closest one.

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
items. The size of the tree (24 bytes a node, 16 a candidate of a leaf) is
kept under `budget_mb` MiB: the first split that would pass it stops all
further subdivision, the remaining hypercubes stay leaves with their
(longer, still complete) candidate lists, and a warning (RcBudgetWarning)
says so once; stats["budget_exceeded"] is set. Results stay exact; only the
speed suffers. The six roots are always kept, even when they alone exceed
the budget.

Eager (lazy=off, build_rc) builds the trees before any ray is cast, breadth
first over all six faces together, so the budget is spent evenly over the
5D space, most of which no ray ever visits.

Lazy (lazy=on, the default), as Arvo and Kirk subdivide: each face's root
starts as one leaf holding every item, and a leaf is split only where rays
arrive. The trees change only between passes of rays (those of
aggregates/lazyoctree.py, as render.py and RayScene cut them; boundaries
depend only on tile and ray indices), never while rays are in flight. A
leaf that may still split (more than `leaf` candidates, above the depth
limit, not stopped by the progress rule or the budget) is a *candidate*:
during a pass, each ray that reaches it adds one to a counter column of its
tile's or chunk's row. So that one pass can deepen the tree by more than
one level, a candidate counts not only arrivals but where in it they fall:
its cell is split K times more in thought (its *virtual* subtree, split
exactly as real splits would be) and each of the 2**K virtual cells has its
column. K follows the arrivals expected in the next pass: VIRTUAL_LEVELS
for the six roots, else 0 for none and about log2(arrivals / rays) + 2 (at
most VIRTUAL_LEVELS), from the candidate's arrivals in the last pass or,
for a child below its parent's virtual subtree, half of the parent's. So
the columns stay about as many as the candidates plus the rays of a pass.

Between passes, refine() sums the rows (integer sums: any order, any thread
count) and walks each candidate's virtual subtree top down, in node order:
a cell at which at least `rays` rays arrived (counted since it became a
leaf) is split for real, its children's lists taken from its own by the
beam test, and a child's arrivals are those of its virtual cell in this
pass; a cell at the bottom of the virtual subtree may still split once,
its children waiting for rays of their own. Every other leaf waits for
later passes, keeping its count. So a region no ray reaches is never
split, and images, hits and counters are the same at any thread count.
Refinement appends nodes and lists in candidate order, one split after
another; only the beam tests of a list of at least PARALLEL_LIST (256)
candidates are shared among the threads, each writing its own entries of a
mask, so the trees do not depend on the thread count either (on SPD balls
this shortened refinement markedly against one split at a time, moving the
lists together in compiled code included).

The progress rule allows LAZY_STALE_SPLITS (40, eight rounds) splits in a
row without progress instead of five: near the root of a scene with a large
floor no single split separates anything yet (a beam from half of a 24-unit
floor still sweeps the whole cluster of balls), in a cluster of thousands
of items a split keeps most of them until the beams are narrow, and lazily
the rule only guards paths rays actually take, where the budget bounds the
cost anyway. With five, lazy trees stopped there and tested more candidates
per ray than the eager ones (SPD teapot); with 15 and depth 20, SPD balls
made many more tests per ray than with 40 and depth 40 (the default).

Storage: LazyRC keeps the scene's rc node and candidate arrays with room to
grow (doubling); the Geometry handed back views the used part. A split
leaf's list stays behind unused until the unused entries outnumber the
leaves' lists; then, between passes, the lists are moved together (not
while a checkpoint of an all-hits query is out, which needs them in place).
The budget counts the trees' nodes and leaves' lists, as eagerly;
build.bytes counts the arrays as they are, unused entries included.
"""

from __future__ import annotations

import math
import time
import warnings
from typing import NamedTuple

import numpy as np
from numba import prange

from ..geometry import counters as C
from ..geometry.config import njit
from ..geometry.primitives import PRIMITIVE_KINDS
from ..options import number
from .grid import grid_box
from .lazyset import scene_totals, tree_counts
from .memory import grown, memory_limit, over_budget
from .spec import Kind, Param
from .walk import F_KEY_D, F_KEY_END, F_KEY_O, Cells, Field, Walk, one_cell

__all__ = ["RcArrays", "RcBudgetWarning", "LazyRC", "build_rc", "start_rc", "face_of", "NODE_BYTES",
           "CANDIDATE_BYTES", "VIRTUAL_LEVELS"]

NODE_BYTES = 24
CANDIDATE_BYTES = 16
KEEP = 0.75                 # a child keeping more than this share of its parent's list made no progress
STALE_SPLITS = 5            # splits in a row that removed nothing before a hypercube stops splitting
LAZY_STALE_SPLITS = 40      # the same, lazy: eight rounds over x, y, z, u, v (module docstring)
BOX_MARGIN = 1e-8           # item boxes widened by this fraction of the aggregate's size
UV_MARGIN = 1e-9            # direction cells widened by this much in u and v
VIRTUAL_LEVELS = 5          # lazy: most levels of a candidate's virtual subtree (one round over x, y, z, u, v)
PARALLEL_LIST = 256        # lazy: a list at least this long is beam-tested by all threads when split
PEAK_FACTOR = 4            # memory at the peak of a build per byte of the finished trees (doubling, copies)
# lazy: per-node state columns (owner aggregate, face, depth, progress-free splits in a row, arrivals,
# arrivals expected in a pass)
_OWNER, _FACE, _DEPTH, _STALE, _ARRIVED, _RATE = range(6)


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


@njit(borrows=True)   # called per candidate: no reference counting
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


@njit(inline="always")
def _longest(lo, hi, norm):
    """The dimension a hypercube is split along: its longest side in units of the root's sides
    (ties to the lower dimension). Eager, lazy and virtual splits all use this one rule."""
    dim = 0
    best = -1.0
    for k in range(5):
        side = (hi[k] - lo[k]) * norm[k]
        if side > best:
            best = side
            dim = k
    return dim


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
                dim = _longest(lv_lo[j], lv_hi[j], norm)
                mid = 0.5 * (lv_lo[j, dim] + lv_hi[j, dim])
                nx_buf = grown(nx_buf, nb + 2 * cnt, nx_buf.shape[0])
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
                    node_a = grown(node_a, n_nodes + 2, node_a.shape[0])
                    node_b = grown(node_b, n_nodes + 2, node_b.shape[0])
                    split = grown(split, n_nodes + 2, split.shape[0])
                    node_a[nd] = n_nodes
                    node_b[nd] = -(dim + 1)
                    split[nd] = mid
                    nx_node = grown(nx_node, nm + 2, nx_node.shape[0])
                    nx_info = grown(nx_info, nm + 2, nx_info.shape[0])
                    nx_lo = grown(nx_lo, nm + 2, nx_lo.shape[0])
                    nx_hi = grown(nx_hi, nm + 2, nx_hi.shape[0])
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
                node_a = grown(node_a, n_nodes, node_a.shape[0])
                node_b = grown(node_b, n_nodes, node_b.shape[0])
                split = grown(split, n_nodes, split.shape[0])
                node_a[nd] = n_out
                node_b[nd] = cnt
                split[nd] = 0.0
                out_items = grown(out_items, n_out + cnt, out_items.shape[0])
                out_keys = grown(out_keys, n_out + cnt, out_keys.shape[0])
                for q in range(st, st + cnt):
                    out_items[n_out] = buf[q]
                    out_keys[n_out] = keys[buf[q], face]
                    n_out += 1
        lv_node, lv_info, lv_lo, lv_hi, buf = nx_node, nx_info, nx_lo, nx_hi, nx_buf
        m = nm
    return (node_a[:n_nodes].copy(), node_b[:n_nodes].copy(), split[:n_nodes].copy(),
            out_items[:n_out].copy(), out_keys[:n_out].copy(), deepest, exceeded)


def _check_all(leaf, depth, budget_mb):
    number(leaf, "rc leaf", 1, 1 << 20, integer=True)
    number(depth, "rc depth", 0, 200, integer=True)
    number(budget_mb, "rc budget_mb", 0.0, 1 << 20)


def _prepare(bounds):
    """Widened item boxes, their keys per face, each face's items in key order and the root hypercube."""
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
    return box, np.ascontiguousarray(bx), np.ascontiguousarray(keys), orders, root_lo, root_hi


def _budget_warning(name, budget_mb, nodes, cands, nbytes):
    warnings.warn(f"rc aggregate {name or '(unnamed)'}: the memory budget of {budget_mb} MiB is reached; "
                  f"subdivision stopped at {nodes} hypercubes and {cands} candidates "
                  f"({nbytes / (1 << 20):.3g} MiB). Hits stay exact but tracing is slower; raise budget_mb "
                  f"or lower depth", RcBudgetWarning, stacklevel=3)


def _memory_budget(budget_mb, max_bytes):
    """(bytes the trees may take, whether the memory budget rather than budget_mb sets them)."""
    limit = (memory_limit() if max_bytes is None else int(max_bytes)) // PEAK_FACTOR
    budget = int(float(budget_mb) * (1 << 20))
    return min(budget, limit), limit < budget


def build_rc(bounds, *, leaf=8, depth=40, budget_mb=256.0, name=None, max_bytes=None):
    """Build the ray-classification trees over item boxes, eagerly (lazy=off).

    bounds: (n, 6) item boxes, finite (or the empty box +inf..-inf, which no
    list holds), n >= 1. leaf >= 1: most candidates a hypercube keeps
    without splitting; depth >= 0: most splits below a face root; budget_mb
    >= 0: MiB the finished tree may take (see the module docstring).

    Returns (RcArrays, stats) with stats = {"nodes" (hypercubes), "inner",
    "leaves", "empty_leaves", "refs" (candidates in all lists), "bytes",
    "seconds", "max_depth", "budget_exceeded"}. max_bytes: the memory budget
    (memory.memory_limit() when None); trees that reach it rather than budget_mb are a
    MemoryBudgetError.
    """
    t0 = time.perf_counter()
    _check_all(leaf, depth, budget_mb)
    box, bx, keys, orders, root_lo, root_hi = _prepare(bounds)
    budget, by_memory = _memory_budget(budget_mb, max_bytes)
    node_a, node_b, split, cand, ckeys, deepest, exceeded = _build_kernel(
        bx, keys, orders, root_lo, root_hi, int(leaf), int(depth), budget, KEEP)
    tree = RcArrays(box, np.arange(6, dtype=np.int64), node_a, node_b, split, cand, ckeys)
    leaves = node_b >= 0
    nbytes = NODE_BYTES * len(node_a) + CANDIDATE_BYTES * len(cand)
    if exceeded and by_memory:
        over_budget(budget * PEAK_FACTOR, f"the ray classification of group {name or '(unnamed)'}",
              f"give it a budget_mb under {budget / (1 << 20):.0f} (hits stay exact) or lower depth")
    if exceeded:
        _budget_warning(name, budget_mb, len(node_a), len(cand), nbytes)
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


def start_rc(bounds, *, leaf=8, depth=40, budget_mb=256.0, rays=1, name=None):
    """The start of a lazy ray classification (lazy=on): six root leaves, each face's list
    holding every item with a box, in key order. Arguments as build_rc; rays >= 1: arrivals
    at a leaf before it splits.

    Returns (RcArrays, stats as build_rc's, widened item boxes (n, 6), keys (n, 6)): the
    boxes and keys are what LazyRC needs to split leaves later."""
    t0 = time.perf_counter()
    _check_all(leaf, depth, budget_mb)
    number(rays, "rc rays", 1, 1 << 40, integer=True)
    box, bx, keys, orders, root_lo, root_hi = _prepare(bounds)
    n = orders.shape[1]
    cand = orders.reshape(-1).copy()
    ckeys = np.concatenate([keys[orders[f], f] for f in range(6)])
    tree = RcArrays(box, np.arange(6, dtype=np.int64), np.arange(6, dtype=np.int64) * n,
                    np.full(6, n, np.int64), np.zeros(6), cand, ckeys)
    nbytes = NODE_BYTES * 6 + CANDIDATE_BYTES * len(cand)
    exceeded = nbytes > float(budget_mb) * (1 << 20)
    if exceeded:
        _budget_warning(name, budget_mb, 6, len(cand), nbytes)
    stats = {"nodes": 6, "inner": 0, "leaves": 6, "empty_leaves": 6 if n == 0 else 0, "refs": int(len(cand)),
             "bytes": int(nbytes), "seconds": time.perf_counter() - t0, "max_depth": 0,
             "budget_exceeded": bool(exceeded), "passes": 0, "subdivisions": 0, "refine_seconds": 0.0}
    return tree, stats, bx, keys


# ----------------------------------------------------------------- lazy subdivision

@njit(parallel=True)
def _beam_sides(bx, item, st, m, lo, hi, face, side_mask):
    """side_mask[p] for the p-th candidate of a list at st: bit s set if it meets the beam of
    side s of a split (lo[s], hi[s]); all threads, for long lists."""
    for p in prange(m):
        it = item[st + p]
        side_mask[p] = (1 if meets_beam(bx, it, lo[0], hi[0], face) else 0) | \
            (2 if meets_beam(bx, it, lo[1], hi[1], face) else 0)


@njit
def _refine_kernel(cand, levels, hoff, hist, node_a, node_b, split, key, ref, item, state, cell, n_nodes, n_cands,
                   bx, norm, p_leaf, p_depth, p_rays, p_stale, budget, used, exhausted, subdivisions, keep):
    """Split candidates where their arrivals say so (module docstring), in candidate order.
    cand: candidate leaves, in node order; levels: K of each; hist[hoff[j]:hoff[j] + 2**K]:
    arrivals of this pass in each virtual cell of candidate j. Appends nodes at n_nodes and
    lists at n_cands, growing the arrays as needed. Returns the arrays, n_nodes, n_cands."""
    heap = np.zeros(2 << VIRTUAL_LEVELS, np.int64)
    st_node = np.empty(2 * VIRTUAL_LEVELS + 2, np.int64)
    st_h = np.empty(2 * VIRTUAL_LEVELS + 2, np.int64)
    lo2 = np.empty((2, 5))      # the two children's cells
    hi2 = np.empty((2, 5))
    side_mask = np.zeros(0, np.int64)
    counts = np.zeros(2, np.int64)
    for j in range(cand.shape[0]):
        c = cand[j]
        r = state[c, _OWNER]
        k = levels[j]
        v = 1 << k
        # arrivals per virtual node (heap order: node h has children 2h and 2h + 1, cells at v..2v-1)
        for q in range(v):
            heap[v + q] = hist[hoff[j] + q]
        for h in range(v - 1, 0, -1):
            heap[h] = heap[2 * h] + heap[2 * h + 1]
        state[c, _ARRIVED] += heap[1]
        state[c, _RATE] = heap[1]
        st_node[0] = c
        st_h[0] = 1
        sp = 1
        while sp > 0:
            sp -= 1
            nd = st_node[sp]
            h = st_h[sp]
            m = node_b[nd]
            if exhausted[r] or state[nd, _ARRIVED] < p_rays[r] or m <= p_leaf[r] or \
                    state[nd, _DEPTH] >= p_depth[r] or state[nd, _STALE] >= p_stale[r]:
                continue
            face = state[nd, _FACE]
            dim = _longest(cell[nd, :5], cell[nd, 5:], norm[r])
            mid = 0.5 * (cell[nd, dim] + cell[nd, 5 + dim])
            # the children's lists from the parent's, in the same (key) order
            key = grown(key, n_cands + 2 * m, key.shape[0])
            ref = grown(ref, n_cands + 2 * m, ref.shape[0])
            item = grown(item, n_cands + 2 * m, item.shape[0])
            start0 = n_cands
            st = node_a[nd]
            for side in range(2):
                for q in range(5):
                    lo2[side, q] = cell[nd, q]
                    hi2[side, q] = cell[nd, 5 + q]
            hi2[0, dim] = mid
            lo2[1, dim] = mid
            if m >= PARALLEL_LIST:
                side_mask = grown(side_mask, m, side_mask.shape[0])
                _beam_sides(bx, item, st, m, lo2, hi2, face, side_mask)
            for side in range(2):
                counts[side] = 0
                for q in range(st, st + m):
                    it = item[q]
                    if m >= PARALLEL_LIST:
                        inside = (side_mask[q - st] >> side) & 1 == 1
                    else:
                        inside = meets_beam(bx, it, lo2[side], hi2[side], face)
                    if inside:
                        key[n_cands] = key[q]
                        ref[n_cands] = ref[q]
                        item[n_cands] = it
                        n_cands += 1
                        counts[side] += 1
            delta = 2 * NODE_BYTES + CANDIDATE_BYTES * (counts[0] + counts[1] - m)
            if used[r] + delta > budget[r]:
                # the budget: this aggregate's trees stop growing here
                exhausted[r] = True
                n_cands = start0
                continue
            used[r] += delta
            subdivisions[r] += 1
            node_a = grown(node_a, n_nodes + 2, node_a.shape[0])
            node_b = grown(node_b, n_nodes + 2, node_b.shape[0])
            split = grown(split, n_nodes + 2, split.shape[0])
            state = grown(state, n_nodes + 2, state.shape[0])
            cell = grown(cell, n_nodes + 2, cell.shape[0])
            node_a[nd] = n_nodes
            node_b[nd] = -(dim + 1)
            split[nd] = mid
            pos = start0
            for side in range(2):
                kid = n_nodes + side
                node_a[kid] = pos
                node_b[kid] = counts[side]
                split[kid] = 0.0
                pos += counts[side]
                state[kid, _OWNER] = r
                state[kid, _FACE] = face
                state[kid, _DEPTH] = state[nd, _DEPTH] + 1
                state[kid, _STALE] = state[nd, _STALE] + 1 if counts[side] > keep * m else 0
                # arrivals of this pass in the child's virtual cell, if it is one; beyond the virtual
                # subtree only the parent's are known: half of them are expected next time
                if h < v:
                    state[kid, _ARRIVED] = heap[2 * h + side]
                    state[kid, _RATE] = heap[2 * h + side]
                else:
                    state[kid, _ARRIVED] = 0
                    state[kid, _RATE] = state[nd, _RATE] // 2
                for q in range(10):
                    cell[kid, q] = cell[nd, q]
                if side == 0:
                    cell[kid, 5 + dim] = mid
                else:
                    cell[kid, dim] = mid
            # children inside the virtual subtree (their arrivals known) may split further now, first child first
            if h < v:
                st_node[sp], st_h[sp] = n_nodes + 1, 2 * h + 1
                st_node[sp + 1], st_h[sp + 1] = n_nodes, 2 * h
                sp += 2
            n_nodes += 2
    return node_a, node_b, split, key, ref, item, state, cell, n_nodes, n_cands


@njit
def _virtual_subtrees(cand, levels, cell, state, norm, vdim, vsplit, voff):
    """Split dimension and coordinate of every inner node of each candidate's virtual subtree
    (heap order, node h at vsplit[voff[j] + h - 1]), computed exactly as _refine_kernel splits."""
    lo = np.empty((2 << VIRTUAL_LEVELS, 5))
    hi = np.empty((2 << VIRTUAL_LEVELS, 5))
    for j in range(cand.shape[0]):
        c = cand[j]
        v = 1 << levels[j]
        r = state[c, _OWNER]
        for q in range(5):
            lo[1, q] = cell[c, q]
            hi[1, q] = cell[c, 5 + q]
        for h in range(1, v):
            dim = _longest(lo[h], hi[h], norm[r])
            mid = 0.5 * (lo[h, dim] + hi[h, dim])
            vdim[voff[j] + h - 1] = dim
            vsplit[voff[j] + h - 1] = mid
            if 2 * h < v:
                for q in range(5):
                    lo[2 * h, q] = lo[h, q]
                    hi[2 * h, q] = hi[h, q]
                    lo[2 * h + 1, q] = lo[h, q]
                    hi[2 * h + 1, q] = hi[h, q]
                hi[2 * h, dim] = mid
                lo[2 * h + 1, dim] = mid


def _levels(arrived, rays):
    """K of each candidate's virtual subtree: none without arrivals, else about log2(arrivals / rays) + 2."""
    ratio = arrived // rays
    bits = np.zeros(len(ratio), np.int64)
    nz = ratio > 0
    bits[nz] = np.floor(np.log2(ratio[nz].astype(np.float64))).astype(np.int64) + 1
    return np.where(arrived > 0, np.minimum(VIRTUAL_LEVELS, 1 + bits), 0)


@njit
def _move_lists(leaves, node_a, node_b, key, ref, item, key_out, ref_out, item_out):
    """Copy the lists of `leaves` (in their order) to the front of the *_out arrays and point
    the leaves at their new places."""
    pos = 0
    for leaf in leaves:
        s = node_a[leaf]
        for q in range(s, s + node_b[leaf]):
            key_out[pos] = key[q]
            ref_out[pos] = ref[q]
            item_out[pos] = item[q]
            pos += 1
        node_a[leaf] = pos - node_b[leaf]


_NODE_ARRAYS = ("node_a", "node_b", "split", "state", "cell", "pass_")
_CAND_ARRAYS = ("key", "ref", "item")


class LazyRC:
    """Every lazy ray classification of one built scene, with room to grow its arrays.

    columns: pass counter columns a pass must provide (after counters.N_COUNTERS and
    `base` columns of other lazy structures); refine() takes their counts and returns
    the Geometry to use next. See the module docstring."""

    def __init__(self):
        raise TypeError("use LazyRC.attach(geo, records)")

    @classmethod
    def attach(cls, geo, records, base=0):
        """Take over geo's rc arrays for the lazy rc aggregates in `records` (from flatten: first
        root node, first candidate, items of the root lists, widened boxes, keys, tagged refs,
        box, params, stats dict). Returns (geo viewing the growable arrays, LazyRC)."""
        self = object.__new__(cls)
        self.records = records
        self.base = int(base)
        n, nc = len(geo.rc_node_a), len(geo.keyed_key)
        self.n_nodes, self.n_cands = n, nc
        cap, ccap = n + max(1024, n), nc + max(4096, nc)
        b = self.buf = {}
        for name, a in (("node_a", geo.rc_node_a), ("node_b", geo.rc_node_b), ("split", geo.rc_split),
                        ("key", geo.keyed_key), ("ref", geo.keyed_ref)):
            b[name] = np.empty(ccap if name in _CAND_ARRAYS else cap, a.dtype)
            b[name][:len(a)] = a
        b["state"] = np.zeros((cap, 6), np.int64)
        b["state"][:, _OWNER] = -1
        b["cell"] = np.zeros((cap, 10))
        b["pass_"] = np.full(cap, -1, np.int64)
        b["item"] = np.full(ccap, -1, np.int64)
        boxes = []
        n_items = 0
        for r, rec in enumerate(records):
            node, start, items = rec["node"], rec["cand"], rec["items"]
            b["item"][start:start + len(items)] = items + n_items
            boxes.append(rec["boxes"])
            n_items += len(rec["boxes"])
            root_lo = np.concatenate([rec["box"][:3], [-1.0, -1.0]])
            root_hi = np.concatenate([rec["box"][3:], [1.0, 1.0]])
            for f in range(6):
                b["state"][node + f] = (r, f, 0, 0, 0, 0)
                b["cell"][node + f] = np.concatenate([root_lo, root_hi])
        self.boxes = np.ascontiguousarray(np.concatenate(boxes))
        self.norm = np.array([1.0 / (c[5:] - c[:5]) for c in (b["cell"][rec["node"]] for rec in records)])
        self.leaf = np.array([rec["leaf"] for rec in records], np.int64)
        self.depth = np.array([rec["depth"] for rec in records], np.int64)
        self.rays = np.array([rec["rays"] for rec in records], np.int64)
        self.stale = np.full(len(records), LAZY_STALE_SPLITS, np.int64)
        self.budget_mb = [rec["budget_mb"] for rec in records]
        budgets = [_memory_budget(rec["budget_mb"], rec["max_bytes"]) for rec in records]
        self.budget = np.array([b for b, _ in budgets], np.int64)
        self.by_memory = np.array([m for _, m in budgets], np.bool_)
        self.used = np.array([rec["stats"]["bytes"] for rec in records], np.int64)
        self.exhausted = np.array([rec["stats"]["budget_exceeded"] for rec in records], np.bool_)
        self.warned = self.exhausted.copy()      # start_rc warned already
        self.held = False                        # a checkpoint is out: keep the lists in place
        self.subdivisions = np.zeros(len(records), np.int64)
        self.passes = 0
        self.seconds = 0.0
        roots = np.concatenate([rec["node"] + np.arange(6) for rec in records])
        self.cand = roots[self._may_split(roots)]
        self.levels = np.full(len(self.cand), VIRTUAL_LEVELS, np.int64)   # no arrivals seen yet: look deep
        return self._number(geo), self

    # ------------------------------------------------------------- passes

    @property
    def columns(self) -> int:
        return int(self._widths.sum())

    def _may_split(self, nodes):
        b = self.buf
        own = b["state"][nodes, _OWNER]
        return (b["node_b"][nodes] > self.leaf[own]) & (b["state"][nodes, _DEPTH] < self.depth[own]) & \
            (b["state"][nodes, _STALE] < self.stale[own]) & ~self.exhausted[own]

    def refine(self, geo, pass_counts, base=None):
        """Add a pass's counts ((work items, columns) int64, one row per tile or chunk) and split
        the candidates where rays arrived; number the columns of the next pass from `base`
        (columns of other lazy structures before these). Returns the Geometry to trace with."""
        t0 = time.perf_counter()
        pass_counts = np.asarray(pass_counts)
        if pass_counts.ndim != 2 or pass_counts.shape[1] != self.columns:
            raise ValueError(f"pass counts must have {self.columns} columns, got shape {pass_counts.shape}")
        if base is not None:
            self.base = int(base)
        self.passes += 1
        if len(self.cand):
            b = self.buf
            hist = pass_counts.sum(axis=0, dtype=np.int64)
            hoff = np.concatenate([[0], np.cumsum(self._widths)[:-1]]).astype(np.int64)
            old_n = self.n_nodes
            out = _refine_kernel(self.cand, self.levels, hoff, hist, b["node_a"], b["node_b"], b["split"], b["key"],
                                 b["ref"], b["item"], b["state"], b["cell"], np.int64(self.n_nodes),
                                 np.int64(self.n_cands), self.boxes, self.norm, self.leaf, self.depth, self.rays,
                                 self.stale, self.budget, self.used, self.exhausted, self.subdivisions, KEEP)
            for name, a in zip(("node_a", "node_b", "split", "key", "ref", "item", "state", "cell"), out[:8]):
                b[name] = a
            self.n_nodes, self.n_cands = int(out[8]), int(out[9])
            if len(b["pass_"]) < len(b["node_a"]):
                grown = np.full(len(b["node_a"]), -1, np.int64)
                grown[:old_n] = b["pass_"][:old_n]
                b["pass_"] = grown
            b["pass_"][self.cand] = -1
            # candidates now: old ones still leaves, and the new leaves, in node order
            new = np.arange(old_n, self.n_nodes, dtype=np.int64)
            nodes = np.concatenate([self.cand[b["node_b"][self.cand] >= 0], new[b["node_b"][new] >= 0]])
            self.cand = nodes[self._may_split(nodes)]
            self.levels = _levels(b["state"][self.cand, _RATE], self.rays[b["state"][self.cand, _OWNER]])
            self._warn()
            self._compact()
        self.seconds += time.perf_counter() - t0
        return self._number(geo)

    def _compact(self):
        """Move the leaves' lists together once the split leaves' old lists outnumber them."""
        b, n = self.buf, self.n_nodes
        leaves = np.flatnonzero(b["node_b"][:n] >= 0)
        count = b["node_b"][leaves]
        live = int(count.sum())
        if self.held or self.n_cands <= 2 * live:
            return
        cap = live + max(4096, live)
        moved = [np.empty(cap, b[name].dtype) for name in _CAND_ARRAYS]
        _move_lists(leaves, b["node_a"], b["node_b"], b["key"], b["ref"], b["item"], *moved)
        for name, a in zip(_CAND_ARRAYS, moved):
            b[name] = a
        self.n_cands = live

    def _warn(self):
        for r in np.flatnonzero(self.exhausted & ~self.warned):
            rec = self.records[r]
            if self.by_memory[r]:
                over_budget(int(self.budget[r]) * PEAK_FACTOR,
                      f"the lazy ray classification of group {rec['name'] or '(unnamed)'}",
                      f"give it a budget_mb under {self.budget[r] / (1 << 20):.0f} (hits stay exact) or lower depth")
            sel = self.buf["state"][:self.n_nodes, _OWNER] == r
            refs = int(self.buf["node_b"][:self.n_nodes][sel & (self.buf["node_b"][:self.n_nodes] >= 0)].sum())
            _budget_warning(rec["name"], self.budget_mb[r], int(sel.sum()), refs, int(self.used[r]))
            self.warned[r] = True

    def _number(self, geo):
        """Columns of the candidates (in node order, 2**K each, from base) and their virtual subtrees."""
        b = self.buf
        self._widths = np.left_shift(1, self.levels).astype(np.int64)
        n_cand = len(self.cand)
        b["pass_"][self.cand] = np.arange(n_cand, dtype=np.int64)
        vinfo = np.empty((n_cand, 3), np.int64)
        vinfo[:, 0] = self.base + np.concatenate([[0], np.cumsum(self._widths)[:-1]]).astype(np.int64)
        vinfo[:, 1] = self.levels
        vinfo[:, 2] = np.concatenate([[0], np.cumsum(self._widths - 1)[:-1]]).astype(np.int64)
        n_split = int((self._widths - 1).sum())
        vdim = np.zeros(n_split, np.int64)
        vsplit = np.zeros(n_split)
        _virtual_subtrees(self.cand, self.levels, b["cell"], b["state"], self.norm, vdim, vsplit, vinfo[:, 2].copy())
        self.vinfo, self.vdim, self.vsplit = vinfo, vdim, vsplit
        return self._view(geo)

    def _view(self, geo):
        n, nc, b = self.n_nodes, self.n_cands, self.buf
        return geo._replace(rc_node_a=b["node_a"][:n], rc_node_b=b["node_b"][:n], rc_split=b["split"][:n],
                            keyed_key=b["key"][:nc], keyed_ref=b["ref"][:nc], rc_pass=b["pass_"][:n],
                            rc_vinfo=self.vinfo, rc_vdim=self.vdim, rc_vsplit=self.vsplit)

    # ------------------------------------------------------------- all-hits queries run twice

    def checkpoint(self):
        """The state to go back to, so that a second run over the same rays meets the same trees."""
        n, b = self.n_nodes, self.buf
        self.held = True
        return dict(n_nodes=n, n_cands=self.n_cands, arrays={name: b[name][:n].copy() for name in _NODE_ARRAYS},
                    cand=self.cand.copy(), levels=self.levels.copy(), base=self.base, passes=self.passes,
                    used=self.used.copy(), exhausted=self.exhausted.copy(), warned=self.warned.copy(),
                    subdivisions=self.subdivisions.copy())

    def restore(self, mark, geo):
        """Back to `mark` (from checkpoint); returns the Geometry to use."""
        n = mark["n_nodes"]
        for name, a in mark["arrays"].items():
            self.buf[name][:n] = a
        self.buf["pass_"][n:] = -1
        self.n_nodes, self.n_cands = n, mark["n_cands"]
        self.cand, self.levels, self.base = mark["cand"], mark["levels"], mark["base"]
        self.passes = mark["passes"]
        self.used, self.exhausted = mark["used"], mark["exhausted"]
        self.warned, self.subdivisions = mark["warned"], mark["subdivisions"]
        self.held = False
        return self._number(geo)

    # ------------------------------------------------------------- statistics

    def update_stats(self, build, geo):
        """Write the trees as they now stand into the build statistics of flatten()."""
        n, b = self.n_nodes, self.buf
        owner = b["state"][:n, _OWNER]
        node_b = b["node_b"][:n]
        for r, rec in enumerate(self.records):
            sel = owner == r
            tree = tree_counts(node_b[sel])
            rec["stats"].update(tree, bytes=NODE_BYTES * tree["nodes"] + CANDIDATE_BYTES * tree["refs"],
                                max_depth=int(b["state"][:n, _DEPTH][sel].max()), passes=self.passes,
                                subdivisions=int(self.subdivisions[r]), refine_seconds=self.seconds,
                                budget_exceeded=bool(self.exhausted[r]))
        scene_totals(build, geo, self.passes, int(self.subdivisions.sum()), self.seconds)


# ----------------------------------------------------------------- flat layout (see the module docstring) and walk


CODE = 4
FIELDS = (   # and the driver's keyed lists, keyed_key and keyed_ref (walk.py): the candidate lists
    Field("rc_face_root", np.int64, (6,)), Field("rc_node_a", np.int64, ()), Field("rc_node_b", np.int64, ()),
    Field("rc_split", np.float64, ()), Field("rc_pass", np.int64, ()), Field("rc_vinfo", np.int64, (3,)),
    Field("rc_vdim", np.int64, ()), Field("rc_vsplit", np.float64, ()),
)


def append_rc(flat, tree: RcArrays, refs, box) -> int:
    """Store rc trees over refs as the next aggregate."""
    n0, k0 = flat.size("rc_node_b"), flat.size("keyed_key")
    r = flat.size("rc_face_root")
    flat.append(rc_face_root=tree.face_root[None] + n0,
                rc_node_a=np.where(tree.node_b < 0, tree.node_a + n0, tree.node_a + k0), rc_node_b=tree.node_b,
                rc_split=tree.split, rc_pass=np.full(len(tree.node_b), -1), keyed_key=tree.keys, keyed_ref=refs[tree.items])
    return flat.add_aggregate(CODE, r, len(tree.node_b), box)


@njit(inline="always")
def walk_step(geo, step, a, te, ray, lo, best_t, f, sp, ws, cnt):
    """walk.py's step contract: the ray's hypercube's candidates, a keyed list."""
    ox, oy, oz, dx, dy, dz, _, _, _ = ray
    s, e, key_o, key_d = classify(geo.rc_face_root, geo.rc_node_a, geo.rc_node_b, geo.rc_pass, geo.rc_split,
                                  geo.rc_vdim, geo.rc_vinfo, geo.rc_vsplit, a, te, ox, oy, oz, dx, dy, dz, best_t,
                                  ws.frame_f, f, cnt)
    return sp, s, e, True, key_o, key_d, ray, best_t, False


@njit(private=True)
def classify(rc_face_root, rc_node_a, rc_node_b, rc_pass, rc_split, rc_vdim, rc_vinfo, rc_vsplit, a, te, ox, oy, oz,
             dx, dy, dz, best_t, frame_f, f, cnt):
    """Classify the ray (direction-cube face, u, v, and its entry point at te as origin),
    descend its face's 5D tree to one hypercube and return (s, e, key_o, key_d): the
    hypercube's keyed candidate list (none: s == e), also kept in the frame for resuming.
    A lazy leaf that may still split (rc_pass >= 0) counts the ray's arrival in
    cnt[N_COUNTERS + column], the column of the cell of its virtual subtree the ray's 5D
    point falls in, where the kernel gave cnt room for it."""
    if te > best_t:
        return 0, 0, 0.0, 0.0
    rax, ray_, raz = abs(dx), abs(dy), abs(dz)
    if rax >= ray_ and rax >= raz:
        face = 0 if dx > 0.0 else 1
        key_d, key_o, u, v = rax, (ox if dx > 0.0 else -ox), dy / rax, dz / rax
    elif ray_ >= raz:
        face = 2 if dy > 0.0 else 3
        key_d, key_o, u, v = ray_, (oy if dy > 0.0 else -oy), dz / ray_, dx / ray_
    else:
        face = 4 if dz > 0.0 else 5
        key_d, key_o, u, v = raz, (oz if dz > 0.0 else -oz), dx / raz, dy / raz
    px, py, pz = ox + te * dx, oy + te * dy, oz + te * dz
    node = rc_face_root[a, face]
    while True:
        cnt[C.CELLS_VISITED] += 1
        nb = rc_node_b[node]
        if nb >= 0:
            break
        q = px if nb == -1 else (py if nb == -2 else (pz if nb == -3 else (u if nb == -4 else v)))
        node = rc_node_a[node] + (0 if q < rc_split[node] else 1)
    pj = rc_pass[node]
    if pj >= 0:
        # a lazy leaf that may split: count the arrival in its virtual cell
        col = C.N_COUNTERS + rc_vinfo[pj, 0]
        k = rc_vinfo[pj, 1]
        if col + (1 << k) <= cnt.shape[0]:
            off = rc_vinfo[pj, 2] - 1
            h = 1
            for _ in range(k):
                dim = rc_vdim[off + h]
                q = px if dim == 0 else (py if dim == 1 else (pz if dim == 2 else (u if dim == 3 else v)))
                h = 2 * h + (0 if q < rc_vsplit[off + h] else 1)
            cnt[col + h - (1 << k)] += 1
    cnt[C.CELLS_LEAVES] += 1
    if nb == 0:
        cnt[C.CELLS_EMPTY] += 1
        return 0, 0, 0.0, 0.0
    s = rc_node_a[node]
    e = s + nb
    frame_f[f, F_KEY_END], frame_f[f, F_KEY_O], frame_f[f, F_KEY_D] = e, key_o, key_d
    return s, e, key_o, key_d


def flatten(builder, params, refs, bounds, name, box):
    flat = builder.flat
    if params["lazy"]:
        # six root leaves now, split between passes where rays arrive (LazyRC)
        tree, stats, boxes, keys = start_rc(bounds, leaf=params["leaf"], depth=params["depth"],
                                            budget_mb=params["budget_mb"], rays=params["rays"], name=name)
        flat.lazy[KIND.name].append(dict(params, node=flat.size("rc_node_b"), cand=flat.size("keyed_key"),
                                         items=tree.items, boxes=boxes, box=tree.box, stats=stats, name=name,
                                         max_bytes=builder.max_bytes))
    else:
        tree, stats = build_rc(bounds, leaf=params["leaf"], depth=params["depth"], budget_mb=params["budget_mb"],
                               name=name, max_bytes=builder.max_bytes)
    return append_rc(flat, tree, refs, box), stats


TESTS_PER_STEP = 8       # test.rc: the first tests of each hypercube's list; test.rc.more: the rest


def features(stats, f, used) -> None:
    """The cost model's features. In a render walked by ray classification alone, the first
    TESTS_PER_STEP ray/primitive tests of each hypercube visited (test.rc): its candidate lists,
    sorted by distance, send them to primitives scattered in memory (clearly more a test than a
    grid's in the reference costs); the tests further down a long list (test.rc.more) cost no
    more than a grid's (priced as the first, SPD balls' and shells' long lists of spheres were
    much over-predicted); and the corners its tests walked (polygon.corner.rc). A lazy one's
    rays weighted by log2(1 + MiB of its structure) (ray.lazy.rc_mb: a ray's hypercube and
    candidates are found in memory that grows with the refinement), and its refinement's
    references by the MiB themselves (refine.rc.ref_size: past the caches, at the hundreds of
    MiB rc reaches on a 256-pixel render, a reference costs markedly more than at a few MiB)."""
    if used == {"rc"}:
        tests = sum(float(stats.get(f"tests.{k}", 0)) for k in PRIMITIVE_KINDS)
        f["test.rc"] = min(tests, TESTS_PER_STEP * f["step.rc"])
        f["test.rc.more"] = tests - f["test.rc"]
        f["polygon.corner.rc"] = float(stats.get("polygon.corners", 0))
    rays = f["ray.shaded"] + f["ray.shadow"]
    for a in getattr(stats, "aggregates", []):
        if "subdivisions" in a and a.get("kind", "").split("(")[0] == "rc":
            megabytes = math.log2(1.0 + a.get("bytes", 0) / 2 ** 20)
            f["ray.lazy.rc_mb"] = f.get("ray.lazy.rc_mb", 0.0) + rays * megabytes
            f["refine.rc.ref_size"] = f.get("refine.rc.ref_size", 0.0) + float(a.get("refs", 0)) * a.get("bytes", 0) / 2 ** 20


def references(geo, a) -> np.ndarray:
    """Every reference of rc aggregate a's candidate lists, once (Walk.references)."""
    todo, found = list(geo.rc_face_root[geo.agg_start[a]]), []
    seen = set()
    while todo:
        node = int(todo.pop())
        if node in seen:
            continue
        seen.add(node)
        nb = int(geo.rc_node_b[node])
        if nb < 0:
            todo += [int(geo.rc_node_a[node]), int(geo.rc_node_a[node]) + 1]
        elif nb:
            found.append(geo.keyed_ref[geo.rc_node_a[node]:geo.rc_node_a[node] + nb])
    return np.unique(np.concatenate(found)) if found else np.zeros(0, np.int64)


def cells(geo, a) -> Cells:
    """The aggregate's box (its beams live in the space of rays), holding its candidates (Walk.cells)."""
    return one_cell(geo.agg_bounds[a], 0, len(references(geo, a)))


WALK = Walk(code=CODE, name="rc", fields=FIELDS, step=walk_step, features=features, cells=cells,
            references=references)
# the annealer does not offer it: a sample of rays would price the lazy one as the coarse trees it
# leaves, and the eager one costs more to build, on scenes of thousands of items, than a search has
# time for
KIND = Kind("rc", "ray classification (Arvo-Kirk 1987): rays as 5D points (origin, direction-cube face and "
              "u, v), six 5D bisection trees, candidate lists tested near first; lazy (default): each face's root "
              "starts as one leaf, and between passes of rays (those of lazyoctree) a leaf where at least `rays` "
              "rays arrived is split, several levels where the arrivals go on; lazy=off builds the whole trees "
              "before any ray", (
    Param("leaf", 8, "a hypercube with at most this many candidates is not split", int, 1, 1 << 20),
    Param("depth", 40, "most splits below a face's root hypercube", int, 0, 200),
    Param("budget_mb", 256.0, "MiB the trees and candidate lists may take; reaching it stops subdivision "
          "with a warning (hits stay exact)", float, 0.0, 1 << 20),
    Param("lazy", True, "on: subdivide lazily where rays arrive (Arvo and Kirk), a hypercube stopping after 40 "
          "splits in a row that each keep more than 3/4 of its candidates; off: eagerly, breadth first over all "
          "of 5D space until leaf, depth, 5 such splits or the budget stop it", bool),
    Param("rays", 1, "lazy: rays that must arrive at a leaf before it is split", int, 1, 1 << 40),
), flatten=flatten, walk=WALK, lazy=LazyRC)

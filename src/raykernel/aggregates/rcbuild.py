"""Ray classification's eager build: the beam test and the six 5D trees over item boxes (rc.py's layout).

    tree, stats = build_rc(item_bounds, leaf=8, depth=40, budget_mb=256)   # eager: the whole trees now
    tree, stats, boxes, keys = start_rc(item_bounds, rays=1)   # lazy: six root leaves (rclazy.LazyRC grows them)
    face, u, v = face_of((dx, dy, dz))                         # the direction-cube face a ray is classified by
    meets_beam(boxes, i, lo, hi, face)                         # does item box i meet hypercube lo..hi's beam?

rc.py's docstring describes the rays as 5D points, the trees, the candidate
lists, their keys and the memory budget; rclazy.py splits leaves where rays
arrive, rcwalk.py is what a ray runs.
"""

from __future__ import annotations

import time
import warnings
from typing import NamedTuple

import numpy as np

from ..geometry.config import njit
from ..options import number
from .grid import grid_box
from .memory import grown, memory_limit, over_budget

__all__ = ["RcArrays", "RcBudgetWarning", "build_rc", "start_rc", "face_of", "meets_beam", "longest",
           "budget_warning", "memory_budget", "NODE_BYTES", "CANDIDATE_BYTES", "KEEP", "PEAK_FACTOR"]

NODE_BYTES = 24
CANDIDATE_BYTES = 16
KEEP = 0.75                 # a child keeping more than this share of its parent's list made no progress
STALE_SPLITS = 5            # splits in a row that removed nothing before a hypercube stops splitting
BOX_MARGIN = 1e-8           # item boxes widened by this fraction of the aggregate's size
UV_MARGIN = 1e-9            # direction cells widened by this much in u and v
PEAK_FACTOR = 4            # memory at the peak of a build per byte of the finished trees (doubling, copies)


class RcBudgetWarning(UserWarning):
    """A ray-classification build reached its memory budget and stopped subdividing."""


class RcArrays(NamedTuple):
    """Six 5D bisection trees and their candidate lists; see rc.py's docstring."""

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
def longest(lo, hi, norm):
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
    """Breadth-first build of the six face trees; see rc.py's docstring.
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
                dim = longest(lv_lo[j], lv_hi[j], norm)
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


def budget_warning(name, budget_mb, nodes, cands, nbytes):
    warnings.warn(f"rc aggregate {name or '(unnamed)'}: the memory budget of {budget_mb} MiB is reached; "
                  f"subdivision stopped at {nodes} hypercubes and {cands} candidates "
                  f"({nbytes / (1 << 20):.3g} MiB). Hits stay exact but tracing is slower; raise budget_mb "
                  f"or lower depth", RcBudgetWarning, stacklevel=3)


def memory_budget(budget_mb, max_bytes):
    """(bytes the trees may take, whether the memory budget rather than budget_mb sets them)."""
    limit = (memory_limit() if max_bytes is None else int(max_bytes)) // PEAK_FACTOR
    budget = int(float(budget_mb) * (1 << 20))
    return min(budget, limit), limit < budget


def build_rc(bounds, *, leaf=8, depth=40, budget_mb=256.0, name=None, max_bytes=None):
    """Build the ray-classification trees over item boxes, eagerly (lazy=off).

    bounds: (n, 6) item boxes, finite (or the empty box +inf..-inf, which no
    list holds), n >= 1. leaf >= 1: most candidates a hypercube keeps
    without splitting; depth >= 0: most splits below a face root; budget_mb
    >= 0: MiB the finished tree may take (see rc.py's docstring).

    Returns (RcArrays, stats) with stats = {"nodes" (hypercubes), "inner",
    "leaves", "empty_leaves", "refs" (candidates in all lists), "bytes",
    "seconds", "max_depth", "budget_exceeded"}. max_bytes: the memory budget
    (memory.memory_limit() when None); trees that reach it rather than budget_mb are a
    MemoryBudgetError.
    """
    t0 = time.perf_counter()
    _check_all(leaf, depth, budget_mb)
    box, bx, keys, orders, root_lo, root_hi = _prepare(bounds)
    budget, by_memory = memory_budget(budget_mb, max_bytes)
    node_a, node_b, split, cand, ckeys, deepest, exceeded = _build_kernel(
        bx, keys, orders, root_lo, root_hi, int(leaf), int(depth), budget, KEEP)
    tree = RcArrays(box, np.arange(6, dtype=np.int64), node_a, node_b, split, cand, ckeys)
    leaves = node_b >= 0
    nbytes = NODE_BYTES * len(node_a) + CANDIDATE_BYTES * len(cand)
    if exceeded and by_memory:
        over_budget(budget * PEAK_FACTOR, f"the ray classification of group {name or '(unnamed)'}",
              f"give it a budget_mb under {budget / (1 << 20):.0f} (hits stay exact) or lower depth")
    if exceeded:
        budget_warning(name, budget_mb, len(node_a), len(cand), nbytes)
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
        budget_warning(name, budget_mb, 6, len(cand), nbytes)
    stats = {"nodes": 6, "inner": 0, "leaves": 6, "empty_leaves": 6 if n == 0 else 0, "refs": int(len(cand)),
             "bytes": int(nbytes), "seconds": time.perf_counter() - t0, "max_depth": 0,
             "budget_exceeded": bool(exceeded), "passes": 0, "subdivisions": 0, "refine_seconds": 0.0}
    return tree, stats, bx, keys

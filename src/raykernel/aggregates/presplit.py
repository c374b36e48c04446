"""Early split clipping (Ernst and Greiner 2007): flat primitives cut into pieces with tight
boxes before a BVH is built over them, for `bvh(split=N)`.

    piece_item, piece_box = split_boxes(outline_verts, outline_start, outline_count, item_boxes, 8)
    tree, stats = build_bvh(piece_box)                 # over the pieces
    tree = leaves_of_items(tree, piece_item)           # leaves over the items, each once per leaf

A long thin polygon or triangle lying across the axes (a facet of a gem that runs from its point
to its girdle) has a box far larger than itself, and every ray through that box tests it. Cut
across its box's longest axis, its two halves have boxes whose surface areas add up to about
half the whole's, and the SAH build then places the halves apart. A piece is cut in half again
while that lowers the sum of its boxes' surface areas by at least a quarter (CUT_GAIN: a flat
rectangle lying along the axes gains nothing, so it stays whole), up to `pieces` pieces per
item. Only the boxes are cut: every piece refers to its whole primitive, which a leaf holds once
however many of its pieces landed there. A primitive can then be in several leaves, and a ray
may test it more than once (counted each time), as a grid's cells share items; every hit found
is a true hit of the whole primitive, and the pieces' boxes together cover it, so the closest
hit is the same.

Clipping is Sutherland-Hodgman against the cut plane, which also serves concave polygons: the
points it keeps are the polygon's corners on one side and its edges' crossings of the plane, so
their box is the box of that side's part. The coordinate on the cut axis is set to the plane's
exactly, and a piece's box never leaves its item's box.
"""

from __future__ import annotations

import numpy as np

from ..geometry.config import njit
from .bvhtree import BVHArrays
from .memory import grown

CUT_GAIN = 0.75          # a piece is cut when its halves' box areas add up to at most this times its own
MAX_PIECES = 64


@njit
def _area2(px, py, pz, k):
    """Twice the area of the planar polygon p[:k]."""
    ax = ay = az = 0.0
    for i in range(k):
        j = i + 1 if i + 1 < k else 0
        ax += py[i] * pz[j] - pz[i] * py[j]
        ay += pz[i] * px[j] - px[i] * pz[j]
        az += px[i] * py[j] - py[i] * px[j]
    return np.sqrt(ax * ax + ay * ay + az * az)


@njit
def _surface(b):
    ex, ey, ez = b[3] - b[0], b[4] - b[1], b[5] - b[2]
    return 2.0 * (ex * ey + ey * ez + ez * ex)


@njit
def _clip(px, py, pz, k, axis, c, below, qx, qy, qz):
    """The part of polygon p[:k] with coordinate `axis` <= c (below) or >= c, into q; its corners."""
    m = 0
    for i in range(k):
        j = i + 1 if i + 1 < k else 0
        a = (px[i], py[i], pz[i])[axis]
        b = (px[j], py[j], pz[j])[axis]
        a_in = a <= c if below else a >= c
        b_in = b <= c if below else b >= c
        if a_in:
            qx[m], qy[m], qz[m] = px[i], py[i], pz[i]
            m += 1
        if a_in != b_in:
            s = (c - a) / (b - a)
            qx[m] = px[i] + s * (px[j] - px[i])
            qy[m] = py[i] + s * (py[j] - py[i])
            qz[m] = pz[i] + s * (pz[j] - pz[i])
            if axis == 0:
                qx[m] = c
            elif axis == 1:
                qy[m] = c
            else:
                qz[m] = c
            m += 1
    return m


@njit
def _box_of(px, py, pz, k, limit, out):
    """The box of p[:k], inside `limit`."""
    out[0], out[1], out[2] = np.inf, np.inf, np.inf
    out[3], out[4], out[5] = -np.inf, -np.inf, -np.inf
    for i in range(k):
        out[0], out[3] = min(out[0], px[i]), max(out[3], px[i])
        out[1], out[4] = min(out[1], py[i]), max(out[4], py[i])
        out[2], out[5] = min(out[2], pz[i]), max(out[5], pz[i])
    for a in range(3):
        out[a] = max(out[a], limit[a])
        out[a + 3] = min(out[a + 3], limit[a + 3])


@njit
def _split_kernel(verts, start, count, boxes, pieces):
    n = boxes.shape[0]
    cap = n + 16
    item = np.empty(cap, np.int64)
    out = np.empty((cap, 6))
    m = 0
    most = 0
    for r in range(n):
        most = max(most, count[r])
    width = 2 * most + 4          # corners a piece may have: a cut of k corners leaves at most 2k
    depth_max = 0
    while (1 << depth_max) < pieces:
        depth_max += 1
    # a stack of pieces: corners, count, box, depth
    sx = np.empty((depth_max + 2, width))
    sy = np.empty((depth_max + 2, width))
    sz = np.empty((depth_max + 2, width))
    sk = np.empty(depth_max + 2, np.int64)
    sb = np.empty((depth_max + 2, 6))
    sd = np.empty(depth_max + 2, np.int64)
    lx, ly, lz = np.empty(width), np.empty(width), np.empty(width)
    rx, ry, rz = np.empty(width), np.empty(width), np.empty(width)
    lb, rb = np.empty(6), np.empty(6)
    for r in range(n):
        k = count[r]
        if k < 3 or pieces <= 1:        # no outline (a sphere, a cone, a child aggregate): whole
            if m == cap:
                cap *= 2
                item, out = grown(item, cap, m), grown(out, cap, m)
            item[m] = r
            out[m] = boxes[r]
            m += 1
            continue
        for i in range(k):
            sx[0, i], sy[0, i], sz[0, i] = verts[start[r] + i, 0], verts[start[r] + i, 1], verts[start[r] + i, 2]
        sk[0] = k
        sb[0] = boxes[r]
        sd[0] = 0
        top = 1
        while top > 0:
            top -= 1
            k = sk[top]
            b = sb[top].copy()
            d = sd[top]
            cut = False
            # a piece whose halves might outgrow the buffers (a concave one cut many times) stays whole
            if d < depth_max and 2 * k <= width and _area2(sx[top], sy[top], sz[top], k) > 0.0:
                axis = 0
                for a in range(1, 3):
                    if b[a + 3] - b[a] > b[axis + 3] - b[axis]:
                        axis = a
                c = 0.5 * (b[axis] + b[axis + 3])
                kl = _clip(sx[top], sy[top], sz[top], k, axis, c, True, lx, ly, lz)
                kr = _clip(sx[top], sy[top], sz[top], k, axis, c, False, rx, ry, rz)
                if kl > 0 and kr > 0:
                    lim = b.copy()
                    lim[axis + 3] = c
                    _box_of(lx, ly, lz, kl, lim, lb)
                    lim[axis + 3] = b[axis + 3]
                    lim[axis] = c
                    _box_of(rx, ry, rz, kr, lim, rb)
                    if _surface(lb) + _surface(rb) <= CUT_GAIN * _surface(b):
                        cut = True
            if cut:
                for i in range(kl):
                    sx[top, i], sy[top, i], sz[top, i] = lx[i], ly[i], lz[i]
                sk[top], sb[top], sd[top] = kl, lb, d + 1
                for i in range(kr):
                    sx[top + 1, i], sy[top + 1, i], sz[top + 1, i] = rx[i], ry[i], rz[i]
                sk[top + 1], sb[top + 1], sd[top + 1] = kr, rb, d + 1
                top += 2
            else:
                if m == cap:
                    cap *= 2
                    item, out = grown(item, cap, m), grown(out, cap, m)
                item[m] = r
                out[m] = b
                m += 1
    return item[:m].copy(), out[:m].copy()


def split_boxes(verts, start, count, boxes, pieces: int):
    """(piece_item, piece_box): the pieces of every item, in item order. Items with fewer than 3
    outline corners (count: 0 for spheres, cones and child aggregates) stay whole, as their box."""
    verts = np.ascontiguousarray(verts, np.float64).reshape(-1, 3)
    return _split_kernel(verts, np.ascontiguousarray(start, np.int64), np.ascontiguousarray(count, np.int64),
                         np.ascontiguousarray(boxes, np.float64), np.int64(min(pieces, MAX_PIECES)))


def leaves_of_items(tree: BVHArrays, piece_item: np.ndarray) -> BVHArrays:
    """The tree over pieces as a tree over their items: each leaf holds each of its pieces' items
    once, in the order first met."""
    first, count, order = _dedup_leaves(tree.first, tree.count, np.ascontiguousarray(piece_item[tree.order]))
    return BVHArrays(tree.bounds, first, count, order)


@njit
def _dedup_leaves(first, count, items):
    first, count = first.copy(), count.copy()
    order = np.empty(items.shape[0], np.int64)
    at = 0
    for node in range(count.shape[0]):
        if count[node] == 0:
            continue
        s, e = first[node], first[node] + count[node]
        first[node] = at
        for i in range(s, e):
            seen = False
            for j in range(first[node], at):
                if order[j] == items[i]:
                    seen = True
                    break
            if not seen:
                order[at] = items[i]
                at += 1
        count[node] = at - first[node]
    return first, count, order[:at].copy()

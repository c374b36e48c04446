"""Bins for the crossings test of polygons with many corners (Haines, "Point in Polygon
Strategies", Graphics Gems IV): the polygon's 2D projection cut into horizontal bands, each
listing the edges that reach into it, so that a point's test walks its band's edges only.

    band, band_f, band_i = build(verts, start, count, axis)     # flatten: one table per large polygon
    inside, walked = point_in_bands(verts, start, count, iu, iv, u0, v0, band_f, band_i, band[p])

The result is the crossings test's, bit for bit: an edge can change the parity only where
the point's v lies in [min, max) of the edge's two v's, so an edge outside the point's band
cannot; the edges of the band are tested by the same step (`crosses`, as primitives.point_in_polygon)
and parity does not depend on their order. Horizontal edges never count and are listed in
no band. A point outside [vmin, vmax) of the polygon is outside it with no edge walked.

Tables (one per polygon of at least MIN_CORNERS corners whose projection has height; band -1
for the others, which walk every corner):
    band_f[o:]   number of bands B, B / (vmax - vmin), the band lists' offset q in band_i,
                 then the B + 1 band boundaries vmin = b0 <= b1 <= ... <= bB = vmax
    band_i[q:]   B + 1 offsets (absolute, into band_i) of the bands' edge lists, then the lists:
                 edge e runs from corner e - 1 (the last corner for e = 0) to corner e
A point's band is found by arithmetic and then checked against the stored boundaries, so
rounding in the arithmetic cannot put it in the wrong one. The build finds each edge's first
and last band the same way, so it takes time and memory in proportion to the corners and
the lists, not to corners times bands.
"""

from __future__ import annotations

import numpy as np

from .config import njit

MIN_CORNERS = 16        # smaller polygons walk every corner: the table would cost more than it saves
CORNERS_PER_BAND = 4    # bands per polygon: corners / CORNERS_PER_BAND, at most MAX_BANDS
MAX_BANDS = 64
_HEAD = 3               # B, scale, q before the boundaries


@njit(inline="always")
def plane_coordinates(axis, px, py, pz):
    """(iu, iv, u, v): the coordinates of the plane that drops `axis`, in the crossings test's
    order, and the point's in it."""
    if axis == 0:
        return 1, 2, py, pz
    if axis == 1:
        return 2, 0, pz, px
    return 0, 1, px, py


@njit(inline="always")
def crosses(verts, i, j, iu, iv, u0, v0):
    """Whether the edge from corner j to corner i crosses the line v = v0 strictly right of
    the point (u0, v0): the crossings test's step, with half-open rules. num is negated
    exactly when the edge is walked the other way, so two polygons sharing an edge agree:
    a point on it lies in exactly one of them."""
    ui, vi = verts[i, iu] - u0, verts[i, iv] - v0
    uj, vj = verts[j, iu] - u0, verts[j, iv] - v0
    if (vi > 0.0) == (vj > 0.0):
        return False
    num = ui * vj - uj * vi
    return num != 0.0 and (vj > vi) == (num > 0.0)


@njit(inline="always")
def _bands(count):
    return min(MAX_BANDS, max(2, count // CORNERS_PER_BAND))


@njit(inline="always")
def _band_of(band_f, o, v):
    """The band k of the table at band_f[o] with b_k <= v < b_(k+1), for vmin <= v < vmax: by
    arithmetic, then moved to agree with the stored boundaries."""
    b = np.int64(band_f[o])
    first = o + _HEAD
    k = min(max(np.int64((v - band_f[first]) * band_f[o + 1]), np.int64(0)), b - 1)
    while v < band_f[first + k]:
        k -= 1
    while v >= band_f[first + k + 1]:
        k += 1
    return k


@njit(inline="always")
def _edge_bands(band_f, o, e_lo, e_hi):
    """The bands first .. last that the edge's heights [e_lo, e_hi) reach into (e_lo < e_hi):
    every band where a point can lie with e_lo <= v < e_hi."""
    b = np.int64(band_f[o])
    first = _band_of(band_f, o, e_lo)
    last = b - 1 if e_hi >= band_f[o + _HEAD + b] else _band_of(band_f, o, e_hi)
    while last > first and band_f[o + _HEAD + last] >= e_hi:
        last -= 1           # a band that starts at e_hi holds no point below it
    return first, last


@njit
def _build(verts, start, count, axis):
    n = start.shape[0]
    band = np.full(n, -1, np.int64)
    height = np.zeros((n, 2))
    size_f = 0
    for p in range(n):          # which polygons get a table: enough corners, and height
        c = count[p]
        if c < MIN_CORNERS:
            continue
        _, iv, _, _ = plane_coordinates(axis[p], 0.0, 0.0, 0.0)
        lo, hi = verts[start[p], iv], verts[start[p], iv]
        for k in range(start[p], start[p] + c):
            lo, hi = min(lo, verts[k, iv]), max(hi, verts[k, iv])
        if hi > lo and np.isfinite(hi - lo):
            band[p] = size_f
            height[p, 0], height[p, 1] = lo, hi
            size_f += _HEAD + _bands(c) + 1
    band_f = np.zeros(size_f)
    sizes = np.zeros(size_f, np.int64)      # edges per band, at each table's boundary slots
    size_i = 0
    for p in range(n):          # the boundaries, and how many edges each band lists
        o = band[p]
        if o < 0:
            continue
        c, s = count[p], start[p]
        _, iv, _, _ = plane_coordinates(axis[p], 0.0, 0.0, 0.0)
        lo, hi = height[p, 0], height[p, 1]
        b = _bands(c)
        band_f[o], band_f[o + 1] = b, b / (hi - lo)
        band_f[o + _HEAD] = lo
        for k in range(1, b):
            band_f[o + _HEAD + k] = min(hi, max(band_f[o + _HEAD + k - 1], lo + (hi - lo) * k / b))
        band_f[o + _HEAD + b] = hi
        for e in range(c):
            i = s + e
            j = s + c - 1 if e == 0 else i - 1
            e_lo, e_hi = min(verts[i, iv], verts[j, iv]), max(verts[i, iv], verts[j, iv])
            if e_lo < e_hi:     # an edge can count for a point v only where e_lo <= v < e_hi
                first, last = _edge_bands(band_f, o, e_lo, e_hi)
                for k in range(first, last + 1):
                    sizes[o + k] += 1
        size_i += b + 1
        for k in range(b):
            size_i += sizes[o + k]
    band_i = np.zeros(size_i, np.int64)
    used = 0
    for p in range(n):          # the lists
        o = band[p]
        if o < 0:
            continue
        c, s = count[p], start[p]
        _, iv, _, _ = plane_coordinates(axis[p], 0.0, 0.0, 0.0)
        b = np.int64(band_f[o])
        band_f[o + 2] = used
        at = used + b + 1
        for k in range(b):
            band_i[used + k] = at
            at += sizes[o + k]
        band_i[used + b] = at
        fill = band_i[used:used + b].copy()
        for e in range(c):
            i = s + e
            j = s + c - 1 if e == 0 else i - 1
            e_lo, e_hi = min(verts[i, iv], verts[j, iv]), max(verts[i, iv], verts[j, iv])
            if e_lo < e_hi:
                first, last = _edge_bands(band_f, o, e_lo, e_hi)
                for k in range(first, last + 1):
                    band_i[fill[k]] = e
                    fill[k] += 1
        used = at
    return band, band_f, band_i


def build(verts, start, count, axis):
    """(band, band_f, band_i): the bins of every polygon of at least MIN_CORNERS corners
    (band[p] = -1 for the others), for point_in_bands."""
    start = np.ascontiguousarray(start, np.int64)
    if not np.any(np.asarray(count) >= MIN_CORNERS):
        return np.full(len(start), -1, np.int64), np.zeros(0), np.zeros(0, np.int64)
    return _build(np.ascontiguousarray(verts, np.float64), start, np.ascontiguousarray(count, np.int64),
                  np.ascontiguousarray(axis, np.int64))


@njit(inline="always")
def point_in_bands(verts, start, count, iu, iv, u0, v0, band_f, band_i, o):
    """(point_in_polygon's answer for the point (u0, v0) of the plane (iu, iv), the edges walked),
    walking only the edges of the point's band of the table at band_f[o]."""
    b = np.int64(band_f[o])
    if not (band_f[o + _HEAD] <= v0 < band_f[o + _HEAD + b]):
        return False, np.int64(0)      # below or above every corner: no edge can cross
    k = _band_of(band_f, o, v0)
    q = np.int64(band_f[o + 2])
    lo, hi = band_i[q + k], band_i[q + k + 1]
    inside = False
    for m in range(lo, hi):
        e = band_i[m]
        i = start + e
        j = start + count - 1 if e == 0 else i - 1
        if crosses(verts, i, j, iu, iv, u0, v0):
            inside = not inside
    return inside, hi - lo

"""Bins for the crossings test of polygons with many corners (Haines, "Point in Polygon
Strategies", Graphics Gems IV): the polygon's 2D projection cut into horizontal bands, each
listing the edges that reach into it, so that a point's test walks its band's edges only.

    band, band_f, band_i = build(verts, start, count, axis)     # flatten: one table per large polygon
    inside, walked = point_in_bands(verts, start, count, iu, iv, u0, v0, band_f, band_i, band[p])

The result is the crossings test's, bit for bit: an edge can change the parity only where
the point's v lies in [min, max) of the edge's two v's, so an edge outside the point's band
cannot; the edges of the band are tested by the same arithmetic (primitives.point_in_polygon)
and parity does not depend on their order. Horizontal edges never count and are listed in
no band. A point outside [vmin, vmax) of the polygon is outside it with no edge walked.

Tables (one per polygon of at least MIN_CORNERS corners whose projection has height; band -1
for the others, which walk every corner):
    band_f[o:]   number of bands B, B / (vmax - vmin), the band lists' offset q in band_i,
                 then the B + 1 band boundaries vmin = b0 <= b1 <= ... <= bB = vmax
    band_i[q:]   B + 1 offsets (absolute, into band_i) of the bands' edge lists, then the lists:
                 edge e runs from corner e - 1 (the last corner for e = 0) to corner e
A point's band is found by arithmetic and then checked against the stored boundaries, so
rounding in the arithmetic cannot put it in the wrong one.
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
def _bands(count):
    return min(MAX_BANDS, max(2, count // CORNERS_PER_BAND))


@njit
def _build(verts, start, count, axis):
    n = start.shape[0]
    band = np.full(n, -1, np.int64)
    # first pass: which polygons get a table, and how big the tables are
    size_f, size_i = 0, 0
    for p in range(n):
        c = count[p]
        if c < MIN_CORNERS:
            continue
        iu, iv, _, _ = plane_coordinates(axis[p], 0.0, 0.0, 0.0)
        lo, hi = verts[start[p], iv], verts[start[p], iv]
        for k in range(start[p], start[p] + c):
            lo, hi = min(lo, verts[k, iv]), max(hi, verts[k, iv])
        if not hi > lo or not np.isfinite(hi - lo):
            continue
        b = _bands(c)
        band[p] = size_f
        size_f += _HEAD + b + 1
        size_i += b + 1 + c * b     # at most every edge in every band; trimmed below
    band_f = np.zeros(size_f)
    band_i = np.zeros(size_i, np.int64)
    used = 0
    for p in range(n):
        o = band[p]
        if o < 0:
            continue
        c = count[p]
        s = start[p]
        iu, iv, _, _ = plane_coordinates(axis[p], 0.0, 0.0, 0.0)
        lo, hi = verts[s, iv], verts[s, iv]
        for k in range(s, s + c):
            lo, hi = min(lo, verts[k, iv]), max(hi, verts[k, iv])
        b = _bands(c)
        band_f[o] = b
        band_f[o + 1] = b / (hi - lo)
        band_f[o + 2] = used
        band_f[o + _HEAD] = lo
        for k in range(1, b):
            band_f[o + _HEAD + k] = min(hi, max(band_f[o + _HEAD + k - 1], lo + (hi - lo) * k / b))
        band_f[o + _HEAD + b] = hi
        q = used
        at = q + b + 1
        for k in range(b):
            band_i[q + k] = at
            b_lo, b_hi = band_f[o + _HEAD + k], band_f[o + _HEAD + k + 1]
            for e in range(c):
                i = s + e
                j = s + c - 1 if e == 0 else i - 1
                e_lo, e_hi = min(verts[i, iv], verts[j, iv]), max(verts[i, iv], verts[j, iv])
                # the edge can count for a point v only where e_lo <= v < e_hi
                if e_lo < e_hi and e_lo < b_hi and e_hi > b_lo:
                    band_i[at] = e
                    at += 1
        band_i[q + b] = at
        used = at
    return band, band_f, band_i[:used].copy()


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
    first = o + _HEAD
    if not (band_f[first] <= v0 < band_f[first + b]):
        return False, np.int64(0)      # below or above every corner: no edge can cross
    k = min(max(np.int64((v0 - band_f[first]) * band_f[o + 1]), np.int64(0)), b - 1)
    while v0 < band_f[first + k]:
        k -= 1
    while v0 >= band_f[first + k + 1]:
        k += 1
    q = np.int64(band_f[o + 2])
    lo, hi = band_i[q + k], band_i[q + k + 1]
    inside = False
    for m in range(lo, hi):
        e = band_i[m]
        i = start + e
        j = start + count - 1 if e == 0 else i - 1
        ui, vi = verts[i, iu] - u0, verts[i, iv] - v0
        uj, vj = verts[j, iu] - u0, verts[j, iv] - v0
        if (vi > 0.0) != (vj > 0.0):
            num = ui * vj - uj * vi
            if num != 0.0 and (vj > vi) == (num > 0.0):
                inside = not inside
    return inside, hi - lo

"""Ray/primitive intersection and surface normals, as small compiled functions.

    t = hit_sphere(cx, cy, cz, r, ox, oy, oz, dx, dy, dz, tmin, tmax)   # inf on a miss

Every function takes the ray as scalars (origin o, direction d, not
necessarily unit length, so that t stays comparable through instance
transforms) and returns the ray parameter of the nearest hit in
[tmin, tmax], or +inf. They inline into the traversal kernels.

Kinds are tagged in references as `kind << KIND_SHIFT | index`.
"""

import math

import numpy as np

from .config import njit

SPHERE, POLYGON, PATCH, CONE, TRIANGLE, AGGREGATE, INSTANCE = 0, 1, 2, 3, 4, 5, 6
PRIMITIVE_KINDS = ("sphere", "polygon", "patch", "cone", "triangle")
KIND_SHIFT = 40
INDEX_MASK = (1 << KIND_SHIFT) - 1
INF = np.inf


@njit(inline="always")
def ref_kind(ref):
    return ref >> KIND_SHIFT


@njit(inline="always")
def ref_index(ref):
    return ref & INDEX_MASK


def make_ref(kind, index):
    """Tagged references for an index array (Python side)."""
    return (np.int64(kind) << KIND_SHIFT) | np.asarray(index, np.int64)


@njit(inline="always")
def _quadratic_roots(a, half_b, c):
    """Roots of a t^2 + 2 half_b t + c = 0 (ordered), computed without
    cancellation; (inf, inf) when there are none."""
    disc = half_b * half_b - a * c
    if disc < 0.0 or a == 0.0:
        if a == 0.0 and half_b != 0.0:
            t = -c / (2.0 * half_b)
            return t, t
        return INF, INF
    s = math.sqrt(disc)
    q = -(half_b + s) if half_b >= 0.0 else -(half_b - s)
    if q == 0.0:
        return 0.0, 0.0
    t0 = q / a
    t1 = c / q
    if t0 > t1:
        t0, t1 = t1, t0
    return t0, t1


@njit(inline="always")
def hit_sphere(cx, cy, cz, r, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Nearest t in [tmin, tmax]. A negative radius shows only the inside:
    hits where the ray enters the sphere from outside are ignored."""
    a = dx * dx + dy * dy + dz * dz
    fx, fy, fz = ox - cx, oy - cy, oz - cz
    half_b = fx * dx + fy * dy + fz * dz
    # discriminant from the closest point on the line (stable for far, small spheres)
    k = half_b / a
    lx, ly, lz = fx - k * dx, fy - k * dy, fz - k * dz
    r2 = r * r
    disc = r2 - (lx * lx + ly * ly + lz * lz)
    if disc < 0.0:
        return INF
    s = math.sqrt(a * disc)
    q = -(half_b + s) if half_b >= 0.0 else -(half_b - s)
    c = fx * fx + fy * fy + fz * fz - r2
    if q == 0.0:
        return INF
    t0 = q / a
    t1 = c / q
    if t0 > t1:
        t0, t1 = t1, t0
    if r > 0.0:
        if tmin <= t0 <= tmax:
            return t0
        if tmin <= t1 <= tmax:
            return t1
        return INF
    # inside only: the far root is where the ray leaves the sphere
    if tmin <= t1 <= tmax:
        return t1
    return INF


@njit(inline="always")
def point_in_polygon(verts, start, count, axis, px, py, pz):
    """Crossing-number test in the plane that drops `axis`, with half-open
    edge rules so that a point on an edge shared by two coplanar polygons
    lies in exactly one of them. Concave polygons work. Coordinates stay
    world coordinates, so both polygons of a shared edge round it alike."""
    if axis == 0:
        u0, v0 = py, pz
        iu, iv = 1, 2
    elif axis == 1:
        u0, v0 = pz, px
        iu, iv = 2, 0
    else:
        u0, v0 = px, py
        iu, iv = 0, 1
    inside = False
    j = start + count - 1
    for i in range(start, start + count):
        ui, vi = verts[i, iu] - u0, verts[i, iv] - v0
        uj, vj = verts[j, iu] - u0, verts[j, iv] - v0
        if (vi > 0.0) != (vj > 0.0):
            # the edge crosses the line v = 0 at u = num / (vj - vi); count it
            # when that is strictly right of the point. num is negated exactly
            # when the edge is walked the other way, so two polygons sharing an
            # edge agree: a point on it lies in exactly one of them.
            num = ui * vj - uj * vi
            if num != 0.0 and (vj > vi) == (num > 0.0):
                inside = not inside
        j = i
    return inside


@njit(inline="always")
def hit_polygon(normals, dists, starts, counts, axes, verts, i, ox, oy, oz, dx, dy, dz, tmin, tmax):
    # t from the first vertex, not the stored plane offset: (v0 - o) keeps its
    # digits when the polygon is far from the world origin but near the ray
    nx, ny, nz = normals[i, 0], normals[i, 1], normals[i, 2]
    den = nx * dx + ny * dy + nz * dz
    if den == 0.0:
        return INF
    v0 = starts[i]
    wx, wy, wz = ox - verts[v0, 0], oy - verts[v0, 1], oz - verts[v0, 2]
    t = -(nx * wx + ny * wy + nz * wz) / den
    if not (tmin <= t <= tmax):
        return INF
    if point_in_polygon(verts, v0, counts[i], axes[i], ox + t * dx, oy + t * dy, oz + t * dz):
        return t
    return INF


@njit(inline="always")
def hit_triangle(v0x, v0y, v0z, v1x, v1y, v1z, v2x, v2y, v2z, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Moller-Trumbore in double precision; edges shared by two triangles
    may be reported by either (the closest-hit tie rule picks one)."""
    e1x, e1y, e1z = v1x - v0x, v1y - v0y, v1z - v0z
    e2x, e2y, e2z = v2x - v0x, v2y - v0y, v2z - v0z
    px, py, pz = dy * e2z - dz * e2y, dz * e2x - dx * e2z, dx * e2y - dy * e2x
    det = e1x * px + e1y * py + e1z * pz
    if det == 0.0:
        return INF
    inv = 1.0 / det
    sx, sy, sz = ox - v0x, oy - v0y, oz - v0z
    u = (sx * px + sy * py + sz * pz) * inv
    if u < 0.0 or u > 1.0:
        return INF
    qx, qy, qz = sy * e1z - sz * e1y, sz * e1x - sx * e1z, sx * e1y - sy * e1x
    v = (dx * qx + dy * qy + dz * qz) * inv
    if v < 0.0 or u + v > 1.0:
        return INF
    t = (e2x * qx + e2y * qy + e2z * qz) * inv
    if tmin <= t <= tmax:
        return t
    return INF


@njit(inline="always")
def hit_cone(bx, by, bz, ax, ay, az, length, r0, r1, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Open cone or cylinder from base b along unit axis a for `length`,
    radius r0 at the base and r1 at the apex, no caps. Negative radii
    (NFF): only the inside is visible."""
    inside_only = r0 < 0.0 or r1 < 0.0
    r0 = abs(r0)
    r1 = abs(r1)
    slope = (r1 - r0) / length
    # work relative to the base, from the point of the ray nearest to it, so
    # that a small cone far from the ray origin keeps its digits
    wx, wy, wz = ox - bx, oy - by, oz - bz
    shift = -(wx * dx + wy * dy + wz * dz) / (dx * dx + dy * dy + dz * dz)
    wx, wy, wz = wx + shift * dx, wy + shift * dy, wz + shift * dz
    wa = wx * ax + wy * ay + wz * az
    da = dx * ax + dy * ay + dz * az
    qwx, qwy, qwz = wx - wa * ax, wy - wa * ay, wz - wa * az
    qdx, qdy, qdz = dx - da * ax, dy - da * ay, dz - da * az
    rw = r0 + slope * wa
    a = qdx * qdx + qdy * qdy + qdz * qdz - slope * slope * da * da
    half_b = qwx * qdx + qwy * qdy + qwz * qdz - slope * da * rw
    c = qwx * qwx + qwy * qwy + qwz * qwz - rw * rw
    t0, t1 = _quadratic_roots(a, half_b, c)
    for k in range(2):
        t = t0 if k == 0 else t1
        if not (tmin <= t + shift <= tmax):
            continue
        s = wa + t * da
        if s < 0.0 or s > length or r0 + slope * s < 0.0:
            continue
        if inside_only:
            # keep only hits where the ray meets the inner face
            nx, ny, nz = cone_normal(0.0, 0.0, 0.0, ax, ay, az, r0, slope, wx + t * dx, wy + t * dy, wz + t * dz)
            if nx * dx + ny * dy + nz * dz < 0.0:
                continue
        return t + shift
    return INF


@njit(inline="always")
def cone_normal(bx, by, bz, ax, ay, az, r0, slope, px, py, pz):
    """Outward (unnormalised) normal of the cone surface at p."""
    wx, wy, wz = px - bx, py - by, pz - bz
    s = wx * ax + wy * ay + wz * az
    qx, qy, qz = wx - s * ax, wy - s * ay, wz - s * az
    rr = r0 + slope * s
    ql = math.sqrt(qx * qx + qy * qy + qz * qz)
    if ql > 0.0:
        qx, qy, qz = qx / ql * rr, qy / ql * rr, qz / ql * rr
    k = rr * slope
    return qx - k * ax, qy - k * ay, qz - k * az

"""Ray/primitive intersection and surface normals, as small compiled functions.

    t = hit_sphere(cx, cy, cz, r, ox, oy, oz, dx, dy, dz, tmin, tmax)   # inf on a miss

Every function takes the ray as scalars (origin o, direction d, not
necessarily unit length, so that t stays comparable through instance
transforms) and returns the ray parameter of the nearest hit in
[tmin, tmax], or +inf. They are compiled once each, not inlined into every
caller at the IR level: LLVM inlines the small ones by itself.

Kinds are tagged in references as `kind << KIND_SHIFT | index`.
"""

import math

import numpy as np

from .config import njit
from .counters import POLYGON_CORNERS
from .limits import MAX_COORDINATE, MIN_SIZE  # noqa: F401  (the range answered exactly: limits.py)
from .polybands import crosses, plane_coordinates, point_in_bands

SPHERE, POLYGON, PATCH, CONE, TRIANGLE, AGGREGATE, INSTANCE = 0, 1, 2, 3, 4, 5, 6
PRIMITIVE_KINDS = ("sphere", "polygon", "patch", "cone", "triangle")
KIND_SHIFT = 40
INDEX_MASK = (1 << KIND_SHIFT) - 1
INF = np.inf


@njit(inline="always")
def normalize(x, y, z):
    """(x, y, z) scaled to unit length; the zero vector stays zero."""
    n = math.sqrt(x * x + y * y + z * z)
    if n == 0.0:
        return 0.0, 0.0, 0.0
    return x / n, y / n, z / n


def make_ref(kind, index):
    """Tagged references for an index array (Python side)."""
    return (np.int64(kind) << KIND_SHIFT) | np.asarray(index, np.int64)


@njit
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


@njit
def sphere_roots(cx, cy, cz, r, ox, oy, oz, dx, dy, dz):
    """Both roots of the ray's line with the sphere, t0 <= t1 (equal where it grazes),
    or (inf, inf)."""
    a = dx * dx + dy * dy + dz * dz
    fx, fy, fz = ox - cx, oy - cy, oz - cz
    half_b = fx * dx + fy * dy + fz * dz
    # discriminant from the closest point on the line (stable for far, small spheres)
    k = half_b / a
    lx, ly, lz = fx - k * dx, fy - k * dy, fz - k * dz
    r2 = r * r
    disc = r2 - (lx * lx + ly * ly + lz * lz)
    if disc < 0.0:
        return INF, INF
    s = math.sqrt(a * disc)
    q = -(half_b + s) if half_b >= 0.0 else -(half_b - s)
    c = fx * fx + fy * fy + fz * fz - r2
    if q == 0.0:
        return INF, INF
    t0 = q / a
    t1 = c / q
    if t0 > t1:
        t0, t1 = t1, t0
    return t0, t1


@njit
def hit_sphere(cx, cy, cz, r, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Nearest t in [tmin, tmax]. A negative radius shows only the inside:
    hits where the ray enters the sphere from outside are ignored."""
    t0, t1 = sphere_roots(cx, cy, cz, r, ox, oy, oz, dx, dy, dz)
    if t0 == INF:
        return INF
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


@njit(borrows=True)   # called per candidate: no reference counting
def point_in_polygon(verts, start, count, axis, px, py, pz):
    """Crossing-number test in the plane that drops `axis`, with half-open
    edge rules so that a point on an edge shared by two coplanar polygons
    lies in exactly one of them. Concave polygons work. Coordinates stay
    world coordinates, so both polygons of a shared edge round it alike."""
    iu, iv, u0, v0 = plane_coordinates(axis, px, py, pz)
    inside = False
    j = start + count - 1
    for i in range(start, start + count):
        if crosses(verts, i, j, iu, iv, u0, v0):
            inside = not inside
        j = i
    return inside


@njit(borrows=True)   # called per candidate: no reference counting
def point_in_triangle(verts, start, axis, px, py, pz):
    """point_in_polygon of a polygon of three corners: its three steps, without the loop."""
    iu, iv, u0, v0 = plane_coordinates(axis, px, py, pz)
    return (crosses(verts, start, start + 2, iu, iv, u0, v0) != crosses(verts, start + 1, start, iu, iv, u0, v0)) \
        != crosses(verts, start + 2, start + 1, iu, iv, u0, v0)


@njit(borrows=True)   # called per candidate: no reference counting
def hit_polygon(normals, starts, counts, axes, bands, verts, band_f, band_i, i, ox, oy, oz, dx, dy, dz, tmin,
                tmax, cnt):
    return hit_plane_polygon(normals[i, 0], normals[i, 1], normals[i, 2], starts[i], counts[i], axes[i], bands[i],
                             verts, band_f, band_i, ox, oy, oz, dx, dy, dz, tmin, tmax, cnt)


@njit(inline="always")     # in hit_polygon's body as it was: a call per candidate costs grids and octrees
def hit_plane_polygon(nx, ny, nz, v0, count, axis, band, verts, band_f, band_i, ox, oy, oz, dx, dy, dz, tmin, tmax,
                      cnt):
    """hit_polygon of the polygon with unit normal n and corners verts[v0:v0 + count], whose
    bins (polybands.py) are at band_f[band] (-1: none, walk every corner); counts the corners
    the inside test walks (cnt[POLYGON_CORNERS]: its cost grows with them)."""
    # t from the first vertex, not the stored plane offset: (v0 - o) keeps its
    # digits when the polygon is far from the world origin but near the ray
    den = nx * dx + ny * dy + nz * dz
    if den == 0.0:
        return INF
    wx, wy, wz = ox - verts[v0, 0], oy - verts[v0, 1], oz - verts[v0, 2]
    t = -(nx * wx + ny * wy + nz * wz) / den
    if not (tmin <= t <= tmax):
        return INF
    px, py, pz = ox + t * dx, oy + t * dy, oz + t * dz
    if band < 0:
        cnt[POLYGON_CORNERS] += count
        if count == 3:      # the commonest polygon
            inside = point_in_triangle(verts, v0, axis, px, py, pz)
        else:
            inside = point_in_polygon(verts, v0, count, axis, px, py, pz)
    else:
        iu, iv, u, v = plane_coordinates(axis, px, py, pz)
        inside, walked = point_in_bands(verts, v0, count, iu, iv, u, v, band_f, band_i, band)
        cnt[POLYGON_CORNERS] += walked
    if inside:
        return t
    return INF


@njit(inline="always")
def _edge_sign(px, py, qx, qy):
    """Side of the ray (the origin of the sheared plane) relative to the
    directed edge p -> q: the sign of p x q, and where that is exactly 0 the
    sign it takes for the origin nudged to (eps, eps^2). The rule is
    antisymmetric (q -> p gives the opposite sign, bit for bit), so the two
    triangles of a shared edge never both claim, nor both drop, a ray
    through it; at a shared vertex exactly one triangle of the fan claims it."""
    e = px * qy - py * qx
    if e != 0.0:
        return e, (1 if e > 0.0 else -1)
    if py != qy:
        return e, (1 if py > qy else -1)
    if qx != px:
        return e, (1 if qx > px else -1)
    return e, 0


@njit
def ray_shear(dx, dy, dz):
    """The watertight triangle test's per-ray constants: the dominant axis kz, the other two
    (kx, ky) in the order that keeps the winding, and the shear sx, sy, sz (sz = 0: a zero
    direction, which hits nothing)."""
    ax, ay, az = abs(dx), abs(dy), abs(dz)
    if ax >= ay and ax >= az:
        kz, kx, ky = 0, 1, 2
        rz, rx, ry = dx, dy, dz
    elif ay >= az:
        kz, kx, ky = 1, 2, 0
        rz, rx, ry = dy, dz, dx
    else:
        kz, kx, ky = 2, 0, 1
        rz, rx, ry = dz, dx, dy
    if rz < 0.0:
        rx, ry = ry, rx
        kx, ky = ky, kx
    if rz == 0.0:
        return kx, ky, kz, 0.0, 0.0, 0.0
    return kx, ky, kz, rx / rz, ry / rz, 1.0 / rz


WATERTIGHT, INCLUSIVE = 0, 1    # edge rules of the triangle test


@njit
def hit_sheared(px0, py0, pz0, px1, py1, pz1, px2, py2, pz2, sx, sy, sz, tmin, tmax, edges=WATERTIGHT):
    """The watertight test for corners already moved to the ray origin and permuted to
    (kx, ky, kz) of ray_shear. edges=INCLUSIVE counts a ray through an edge or vertex
    as a hit of every triangle there (zero edge functions accepted on either side)."""
    if sz == 0.0:
        return INF
    # shear: the ray becomes the +z axis through the origin
    ax0, ay0 = px0 - sx * pz0, py0 - sy * pz0
    ax1, ay1 = px1 - sx * pz1, py1 - sy * pz1
    ax2, ay2 = px2 - sx * pz2, py2 - sy * pz2
    # edge functions: u weighs v0 (edge v1 -> v2), v weighs v1, w weighs v2
    u, su = _edge_sign(ax1, ay1, ax2, ay2)
    v, sv = _edge_sign(ax2, ay2, ax0, ay0)
    w, sw = _edge_sign(ax0, ay0, ax1, ay1)
    if edges == INCLUSIVE:
        if (u < 0.0 or v < 0.0 or w < 0.0) and (u > 0.0 or v > 0.0 or w > 0.0):
            return INF
    elif su == 0 or su != sv or su != sw:
        return INF
    det = u + v + w
    if det == 0.0:
        return INF
    t = (u * pz0 + v * pz1 + w * pz2) * sz / det
    if tmin <= t <= tmax:
        return t
    return INF


@njit
def hit_triangle(v0x, v0y, v0z, v1x, v1y, v1z, v2x, v2y, v2z, ox, oy, oz, dx, dy, dz, tmin, tmax, edges=WATERTIGHT):
    """Watertight ray/triangle test (Woop, Benthin and Wald 2013) in double
    precision, two-sided. The vertices are moved to the ray origin, permuted
    so that the ray's dominant axis is z, and sheared so that the ray runs
    along +z; the 2D edge functions of a shared edge are then computed from
    the same numbers in both triangles. An edge function that is exactly 0
    is resolved by a consistent tie rule (_edge_sign) instead of the paper's
    fallback to higher precision, so a ray through a shared edge or vertex of
    a closed mesh hits exactly one of the triangles there. edges=INCLUSIVE: every one
    of them (rays grazing a silhouette edge or running in a face's plane then hit
    the neighbouring faces' edges, as Embree's test reports them)."""
    kx, ky, kz, sx, sy, sz = ray_shear(dx, dy, dz)
    p0 = (v0x - ox, v0y - oy, v0z - oz)
    p1 = (v1x - ox, v1y - oy, v1z - oz)
    p2 = (v2x - ox, v2y - oy, v2z - oz)
    return hit_sheared(p0[kx], p0[ky], p0[kz], p1[kx], p1[ky], p1[kz], p2[kx], p2[ky], p2[kz], sx, sy, sz,
                       tmin, tmax, edges)


# hit_cone's pre-test rejects a ray only when the squared distance between its line and the axis'
# line exceeds the widest radius' square by CONE_MARGIN of the squared sizes involved: some 1e6 times
# the rounding of the full test's quadratic there, so that the full test would have missed it too
CONE_MARGIN = 1e-10
CONE_PARALLEL = 1e-6    # |a x d|^2 / |d|^2 below it (within 1e-3 of the axis' direction): no pre-test


@njit
def hit_cone(bx, by, bz, ax, ay, az, length, r0, r1, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Open cone or cylinder from base b along unit axis a for `length`,
    radius r0 at the base and r1 at the apex, no caps. Negative radii
    (NFF): only the inside is visible. A ray whose line passes the axis' line
    farther off than the widest radius misses without the quadratic (most of
    the cones a ray is tested against)."""
    wide = max(abs(r0), abs(r1))
    cx, cy, cz = ay * dz - az * dy, az * dx - ax * dz, ax * dy - ay * dx      # a x d, normal to both lines
    cc = cx * cx + cy * cy + cz * cz
    if cc > CONE_PARALLEL * (dx * dx + dy * dy + dz * dz):
        wx, wy, wz = ox - bx, oy - by, oz - bz
        off = wx * cx + wy * cy + wz * cz      # the lines' distance times |a x d|
        far = abs(wx) + abs(wy) + abs(wz)
        span = far + length + wide + wide * far / length    # bounds what the quadratic's terms hold
        if off * off > (wide * wide + CONE_MARGIN * span * span) * cc:
            return INF
    return cone_roots(bx, by, bz, ax, ay, az, length, r0, r1, ox, oy, oz, dx, dy, dz, tmin, tmax)


@njit(inline="always")
def cone_roots(bx, by, bz, ax, ay, az, length, r0, r1, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """hit_cone without its pre-test: the quadratic, its roots and their checks."""
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


@njit
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

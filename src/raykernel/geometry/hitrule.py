"""What every walk of the scene shares once it meets a primitive: the query modes, the
primitive tests and the hit rule.

    t = hit(kind, geo, idx, geo.poly_verts, geo.poly_band_f, geo.poly_band_i, geo.tri_edges[0],
            ox, oy, oz, dx, dy, dz, tmin, tmax, cnt)                 # inf on a miss
    t = hit(kind, prims, row, verts, band_f, band_i, edges, ...)      # the same test on a leaf-order record
    found, best_t, best_ref, best_inst = take(mode, t, kind, idx, inst, 0, maps, row, col, hit_f, hit_i,
                                              found, best_t, best_ref, best_inst)

The primitive tests are dispatched once, in `hit`: the kind picks the test, and the test reads
its primitive's numbers either from the Geometry's arrays (the general driver, traverse.py;
tricks.py) or from the fast walk's leaf-order records (widewalk.py, one row per reference), the
same numbers either way (`sphere_of`, `polygon_of`, `triangle_of`, `cone_of` give them for
either form). Both walks apply `take`, so they answer every query with the same hit, tie for
tie.
"""

import numpy as np
from numba.core import types
from numba.extending import overload

from . import counters as C
from .boxes import INF
from .config import njit
from .primitives import (
    CONE,
    KIND_SHIFT,
    PATCH,
    POLYGON,
    SPHERE,
    TRIANGLE,
    hit_cone,
    hit_plane_polygon,
    hit_sphere,
    hit_triangle,
    normalize,
)
from .surface import surface

# intersect's mode: the closest hit, any hit, every hit. numpy integers, not Python ints: numba
# compiles a function again for each literal int value it is passed
CLOSEST, ANY_HIT, ALL_HITS = np.int64(0), np.int64(1), np.int64(2)
# the closest hit, computing the surface normal of every closer hit as it is found (what a tracer
# without Haines's trick 5, "normals only for the final hit", does; rendering/tricks.py)
CLOSEST_EAGER = np.int64(3)
# any hit on an opaque surface: transparent primitives (geo.mat_clear) are passed over (Haines's trick 4)
ANY_OPAQUE = np.int64(4)
HIT_F = 13                   # hit_f: t, world-to-local 3x4 of the frame that was hit (then, in a workspace's,
                             # room for CLOSEST_EAGER's normal)
HIT_I = 4                    # hit_i: kind, index, innermost instance (-1: none), flags:
FLIP, OPERATOR_SURFACE = 1, 2  # hit_i[3] bits: reverse the normal; a surface of an operator's result (not its
                               # primitive's own surface everywhere, so a test of the primitive alone may disagree)
# a leaf-order record (widewalk.py): a sphere's centre and signed radius; a polygon's unit normal, first
# corner, corner count, dropped axis and bins; a triangle's corners; a cone's base, unit axis, length
# and radii; CLEAR: 1.0 when the material transmits
RECORD_COLUMNS = 10
CLEAR = 9


def sphere_of(src, i):
    """(centre, signed radius) of sphere i: src a Geometry, or records and i a row."""


def polygon_of(src, i):
    """(unit normal, first corner in poly_verts, corner count, dropped axis, bins) of polygon i."""


def triangle_of(src, i):
    """The corners v0, v1, v2 of triangle i."""


def cone_of(src, i):
    """(base, unit axis, length, base radius, apex radius) of cone i."""


def _records(src) -> bool:
    return isinstance(src, types.Array)


@overload(sphere_of, inline="always")
def _sphere_of(src, i):
    if _records(src):
        return lambda src, i: (src[i, 0], src[i, 1], src[i, 2], src[i, 3])
    return lambda src, i: (src.sph_center[i, 0], src.sph_center[i, 1], src.sph_center[i, 2], src.sph_radius[i])


@overload(polygon_of, inline="always")
def _polygon_of(src, i):
    if _records(src):
        return lambda src, i: (src[i, 0], src[i, 1], src[i, 2], np.int64(src[i, 3]), np.int64(src[i, 4]),
                               np.int64(src[i, 5]), np.int64(src[i, 6]))
    return lambda src, i: (src.poly_normal[i, 0], src.poly_normal[i, 1], src.poly_normal[i, 2], src.poly_start[i],
                           src.poly_count[i], src.poly_axis[i], src.poly_band[i])


@overload(triangle_of, inline="always")
def _triangle_of(src, i):
    if _records(src):
        return lambda src, i: (src[i, 0], src[i, 1], src[i, 2], src[i, 3], src[i, 4], src[i, 5], src[i, 6],
                               src[i, 7], src[i, 8])

    def corners(src, i):
        fa, fb, fc = src.tri_faces[i, 0], src.tri_faces[i, 1], src.tri_faces[i, 2]
        v = src.tri_verts
        return v[fa, 0], v[fa, 1], v[fa, 2], v[fb, 0], v[fb, 1], v[fb, 2], v[fc, 0], v[fc, 1], v[fc, 2]
    return corners


@overload(cone_of, inline="always")
def _cone_of(src, i):
    if _records(src):
        return lambda src, i: (src[i, 0], src[i, 1], src[i, 2], src[i, 3], src[i, 4], src[i, 5], src[i, 6],
                               src[i, 7], src[i, 8])
    return lambda src, i: (src.cone_base[i, 0], src.cone_base[i, 1], src.cone_base[i, 2], src.cone_axis[i, 0],
                           src.cone_axis[i, 1], src.cone_axis[i, 2], src.cone_length[i], src.cone_r0[i],
                           src.cone_r1[i])


@njit(inline="always")
def hit(kind, src, i, verts, band_f, band_i, edges, ox, oy, oz, dx, dy, dz, tmin, tmax, cnt):
    """t of the ray's nearest hit on primitive i of `kind` in [tmin, tmax], inf for a miss: src
    the Geometry (i the primitive's index) or the leaf-order records (i the row); verts, band_f
    and band_i the polygons' corners and bins, edges the triangle test's edge rule."""
    if kind == SPHERE:
        cx, cy, cz, r = sphere_of(src, i)
        return hit_sphere(cx, cy, cz, r, ox, oy, oz, dx, dy, dz, tmin, tmax)
    if kind == POLYGON or kind == PATCH:
        nx, ny, nz, v0, count, axis, band = polygon_of(src, i)
        return hit_plane_polygon(nx, ny, nz, v0, count, axis, band, verts, band_f, band_i, ox, oy, oz, dx, dy, dz,
                                 tmin, tmax, cnt)
    if kind == TRIANGLE:
        ax, ay, az, bx, by, bz, cx, cy, cz = triangle_of(src, i)
        return hit_triangle(ax, ay, az, bx, by, bz, cx, cy, cz, ox, oy, oz, dx, dy, dz, tmin, tmax, edges)
    if kind == CONE:
        bx, by, bz, ax, ay, az, length, r0, r1 = cone_of(src, i)
        return hit_cone(bx, by, bz, ax, ay, az, length, r0, r1, ox, oy, oz, dx, dy, dz, tmin, tmax)
    return INF


@njit(inline="always")
def hit_primitive(geo, kind, idx, ox, oy, oz, dx, dy, dz, tmin, tmax, cnt):
    """hit for primitive (kind, idx) of the Geometry."""
    return hit(kind, geo, idx, geo.poly_verts, geo.poly_band_f, geo.poly_band_i, geo.tri_edges[0], ox, oy, oz,
               dx, dy, dz, tmin, tmax, cnt)


@njit(private=True)
def take(mode, t, kind, idx, inst, flip, maps, row, col, hit_f, hit_i, found, best_t, best_ref, best_inst):
    """The hit rule: hit (t, kind, idx, inst) with the map maps[row, col:col + 12] against
    the best so far; returns the new (found, best_t, best_ref, best_inst)."""
    if mode == ALL_HITS:
        # every hit: hit_i[0] counts them; hit k is t = hit_f[HIT_F + k] and
        # (kind, index, instance) = hit_i[HIT_I + 3k ..], stored while they fit
        k = hit_i[0]
        if HIT_F + k < hit_f.shape[0] and HIT_I + 3 * k + 2 < hit_i.shape[0]:
            hit_f[HIT_F + k] = t
            hit_i[HIT_I + 3 * k] = kind
            hit_i[HIT_I + 3 * k + 1] = idx
            hit_i[HIT_I + 3 * k + 2] = inst
        hit_i[0] = k + 1
        return True, best_t, best_ref, best_inst
    # t <= best_t here; ties at equal t go to the smaller
    # (ref, instance), so every traversal order reports the same primitive
    ref = (kind << KIND_SHIFT) | idx
    if not found or t < best_t or ref < best_ref or (ref == best_ref and inst < best_inst):
        hit_f[0] = t
        for k in range(12):
            hit_f[1 + k] = maps[row, col + k]
        hit_i[0], hit_i[1], hit_i[2], hit_i[3] = kind, idx, inst, flip
        return True, t, ref, inst
    return found, best_t, best_ref, best_inst


@njit(inline="always")
def clear_material(geo, kind, idx):
    """True when primitive (kind, idx) has a transparent material."""
    if kind == SPHERE:
        return geo.mat_clear[geo.sph_mat[idx]]
    if kind == POLYGON or kind == PATCH:
        return geo.mat_clear[geo.poly_mat[idx]]
    if kind == CONE:
        return geo.mat_clear[geo.cone_mat[idx]]
    return geo.mat_clear[geo.tri_mat[idx]]


@njit(private=True)
def eager_normal(geo, kind, idx, px, py, pz, hit_f, cnt):
    """CLOSEST_EAGER: the shading normal of the hit just taken, at its local point p, into hit_f."""
    _, _, _, sx, sy, sz, _ = surface(geo, kind, idx, px, py, pz)
    hit_f[HIT_F], hit_f[HIT_F + 1], hit_f[HIT_F + 2] = normalize(sx, sy, sz)
    cnt[C.NORMALS_COMPUTED] += 1

"""What every walk of the scene shares once it meets a primitive: the query modes, the
primitive tests and the hit rule.

    t = hit_primitive(geo, kind, idx, ox, oy, oz, dx, dy, dz, tmin, tmax, cnt)     # inf on a miss
    found, best_t, best_ref, best_inst = take(mode, t, kind, idx, inst, 0, maps, row, col, hit_f, hit_i,
                                              found, best_t, best_ref, best_inst)

The general driver (traverse.py) and the fast walk of a scene that is one BVH over
primitives (widewalk.py) both apply `take`, so the two answer every query with the same hit,
tie for tie. Both make the primitive tests of `hit_primitive` (the same functions on the same
numbers) inline in their own loops, the driver from Geometry's arrays, the fast walk from its
leaf-order records; hit_primitive itself tests the objects Haines's tricks remember.
"""

import numpy as np

from ..geometry import counters as C
from ..geometry.boxes import INF
from ..geometry.config import njit
from ..geometry.primitives import (
    CONE,
    KIND_SHIFT,
    PATCH,
    POLYGON,
    SPHERE,
    TRIANGLE,
    hit_cone,
    hit_polygon,
    hit_sphere,
    hit_triangle,
    normalize,
)
from ..geometry.surface import surface

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


@njit(inline="always")
def hit_primitive(geo, kind, idx, ox, oy, oz, dx, dy, dz, tmin, tmax, cnt):
    """t of the ray's nearest hit on primitive (kind, idx) in [tmin, tmax], inf for a miss."""
    if kind == SPHERE:
        return hit_sphere(geo.sph_center[idx, 0], geo.sph_center[idx, 1], geo.sph_center[idx, 2],
                          geo.sph_radius[idx], ox, oy, oz, dx, dy, dz, tmin, tmax)
    if kind == POLYGON or kind == PATCH:
        return hit_polygon(geo.poly_normal, geo.poly_start, geo.poly_count, geo.poly_axis, geo.poly_band,
                           geo.poly_verts, geo.poly_band_f, geo.poly_band_i, idx, ox, oy, oz, dx, dy, dz, tmin, tmax,
                           cnt)
    if kind == TRIANGLE:
        fa, fb, fc = geo.tri_faces[idx, 0], geo.tri_faces[idx, 1], geo.tri_faces[idx, 2]
        v = geo.tri_verts
        return hit_triangle(v[fa, 0], v[fa, 1], v[fa, 2], v[fb, 0], v[fb, 1], v[fb, 2],
                            v[fc, 0], v[fc, 1], v[fc, 2], ox, oy, oz, dx, dy, dz, tmin, tmax, geo.tri_edges[0])
    if kind == CONE:
        return hit_cone(geo.cone_base[idx, 0], geo.cone_base[idx, 1], geo.cone_base[idx, 2],
                        geo.cone_axis[idx, 0], geo.cone_axis[idx, 1], geo.cone_axis[idx, 2],
                        geo.cone_length[idx], geo.cone_r0[idx], geo.cone_r1[idx], ox, oy, oz, dx, dy, dz, tmin, tmax)
    return INF


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

"""Surface quantities of a hit, shared by every ray-casting kernel.

    store_surface(geo, r, kind, idx, px, py, pz, m, uv_out, gn_out, sn_out, flip=0)
    store_triangle_surface(geo, r, idx, px, py, pz, m, uv_out, gn_out, sn_out)  # kernels that meet only triangles
    store_no_surface(r, uv_out, gn_out, sn_out)                           # a miss's: NaN

`m` is the world-to-local 3x4 map (row-major, 12 numbers) of the frame the
hit was found in; p is the world hit point; flip (hit_i[3]) reverses the
normals of a surface a CSG difference cut. Row r of the outputs receives
the surface (u, v) and the unit geometric and shading normals in world space.
"""

from __future__ import annotations

import math

import numpy as np

from ..geometry.config import njit
from ..geometry.primitives import CONE, SPHERE, TRIANGLE, normalize
from ..geometry.surface import corner_normal, corner_weights, surface, triangle_surface, triangle_uv
from .triangles4 import corner

IDENTITY = np.array([1.0, 0, 0, 0, 0, 1.0, 0, 0, 0, 0, 1.0, 0])     # the map of a hit outside any instance


@njit(inline="always")
def surface_uv(geo, kind, idx, px, py, pz):
    """(u, v) of local point p on primitive (kind, idx)."""
    if kind == TRIANGLE:
        return triangle_uv(geo, idx, px, py, pz)
    if kind == SPHERE:
        x, y, z = normalize(px - geo.sph_center[idx, 0], py - geo.sph_center[idx, 1], pz - geo.sph_center[idx, 2])
        u = math.atan2(y, x) / (2.0 * math.pi)
        if u < 0.0:
            u += 1.0
        return u, math.acos(min(1.0, max(-1.0, z))) / math.pi
    if kind == CONE:
        ax, ay, az = geo.cone_axis[idx, 0], geo.cone_axis[idx, 1], geo.cone_axis[idx, 2]
        wx, wy, wz = px - geo.cone_base[idx, 0], py - geo.cone_base[idx, 1], pz - geo.cone_base[idx, 2]
        s = wx * ax + wy * ay + wz * az
        # a frame across the axis: e1 = axis x (the coordinate axis least aligned with it)
        if abs(ax) <= abs(ay) and abs(ax) <= abs(az):
            e1x, e1y, e1z = normalize(0.0, az, -ay)
        elif abs(ay) <= abs(az):
            e1x, e1y, e1z = normalize(-az, 0.0, ax)
        else:
            e1x, e1y, e1z = normalize(ay, -ax, 0.0)
        e2x, e2y, e2z = ay * e1z - az * e1y, az * e1x - ax * e1z, ax * e1y - ay * e1x
        u = math.atan2(wx * e2x + wy * e2y + wz * e2z, wx * e1x + wy * e1y + wz * e1z) / (2.0 * math.pi)
        if u < 0.0:
            u += 1.0
        return u, s / geo.cone_length[idx]
    return np.nan, np.nan


@njit(inline="always")
def store_surface(geo, r, kind, idx, px, py, pz, m, uv_out, gn_out, sn_out, flip=0):
    """Write (u, v) and the world-space unit normals of the hit into row r of those asked
    for (the others have no rows), reversed where flip is set: a surface a CSG difference cut."""
    # the hit point in the primitive's own frame; normals back by the transpose
    lx, ly, lz = to_local(m, px, py, pz)
    gx, gy, gz, sx, sy, sz, _ = surface(geo, kind, idx, lx, ly, lz)
    _store_normals(r, m, gx, gy, gz, sx, sy, sz, flip, gn_out, sn_out)
    if uv_out.shape[0]:
        uv_out[r, 0], uv_out[r, 1] = surface_uv(geo, kind, idx, lx, ly, lz)


@njit(inline="always")
def store_triangle_surface(geo, r, idx, px, py, pz, m, uv_out, gn_out, sn_out):
    """store_surface of a hit on triangle idx, compiling the triangle's code alone (the mesh kernel's)."""
    lx, ly, lz = to_local(m, px, py, pz)
    gx, gy, gz, sx, sy, sz, _ = triangle_surface(geo, idx, lx, ly, lz)
    _store_normals(r, m, gx, gy, gz, sx, sy, sz, 0, gn_out, sn_out)
    if uv_out.shape[0]:
        uv_out[r, 0], uv_out[r, 1] = triangle_uv(geo, idx, lx, ly, lz)


@njit(inline="always")
def store_corner_surface(src, row, r, px, py, pz, uv_out, gn_out, sn_out):
    """store_triangle_surface of a flat triangle (no vertex normals) from its corners, row `row`
    of src (triangles4.corner): the numbers the walk has just read, where the mesh's own arrays
    would be read from memory again; the same arithmetic on the same values."""
    ax, ay, az = corner(src, row, 0), corner(src, row, 1), corner(src, row, 2)
    bx, by, bz = corner(src, row, 3), corner(src, row, 4), corner(src, row, 5)
    cx, cy, cz = corner(src, row, 6), corner(src, row, 7), corner(src, row, 8)
    lx, ly, lz = to_local(IDENTITY, px, py, pz)
    gx, gy, gz = corner_normal(ax, ay, az, bx, by, bz, cx, cy, cz)
    _store_normals(r, IDENTITY, gx, gy, gz, gx, gy, gz, 0, gn_out, sn_out)
    if uv_out.shape[0]:
        beta, gamma, _ = corner_weights(ax, ay, az, bx, by, bz, cx, cy, cz, gx, gy, gz, lx, ly, lz)
        uv_out[r, 0], uv_out[r, 1] = beta, gamma


@njit(inline="always")
def to_local(m, px, py, pz):
    """Point p mapped by the 3x4 row-major map m."""
    return (m[0] * px + m[1] * py + m[2] * pz + m[3], m[4] * px + m[5] * py + m[6] * pz + m[7],
            m[8] * px + m[9] * py + m[10] * pz + m[11])


@njit(inline="always")
def _store_normals(r, m, gx, gy, gz, sx, sy, sz, flip, gn_out, sn_out):
    """Local normals to world space by the transpose of m, unit, reversed where flip is set, into row r."""
    gx, gy, gz = normalize(m[0] * gx + m[4] * gy + m[8] * gz, m[1] * gx + m[5] * gy + m[9] * gz,
                      m[2] * gx + m[6] * gy + m[10] * gz)
    sx, sy, sz = normalize(m[0] * sx + m[4] * sy + m[8] * sz, m[1] * sx + m[5] * sy + m[9] * sz,
                      m[2] * sx + m[6] * sy + m[10] * sz)
    if sx == 0.0 and sy == 0.0 and sz == 0.0:
        sx, sy, sz = gx, gy, gz
    if flip & 1:
        gx, gy, gz, sx, sy, sz = -gx, -gy, -gz, -sx, -sy, -sz
    if gn_out.shape[0]:
        gn_out[r, 0], gn_out[r, 1], gn_out[r, 2] = gx, gy, gz
    if sn_out.shape[0]:
        sn_out[r, 0], sn_out[r, 1], sn_out[r, 2] = sx, sy, sz


@njit(inline="always")
def store_no_surface(r, uv_out, gn_out, sn_out):
    """A miss's surface, NaN, in row r of the outputs asked for."""
    if uv_out.shape[0]:
        uv_out[r, 0] = uv_out[r, 1] = np.nan
    for k in range(3):
        if gn_out.shape[0]:
            gn_out[r, k] = np.nan
        if sn_out.shape[0]:
            sn_out[r, k] = np.nan

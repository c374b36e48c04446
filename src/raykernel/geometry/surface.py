"""Where a ray hit: the normals and material of a primitive at a point, for every shading model.

    gx, gy, gz, sx, sy, sz, mat = surface(geo, kind, index, x, y, z)   # in the primitive's own frame
    gx, gy, gz, sx, sy, sz, mat = hit_normals(geo, ws.hit_f, ws.hit_i, px, py, pz)   # of intersect's hit, world
"""

from .config import njit
from .primitives import CONE, PATCH, POLYGON, SPHERE, cone_normal, normalize


@njit(inline="always")
def dot(ax, ay, az, bx, by, bz):
    return ax * bx + ay * by + az * bz


@njit(inline="always")
def barycentric(v, a, b, c, gx, gy, gz, px, py, pz):
    """(beta, gamma, area): the weights of corners b and c (rows of v) at point p in triangle
    (a, b, c), from signed areas along the normal g (the triangle's own or its plane's);
    all 0 where the triangle has no area along g."""
    return corner_weights(v[a, 0], v[a, 1], v[a, 2], v[b, 0], v[b, 1], v[b, 2], v[c, 0], v[c, 1], v[c, 2],
                          gx, gy, gz, px, py, pz)


@njit(inline="always")
def corner_weights(ax, ay, az, bx, by, bz, cx, cy, cz, gx, gy, gz, px, py, pz):
    """barycentric of the triangle with corners a, b, c given as numbers."""
    e1x, e1y, e1z = bx - ax, by - ay, bz - az
    e2x, e2y, e2z = cx - ax, cy - ay, cz - az
    area = dot(e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x, gx, gy, gz)
    if area == 0.0:
        return 0.0, 0.0, 0.0
    wx, wy, wz = px - ax, py - ay, pz - az
    beta = dot(wy * e2z - wz * e2y, wz * e2x - wx * e2z, wx * e2y - wy * e2x, gx, gy, gz) / area
    gamma = dot(e1y * wz - e1z * wy, e1z * wx - e1x * wz, e1x * wy - e1y * wx, gx, gy, gz) / area
    return beta, gamma, area


@njit(inline="always")
def triangle_normal(geo, idx):
    """Corners (vertex rows) and geometric normal (unnormalised, by the winding) of triangle idx."""
    v = geo.tri_verts
    a, b, c = geo.tri_faces[idx, 0], geo.tri_faces[idx, 1], geo.tri_faces[idx, 2]
    gx, gy, gz = corner_normal(v[a, 0], v[a, 1], v[a, 2], v[b, 0], v[b, 1], v[b, 2], v[c, 0], v[c, 1], v[c, 2])
    return a, b, c, gx, gy, gz


@njit(inline="always")
def corner_normal(ax, ay, az, bx, by, bz, cx, cy, cz):
    """The geometric normal (unnormalised, by the winding) of the triangle with corners a, b, c."""
    e1x, e1y, e1z = bx - ax, by - ay, bz - az
    e2x, e2y, e2z = cx - ax, cy - ay, cz - az
    return e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x


@njit(inline="always")
def triangle_uv(geo, idx, px, py, pz):
    """(u, v) of local point p on triangle idx: barycentric, of its second and third corners."""
    a, b, c, gx, gy, gz = triangle_normal(geo, idx)
    beta, gamma, _ = barycentric(geo.tri_verts, a, b, c, gx, gy, gz, px, py, pz)
    return beta, gamma


@njit(inline="always")
def _patch_normal(geo, idx, px, py, pz):
    """Interpolated vertex normal of patch idx at local point p: barycentric
    in the fan triangle (v0, vk, vk+1) that contains p."""
    s = geo.poly_start[idx]
    n = geo.poly_count[idx]
    v = geo.poly_verts
    vn = geo.poly_vnormals
    gx, gy, gz = geo.poly_normal[idx, 0], geo.poly_normal[idx, 1], geo.poly_normal[idx, 2]
    best_x, best_y, best_z = gx, gy, gz
    best_score = -1e300
    for k in range(1, n - 1):
        a, b, c = s, s + k, s + k + 1
        beta, gamma, area = barycentric(v, a, b, c, gx, gy, gz, px, py, pz)
        if area == 0.0:
            continue
        alpha = 1.0 - beta - gamma
        score = min(alpha, min(beta, gamma))
        if score > best_score:
            best_score = score
            best_x = alpha * vn[a, 0] + beta * vn[b, 0] + gamma * vn[c, 0]
            best_y = alpha * vn[a, 1] + beta * vn[b, 1] + gamma * vn[c, 1]
            best_z = alpha * vn[a, 2] + beta * vn[b, 2] + gamma * vn[c, 2]
            if score >= 0.0:
                break
    return best_x, best_y, best_z



@njit(inline="always")
def surface(geo, kind, idx, px, py, pz):
    """Local geometric normal, local shading normal (both unnormalised) and
    material of primitive (kind, idx) at local point p."""
    if kind == SPHERE:
        nx = px - geo.sph_center[idx, 0]
        ny = py - geo.sph_center[idx, 1]
        nz = pz - geo.sph_center[idx, 2]
        return nx, ny, nz, nx, ny, nz, geo.sph_mat[idx]
    if kind == POLYGON or kind == PATCH:
        gx, gy, gz = geo.poly_normal[idx, 0], geo.poly_normal[idx, 1], geo.poly_normal[idx, 2]
        if kind == PATCH:
            sx, sy, sz = _patch_normal(geo, idx, px, py, pz)
            return gx, gy, gz, sx, sy, sz, geo.poly_mat[idx]
        return gx, gy, gz, gx, gy, gz, geo.poly_mat[idx]
    if kind == CONE:
        r0 = abs(geo.cone_r0[idx])
        slope = (abs(geo.cone_r1[idx]) - r0) / geo.cone_length[idx]
        nx, ny, nz = cone_normal(geo.cone_base[idx, 0], geo.cone_base[idx, 1], geo.cone_base[idx, 2],
                                 geo.cone_axis[idx, 0], geo.cone_axis[idx, 1], geo.cone_axis[idx, 2],
                                 r0, slope, px, py, pz)
        return nx, ny, nz, nx, ny, nz, geo.cone_mat[idx]
    return triangle_surface(geo, idx, px, py, pz)


@njit(inline="always")
def triangle_surface(geo, idx, px, py, pz):
    """surface of triangle idx: its code alone, for kernels that meet only triangles."""
    a, b, c, gx, gy, gz = triangle_normal(geo, idx)
    if not geo.tri_smooth[idx]:
        return gx, gy, gz, gx, gy, gz, geo.tri_mat[idx]
    beta, gamma, _ = barycentric(geo.tri_verts, a, b, c, gx, gy, gz, px, py, pz)
    alpha = 1.0 - beta - gamma
    vn = geo.tri_vnormals
    sx = alpha * vn[a, 0] + beta * vn[b, 0] + gamma * vn[c, 0]
    sy = alpha * vn[a, 1] + beta * vn[b, 1] + gamma * vn[c, 1]
    sz = alpha * vn[a, 2] + beta * vn[b, 2] + gamma * vn[c, 2]
    return gx, gy, gz, sx, sy, sz, geo.tri_mat[idx]


@njit(private=True)     # a call per hit, not inlined: inlined into trace it tripled trace's compile time
def hit_normals(geo, hit_f, hit_i, px, py, pz):
    """Unit geometric and shading normals in world space, and the material, of the hit that
    traverse.intersect recorded in hit_f, hit_i (workspace entries 5 and 6), at world point p;
    not yet turned toward the ray."""
    m = hit_f[1:13]
    lx = m[0] * px + m[1] * py + m[2] * pz + m[3]
    ly = m[4] * px + m[5] * py + m[6] * pz + m[7]
    lz = m[8] * px + m[9] * py + m[10] * pz + m[11]
    gx, gy, gz, sx, sy, sz, mat = surface(geo, hit_i[0], hit_i[1], lx, ly, lz)
    # normals to world space by the transpose of the world-to-local map
    gx, gy, gz = normalize(m[0] * gx + m[4] * gy + m[8] * gz, m[1] * gx + m[5] * gy + m[9] * gz,
                           m[2] * gx + m[6] * gy + m[10] * gz)
    sx, sy, sz = normalize(m[0] * sx + m[4] * sy + m[8] * sz, m[1] * sx + m[5] * sy + m[9] * sz,
                           m[2] * sx + m[6] * sy + m[10] * sz)
    if hit_i[3] & 1:
        # a surface a CSG difference cut: its outside is the operand's inside
        gx, gy, gz, sx, sy, sz = -gx, -gy, -gz, -sx, -sy, -sz
    return gx, gy, gz, sx, sy, sz, mat

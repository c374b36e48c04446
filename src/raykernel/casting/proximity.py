"""Point queries on a RayScene: the closest point of the surface, distances, inside tests.

    near = scene.closest_points(points)      # near.points, .distance, .prim_id, .geom_id, .normal
    d = scene.distance(points)
    s = scene.signed_distance(points)        # negative inside
    inside = scene.contains(points)
    near, inside = closest_points(scene, points), contains(scene, points, method="auto")   # what those call

Closest points: a BVH over every triangle, polygon, patch and sphere of the
scene in world space (built on the first query and kept), searched per
point near child first, a subtree skipped once its box lies farther than
the closest point so far. Exact in double precision: a triangle's closest
point by the region tests of Ericson's "Real-Time Collision Detection"
(5.1.5), a polygon's by projection onto its plane when the projection lies
inside it (the same crossing test the ray tests use, so concave polygons
work) and else the nearest point of its edges, a sphere's along the line
to its centre. Ties at equal distance go to the smaller (kind, index), as
in ray queries. Instanced scenes and cones are not supported (an error
says so).

Inside tests: a point is inside when a ray from it crosses the scene's
triangles and polygons an odd number of times, by the majority of three
rays in fixed, unrelated directions (robust where one ray grazes an edge or
runs along a face), or when it lies inside a sphere. The mesh should be
closed; signed_distance is the distance, negated inside. That is contains'
"vote"; its "parity" casts one ray a point (closed meshes: an occupancy grid
answers the points in cells no triangle touches, occupancy.py) and its
"winding" takes the generalized winding number (winding.py).

RayScene's point-query methods are thin: `closest_points` and `contains`
below hold their bodies; `is_closed`, `occupancy` and `winding_tree` keep on
the RayScene what contains builds once.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np

from ..aggregates.bvhbuild import build_bvh
from ..geometry.parallel import for_ranges
from ..geometry.config import njit
from ..geometry.primitives import INDEX_MASK, KIND_SHIFT, PATCH, POLYGON, SPHERE, TRIANGLE, point_in_polygon
from .meshbuild import build_mesh
from .occupancy import occupancy_grid
from .raybuild import EDGE_RULES
from .rayinput import RayInputError, read_only, vectors
from .winding import dipoles, winding_numbers

CHUNK = 1024
# three directions with no two in a plane with a coordinate axis, and no simple ratios
INSIDE_DIRECTIONS = np.array([[0.4395064455, 0.617598629942, 0.652231566745],
                              [-0.7235983, 0.2128742, 0.6565432],
                              [0.1836471, -0.8812345, 0.4355117]])


def parity_directions(points: np.ndarray, box: np.ndarray, threads=None) -> np.ndarray:
    """For each point, INSIDE_DIRECTIONS[0] with each component's sign turned toward the nearer
    face of `box` on that axis: of the eight such directions, the one that leaves the box soonest
    (each axis' exit distance is the smaller, so their minimum is). Any direction gives a closed
    mesh's parity, and a short ray crosses fewer nodes than one fixed direction."""
    out = np.empty_like(points)
    points = read_only(points)
    for_ranges(lambda i0, i1: _toward_nearer_faces(points, np.asarray(box, np.float64), np.abs(INSIDE_DIRECTIONS[0]),
                                                   out, np.int64(i0), np.int64(i1)),
               len(points), threads, kernel=_toward_nearer_faces, min_size=1 << 16)
    return out


@njit
def _toward_nearer_faces(points, box, d, out, i0, i1):
    for i in range(i0, i1):
        for a in range(3):
            out[i, a] = d[a] if box[3 + a] - points[i, a] <= points[i, a] - box[a] else -d[a]


@dataclass
class ClosestPoints:
    """The closest surface point of each query point, shaped as the points were."""

    points: np.ndarray      # (N, 3) the closest point on the surface
    distance: np.ndarray    # (N,) distance to it (inf for an empty scene)
    prim_id: np.ndarray     # (N,) the primitive within its geometry, -1 for an empty scene
    geom_id: np.ndarray     # (N,) its geometry (RayScene.geometries), -1 for an empty scene
    kind: np.ndarray        # (N,) its kind (0 sphere, 1 polygon, 2 patch, 4 triangle), -1
    normal: np.ndarray      # (N, 3) unit geometric normal of that primitive there (winding / outward)


# ----------------------------------------------------------------- kernel

@njit(inline="always")
def _closest_on_triangle(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz):
    """Ericson's region tests: the closest point of triangle abc to p."""
    abx, aby, abz = bx - ax, by - ay, bz - az
    acx, acy, acz = cx - ax, cy - ay, cz - az
    apx, apy, apz = px - ax, py - ay, pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        return ax, ay, az
    bpx, bpy, bpz = px - bx, py - by, pz - bz
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        return bx, by, bz
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v = d1 / (d1 - d3)
        return ax + v * abx, ay + v * aby, az + v * abz
    cpx, cpy, cpz = px - cx, py - cy, pz - cz
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:
        return cx, cy, cz
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        w = d2 / (d2 - d6)
        return ax + w * acx, ay + w * acy, az + w * acz
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return bx + w * (cx - bx), by + w * (cy - by), bz + w * (cz - bz)
    denom = va + vb + vc
    if denom == 0.0:        # a degenerate triangle: its longest edge is all of it
        return _closest_on_segment(px, py, pz, ax, ay, az, bx, by, bz)
    v = vb / denom
    w = vc / denom
    return ax + abx * v + acx * w, ay + aby * v + acy * w, az + abz * v + acz * w


@njit(inline="always")
def _closest_on_segment(px, py, pz, ax, ay, az, bx, by, bz):
    ex, ey, ez = bx - ax, by - ay, bz - az
    ee = ex * ex + ey * ey + ez * ez
    s = 0.0 if ee == 0.0 else ((px - ax) * ex + (py - ay) * ey + (pz - az) * ez) / ee
    s = min(1.0, max(0.0, s))
    return ax + s * ex, ay + s * ey, az + s * ez


@njit(borrows=True)   # called per candidate: no reference counting
def _closest_on_polygon(poly_normal, poly_start, poly_count, poly_axis, v, i, px, py, pz):
    nx, ny, nz = poly_normal[i, 0], poly_normal[i, 1], poly_normal[i, 2]
    s, n = poly_start[i], poly_count[i]
    h = (px - v[s, 0]) * nx + (py - v[s, 1]) * ny + (pz - v[s, 2]) * nz
    qx, qy, qz = px - h * nx, py - h * ny, pz - h * nz
    if (nx != 0.0 or ny != 0.0 or nz != 0.0) and point_in_polygon(v, s, n, poly_axis[i], qx, qy, qz):
        return qx, qy, qz
    best = np.inf
    bx = by = bz = 0.0
    for k in range(n):
        a, b = s + k, s + (k + 1) % n
        cx, cy, cz = _closest_on_segment(px, py, pz, v[a, 0], v[a, 1], v[a, 2], v[b, 0], v[b, 1], v[b, 2])
        d = (cx - px) ** 2 + (cy - py) ** 2 + (cz - pz) ** 2
        if d < best:
            best, bx, by, bz = d, cx, cy, cz
    return bx, by, bz


@njit(inline="always")
def _closest_point(tri_verts, tri_faces, sph_center, sph_radius, poly_normal, poly_start, poly_count, poly_axis,
                   poly_verts, ref, px, py, pz):
    kind = ref >> KIND_SHIFT
    idx = ref & INDEX_MASK
    if kind == TRIANGLE:
        a, b, c = tri_faces[idx, 0], tri_faces[idx, 1], tri_faces[idx, 2]
        v = tri_verts
        return _closest_on_triangle(px, py, pz, v[a, 0], v[a, 1], v[a, 2], v[b, 0], v[b, 1], v[b, 2], v[c, 0],
                                    v[c, 1], v[c, 2])
    if kind == SPHERE:
        cx, cy, cz = sph_center[idx, 0], sph_center[idx, 1], sph_center[idx, 2]
        r = abs(sph_radius[idx])
        dx, dy, dz = px - cx, py - cy, pz - cz
        n = np.sqrt(dx * dx + dy * dy + dz * dz)
        if n == 0.0:
            return cx + r, cy, cz       # the centre: every surface point is as near; take +x
        return cx + r * dx / n, cy + r * dy / n, cz + r * dz / n
    return _closest_on_polygon(poly_normal, poly_start, poly_count, poly_axis, poly_verts, idx, px, py, pz)


@njit(inline="always")
def _box_distance2(b, n, px, py, pz):
    dx = max(max(b[n, 0] - px, 0.0), px - b[n, 3])
    dy = max(max(b[n, 1] - py, 0.0), py - b[n, 4])
    dz = max(max(b[n, 2] - pz, 0.0), pz - b[n, 5])
    return dx * dx + dy * dy + dz * dz


@njit
def _query(tri_verts, tri_faces, sph_center, sph_radius, poly_normal, poly_start, poly_count, poly_axis, poly_verts,
           bounds, first, count, refs, points, out_p, out_d, out_ref, c0, c1):
    """Closest item of every point in chunks c0..c1-1 (the scene's arrays one by one: a call
    taking the whole Geometry tuple pays for every array in it)."""
    stack = np.empty(256, np.int64)
    for c in range(c0, c1):
        for r in range(c * CHUNK, min(points.shape[0], (c + 1) * CHUNK)):
            px, py, pz = points[r, 0], points[r, 1], points[r, 2]
            best = np.inf
            best_ref = np.int64(-1)
            bx = by = bz = np.nan
            sp = 0
            if refs.shape[0] > 0:
                stack[0] = 0
                sp = 1
            while sp > 0:
                sp -= 1
                n = stack[sp]
                if _box_distance2(bounds, n, px, py, pz) > best:
                    continue
                if count[n] > 0:
                    for k in range(first[n], first[n] + count[n]):
                        ref = refs[k]
                        qx, qy, qz = _closest_point(tri_verts, tri_faces, sph_center, sph_radius, poly_normal,
                                                    poly_start, poly_count, poly_axis, poly_verts, ref, px, py, pz)
                        d = (qx - px) ** 2 + (qy - py) ** 2 + (qz - pz) ** 2
                        if d < best or (d == best and ref < best_ref):
                            best, best_ref, bx, by, bz = d, ref, qx, qy, qz
                    continue
                left, right = first[n], first[n] + 1
                dl = _box_distance2(bounds, left, px, py, pz)
                dr = _box_distance2(bounds, right, px, py, pz)
                # the nearer child on top
                if dl <= dr:
                    stack[sp], stack[sp + 1] = right, left
                else:
                    stack[sp], stack[sp + 1] = left, right
                sp += 2
            out_p[r, 0], out_p[r, 1], out_p[r, 2] = bx, by, bz
            out_d[r] = np.sqrt(best)
            out_ref[r] = best_ref


# ----------------------------------------------------------------- the index

class PointIndex:
    """The BVH over a RayScene's primitives for point queries (built once, thread-safe)."""

    def __init__(self, geo):
        if len(geo.inst_agg):
            raise ValueError("point queries (closest_points, distance, contains) do not handle instances yet")
        if len(geo.cone_length):
            raise ValueError("point queries do not handle cones (open surfaces)")
        self.geo = geo
        refs, boxes = [], []
        if len(geo.tri_faces):
            tri = geo.tri_verts[geo.tri_faces]
            refs.append((np.int64(TRIANGLE) << KIND_SHIFT) | np.arange(len(tri)))
            boxes.append(np.hstack([tri.min(axis=1), tri.max(axis=1)]))
        if len(geo.sph_radius):
            r = np.abs(geo.sph_radius)[:, None]
            refs.append((np.int64(SPHERE) << KIND_SHIFT) | np.arange(len(r)))
            boxes.append(np.hstack([geo.sph_center - r, geo.sph_center + r]))
        if len(geo.poly_start):
            lo = np.minimum.reduceat(geo.poly_verts, geo.poly_start, axis=0)
            hi = np.maximum.reduceat(geo.poly_verts, geo.poly_start, axis=0)
            refs.append((np.int64(POLYGON) << KIND_SHIFT) | np.arange(len(lo)))
            boxes.append(np.hstack([lo, hi]))
        self.refs_by_item = np.concatenate(refs) if refs else np.zeros(0, np.int64)
        bounds = np.vstack(boxes) if boxes else np.zeros((0, 6))
        self.bvh, _ = build_bvh(bounds, leaf_size=4)
        self.refs = np.ascontiguousarray(self.refs_by_item[self.bvh.order])

    def query(self, points: np.ndarray, threads=None):
        """(closest points (N, 3), distances (N,), tagged references (N,)) of points (N, 3)."""
        n = len(points)
        points = read_only(points)      # one compiled kernel whatever the caller's flags
        out_p, out_d, out_ref = np.empty((n, 3)), np.empty(n), np.empty(n, np.int64)
        b, g = self.bvh, self.geo
        arrays = (g.tri_verts, g.tri_faces, g.sph_center, g.sph_radius, g.poly_normal, g.poly_start, g.poly_count,
                  g.poly_axis, g.poly_verts, b.bounds, b.first, b.count, self.refs, points, out_p, out_d, out_ref)
        for_ranges(lambda c0, c1: _query(*arrays, c0, c1), (n + CHUNK - 1) // CHUNK, threads, kernel=_query)
        return out_p, out_d, out_ref


_index_lock = threading.Lock()


def point_index(scene) -> PointIndex:
    """The scene's PointIndex, built on first use (once, whichever thread asks first)."""
    with _index_lock:
        index = getattr(scene, "_point_index", None)
        if index is None:
            index = PointIndex(scene.geo)
            scene._point_index = index
        return index


def kinds_of(geo, refs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(kind, global index) of tagged references; -1 for -1. Polygons that are patches (they
    have vertex normals) get PATCH."""
    kind = np.where(refs >= 0, refs >> KIND_SHIFT, -1)
    idx = np.where(refs >= 0, refs & INDEX_MASK, -1)
    poly = kind == POLYGON
    if poly.any():
        first = geo.poly_start[idx[poly]]
        kind[np.flatnonzero(poly)[np.any(geo.poly_vnormals[first] != 0.0, axis=1)]] = PATCH
    return kind, idx


def _unit(v):
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 0, n, 1.0)


def surface_normals(geo, kind, idx, points):
    """Geometric unit normals of the primitives at their closest points (NaN where kind is -1)."""
    normal = np.full((len(kind), 3), np.nan)
    tri = kind == TRIANGLE
    if tri.any():
        f = geo.tri_faces[idx[tri]]
        v = geo.tri_verts
        normal[tri] = _unit(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]))
    sph = kind == SPHERE
    if sph.any():
        normal[sph] = _unit(points[sph] - geo.sph_center[idx[sph]]) * np.sign(geo.sph_radius[idx[sph]])[:, None]
    poly = (kind == POLYGON) | (kind == PATCH)
    if poly.any():
        normal[poly] = geo.poly_normal[idx[poly]]
    return normal


def inside_spheres(geo, points: np.ndarray, block: int = 1 << 22) -> np.ndarray:
    """True where a point lies strictly inside any sphere (in blocks of about `block` pairs)."""
    inside = np.zeros(len(points), bool)
    c, r2 = geo.sph_center, geo.sph_radius ** 2
    if not len(r2):
        return inside
    step = max(1, block // len(r2))
    for a in range(0, len(points), step):
        p = points[a:a + step]
        d2 = ((p[:, None, :] - c[None, :, :]) ** 2).sum(axis=2)
        inside[a:a + step] = np.any(d2 < r2[None, :], axis=1)
    return inside


# ----------------------------------------------------------------- RayScene's point queries

def _points(points) -> tuple[np.ndarray, tuple]:
    """(N, 3) float64 points, checked (RayInputError names a bad one), and their shape."""
    p = vectors(points, "points")
    return np.ascontiguousarray(p.reshape(-1, 3)), p.shape[:-1]


def closest_points(rs, points, threads: int | None = None) -> ClosestPoints:
    """RayScene.closest_points: the closest point of the scene's surface to each point."""
    p, shape = _points(points)
    try:
        index = point_index(rs)
    except ValueError as e:
        raise RayInputError(str(e)) from None
    q, dist, refs = index.query(p, threads)
    kind, idx = kinds_of(rs.geo, refs)
    geom, prim = rs._identify(kind, idx)
    normal = surface_normals(rs.geo, kind, idx, q)
    return ClosestPoints(points=q.reshape(shape + (3,)), distance=dist.reshape(shape), prim_id=prim.reshape(shape),
                         geom_id=geom.reshape(shape), kind=kind.reshape(shape), normal=normal.reshape(shape + (3,)))


def contains(rs, points, threads: int | None = None, method: str = "auto") -> np.ndarray:
    """RayScene.contains: True where a point lies inside the scene."""
    p, shape = _points(points)
    if method not in ("auto", "parity", "winding", "vote"):
        raise RayInputError(f"method must be auto, parity, winding or vote, got {method!r}")
    if rs._geo is not None and (len(rs._geo.inst_agg) or len(rs._geo.cone_length)):
        raise RayInputError("contains does not handle instances or cones yet")
    meshes_only = [g["kind"] for g in rs.geometries] == ["triangle"] * len(rs.geometries)
    if method == "auto":
        method = "vote" if not meshes_only else "parity" if is_closed(rs) else "winding"
    if method != "vote" and not meshes_only:
        raise RayInputError(f"contains(method={method!r}) takes triangle meshes only; this scene has "
                            f"{', '.join(sorted({g['kind'] for g in rs.geometries} - {'triangle'}))}")
    if method == "winding":
        mesh, far = winding_tree(rs)
        return (winding_numbers(mesh, p, far, threads) > 0.5).reshape(shape)
    if method == "parity":
        box = rs._mesh.geo.agg_bounds[0] if rs._mesh is not None else rs.geo.agg_bounds[rs.geo.root]

        def odd_crossings(q):
            return rs.count_hits(q, parity_directions(q, box, threads), threads=threads) % 2 == 1

        if not is_closed(rs):
            return odd_crossings(p).reshape(shape)
        # a closed mesh: points in cells no triangle touches take their region's answer (occupancy.py)
        inside, known = occupancy(rs, odd_crossings).lookup(p, threads)
        rest = np.flatnonzero(~known)
        if len(rest):
            inside[rest] = odd_crossings(p[rest])
        return inside.reshape(shape)
    spheres = [g for g, info in enumerate(rs.geometries) if info["kind"] == "sphere"]

    def odd(q, direction):
        if spheres:
            # a sphere counts once per ray in hit lists, but is crossed twice: its own test below
            ray, _, _, geom, _ = rs.intersect_all(q, direction, ids=True, threads=threads)
            return np.bincount(ray[~np.isin(geom, spheres)], minlength=len(q)) % 2 == 1
        return rs.count_hits(q, direction, threads=threads) % 2 == 1

    first, second = odd(p, INSIDE_DIRECTIONS[0]), odd(p, INSIDE_DIRECTIONS[1])
    inside = first & second
    split = np.flatnonzero(first != second)         # the third ray decides only where two disagree
    if len(split):
        inside[split] = odd(p[split], INSIDE_DIRECTIONS[2])
    inside |= inside_spheres(rs.geo, p)
    return inside.reshape(shape)


def is_closed(rs) -> bool:
    """Whether the scene is closed triangle meshes, not nested: every edge two triangles', once each way."""
    if not hasattr(rs, "_is_closed"):
        root = rs.scene.root
        rs._is_closed = bool(root.meshes) and not root.children and all(map(_closed_mesh, root.meshes))
    return rs._is_closed


def occupancy(rs, odd_crossings):
    """The closed meshes' occupancy grid (built once; its regions decided by odd_crossings)."""
    if not hasattr(rs, "_grid"):
        meshes = rs.scene.root.meshes
        offsets = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
        vertices = np.concatenate([np.asarray(m.vertices, np.float64) for m in meshes])
        faces = np.concatenate([np.asarray(m.faces, np.int64) + o for m, o in zip(meshes, offsets)])
        rs._grid = occupancy_grid(vertices, faces, odd_crossings)
    return rs._grid


def winding_tree(rs):
    """The 4-wide mesh kernel and its dipoles for winding numbers (built once: for a scene
    walked another way, from its triangles at medium quality)."""
    if not hasattr(rs, "_far"):
        mesh = rs._mesh
        if mesh is None or not len(mesh.wide.nodes):
            g = rs.geo
            mesh, _ = build_mesh(np.ascontiguousarray(g.tri_verts), np.ascontiguousarray(g.tri_faces), None,
                                 "medium", EDGE_RULES[rs.edges])
        rs._far = (mesh, dipoles(mesh))
    return rs._far


def _closed_mesh(mesh) -> bool:
    """Every directed edge of the mesh appears once, and so does its reverse."""
    f = mesh.faces
    edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    key = np.sort(edges[:, 0] * (len(mesh.vertices) + 1) + edges[:, 1])
    twin = edges[:, 1] * (len(mesh.vertices) + 1) + edges[:, 0]
    found = key[np.minimum(np.searchsorted(key, twin), len(key) - 1)]
    return bool(np.all(np.diff(key) > 0)) and bool(np.all(found == twin))

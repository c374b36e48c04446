"""The fast path of RayScene: one triangle mesh (or several) under one BVH.

    mesh = MeshKernel.of(geo, geometries)   # None unless geo is triangles under a single BVH, no instances
    mesh.kernel(*mesh, origins, directions, tmin, tmax, mode, ...)   # the outputs of rayqueries' generic kernel
                                                                     # (surfaces: None or (uv, gn, sn))

The generic intersection routine (traverse.py) carries every aggregate kind,
nesting frames, instances and mailboxes through one loop; for the common
case of ray casting against a plain mesh that generality costs several
times the work. This kernel walks the same BVH with the same conservative
box test and runs the same watertight triangle test, so its hits, ties and
surfaces are identical to the generic kernel's (tested), with four changes
that make it fast:

* `query` walks the BVH collapsed 4-wide (aggregates/widebvh.py, next_leaf:
  the 4-wide walk the fast render walk takes too): a node's four child boxes
  are tested in one vector slab test and the children the ray enters are
  visited nearest first. The leaves are the binary tree's, so a ray meets the
  same triangles; `query_binary` (bvh(width=2)) walks the binary tree with the
  generic kernel's own binary walk (bvhwalk.descend), counters included;
* the ray's permutation and shear for the watertight test are computed once
  per ray instead of once per triangle (the same arithmetic, bit for bit),
  and the test is inlined into the leaf loop;
* the triangles' corners are in leaf order, so a leaf's triangles are read
  from one contiguous block: on the 4-wide tree blocks of four triangles as
  structure of arrays (triangles4.py), tested four at a time by one vector
  watertight test (the same t bit for bit; edge and vertex ties go to the
  scalar test, which reads the same block), a leaf's child field naming its
  first lane and `prims` each lane's triangle; nine numbers per reference
  copied here for the binary one;
* the loop knows only BVH nodes and triangles.

The surfaces of the closest hits (uv, normals) are made after each chunk's
walk, from the lane and t it left, by `_surfaces`: compiled apart and only
for a query that asks for a surface field (numba drops the call when
surface_out is None), so a first query of t and ids compiles no surface code
and the walk is compiled once for both (BENCHMARKS.md, "Start-up"); the
general kernel (rayqueries._query) does the same.

Meshes (RayScene.from_mesh, from_trimesh) are built straight into these
arrays (meshbuild.py), at medium quality with MESH_ACCEL's tree: a BVH whose
SAH prices leaves in blocks of four triangles (bvh(block=4), as Embree
prices its leaves), so that leaves fill their blocks.

Tracing large incoherent batches in Morton order of origin and direction
octant was tried and dropped: the scattered reads and writes cost more than
the better cache use of the traversal saved (bench/raycast.py numbers in
BENCHMARKS.md).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..aggregates.bvhwalk import CODE as BVH
from ..aggregates.bvhwalk import descend
from ..aggregates.widebvh import CHILD, COUNT, NO_CHILD, WideBVH, leaf_range, next_leaf, wide_ray
from ..engine.flatten import Geometry
from ..engine.traverse import ALL_HITS
from ..geometry import counters as C
from ..geometry.boxes import CONSERVATIVE, box_entry, inverse
from ..geometry.config import njit
from ..geometry.primitives import INDEX_MASK, TRIANGLE, hit_sheared, ray_shear
from .hitsurface import IDENTITY, store_corner_surface, store_no_surface, store_triangle_surface
from .rayinput import valid_ray
from ..errors import SceneError
from .triangles4 import BLOCK, COLUMNS, corner, hit4, leaf_blocks

INF = np.inf
MESH_ACCEL = "bvh(block=4)"  # RayScene's meshes: the SAH counts triangles in blocks of four (triangles4.py)
STACK = 192                  # a BVH is at most 96 nodes deep (flatten.MAX_TREE_DEPTH): 2 entries per level
STACK4 = 384                 # the 4-wide tree is no deeper: 4 entries per level


class MeshArrays(NamedTuple):
    """The scene Geometry's arrays that the mesh kernel reads. Given the whole Geometry (79
    fields) the kernel compiled their unpacking as well: seconds more of a first query (BENCHMARKS.md,
    "Start-up")."""
    agg_bounds: np.ndarray
    root: int
    tri_edges: np.ndarray
    tri_verts: np.ndarray
    tri_faces: np.ndarray
    tri_smooth: np.ndarray      # (a mesh built with no normals has none: every triangle flat)
    tri_mat: np.ndarray
    tri_vnormals: np.ndarray
    node_bounds: np.ndarray
    node_first: np.ndarray
    node_count: np.ndarray


class MeshKernel(NamedTuple):
    geo: MeshArrays          # what the kernel reads of the scene's Geometry (or of the mesh: meshbuild.py)
    corners: np.ndarray      # binary walk: (R, 9 or more) float64, v0, v1, v2 of each leaf reference; else (0, 9)
    prims: np.ndarray        # the global triangle of each leaf reference (binary walk, (R,) int64), or of
                             # each block lane (4-wide walk, (4 B,) int32, -1 where unused)
    geoms: np.ndarray        # (G + 1,) int64: the first global triangle of each mesh, then the triangle count
    root: int                # root node of the binary BVH
    wide: WideBVH            # the BVH collapsed 4-wide (widebvh.py), a leaf's child its first lane; empty for width 2
    blocks: np.ndarray       # (B, 36) float64 the 4-wide tree's leaves in blocks of 4 triangles (triangles4.py)

    @classmethod
    def of(cls, geo: Geometry, geometries: np.ndarray, dtype=np.float64) -> "MeshKernel | None":
        """The fast-path arrays, or None when geo holds anything but triangles under one BVH.
        geometries: flatten's (kind, first global index, count) rows, all triangle meshes here;
        dtype: the 4-wide tree's triangle blocks' (float32 for a mesh of precision "single").
        Walks the BVH collapsed 4-wide (query) where flatten collapsed it (bvh(width=4)), else
        the binary tree as built (query_binary)."""
        if (len(geo.agg_kind) != 1 or geo.agg_kind[0] != BVH or len(geo.inst_agg) or len(geo.sph_radius)
                or len(geo.cone_length) or len(geo.poly_start) or not len(geo.tri_faces)):
            return None
        prims = (geo.refs & INDEX_MASK).astype(np.int64)
        geoms = np.append(geometries[:, 1], len(geo.tri_faces)).astype(np.int64)
        arrays = MeshArrays(*(getattr(geo, name) for name in MeshArrays._fields))
        root = int(geo.agg_start[geo.root])
        if not len(geo.wide_nodes):
            corners = np.ascontiguousarray(geo.tri_verts[geo.tri_faces[prims]].reshape(-1, 9))
            return cls(arrays, corners, prims, geoms, root, WideBVH(geo.wide_nodes, geo.wide_center), NO_BLOCKS)
        # the center copied: the Geometry's is read-only (widewalk.wide_only), a mesh's own writable, and
        # numba would compile the kernel once for each
        wide, blocks, lanes = wide_leaves(WideBVH(geo.wide_nodes.copy(), geo.wide_center.copy()), geo.tri_verts,
                                          geo.tri_faces, prims, dtype=dtype)
        return cls(arrays, NO_CORNERS, lanes, geoms, root, wide, blocks)

    @property
    def kernel(self):
        return query if len(self.wide.nodes) else query_binary

    @property
    def nbytes(self) -> int:
        """Bytes of the arrays this kernel holds beyond the mesh's vertices and faces."""
        own = (self.corners, self.prims, self.geoms, self.wide.nodes, self.blocks, self.geo.agg_bounds,
               self.geo.node_bounds, self.geo.node_first, self.geo.node_count, self.geo.tri_smooth, self.geo.tri_mat)
        return int(sum(a.nbytes for a in own))


NO_CORNERS = np.zeros((0, 9))
NO_BLOCKS = np.zeros((0, COLUMNS))


def wide_leaves(wide: WideBVH, verts, faces, prims, threads=None, dtype=np.float64) -> tuple[WideBVH, np.ndarray, np.ndarray]:
    """The 4-wide tree's leaves in blocks (triangles4.leaf_blocks), the tree's leaf children
    changed in place from first reference to first lane: (wide, blocks, lane triangles).
    dtype: the blocks' (triangles4.leaf_blocks)."""
    count = wide.nodes[:, COUNT:COUNT + 4]
    leaves = count > 0
    child = wide.nodes[:, CHILD:CHILD + 4]
    blocks, lanes, start = leaf_blocks(verts, faces, prims, child[leaves], count[leaves], threads, dtype)
    if len(start) and start[-1] >= 2 ** 31:
        raise SceneError(f"the 4-wide mesh kernel holds at most 2**31 - 1 triangle lanes; this mesh needs "
                         f"{int(start[-1]):,}: use bvh(width=2)")
    child[leaves] = start
    return wide, blocks, lanes


# the same test, inlined here where it is the inner loop (a call spills its 15 arguments)
_hit_sheared = njit(inline="always")(hit_sheared.py_func)


@njit(inline="always")
def _hit(c, j, o, kx, ky, kz, sx, sy, sz, tmin, tmax, edges):
    """primitives.hit_triangle for triangle j of c (a corners row or a block lane: triangles4.corner)
    with the ray's shear precomputed."""
    return _hit_sheared(corner(c, j, kx) - o[kx], corner(c, j, ky) - o[ky], corner(c, j, kz) - o[kz],
                        corner(c, j, 3 + kx) - o[kx], corner(c, j, 3 + ky) - o[ky], corner(c, j, 3 + kz) - o[kz],
                        corner(c, j, 6 + kx) - o[kx], corner(c, j, 6 + ky) - o[ky], corner(c, j, 6 + kz) - o[kz],
                        sx, sy, sz, tmin, tmax, edges)


@njit
def query(geo, corners, prims, geoms, root, wide, blocks, origins, directions, tmin, tmax, mode,
          chunk, t_out, kind_out, geom_out, idx_out, inst_out, surface_out, offsets, all_t, all_i, counters, c0, c1):
    """Closest (mode 0), any (mode 1) or all hits (ALL_HITS) of every ray, with the
    outputs of rayqueries._query, identities as the user sees them: geometry and
    index within it (-1 on a miss). All hits: with len(offsets) == 0 counts them
    into idx_out, else writes ray r's hits to rows offsets[r] .. offsets[r + 1]
    of all_t / all_i as (kind, global index, instance), like the generic kernel.
    surface_out: None, or (uv, gn, sn) to fill with the closest hits' surfaces, a chunk's after its
    walk (_surfaces): without them numba compiles no surface code (it drops the branch for None).
    Chunks c0..c1-1 of `chunk` rays, counting into counters[c]. Walks the 4-wide tree."""
    n = origins.shape[0]
    hit_j, hit_t = np.empty(chunk, np.int64), np.empty(chunk)
    for c in range(c0, c1):
        stack = np.empty(STACK4, np.int64)
        stack_t = np.empty(STACK4)
        o = np.empty(3)
        t4 = np.empty(4)
        r0, r1 = c * chunk, min(n, (c + 1) * chunk)
        _chunk4(geo, prims, geoms, wide, blocks, origins, directions, tmin, tmax, mode,
                t_out, kind_out, geom_out, idx_out, inst_out, offsets, all_t, all_i, counters, c, r0, r1,
                stack, stack_t, o, t4, hit_j, hit_t)
        if surface_out is not None and mode != ALL_HITS:
            _surfaces(geo, blocks, prims, origins, directions, hit_j, hit_t, r0, r1, surface_out)


@njit
def query_binary(geo, corners, prims, geoms, root, wide, blocks, origins, directions, tmin, tmax,
                 mode, chunk, t_out, kind_out, geom_out, idx_out, inst_out, surface_out, offsets, all_t, all_i,
                 counters, c0, c1):
    """query on the binary tree as built (bvh(width=2)), with the general kernel's binary walk."""
    n = origins.shape[0]
    hit_j, hit_t = np.empty(chunk, np.int64), np.empty(chunk)
    for c in range(c0, c1):
        stack_a = np.empty(STACK, np.int64)
        stack_b = np.empty(STACK, np.int64)
        stack_t = np.empty(STACK)
        o = np.empty(3)
        cnt = np.zeros(C.N_COUNTERS, np.int64)
        r0, r1 = c * chunk, min(n, (c + 1) * chunk)
        _chunk(geo, corners, prims, geoms, root, origins, directions, tmin, tmax, mode, t_out, kind_out, geom_out,
               idx_out, inst_out, offsets, all_t, all_i, counters, c, r0, r1, stack_a, stack_b, stack_t, o, cnt,
               hit_j, hit_t)
        if surface_out is not None and mode != ALL_HITS:
            _surfaces(geo, corners, prims, origins, directions, hit_j, hit_t, r0, r1, surface_out)


@njit(private=True)     # one call per chunk, without reference counting
def _chunk(geo, corners, prims, geoms, root, origins, directions, tmin, tmax, mode, t_out, kind_out, geom_out,
           idx_out, inst_out, offsets, all_t, all_i, counters, c, r0, r1, stack_a, stack_b, stack_t, o, cnt,
           hit_j, hit_t):
    """Rays r0..r1-1 of query but their surfaces, counting into counters[c], with the chunk's stack,
    origin scratch and counter row for the binary walk's visits (bvhwalk.descend counts them); ray
    r0 + i's closest hit into hit_j[i] (its row of corners; -1 a miss, -2 a ray not cast) and hit_t[i]."""
    store = offsets.shape[0] > 0
    edges = geo.tri_edges[0]
    per_lo, per_hi = tmin.shape[0] > 1, tmax.shape[0] > 1     # else one bound for every ray
    # counters in locals (registers), written once per chunk
    n_bounds = n_tests = n_hits = n_entries = n_invalid = np.int64(0)
    for r in range(r0, r1):
        ox, oy, oz = origins[r, 0], origins[r, 1], origins[r, 2]
        dx, dy, dz = directions[r, 0], directions[r, 1], directions[r, 2]
        if not valid_ray(ox, oy, oz, dx, dy, dz):
            n_invalid += 1      # not cast: RayScene names it (rayinput.py)
            hit_j[r - r0] = -2
            continue
        o[0], o[1], o[2] = ox, oy, oz
        ix, iy, iz = inverse(dx), inverse(dy), inverse(dz)
        kx, ky, kz, sx, sy, sz = ray_shear(dx, dy, dz)
        lo = tmin[r if per_lo else 0]
        best = tmax[r if per_hi else 0]
        best_j = np.int64(-1)
        n_all = np.int64(0)
        base = offsets[r] if store else 0
        sp = 0
        n_bounds += 1
        te = box_entry(geo.agg_bounds, geo.root, ox, oy, oz, ix, iy, iz, lo, best)
        if te != INF:
            stack_a[0] = root
            stack_t[0] = te
            sp = 1
            n_entries += 1
        while sp > 0:
            sp -= 1
            if stack_t[sp] > best and stack_t[sp] > best * CONSERVATIVE:
                continue        # entered beyond the closest hit, beyond rounding (ties need the node)
            sp, s, e = descend(geo.node_bounds, geo.node_first, geo.node_count, stack_a[sp], ox, oy, oz, ix, iy, iz,
                               lo, best, stack_a, stack_b, stack_t, sp, cnt, None)
            if s == e:
                continue
            best, best_j, n_all, tested, hits, done = _leaf(corners, prims, s, e, o, kx, ky, kz, sx, sy, sz, lo,
                                                            best, best_j, edges, mode, store, offsets, r, base, n_all,
                                                            all_t, all_i)
            n_tests += tested
            n_hits += hits
            if done:
                sp = 0
        hit_j[r - r0], hit_t[r - r0] = best_j, best
        _finish(prims, geoms, mode, r, best, best_j, n_all, store, t_out, kind_out, geom_out, idx_out, inst_out)
    _count(counters, c, r1 - r0 - n_invalid, n_bounds + cnt[C.BOUNDS_TESTS], cnt[C.CELLS_VISITED], n_entries,
           cnt[C.CELLS_LEAVES], n_tests, n_hits)


@njit(private=True)
def _chunk4(geo, prims, geoms, wide, blocks, origins, directions, tmin, tmax, mode, t_out,
            kind_out, geom_out, idx_out, inst_out, offsets, all_t, all_i, counters, c, r0, r1, stack, stack_t, o, t4,
            hit_j, hit_t):
    """_chunk on the 4-wide tree (hit_j the hit's lane). Stack entries: v >= 0 a wide node to
    visit, v < 0 the leaf in child slot -v - 1 (node * 4 + slot); of a node's children the ray
    enters, the nearest is taken next and the others go on the stack nearest on top (widebvh.visit)."""
    store = offsets.shape[0] > 0
    nodes, center = wide
    edges = geo.tri_edges[0]
    per_lo, per_hi = tmin.shape[0] > 1, tmax.shape[0] > 1
    n_bounds = n_nodes = n_leaves = n_tests = n_hits = n_entries = n_invalid = np.int64(0)
    for r in range(r0, r1):
        ox, oy, oz = origins[r, 0], origins[r, 1], origins[r, 2]
        dx, dy, dz = directions[r, 0], directions[r, 1], directions[r, 2]
        if not valid_ray(ox, oy, oz, dx, dy, dz):
            n_invalid += 1      # not cast: RayScene names it (rayinput.py)
            hit_j[r - r0] = -2
            continue
        o[0], o[1], o[2] = ox, oy, oz
        ix, iy, iz = inverse(dx), inverse(dy), inverse(dz)
        wx, wy, wz, vx, vy, vz, near = wide_ray(center, ox, oy, oz, ix, iy, iz)
        kx, ky, kz, sx, sy, sz = ray_shear(dx, dy, dz)
        lo = tmin[r if per_lo else 0]
        best = tmax[r if per_hi else 0]
        best_j = np.int64(-1)
        n_all = np.int64(0)
        base = offsets[r] if store else 0
        sp = 0
        n_bounds += 1
        te = box_entry(geo.agg_bounds, geo.root, ox, oy, oz, ix, iy, iz, lo, best)
        if te != INF:
            stack[0] = 0
            stack_t[0] = te
            sp = 1
            n_entries += 1
        while sp > 0:
            v, sp, n_nodes, n_bounds = next_leaf(nodes, wx, wy, wz, vx, vy, vz, near, lo, best, t4, stack, stack_t,
                                                 sp, n_nodes, n_bounds)
            if v == NO_CHILD:
                continue
            n_leaves += 1
            s0, e0 = leaf_range(nodes, v)
            best, best_j, n_all, tested, hits, done = _leaf4(blocks, prims, s0, e0, o, kx, ky, kz, sx, sy, sz, lo,
                                                             best, best_j, edges, mode, store, offsets, r, base, n_all,
                                                             all_t, all_i, t4)
            n_tests += tested
            n_hits += hits
            if done:
                sp = 0
        hit_j[r - r0], hit_t[r - r0] = best_j, best
        _finish(prims, geoms, mode, r, best, best_j, n_all, store, t_out, kind_out, geom_out, idx_out, inst_out)
    _count(counters, c, r1 - r0 - n_invalid, n_bounds, n_nodes, n_entries, n_leaves, n_tests, n_hits)


@njit(inline="always")
def _leaf4(blocks, prims, s, e, o, kx, ky, kz, sx, sy, sz, lo, best, best_j, edges, mode, store, offsets, r, base,
           n_all, all_t, all_i, t4):
    """_leaf on the leaf's lanes s..e-1 (s a block's first lane), four at a time (triangles4.hit4):
    each block in one vector test, its lanes then taken in order as _leaf takes them (a lane's t
    is checked against the closest hit of the lanes before it; lanes with a zero edge function
    go through the scalar test and its tie rule). best_j: the closest hit's lane."""
    okx, oky, okz = o[kx], o[ky], o[kz]
    hits = 0
    for j0 in range(s, e, BLOCK):
        m = hit4(blocks, j0 >> 2, kx, ky, kz, okx, oky, okz, sx, sy, sz, lo, best, t4)
        if m == 0:
            continue
        for lane in range(min(BLOCK, e - j0)):
            j = j0 + lane
            if m >> (BLOCK + lane) & 1:
                t = _hit(blocks, j, o, kx, ky, kz, sx, sy, sz, lo, best, edges)
                if t == INF:
                    continue
            elif m >> lane & 1 and t4[lane] <= best:
                t = t4[lane]
            else:
                continue
            hits += 1
            best, best_j, n_all, closer = _take(prims, j, t, best, best_j, mode, store, offsets, r, base, n_all,
                                                all_t, all_i)
            if closer and mode != 0:
                return best, best_j, n_all, min(e - s, j0 - s + BLOCK), hits, True
    return best, best_j, n_all, e - s, hits, False


@njit(inline="always")
def _leaf(corners, prims, s, e, o, kx, ky, kz, sx, sy, sz, lo, best, best_j, edges, mode, store, offsets, r, base,
          n_all, all_t, all_i):
    """Test the leaf's references s..e-1 against ray r, the binary walk's leaf loop: returns the closest
    hit so far (best, best_j), the hits counted or stored (all hits), the tests made, those that
    found their triangle in range, and whether the ray is done (any hit found)."""
    hits = 0
    for j in range(s, e):
        t = _hit(corners, j, o, kx, ky, kz, sx, sy, sz, lo, best, edges)
        if t == INF:
            continue
        hits += 1
        best, best_j, n_all, closer = _take(prims, j, t, best, best_j, mode, store, offsets, r, base, n_all, all_t,
                                            all_i)
        if closer and mode != 0:
            return best, best_j, n_all, j - s + 1, hits, True
    return best, best_j, n_all, e - s, hits, False


@njit(inline="always")
def _take(prims, j, t, best, best_j, mode, store, offsets, r, base, n_all, all_t, all_i):
    """Reference (or lane) j's hit at t, for both leaf loops: all hits counts it (and stores it where
    offsets say); else it becomes the closest hit if it is closer, ties at equal t going to the
    smaller triangle index as in the generic kernel. Returns best, best_j, n_all and whether j
    became the closest."""
    if mode == ALL_HITS:
        if store and n_all < offsets[r + 1] - base:
            all_t[base + n_all] = t
            all_i[base + n_all, 0] = TRIANGLE
            all_i[base + n_all, 1] = prims[j]
            all_i[base + n_all, 2] = -1
        return best, best_j, n_all + 1, False
    if best_j < 0 or t < best or prims[j] < prims[best_j]:
        return t, j, n_all, True
    return best, best_j, n_all, False


@njit(inline="always")
def _mesh_of(geoms, prim):
    """The mesh that global triangle prim belongs to (geoms: each mesh's first triangle, then the count)."""
    lo, hi = 0, geoms.shape[0] - 2
    while lo < hi:
        mid = (lo + hi + 1) >> 1
        if geoms[mid] <= prim:
            lo = mid
        else:
            hi = mid - 1
    return lo


@njit(inline="always")
def _finish(prims, geoms, mode, r, best, best_j, n_all, store, t_out, kind_out, geom_out, idx_out, inst_out):
    """Ray r's outputs but its surface: its hit count (all hits), its miss, or its closest hit's identity."""
    if mode == ALL_HITS:
        if not store:
            idx_out[r] = n_all
        return
    if best_j < 0:
        t_out[r] = INF
        if kind_out.shape[0]:       # (outputs not asked for have no rows)
            kind_out[r] = -1
        if geom_out.shape[0]:
            geom_out[r] = -1
        if idx_out.shape[0]:
            idx_out[r] = -1
        if inst_out.shape[0]:
            inst_out[r] = -1
        return
    prim = np.int64(prims[best_j])
    t_out[r] = best
    if kind_out.shape[0]:
        kind_out[r] = TRIANGLE
    if geom_out.shape[0] or idx_out.shape[0]:
        g = _mesh_of(geoms, prim)
        if geom_out.shape[0]:
            geom_out[r] = g
        if idx_out.shape[0]:
            idx_out[r] = prim - geoms[g]
    if inst_out.shape[0]:
        inst_out[r] = -1


@njit(private=True)     # one call per chunk, after its walk: compiled once, apart from the walks
def _surfaces(geo, src, prims, origins, directions, hit_j, hit_t, r0, r1, surface_out):
    """The surfaces of rays r0..r1-1 as the walk left them (hit_j, hit_t: _chunk's): NaN for a miss;
    a hit on triangle prims[j] at t, its corners row j of src (corners, or lane j of blocks:
    triangles4.corner), the numbers the walk read, where the mesh's own arrays would be read again."""
    uv_out, gn_out, sn_out = surface_out
    for r in range(r0, r1):
        j = hit_j[r - r0]
        if j == -2:
            continue            # not cast
        if j < 0:
            store_no_surface(r, uv_out, gn_out, sn_out)
            continue
        t = hit_t[r - r0]
        px, py, pz = (origins[r, 0] + t * directions[r, 0], origins[r, 1] + t * directions[r, 1],
                      origins[r, 2] + t * directions[r, 2])
        prim = np.int64(prims[j])
        if geo.tri_smooth.shape[0] and geo.tri_smooth[prim]:     # (a mesh without normals: none)
            store_triangle_surface(geo, r, prim, px, py, pz, IDENTITY, uv_out, gn_out, sn_out)
        else:
            store_corner_surface(src, j, r, px, py, pz, uv_out, gn_out, sn_out)


@njit(inline="always")
def _count(counters, c, rays, n_bounds, n_nodes, n_entries, n_leaves, n_tests, n_hits):
    counters[c, C.RAYS_CAST] = rays
    counters[c, C.BOUNDS_TESTS] = n_bounds
    counters[c, C.CELLS_VISITED] = n_nodes
    counters[c, C.WALK_ENTRIES + BVH] = n_entries      # all of it the BVH walk's, as the general kernel counts it
    counters[c, C.WALK_BOUNDS + BVH] = n_bounds
    counters[c, C.WALK_STEPS + BVH] = n_nodes
    counters[c, C.CELLS_LEAVES] = n_leaves
    counters[c, C.TESTS + TRIANGLE] = n_tests
    counters[c, C.HITS + TRIANGLE] = n_hits

"""The BVH kind's walk of a whole scene that is one BVH over primitives (every SPD scene at its default).

    geo = prepare(Geometry(..., **NO_WALK), agg_stats)   # flatten: collapse the root BVH 4-wide, lay out its primitives
    if walks(geo):                       # traverse.intersect then hands each query here
        found = intersect(geo, ox, oy, oz, dx, dy, dz, tmin, tmax, mode, ws, cnt)

The BVH kind declares it (bvh.KIND.scene_walk) and the registry names it to the engine
(registry.SCENE_WALK), so the engine names no kind: flatten calls prepare, the driver hands
over what walks() accepts, and a kernel whose geometry's type says `alone` compiles no driver.

Why a walk of its own: the general driver carries frames, instances, mailboxes and CSG, and
every call that takes the scene's Geometry (dozens of arrays, each passed by numba as several
numbers) costs more than a coherent ray's whole walk. This
walk takes only the arrays it reads: the root BVH collapsed 4-wide (aggregates/widebvh.py),
whose node tests its four child boxes in one vector slab test, children entered nearest first
(widebvh.next_leaf, the 4-wide walk the mesh kernel takes too); and the leaves' primitives laid
out in leaf order (wide_prims), one 80-byte record per reference, so a leaf's primitives are
read from one block. The leaves are the binary tree's and the tests and the hit rule the
driver's (hitrule.hit and take, reading the records), so every query gets the same hit as the
general walk, tie for tie.

wide_prims, one row of hitrule.RECORD_COLUMNS float64 per reference of geo.refs (R, 10):
    sphere     centre (3), signed radius
    triangle   corners v0, v1, v2 (9): also the mesh kernel's corners (casting/meshcast.py)
    polygon    unit normal (3), first corner in poly_verts, corner count, dropped axis, its bins'
    and patch  table in poly_band_f (-1: none; geometry/polybands.py)
    cone       base (3), unit axis (3), length, base radius, apex radius
    column 9   1.0 when the material transmits (ANY_OPAQUE passes it over), else 0.0

Counting, as RayScene's mesh kernel counts its 4-wide walk: one `cells.visited` per wide node,
one `bounds.tests` per child box tested (the used slots of each visited node) and one for the
root's box; `cells.leaves` per leaf; all of it the BVH walk's (`walk.bvh.*`).
"""

import numpy as np

from ..geometry import counters as C
from ..geometry.boxes import INF, box_entry, inverse
from ..geometry.config import njit
from ..geometry.hitrule import ANY_HIT, ANY_OPAQUE, CLEAR, RECORD_COLUMNS, hit, take
from ..geometry.primitives import CONE, INDEX_MASK, KIND_SHIFT, PATCH, POLYGON, SPHERE, TRIANGLE
from ..geometry.work import ENTER, STEP, TEST, note
from .bvhwalk import CODE as BVH
from .walk import F_MAP
from .widebvh import NO_CHILD, NO_WIDE, collapse, leaf_range, next_leaf, wide_ray

# the Geometry fields of this walk (engine/flatten.py appends them), as every other scene has them:
# nothing to walk. wide_nodes: the BVH collapsed 4-wide (widebvh.py); wide_center: read-only when the
# scene is that BVH, so that kernels compile no general driver (wide_only); wide_prims: the leaves'
# primitives in leaf order, one record each (see above)
NO_WALK = dict(wide_nodes=NO_WIDE.nodes, wide_center=NO_WIDE.center,
               wide_prims=np.zeros((0, RECORD_COLUMNS)))


def prepare(geo, agg_stats: list):
    """geo with its wide_* fields filled when it is one BVH of width 4 over primitives (no other
    aggregate, no instance); agg_stats[0], that BVH's build statistics, gains the wide tree's size."""
    if not (len(geo.agg_kind) == 1 and geo.agg_kind[0] == BVH and not len(geo.inst_agg)
            and agg_stats[0].get("width", 4) == 4):
        return geo
    wide, _ = collapse(geo.node_bounds, geo.node_first, geo.node_count, int(geo.agg_start[geo.root]))
    prims = _records(geo)
    agg_stats[0].update(wide_nodes=len(wide.nodes), wide_bytes=wide.nbytes + prims.nbytes)
    center = wide.center.copy()
    center.flags.writeable = False      # the type that says "wide only" (see wide_only)
    return geo._replace(wide_nodes=wide.nodes, wide_center=center, wide_prims=prims)


def wide_only(geo) -> bool:
    """True when kernels given geo compile this walk alone, without the general driver (a large
    part of a first render's compile: BENCHMARKS.md, "Start-up"). numba compiles a kernel once per argument type, and a read-only
    array is a type of its own: a scene that is one 4-wide BVH has a read-only wide_center. (A
    field of its own for the mark slowed the general driver's octree walks measurably: it made
    the Geometry one array longer.)"""
    return not geo.wide_center.flags.writeable


def with_driver(geo):
    """geo, typed so that the kernels it is given to compile the general driver too: queries in
    mode CLOSEST_EAGER (eager normals, tricks.py) go to it even on a 4-wide BVH."""
    return geo._replace(wide_center=geo.wide_center.copy()) if wide_only(geo) else geo


def _records(geo) -> np.ndarray:
    """wide_prims (see the module docstring) for geo.refs."""
    kind = geo.refs >> KIND_SHIFT
    idx = geo.refs & INDEX_MASK
    rec = np.zeros((len(kind), RECORD_COLUMNS))
    clear = geo.mat_clear
    k = kind == SPHERE
    rec[k, :3] = geo.sph_center[idx[k]]
    rec[k, 3] = geo.sph_radius[idx[k]]
    rec[k, CLEAR] = clear[geo.sph_mat[idx[k]]]
    k = (kind == POLYGON) | (kind == PATCH)
    rec[k, :3] = geo.poly_normal[idx[k]]
    rec[k, 3] = geo.poly_start[idx[k]]
    rec[k, 4] = geo.poly_count[idx[k]]
    rec[k, 5] = geo.poly_axis[idx[k]]
    rec[k, 6] = geo.poly_band[idx[k]]
    rec[k, CLEAR] = clear[geo.poly_mat[idx[k]]]
    k = kind == TRIANGLE
    rec[k, :9] = geo.tri_verts[geo.tri_faces[idx[k]]].reshape(-1, 9)
    rec[k, CLEAR] = clear[geo.tri_mat[idx[k]]]
    k = kind == CONE
    rec[k, :3] = geo.cone_base[idx[k]]
    rec[k, 3:6] = geo.cone_axis[idx[k]]
    rec[k, 6] = geo.cone_length[idx[k]]
    rec[k, 7] = geo.cone_r0[idx[k]]
    rec[k, 8] = geo.cone_r1[idx[k]]
    rec[k, CLEAR] = clear[geo.cone_mat[idx[k]]]
    return rec


@njit(inline="always")
def _flush(cnt, n_bounds, n_nodes, n_leaves):
    cnt[C.BOUNDS_TESTS] += n_bounds
    cnt[C.WALK_BOUNDS + BVH] += n_bounds
    cnt[C.CELLS_VISITED] += n_nodes
    cnt[C.WALK_STEPS + BVH] += n_nodes
    cnt[C.CELLS_LEAVES] += n_leaves


def alone(geo_type) -> bool:
    """At compile time, from the numba type of a Geometry: its kernels need this walk alone (wide_only)."""
    return not geo_type.types[geo_type.fields.index("wide_center")].mutable


@njit(inline="always")
def walks(geo):
    """geo is a scene this walk takes (prepare filled its fields)."""
    return geo.wide_nodes.shape[0] > 0


@njit(inline="always")
def intersect(geo, ox, oy, oz, dx, dy, dz, tmin, tmax, mode, ws, cnt):
    """traverse.intersect of a scene walks() takes, with the workspace ws (traverse.workspace)."""
    return intersect_wide(geo.wide_nodes, geo.wide_center, geo.agg_bounds, geo.root, geo.refs, geo.wide_prims,
                          geo.poly_verts, geo.poly_band_f, geo.poly_band_i, geo.tri_edges, ox, oy, oz, dx, dy, dz,
                          tmin, tmax, mode, ws.stack_a, ws.stack_t, ws.frame_f, ws.hit_f, ws.hit_i, ws.t4, cnt,
                          ws.work)


@njit(inline="always")
def count_misses(cnt, n):
    """The counts of n rays that miss the scene's box, intersect_wide's first test (render.py
    counts a tile's eye rays so when none can enter the box: rendering/frustum.py)."""
    _flush(cnt, n, np.int64(0), np.int64(0))


@njit(inline="always")
def intersect_wide(nodes, center, agg_bounds, root, refs, prims, verts, band_f, band_i, tri_edges, ox, oy, oz,
                   dx, dy, dz, tmin, tmax, mode, stack, stack_t, frame_f, hit_f, hit_i, t4, cnt, work):
    """traverse.intersect (modes CLOSEST, ANY_HIT, ALL_HITS, ANY_OPAQUE) on the arrays prepare()
    made, with the workspace's stack, frames, hit record and t4. The scene's box is tested
    here, in the caller's body: a ray that misses the whole scene (most eye rays of a small
    one) pays no call of the walk and the arrays it passes."""
    ix, iy, iz = inverse(dx), inverse(dy), inverse(dz)
    te = box_entry(agg_bounds, root, ox, oy, oz, ix, iy, iz, tmin, tmax)
    note(work, ENTER, 0, root, -1, 0 if te == INF else 1, 0, 0, 0, 0, 0)      # nothing unless a sample is probed
    if te == INF:
        count_misses(cnt, np.int64(1))
        return False
    # the center as three numbers: the array is read-only or not by what the scene is (wide_only), and
    # the walk, compiled apart, would be compiled once for each
    return _walk_wide(nodes, (center[0], center[1], center[2]), refs, prims, verts, band_f, band_i, tri_edges, ox,
                      oy, oz, dx, dy, dz, ix, iy, iz, te, tmin, tmax, mode, stack, stack_t, frame_f, hit_f, hit_i, t4,
                      cnt, root, work)


@njit(private=True)
def _walk_wide(nodes, center, refs, prims, verts, band_f, band_i, tri_edges, ox, oy, oz, dx, dy, dz, ix, iy, iz,
               te, tmin, tmax, mode, stack, stack_t, frame_f, hit_f, hit_i, t4, cnt, root, work):
    """intersect_wide below the scene's box, which the ray enters at te; center: the tree's center
    (x, y, z). Stack entries as widebvh.visit pushes them: v >= 0 a wide node to visit, v < 0 a
    leaf. work: the render's per-sample work (geometry/work.py), for a probed sample's log; None
    otherwise."""
    for k in range(12):     # the hit's frame is the world: an identity map for take
        frame_f[0, F_MAP + k] = 1.0 if k == 0 or k == 5 or k == 10 else 0.0
    found = np.bool_(False)      # typed, not literal: numba compiles a private callee once per literal
    best_t = tmax
    best_ref = np.int64(-1)
    best_inst = np.int64(-1)
    edges = tri_edges[0]
    n_bounds, n_nodes, n_leaves = np.int64(1), np.int64(0), np.int64(0)
    logged_nodes, logged_bounds = np.int64(0), np.int64(1)     # a probed sample's log: counted so far (the box: ENTER)
    cnt[C.WALK_ENTRIES + BVH] += 1
    wx, wy, wz, vx, vy, vz, near = wide_ray(center, ox, oy, oz, ix, iy, iz)
    stack[0] = 0
    stack_t[0] = te
    sp = 1
    while sp > 0:
        v, sp, n_nodes, n_bounds = next_leaf(nodes, wx, wy, wz, vx, vy, vz, near, tmin, best_t, t4, stack, stack_t,
                                             sp, n_nodes, n_bounds)
        if v == NO_CHILD:
            note(work, STEP, 0, root, BVH, n_nodes - logged_nodes, n_bounds - logged_bounds, 0, 0, 0, 0)
            logged_nodes, logged_bounds = n_nodes, n_bounds
            continue
        # a leaf: its references, all primitives
        n_leaves += 1
        first, end = leaf_range(nodes, v)
        note(work, STEP, 0, root, BVH, n_nodes - logged_nodes, n_bounds - logged_bounds, first, end, 0, 0)
        logged_nodes, logged_bounds = n_nodes, n_bounds
        for i in range(first, end):
            if mode == ANY_OPAQUE and prims[i, CLEAR] != 0.0:
                continue        # transparent: left to the walk that filters light through it
            ref = refs[i]
            kind = ref >> KIND_SHIFT
            cnt[C.TESTS + kind] += 1
            t = hit(kind, prims, i, verts, band_f, band_i, edges, ox, oy, oz, dx, dy, dz, tmin, best_t, cnt)
            note(work, TEST, 0, root, kind, ref & INDEX_MASK, t, -1, 0, 0, 0)
            if t == INF:
                continue
            cnt[C.HITS + kind] += 1
            found, best_t, best_ref, best_inst = take(mode, t, kind, ref & INDEX_MASK, np.int64(-1), np.int64(0),
                                                      frame_f, np.int64(0), np.int64(F_MAP), hit_f, hit_i, found,
                                                      best_t, best_ref, best_inst)
            if found and (mode == ANY_HIT or mode == ANY_OPAQUE):
                _flush(cnt, n_bounds, n_nodes, n_leaves)
                return True
    _flush(cnt, n_bounds, n_nodes, n_leaves)
    return found

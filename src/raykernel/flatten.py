"""From the scene model to flat arrays the kernels read, building every aggregate.

    geo, build = flatten(scene, default_accel="bvh")
    geo.root          # index of the top aggregate
    build["build.nodes"], build["aggregates"]   # what the builds made

Each Group becomes one aggregate over its primitives and children, built
with the group's `accel` spec (or the default). A child Group with no spec
of its own is merged into its parent; a child Group with a spec is a nested
aggregate; an Instance refers to its group's aggregate through a matrix. A
group instanced many times is built once.

References are tagged integers (see primitives.make_ref): a leaf of any
aggregate can hold a primitive, an aggregate or an instance.

With lazy octrees in the scene, build["lazy"] holds them
(aggregates/lazyoctree.py): whoever traces rays refines them between passes.
With lazy ray classification (aggregates/rc.py) too, it holds a LazySet
(aggregates/lazyset.py) of both.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np

from . import accel
from .errors import SceneError
from .primitives import AGGREGATE, CONE, INSTANCE, PATCH, POLYGON, SPHERE, TRIANGLE, make_ref
from .primitives import INDEX_MASK, KIND_SHIFT
from .scene import Group, Instance, Scene

MAX_NESTING = 16          # aggregates along any path from the root (the kernel's frame stack)
MAX_TREE_DEPTH = 96       # nodes along any path within one hierarchy (the kernel's node stack)
STACK_SIZE = MAX_NESTING * (MAX_TREE_DEPTH + 2)

LIST, BVH, GRID = 0, 1, 2
HGRID_BUDGET = 8          # an hgrid's sub-grids stop once all its levels hold this many references per top-level one
AGG_KIND_CODES = {"list": LIST, "bvh": BVH, "grid": GRID}
OCTREE = 3
AGG_KIND_CODES["octree"] = OCTREE
RC = 6
AGG_KIND_CODES["rc"] = RC
AGG_KIND_CODES["lazyoctree"] = OCTREE   # walked as an octree, refined between passes (aggregates/lazyoctree.py)


class Geometry(NamedTuple):
    """Flat arrays of a built scene, read by the kernels."""
    sph_center: np.ndarray      # (S, 3)
    sph_radius: np.ndarray      # (S,) signed: negative = inside only
    sph_mat: np.ndarray         # (S,) int32 material index
    cone_base: np.ndarray       # (C, 3)
    cone_axis: np.ndarray       # (C, 3) unit vector base -> apex
    cone_length: np.ndarray     # (C,)
    cone_r0: np.ndarray         # (C,) signed radius at the base
    cone_r1: np.ndarray         # (C,) signed radius at the apex
    cone_mat: np.ndarray        # (C,)
    poly_normal: np.ndarray     # (P, 3) unit plane normal from the first corner
    poly_d: np.ndarray          # (P,) plane offset: normal . x = d
    poly_start: np.ndarray      # (P,) first vertex in poly_verts
    poly_count: np.ndarray      # (P,) vertex count
    poly_axis: np.ndarray       # (P,) axis dropped for the 2D inside test
    poly_mat: np.ndarray        # (P,)
    poly_verts: np.ndarray      # (V, 3) vertices of polygons and patches
    poly_vnormals: np.ndarray   # (V, 3) unit vertex normals (patches; zero for polygons)
    tri_verts: np.ndarray       # (TV, 3) mesh vertices
    tri_vnormals: np.ndarray    # (TV, 3) mesh vertex normals (zero where absent)
    tri_faces: np.ndarray       # (T, 3) int64 vertex indices
    tri_smooth: np.ndarray      # (T,) bool: interpolate tri_vnormals
    tri_mat: np.ndarray         # (T,)
    agg_kind: np.ndarray        # (A,) LIST, BVH or GRID
    agg_bounds: np.ndarray      # (A, 6) xmin ymin zmin xmax ymax zmax
    agg_start: np.ndarray       # (A,) list: first ref; bvh: root node; grid: grid index
    agg_count: np.ndarray       # (A,) list: number of refs; bvh: number of nodes; grid: number of cells
    node_bounds: np.ndarray     # (N, 6) BVH node boxes
    node_first: np.ndarray      # (N,) inner: left child (right = left + 1); leaf: first ref
    node_count: np.ndarray      # (N,) 0 for inner nodes, else refs in the leaf
    refs: np.ndarray            # (R,) tagged references of every list and leaf
    inst_agg: np.ndarray        # (I,) aggregate an instance shows
    inst_to_local: np.ndarray   # (I, 12) world-to-local affine map, row-major 3x4
    grid_origin: np.ndarray     # (G, 3) lower corner of each grid
    grid_cell_size: np.ndarray  # (G, 3) cell side per axis
    grid_inv_cell: np.ndarray   # (G, 3) 1 / cell side
    grid_res: np.ndarray        # (G, 3) int64 cells per axis
    grid_cell_offset: np.ndarray  # (G,) first entry of the grid's cells in grid_cells
    grid_mailbox: np.ndarray    # (G,) int64 1: skip refs already tested in an earlier cell
    grid_cells: np.ndarray      # (sum of ncells + 1,) cell c of grid g holds refs
    #                             grid_cells[o + c] .. grid_cells[o + c + 1], o = grid_cell_offset[g]
    rc_face_root: np.ndarray    # (RC, 6) root hypercube of each direction-cube face (see aggregates/rc.py)
    rc_node_a: np.ndarray       # (RN,) inner: first child (global node); leaf: first candidate in rc_ref
    rc_node_b: np.ndarray       # (RN,) inner: -(split dimension + 1) of x, y, z, u, v; leaf: candidates
    rc_split: np.ndarray        # (RN,) inner: split coordinate
    rc_key: np.ndarray          # (RK,) near-face key of each candidate, rising within a leaf
    rc_ref: np.ndarray          # (RK,) tagged reference of each candidate
    rc_pass: np.ndarray         # (RN,) lazy rc leaf that may split: its row of rc_vinfo, else -1
    rc_vinfo: np.ndarray        # (RP, 3) first pass counter column, levels K, first entry in rc_vdim/rc_vsplit
    rc_vdim: np.ndarray         # (RS,) split dimension of each inner node of the candidates' virtual subtrees
    rc_vsplit: np.ndarray       # (RS,) split coordinate of each inner node of those subtrees
    oct_bounds: np.ndarray      # (ON, 6) octree node boxes (see aggregates/octree.py)
    oct_first: np.ndarray       # (ON,) inner: first of 8 children (global node); leaf: first ref
    oct_count: np.ndarray       # (ON,) refs in a leaf; -1 for an inner node
    oct_loc: np.ndarray         # (ON, 3) int64 lower 28-bit address of the node's box
    oct_level: np.ndarray       # (ON,) level of the node's box
    oct_slot: np.ndarray        # (ON,) level of the octant the node occupies in its parent
    oct_nbr: np.ndarray         # (ON, 6) neighbour across -x, +x, -y, +y, -z, +z (global node), -1: none
    oct_root: np.ndarray        # (O,) root node of each octree
    oct_origin: np.ndarray      # (O, 3) lower corner of the root box
    oct_unit: np.ndarray        # (O, 3) side of one address unit
    oct_scale: np.ndarray       # (O, 3) 1 / oct_unit
    oct_walk: np.ndarray        # (O,) 0 point, 1 neighbor, 2 parametric
    oct_mailbox: np.ndarray     # (O,) 1: skip refs already tested in an earlier leaf
    oct_pass: np.ndarray        # (ON,) lazy octree leaf that may split: its pass counter column, else -1
    root: int                   # the top aggregate


def _box_of_points(points: np.ndarray) -> np.ndarray:
    return np.concatenate([points.min(axis=0), points.max(axis=0)])


def transform_box(box: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Bounds of the 8 corners of `box` mapped by the 4x4 matrix `m`."""
    if not np.all(np.isfinite(box)):
        return box.copy()
    lo, hi = box[:3], box[3:]
    corners = np.array([[lo[0] if i & 1 == 0 else hi[0], lo[1] if i & 2 == 0 else hi[1],
                         lo[2] if i & 4 == 0 else hi[2]] for i in range(8)])
    mapped = corners @ m[:3, :3].T + m[:3, 3]
    return _box_of_points(mapped)


class _Arrays:
    """Growing global arrays while the groups are walked."""

    def __init__(self):
        self.sph = []      # (center, radius, mat)
        self.cone = []
        self.poly = []     # (Polygons set, is_patch)
        self.mesh = []
        self.n_sph = self.n_cone = self.n_poly = self.n_poly_verts = self.n_tri = self.n_tri_verts = 0
        self.geometries = []   # (kind, first global index, count) of each primitive set, in build order
        self.agg_kind, self.agg_bounds, self.agg_start, self.agg_count = [], [], [], []
        self.node_bounds, self.node_first, self.node_count = [], [], []
        self.n_nodes = 0
        self.refs = []
        self.n_refs = 0
        self.inst_agg, self.inst_to_local = [], []
        self.grid_origin, self.grid_cell_size, self.grid_res, self.grid_cell_offset = [], [], [], []
        self.grid_mailbox, self.grid_cells = [], []
        self.n_grid_cells = 0
        self.oct = {k: [] for k in ("bounds", "first", "count", "loc", "level", "slot", "nbr", "root", "origin",
                                    "unit", "walk", "mailbox")}
        self.n_oct_nodes = 0
        self.lazy = []     # one record per lazy octree, for aggregates/lazyoctree.py
        self.rc = {k: [] for k in ("face_root", "node_a", "node_b", "split", "key", "ref")}
        self.lazy_rc = []  # one record per lazy rc aggregate, for aggregates/rc.py
        self.n_rc_nodes = self.n_rc_keys = 0


def _sphere_refs(arr: _Arrays, s):
    if np.any(s.radius == 0.0) or not np.all(np.isfinite(s.radius)) or not np.all(np.isfinite(s.center)):
        bad = int(np.flatnonzero((s.radius == 0.0) | ~np.isfinite(s.radius))[0]) if np.any(
            (s.radius == 0.0) | ~np.isfinite(s.radius)) else 0
        raise SceneError(f"sphere {bad}: radius must be finite and non-zero, centre finite")
    idx = np.arange(arr.n_sph, arr.n_sph + len(s))
    arr.geometries.append((SPHERE, arr.n_sph, len(s)))
    arr.sph.append(s)
    arr.n_sph += len(s)
    r = np.abs(s.radius)[:, None]
    return make_ref(SPHERE, idx), np.hstack([s.center - r, s.center + r])


def _cone_refs(arr: _Arrays, c):
    axis = c.apex - c.base
    length = np.linalg.norm(axis, axis=1)
    bad = (length == 0.0) | ((c.base_radius == 0.0) & (c.apex_radius == 0.0)) | \
        (np.sign(c.base_radius) * np.sign(c.apex_radius) < 0)
    if np.any(bad):
        raise SceneError(f"cone {int(np.flatnonzero(bad)[0])}: base and apex must differ, radii must not both be "
                         "zero and must have the same sign")
    idx = np.arange(arr.n_cone, arr.n_cone + len(c))
    arr.geometries.append((CONE, arr.n_cone, len(c)))
    arr.cone.append(c)
    arr.n_cone += len(c)
    unit = axis / length[:, None]
    # a disc of radius r with unit normal a extends r*sqrt(1 - a_i^2) along axis i
    spread = np.sqrt(np.clip(1.0 - unit ** 2, 0.0, 1.0))
    e0 = np.abs(c.base_radius)[:, None] * spread
    e1 = np.abs(c.apex_radius)[:, None] * spread
    lo = np.minimum(c.base - e0, c.apex - e1)
    hi = np.maximum(c.base + e0, c.apex + e1)
    return make_ref(CONE, idx), np.hstack([lo, hi])


def _polygon_refs(arr: _Arrays, p):
    kind = PATCH if p.patches else POLYGON
    idx = np.arange(arr.n_poly, arr.n_poly + len(p))
    arr.geometries.append((kind, arr.n_poly, len(p)))
    arr.poly.append(p)
    arr.n_poly += len(p)
    arr.n_poly_verts += len(p.vertices)
    lo = np.minimum.reduceat(p.vertices, p.start, axis=0)
    hi = np.maximum.reduceat(p.vertices, p.start, axis=0)
    return make_ref(kind, idx), np.hstack([lo, hi])


def _mesh_refs(arr: _Arrays, m):
    idx = np.arange(arr.n_tri, arr.n_tri + len(m.faces))
    arr.geometries.append((TRIANGLE, arr.n_tri, len(m.faces)))
    arr.mesh.append((m, arr.n_tri_verts))
    arr.n_tri += len(m.faces)
    arr.n_tri_verts += len(m.vertices)
    tri = m.vertices[m.faces]
    return make_ref(TRIANGLE, idx), np.hstack([tri.min(axis=1), tri.max(axis=1)])


class _Builder:
    def __init__(self, default_accel: str):
        self.arr = _Arrays()
        self.default = accel.parse_spec(default_accel)
        self.built: dict[int, tuple[int, int]] = {}   # id(group) -> (aggregate, depth)
        self._active_groups: list[Group] = []           # the path being walked, to catch cycles
        self.agg_stats: list[dict] = []

    def build_group(self, group: Group) -> tuple[int, int]:
        key = id(group)
        if key in self.built:
            return self.built[key]
        if key in (id(g) for g in self._active_groups):
            names = " -> ".join(g.name or "?" for g in self._active_groups) + f" -> {group.name or '?'}"
            raise SceneError(f"group cycle: {names}")
        self._active_groups.append(group)
        refs, bounds = [], []
        depth = self._collect(group, refs, bounds)
        self._active_groups.pop()
        if depth + 1 > MAX_NESTING:
            raise SceneError(f"group {group.name or '(unnamed)'}: aggregates nest {depth + 1} deep; "
                             f"the limit is {MAX_NESTING}")
        spec = accel.parse_spec(group.accel) if group.accel else self.default
        refs = np.concatenate(refs) if refs else np.zeros(0, np.int64)
        bounds = np.vstack(bounds) if bounds else np.zeros((0, 6))
        self._nesting, self._extra_nesting = depth + 1, 0
        agg = self._build_aggregate(spec, refs, bounds, group.name)
        depth += self._extra_nesting    # aggregates an aggregate nests in itself (hgrid sub-grids)
        self.built[key] = (agg, depth + 1)
        return agg, depth + 1

    def _collect(self, group: Group, refs: list, bounds: list) -> int:
        """Gather refs and bounds of `group` (merging spec-less child groups);
        returns the deepest nesting among its children."""
        depth = 0
        for s in group.primitive_sets():
            if s.kind == "sphere":
                r, b = _sphere_refs(self.arr, s)
            elif s.kind == "cone":
                r, b = _cone_refs(self.arr, s)
            elif s.kind in ("polygon", "patch"):
                r, b = _polygon_refs(self.arr, s)
            else:
                r, b = _mesh_refs(self.arr, s)
            refs.append(r)
            bounds.append(b)
        for child in group.children:
            if isinstance(child, Instance):
                agg, d = self.build_group(child.group)
                depth = max(depth, d)
                if not np.all(np.isfinite(self.arr.agg_bounds[agg])):
                    continue        # an empty group shows nothing: no reference to it
                k = len(self.arr.inst_agg)
                self.arr.inst_agg.append(agg)
                self.arr.inst_to_local.append(np.linalg.inv(child.matrix)[:3, :].reshape(-1))
                refs.append(make_ref(INSTANCE, [k]))
                bounds.append(transform_box(self.arr.agg_bounds[agg], child.matrix)[None, :])
                depth = max(depth, d)
            elif isinstance(child, Group) and child.accel is None:
                if id(child) in (id(g) for g in self._active_groups):
                    raise SceneError(f"group cycle through {child.name or '(unnamed)'}")
                self._active_groups.append(child)
                depth = max(depth, self._collect(child, refs, bounds))
                self._active_groups.pop()
            elif isinstance(child, Group):
                agg, d = self.build_group(child)
                depth = max(depth, d)
                if not np.all(np.isfinite(self.arr.agg_bounds[agg])):
                    continue
                refs.append(make_ref(AGGREGATE, [agg]))
                bounds.append(self.arr.agg_bounds[agg][None, :])
                depth = max(depth, d)
            else:
                raise SceneError(f"group {group.name or '(unnamed)'} holds a {type(child).__name__}")
        return depth

    def _vertex_weights(self, refs):
        """Glassner's vertex count per reference: polygon and patch vertices, 3 per triangle, else 1."""
        kinds = refs >> KIND_SHIFT
        idx = refs & INDEX_MASK
        counts = np.concatenate([p.count for p in self.arr.poly]) if self.arr.poly else np.zeros(0, np.int64)
        w = np.ones(len(refs), np.int64)
        poly = (kinds == POLYGON) | (kinds == PATCH)
        w[poly] = counts[idx[poly]]
        w[kinds == TRIANGLE] = 3
        return w

    def _build_hgrid(self, params, refs, bounds, name, level=0, levels=None) -> int:
        """A grid whose cells holding more than `threshold` references hold one reference to a
        sub-grid over those items instead, down to `depth` levels (aggregates/hgrid.py)."""
        from .aggregates.grid import build_grid
        from .aggregates.hgrid import clipped_bounds, dense_cells, replace_cells
        arr = self.arr
        start = time.perf_counter()
        grid, stats = build_grid(bounds, res_rule=params["res"], density=params["density"],
                                 max_res=params["max_res"], name=name or "(unnamed)")
        if levels is None:
            # every level is one more aggregate on a ray's path: stay within MAX_NESTING
            levels = max(0, min(params["depth"], MAX_NESTING - getattr(self, "_nesting", 1)))
            self._hgrid_budget = HGRID_BUDGET * len(grid.items) + 4096
        cells = dense_cells(grid, params["threshold"]) if level < levels else np.zeros(0, np.int64)
        if level > 0:
            # a cell that kept every item of its grid made no progress: refining it again could go on forever
            cells = cells[np.diff(grid.cell_start)[cells] < len(refs)]
        cell_start, cell_refs = grid.cell_start, refs[grid.items]
        self._hgrid_budget -= len(cell_refs)
        subs = []
        for c in cells:
            if self._hgrid_budget <= 0:
                break           # out of references: the remaining crowded cells keep their items
            items = grid.items[grid.cell_start[c]:grid.cell_start[c + 1]]
            subs.append(self._build_hgrid(params, refs[items], clipped_bounds(grid, bounds, c, items), name,
                                          level + 1, levels))
        cells = cells[:len(subs)]
        if len(subs):
            cell_start, cell_refs = replace_cells(cell_start, cell_refs, cells, make_ref(AGGREGATE, subs))
            self._extra_nesting = max(getattr(self, "_extra_nesting", 0), level + 1)
        agg = len(arr.agg_kind)
        ncells = len(cell_start) - 1
        arr.agg_kind.append(GRID)
        arr.agg_start.append(len(arr.grid_res))
        arr.agg_count.append(ncells)
        arr.grid_origin.append(grid.origin)
        arr.grid_cell_size.append(grid.cell_size)
        arr.grid_res.append(grid.res)
        arr.grid_cell_offset.append(arr.n_grid_cells)
        arr.grid_mailbox.append(int(params["mailbox"]))
        arr.grid_cells.append(cell_start + arr.n_refs)
        arr.n_grid_cells += ncells + 1
        arr.refs.append(cell_refs)
        arr.n_refs += len(cell_refs)
        arr.agg_bounds.append(np.concatenate([bounds[:, :3].min(axis=0), bounds[:, 3:].max(axis=0)]))
        stats = dict(stats, refs=len(cell_refs), empty_leaves=int(np.count_nonzero(np.diff(cell_start) == 0)),
                     bytes=int(cell_start.nbytes + cell_refs.nbytes + 72), level=level, levels=levels,
                     subgrids=len(cells))
        stats.update(kind=accel.format_spec("hgrid", params), name=name, items=len(refs),
                     seconds=time.perf_counter() - start)
        self.agg_stats.append(stats)
        return agg

    def _append_octree(self, tree, params, refs):
        """Store an octree (aggregates/octree.py) as the next aggregate; its leaves hold refs[tree.order]."""
        from .aggregates.octree import WALKS
        arr = self.arr
        o = arr.oct
        arr.agg_kind.append(OCTREE)
        arr.agg_start.append(len(o["root"]))
        arr.agg_count.append(len(tree.count))
        inner = tree.count < 0
        o["bounds"].append(tree.bounds)
        o["first"].append(np.where(inner, tree.first + arr.n_oct_nodes, tree.first + arr.n_refs))
        o["count"].append(tree.count)
        o["loc"].append(tree.loc)
        o["level"].append(tree.level)
        o["slot"].append(tree.slot)
        o["nbr"].append(np.where(tree.nbr >= 0, tree.nbr + arr.n_oct_nodes, -1))
        o["root"].append(arr.n_oct_nodes)
        o["origin"].append(tree.origin)
        o["unit"].append(tree.unit)
        o["walk"].append(WALKS.index(params["walk"]))
        o["mailbox"].append(int(params["mailbox"]))
        arr.n_oct_nodes += len(tree.count)
        arr.refs.append(refs[tree.order])
        arr.n_refs += len(tree.order)

    def _build_hybrid(self, params, refs, bounds, name) -> int:
        """An octree whose problem voxels (leaves holding more than `threshold` items) hold one
        reference to a Goldsmith-Salmon BVH over their items cut to the voxel (aggregates/hybrid.py)."""
        from .aggregates.hybrid import clipped_bounds, hybrid_stats, problem_voxels, replace_leaves
        from .aggregates.octree import build_octree
        start = time.perf_counter()
        weights = self._vertex_weights(refs) if params["vertexcount"] else None
        tree, octree_stats = build_octree(bounds, depth=params["depth"], leaf=params["leaf"],
                                          rule60=params["rule60"], density=params["density"],
                                          vertexcount=params["vertexcount"], weights=weights,
                                          collapse=params["collapse"], budget=params["budget"], name=name)
        voxels = problem_voxels(tree, params["threshold"])
        n_problem = len(voxels)
        if getattr(self, "_nesting", 1) >= MAX_NESTING:
            voxels = voxels[:0]     # a BVH would be one aggregate too many on a ray's path
        bvh_spec = accel.parse_spec(f"bvh(build=gs, order={params['order']}, seed={params['seed']})")
        subs, bvh_stats = [], []
        for node in voxels:
            items = tree.order[tree.first[node]:tree.first[node] + tree.count[node]]
            subs.append(self._build_aggregate(bvh_spec, refs[items],
                                              clipped_bounds(tree, bounds, node, items, params["depth"]), name))
            bvh_stats.append(self.agg_stats.pop())
        leaf_refs = refs
        if len(subs):
            tree = replace_leaves(tree, voxels, len(refs))
            leaf_refs = np.concatenate([refs, make_ref(AGGREGATE, subs)])
            self._extra_nesting = max(getattr(self, "_extra_nesting", 0), 1)
        agg = len(self.arr.agg_kind)
        self._append_octree(tree, params, leaf_refs)
        self.arr.agg_bounds.append(np.concatenate([bounds[:, :3].min(axis=0), bounds[:, 3:].max(axis=0)]))
        stats = hybrid_stats(octree_stats, tree, bvh_stats, n_problem)
        stats.update(kind=accel.format_spec("hybrid", params), name=name, items=len(refs),
                     seconds=time.perf_counter() - start)
        self.agg_stats.append(stats)
        return agg

    def _build_aggregate(self, spec, refs, bounds, name) -> int:
        kind, params = spec
        if kind == "hgrid" and len(refs):
            return self._build_hgrid(params, refs, bounds, name)
        if kind == "hybrid" and len(refs):
            return self._build_hybrid(params, refs, bounds, name)
        arr = self.arr
        start = time.perf_counter()
        # empty children (an empty group's box is +inf..-inf) add nothing to the box
        solid = np.all(bounds[:, :3] <= bounds[:, 3:], axis=1) if len(bounds) else np.zeros(0, bool)
        box = np.concatenate([bounds[solid, :3].min(axis=0), bounds[solid, 3:].max(axis=0)]) if solid.any() \
            else np.array([np.inf] * 3 + [-np.inf] * 3)
        agg = len(arr.agg_kind)
        if kind == "list" or len(refs) == 0:
            # an empty aggregate of any kind is an empty list: nothing to traverse
            arr.agg_kind.append(LIST)
            arr.agg_start.append(arr.n_refs)
            arr.agg_count.append(len(refs))
            arr.refs.append(refs)
            arr.n_refs += len(refs)
            stats = {"nodes": 0, "inner": 0, "leaves": 1, "empty_leaves": int(len(refs) == 0),
                     "refs": len(refs), "bytes": refs.nbytes}
        elif kind == "bvh":
            from .aggregates.bvh import build_bvh
            if params.get("build", "sah") == "gs":
                from .aggregates.gsbvh import build_gs
                tree, stats = build_gs(bounds, order=params["order"], seed=params["seed"])
            else:
                tree, stats = build_bvh(bounds, leaf_size=params["leaf"], bins=params["bins"])
            if stats.get("max_depth", 0) > MAX_TREE_DEPTH:
                raise SceneError(f"group {name or '(unnamed)'}: BVH depth {stats['max_depth']} exceeds "
                                 f"{MAX_TREE_DEPTH}")
            arr.agg_kind.append(BVH)
            arr.agg_start.append(arr.n_nodes)
            arr.agg_count.append(len(tree.count))
            inner = tree.count == 0
            first = np.where(inner, tree.first + arr.n_nodes, tree.first + arr.n_refs)
            arr.node_bounds.append(tree.bounds)
            arr.node_first.append(first)
            arr.node_count.append(tree.count)
            arr.n_nodes += len(tree.count)
            arr.refs.append(refs[tree.order])
            arr.n_refs += len(refs)
            stats = dict(stats)
        elif kind == "grid":
            from .aggregates.grid import build_grid
            grid, stats = build_grid(bounds, res_rule=params["res"], density=params["density"],
                                     max_res=params["max_res"], name=name or "(unnamed)")
            ncells = len(grid.cell_start) - 1
            arr.agg_kind.append(GRID)
            arr.agg_start.append(len(arr.grid_res))
            arr.agg_count.append(ncells)
            arr.grid_origin.append(grid.origin)
            arr.grid_cell_size.append(grid.cell_size)
            arr.grid_res.append(grid.res)
            arr.grid_cell_offset.append(arr.n_grid_cells)
            arr.grid_mailbox.append(int(params["mailbox"]))
            arr.grid_cells.append(grid.cell_start + arr.n_refs)
            arr.n_grid_cells += ncells + 1
            arr.refs.append(refs[grid.items])
            arr.n_refs += len(grid.items)
            stats = dict(stats)
        elif kind == "rc":
            from .aggregates.rc import build_rc, start_rc
            rc = arr.rc
            if params["lazy"]:
                # six root leaves now, split between passes where rays arrive (LazyRC)
                tree, stats, boxes, keys = start_rc(bounds, leaf=params["leaf"], depth=params["depth"],
                                                    budget_mb=params["budget_mb"], rays=params["rays"], name=name)
                arr.lazy_rc.append(dict(params, node=arr.n_rc_nodes, cand=arr.n_rc_keys, items=tree.items,
                                        boxes=boxes, box=tree.box, stats=stats, name=name))
            else:
                tree, stats = build_rc(bounds, leaf=params["leaf"], depth=params["depth"],
                                       budget_mb=params["budget_mb"], name=name)
            arr.agg_kind.append(RC)
            arr.agg_start.append(len(rc["face_root"]))
            arr.agg_count.append(len(tree.node_b))
            rc["face_root"].append(tree.face_root + arr.n_rc_nodes)
            rc["node_a"].append(np.where(tree.node_b < 0, tree.node_a + arr.n_rc_nodes, tree.node_a + arr.n_rc_keys))
            rc["node_b"].append(tree.node_b)
            rc["split"].append(tree.split)
            rc["key"].append(tree.keys)
            rc["ref"].append(refs[tree.items])
            arr.n_rc_nodes += len(tree.node_b)
            arr.n_rc_keys += len(tree.keys)
        elif kind == "octree":
            from .aggregates.octree import build_octree
            weights = self._vertex_weights(refs) if params["vertexcount"] else None
            tree, stats = build_octree(bounds, depth=params["depth"], leaf=params["leaf"], rule60=params["rule60"],
                                       density=params["density"], vertexcount=params["vertexcount"],
                                       weights=weights, collapse=params["collapse"], budget=params["budget"],
                                       name=name)
            self._append_octree(tree, params, refs)
            stats = dict(stats)
        elif kind == "lazyoctree":
            # Lathrop's lazy octree: one leaf now, subdivided between passes of rays
            from .aggregates.lazyoctree import build_lazy
            tree, stats, boxes = build_lazy(bounds, depth=params["depth"], rays=params["rays"], k=params["k"],
                                            rule60=params["rule60"], budget=params["budget"], name=name)
            arr.lazy.append(dict(params, octree=len(arr.oct["root"]), node=arr.n_oct_nodes, ref=arr.n_refs,
                                 refs=refs, boxes=boxes, stats=stats))
            self._append_octree(tree, params, refs)
        else:
            raise SceneError(f"accelerator {kind!r} is not available in this build")
        arr.agg_bounds.append(box)
        stats.update(kind=accel.format_spec(kind, params), name=name, items=len(refs),
                     seconds=time.perf_counter() - start)
        self.agg_stats.append(stats)
        return agg


CULL_MARGIN = 1e-9        # culling boxes grow by this much of their aggregate's size or distance from the origin


def _culling_boxes(agg_kind, agg_bounds, agg_start, agg_count, node_bounds):
    """Aggregate and BVH node boxes widened by CULL_MARGIN of the aggregate's size or distance
    from the origin (the margin the grid and the octree give their cells). A ray through a
    vertex on a box's wall, rounded by an instance's map, can pass just outside the box while
    the primitive test still reports the hit: without the margin a BVH or a nested aggregate
    would miss a hit that a list finds."""
    agg = agg_bounds.copy()
    nodes = node_bounds.copy()
    finite = np.all(np.isfinite(agg), axis=1)
    box = np.where(finite[:, None], agg, 0.0)
    margin = CULL_MARGIN * np.maximum((box[:, 3:] - box[:, :3]).max(axis=1, initial=0.0),
                                      np.abs(box).max(axis=1, initial=0.0))
    agg[finite, :3] -= margin[finite, None]
    agg[finite, 3:] += margin[finite, None]
    for a in np.flatnonzero((agg_kind == BVH) & finite):
        s, n = agg_start[a], agg_count[a]
        nodes[s:s + n, :3] -= margin[a]
        nodes[s:s + n, 3:] += margin[a]
    return agg, nodes


def _concat(parts, shape, dtype):
    return np.ascontiguousarray(np.concatenate(parts) if parts else np.zeros(shape, dtype), dtype=dtype)


def _polygon_planes(verts, start, count):
    """Unit normal from the first corner (NFF's rule), plane offset, and the
    axis to drop for the 2D inside test. Where the first corner is degenerate
    the polygon's area vector (Newell) gives the normal; a polygon with no
    area at all gets a zero normal, which no ray can hit."""
    v0 = verts[start]
    e1 = verts[start + 1] - v0
    e2 = verts[start + 2] - v0
    n = np.cross(e1, e2)
    length = np.linalg.norm(n, axis=1)
    size = np.maximum(np.linalg.norm(e1, axis=1), np.linalg.norm(e2, axis=1))
    bad = np.flatnonzero(~(length > 1e-12 * size * size))
    for i in bad:
        poly = verts[start[i]:start[i] + count[i]]
        area = 0.5 * np.cross(poly, np.roll(poly, -1, axis=0)).sum(axis=0)
        n[i] = area if np.linalg.norm(area) > 1e-12 * np.ptp(poly, axis=0).max() ** 2 else 0.0
        length[i] = np.linalg.norm(n[i])
    n = n / np.where(length > 0.0, length, 1.0)[:, None]
    return n, np.einsum("ij,ij->i", n, v0), np.argmax(np.abs(n), axis=1).astype(np.int64)


def flatten(scene: Scene, default_accel: str = "bvh") -> tuple[Geometry, dict]:
    """Build every aggregate of `scene` and return the flat arrays and the build statistics."""
    t0 = time.perf_counter()
    b = _Builder(default_accel)
    root, depth = b.build_group(scene.root)
    arr = b.arr
    agg_kind, agg_start = np.array(arr.agg_kind, np.int64), np.array(arr.agg_start, np.int64)
    agg_count = np.array(arr.agg_count, np.int64)
    agg_bounds, node_bounds = _culling_boxes(agg_kind, np.array(arr.agg_bounds, np.float64).reshape(-1, 6), agg_start,
                                             agg_count, _concat(arr.node_bounds, (0, 6), np.float64))

    sph = arr.sph
    cone = arr.cone
    cone_base = _concat([c.base for c in cone], (0, 3), np.float64)
    cone_apex = _concat([c.apex for c in cone], (0, 3), np.float64)
    axis = cone_apex - cone_base
    length = np.linalg.norm(axis, axis=1)
    axis = axis / np.where(length > 0, length, 1.0)[:, None]

    verts_parts, vn_parts, start_parts, count_parts, mat_parts = [], [], [], [], []
    offset = 0
    for p in arr.poly:
        verts_parts.append(p.vertices)
        if p.patches:
            nrm = p.normals / np.maximum(np.linalg.norm(p.normals, axis=1), 1e-300)[:, None]
        else:
            nrm = np.zeros_like(p.vertices)
        vn_parts.append(nrm)
        start_parts.append(p.start + offset)
        count_parts.append(p.count)
        mat_parts.append(p.material)
        offset += len(p.vertices)
    poly_verts = _concat(verts_parts, (0, 3), np.float64)
    poly_start = _concat(start_parts, (0,), np.int64)
    poly_count = _concat(count_parts, (0,), np.int64)
    if len(poly_start):
        normal, dist, paxis = _polygon_planes(poly_verts, poly_start, poly_count)
    else:
        normal, dist, paxis = np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64)

    tri_faces = _concat([m.faces + off for m, off in arr.mesh], (0, 3), np.int64)
    tri_verts = _concat([m.vertices for m, _ in arr.mesh], (0, 3), np.float64)
    tri_vn = _concat([m.normals if m.normals is not None else np.zeros_like(m.vertices) for m, _ in arr.mesh],
                     (0, 3), np.float64)
    tri_smooth = _concat([np.full(len(m.faces), m.normals is not None) for m, _ in arr.mesh], (0,), np.bool_)

    geo = Geometry(
        sph_center=_concat([s.center for s in sph], (0, 3), np.float64),
        sph_radius=_concat([s.radius for s in sph], (0,), np.float64),
        sph_mat=_concat([s.material for s in sph], (0,), np.int32),
        cone_base=cone_base, cone_axis=np.ascontiguousarray(axis), cone_length=length,
        cone_r0=_concat([c.base_radius for c in cone], (0,), np.float64),
        cone_r1=_concat([c.apex_radius for c in cone], (0,), np.float64),
        cone_mat=_concat([c.material for c in cone], (0,), np.int32),
        poly_normal=np.ascontiguousarray(normal), poly_d=dist, poly_start=poly_start, poly_count=poly_count,
        poly_axis=paxis, poly_mat=_concat(mat_parts, (0,), np.int32), poly_verts=poly_verts,
        poly_vnormals=_concat(vn_parts, (0, 3), np.float64),
        tri_verts=tri_verts, tri_vnormals=tri_vn, tri_faces=tri_faces, tri_smooth=tri_smooth,
        tri_mat=_concat([m.material for m, _ in arr.mesh], (0,), np.int32),
        agg_kind=agg_kind, agg_bounds=agg_bounds, agg_start=agg_start, agg_count=agg_count,
        node_bounds=node_bounds,
        node_first=_concat(arr.node_first, (0,), np.int64),
        node_count=_concat(arr.node_count, (0,), np.int64),
        refs=_concat(arr.refs, (0,), np.int64),
        inst_agg=np.array(arr.inst_agg, np.int64),
        inst_to_local=np.array(arr.inst_to_local, np.float64).reshape(-1, 12),
        grid_origin=np.array(arr.grid_origin, np.float64).reshape(-1, 3),
        grid_cell_size=np.array(arr.grid_cell_size, np.float64).reshape(-1, 3),
        grid_inv_cell=1.0 / np.array(arr.grid_cell_size, np.float64).reshape(-1, 3),
        grid_res=np.array(arr.grid_res, np.int64).reshape(-1, 3),
        grid_cell_offset=np.array(arr.grid_cell_offset, np.int64),
        grid_mailbox=np.array(arr.grid_mailbox, np.int64),
        grid_cells=_concat(arr.grid_cells, (0,), np.int64),
        rc_face_root=np.array(arr.rc["face_root"], np.int64).reshape(-1, 6),
        rc_node_a=_concat(arr.rc["node_a"], (0,), np.int64),
        rc_node_b=_concat(arr.rc["node_b"], (0,), np.int64),
        rc_split=_concat(arr.rc["split"], (0,), np.float64),
        rc_key=_concat(arr.rc["key"], (0,), np.float64),
        rc_ref=_concat(arr.rc["ref"], (0,), np.int64),
        rc_pass=np.full(arr.n_rc_nodes, -1, np.int64),
        rc_vinfo=np.zeros((0, 3), np.int64),
        rc_vdim=np.zeros(0, np.int64),
        rc_vsplit=np.zeros(0, np.float64),
        oct_bounds=_concat(arr.oct["bounds"], (0, 6), np.float64),
        oct_first=_concat(arr.oct["first"], (0,), np.int64),
        oct_count=_concat(arr.oct["count"], (0,), np.int64),
        oct_loc=_concat(arr.oct["loc"], (0, 3), np.int64),
        oct_level=_concat(arr.oct["level"], (0,), np.int64),
        oct_slot=_concat(arr.oct["slot"], (0,), np.int64),
        oct_nbr=_concat(arr.oct["nbr"], (0, 6), np.int64),
        oct_root=np.array(arr.oct["root"], np.int64),
        oct_origin=np.array(arr.oct["origin"], np.float64).reshape(-1, 3),
        oct_unit=np.array(arr.oct["unit"], np.float64).reshape(-1, 3),
        oct_scale=1.0 / np.array(arr.oct["unit"], np.float64).reshape(-1, 3),
        oct_walk=np.array(arr.oct["walk"], np.int64),
        oct_mailbox=np.array(arr.oct["mailbox"], np.int64),
        oct_pass=np.full(arr.n_oct_nodes, -1, np.int64),
        root=int(root),
    )
    lazy = None
    if arr.lazy:
        # lazy octrees take over the octree and reference arrays to grow them between passes
        from .aggregates.lazyoctree import LazyOctrees
        geo, lazy = LazyOctrees.attach(geo, arr.lazy)
    if arr.lazy_rc:
        # lazy ray classification refines between the same passes; its columns follow the octrees'
        from .aggregates.lazyset import LazySet
        from .aggregates.rc import LazyRC
        geo, lazy_rc = LazyRC.attach(geo, arr.lazy_rc, base=0 if lazy is None else lazy.columns)
        lazy = LazySet(lazy, lazy_rc)
    n_materials = max(1, len(scene.materials))
    for name in ("sph_mat", "cone_mat", "poly_mat", "tri_mat"):
        mats = getattr(geo, name)
        if len(mats) and (mats.min() < 0 or mats.max() >= n_materials):
            raise SceneError(f"a primitive refers to material {int(mats.max())}, but the scene has "
                             f"{len(scene.materials)} materials")
    nbytes = sum(a.nbytes for a in geo if isinstance(a, np.ndarray))
    stats = {
        "build.nodes": int(sum(s.get("nodes", 0) for s in b.agg_stats)),
        "build.empty_leaves": int(sum(s.get("empty_leaves", 0) for s in b.agg_stats)),
        "build.refs": int(sum(s.get("refs", 0) for s in b.agg_stats)),
        "build.bytes": int(nbytes),
        "build.seconds": time.perf_counter() - t0,
        "build.aggregates": len(b.agg_stats) + sum(s.get("nested_aggregates", 0) for s in b.agg_stats),
        "build.nesting": int(depth),
        "aggregates": b.agg_stats,
        "geometries": np.array(arr.geometries, np.int64).reshape(-1, 3),
    }
    if lazy is not None:
        stats["lazy"] = lazy
        lazy.update_stats(stats, geo)
    return geo, stats

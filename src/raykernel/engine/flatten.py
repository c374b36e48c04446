"""From the scene model to flat arrays the kernels read, building every aggregate.

    geo, build = flatten(scene, default_accel="bvh")
    geo.root          # index of the top aggregate
    build["build.nodes"], build["aggregates"]   # what the builds made

Each Group becomes one aggregate over its primitives and children, built
with the group's `accel` spec (or the default) by that kind's `flatten`
(the registry, aggregates/registry.py). A child Group with no spec of its
own is merged into its parent; a child Group with a spec is a nested
aggregate; an Instance refers to its group's aggregate through a matrix. A
group instanced many times is built once.

References are tagged integers (see primitives.make_ref): a leaf of any
aggregate can hold a primitive, an aggregate or an instance.

Geometry is one named tuple of arrays: the primitives' and the aggregates'
fields below, then the fields each walk kind declares in its module
(Walk.fields: grid_*, node_*, oct_*, rc_*, after the driver's keyed lists), in code order, then, for a
scene that is one BVH over primitives, that BVH collapsed 4-wide (wide_*),
which the driver hands to the walk of a whole scene its kind declares (registry.SCENE_WALK).

With lazy structures in the scene (lazy octrees, lazy ray classification),
build["lazy"] holds them as a LazySet (aggregates/lazyset.py): whoever traces
rays refines them between passes.
"""

from __future__ import annotations

import time
from collections import defaultdict
from typing import NamedTuple

import numpy as np
from numba.core import types
from numba.core.typing.typeof import typeof
from numba.extending import typeof_impl

from ..aggregates.lazyset import LazySet
from ..aggregates.memory import memory_limit
from ..aggregates.registry import DEFAULT, EMPTY, FIELDS, KINDS, LAZY_KINDS, SCENE_WALK, format_spec, parse_spec
from ..aggregates.spec import AUTO
from ..aggregates.walk import MAX_NESTING, MAX_TREE_DEPTH, STACK_SIZE, Field
from ..errors import OptionError, SceneError
from ..geometry import polybands
from ..geometry.boxes import cull_margin
from ..geometry.primitives import (
    AGGREGATE,
    CONE,
    INDEX_MASK,
    INSTANCE,
    KIND_SHIFT,
    MAX_COORDINATE,
    MIN_SIZE,
    PATCH,
    POLYGON,
    PRIMITIVE_KINDS,
    SPHERE,
    TRIANGLE,
    make_ref,
)
from ..scene.model import Group, Instance, Scene
from .transforms import transform_class

__all__ = ["Geometry", "flatten", "transform_box", "MAX_NESTING", "MAX_TREE_DEPTH", "STACK_SIZE"]

PRIMITIVE_FIELDS = (
    "sph_center",      # (S, 3)
    "sph_radius",      # (S,) signed: negative = inside only
    "sph_mat",         # (S,) int32 material index
    "cone_base",       # (C, 3)
    "cone_axis",       # (C, 3) unit vector base -> apex
    "cone_length",     # (C,)
    "cone_r0",         # (C,) signed radius at the base
    "cone_r1",         # (C,) signed radius at the apex
    "cone_mat",        # (C,)
    "poly_normal",     # (P, 3) unit plane normal from the first corner
    "poly_d",          # (P,) plane offset: normal . x = d
    "poly_start",      # (P,) first vertex in poly_verts
    "poly_count",      # (P,) vertex count
    "poly_axis",       # (P,) axis dropped for the 2D inside test
    "poly_band",       # (P,) its bins' table in poly_band_f, -1 for none (geometry/polybands.py)
    "poly_mat",        # (P,)
    "poly_verts",      # (V, 3) vertices of polygons and patches
    "poly_vnormals",   # (V, 3) unit vertex normals (patches; zero for polygons)
    "poly_band_f",     # bins of the polygons with many corners: bounds (polybands.py)
    "poly_band_i",     # and their edge lists
    "tri_verts",       # (TV, 3) mesh vertices
    "tri_vnormals",    # (TV, 3) mesh vertex normals (zero where absent)
    "tri_faces",       # (T, 3) int64 vertex indices
    "tri_smooth",      # (T,) bool: interpolate tri_vnormals
    "tri_mat",         # (T,)
    "tri_edges",       # (1,) int64: the triangle test's edge rule, primitives.WATERTIGHT or INCLUSIVE
    "mat_clear",       # (M,) bool: the material transmits (T > 0), skipped by opaque-only shadow queries
)
AGGREGATE_FIELDS = (
    Field("agg_kind", np.int64),          # (A,) its walk's code (aggregates/walk.py)
    Field("agg_bounds", np.float64, (6,)),  # (A, 6) xmin ymin zmin xmax ymax zmax, widened by boxes.cull_margin
    Field("agg_start", np.int64),         # (A,) list: first ref; other kinds: see their module
    Field("agg_count", np.int64),         # (A,) list: refs; other kinds: nodes or cells
    Field("refs", np.int64),              # (R,) tagged references of every list, leaf and cell
    Field("inst_agg", np.int64),          # (I,) aggregate an instance shows
    Field("inst_to_local", np.float64, (12,)),  # (I, 12) world-to-local affine map, row-major 3x4
    Field("inst_class", np.int64),        # (I,) the map's class (transform_class): what mapping a ray needs
) + FIELDS     # the keyed lists and the walks' own fields (aggregates/registry.py)

WIDE_FIELDS = tuple(SCENE_WALK.NO_WALK)      # the arrays of the walk of a whole scene (its module says what they hold)
Geometry = NamedTuple("Geometry", [(name, np.ndarray) for name in PRIMITIVE_FIELDS] +
                      [(f.name, np.ndarray) for f in AGGREGATE_FIELDS] +
                      [(name, np.ndarray) for name in WIDE_FIELDS] + [("root", int)])
Geometry.__module__ = __name__
Geometry.__doc__ = "Flat arrays of a built scene, read by the kernels (see the module docstring)."


def _unpickled(fields: list, read_only: list) -> Geometry:
    """A Geometry as pickled: its read-only arrays made read-only again, since that is part of its
    numba type (what its kernels compile: aggregates/widewalk.py), and pickle drops it."""
    for k in read_only:
        fields[k].flags.writeable = False
    return Geometry(*fields)


Geometry.__reduce__ = lambda geo: (_unpickled, (list(geo), [k for k, a in enumerate(geo[:-1])
                                                             if not a.flags.writeable]))

_GEOMETRY_TYPES: dict = {}


@typeof_impl.register(Geometry)
def _typeof_geometry(geo, context):
    """numba's type of a Geometry, computed once per layout: numba types a named tuple
    field by field at every call of a kernel (for these dozens of arrays, a large share of a
    short call, with the interpreter lock held), and renders and queries call their kernels once per range of
    work, lazy structures once per pass."""
    key = tuple((a.dtype, a.ndim, a.flags.c_contiguous, a.flags.f_contiguous, a.flags.writeable, a.flags.aligned)
                for a in geo[:-1]) + (type(geo.root),)
    ty = _GEOMETRY_TYPES.get(key)
    if ty is None:
        ty = _GEOMETRY_TYPES[key] = types.NamedTuple([typeof(x, context.purpose) for x in geo], Geometry)
    return ty


def _box_of_points(points: np.ndarray) -> np.ndarray:
    return np.concatenate([points.min(axis=0), points.max(axis=0)])


def transform_box(box: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Bounds of the 8 corners of `box` mapped by the 4x4 matrix `m`."""
    if not np.all(np.isfinite(box)):
        return box.copy()
    lo, hi = box[:3], box[3:]
    corners = np.array([[lo[0] if i & 1 == 0 else hi[0], lo[1] if i & 2 == 0 else hi[1],
                         lo[2] if i & 4 == 0 else hi[2]] for i in range(8)])
    with np.errstate(over="ignore", invalid="ignore"):      # out of range: refused by check_range
        mapped = corners @ m[:3, :3].T + m[:3, 3]
        return _box_of_points(mapped)


class FlatArrays:
    """The growing flat arrays while the groups are walked: primitive sets, and per
    Geometry field of the aggregates the list of parts to concatenate at the end.

        first = flat.add_refs(refs)          # index of refs[0] in Geometry.refs
        g = flat.size("grid_res")            # rows of a field so far: global indices
        flat.append(grid_res=..., grid_cells=...)
        agg = flat.add_aggregate(CODE, g, count, box)
    """

    def __init__(self):
        self.sph = []      # primitive sets, in build order
        self.cone = []
        self.poly = []
        self.mesh = []
        self.n_sph = self.n_cone = self.n_poly = self.n_poly_verts = self.n_tri = self.n_tri_verts = 0
        self.geometries = []   # (kind, first global index, count) of each primitive set, in build order
        self.parts = {f.name: [] for f in AGGREGATE_FIELDS}
        self.rows = {f.name: 0 for f in AGGREGATE_FIELDS}
        self.lazy = defaultdict(list)   # kind name -> one record per lazy aggregate of the kind (lazyset.py)
        self.seeded = {}   # field -> rows it started with (seed)

    def size(self, name: str) -> int:
        """Rows of field `name` so far."""
        return self.rows[name]

    def append(self, **parts) -> None:
        """Append a part (rows) to each named field."""
        for name, part in parts.items():
            part = np.asarray(part)
            self.parts[name].append(part)
            self.rows[name] += len(part)

    def add_refs(self, refs) -> int:
        """Append references; returns the index of the first in Geometry.refs."""
        first = self.rows["refs"]
        self.append(refs=np.asarray(refs, np.int64))
        return first

    def add_aggregate(self, code: int, start: int, count: int, box) -> int:
        """The next aggregate: its walk kind, agg_start, agg_count and box; returns its index."""
        agg = self.rows["agg_kind"]
        self.append(agg_kind=[code], agg_start=[start], agg_count=[count],
                    agg_bounds=np.asarray(box, np.float64).reshape(1, 6))
        return agg

    def agg_box(self, agg: int) -> np.ndarray:
        """The box of aggregate agg (a row of the seed, or one appended part per aggregate)."""
        seeded = self.seeded.get("agg_bounds")
        if seeded is None:
            return self.parts["agg_bounds"][agg][0]
        return self.parts["agg_bounds"][0][agg] if agg < seeded else self.parts["agg_bounds"][1 + agg - seeded][0]

    def seed(self, fields: dict) -> None:
        """Start the named fields from whole arrays (the previous frame's, incremental.py)."""
        for name, arr in fields.items():
            self.parts[name] = [arr]
            self.rows[name] = len(arr)
            self.seeded[name] = len(arr)

    def field(self, f: Field) -> np.ndarray:
        parts = self.parts[f.name]
        if not parts:
            return np.zeros((0,) + f.shape, f.dtype)
        return np.ascontiguousarray(np.concatenate(parts).reshape((-1,) + f.shape), dtype=f.dtype)


def check_range(kind: str, bounds: np.ndarray, first: int = 0, sizes: np.ndarray | None = None) -> None:
    """SceneError naming the first item whose box (n, 6) leaves +-MAX_COORDINATE, or whose size
    is below MIN_SIZE without being zero: beyond the range raykernel answers exactly."""
    with np.errstate(invalid="ignore"):
        out = ~np.all(np.abs(bounds) <= MAX_COORDINATE, axis=1)
        if sizes is not None:
            out |= (sizes != 0.0) & (np.abs(sizes) < MIN_SIZE)
    if out.any():
        i = int(np.flatnonzero(out)[0])
        lo, hi = bounds[i, :3].tolist(), bounds[i, 3:].tolist()
        raise SceneError(f"{kind} {first + i} spans {lo} to {hi}: coordinates must lie within +-{MAX_COORDINATE:g} and "
                         f"sizes be at least {MIN_SIZE:g}, the range raykernel answers exactly; scale the scene")


def _sphere_refs(arr: FlatArrays, s):
    if np.any(s.radius == 0.0) or not np.all(np.isfinite(s.radius)) or not np.all(np.isfinite(s.center)):
        bad = int(np.flatnonzero((s.radius == 0.0) | ~np.isfinite(s.radius))[0]) if np.any(
            (s.radius == 0.0) | ~np.isfinite(s.radius)) else 0
        raise SceneError(f"sphere {bad}: radius must be finite and non-zero, centre finite")
    idx = np.arange(arr.n_sph, arr.n_sph + len(s))
    arr.geometries.append((SPHERE, arr.n_sph, len(s)))
    arr.sph.append(s)
    arr.n_sph += len(s)
    r = np.abs(s.radius)[:, None]
    with np.errstate(over="ignore"):
        bounds = np.hstack([s.center - r, s.center + r])
    check_range("sphere", bounds, idx[0] if len(idx) else 0, s.radius)
    return make_ref(SPHERE, idx), bounds


def _cone_refs(arr: FlatArrays, c):
    for name, points in (("base", c.base), ("apex", c.apex)):
        check_range(f"cone {name} of cone", np.hstack([points, points]), arr.n_cone)
    check_range("cone radii of cone", np.abs(np.stack([c.base_radius, c.apex_radius], axis=1)).repeat(3, axis=1),
                 arr.n_cone)
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


def _polygon_refs(arr: FlatArrays, p):
    kind = PATCH if p.patches else POLYGON
    idx = np.arange(arr.n_poly, arr.n_poly + len(p))
    arr.geometries.append((kind, arr.n_poly, len(p)))
    arr.poly.append(p)
    arr.n_poly += len(p)
    arr.n_poly_verts += len(p.vertices)
    lo = np.minimum.reduceat(p.vertices, p.start, axis=0)
    hi = np.maximum.reduceat(p.vertices, p.start, axis=0)
    with np.errstate(over="ignore", invalid="ignore"):
        check_range(PRIMITIVE_KINDS[kind], np.hstack([lo, hi]), idx[0] if len(idx) else 0, np.max(hi - lo, axis=1))
    return make_ref(kind, idx), np.hstack([lo, hi])


def _mesh_refs(arr: FlatArrays, m):
    idx = np.arange(arr.n_tri, arr.n_tri + len(m.faces))
    arr.geometries.append((TRIANGLE, arr.n_tri, len(m.faces)))
    arr.mesh.append((m, arr.n_tri_verts))
    arr.n_tri += len(m.faces)
    arr.n_tri_verts += len(m.vertices)
    tri = m.vertices[m.faces]
    bounds = np.hstack([tri.min(axis=1), tri.max(axis=1)])
    with np.errstate(over="ignore", invalid="ignore"):
        check_range("triangle", bounds, idx[0] if len(idx) else 0, np.max(bounds[:, 3:] - bounds[:, :3], axis=1))
    return make_ref(TRIANGLE, idx), bounds


def _concrete(spec):
    if spec[0] == AUTO.name:
        raise OptionError("auto is a search for a hierarchy, made by render() before anything is built "
                          "(analysis/anneal.py); flatten takes the structures it found")
    return spec


class Builder:
    """Walks the scene's groups and builds each into the flat arrays (`flat`). Each kind's
    flatten (see aggregates/__init__.py) gets the builder, to store its arrays, build
    nested aggregates (`build`) and read `nesting`, the aggregates on the path to it."""

    def __init__(self, default_accel: str, max_bytes: int):
        self.flat = FlatArrays()
        self.max_bytes = max_bytes     # the memory budget every build keeps within (memory.py)
        self.default = _concrete(parse_spec(default_accel))
        if KINDS[self.default[0]].operands:
            raise OptionError(f"{self.default[0]} is a boolean operator, not a structure for every group: "
                              "give it to a group (a JSON \"difference\", \"intersection\" or \"union\" item)")
        self.built: dict[int, tuple[int, int]] = {}   # id(group) -> (aggregate, depth)
        self._active_groups: list[Group] = []           # the path being walked, to catch cycles
        self.agg_stats: list[dict] = []
        self.nesting = 1            # aggregates on the path down to the one being built
        self.extra_nesting = 0      # aggregates it nests inside itself (hgrid sub-grids, hybrid BVHs)

    def build_group(self, group: Group) -> tuple[int, int]:
        key = id(group)
        if key in self.built:
            return self.built[key]
        if key in (id(g) for g in self._active_groups):
            names = " -> ".join(g.name or "?" for g in self._active_groups) + f" -> {group.name or '?'}"
            raise SceneError(f"group cycle: {names}")
        self._active_groups.append(group)
        spec = _concrete(parse_spec(group.accel)) if group.accel else self.default
        refs, bounds = [], []
        if KINDS[spec[0]].operands:
            depth = self._collect_operands(group, spec[0], refs, bounds)
        else:
            depth = self._collect(group, refs, bounds)
        self._active_groups.pop()
        if depth + 1 > MAX_NESTING:
            raise SceneError(f"group {group.name or '(unnamed)'}: aggregates nest {depth + 1} deep; "
                             f"the limit is {MAX_NESTING}")
        refs = np.concatenate(refs) if refs else np.zeros(0, np.int64)
        bounds = np.vstack(bounds) if bounds else np.zeros((0, 6))
        self.nesting, self.extra_nesting = depth + 1, 0
        agg = self.build(spec, refs, bounds, group.name)
        depth += self.extra_nesting
        self.built[key] = (agg, depth + 1)
        return agg, depth + 1

    def _collect(self, group: Group, refs: list, bounds: list) -> int:
        """Gather refs and bounds of `group` (merging spec-less child groups);
        returns the deepest nesting among its children."""
        depth = 0
        flat = self.flat
        for s in group.primitive_sets():
            if s.kind == "sphere":
                r, b = _sphere_refs(flat, s)
            elif s.kind == "cone":
                r, b = _cone_refs(flat, s)
            elif s.kind in ("polygon", "patch"):
                r, b = _polygon_refs(flat, s)
            else:
                r, b = _mesh_refs(flat, s)
            refs.append(r)
            bounds.append(b)
        for child in group.children:
            if isinstance(child, Instance):
                agg, d = self.build_group(child.group)
                depth = max(depth, d)
                if not np.all(np.isfinite(flat.agg_box(agg))):
                    continue        # an empty group shows nothing: no reference to it
                ref, box = self._instance(child, agg)
                refs.append(ref)
                bounds.append(box[None, :])
            elif isinstance(child, Group) and child.accel is None:
                if id(child) in (id(g) for g in self._active_groups):
                    raise SceneError(f"group cycle through {child.name or '(unnamed)'}")
                self._active_groups.append(child)
                depth = max(depth, self._collect(child, refs, bounds))
                self._active_groups.pop()
            elif isinstance(child, Group):
                agg, d = self.build_group(child)
                depth = max(depth, d)
                if not np.all(np.isfinite(flat.agg_box(agg))):
                    continue
                refs.append(make_ref(AGGREGATE, [agg]))
                bounds.append(flat.agg_box(agg)[None, :])
            else:
                raise SceneError(f"group {group.name or '(unnamed)'} holds a {type(child).__name__}")
        return depth

    def _instance(self, child: Instance, agg: int):
        """A reference to a new instance of aggregate agg, and its box in the parent's space."""
        k = self.flat.size("inst_agg")
        to_local = np.linalg.inv(child.matrix)[:3, :]   # classified for sparse mapping (transforms.py)
        self.flat.append(inst_agg=[agg], inst_to_local=to_local.reshape(1, 12), inst_class=[transform_class(to_local)])
        box = transform_box(self.flat.agg_box(agg), child.matrix)
        check_range(f"the instance of group {child.group.name or '(unnamed)'}, instance", box[None], k)
        return make_ref(INSTANCE, [k]), box

    def _collect_operands(self, group: Group, kind: str, refs: list, bounds: list) -> int:
        """One reference per child of an operator group (csg.py), in order, each child built
        as an aggregate of its own (with the default spec where it has none), empty ones
        included; returns the deepest nesting among them."""
        if any(True for _ in group.primitive_sets()):
            raise SceneError(f"{kind} {group.name or '(unnamed)'}: its operands are its child groups and instances; "
                             "put each primitive in a group of its own")
        depth = 0
        flat = self.flat
        for child in group.children:
            target = child.group if isinstance(child, Instance) else child
            if not isinstance(target, Group):
                raise SceneError(f"{kind} {group.name or '(unnamed)'} holds a {type(child).__name__}")
            agg, d = self.build_group(target)
            depth = max(depth, d)
            if isinstance(child, Instance):
                ref, box = self._instance(child, agg)
            else:
                ref, box = make_ref(AGGREGATE, [agg]), flat.agg_box(agg)
            refs.append(ref)
            bounds.append(box[None, :])
        return depth

    def vertex_weights(self, refs):
        """Glassner's vertex count per reference: polygon and patch vertices, 3 per triangle, else 1."""
        kinds = refs >> KIND_SHIFT
        idx = refs & INDEX_MASK
        w = np.ones(len(refs), np.int64)
        poly = (kinds == POLYGON) | (kinds == PATCH)
        if poly.any():      # (every aggregate asks: gather the polygons' counts only where it holds some)
            w[poly] = np.concatenate([p.count for p in self.flat.poly])[idx[poly]]
        w[kinds == TRIANGLE] = 3
        return w

    def outlines(self, refs):
        """(verts, start, count): the corners of each reference's polygon, patch or triangle
        (count 0 for any other kind), for early split clipping (aggregates/presplit.py)."""
        refs = np.asarray(refs, np.int64)
        kinds, idx = refs >> KIND_SHIFT, refs & INDEX_MASK
        count = np.zeros(len(refs), np.int64)
        parts = [np.zeros((0, 3))]
        poly = (kinds == POLYGON) | (kinds == PATCH)
        if poly.any():
            sets = self.flat.poly
            offsets = np.cumsum([0] + [len(p.vertices) for p in sets[:-1]])
            p_start = np.concatenate([p.start + o for p, o in zip(sets, offsets)])
            p_count = np.concatenate([p.count for p in sets])
            p_verts = np.vstack([p.vertices for p in sets])
            count[poly] = p_count[idx[poly]]
            take = np.repeat(p_start[idx[poly]] - np.cumsum(count[poly]) + count[poly], count[poly]) + \
                np.arange(int(count[poly].sum()))
            parts.append(p_verts[take])
        tri = kinds == TRIANGLE
        if tri.any():
            corners = np.vstack([m.vertices[m.faces] for m, _ in self.flat.mesh])
            count[tri] = 3
            parts.append(corners[idx[tri]].reshape(-1, 3))
        # the corners are stored polygons first, then triangles: each reference's start
        start = np.zeros(len(refs), np.int64)
        order = np.concatenate([np.flatnonzero(poly), np.flatnonzero(tri)])
        start[order] = np.concatenate([[0], np.cumsum(count[order])[:-1]]) if len(order) else order
        return np.vstack(parts), start, count

    def build(self, spec, refs, bounds, name) -> int:
        """Build one aggregate of spec (kind, params) over refs with item boxes `bounds`;
        returns its index and records its statistics in agg_stats."""
        kind, params = spec
        start = time.perf_counter()
        # empty children (an empty group's box is +inf..-inf) add nothing to the box
        solid = np.all(bounds[:, :3] <= bounds[:, 3:], axis=1) if len(bounds) else np.zeros(0, bool)
        box = np.concatenate([bounds[solid, :3].min(axis=0), bounds[solid, 3:].max(axis=0)]) if solid.any() \
            else np.array([np.inf] * 3 + [-np.inf] * 3)
        # an empty aggregate of any kind is stored as an empty EMPTY: nothing to traverse
        entry = EMPTY if len(refs) == 0 else KINDS[kind]
        agg, stats = entry.flatten(self, params, refs, bounds, name, box)
        stats.update(kind=format_spec(kind, params), name=name, items=len(refs),
                     seconds=time.perf_counter() - start)
        self.agg_stats.append(stats)
        return agg

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


def flatten(scene: Scene, default_accel: str = DEFAULT, max_memory=None, builder=None) -> tuple[Geometry, dict]:
    """Build every aggregate of `scene` and return the flat arrays and the build statistics.
    max_memory: the memory budget of every build and refinement, in bytes or as "8G"
    (default: memory.memory_limit()); a structure that would need more is a MemoryBudgetError.
    builder: a Builder (class) to build with, taking (default_accel, max_bytes); incremental.py's
    reuses the previous frame's aggregates."""
    t0 = time.perf_counter()
    b = (builder or Builder)(default_accel, memory_limit(max_memory))
    root, depth = b.build_group(scene.root)
    arr = b.flat
    fields = {f.name: arr.field(f) for f in AGGREGATE_FIELDS}
    # the culling boxes (BVH nodes are widened when stored, aggregates here)
    box = fields["agg_bounds"]
    for a in range(len(box)):
        m = cull_margin(box[a])
        box[a, :3] -= m
        box[a, 3:] += m
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
    band, band_f, band_i = polybands.build(poly_verts, poly_start, poly_count, paxis)

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
        poly_axis=paxis, poly_band=band, poly_mat=_concat(mat_parts, (0,), np.int32), poly_verts=poly_verts,
        poly_vnormals=_concat(vn_parts, (0, 3), np.float64), poly_band_f=band_f, poly_band_i=band_i,
        tri_verts=tri_verts, tri_vnormals=tri_vn, tri_faces=tri_faces, tri_smooth=tri_smooth,
        tri_mat=_concat([m.material for m, _ in arr.mesh], (0,), np.int32),
        tri_edges=np.zeros(1, np.int64),
        mat_clear=np.array([m.t > 0.0 for m in scene.materials] or [False], np.bool_),
        root=int(root), **fields, **SCENE_WALK.NO_WALK,
    )
    geo = SCENE_WALK.prepare(geo, b.agg_stats)
    # lazy structures take over the arrays they grow between passes (aggregates/lazyset.py)
    geo, lazy = LazySet.attach(geo, LAZY_KINDS, arr.lazy)
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

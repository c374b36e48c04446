"""Ray casting against your own geometry: numpy arrays in, numpy arrays out.

    scene = RayScene.from_mesh(vertices, faces)          # built once
    hits = scene.intersect(origins, directions)          # closest hits: hits.t, hits.prim_id, hits.normal ...
    blocked = scene.occluded(origins, directions, tmax=1.0)
    ray, t, prim = scene.intersect_all(origins, directions)
    hits = scene.intersect(origins, directions, fields=("t", "prim_id"), dtype="float32")   # only what you need
    scene.intersect(origins, directions, fields=("t", "prim_id"), dtype="float32", out=hits)   # into those arrays

Rays are rows of (N, 3) arrays (a single (3,) row is broadcast against the
other argument); directions need not be unit length, t is measured in units
of the direction given. Queries run in parallel over chunks of rays, with
watertight ray/triangle tests: a scene of triangles under one BVH (every
from_mesh) takes the fast kernel of meshcast.py, any other scene the one
traversal of traverse.py; both give the same hits and counters.

Identities of a hit:

* `geom_id`: which geometry was hit: one mesh, or one set of spheres,
  polygons, patches or cones, numbered in build order (`RayScene.geometries`
  describes each); a RayScene from one mesh or one sphere set has geom_id 0.
  -1 on a miss.
* `prim_id`: the primitive's index within its geometry (the face index of a
  mesh, the sphere index of a sphere set). -1 on a miss.
* `inst_id`: the innermost Instance the primitive was reached through
  (instances numbered in flatten order), -1 outside instances.
* `kind`: the primitive kind (SPHERE 0, POLYGON 1, PATCH 2, CONE 3,
  TRIANGLE 4), -1 on a miss.

Geometry is stored in float64 whatever the input dtype: float32 vertices are
widened exactly, and the intersection and traversal arithmetic stays in
double precision, so that hits stay exact (watertight, t to ~1e-16
relative) on scenes spanning 1e7 in scale, where float32 (7 digits) would
already round a vertex by more than the smallest feature.
"""

from __future__ import annotations

import math
import threading
import time
from contextlib import nullcontext
from dataclasses import dataclass

import numpy as np

from ..geometry.compiletime import CompileClock, compile_notice
from ..aggregates.memory import check, describe_bytes, memory_limit
from ..aggregates.registry import COUNTER_NAMES
from ..engine.flatten import flatten
from ..geometry.parallel import for_ranges
from ..engine.traverse import ALL_HITS, HIT_F, HIT_I, intersect, workspace
from ..errors import RayKernelError
from ..geometry import counters as C
from ..geometry.config import njit
from ..geometry.primitives import (CONE, INCLUSIVE, MAX_COORDINATE, MIN_SIZE, PATCH, POLYGON, SPHERE, TRIANGLE,
                                   WATERTIGHT)
from ..scene.model import Scene, TriangleMesh
from .hitsurface import store_miss, store_surface
from .meshbuild import BUILD_BYTES, QUALITY, build_mesh
from .meshcast import MESH_ACCEL, MeshKernel
from .occupancy import occupancy_grid
from .proximity import (INSIDE_DIRECTIONS, ClosestPoints, inside_spheres, kinds_of, parity_directions, point_index,
                        surface_normals)
from .rayinput import valid_ray
from .winding import dipoles, winding_numbers

CHUNK = 1024
CLOSEST, ANY = 0, 1
HIT_FIELDS = ("t", "prim_id", "geom_id", "inst_id", "kind", "uv", "normal", "shading_normal")   # intersect's fields=
FLOAT_FIELDS = ("t", "uv", "normal", "shading_normal")
FIELD_COLUMNS = {"uv": (2,), "normal": (3,), "shading_normal": (3,)}
DTYPES = {"float64": (np.float64, np.int64), "float32": (np.float32, np.int32)}    # floats, ids
HIT_BYTES = 2 * (8 + 24 + 8) + 8     # intersect_all: a hit's t, identity and ray, sorted into copies, and the order
OUTPUTS = ("t", "kind", "geom", "idx", "inst", "uv", "gn", "sn")     # the kernels' output arrays, in call order
EDGE_RULES = {"watertight": WATERTIGHT, "inclusive": INCLUSIVE}
KIND_NAMES = {SPHERE: "sphere", POLYGON: "polygon", PATCH: "patch", CONE: "cone", TRIANGLE: "triangle"}


class RayInputError(RayKernelError, ValueError):
    """Rays or geometry given to RayScene are not valid; the message names the argument.

    It is a ValueError too.
    """


@dataclass
class Hits:
    """Closest hits of a batch of rays (RayScene.intersect), shaped as the rays were.

    Each field has the rays' shape: (N,) for (N, 3) origins and directions, (H, W) for an
    image of rays; the vector fields add a last axis. The float fields are float64 and the ids
    int64, or float32 and int32 with ``intersect(..., dtype="float32")``; a field not asked for
    (intersect's `fields`) is None.

    Attributes
    ----------
    t : (N,) float array
        The ray parameter of the hit, in units of the direction given; inf on a miss.
    prim_id : (N,) int array
        The primitive's index within its geometry (the face index for a mesh); -1 on a miss.
    geom_id : (N,) int array
        The geometry (mesh or primitive set) in ``RayScene.geometries``; -1 on a miss.
    inst_id : (N,) int array
        The innermost instance; -1 outside instances or on a miss.
    kind : (N,) int array
        The primitive kind (0 sphere, 1 polygon, 2 patch, 3 cone, 4 triangle); -1 on a miss.
    uv : (N, 2) float array
        Triangles: barycentric (p = (1-u-v) v0 + u v1 + v v2); spheres: (longitude / 2 pi,
        colatitude / pi) in the sphere's frame; cones: (angle around the axis / 2 pi,
        height / length); NaN otherwise.
    normal : (N, 3) float array
        The unit geometric normal in world space (by winding, or outward); NaN on a miss.
    shading_normal : (N, 3) float array
        The unit interpolated normal (vertex normals, patches), else equal to `normal`.
    origins : (N, 3) float64 array
        The rays' origins, as given (broadcast).
    directions : (N, 3) float64 array
        The rays' directions, as given (broadcast).
    """

    t: np.ndarray               # (N,) ray parameter of the hit, inf on a miss
    prim_id: np.ndarray         # (N,) index within its geometry (face index for a mesh), -1 on a miss
    geom_id: np.ndarray         # (N,) geometry (mesh or primitive set) in RayScene.geometries, -1 on a miss
    inst_id: np.ndarray         # (N,) innermost instance, -1 outside instances or on a miss
    kind: np.ndarray            # (N,) primitive kind (0 sphere, 1 polygon, 2 patch, 3 cone, 4 triangle), -1
    uv: np.ndarray              # (N, 2) triangles: barycentric (p = (1-u-v) v0 + u v1 + v v2);
    #                             spheres: (longitude / 2pi, colatitude / pi) in the sphere's frame;
    #                             cones: (angle around the axis / 2pi, height / length); NaN otherwise
    normal: np.ndarray          # (N, 3) unit geometric normal in world space (winding / outward), NaN on a miss
    shading_normal: np.ndarray  # (N, 3) unit interpolated normal (vertex normals, patches), else = normal
    origins: np.ndarray | None = None      # (N, 3) the rays, as given (broadcast)
    directions: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.t)

    @property
    def hit(self) -> np.ndarray:
        """(N,) bool array: True where the ray hit something (t is finite)."""
        return np.isfinite(self.t)

    @property
    def points(self) -> np.ndarray:
        """(N, 3) float64 array: the hit points, origin + t direction; NaN on a miss."""
        t = np.where(self.hit, self.t, np.nan)[..., None]
        return self.origins + t * self.directions


# ----------------------------------------------------------------- kernel

@njit
def _query(geo, origins, directions, tmin, tmax, mode, chunk, t_out, kind_out, idx_out, inst_out,
           uv_out, gn_out, sn_out, with_surface, offsets, all_t, all_i, counters, c0, c1):
    """Closest (mode 0), any (mode 1) or all hits (ALL_HITS) of every ray.
    Closest/any fill t/kind/idx/inst (and uv, normals when with_surface).
    All hits: with len(offsets) == 0 only counts them into idx_out; else
    writes ray r's hits to rows offsets[r] .. offsets[r + 1] of all_t/all_i.
    Chunks c0..c1-1 of `chunk` rays, counting into counters[c]."""
    n = origins.shape[0]
    store = offsets.shape[0] > 0
    for c in range(c0, c1):
        r0 = c * chunk
        r1 = min(n, (c + 1) * chunk)
        cap = np.int64(0)       # not the literal 0: numba would compile workspace again for it
        if mode == ALL_HITS and store:
            for r in range(r0, r1):
                cap = max(cap, offsets[r + 1] - offsets[r])
        ws = workspace(cap)
        cnt = np.zeros(counters.shape[1], np.int64)     # columns past N_COUNTERS: lazy octree passes
        _cast(geo, origins, directions, tmin, tmax, mode, t_out, kind_out, idx_out, inst_out, uv_out, gn_out, sn_out,
              with_surface, offsets, all_t, all_i, r0, r1, ws, cnt)
        for k in range(counters.shape[1]):
            counters[c, k] = cnt[k]


@njit(private=True)     # one call per chunk: the rays' calls into intersect count no references
def _cast(geo, origins, directions, tmin, tmax, mode, t_out, kind_out, idx_out, inst_out, uv_out, gn_out, sn_out,
          with_surface, offsets, all_t, all_i, r0, r1, ws, cnt):
    """Rays r0..r1-1 of _query, with the chunk's workspace and counters."""
    hit_f, hit_i = ws.hit_f, ws.hit_i
    store = offsets.shape[0] > 0
    per_lo, per_hi = tmin.shape[0] > 1, tmax.shape[0] > 1     # else one bound for every ray
    for r in range(r0, r1):
        lo, hi = tmin[r if per_lo else 0], tmax[r if per_hi else 0]
        ox, oy, oz = origins[r, 0], origins[r, 1], origins[r, 2]
        dx, dy, dz = directions[r, 0], directions[r, 1], directions[r, 2]
        if not valid_ray(ox, oy, oz, dx, dy, dz):
            continue            # not cast: RayScene names it (rayinput.py)
        cnt[C.RAYS_CAST] += 1
        if mode == ALL_HITS:
            hit_i[0] = 0
            intersect(geo, ox, oy, oz, dx, dy, dz, lo, hi, mode, ws, cnt)
            k = hit_i[0]
            if store:
                base = offsets[r]
                for j in range(min(k, offsets[r + 1] - base)):
                    all_t[base + j] = hit_f[HIT_F + j]
                    all_i[base + j, 0] = hit_i[HIT_I + 3 * j]
                    all_i[base + j, 1] = hit_i[HIT_I + 3 * j + 1]
                    all_i[base + j, 2] = hit_i[HIT_I + 3 * j + 2]
            else:
                idx_out[r] = k
            continue
        if not intersect(geo, ox, oy, oz, dx, dy, dz, lo, hi, mode, ws, cnt):
            store_miss(r, t_out, idx_out, uv_out, gn_out, sn_out, with_surface)
            if kind_out.shape[0]:
                kind_out[r] = -1
            if inst_out.shape[0]:
                inst_out[r] = -1
            continue
        t = hit_f[0]
        kind = hit_i[0]
        idx = hit_i[1]
        t_out[r] = t
        if kind_out.shape[0]:           # (outputs not asked for have no rows)
            kind_out[r] = kind
        if idx_out.shape[0]:
            idx_out[r] = idx
        if inst_out.shape[0]:
            inst_out[r] = hit_i[2]
        if with_surface:
            store_surface(geo, r, kind, idx, ox + t * dx, oy + t * dy, oz + t * dz, hit_f[1:13],
                          uv_out, gn_out, sn_out, hit_i[3])


# ----------------------------------------------------------------- input checks

def _real_array(value, name: str) -> np.ndarray:
    arr = np.asarray(value)
    if arr.dtype == object or not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise RayInputError(f"{name} must be an array of real numbers, got dtype {arr.dtype}")
    return arr.astype(np.float64, copy=False)


def _vectors(value, name: str, finite: bool = True) -> np.ndarray:
    """(..., 3) real array, finite unless finite=False; one (3,) vector is one row, (1, 3)."""
    arr = _real_array(value, name)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim == 0 or arr.shape[-1] != 3:
        raise RayInputError(f"{name} must have shape (..., 3), e.g. (N, 3) or (3,), got {arr.shape}")
    if finite:
        _finite(arr, name)
    return arr


def _finite(arr: np.ndarray, name: str) -> None:
    if not np.isfinite(arr).all():        # (whole-array test first: reductions along rows are slow)
        flat = arr.reshape(-1, 3)
        i = int(np.flatnonzero(~np.all(np.isfinite(flat), axis=1))[0])
        raise RayInputError(f"{name}[{i}] is not finite: {flat[i].tolist()}")


def _interval(value, name: str, shape: tuple) -> np.ndarray:
    """tmin or tmax flat, one per ray, or one number as a (1,) array: the kernels then read it for every ray."""
    if isinstance(value, float):        # one number, the common call: no array machinery (a few us a call)
        if value != value:
            raise RayInputError(f"{name}[0] is NaN")
        return np.array([value])
    arr = _real_array(value, name)
    if arr.ndim == 0:
        arr = arr.reshape(1)
    else:
        try:
            arr = np.broadcast_to(arr, shape)
        except ValueError:
            raise RayInputError(f"{name} must be a number or have shape {shape}, got {arr.shape}") from None
        arr = np.ascontiguousarray(arr).reshape(-1)
    if np.isnan(arr).any():
        raise RayInputError(f"{name}[{int(np.flatnonzero(np.isnan(arr))[0])}] is NaN")
    return arr


def check_rays(origins, directions, tmin=0.0, tmax=np.inf, budget=None):
    """Checked float64 copies, flat: origins (N, 3), directions (N, 3), tmin and tmax ((N,), or
    (1,) for one number), and the rays' shape: the leading dimensions of origins and directions
    broadcast together ((N,) for (N, 3) arrays, (H, W) for an image of rays, (1,) for one (3,) ray).
    The values of origins and directions are checked by the kernels as they cast (rayinput.py);
    check_ray_values names the first bad ray. budget(n, copied): called before anything is
    copied, with the rays' number and the bytes their copies take (RayScene._budget)."""
    if _plain(origins, directions):
        o, d, shape = origins, directions, origins.shape[:1]      # the common call: nothing to broadcast
        if budget is not None:
            budget(len(o), 0)
    else:
        o = _vectors(origins, "origins", finite=False)
        d = _vectors(directions, "directions", finite=False)
        try:
            shape = np.broadcast_shapes(o.shape[:-1], d.shape[:-1])
        except ValueError:
            raise RayInputError(f"origins and directions differ in length: {o.shape[:-1]} vs "
                                f"{d.shape[:-1]}") from None
        if budget is not None:
            budget(math.prod(shape), 64 * math.prod(shape))    # origins, directions, tmin, tmax
        o = np.broadcast_to(o, shape + (3,)).reshape(-1, 3)
        d = np.broadcast_to(d, shape + (3,)).reshape(-1, 3)
    lo = _interval(tmin, "tmin", shape)
    hi = _interval(tmax, "tmax", shape)
    bad = lo > hi
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise RayInputError(f"tmin > tmax for ray {i}: {lo[i if len(lo) > 1 else 0]} > {hi[i if len(hi) > 1 else 0]}")
    return np.ascontiguousarray(o), np.ascontiguousarray(d), lo, hi, shape


def _plain(origins, directions) -> bool:
    """Both are C-contiguous float64 ndarrays of the same shape (N, 3): check_rays then skips numpy's
    broadcasting machinery, most of a small batch's time."""
    return (type(origins) is np.ndarray and type(directions) is np.ndarray and origins.dtype == np.float64
            and directions.dtype == np.float64 and origins.ndim == 2 and origins.shape == directions.shape
            and origins.shape[1] == 3 and origins.flags.c_contiguous and directions.flags.c_contiguous)


def check_ray_values(o: np.ndarray, d: np.ndarray) -> None:
    """Raise RayInputError naming the first ray (of check_rays' flat arrays) that is not finite, has
    a zero direction or lies outside the range raykernel answers: what valid_ray refuses in the kernels."""
    _finite(o, "origins")
    _finite(d, "directions")
    zero = (d[:, 0] == 0.0) & (d[:, 1] == 0.0) & (d[:, 2] == 0.0)
    if zero.any():
        raise RayInputError(f"directions[{int(np.flatnonzero(zero)[0])}] has zero length")
    far = np.any(np.abs(o) > MAX_COORDINATE, axis=1)
    if far.any():
        i = int(np.flatnonzero(far)[0])
        raise RayInputError(f"origins[{i}] {o[i].tolist()} lies beyond +-{MAX_COORDINATE:g}, the range raykernel "
                            f"answers exactly")
    longest = np.max(np.abs(d), axis=1)
    odd = (longest < MIN_SIZE) | (longest > MAX_COORDINATE)
    if odd.any():
        i = int(np.flatnonzero(odd)[0])
        raise RayInputError(f"directions[{i}] {d[i].tolist()}: its largest component must lie between {MIN_SIZE:g} "
                            f"and {MAX_COORDINATE:g} (scale the direction; only its way matters)")


def _field_names(fields) -> tuple:
    """intersect's fields= as names of HIT_FIELDS in their order, t among them."""
    names = (fields,) if isinstance(fields, str) else tuple(fields)
    for name in names:
        if name not in HIT_FIELDS:
            raise RayInputError(f"fields: no Hits field {name!r}; fields: {', '.join(HIT_FIELDS)}")
    return tuple(f for f in HIT_FIELDS if f == "t" or f in names)


def _out_array(out, name: str, shape: tuple, dtype) -> np.ndarray:
    """out.<name> as a flat view to fill, if it has the shape and dtype this call writes."""
    arr = getattr(out, name)
    if arr is None:
        raise RayInputError(f"out.{name} is None (out was made without it): pass the same fields")
    if not isinstance(arr, np.ndarray) or arr.shape != shape or arr.dtype != dtype or not arr.flags.c_contiguous \
            or not arr.flags.writeable:
        got = f"{arr.dtype} {arr.shape}" if isinstance(arr, np.ndarray) else type(arr).__name__
        raise RayInputError(f"out.{name} must be a writable contiguous {np.dtype(dtype)} array of shape {shape} "
                            f"for these rays, got {got}")
    return arr.reshape((-1,) + FIELD_COLUMNS.get(name, ()))     # a view: the array is contiguous


# ----------------------------------------------------------------- the scene

def coarse_to_fine(n: int) -> np.ndarray:
    """Ray indices 0..n-1 coarse to fine: 0, then the odd multiples of 2^k for k from high to
    low (with n = 8: 0, 4, 2, 6, 1, 3, 5, 7), so that every prefix samples the whole array."""
    parts = [np.zeros(min(n, 1), np.int64)]
    step = 1 << max(0, (n - 1).bit_length())
    while step > 1:
        parts.append(np.arange(step // 2, n, step, dtype=np.int64))
        step //= 2
    return np.concatenate(parts)


def _closed_mesh(mesh) -> bool:
    """Every directed edge of the mesh appears once, and so does its reverse."""
    f = mesh.faces
    edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    key = np.sort(edges[:, 0] * (len(mesh.vertices) + 1) + edges[:, 1])
    twin = edges[:, 1] * (len(mesh.vertices) + 1) + edges[:, 0]
    found = key[np.minimum(np.searchsorted(key, twin), len(key) - 1)]
    return bool(np.all(np.diff(key) > 0)) and bool(np.all(found == twin))


# the parts of the ray queries' docstrings they share (_ray_query_doc puts them in)
_RAYS_DOC = """origins, directions : (N, 3) array_like
            The rays: (N, 3), (H, W, 3) for an image of rays (camera_rays), or one (3,) ray
            broadcast against the other argument; any real dtype, read as float64. Directions
            need not be unit length: t is measured in units of the direction given.
        tmin : float or (N,) array_like, default 0
            The start of the interval of t in which a hit counts (tmin <= t <= tmax): one
            number for every ray, or one per ray.
        tmax : float or (N,) array_like, default inf
            The end of that interval, as `tmin`."""
_RAISES_DOC = """Raises
        ------
        RayInputError
            An argument is not valid: the message names it (and the first bad ray).
        MemoryBudgetError
            The outputs and copies of the rays would not fit in the memory budget."""


def _ray_query_doc(method):
    """`method` with {rays} and {raises} in its docstring replaced by the shared parts."""
    method.__doc__ = method.__doc__.replace("{rays}", _RAYS_DOC).replace("{raises}", _RAISES_DOC)
    return method


class RayScene:
    """Geometry built once into flat arrays and aggregates, queried with batches of rays.

    Build with `from_mesh`, `from_file`, `from_trimesh`, `from_spheres` or `from_scene` (or
    with the constructor, from a Scene). Queries take origins and directions ((N, 3) arrays,
    or one (3,) row, any real dtype) and optional `tmin` and `tmax` (numbers or (N,) arrays);
    a hit counts when tmin <= t <= tmax. Invalid input raises RayInputError (a ValueError)
    naming the argument. After each query, `last_stats` holds the counters of that query
    (``rays.cast``, ``tests.triangle``, ``bounds.tests``, ``cells.visited``, ...) and its
    ``time.trace`` in seconds.

    Any number of Python threads may query one RayScene at once; `last_stats` is the calling
    thread's own last query. Lazy structures (lazyoctree, rc) refine between passes of one
    query, so their queries take turns (a lock); the others run side by side. Hits never
    depend on the order: only the counters of lazy kinds do, as the trees they meet have
    grown.

    Parameters
    ----------
    scene : Scene
        Any scene model: all its primitive kinds, nested groups and instances.
    accel : str, default "bvh"
        The accelerator spec of groups that name none.
    max_memory : int or str, optional
        The memory budget of the build and of lazy refinement, in bytes or as ``"8G"``
        (default: half of this machine's memory).
    edges : {"watertight", "inclusive"}
        ``"watertight"``: a ray through a shared edge or vertex hits exactly one triangle
        there; ``"inclusive"``: every triangle there, reported once (rays grazing a silhouette
        edge or running in a face's plane hit, as in Embree).

    Attributes
    ----------
    scene : Scene
        The scene built.
    geometries : list of dict
        One ``{"kind": str, "count": int}`` per geometry (a mesh, or a set of spheres,
        polygons, patches or cones), in the order of ``geom_id``.

    Raises
    ------
    RayInputError
        `scene` is not a Scene, or `edges` is not one of the two rules.
    MemoryBudgetError
        The structures would need more than `max_memory`.

    Examples
    --------
    >>> scene = RayScene.from_mesh(vertices, faces)
    >>> hits = scene.intersect(origins, directions)
    >>> hits.t, hits.prim_id, hits.normal
    >>> blocked = scene.occluded(origins, directions, tmax=1.0)
    >>> ray, t, prim = scene.intersect_all(origins, directions)
    """

    SPHERE, POLYGON, PATCH, CONE, TRIANGLE = SPHERE, POLYGON, PATCH, CONE, TRIANGLE

    def __init__(self, scene: Scene, accel: str = "bvh", max_memory=None, edges: str = "watertight"):
        """Build the structures of `scene` (the parameters: see RayScene)."""
        if not isinstance(scene, Scene):
            raise RayInputError(f"scene must be a raykernel Scene, got {type(scene).__name__}")
        self._start(scene, accel, max_memory, edges)
        geo, self.build_stats = flatten(scene, accel, max_memory)
        self._geo = geo._replace(tri_edges=np.array([EDGE_RULES[edges]], np.int64))
        table = self.build_stats.pop("geometries")
        self.geometries = [{"kind": KIND_NAMES[k], "count": int(n)} for k, _, n in table]
        # per kind family (polygons and patches share one numbering): first global index of each geometry
        family = np.where(table[:, 0] == PATCH, POLYGON, table[:, 0]) if len(table) else table[:, 0]
        self._geom_of = {int(k): (np.flatnonzero(family == k), table[family == k, 1]) for k in np.unique(family)}
        # a primitive can be met twice along a ray through a group nested twice, or where its aggregate
        # refers to it more than once (a grid or an octree holds an item in every cell it overlaps, a BVH
        # built over pieces in every leaf of a piece: bvh(split=...))
        self._may_repeat = len(self.geo.agg_kind) > 1 or any(
            a.get("refs", np.inf) > a.get("items", 0) for a in self.build_stats.get("aggregates", ()))
        # lazy octrees refine between passes of rays (aggregates/lazyoctree.py); their leaves share items
        self._lazy = self.build_stats.get("lazy")
        self._may_repeat = self._may_repeat or self._lazy is not None or edges == "inclusive"
        self._mesh = MeshKernel.of(self.geo, table)

    def _start(self, scene: Scene, accel: str, max_memory, edges: str) -> None:
        """What every RayScene holds, however it is built: its scene and options, the memory
        budget, the lock and the per-thread statistics."""
        if edges not in EDGE_RULES:
            raise RayInputError(f"edges must be one of {', '.join(EDGE_RULES)}, got {edges!r}")
        self.scene, self.edges, self._accel, self._max_memory = scene, edges, accel, max_memory
        self._limit = memory_limit(max_memory)
        self._lock = threading.RLock()      # held by queries that refine lazy structures
        self._local = threading.local()     # last_stats, per thread

    @property
    def geo(self):
        """The scene's flat Geometry (engine/flatten.py), which every query but the mesh kernel's walks.

        A mesh built straight into the mesh kernel's arrays (from_mesh) builds it on first use,
        with the scene's spec: point queries and parity tests need it, ray casts do not.
        """
        if self._geo is None:
            with self._lock:
                if self._geo is None:
                    geo, _ = flatten(self.scene, self._accel, self._max_memory)
                    self._geo = geo._replace(tri_edges=np.array([EDGE_RULES[self.edges]], np.int64))
        return self._geo

    @geo.setter
    def geo(self, geo) -> None:
        self._geo = geo

    @property
    def stats(self) -> dict:
        """The build's statistics, and the bytes held beyond the user's arrays.

        A dict: the build's figures, ``aggregates`` (one dict per aggregate built), ``bytes``
        (the mesh kernel's arrays and the Geometry where it is built) and, for meshes,
        ``bytes_per_triangle``.
        """
        stats = dict(self.build_stats)
        held = self._mesh.nbytes if self._mesh is not None else 0
        if self._geo is not None:
            held += sum(a.nbytes for a in self._geo if isinstance(a, np.ndarray))
        stats["bytes"] = held
        triangles = sum(g["count"] for g in self.geometries if g["kind"] == "triangle")
        if triangles:
            stats["bytes_per_triangle"] = held / triangles
        return stats

    @property
    def last_stats(self) -> dict:
        """The counters and times of this thread's last query, as a dict.

        Counter names (``rays.cast``, ``tests.triangle``, ...) and ``time.trace``,
        ``time.compile`` and ``time.load`` in seconds; empty before any query.
        """
        return getattr(self._local, "stats", {})

    @last_stats.setter
    def last_stats(self, stats: dict) -> None:
        self._local.stats = stats

    def _turn(self):
        """The lock while a query may refine lazy structures; nothing to wait for otherwise."""
        return self._lock if self._lazy is not None else nullcontext()

    def __getstate__(self):
        state = self.__dict__.copy()
        del state["_lock"], state["_local"]
        state.pop("_point_index", None)      # rebuilt on demand
        state.pop("_far", None)
        state.pop("_grid", None)
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._lock = threading.RLock()
        self._local = threading.local()

    def _identify(self, kind: np.ndarray, index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(geometry, index within it) of global (kind, index) pairs; -1 where kind is -1."""
        geom = np.full(len(kind), -1, np.int64)
        local = np.full(len(kind), -1, np.int64)
        family = np.where(kind == PATCH, POLYGON, kind)
        for k, (ids, starts) in self._geom_of.items():
            sel = family == k
            if np.any(sel):
                g = np.searchsorted(starts, index[sel], side="right") - 1
                geom[sel] = ids[g]
                local[sel] = index[sel] - starts[g]
        return geom, local

    @classmethod
    def from_trimesh(cls, mesh, accel: str | None = None, edges: str = "watertight", quality: str = "medium",
                     max_memory=None) -> "RayScene":
        """A RayScene of a trimesh.Trimesh, or of any object with ``.vertices`` and ``.faces``.

        Parameters
        ----------
        mesh : trimesh.Trimesh or object
            ``mesh.vertices``: (V, 3) real array; ``mesh.faces``: (F, 3) integer array.
        accel, edges, quality, max_memory
            As for `from_mesh`.

        Returns
        -------
        RayScene

        Raises
        ------
        RayInputError
            `mesh` has no ``.vertices`` and ``.faces``, or they are not valid.
        """
        if not (hasattr(mesh, "vertices") and hasattr(mesh, "faces")):
            raise RayInputError(f"expected a mesh with .vertices and .faces, got {type(mesh).__name__}")
        return cls.from_mesh(np.asarray(mesh.vertices), np.asarray(mesh.faces), accel=accel, edges=edges,
                             quality=quality, max_memory=max_memory)

    @classmethod
    def from_file(cls, path, accel: str | None = None, edges: str = "watertight", quality: str = "medium",
                  max_memory=None) -> "RayScene":
        """A RayScene of the triangles of a model file, every mesh of it in one.

        Parameters
        ----------
        path : str or path-like
            An OBJ, PLY, STL, OFF, glTF or GLB file, read by trimesh (the ``mesh`` extra); its
            meshes are placed by the file's transforms (scene/meshfile.py).
        accel, edges, quality, max_memory
            As for `from_mesh`.

        Returns
        -------
        RayScene

        Raises
        ------
        SceneError
            The file does not exist, cannot be read, or holds no triangles.
        OptionError
            trimesh is not installed.
        """
        from ..scene.meshfile import mesh_arrays
        vertices, faces = mesh_arrays(path)
        return cls.from_mesh(vertices, faces, accel=accel, edges=edges, quality=quality, max_memory=max_memory)

    @classmethod
    def from_mesh(cls, vertices, faces=None, normals=None, accel: str | None = None, edges: str = "watertight",
                  quality: str = "medium", max_memory=None, threads: int | None = None) -> "RayScene":
        """A RayScene of a triangle mesh.

        Unless `accel` is given (or there are no faces), the tree is built straight into the
        mesh kernel's arrays: the triangles' corners once, in float64 blocks of four, the
        4-wide nodes and a triangle index a lane (``stats["bytes_per_triangle"]``); float64
        vertices and int64 faces are read, not copied.

        Parameters
        ----------
        vertices : (V, 3) float32 or float64 array_like
            The vertices; or a mesh object (trimesh.Trimesh, anything with ``.vertices`` and
            ``.faces``) standing for both, with `faces` None.
        faces : (F, 3) integer array_like
            Vertex indices of each triangle.
        normals : (V, 3) array_like, optional
            Per-vertex normals, interpolated into ``Hits.shading_normal``.
        accel : str, optional
            Any accelerator spec instead, built through the scene's general path.
        edges : {"watertight", "inclusive"}
            The rule at shared edges and vertices (as for RayScene).
        quality : {"fast", "medium", "high"}
            The build, as Embree's build qualities: ``"fast"`` (Morton order: quickest to
            build, for few rays), ``"medium"`` (binned SAH, the default) or ``"high"`` (the SAH
            tree with nodes reinserted: slowest to build, for many rays).
        max_memory : int or str, optional
            The budget of the build, in bytes or as ``"8G"``.
        threads : int, optional
            The build's threads (default: all).

        Returns
        -------
        RayScene

        Raises
        ------
        RayInputError
            The arrays do not have these shapes and types, vertices or normals are not finite,
            a face refers to a vertex that does not exist, or `quality` is not one of the three.
        MemoryBudgetError
            The build would need more than `max_memory`.
        """
        if faces is None and hasattr(vertices, "vertices") and hasattr(vertices, "faces"):
            return cls.from_trimesh(vertices, accel, edges, quality, max_memory)
        if faces is None:
            raise RayInputError(f"from_mesh needs faces, or a mesh object with .vertices and .faces "
                                f"(got a {type(vertices).__name__})")
        v = _real_array(vertices, "vertices")
        if v.ndim != 2 or v.shape[1] != 3:
            raise RayInputError(f"vertices must have shape (V, 3), got {v.shape}")
        if not np.all(np.isfinite(v)):
            raise RayInputError(f"vertices[{int(np.flatnonzero(~np.all(np.isfinite(v), axis=1))[0])}] is not finite")
        f = np.asarray(faces)
        if not np.issubdtype(f.dtype, np.integer):
            raise RayInputError(f"faces must be integer vertex indices, got dtype {f.dtype}")
        if f.ndim != 2 or f.shape[1] != 3:
            raise RayInputError(f"faces must have shape (F, 3), got {f.shape}")
        if len(f) and (f.min() < 0 or f.max() >= len(v)):
            raise RayInputError(f"faces refer to vertex {int(f.max() if f.max() >= len(v) else f.min())}, "
                                f"but there are {len(v)} vertices")
        n = None
        if normals is not None:
            n = _real_array(normals, "normals")
            if n.shape != v.shape:
                raise RayInputError(f"normals must have the shape of vertices {v.shape}, got {n.shape}")
            if not np.all(np.isfinite(n)):
                raise RayInputError("normals must be finite")
        if quality not in QUALITY:
            raise RayInputError(f"quality must be one of {', '.join(QUALITY)}, got {quality!r}")
        v = np.ascontiguousarray(v, np.float64)
        f = np.ascontiguousarray(f, np.int64)
        n = None if n is None else np.ascontiguousarray(n, np.float64)
        scene = Scene()
        scene.root.add(TriangleMesh(v, f, normals=n))
        if accel is not None or not len(f):
            return cls(scene, accel or QUALITY[quality], max_memory, edges=edges)
        self = cls.__new__(cls)
        self._start(scene, MESH_ACCEL, max_memory, edges)      # the Geometry, if ever built: the medium tree
        check(len(f) * BUILD_BYTES, self._limit, f"building a BVH over {len(f):,} triangles", "build a smaller mesh")
        self._geo = None
        self._mesh, self.build_stats = build_mesh(v, f, n, quality, EDGE_RULES[edges], threads)
        self.build_stats["aggregates"] = [dict(self.build_stats, kind="bvh", spec=QUALITY[quality])]
        self.geometries = [{"kind": "triangle", "count": len(f)}]
        self._geom_of = {TRIANGLE: (np.array([0]), np.array([0]))}
        self._may_repeat = edges == "inclusive"
        self._lazy = None
        return self

    @classmethod
    def from_spheres(cls, centers, radii, accel: str = "bvh") -> "RayScene":
        """A RayScene of spheres.

        Parameters
        ----------
        centers : (N, 3) array_like
            The spheres' centres, finite.
        radii : float or (N,) array_like
            Their radii, finite and positive.
        accel : str, default "bvh"
            The accelerator spec.

        Returns
        -------
        RayScene

        Raises
        ------
        RayInputError
            The arrays do not have these shapes, or a value is not finite or a radius not
            positive.
        """
        c = _real_array(centers, "centers")
        if c.ndim == 1 and c.shape[0] == 3:
            c = c[None, :]
        if c.ndim != 2 or c.shape[1] != 3:
            raise RayInputError(f"centers must have shape (N, 3), got {c.shape}")
        r = _real_array(radii, "radii")
        if r.ndim > 1 or (r.ndim == 1 and len(r) != len(c)):
            raise RayInputError(f"radii must be a number or have shape ({len(c)},), got {r.shape}")
        r = np.broadcast_to(r, (len(c),)).copy()
        if not np.all(np.isfinite(c)):
            raise RayInputError("centers must be finite")
        if not np.all(np.isfinite(r) & (r > 0)):
            raise RayInputError(f"radii[{int(np.flatnonzero(~(np.isfinite(r) & (r > 0)))[0])}] must be finite "
                                "and positive")
        scene = Scene()
        sph = scene.root.spheres
        sph.center, sph.radius, sph.material = c.copy(), r, np.zeros(len(c), np.int32)
        return cls(scene, accel)

    @classmethod
    def from_scene(cls, scene: Scene, accel: str = "bvh", edges: str = "watertight") -> "RayScene":
        """A RayScene of any scene model (loaded NFF or JSON, SPD generator, pathological scenes).

        Parameters
        ----------
        scene : Scene
            All its primitive kinds, nested groups and instances.
        accel : str, default "bvh"
            The accelerator spec of groups without their own.
        edges : {"watertight", "inclusive"}
            The rule at shared edges and vertices (as for RayScene).

        Returns
        -------
        RayScene
        """
        return cls(scene, accel, edges=edges)

    # ------------------------------------------------------------- queries

    def _run(self, mode, o, d, lo, hi, out: dict, offsets=None, all_t=None, all_i=None, threads=None) -> dict:
        """One query kernel over all rays, filling the arrays of `out` (t, kind, geom, idx, inst, uv,
        gn, sn; those not wanted have no rows) in place; returns the query's statistics. Closest
        and any hits: the mesh kernel writes identities as the user sees them (geom, index within
        it), the general one kind and global index in idx (see _identify). All hits: idx holds
        the counts, or with offsets the hits go to all_t / all_i as (kind, global index, instance)."""
        n = len(o)
        t, kind, geom, idx, inst, uv, gn, sn = (out[k] for k in OUTPUTS)
        with_surface = len(uv) > 0 or len(gn) > 0 or len(sn) > 0
        offsets = np.zeros(0, np.int64) if offsets is None else offsets
        all_t = np.zeros(0) if all_t is None else all_t
        all_i = np.zeros((0, 3), np.int64) if all_i is None else all_i
        counters = np.zeros((max(1, (n + CHUNK - 1) // CHUNK), C.N_COUNTERS), np.int64)
        kernel = self._mesh.kernel if self._mesh is not None else _query
        name = f"meshcast.{kernel.__name__}" if self._mesh is not None else "rayscene._query"
        about = ("several seconds" if self._mesh is not None
                 else "tens of seconds, longer for other structures than one BVH")
        notice = compile_notice(name, f"raykernel: compiling the ray-casting kernels (first use after install, "
                                      f"{about}; cached for later processes)")
        with self._turn(), CompileClock(notice=notice) as clock:
            start = time.perf_counter()         # (after waiting for the lock)
            if n and self._mesh is not None:
                mesh = self._mesh
                for_ranges(lambda c0, c1: kernel(*mesh, o, d, lo, hi, np.int64(mode), CHUNK, t, kind, geom,
                                                 idx, inst, uv, gn, sn, with_surface, offsets, all_t, all_i, counters,
                                                 c0, c1), len(counters), threads, kernel=kernel)
            elif n and self._lazy is not None:
                # the rays coarse to fine (every 2^k-th first), in passes from a few rays up to PASS_CHUNKS
                # chunks (lazyset.pass_ranges); the lazy structures refine after each; passes shorter
                # than a chunk add into the first chunk's row. Results go back to the rays' own order.
                order = coarse_to_fine(n)
                ins = [np.broadcast_to(a, (n,) + a.shape[1:])[order] for a in (o, d, lo, hi)]
                outs = [np.empty_like(a) for a in (t, kind, idx, inst, uv, gn, sn)]
                p_offsets, p_all_t, p_all_i = offsets, all_t, all_i
                if len(offsets):
                    counts = np.diff(offsets)
                    p_offsets = np.zeros(n + 1, np.int64)
                    np.cumsum(counts[order], out=p_offsets[1:])
                    p_all_t, p_all_i = np.empty_like(all_t), np.empty_like(all_i)
                for a, b in self._lazy.ranges(n, CHUNK):
                    rows = np.zeros(((b - a + CHUNK - 1) // CHUNK, C.N_COUNTERS + self._lazy.columns), np.int64)
                    args = (self.geo, *(x[a:b] for x in ins), np.int64(mode), CHUNK, *(x[a:b] for x in outs),
                            with_surface, p_offsets[a:b + 1] if len(offsets) else offsets, p_all_t, p_all_i, rows)
                    for_ranges(lambda c0, c1, args=args: _query(*args, c0, c1), len(rows), threads, kernel=_query)
                    counters[a // CHUNK:a // CHUNK + len(rows)] += rows[:, :C.N_COUNTERS]
                    self.geo = self._lazy.refine(self.geo, rows[:, C.N_COUNTERS:])
                for mine, theirs in zip((t, kind, idx, inst, uv, gn, sn), outs):
                    if len(mine):       # only what was asked for
                        mine[order] = theirs
                if len(offsets):
                    # ray order[k]'s hits lie at p_offsets[k]..p_offsets[k + 1]
                    start = np.empty(n, np.int64)
                    start[order] = p_offsets[:-1]
                    src = np.repeat(start - offsets[:-1], counts) + np.arange(offsets[-1])
                    all_t[:] = p_all_t[src]
                    all_i[:] = p_all_i[src]
                self._lazy.update_stats(self.build_stats, self.geo)
            elif n:
                for_ranges(lambda c0, c1: _query(self.geo, o, d, lo, hi, np.int64(mode), CHUNK, t, kind, idx, inst, uv,
                                                 gn, sn, with_surface, offsets, all_t, all_i, counters, c0, c1),
                           len(counters), threads, kernel=_query)
        seconds = time.perf_counter() - start - clock.seconds - clock.loading
        totals = counters.sum(axis=0)
        if totals[C.RAYS_CAST] != n:        # the kernels left out rays that are not finite or do not move
            check_ray_values(o, d)
            raise RuntimeError(f"the kernels cast {totals[C.RAYS_CAST]} of {n} rays, all of them valid")
        totals = totals.tolist()
        stats = {name: totals[k] for k, name in COUNTER_NAMES.items() if totals[k]}
        stats["rays.cast"] = n
        stats["time.trace"] = seconds
        stats["time.compile"] = clock.seconds
        stats["time.load"] = clock.loading
        return stats

    def _budget(self, what: str, per_ray: int, hint: str = "cast fewer rays at a time"):
        """check_rays' budget: MemoryBudgetError unless the structures, the rays' copies and
        `per_ray` bytes of outputs a ray fit in the memory budget (max_memory)."""
        def fits(n: int, copied: int) -> None:
            need = n * (per_ray + C.N_COUNTERS * 8 // CHUNK + 1) + copied
            if need > (1 << 24):        # small batches are not worth summing the structures for
                held = self.stats["bytes"]
                check(held + need, self._limit, f"RayScene.{what} of {n:,} rays ({describe_bytes(need)} of outputs "
                      f"and copies, beside {describe_bytes(held)} of structures)", hint)
        return fits

    def _output_bytes(self, fields=None, dtype="float64") -> int:
        """The bytes a ray's outputs take: the fields asked for, and the general kernel's identities."""
        fdt, idt = DTYPES.get(dtype, DTYPES["float64"])
        per = sum(np.dtype(fdt if name in FLOAT_FIELDS else idt).itemsize * math.prod(FIELD_COLUMNS.get(name, ()))
                  for name in (HIT_FIELDS if fields is None else _field_names(fields)))
        return per + (0 if self._mesh is not None else 16)

    def _outputs(self, shape: tuple, fields=None, dtype="float64", out=None) -> tuple[dict, dict]:
        """(the kernel's output arrays by OUTPUTS name, the Hits fields asked for by name): the
        fields' arrays come from `out` (a Hits) or are new; what nobody asked for has no rows.
        The general kernel writes kind and global index (int64) for _identify, apart."""
        fields = HIT_FIELDS if fields is None else _field_names(fields)
        if dtype not in DTYPES:
            raise RayInputError(f"dtype must be one of {', '.join(DTYPES)}, got {dtype!r}")
        fdt, idt = DTYPES[dtype]
        if out is not None and not isinstance(out, Hits):
            raise RayInputError(f"out must be the Hits of an earlier intersect call, got {type(out).__name__}")
        n = math.prod(shape)
        hits = {}
        for name in fields:
            dt = fdt if name in FLOAT_FIELDS else idt
            columns = FIELD_COLUMNS.get(name, ())
            hits[name] = np.empty((n,) + columns, dt) if out is None else _out_array(out, name, shape + columns, dt)
        none_i = np.empty(0, idt)
        arrays = dict(t=hits["t"], kind=hits.get("kind", none_i), geom=hits.get("geom_id", none_i),
                      idx=hits.get("prim_id", none_i), inst=hits.get("inst_id", none_i),
                      uv=hits.get("uv", np.empty((0, 2), fdt)), gn=hits.get("normal", np.empty((0, 3), fdt)),
                      sn=hits.get("shading_normal", np.empty((0, 3), fdt)))
        if self._mesh is None:
            identify = "prim_id" in hits or "geom_id" in hits
            arrays["kind"] = np.empty(n, np.int64) if identify or "kind" in hits else np.empty(0, np.int64)
            arrays["idx"] = np.empty(n, np.int64) if identify else np.empty(0, np.int64)
            arrays["geom"] = np.empty(0, np.int64)
        return arrays, hits

    @_ray_query_doc
    def intersect(self, origins, directions, tmin=0.0, tmax=np.inf, threads: int | None = None, fields=None,
                  dtype: str = "float64", out: Hits | None = None) -> Hits:
        """Closest hit of every ray in [tmin, tmax].

        Ties at equal t go to the smaller (geom_id, prim_id, inst_id), whatever the traversal
        order.

        Parameters
        ----------
        {rays}
        threads : int, optional
            How many threads to use (default: numba's thread count).
        fields : str or sequence of str, optional
            The Hits fields to compute, e.g. ``("t", "prim_id")`` (default: all of them; t
            always); the others are None. The surface fields (uv, normal, shading_normal)
            cost the most.
        dtype : {"float64", "float32"}
            ``"float32"`` gives float32 t, uv and normals and int32 ids: half the memory to
            fill (the arithmetic stays in double precision, t is rounded once).
        out : Hits, optional
            The Hits of an earlier call with these fields and dtype, for rays of this shape:
            its arrays are filled in place instead of new ones (no memory to allocate).

        Returns
        -------
        Hits
            Shaped as the rays: (N,) fields for (N, 3) rays; `out` itself where given.

        {raises}

        Notes
        -----
        A ray that is not finite or has a zero direction raises RayInputError naming it, after
        the other rays were cast: `out`'s arrays then hold their hits.
        """
        per_ray = 0 if out is not None else self._output_bytes(fields, dtype)
        o, d, lo, hi, shape = check_rays(origins, directions, tmin, tmax,
                                         self._budget("intersect", per_ray, "cast fewer rays at a time, or fill the "
                                                      "arrays of an earlier call (out=)"))
        arrays, hits = self._outputs(shape, fields, dtype, out)
        stats = self._run(CLOSEST, o, d, lo, hi, arrays, threads=threads)
        if self._mesh is None:
            if "prim_id" in hits or "geom_id" in hits:
                geom, prim = self._identify(arrays["kind"], arrays["idx"])
                for name, value in (("prim_id", prim), ("geom_id", geom)):
                    if name in hits:
                        hits[name][...] = value
            if "kind" in hits:
                hits["kind"][...] = arrays["kind"]
        self.last_stats = stats
        if out is not None:
            out.origins, out.directions = o.reshape(shape + (3,)), d.reshape(shape + (3,))
            return out
        return Hits(**{name: (hits[name].reshape(shape + FIELD_COLUMNS.get(name, ())) if name in hits else None)
                       for name in HIT_FIELDS}, origins=o.reshape(shape + (3,)), directions=d.reshape(shape + (3,)))

    @_ray_query_doc
    def occluded(self, origins, directions, tmin=0.0, tmax=np.inf, threads: int | None = None) -> np.ndarray:
        """True where the ray meets anything in [tmin, tmax] (stops at the first hit found).

        Parameters
        ----------
        {rays}
        threads : int, optional
            How many threads to use (default: numba's thread count).

        Returns
        -------
        (N,) bool array
            Shaped as the rays.

        {raises}
        """
        o, d, lo, hi, shape = check_rays(origins, directions, tmin, tmax, self._budget("occluded", 9))
        arrays, _ = self._outputs((len(o),), ("t",))
        self.last_stats = self._run(ANY, o, d, lo, hi, arrays, threads=threads)
        return np.isfinite(arrays["t"]).reshape(shape)

    def _counts(self, n: int) -> dict:
        """Output arrays for an all-hits run: t and the counts (idx) only."""
        arrays, _ = self._outputs((n,), ("t",))
        arrays["idx"] = np.empty(n, np.int64)
        return arrays

    def _all(self, o, d, lo, hi, threads=None):
        with self._turn():      # both runs, with no other query refining in between
            mark = self._lazy.checkpoint() if self._lazy is not None else None
            arrays = self._counts(len(o))
            stats = self._run(ALL_HITS, o, d, lo, hi, arrays, threads=threads)
            counts = arrays["idx"]
            if mark is not None:
                self.geo = self._lazy.restore(mark, self.geo)   # the second run must meet the same trees
            offsets = np.zeros(len(o) + 1, np.int64)
            np.cumsum(counts, out=offsets[1:])
            # each hit: t, (kind, index, instance), its ray, and the sort's order and copies
            self._budget("intersect_all", 0)(len(o), int(offsets[-1]) * HIT_BYTES)
            all_t = np.empty(offsets[-1])
            all_i = np.empty((offsets[-1], 3), np.int64)
            stats2 = self._run(ALL_HITS, o, d, lo, hi, self._counts(len(o)), offsets=offsets, all_t=all_t,
                               all_i=all_i, threads=threads)
        for k, v in stats2.items():
            stats[k] = stats.get(k, 0) + v
        stats["rays.cast"] = len(o)
        ray = np.repeat(np.arange(len(o), dtype=np.int64), counts)
        # identities as the user sees them: (geometry, index within it, instance)
        all_i[:, 0], all_i[:, 1] = self._identify(all_i[:, 0], all_i[:, 1])
        order = np.lexsort((all_i[:, 2], all_i[:, 1], all_i[:, 0], all_t, ray))
        ray, all_t, all_i = ray[order], all_t[order], all_i[order]
        if self._may_repeat and len(ray) > 1:
            # the same primitive met again in a later grid cell: same ray, t and identity; with
            # inclusive edges also the neighbours of an edge or vertex the ray passes through (same
            # geometry and instance at the same t): the first, the smallest prim_id, stays
            differ = all_i[1:] != all_i[:-1]      # geometry, prim_id, instance
            if self.edges == "inclusive":
                differ[:, 1] = False
            keep = np.ones(len(ray), bool)
            keep[1:] = (ray[1:] != ray[:-1]) | (all_t[1:] != all_t[:-1]) | np.any(differ, axis=1)
            ray, all_t, all_i = ray[keep], all_t[keep], all_i[keep]
        return ray, all_t, all_i, counts, stats

    @_ray_query_doc
    def intersect_all(self, origins, directions, tmin=0.0, tmax=np.inf, ids: bool = False,
                      threads: int | None = None):
        """Every primitive each ray meets in [tmin, tmax], once, at its first crossing in the interval.

        A sphere the ray passes through counts once, where it enters. A ray through a shared
        edge or vertex of a mesh meets exactly one of the triangles there (watertight tests).
        The hits come sorted by ray, then t, then (geom_id, prim_id, inst_id).

        Parameters
        ----------
        {rays}
        ids : bool, default False
            Return geom_id and inst_id too.
        threads : int, optional
            How many threads to use (default: numba's thread count).

        Returns
        -------
        ray_index : (K,) int64 array
            The ray of each hit, counting the rays in row-major order
            (``np.unravel_index(ray_index, shape)`` for shaped rays).
        t : (K,) float64 array
            The ray parameter of each hit.
        prim_id : (K,) int64 array
            The primitive within its geometry.
        geom_id : (K,) int64 array
            With ``ids=True`` only: the geometry (``RayScene.geometries``).
        inst_id : (K,) int64 array
            With ``ids=True`` only: the innermost instance, -1 outside instances.

        {raises}
        """
        o, d, lo, hi, _ = check_rays(origins, directions, tmin, tmax, self._budget("intersect_all", 48))
        ray, t, ident, _, stats = self._all(o, d, lo, hi, threads)
        self.last_stats = stats
        if ids:
            return ray, t, ident[:, 1].copy(), ident[:, 0].copy(), ident[:, 2].copy()
        return ray, t, ident[:, 1].copy()

    @_ray_query_doc
    def count_hits(self, origins, directions, tmin=0.0, tmax=np.inf, threads: int | None = None) -> np.ndarray:
        """Number of primitives each ray meets in [tmin, tmax] (the lengths of intersect_all's lists).

        Parameters
        ----------
        {rays}
        threads : int, optional
            How many threads to use (default: numba's thread count).

        Returns
        -------
        (N,) int64 array
            Shaped as the rays.

        {raises}
        """
        o, d, lo, hi, shape = check_rays(origins, directions, tmin, tmax, self._budget("count_hits", 48))
        if self._may_repeat:
            ray, _, _, _, stats = self._all(o, d, lo, hi, threads)
            counts = np.bincount(ray, minlength=len(o)).astype(np.int64)
        else:
            arrays = self._counts(len(o))
            stats = self._run(ALL_HITS, o, d, lo, hi, arrays, threads=threads)
            counts = arrays["idx"]
        self.last_stats = stats
        return counts.reshape(shape)

    # ------------------------------------------------------------- point queries (proximity.py)

    def _points(self, points) -> tuple[np.ndarray, tuple]:
        p = _vectors(points, "points")
        return np.ascontiguousarray(p.reshape(-1, 3)), p.shape[:-1]

    def closest_points(self, points, threads: int | None = None) -> ClosestPoints:
        """The closest point of the scene's surface to each point.

        Triangles, polygons, patches and spheres; a scene with instances or cones raises
        RayInputError.

        Parameters
        ----------
        points : (N, 3) array_like
            The query points ((..., 3): any leading shape), finite.
        threads : int, optional
            How many threads to use (default: numba's thread count).

        Returns
        -------
        ClosestPoints
            Shaped as the points: ``points`` (N, 3) float64, the closest surface point;
            ``distance`` (N,) float64 (inf for an empty scene); ``prim_id``, ``geom_id`` and
            ``kind`` (N,) int64, the primitive there (-1 for an empty scene); ``normal``
            (N, 3) float64, its unit geometric normal there.

        Raises
        ------
        RayInputError
            The points are not valid, or the scene has instances or cones.
        """
        p, shape = self._points(points)
        try:
            index = point_index(self)
        except ValueError as e:
            raise RayInputError(str(e)) from None
        q, dist, refs = index.query(p, threads)
        kind, idx = kinds_of(self.geo, refs)
        geom, prim = self._identify(kind, idx)
        normal = surface_normals(self.geo, kind, idx, q)
        return ClosestPoints(points=q.reshape(shape + (3,)), distance=dist.reshape(shape), prim_id=prim.reshape(shape),
                             geom_id=geom.reshape(shape), kind=kind.reshape(shape), normal=normal.reshape(shape + (3,)))

    def distance(self, points, threads: int | None = None) -> np.ndarray:
        """Distance from each point to the scene's surface (as `closest_points`).

        Parameters
        ----------
        points : (N, 3) array_like
            The query points ((..., 3): any leading shape), finite.
        threads : int, optional
            How many threads to use (default: numba's thread count).

        Returns
        -------
        (N,) float64 array
            Shaped as the points.
        """
        return self.closest_points(points, threads).distance

    def contains(self, points, threads: int | None = None, method: str = "auto") -> np.ndarray:
        """True where a point lies inside the scene.

        Parameters
        ----------
        points : (N, 3) array_like
            The query points ((..., 3): any leading shape), finite.
        threads : int, optional
            How many threads to use (default: numba's thread count).
        method : {"auto", "parity", "winding", "vote"}
            ``"parity"`` casts one ray a point, toward the nearest side of the scene's box, and
            counts the triangles it crosses (exact for a closed mesh: the watertight test
            counts a crossing through a shared edge once); ``"winding"`` takes the generalized
            winding number above one half (winding.py: for meshes with holes, an answer that
            depends on no ray's direction); ``"vote"``, the majority of three parity rays, also
            for polygons and spheres; ``"auto"`` (the default): parity for a closed triangle
            mesh, winding for one with holes, vote for any other scene.

        Returns
        -------
        (N,) bool array
            Shaped as the points.

        Raises
        ------
        RayInputError
            The points or `method` are not valid, parity or winding is asked of a scene that
            is not triangle meshes, or the scene has instances or cones.
        """
        p, shape = self._points(points)
        if method not in ("auto", "parity", "winding", "vote"):
            raise RayInputError(f"method must be auto, parity, winding or vote, got {method!r}")
        if self._geo is not None and (len(self._geo.inst_agg) or len(self._geo.cone_length)):
            raise RayInputError("contains does not handle instances or cones yet")
        meshes_only = [g["kind"] for g in self.geometries] == ["triangle"] * len(self.geometries)
        if method == "auto":
            method = "vote" if not meshes_only else "parity" if self._closed() else "winding"
        if method != "vote" and not meshes_only:
            raise RayInputError(f"contains(method={method!r}) takes triangle meshes only; this scene has "
                                f"{', '.join(sorted({g['kind'] for g in self.geometries} - {'triangle'}))}")
        if method == "winding":
            mesh, far = self._winding_tree()
            return (winding_numbers(mesh, p, far, threads) > 0.5).reshape(shape)
        if method == "parity":
            box = self._mesh.geo.agg_bounds[0] if self._mesh is not None else self.geo.agg_bounds[self.geo.root]

            def odd_crossings(q):
                return self.count_hits(q, parity_directions(q, box, threads), threads=threads) % 2 == 1

            if not self._closed():
                return odd_crossings(p).reshape(shape)
            # a closed mesh: points in cells no triangle touches take their region's answer (occupancy.py)
            inside, known = self._occupancy(odd_crossings).lookup(p, threads)
            rest = np.flatnonzero(~known)
            if len(rest):
                inside[rest] = odd_crossings(p[rest])
            return inside.reshape(shape)
        spheres = [g for g, info in enumerate(self.geometries) if info["kind"] == "sphere"]

        def odd(q, direction):
            if spheres:
                # a sphere counts once per ray in hit lists, but is crossed twice: its own test below
                ray, _, _, geom, _ = self.intersect_all(q, direction, ids=True, threads=threads)
                return np.bincount(ray[~np.isin(geom, spheres)], minlength=len(q)) % 2 == 1
            return self.count_hits(q, direction, threads=threads) % 2 == 1

        first, second = odd(p, INSIDE_DIRECTIONS[0]), odd(p, INSIDE_DIRECTIONS[1])
        inside = first & second
        split = np.flatnonzero(first != second)         # the third ray decides only where two disagree
        if len(split):
            inside[split] = odd(p[split], INSIDE_DIRECTIONS[2])
        inside |= inside_spheres(self.geo, p)
        return inside.reshape(shape)

    def _closed(self) -> bool:
        """Whether the scene is closed triangle meshes, not nested: every edge two triangles', once each way."""
        if not hasattr(self, "_is_closed"):
            root = self.scene.root
            self._is_closed = bool(root.meshes) and not root.children and all(map(_closed_mesh, root.meshes))
        return self._is_closed

    def _occupancy(self, odd_crossings):
        """The closed meshes' occupancy grid (built once; its regions decided by odd_crossings)."""
        if not hasattr(self, "_grid"):
            meshes = self.scene.root.meshes
            offsets = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
            vertices = np.concatenate([np.asarray(m.vertices, np.float64) for m in meshes])
            faces = np.concatenate([np.asarray(m.faces, np.int64) + o for m, o in zip(meshes, offsets)])
            self._grid = occupancy_grid(vertices, faces, odd_crossings)
        return self._grid

    def _winding_tree(self):
        """The 4-wide mesh kernel and its dipoles for winding numbers (built once: for a scene
        walked another way, from its triangles at medium quality)."""
        if not hasattr(self, "_far"):
            mesh = self._mesh
            if mesh is None or not len(mesh.wide.nodes):
                g = self.geo
                mesh, _ = build_mesh(np.ascontiguousarray(g.tri_verts), np.ascontiguousarray(g.tri_faces), None,
                                     "medium", EDGE_RULES[self.edges])
            self._far = (mesh, dipoles(mesh))
        return self._far

    def signed_distance(self, points, threads: int | None = None) -> np.ndarray:
        """Distance to the surface, negative inside (`contains`, method ``"auto"``).

        Parameters
        ----------
        points : (N, 3) array_like
            The query points ((..., 3): any leading shape), finite.
        threads : int, optional
            How many threads to use (default: numba's thread count).

        Returns
        -------
        (N,) float64 array
            Shaped as the points.
        """
        d = self.distance(points, threads)
        return np.where(self.contains(points, threads), -d, d)

    def __repr__(self) -> str:
        # from the geometry table: a mesh built straight into its kernel has no Geometry to count in
        def count(*kinds):
            return sum(g["count"] for g in self.geometries if g["kind"] in kinds)
        instances = len(self._geo.inst_agg) if self._geo is not None else 0
        return (f"RayScene({count('triangle')} triangles, {count('sphere')} spheres, {count('polygon', 'patch')} "
                f"polygons, {count('cone')} cones, {instances} instances)")

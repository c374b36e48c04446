"""Building a RayScene: from a Scene, a triangle mesh, a mesh object or file, or spheres.

    build(rs, scene, accel, max_memory, edges)        # RayScene(scene, ...): the general path
    rs = from_mesh(RayScene, vertices, faces)          # RayScene.from_mesh, from_trimesh, from_file, from_spheres

Each function is the body of the RayScene constructor or class method of its
name (their docstrings are the class's). A Scene goes through the render's
flattening (engine/flatten.py) into one Geometry; a mesh with no accel given
is built straight into the mesh kernel's arrays (meshbuild.py), its Geometry
left to be flattened on first use (RayScene.geo). Either way a RayScene ends
up holding the same attributes: its scene and options (`start`), the table of
its geometries (`geometries`, and `_geom_of` for RayScene._identify), whether
all-hits lists may meet a primitive twice (`_may_repeat`), its lazy
structures (`_lazy`) and the mesh kernel (`_mesh`, None for other scenes).
"""

from __future__ import annotations

import re
import threading

import numpy as np

from ..aggregates.bvh import PRECISIONS
from ..aggregates.memory import check, memory_limit
from ..aggregates.registry import format_spec, parse_spec
from ..engine.flatten import flatten
from ..geometry.config import njit
from ..geometry.primitives import CONE, INCLUSIVE, PATCH, POLYGON, SPHERE, TRIANGLE, WATERTIGHT
from ..scene.model import Scene, TriangleMesh
from .meshahead import compile_query_ahead
from .meshbuild import BUILD_BYTES, QUALITY, build_mesh
from .meshcast import MESH_ACCEL, MeshKernel
from .rayinput import RayInputError, real_array, writable

EDGE_RULES = {"watertight": WATERTIGHT, "inclusive": INCLUSIVE}
KIND_NAMES = {SPHERE: "sphere", POLYGON: "polygon", PATCH: "patch", CONE: "cone", TRIANGLE: "triangle"}


def build(rs, scene: Scene, accel: str = "bvh", max_memory=None, edges: str = "watertight",
          blocks=np.float64) -> None:
    """RayScene(scene, accel, max_memory, edges): build the structures of `scene` into `rs`; blocks:
    the mesh kernel's triangle blocks' dtype (MeshKernel.of)."""
    if not isinstance(scene, Scene):
        raise RayInputError(f"scene must be a raykernel Scene, got {type(scene).__name__}")
    start(rs, scene, accel, max_memory, edges)
    geo, rs.build_stats = flatten(scene, accel, max_memory)
    rs._geo = geo._replace(tri_edges=np.array([EDGE_RULES[edges]], np.int64))
    table = rs.build_stats.pop("geometries")
    rs.geometries = [{"kind": KIND_NAMES[k], "count": int(n)} for k, _, n in table]
    # per kind family (polygons and patches share one numbering): first global index of each geometry
    family = np.where(table[:, 0] == PATCH, POLYGON, table[:, 0]) if len(table) else table[:, 0]
    rs._geom_of = {int(k): (np.flatnonzero(family == k), table[family == k, 1]) for k in np.unique(family)}
    # a primitive can be met twice along a ray through a group nested twice, or where its aggregate
    # refers to it more than once (a grid or an octree holds an item in every cell it overlaps, a BVH
    # built over pieces in every leaf of a piece: bvh(split=...))
    rs._may_repeat = len(rs.geo.agg_kind) > 1 or any(
        a.get("refs", np.inf) > a.get("items", 0) for a in rs.build_stats.get("aggregates", ()))
    # lazy octrees refine between passes of rays (aggregates/lazyoctree.py); their leaves share items
    rs._lazy = rs.build_stats.get("lazy")
    rs._may_repeat = rs._may_repeat or rs._lazy is not None or edges == "inclusive"
    rs._mesh = MeshKernel.of(rs.geo, table, blocks)


def start(rs, scene: Scene, accel: str, max_memory, edges: str) -> None:
    """What every RayScene holds, however it is built: its scene and options, the memory
    budget, the lock and the per-thread statistics."""
    if edges not in EDGE_RULES:
        raise RayInputError(f"edges must be one of {', '.join(EDGE_RULES)}, got {edges!r}")
    rs.scene, rs.edges, rs._accel, rs._max_memory = scene, edges, accel, max_memory
    rs._limit = memory_limit(max_memory)
    rs._lock = threading.RLock()      # held by queries that refine lazy structures
    rs._local = threading.local()     # last_stats, per thread


def from_trimesh(cls, mesh, accel: str | None = None, edges: str = "watertight", quality: str = "medium",
                 max_memory=None, precision: str | None = None):
    """RayScene.from_trimesh: a RayScene of a trimesh.Trimesh, or of any object with ``.vertices`` and ``.faces``."""
    if not (hasattr(mesh, "vertices") and hasattr(mesh, "faces")):
        raise RayInputError(f"expected a mesh with .vertices and .faces, got {type(mesh).__name__}")
    return cls.from_mesh(np.asarray(mesh.vertices), np.asarray(mesh.faces), accel=accel, edges=edges,
                         quality=quality, max_memory=max_memory, precision=precision)


def from_file(cls, path, accel: str | None = None, edges: str = "watertight", quality: str = "medium",
              max_memory=None, precision: str | None = None):
    """RayScene.from_file: a RayScene of the triangles of a model file, every mesh of it in one."""
    from ..scene.meshfile import mesh_arrays
    vertices, faces = mesh_arrays(path)
    return cls.from_mesh(vertices, faces, accel=accel, edges=edges, quality=quality, max_memory=max_memory,
                         precision=precision)


def from_mesh(cls, vertices, faces=None, normals=None, accel: str | None = None, edges: str = "watertight",
              quality: str = "medium", max_memory=None, threads: int | None = None, precision: str | None = None):
    """RayScene.from_mesh: a RayScene of a triangle mesh."""
    accel, precision = mesh_precision(accel, precision)
    if faces is None and hasattr(vertices, "vertices") and hasattr(vertices, "faces"):
        return cls.from_trimesh(vertices, accel, edges, quality, max_memory, precision)
    if faces is None:
        raise RayInputError(f"from_mesh needs faces, or a mesh object with .vertices and .faces "
                            f"(got a {type(vertices).__name__})")
    v = real_array(vertices, "vertices")
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
        n = real_array(normals, "normals")
        if n.shape != v.shape:
            raise RayInputError(f"normals must have the shape of vertices {v.shape}, got {n.shape}")
        if not np.all(np.isfinite(n)):
            raise RayInputError("normals must be finite")
    if quality not in QUALITY:
        raise RayInputError(f"quality must be one of {', '.join(QUALITY)}, got {quality!r}")
    v = writable(np.ascontiguousarray(v, np.float64))
    f = writable(np.ascontiguousarray(f, np.int64))
    single = precision == "single"
    if single:
        v = single_vertices(v, f)
    n = None if n is None else writable(np.ascontiguousarray(n, np.float64))
    scene = Scene()
    scene.root.add(TriangleMesh(v, f, normals=n))
    rs = cls.__new__(cls)
    if accel is not None or not len(f):
        build(rs, scene, accel or QUALITY[quality], max_memory, edges, np.float32 if single else np.float64)
        rs.build_stats["precision"] = precision
        return rs
    start(rs, scene, MESH_ACCEL, max_memory, edges)      # the Geometry, if ever built: the medium tree
    check(len(f) * BUILD_BYTES, rs._limit, f"building a BVH over {len(f):,} triangles", "build a smaller mesh")
    rs._geo = None
    # a first query's kernel compiled here while a helper compiles the builder (meshahead.py)
    ahead = compile_query_ahead(v, f, n, quality, EDGE_RULES[edges], threads, single)
    rs._mesh, rs.build_stats = build_mesh(v, f, n, quality, EDGE_RULES[edges], threads, single)
    rs.build_stats["query_compile_seconds"] = ahead
    rs.build_stats["aggregates"] = [dict(rs.build_stats, kind="bvh", spec=QUALITY[quality])]
    rs.geometries = [{"kind": "triangle", "count": len(f)}]
    rs._geom_of = {TRIANGLE: (np.array([0]), np.array([0]))}
    rs._may_repeat = edges == "inclusive"
    rs._lazy = None
    return rs


def mesh_precision(accel: str | None, precision: str | None) -> tuple[str | None, str]:
    """(the accel spec without a precision, the mesh's precision) from from_mesh's arguments: the
    precision argument, else the bvh spec's `precision=` (the two must agree where both are
    given), else double."""
    if precision is not None and precision not in PRECISIONS:
        raise RayInputError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    if not isinstance(accel, str) or not re.search(r"\bprecision\s*=", accel):
        return accel, precision or "double"
    name, params = parse_spec(accel)
    if precision is not None and params["precision"] != precision:
        raise RayInputError(f"precision={precision!r} and accel {accel!r} disagree: give the precision once")
    return format_spec(name, dict(params, precision="double")), params["precision"]


def single_vertices(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """The vertices of a mesh of precision "single": each coordinate rounded to the nearest float32
    number (held in float64, so every query reads the same numbers the float32 blocks hold). A
    RayInputError where the rounding makes two different corners of a triangle one point: the
    triangle is smaller than float32 resolves where it lies."""
    r = v.astype(np.float32).astype(np.float64)
    t, a, b = _first_collapsed(v, r, f)
    if t >= 0:
        size = float(np.max(np.abs(v[a] - v[b])))
        where = float(np.max(np.abs(v[a])))
        raise RayInputError(f"precision='single': triangle {t} is smaller than float32 resolves where it lies "
                            f"(corners {size:.3g} apart at {where:.3g} from the origin round to one point); "
                            f"use precision='double'")
    return r


@njit
def _first_collapsed(v, r, f):
    """(triangle, corner, corner): the first triangle of f with two different corners in v that are
    one point in r, and those corners; (-1, -1, -1) if none."""
    for t in range(f.shape[0]):
        for e in range(3):
            a, b = f[t, e], f[t, (e + 1) % 3]
            if (r[a, 0] == r[b, 0] and r[a, 1] == r[b, 1] and r[a, 2] == r[b, 2]
                    and (v[a, 0] != v[b, 0] or v[a, 1] != v[b, 1] or v[a, 2] != v[b, 2])):
                return t, a, b
    return -1, -1, -1


def from_spheres(cls, centers, radii, accel: str = "bvh"):
    """RayScene.from_spheres: a RayScene of spheres."""
    c = real_array(centers, "centers")
    if c.ndim == 1 and c.shape[0] == 3:
        c = c[None, :]
    if c.ndim != 2 or c.shape[1] != 3:
        raise RayInputError(f"centers must have shape (N, 3), got {c.shape}")
    r = real_array(radii, "radii")
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

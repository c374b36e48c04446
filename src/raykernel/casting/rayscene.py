"""Ray casting against your own geometry: numpy arrays in, numpy arrays out.

    scene = RayScene.from_mesh(vertices, faces)          # built once
    hits = scene.intersect(origins, directions)          # closest hits: hits.t, hits.prim_id, hits.normal ...
    blocked = scene.occluded(origins, directions, tmax=1.0)
    ray, t, prim = scene.intersect_all(origins, directions)
    hits = scene.intersect(origins, directions, fields=("t", "prim_id"), dtype="float32")   # only what you need
    scene.intersect(origins, directions, fields=("t", "prim_id"), dtype="float32", out=hits)   # into those arrays
    hits = scene.intersect(da_origins, da_directions)    # dask arrays in: a Hits of dask arrays, cast chunk by chunk

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

The class holds the API and the state every query reads; the code it runs
lives by concern: building (raybuild.py, meshes straight into meshbuild.py's
arrays), ray queries and their kernel (rayqueries.py, the mesh kernel in
meshcast.py), point queries (proximity.py, winding.py, occupancy.py), the
checks of what users pass in (rayinput.py: RayInputError), and the same
queries on dask arrays (daskcast.py, reached only when an argument is one).
"""

from __future__ import annotations

import threading

import numpy as np

from ..engine.flatten import flatten
from ..geometry.primitives import CONE, PATCH, POLYGON, SPHERE, TRIANGLE
from ..scene.model import Scene
from . import daskcast, proximity, raybuild, rayqueries
from .proximity import ClosestPoints
from .raybuild import EDGE_RULES
from .rayinput import RayInputError
from .rayqueries import Hits

__all__ = ["Hits", "RayInputError", "RayScene"]


# the parts of the ray queries' docstrings they share (_ray_query_doc puts them in)
_RAYS_DOC = """origins, directions : (N, 3) array_like
            The rays: (N, 3), (H, W, 3) for an image of rays (camera_rays), or one (3,) ray
            broadcast against the other argument; any real dtype, read as float64. Directions
            need not be unit length: t is measured in units of the direction given. Dask arrays
            (with tmin and tmax numbers, or arrays of the rays' shape) give dask arrays of the
            same answers, cast a chunk a task when computed (daskcast.py).
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

    The queries but intersect_all also take dask arrays and answer with dask arrays, lazily
    (daskcast.py).

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
        raybuild.build(self, scene, accel, max_memory, edges)

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
                     max_memory=None, precision: str | None = None) -> "RayScene":
        """A RayScene of a trimesh.Trimesh, or of any object with ``.vertices`` and ``.faces``.

        Parameters
        ----------
        mesh : trimesh.Trimesh or object
            ``mesh.vertices``: (V, 3) real array; ``mesh.faces``: (F, 3) integer array.
        accel, edges, quality, max_memory, precision
            As for `from_mesh`.

        Returns
        -------
        RayScene

        Raises
        ------
        RayInputError
            `mesh` has no ``.vertices`` and ``.faces``, or they are not valid.
        """
        return raybuild.from_trimesh(cls, mesh, accel, edges, quality, max_memory, precision)

    @classmethod
    def from_file(cls, path, accel: str | None = None, edges: str = "watertight", quality: str = "medium",
                  max_memory=None, precision: str | None = None) -> "RayScene":
        """A RayScene of the triangles of a model file, every mesh of it in one.

        Parameters
        ----------
        path : str or path-like
            An OBJ, PLY, STL, OFF, glTF or GLB file, read by trimesh (the ``mesh`` extra); its
            meshes are placed by the file's transforms (scene/meshfile.py).
        accel, edges, quality, max_memory, precision
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
        return raybuild.from_file(cls, path, accel, edges, quality, max_memory, precision)

    @classmethod
    def from_mesh(cls, vertices, faces=None, normals=None, accel: str | None = None, edges: str = "watertight",
                  quality: str = "medium", max_memory=None, threads: int | None = None,
                  precision: str | None = None) -> "RayScene":
        """A RayScene of a triangle mesh.

        Unless `accel` is given (or there are no faces), the tree is built straight into the
        mesh kernel's arrays: the triangles' corners once, in float64 blocks of four (float32
        with ``precision="single"``), the 4-wide nodes and a triangle index a lane
        (``stats["bytes_per_triangle"]``); float64 vertices and int64 faces are read, not
        copied (``precision="single"`` keeps a rounded copy of the vertices).

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
        precision : {"double", "single"}, optional
            Default: the precision `accel` names (``"bvh(precision=single)"``), else
            ``"double"``, which keeps the vertices as given. ``"single"`` rounds each
            coordinate to the nearest float32 number, as Embree stores a mesh, and stores the
            triangle blocks in float32: about 40% fewer bytes a triangle. Every answer is then
            exact for the rounded mesh (the same watertight test, in float64, on the rounded
            corners), so it equals ``precision="double"`` on
            ``vertices.astype(np.float32)``, bit for bit.

        Returns
        -------
        RayScene

        Raises
        ------
        RayInputError
            The arrays do not have these shapes and types, vertices or normals are not finite,
            a face refers to a vertex that does not exist, `quality` or `precision` is not one
            of its values or disagrees with the precision `accel` names, or with ``precision="single"`` a triangle's corners round to one
            point (a triangle smaller than float32 resolves where it lies).
        MemoryBudgetError
            The build would need more than `max_memory`.
        """
        return raybuild.from_mesh(cls, vertices, faces, normals, accel, edges, quality, max_memory, threads, precision)

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
        return raybuild.from_spheres(cls, centers, radii, accel)

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

    # ------------------------------------------------------------- ray queries (rayqueries.py)

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
        if daskcast.is_dask(origins, directions, tmin, tmax):
            return daskcast.intersect(self, origins, directions, tmin, tmax, threads, fields, dtype, out)
        return rayqueries.closest_hits(self, origins, directions, tmin, tmax, threads, fields, dtype, out)

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
        if daskcast.is_dask(origins, directions, tmin, tmax):
            return daskcast.ray_query(self, "occluded", origins, directions, tmin, tmax, bool, threads=threads)
        return rayqueries.occluded(self, origins, directions, tmin, tmax, threads)

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
        if daskcast.is_dask(origins, directions, tmin, tmax):
            raise RayInputError("intersect_all takes numpy arrays: its hits are not shaped as the rays (count_hits "
                                "takes dask arrays)")
        return rayqueries.intersect_all(self, origins, directions, tmin, tmax, ids, threads)

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
        if daskcast.is_dask(origins, directions, tmin, tmax):
            return daskcast.ray_query(self, "count_hits", origins, directions, tmin, tmax, np.int64, threads=threads)
        return rayqueries.count_hits(self, origins, directions, tmin, tmax, threads)

    # ------------------------------------------------------------- point queries (proximity.py)

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
        if daskcast.is_dask(points):
            return daskcast.closest_points(self, points, threads)
        return proximity.closest_points(self, points, threads)

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
        if daskcast.is_dask(points):
            return daskcast.point_query(self, "distance", points, np.float64, threads=threads)
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
        if daskcast.is_dask(points):
            return daskcast.point_query(self, "contains", points, bool, threads=threads, method=method)
        return proximity.contains(self, points, threads, method)

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

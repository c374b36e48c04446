"""raykernel under trimesh: a drop-in for trimesh's ray intersectors.

    import trimesh, raykernel.trimesh
    mesh = trimesh.creation.icosphere()
    mesh.ray = raykernel.trimesh.RayMeshIntersector(mesh)
    index_tri, index_ray, locations = mesh.ray.intersects_id(origins, directions, return_locations=True)
    mesh.contains(points)          # trimesh's own queries now cast with raykernel

The methods and their answers are those of trimesh's `RayMeshIntersector`
(trimesh.ray.ray_triangle and ray_pyembree): `intersects_id`,
`intersects_location`, `intersects_first`, `intersects_any` and
`contains_points`, with both classes' arguments: the mesh as `geometry` (ray_pyembree)
or `mesh` (ray_triangle), `scale_to_box` (ray_pyembree's float32 rescaling, which
double precision does not need: accepted and kept, changing nothing), and the extra
keywords trimesh's methods pass on to `intersects_id` (`max_hits`). Hits are exact, in double precision. By default edges
are inclusive, as in trimesh's engines: a ray grazing a silhouette edge or
running in the plane of a face hits the edge, and a ray through an edge or
vertex is reported once, by the lowest-numbered triangle there
(`edges="watertight"`: the one triangle the watertight rule gives it); every
triangle along a ray once (Embree's engine in trimesh
offsets each ray past a hit and tests again, which can miss a second hit
closer than the offset, or report one point twice). With multiple hits the
rows come ray by ray, nearest first. The built RayScene is cached with
trimesh's cache, keyed on the mesh's hash: it is rebuilt when the mesh
changes. Pickling and copying keep the mesh and the accelerator, not the
built scene.
"""

from __future__ import annotations

import numpy as np

from ..errors import RayKernelError
from .rayscene import RayScene


class RayMeshIntersector:
    """Ray queries on a trimesh.Trimesh, answered by raykernel: a drop-in for trimesh's intersectors.

    The methods and their answers are those of trimesh's ``RayMeshIntersector``
    (``trimesh.ray.ray_triangle`` and ``ray_pyembree``), with both classes' arguments, and the
    extra keywords trimesh's methods pass on to `intersects_id` (`max_hits`). Hits are exact,
    in double precision. By default edges are inclusive, as in trimesh's engines: a ray grazing
    a silhouette edge or running in the plane of a face hits the edge, and a ray through an
    edge or vertex is reported once, by the lowest-numbered triangle there. Every triangle
    along a ray is reported once (Embree's engine in trimesh offsets each ray past a hit and
    tests again, which can miss a second hit closer than the offset, or report one point
    twice). With multiple hits the rows come ray by ray, nearest first.

    The built RayScene is cached with trimesh's cache, keyed on the mesh's hash: it is rebuilt
    when the mesh changes. Pickling and copying keep the mesh and the accelerator, not the
    built scene.

    Parameters
    ----------
    geometry : trimesh.Trimesh
        The mesh (ray_pyembree's name for it); give it as `geometry` or as `mesh`, not both.
    scale_to_box : bool, default True
        ray_pyembree's float32 rescaling, which double precision does not need: accepted and
        kept, changing nothing.
    accel : str, optional
        An accelerator spec for the mesh's RayScene (default: `RayScene.from_mesh`'s own tree).
    edges : {"inclusive", "watertight"}
        ``"inclusive"`` as trimesh's engines (above); ``"watertight"``: a ray through an edge or
        vertex hits the one triangle the watertight rule gives it.
    mesh : trimesh.Trimesh
        The mesh (ray_triangle's name for it), keyword only.

    Raises
    ------
    RayKernelError
        trimesh is not installed.
    TypeError
        Neither or both of `geometry` and `mesh` are given.

    Examples
    --------
    >>> import trimesh, raykernel.trimesh
    >>> mesh = trimesh.creation.icosphere()
    >>> mesh.ray = raykernel.trimesh.RayMeshIntersector(mesh)
    >>> index_tri, index_ray, locations = mesh.ray.intersects_id(origins, directions, return_locations=True)
    >>> mesh.contains(points)          # trimesh's own queries now cast with raykernel
    """

    def __init__(self, geometry=None, scale_to_box: bool = True, accel: str | None = None, edges: str = "inclusive",
                 *, mesh=None):
        try:
            from trimesh import caching
        except ImportError:
            raise RayKernelError("raykernel.trimesh needs trimesh: pip install raykernel[mesh]") from None
        if (geometry is None) == (mesh is None):
            raise TypeError("RayMeshIntersector needs the mesh, as geometry or as mesh (one of them)")
        self.mesh = geometry if mesh is None else mesh
        self.scale_to_box = scale_to_box
        self.accel = accel
        self.edges = edges      # inclusive, as trimesh's engines: a ray grazing an edge hits it
        self._cache = caching.Cache(id_function=self.mesh.__hash__)

    @property
    def scene(self) -> RayScene:
        """The RayScene of the mesh as it is now (built on first use, again after a change)."""
        scene = self._cache["scene"]      # None when absent, or when the mesh changed since
        if scene is None:
            scene = RayScene.from_mesh(np.asarray(self.mesh.vertices), np.asarray(self.mesh.faces), accel=self.accel,
                                       edges=self.edges)
            self._cache["scene"] = scene
        return scene

    @staticmethod
    def _rays(ray_origins, ray_directions):
        o = np.asarray(ray_origins, np.float64)
        d = np.asarray(ray_directions, np.float64)
        if o.shape != d.shape:
            raise ValueError("Ray origin and direction don't match!")
        return o.reshape(-1, 3), d.reshape(-1, 3)

    def intersects_id(self, ray_origins, ray_directions, multiple_hits: bool = True, max_hits: int = 100,
                      return_locations: bool = False, **kwargs):
        """Triangles hit by each ray.

        Parameters
        ----------
        ray_origins, ray_directions : (n, 3) array_like
            The rays, of the same shape; directions need not be unit length.
        multiple_hits : bool, default True
            Every hit along each ray, nearest first; False: the first hit of each ray.
        max_hits : int or None, default 100
            With `multiple_hits`, the most hits of a ray; None: all.
        return_locations : bool, default False
            Return the hit points too.
        **kwargs
            Accepted and ignored, as trimesh's engines do.

        Returns
        -------
        index_tri : (k,) int64 array
            The triangle of each hit.
        index_ray : (k,) int64 array
            The ray of each hit; the rows come ray by ray.
        locations : (k, 3) float64 array
            With `return_locations` only: the hit points.

        Raises
        ------
        ValueError
            The origins and directions differ in shape.
        RayInputError
            A ray is not finite or has a zero direction.
        """
        o, d = self._rays(ray_origins, ray_directions)
        if len(o) == 0:
            empty = np.zeros(0, np.int64)
            return (empty, empty, np.zeros((0, 3))) if return_locations else (empty, empty)
        if multiple_hits:
            ray, t, tri = self.scene.intersect_all(o, d)      # sorted by ray, then t
            if max_hits is not None:
                first = np.searchsorted(ray, ray)             # each ray's first row
                keep = np.arange(len(ray)) - first < max_hits
                ray, t, tri = ray[keep], t[keep], tri[keep]
        else:
            hits = self.scene.intersect(o, d, fields=("t", "prim_id"))
            ray = np.flatnonzero(np.isfinite(hits.t))
            t, tri = hits.t[ray], hits.prim_id[ray]
        if return_locations:
            return tri, ray, o[ray] + t[:, None] * d[ray]
        return tri, ray

    def intersects_location(self, ray_origins, ray_directions, multiple_hits: bool = True, **kwargs):
        """The hits' points, rays and triangles, as `intersects_id`.

        Parameters
        ----------
        ray_origins, ray_directions : (n, 3) array_like
            The rays, of the same shape; directions need not be unit length.
        multiple_hits : bool, default True
            Every hit along each ray, nearest first; False: the first hit of each ray.
        **kwargs
            Passed to `intersects_id` (its `max_hits`).

        Returns
        -------
        locations : (k, 3) float64 array
            The hit points.
        index_ray : (k,) int64 array
            The ray of each hit.
        index_tri : (k,) int64 array
            The triangle of each hit.
        """
        tri, ray, locations = self.intersects_id(ray_origins, ray_directions, multiple_hits=multiple_hits,
                                                 return_locations=True, **kwargs)
        return locations, ray, tri

    def intersects_first(self, ray_origins, ray_directions, **kwargs) -> np.ndarray:
        """The first triangle each ray hits, -1 where it hits none.

        Parameters
        ----------
        ray_origins, ray_directions : (n, 3) array_like
            The rays, of the same shape; directions need not be unit length.
        **kwargs
            Accepted as trimesh's ray_triangle does, changing nothing.

        Returns
        -------
        (n,) int64 array
        """
        o, d = self._rays(ray_origins, ray_directions)
        if len(o) == 0:
            return np.zeros(0, np.int64)
        return self.scene.intersect(o, d, fields="prim_id").prim_id

    def intersects_any(self, ray_origins, ray_directions, **kwargs) -> np.ndarray:
        """True where the ray hits the mesh at all.

        Parameters
        ----------
        ray_origins, ray_directions : (n, 3) array_like
            The rays, of the same shape; directions need not be unit length.
        **kwargs
            Accepted as trimesh's ray_triangle does, changing nothing.

        Returns
        -------
        (n,) bool array
        """
        o, d = self._rays(ray_origins, ray_directions)
        if len(o) == 0:
            return np.zeros(0, bool)
        return self.scene.occluded(o, d)

    def contains_points(self, points) -> np.ndarray:
        """Inside tests for a closed mesh, by trimesh's own ray-parity rule over these queries.

        Parameters
        ----------
        points : (n, 3) array_like
            The query points.

        Returns
        -------
        (n,) bool array
            True where a point lies inside the mesh.
        """
        from trimesh.ray.ray_util import contains_points
        return contains_points(self, points)

    def __getstate__(self):
        state = self.__dict__.copy()
        state.pop("_cache", None)
        return state

    def __setstate__(self, state):
        from trimesh import caching
        self.__dict__.update(state)
        self._cache = caching.Cache(id_function=self.mesh.__hash__)

    def __copy__(self):
        return RayMeshIntersector(self.mesh, self.scale_to_box, accel=self.accel, edges=self.edges)

    def __deepcopy__(self, memo):
        return self.__copy__()

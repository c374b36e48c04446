"""A first mesh query's two compiles side by side: the query kernel here, the builder in a helper.

    took = compile_query_ahead(v, f, normals, quality, edges, threads, single)   # raybuild.from_mesh, first

RayScene.from_mesh builds the mesh's tree (the builder's kernels compile on first use), then
the first query compiles the mesh kernel. When that kernel is in neither this process nor the
kernel cache, a helper process builds a small mesh of the same kind (geometry/ahead.py: the
builder's kernels compile into the cache) while this process compiles the kernel of a query
without surface fields, which holds the 4-wide walk every query shares (t, ids, occluded),
against a stand-in: the mesh's own arrays and an empty tree of the real tree's types
(`stand_in`). The real build then loads the builder's kernels; a later query of the surface
fields compiles its surface pass and its own kernel, not the walk.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from ..aggregates.widebvh import WideBVH
from ..geometry.ahead import beside, enabled
from ..geometry.compiletime import CompileClock
from ..geometry.config import cached, compiled
from . import meshcast, rayqueries
from .meshbuild import mesh_arrays
from .meshcast import NO_BLOCKS, NO_CORNERS, MeshKernel

# the helper's mesh: an octahedron, every coordinate a float32 number (a single-precision mesh's too)
SMALL_VERTICES = np.array([[1.0, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]])
SMALL_FACES = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])


def stand_in(verts, faces, normals, edges: int, single: bool) -> MeshKernel:
    """The mesh kernel's arguments for this mesh with an empty 4-wide tree (one node, no block):
    the real build's types, for a call that casts nothing."""
    return MeshKernel(mesh_arrays(verts, faces, normals, edges, np.zeros(6)), NO_CORNERS, np.zeros(0, np.int32),
                      np.array([0, len(faces)], np.int64), 0, WideBVH(np.zeros((1, 32), np.int32), np.zeros(3)),
                      NO_BLOCKS.astype(np.float32 if single else np.float64))


def compile_query_ahead(verts, faces, normals, quality: str, edges: int, threads, single: bool) -> float:
    """Compile the mesh kernel of a query without surface fields for this mesh against the
    stand-in while a helper builds the small mesh with the same quality, edge rule and
    precision; the seconds spent compiling here (0.0 where nothing was done: the kernel
    compiled or cached already, or compiling ahead off)."""
    if compiled(meshcast.query) or cached(meshcast.query) or not enabled():
        return 0.0
    small_normals = None if normals is None else SMALL_VERTICES.copy()
    small = (SMALL_VERTICES.copy(), SMALL_FACES.copy(), small_normals, quality, edges, threads, single)
    with CompileClock() as clock:
        beside(("raykernel.casting.meshbuild", "build_mesh", small),
               lambda: rayqueries.compile_query(SimpleNamespace(_mesh=stand_in(verts, faces, normals, edges, single),
                                                                _lazy=None)))
    return clock.seconds

"""A triangle mesh's 4-wide BVH built straight from its arrays, for RayScene.from_mesh.

    mesh, stats = build_mesh(vertices, faces, normals=None, quality="medium", edges=WATERTIGHT, single=False)
    # mesh: a meshcast.MeshKernel; stats: seconds, bytes, bytes_per_triangle, sah_cost, nodes, ...

Why: a scene's general build (engine/flatten.py) copies the triangles into
the Geometry every aggregate kind can walk (vertices, faces, per-reference
records for the render's fast walk, the binary tree) before the mesh kernel
takes its own blocks from it: several times the memory the kernel needs,
and most of a build's time. Here the kernel's arrays are made from the user's vertex and
face arrays alone, which it reads but does not copy:

* the tree over the triangles' boxes, built on every core (bvhbuild.py's binned
  SAH, or its Morton-order build);
* the tree collapsed 4-wide, its boxes widened by the culling margin a
  scene's BVH gets (boxes.cull_margin) and rounded outwards to float32
  (widebvh.py, 128 bytes a node), its leaves' triangles in float64 blocks of four
  (triangles4.py, 288 bytes a block, and 4 bytes a lane naming the triangle), or
  float32 blocks (144 bytes) for a mesh of precision "single", whose corners are
  float32 numbers (raybuild.py rounds them);
* a bool a triangle (smooth shading where vertex normals are given).

The binary tree and the build's temporaries are dropped once the wide tree
is made. The build qualities, as Embree's, and the bvh spec that builds the
same tree (QUALITY): "fast" splits by Morton order, "medium" (the default)
is the binned SAH that prices leaves in blocks of four, "high" then reinserts
nodes where that lowers the SAH cost (bvhopt.py: fewer node visits a ray,
for many rays; split clipping, tried too, cast slower in the 4-wide kernel).
"""

from __future__ import annotations

import sys
import threading
import time

import numpy as np

from ..aggregates.bvhbuild import ROW_COLUMNS, WEIGHT, build_rows
from ..aggregates.bvhopt import optimize
from ..aggregates.bvhtree import BVHArrays
from ..aggregates.walk import MAX_TREE_DEPTH
from ..aggregates.widebvh import collapse
from ..engine.flatten import check_range
from ..geometry.parallel import for_ranges, interrupted
from ..geometry.boxes import cull_margin
from ..geometry.boxrows import HI
from ..geometry.compiletime import CompileClock, compile_notice
from ..geometry.config import njit
from ..geometry.primitives import MAX_COORDINATE, MIN_SIZE
from .meshcast import NO_CORNERS, MeshArrays, MeshKernel, wide_leaves

QUALITY = {"fast": "bvh(block=4, build=morton)", "medium": "bvh(block=4)",
           "high": "bvh(block=4, optimize=reinsertion)"}      # each level's tree as a spec
LEAF, BINS, BLOCK = 4, 16, 4      # bvh(block=4)'s leaves, bins and pricing
PROGRESS_TRIANGLES = 1 << 19     # builds from which a line says what is being built, if it takes a second
# the build's peak a triangle: its rows (64 bytes), order (8), the binary nodes (64 each, up to
# two a triangle and the parallel build's top), and the kernel's arrays it makes (blocks, nodes, lanes)
BUILD_BYTES = 324
_COMPILING = "raykernel: compiling the mesh builder (first use after install, a few seconds)"


@njit
def _triangle_data(verts, faces, data, i0, i1):
    """bvhbuild.build_rows' rows for triangles i0..i1-1: box and weight 1, as boxrows.py lays them out.
    Returns the first of these rows whose box leaves +-MAX_COORDINATE or is smaller than MIN_SIZE
    but not zero (flatten.check_range's rule), or -1: checked as the rows are made, on the threads."""
    bad = -1
    for i in range(i0, i1):
        a, b, c = faces[i, 0], faces[i, 1], faces[i, 2]
        size = 0.0
        for k in range(3):
            lo = min(verts[a, k], min(verts[b, k], verts[c, k]))
            hi = max(verts[a, k], max(verts[b, k], verts[c, k]))
            data[i, k] = lo
            data[i, k + HI] = hi
            if not (abs(lo) <= MAX_COORDINATE and abs(hi) <= MAX_COORDINATE):
                size = -1.0         # out of range (or not a number): bad whatever the other axes
            elif size >= 0.0:
                size = max(size, hi - lo)
        data[i, WEIGHT] = 1.0
        data[i, ROW_COLUMNS - 1] = 0.0
        if bad < 0 and (size < 0.0 or (size != 0.0 and size < MIN_SIZE)):
            bad = i
    return bad


def build_mesh(verts: np.ndarray, faces: np.ndarray, normals: np.ndarray | None, quality: str, edges: int,
               threads: int | None = None, single: bool = False) -> tuple[MeshKernel, dict]:
    """The mesh kernel's arrays for one mesh: verts (V, 3) float64 and faces (F, 3) int64, both
    C-contiguous and checked, normals (V, 3) float64 or None; quality one of QUALITY; single:
    every vertex coordinate is a float32 number, and the blocks are stored in float32."""
    t0 = time.perf_counter()
    n = len(faces)
    # a line for big builds that take more than a second, and their time at the end (not for a
    # small one that waits for its kernels to compile: the compile notice says so)
    slow = threading.Timer(1.0, lambda: print(f"raykernel: building the BVH of {n:,} triangles ({quality} quality) ...",
                                              file=sys.stderr, flush=True))
    slow.daemon = True
    if n >= PROGRESS_TRIANGLES:
        slow.start()
    try:
        mesh, stats = _build_mesh(verts, faces, normals, quality, edges, threads, n, t0, single)
    except SystemError as e:        # Ctrl-C met while numba was loading a kernel: wrapped, said as it is
        if interrupted(e):
            raise KeyboardInterrupt from None
        raise
    finally:
        slow.cancel()
    if n >= PROGRESS_TRIANGLES and stats["seconds"] > 1.0:
        print(f"raykernel: built in {stats['seconds']:.1f} s, {stats['bytes_per_triangle']:.0f} bytes a triangle",
              file=sys.stderr, flush=True)
    return mesh, stats


def mesh_arrays(verts, faces, normals, edges: int, box: np.ndarray) -> MeshArrays:
    """What the mesh kernel reads of the mesh beside its tree: the vertices and faces as given,
    the edge rule, smooth shading where normals are given, and `box` (6,), the culling box."""
    n = len(faces)
    smooth = normals is not None
    return MeshArrays(agg_bounds=box.reshape(1, 6), root=0, tri_edges=np.array([edges], np.int64), tri_verts=verts,
                      tri_faces=faces, tri_smooth=np.ones(n if smooth else 0, np.bool_),
                      tri_mat=np.zeros(n if smooth else 0, np.int32),
                      tri_vnormals=normals if smooth else np.zeros((0, 3)), node_bounds=np.zeros((0, 6)),
                      node_first=np.zeros(0, np.int64), node_count=np.zeros(0, np.int64))


def _build_mesh(verts, faces, normals, quality, edges, threads, n, t0, single):
    with CompileClock(notice=compile_notice("meshbuild", _COMPILING), after=0.0):
        data = np.empty((n, ROW_COLUMNS))
        found = []
        for_ranges(lambda i0, i1: found.append(_triangle_data(verts, faces, data, np.int64(i0), np.int64(i1))), n,
                   threads, kernel=_triangle_data, min_size=1 << 14)
        bad = min((i for i in found if i >= 0), default=-1)
        if bad >= 0:        # the scene's error for it
            box = np.c_[data[bad:bad + 1, :3], data[bad:bad + 1, HI:HI + 3]]
            with np.errstate(over="ignore", invalid="ignore"):
                check_range("triangle", box, bad, np.max(box[:, 3:] - box[:, :3], axis=1))
        method = "morton" if quality == "fast" else "sah"
        # the tree is read from its root on (collapse), so the parallel build's gaps may stay, but
        # reinsertion takes the nodes as an array
        bounds, first, count, order, n_nodes, depth = build_rows(data, method, LEAF, BINS, 1.0, 1.0, BLOCK, threads,
                                                                 compact=quality == "high")
        data = None     # (its memory back before the wide tree is made)
        bounds, first, count = bounds[:n_nodes], first[:n_nodes], count[:n_nodes]
        if quality == "high" and n:       # fewer node visits for many rays: bvhopt's reinsertion
            tree, info = optimize(BVHArrays(bounds, first, count, order), "reinsertion")
            if info["max_depth"] <= MAX_TREE_DEPTH:         # the kernel's stack holds that much
                bounds, first, count, order = tree
                n_nodes, depth = len(count), info["max_depth"]
        box = bounds[0].copy()
        margin = cull_margin(box) if n else 0.0
        # boxes widened by the culling margin a scene's BVH gets (as append_bvh does)
        wide, cost = collapse(bounds, first, count, 0, margin)
        cost = cost if n else 0.0
        del bounds, first, count
        wide, blocks, lanes = wide_leaves(wide, verts, faces, order, threads, np.float32 if single else np.float64)
    del order
    arrays = mesh_arrays(verts, faces, normals, edges, np.r_[box[:3] - margin, box[3:] + margin])
    mesh = MeshKernel(arrays, NO_CORNERS, lanes, np.array([0, n], np.int64), 0, wide, blocks)
    seconds = time.perf_counter() - t0
    stats = {"quality": quality, "precision": "single" if single else "double", "triangles": n, "seconds": seconds, "wide_nodes": len(wide.nodes),
             "lanes": len(lanes), "max_depth": int(depth), "sah_cost": float(cost), "bytes": mesh.nbytes,
             "bytes_per_triangle": mesh.nbytes / max(n, 1)}
    return mesh, stats

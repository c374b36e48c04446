"""The binary BVH, the kind the aggregates registry lists as bvh: its spec, its flat layout and its walk.

    from raykernel.aggregates import bvh
    agg, stats = bvh.flatten(builder, params, refs, bounds, name, box)   # KIND.flatten: build, store
    bvh.KIND, bvh.WALK          # the kind and its walk (code bvhwalk.CODE), as registry.MODULES lists them
    cost = bvh.sah_cost(geo.node_bounds, geo.node_first, geo.node_count, start, count)

The tree is built by bvhbuild.py (binned SAH or Morton order) or gsbvh.py (build=gs), laid
out as bvhtree.py describes, optionally built over pieces (presplit.py) and optimised
(bvhopt.py); it is walked by bvhwalk.py's kernels (binary) or collapsed 4-wide (widebvh.py).

Flat layout (the Geometry fields it owns)
-----------------------------------------
N nodes of all BVHs:
  node_bounds  (N, 6) float64  node box, widened by flatten's culling margin   48 B a node
  node_first   (N,)   int64    inner: left child (right = left + 1, global); leaf: first ref   8 B
  node_count   (N,)   int64    0 for an inner node, else refs in the leaf       8 B
The aggregate's agg_start is its root node. Every stack entry of a BVH is a
node to visit (step START), entered at stack_t.
"""

from __future__ import annotations

import numpy as np

from ..errors import OptionError, SceneError
from ..geometry.boxes import cull_margin
from ..geometry.primitives import PRIMITIVE_KINDS
from .bvhbuild import build_bvh, refit_moved
from .bvhtree import BVHArrays
from . import widewalk
from .bvhwalk import CODE, walk_step
from .spec import Kind, Param, Search
from .walk import MAX_TREE_DEPTH, Cells, Field, Walk

PRECISIONS = ("double", "single")     # of a mesh's triangles in RayScene's mesh kernel (casting/raybuild.py)

# corners a polygon's inside test walks in the time of one whole primitive test (a corner
# walked costs a fraction of a whole test; the cost model's calibration measures both:
# polygon.corner and test.*)
CORNERS_PER_TEST = 8


# ----------------------------------------------------------------- flat layout (see the module docstring) and walk


FIELDS = (Field("node_bounds", np.float64, (6,)), Field("node_first", np.int64, ()),
          Field("node_count", np.int64, ()))


def append_bvh(flat, tree: BVHArrays, refs, box, margin: float) -> int:
    """Store a built BVH over refs as the next aggregate; its node boxes grow by `margin`."""
    first_node = flat.size("node_count")
    first_ref = flat.add_refs(refs[tree.order])
    inner = tree.count == 0
    bounds = tree.bounds.copy()
    bounds[:, :3] -= margin
    bounds[:, 3:] += margin
    flat.append(node_bounds=bounds, node_first=np.where(inner, tree.first + first_node, tree.first + first_ref),
                node_count=tree.count)
    return flat.add_aggregate(CODE, first_node, len(tree.count), box)


def walked_wide(stats) -> bool:
    """Whether a render's rays took the 4-wide walk (aggregates/widewalk.py): its scene was one BVH of
    width 4 over primitives, and its closest-hit searches were lazy about normals (with eager
    normals they take the general walk)."""
    aggregates = getattr(stats, "aggregates", [])
    tricks = getattr(stats, "info", {}).get("tricks", ["lazynormals"])
    return len(aggregates) == 1 and aggregates[0].get("wide_nodes", 0) > 0 and "lazynormals" in tricks


def features(stats, f, used) -> None:
    """The cost model's features of a render walked 4-wide (walked_wide): its node visits and
    tests cost what the general walk's do not (a polygon test much less, its
    primitives' numbers read in leaf order), so its walk is priced as `wide` and its tests,
    hits and corners as test.KIND.wide, hit.KIND.wide and polygon.corner.wide; the eye rays of
    culled tiles, counted as one bound test each, are priced as ray.culled."""
    if not walked_wide(stats):
        return
    for k in PRIMITIVE_KINDS:
        f[f"test.{k}.wide"] = f.pop(f"test.{k}")
        f[f"hit.{k}.wide"] = f.pop(f"hit.{k}")
    f["polygon.corner.wide"] = f.pop("polygon.corner")
    for what in ("entry", "step", "bound"):
        f[f"{what}.wide"] = f.pop(f"{what}.bvh")
    f["bound.wide"] -= f["ray.culled"]


def _areas(b: np.ndarray) -> np.ndarray:
    d = np.maximum(b[:, 3:] - b[:, :3], 0.0)
    return d[:, 0] * d[:, 1] + d[:, 1] * d[:, 2] + d[:, 2] * d[:, 0]


def sah_cost(node_bounds, node_first, node_count, start: int, count: int) -> float:
    """The SAH cost of the BVH in nodes start..start+count-1 (traversal and intersection cost 1):
    sum of inner node areas plus leaf areas times their items, over the root's area."""
    b = node_bounds[start:start + count]
    n = node_count[start:start + count]
    area = _areas(b)
    root = area[0] if area[0] > 0 else 1.0
    return float((np.sum(area[n == 0]) + np.sum(area[n > 0] * n[n > 0])) / root)


def refit_aggregate(flat, agg, memo, refs, old_bounds, bounds, params, threshold):
    """Kind.refit: the BVH agg keeps its tree, the boxes of the nodes above the items that moved
    recomputed from the leaves up; returns the nodes touched, or None (rebuild it) for a tree
    over pieces (split > 1: an item in several leaves) or when its SAH cost grew past
    `threshold` times its cost when built (the refit nodes are then left unused). memo keeps,
    from the first refit on, how the tree placed the items, its cost and its culling margin."""
    if params.get("split", 1) > 1:
        return None
    nb, nf, nc = (flat.parts[n][0] for n in ("node_bounds", "node_first", "node_count"))
    s = int(flat.parts["agg_start"][0][agg])
    n = int(flat.parts["agg_count"][0][agg])
    first, count = nf[s:s + n], nc[s:s + n]
    inner = count == 0
    if not memo:        # first refit since the build
        memo["first_ref"] = int(first[~inner].min())
        placed = flat.parts["refs"][0][memo["first_ref"]:memo["first_ref"] + len(refs)]
        by_ref = np.argsort(refs, kind="stable")
        memo["order"] = by_ref[np.searchsorted(refs[by_ref], placed)]
        memo["cost"] = sah_cost(nb, nf, nc, s, n)
        memo["cost_sum"] = memo["cost"] * _areas(nb[s:s + 1])[0]
        memo["margin"] = cull_margin(flat.agg_box(agg))
    moved = np.any(old_bounds != bounds, axis=1)[memo["order"]]
    box = np.concatenate([bounds[:, :3].min(axis=0), bounds[:, 3:].max(axis=0)])
    m = cull_margin(box)
    if m > memo["margin"]:      # a wider box needs a wider margin everywhere: refit every node
        moved[:] = True
        memo["margin"] = m
    local_first = np.where(inner, first - s, first - memo["first_ref"])
    view = nb[s:s + n]
    touched, grown = refit_moved(view, local_first, count, memo["order"], np.ascontiguousarray(bounds, np.float64),
                                 moved, memo["margin"])
    memo["cost_sum"] += grown
    root = _areas(view[:1])[0]
    if memo["cost_sum"] / (root if root > 0 else 1.0) > threshold * memo["cost"]:
        memo.clear()
        return None
    return int(touched)


def sah_weights(corners) -> np.ndarray | None:
    """SAH weights of items whose tests walk `corners` corners each (1 for items of at most
    CORNERS_PER_TEST, corners / CORNERS_PER_TEST above); None when every item weighs 1."""
    corners = np.asarray(corners, np.float64)
    return np.maximum(1.0, corners / CORNERS_PER_TEST) if np.any(corners > CORNERS_PER_TEST) else None


def flatten(builder, params, refs, bounds, name, box):
    if params.get("precision", "double") != "double":
        raise OptionError(f"group {name or '(unnamed)'}: bvh(precision={params['precision']}) is for the triangle "
                          "meshes of RayScene.from_mesh, from_trimesh and from_file; renders and other scenes "
                          "are traced in double precision")
    split = params.get("split", 1)
    sah = params.get("build", "sah") in ("sah", "morton")
    weights = None
    if sah and params.get("corners", 1):
        weights = sah_weights(builder.vertex_weights(np.asarray(refs, np.int64)))
    if split > 1:       # the tree is built over pieces of the flat primitives (presplit.py)
        from .presplit import split_boxes
        piece_item, bounds = split_boxes(*builder.outlines(refs), bounds, split)
        weights = None if weights is None else weights[piece_item]
    if not sah:
        from .gsbvh import build_gs
        tree, stats = build_gs(bounds, order=params["order"], seed=params["seed"])
    else:
        tree, stats = build_bvh(bounds, leaf_size=params["leaf"], bins=params["bins"], block=params["block"],
                                weights=weights, method=params.get("build", "sah"))
    if split > 1:
        from .presplit import leaves_of_items
        tree = leaves_of_items(tree, piece_item)
        stats.update(pieces=len(piece_item), refs=len(tree.order), bytes=int(sum(a.nbytes for a in tree)))
    if params.get("optimize", "none") != "none":
        from .bvhopt import optimize
        tree, info = optimize(tree, params["optimize"])
        stats.update(max_depth=info["max_depth"], sah_before=info["sah_before"], sah_after=info["sah_after"],
                     optimize_seconds=info["seconds"], optimize_steps=info["steps"])
    if stats.get("max_depth", 0) > MAX_TREE_DEPTH:
        raise SceneError(f"group {name or '(unnamed)'}: BVH depth {stats['max_depth']} exceeds {MAX_TREE_DEPTH}")
    return append_bvh(builder.flat, tree, refs, box, cull_margin(box)), dict(stats, width=params["width"])


def cells(geo, a) -> Cells:
    """The tree's nodes, level by level from the root (Walk.cells)."""
    level, found, depths = np.array([geo.agg_start[a]], np.int64), [], []
    single = geo.agg_count[a] <= 1          # one node: the root is a leaf, even an empty one
    for depth in range(MAX_TREE_DEPTH + 1):
        found.append(level)
        depths.append(np.full(len(level), depth, np.int64))
        left = geo.node_first[level[geo.node_count[level] == 0]]
        level = np.stack([left, left + 1], axis=1).ravel()
        if single or not len(level):
            break
    nodes = np.concatenate(found)
    leaf = (geo.node_count[nodes] > 0) | single
    b = geo.node_bounds[nodes]
    return Cells(b[:, :3], b[:, 3:], np.concatenate(depths), np.where(leaf, geo.node_first[nodes], 0),
                 np.where(leaf, geo.node_count[nodes], -1), nodes)


WALK = Walk(code=CODE, name="bvh", fields=FIELDS, step=walk_step, features=features, cells=cells,
            keys="node_count")
# the annealer starts from a BVH over pieces of long thin polygons (presplit.py), the one structure
# that separates a fan of facets, and from BVHs whose nodes are reinserted (bvhopt.py), the ones that
# tighten a tree around a small dense cluster in a large sparse scene (the stadium's teapot), with
# leaves of at most two items the tightest there
SEARCH = Search(start=True, variants=("bvh(split=16)", "bvh(optimize=reinsertion)",
                                      "bvh(leaf=2, optimize=reinsertion)"),
                candidates=("bvh", "bvh(leaf=1)", "bvh(leaf=2)", "bvh(leaf=8)", "bvh(bins=32)",
                            "bvh(optimize=reinsertion)", "bvh(leaf=2, optimize=reinsertion)",
                            "bvh(build=gs, optimize=reinsertion)", "bvh(split=4)", "bvh(split=16)"))
KIND = Kind("bvh", "bounding volume hierarchy: binned surface-area heuristic (build=sah) or "
              "Goldsmith-Salmon insertion (build=gs)", (
    Param("leaf", 4, "maximum items in a leaf the SAH may keep (sah only; gs leaves hold one item)", int, 1, 64),
    Param("bins", 16, "SAH bins per axis (sah only)", int, 2, 256),
    Param("block", 1, "items the SAH prices as one intersection (sah only): 4 prices leaves in blocks of four, "
          "as RayScene's mesh kernel tests triangles four at a time (casting/triangles4.py)", int, 1, 16),
    Param("build", "sah", "sah: top-down binned SAH; morton: splits by the Morton order of the centres "
          "(a linear BVH: several times faster to build, a costlier tree); gs: Goldsmith-Salmon 1987 "
          "incremental insertion", str, choices=("sah", "morton", "gs")),
    Param("order", "file", "gs insertion order: file (as given), shuffle (seeded permutation) or curve "
          "(Morton order of the box centres); ignored by sah", str, choices=("file", "shuffle", "curve")),
    Param("seed", 1, "seed of order=shuffle (gs only)", int, 0, 2 ** 31 - 1),
    Param("optimize", "none", "after the build, lower the SAH cost keeping the leaves (bvhopt.py): rotations "
          "(Kensler 2008) or reinsertion (Bittner, Hapala and Havran 2013)", str,
          choices=("none", "rotations", "reinsertion")),
    Param("corners", 1, "1: the SAH weighs a polygon of more than 8 corners as corners / 8 items, since its "
          "test walks them all (a corner costs a fraction of a whole test; sah only); 0: every "
          "item weighs one", int, 0, 1),
    Param("split", 1, "early split clipping (Ernst and Greiner 2007): each polygon or triangle is cut across "
          "its box's longest axis, again and again while that shrinks its boxes' surface by a quarter, into at "
          "most this many pieces, and the tree is built over the pieces' tighter boxes; a leaf refers to a "
          "primitive once, but a primitive may sit in several leaves (aggregates/presplit.py); 1: off",
          int, 1, 64),
    Param("width", 4, "children per node where the ray is cast: 4 collapses the binary tree into 4-wide "
          "nodes tested with one vector slab test (widebvh.py), 2 walks the binary tree; RayScene's mesh "
          "kernel and the fast walk of a scene that is one BVH over primitives (aggregates/widewalk.py) use it, "
          "a BVH nested with other aggregates is walked binary", int, choices=(2, 4)),
    Param("precision", "double", "the numbers RayScene's mesh kernel stores a mesh's triangles in: double (the "
          "vertices as given) or single (rounded to float32, as Embree stores a mesh); single is for the meshes "
          "of RayScene.from_mesh, from_trimesh and from_file (their precision argument), and renders trace in "
          "double", str, choices=PRECISIONS),
), flatten=flatten, walk=WALK, refit=refit_aggregate, search=SEARCH, scene_walk=widewalk)

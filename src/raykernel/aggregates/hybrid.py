"""Haines's hybrid (Ray Tracing News 2(1), 1988): an octree whose problem voxels hold a BVH.

    spec "hybrid(depth=8, leaf=3, rule60=on, threshold=8, order=file, walk=neighbor)"
    tree, octree_stats = build_octree(bounds, depth=8, leaf=3, rule60=True)   # the octree part
    voxels = problem_voxels(tree, threshold=8)        # leaves still holding more than 8 items
    boxes = clipped_bounds(tree, bounds, voxel, items, depth=8)   # a voxel's items cut to it
    tree = replace_leaves(tree, voxels, first_new=len(refs))      # each voxel: one reference

Why
---
An octree cannot separate a dense object that is small against the whole
scene (Haines's teapot in a stadium): the depth limit, or the 60% rule,
stops the subdivision with thousands of facets in one voxel, and every ray
through that voxel tests them all. Haines's proposal: subdivide as an octree
to some level, and give every such *problem voxel* a Goldsmith-Salmon BVH
over its objects. Here a problem voxel is a leaf of the octree (built by
octbuild.build_octree with the same criteria as the ``octree`` kind: depth,
leaf, rule60, density, vertexcount, collapse, budget) holding more than
``threshold`` items; only the depth limit, the 60% rule, the density
criterion or the reference budget leave a leaf that full when ``threshold``
>= ``leaf``.

How
---
Nothing new is traversed. Each problem voxel's BVH is an ordinary nested
aggregate (bvh, build=gs, with the hybrid's ``order`` and ``seed``), and the
voxel's item list becomes a single reference to it, the mechanism hgrid uses
for its sub-grids. `flatten` here builds the BVHs, calls replace_leaves, and
stores the octree as usual; the one intersection routine walks the octree
and opens a frame for the BVH when it meets the reference.

Items cut to the voxel
----------------------
Each BVH is built over its items' boxes cut to the voxel (widened by a
margin at least twice the octree's insertion margin, see clipped_bounds), not
over the whole boxes: a floor polygon that crosses the voxel does not
stretch the BVH over the whole floor, and a ray in this voxel meets the box
of an item only where the item can be inside this voxel. No hit is lost: the
octree walk visits, in order along the ray, every leaf the ray crosses up to
the closest hit, and the leaf holding a hit point holds the item (its box
overlaps that leaf), with the hit point inside the item's cut box.

Exactness
---------
The octree's mailbox (per octree frame) skips primitives already tested in
an earlier leaf and each BVH reference (unique to its voxel); inside a BVH
frame there is no mailbox, so an item in several problem voxels may be
tested once per voxel the ray passes through. That costs tests, never
results: the closest hit is the smallest t over all tests, ties at equal t go
to the smaller reference (traverse.py), and the order of the walk is fixed by
the ray alone, so hits and counters are the same at any thread count.
In all-hits mode such an item is reported once per voxel and RayScene
merges the repeats, as it does for grids.

Each BVH adds one aggregate to the nesting on paths through a problem
voxel. Where the hybrid and the aggregates below it already nest
MAX_NESTING (walk.py) deep, the problem voxels keep their items and the
statistics say so (``bvhs`` < ``problem_voxels``). Groups are built from the
leaves up, so a hybrid placed so deep below the root that its BVHs would be
one aggregate too many on a path is rejected with the nesting SceneError,
like any scene nested too deep.
"""

from __future__ import annotations

import numpy as np

from ..geometry.primitives import AGGREGATE, make_ref
from . import bvh
from .octbuild import ADDRESS_BITS, OctreeArrays, build_octree
from .octree import WALK, append_octree
from .spec import Kind, Param, Search
from .walk import MAX_NESTING

__all__ = ["problem_voxels", "clipped_bounds", "clip_margin", "replace_leaves", "hybrid_stats", "STAT_KEYS"]

STAT_KEYS = ("nodes", "inner", "leaves", "empty_leaves", "refs", "bytes", "seconds")


def problem_voxels(tree: OctreeArrays, threshold: int) -> np.ndarray:
    """Leaves holding more than `threshold` items, in node order."""
    return np.flatnonzero(tree.count > threshold)


def clip_margin(tree: OctreeArrays, node: int, depth: int) -> np.ndarray:
    """Per axis, twice the octree's insertion margin (octbuild.build_octree:
    1e-9 of the scene's scale plus 1e-7 of the finest cell) with the node's
    side in place of the finest cell's, which is never smaller."""
    extent = tree.unit * float(1 << ADDRESS_BITS)
    side = extent / float(1 << int(tree.level[node]))
    finest = extent / float(1 << int(depth))
    scale = max(float(extent.max()), float(np.abs(tree.origin).max()))
    return 2.0 * (1e-9 * scale + 1e-7 * np.maximum(side, finest))


def clipped_bounds(tree: OctreeArrays, bounds: np.ndarray, node: int, items: np.ndarray, depth: int) -> np.ndarray:
    """Boxes of `items` cut to leaf `node`'s box widened by clip_margin; never empty for the leaf's items."""
    m = clip_margin(tree, node, depth)
    lo = tree.bounds[node, :3] - m
    hi = tree.bounds[node, 3:] + m
    b = bounds[items]
    out_lo = np.maximum(b[:, :3], lo)
    out_hi = np.minimum(b[:, 3:], hi)
    # an item of the leaf overlaps the widened box; keep min <= max against rounding anyway
    return np.hstack([np.minimum(out_lo, out_hi), np.maximum(out_lo, out_hi)])


def replace_leaves(tree: OctreeArrays, voxels: np.ndarray, first_new: int) -> OctreeArrays:
    """The same octree with leaf voxels[j] holding the single entry first_new + j
    (flatten appends the BVH references after the group's own, so that entry
    names voxel j's BVH); every other leaf keeps its items, in order."""
    voxels = np.asarray(voxels, np.int64)
    leaves = np.flatnonzero(tree.count >= 0)
    is_voxel = np.zeros(len(tree.count), bool)
    is_voxel[voxels] = True
    new_count = tree.count.copy()
    new_count[voxels] = 1
    # the leaves' lists one after the other in node order
    new_first = tree.first.copy()
    counts = new_count[leaves]
    starts = np.zeros(len(leaves), np.int64)
    np.cumsum(counts[:-1], out=starts[1:])
    new_first[leaves] = starts
    order = np.empty(int(counts.sum()), np.int64)
    kept = leaves[~is_voxel[leaves]]
    c = tree.count[kept]
    offset = np.arange(int(c.sum()), dtype=np.int64) - np.repeat(np.cumsum(c) - c, c)
    order[np.repeat(new_first[kept], c) + offset] = tree.order[np.repeat(tree.first[kept], c) + offset]
    order[new_first[voxels]] = first_new + np.arange(len(voxels), dtype=np.int64)
    return tree._replace(first=new_first, count=new_count, order=order)


def hybrid_stats(octree_stats: dict, tree: OctreeArrays, bvh_stats: list[dict], n_problem: int) -> dict:
    """Build statistics of a hybrid: the octree's and the BVHs' counts side by side
    (octree_*, bvh_*), their sums under the usual names, and the voxel counts.
    octree_stats: build_octree's, for the octree before its voxels were replaced
    (`tree`, after replacement, gives refs and bytes)."""
    octree = dict(octree_stats, refs=int(len(tree.order)), bytes=int(sum(a.nbytes for a in tree)))
    bvh = {k: sum(s[k] for s in bvh_stats) for k in STAT_KEYS}
    stats = {k: octree[k] + bvh[k] for k in STAT_KEYS}
    stats["max_depth"] = octree["max_depth"]
    for k in STAT_KEYS:
        stats[f"octree_{k}"] = octree[k]
        stats[f"bvh_{k}"] = bvh[k]
    stats["bvh_max_depth"] = max((s["max_depth"] for s in bvh_stats), default=0)
    stats["problem_voxels"] = int(n_problem)
    stats["bvhs"] = len(bvh_stats)
    stats["nested_aggregates"] = len(bvh_stats)
    return stats


def flatten(builder, params, refs, bounds, name, box):
    """An octree whose problem voxels (leaves holding more than `threshold` items) hold one
    reference to a Goldsmith-Salmon BVH over their items cut to the voxel."""
    weights = builder.vertex_weights(refs) if params["vertexcount"] else None
    tree, octree_stats = build_octree(bounds, depth=params["depth"], leaf=params["leaf"], rule60=params["rule60"],
                                      density=params["density"], vertexcount=params["vertexcount"], weights=weights,
                                      collapse=params["collapse"], budget=params["budget"], name=name,
                                      max_bytes=builder.max_bytes)
    voxels = problem_voxels(tree, params["threshold"])
    n_problem = len(voxels)
    if builder.nesting >= MAX_NESTING:
        voxels = voxels[:0]     # a BVH would be one aggregate too many on a ray's path
    bvh_spec = (bvh.KIND.name, dict(bvh.KIND.defaults(), build="gs", order=params["order"], seed=params["seed"]))
    subs, bvh_stats = [], []
    for node in voxels:
        items = tree.order[tree.first[node]:tree.first[node] + tree.count[node]]
        subs.append(builder.build(bvh_spec, refs[items], clipped_bounds(tree, bounds, node, items, params["depth"]),
                                  name))
        bvh_stats.append(builder.agg_stats.pop())
    leaf_refs = refs
    if len(subs):
        tree = replace_leaves(tree, voxels, len(refs))
        leaf_refs = np.concatenate([refs, make_ref(AGGREGATE, subs)])
        builder.extra_nesting = max(builder.extra_nesting, 1)
    box = np.concatenate([bounds[:, :3].min(axis=0), bounds[:, 3:].max(axis=0)])
    agg = append_octree(builder.flat, tree, leaf_refs, params["walk"], params["mailbox"], box)
    return agg, hybrid_stats(octree_stats, tree, bvh_stats, n_problem)


KIND = Kind("hybrid", "Haines's hybrid (RTN 2(1), 1988): an octree whose problem voxels (leaves the "
              "subdivision left holding more than threshold items: depth limit, rule60, density) each hold "
              "a Goldsmith-Salmon BVH over their items, cut to the voxel", (
    Param("depth", 8, "maximum octree depth (see octree)", int, 0, 24),
    Param("leaf", 3, "an octree node holding at most this many items is a leaf (see octree)", int, 1, 1 << 20),
    Param("rule60", True, "Haines's 60% problem-voxel rule (see octree)", bool),
    Param("density", 0.0, "Glassner's density criterion, 0: off (see octree)", float, 0.0, 1e6),
    Param("vertexcount", False, "count vertices instead of items against leaf (see octree)", bool),
    Param("collapse", True, "collapse single-child chains (see octree)", bool),
    Param("budget", 16.0, "the octree's leaves hold at most budget * items + 4096 references, 0: no limit "
          "(see octree)", float, 0.0, 1e6),
    Param("threshold", 8, "a leaf holding more items than this is a problem voxel and gets a BVH", int, 1,
          1 << 30),
    Param("order", "file", "insertion order of the voxels' BVHs: file, shuffle or curve (see bvh, build=gs)",
          str, choices=("file", "shuffle", "curve")),
    Param("seed", 1, "seed of order=shuffle", int, 0, 2 ** 31 - 1),
    Param("walk", "neighbor", "octree traversal: point, neighbor or parametric (see octree)", str,
          choices=("point", "neighbor", "parametric")),
    Param("mailbox", True, "skip items already tested against the ray in an earlier leaf of the octree", bool),
), flatten=flatten, walk=WALK, search=Search(start=True, candidates=("hybrid",)))

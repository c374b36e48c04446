"""How good a structure's nodes are, node by node, from its boxes alone (rendering/structure.py).

    q = quality(boxes)           # dict of (n,) arrays: area, sah, overlap
    q["sah"].sum()               # the SAH cost of the whole (every aggregate's, summed)
    depth_histogram(boxes)       # leaves by depth; leaf_size_histogram(boxes): leaves by references

The surface area heuristic (MacDonald and Booth; pbrt's BVH builder) prices a tree at
sum over nodes of area(node) / area(root) * (TRAVERSAL for an inner node, TEST * references for a
leaf): the expected work of a ray that crosses the root's box. `sah` is each box's term, against
the root of its own aggregate (the bounding box of all its boxes, for a grid whose cells are all
at depth 0). `overlap` is the volume a box shares with the other boxes of its aggregate at its
depth, as a share of its own volume: zero for grids, octrees and k-d trees, whose boxes tile
space; a BVH's siblings overlap where they share space, and each ray there walks both. Boxes of
an instance under a rotation are measured by their corners' axis-aligned box.
"""

from __future__ import annotations

import numpy as np

TRAVERSAL = 1.0     # the cost of visiting an inner node, relative to
TEST = 1.0          # the cost of one primitive test
PAIRS = 4_000_000   # box pairs compared at a time for the overlap


def quality(boxes) -> dict:
    """Each box's surface area, SAH term and overlap (see the module's docstring)."""
    lo, hi = boxes.corners.min(axis=1), boxes.corners.max(axis=1)
    size = np.maximum(hi - lo, 0.0)
    area = 2.0 * (size[:, 0] * size[:, 1] + size[:, 1] * size[:, 2] + size[:, 2] * size[:, 0])
    root = np.ones(len(boxes))
    for a in np.unique(boxes.aggregate):
        mine = boxes.aggregate == a
        s = np.maximum(hi[mine].max(axis=0) - lo[mine].min(axis=0), 0.0)
        root[mine] = max(2.0 * (s[0] * s[1] + s[1] * s[2] + s[2] * s[0]), np.finfo(float).tiny)
    cost = np.where(boxes.leaf == 1, TEST * np.maximum(boxes.items, 0), TRAVERSAL)
    return {"area": area, "sah": area / root * cost, "overlap": _overlap(boxes, lo, hi)}


def _overlap(boxes, lo, hi) -> np.ndarray:
    volume = np.prod(np.maximum(hi - lo, 0.0), axis=1)
    out = np.zeros(len(boxes))
    groups = boxes.aggregate * (int(boxes.depth.max(initial=0)) + 1) + boxes.depth
    for g in np.unique(groups):
        idx = np.flatnonzero(groups == g)
        step = max(1, PAIRS // max(1, len(idx)))
        for start in range(0, len(idx), step):
            part = idx[start:start + step]
            span = np.minimum(hi[part, None], hi[None, idx]) - np.maximum(lo[part, None], lo[None, idx])
            shared = np.prod(np.maximum(span, 0.0), axis=2)
            shared[np.arange(len(part)), start + np.arange(len(part))] = 0.0     # not with itself
            out[part] = shared.sum(axis=1)
    return np.divide(out, volume, out=np.zeros_like(out), where=volume > 0)


def depth_histogram(boxes) -> tuple:
    """(depths, leaves at each depth)."""
    depths = boxes.depth[boxes.leaf == 1]
    values, counts = np.unique(depths, return_counts=True)
    return values, counts


def leaf_size_histogram(boxes) -> tuple:
    """(references a leaf holds, leaves holding that many)."""
    sizes = boxes.items[boxes.leaf == 1]
    values, counts = np.unique(sizes, return_counts=True)
    return values, counts

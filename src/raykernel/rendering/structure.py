"""A built structure as boxes other tools can open: every cell or node of every aggregate, nested
hierarchies level by level, each box with its values.

    boxes = structure_boxes(scene, accel="hybrid")      # Boxes, in world space
    boxes.level, boxes.depth, boxes.leaf, boxes.items   # one value a box
    write_ply(boxes, "hybrid.ply")                      # 8 vertices and 12 triangles a box, values per face

Each aggregate's walk draws its cells (Walk.cells): BVH and octree nodes, grid cells, k-d tree
nodes with the boxes their planes cut; a list, a CSG node and ray classification (whose beams
live in the space of rays, not of points) are drawn as their box. The items of every leaf that
are aggregates of their own are drawn below it, one nesting level deeper, moved by their
instances' maps (a box under a rotation is drawn rotated); an aggregate referenced by many cells
is drawn once for each way it is reached (each instance). A lazy structure is drawn as built,
before any ray refined it.

Values of each box: `level`, how many aggregates deep (0: the root's); `depth`, how deep in its
own structure (0: its root; a grid's cells all 0); `leaf`, 1 for a box that holds references;
`items`, its references (-1 for an inner node); `aggregate`, the aggregate's index; `walk`, the
walk's code (aggregates/walk.py). The PLY file (binary, written through trimesh, the mesh extra)
carries each as a property of every face, so MeshLab, ParaView, Open3D and trimesh colour by it.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..aggregates.registry import WALKS
from ..aggregates.walk import one_cell
from ..errors import OptionError
from ..geometry.primitives import AGGREGATE, INDEX_MASK, INSTANCE, KIND_SHIFT

VALUES = ("level", "depth", "leaf", "items", "aggregate", "walk")
# the corners of a box: corner k takes hi on x if k & 1, on y if k & 2, on z if k & 4
CORNERS = np.array([[(k >> axis) & 1 for axis in range(3)] for k in range(8)], bool)
# its 12 triangles, counter-clockwise seen from outside
FACES = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
                  [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]], np.int64)


class Boxes(NamedTuple):
    corners: np.ndarray     # (n, 8, 3) world space, corner k as CORNERS[k]
    level: np.ndarray       # (n,) values, as the module's docstring says
    depth: np.ndarray
    leaf: np.ndarray
    items: np.ndarray
    aggregate: np.ndarray
    walk: np.ndarray

    def __len__(self) -> int:
        return len(self.corners)


WALKS_BY_CODE = {w.code: w for w in WALKS}


def _walk_cells(geo, a):
    walk = WALKS_BY_CODE.get(int(geo.agg_kind[a]))
    if walk is not None and walk.cells is not None:
        return walk.cells(geo, a)
    return one_cell(geo.agg_bounds[a], 0, 0)


def _to_world(local_to_world: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    corners = np.where(CORNERS[None], hi[:, None, :], lo[:, None, :])
    return corners @ local_to_world[:, :3].T + local_to_world[:, 3]


def _inverse(to_local: np.ndarray) -> np.ndarray:
    """The local-to-world map (3 x 4) of an instance's world-to-local one (12 numbers, row-major)."""
    m = np.vstack([np.asarray(to_local, np.float64).reshape(3, 4), [0.0, 0.0, 0.0, 1.0]])
    return np.linalg.inv(m)[:3]


def boxes_of(geo) -> Boxes:
    """The boxes of every aggregate reachable from the root of flattened scene arrays."""
    parts = []
    todo = [(int(geo.root), np.hstack([np.eye(3), np.zeros((3, 1))]), 0)]
    while todo:
        a, to_world, level = todo.pop()
        cells = _walk_cells(geo, a)
        n = len(cells.lo)
        parts.append((_to_world(to_world, cells.lo, cells.hi), np.full(n, level), cells.depth,
                      (cells.count >= 0).astype(np.int64), cells.count, np.full(n, a), np.full(n, geo.agg_kind[a])))
        held = cells.count > 0
        if not held.any():
            continue
        counts = cells.count[held]
        index = np.repeat(cells.first[held] - np.cumsum(counts) + counts, counts) + np.arange(int(counts.sum()))
        refs = np.unique(geo.refs[index])
        kinds, items = refs >> KIND_SHIFT, refs & INDEX_MASK
        todo += [(int(c), to_world, level + 1) for c in items[kinds == AGGREGATE]]
        for i in items[kinds == INSTANCE]:
            local = _inverse(geo.inst_to_local[i])
            combined = to_world[:, :3] @ local
            combined[:, 3] += to_world[:, 3]
            todo.append((int(geo.inst_agg[i]), combined, level + 1))
    columns = [np.concatenate(c) for c in zip(*parts)]
    return Boxes(columns[0], *(c.astype(np.int64) for c in columns[1:]))


def structure_boxes(scene, accel: str = "bvh", max_memory=None) -> Boxes:
    """The boxes of `scene` built with `accel` for groups that name no structure of their own."""
    from ..engine.flatten import flatten
    geo, _ = flatten(scene, accel, max_memory=max_memory)
    return boxes_of(geo)


def select(boxes: Boxes, keep: np.ndarray) -> Boxes:
    return Boxes(*(np.asarray(column)[keep] for column in boxes))


def write_ply(boxes: Boxes, path) -> None:
    """Every box as 8 vertices and 12 triangles in a binary PLY file, each face with the box's
    values (VALUES) as int properties; written atomically."""
    try:
        import trimesh
    except ImportError:
        raise OptionError("writing PLY needs trimesh: pip install 'raykernel[mesh]'") from None
    from ..atomicfile import write_bytes
    n = len(boxes)
    faces = (FACES[None] + 8 * np.arange(n)[:, None, None]).reshape(-1, 3)
    mesh = trimesh.Trimesh(boxes.corners.reshape(-1, 3), faces, process=False)
    for name in VALUES:
        mesh.face_attributes[name] = np.repeat(getattr(boxes, name), len(FACES)).astype(np.int32)
    write_bytes(path, trimesh.exchange.ply.export_ply(mesh, encoding="binary", include_attributes=True))

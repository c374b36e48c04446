"""A built structure as boxes other tools can open: every cell or node of every aggregate, nested
hierarchies level by level, each box with its values.

    boxes = structure_boxes(scene, accel="hybrid")      # Boxes, in world space
    boxes.level, boxes.depth, boxes.leaf, boxes.items   # one value a box
    write_ply(boxes, "hybrid.ply")                      # 8 vertices and 12 triangles a box, values per face
    boxes, use, result = structure_use(scene, accel="lazyoctree", resolution=64)   # how a render's rays used them
    write_ply(boxes, "used.ply", use)                   # use["visits"], use["tests"], use["futile"], use["refined"]

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

How rays used them (structure_use): the scene rendered with render's options on one thread, its
walks counting, box by box (geometry/work.py, Use), `visits`, the times a ray entered it (they sum
to the render's cells.visited); `tests`, the primitive tests made in its references (they sum to
its tests.total, less the tests Haines's tricks make outside any search); `futile`, the visits
whose tests hit nothing (an empty cell's every visit); and `refined`, 1 for a lazy octree's cells
this render made. A box that holds no references of its own (an inner node) has futile -1, and
as tests those made in it while it was a leaf (a lazy octree's cell this render split), else 0. A list, an operator and ray classification (drawn as their box) count their walk's visits on
it, and as futile the times their references were reached and nothing hit. An aggregate drawn
once for each instance shows the use of all its instances on each. A BVH that renders 4-wide
(aggregates/widewalk.py) is walked in its binary form here, node by node as drawn.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np

from ..aggregates.octree import CODE as OCTREE
from ..aggregates.registry import WALKS
from ..aggregates.walk import MAX_NESTING, one_cell
from ..geometry.work import AGGREGATES, COUNTS, ENTRIES, FRAMES, HITS, PAUSED, TESTS, VISITS, Use
from ..errors import OptionError
from ..geometry.primitives import AGGREGATE, INDEX_MASK, INSTANCE, KIND_SHIFT

VALUES = ("level", "depth", "leaf", "items", "aggregate", "walk")
USE = ("visits", "tests", "futile", "refined")
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
    key: np.ndarray         # the box's key in its walk (Cells.key; -1: its aggregate's box)

    def __len__(self) -> int:
        return len(self.corners)


WALKS_BY_CODE = {w.code: w for w in WALKS}


def _walk_cells(geo, a):
    walk = WALKS_BY_CODE.get(int(geo.agg_kind[a]))
    if walk is not None and walk.cells is not None:
        return walk.cells(geo, a)
    return one_cell(geo.agg_bounds[a], 0, 0)


def _references(geo, a, cells) -> np.ndarray:
    """The references aggregate a's cells hold, each once."""
    walk = WALKS_BY_CODE.get(int(geo.agg_kind[a]))
    if walk is not None and walk.references is not None:
        return walk.references(geo, a)
    held = cells.count > 0
    counts = cells.count[held]
    index = np.repeat(cells.first[held] - np.cumsum(counts) + counts, counts) + np.arange(int(counts.sum()))
    return np.unique(geo.refs[index])


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
                      (cells.count >= 0).astype(np.int64), cells.count, np.full(n, a), np.full(n, geo.agg_kind[a]),
                      cells.key))
        refs = _references(geo, a, cells)
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


def write_ply(boxes: Boxes, path, use: dict | None = None) -> None:
    """Every box as 8 vertices and 12 triangles in a binary PLY file, each face with the box's
    values (VALUES, and those of `use`, as structure_use gives them) as int properties; written
    atomically."""
    try:
        import trimesh
    except ImportError:
        raise OptionError("writing PLY needs trimesh: pip install 'raykernel[mesh]'") from None
    from ..atomicfile import write_bytes
    n = len(boxes)
    faces = (FACES[None] + 8 * np.arange(n)[:, None, None]).reshape(-1, 3)
    mesh = trimesh.Trimesh(boxes.corners.reshape(-1, 3), faces, process=False)
    values = {name: getattr(boxes, name) for name in VALUES} | (use or {})
    for name, value in values.items():
        mesh.face_attributes[name] = np.repeat(np.asarray(value), len(FACES)).astype(np.int32)
    write_bytes(path, trimesh.exchange.ply.export_ply(mesh, encoding="binary", include_attributes=True))


def structure_use(scene, accel: str = "bvh", **options):
    """The boxes of `scene` built with `accel`, how the rays of its render with `options`
    (render's: resolution, spd, shading, aa, tricks, ...) used them (a dict of USE's values, one
    a box: see the module's docstring), and the render (its image and statistics). The render
    runs on one thread."""
    from ..aggregates.widewalk import with_driver
    from .render import RenderJob
    job = RenderJob(scene, accel=accel, **dict(options, work=True, threads=1))
    job.geo = with_driver(job.geo)._replace(wide_nodes=job.geo.wide_nodes[:0])     # walked node by node
    built = len(job.geo.oct_count)
    job.probe = use_of(job.geo)
    t0 = time.perf_counter()
    for p in range(len(job.passes)):
        job.trace_pass(p, 1)
        job.end_pass(p)
        if job.geo.wide_nodes.shape[0]:
            job.geo = job.geo._replace(wide_nodes=job.geo.wide_nodes[:0])
        job.probe = use_of(job.geo, job.probe)     # a lazy structure refined: room for its new cells
    result = job.result(time.perf_counter() - t0, 0.0)
    boxes = boxes_of(job.geo)
    return boxes, use_values(boxes, job.probe, built), result


def use_values(boxes: Boxes, use: Use, built: int | None = None) -> dict:
    """USE's values of each box from the counts of `use`; built: the octree cells there were
    before the render refined any (None: all of them)."""
    keyed = use.keyed[boxes.walk] != 0
    counts = use.counts[box_rows(boxes, use)]
    inner = boxes.leaf == 0
    futile = np.where(keyed, counts[:, VISITS], counts[:, ENTRIES]) - counts[:, HITS]
    refined = (boxes.walk == OCTREE) & (boxes.key >= built) if built is not None else np.zeros(len(boxes), bool)
    return {"visits": counts[:, VISITS], "tests": counts[:, TESTS], "futile": np.where(inner, -1, futile),
            "refined": refined.astype(np.int64)}


def box_rows(boxes: Boxes, use: Use) -> np.ndarray:
    """The row of `use.counts` each box's use is counted in (an aggregate drawn once for each
    instance: the same row for each)."""
    keyed = use.keyed[boxes.walk] != 0
    return np.where(keyed, use.offset[boxes.walk] + boxes.key, use.offset[AGGREGATES] + boxes.aggregate)


def use_of(geo, old: Use | None = None) -> Use:
    """A Use with a row for every cell and node of geo's walks, and for every aggregate; the
    counts of `old` (for geo before a lazy structure refined) kept."""
    sizes = np.zeros(AGGREGATES + 1, np.int64)
    keyed = np.zeros(AGGREGATES, np.int64)
    for w in WALKS:
        if w.keys is not None:
            sizes[w.code] = len(getattr(geo, w.keys))
            keyed[w.code] = 1
    sizes[AGGREGATES] = len(geo.agg_kind)
    offset = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
    if old is not None and np.array_equal(offset, old.offset):
        return old
    counts = np.zeros((int(sizes.sum()), len(COUNTS)), np.int64)
    if old is not None:
        before = np.diff(np.append(old.offset, len(old.counts)))
        for k in range(AGGREGATES + 1):
            counts[offset[k]:offset[k] + before[k]] = old.counts[old.offset[k]:old.offset[k] + before[k]]
    state = np.full(FRAMES + 2 * (MAX_NESTING + 1), -1, np.int64)
    state[PAUSED] = 0
    return Use(counts, offset, keyed, state)

"""Octree (Glassner 1984) over axis-aligned item boxes, as flat arrays.

    from raykernel.aggregates.octbuild import build_octree
    tree, stats = build_octree(item_bounds)            # the defaults: depth=16, leaf=3, budget=16
    # tree.first, tree.count, tree.loc, tree.level, tree.slot, tree.nbr, tree.bounds, tree.order
    items_of_leaf = tree.order[tree.first[n]:tree.first[n] + tree.count[n]]

Modules: octree.py (this one) is the kind: its flat layout (append_octree),
flatten, and walk_step, the choice among its walks. octbuild.py builds the
tree (build_octree: subdivision, collapse, node layout, neighbours, wall
quadtrees); octwalk.py holds what the walks share and the parametric walk;
octpoint.py the point, neighbor and wall walks.

Flat layout (the Geometry fields it owns)
-----------------------------------------
ON nodes of all octrees, O octrees:
  oct_bounds   (ON, 6) float64  node box                                        48 B a node
  oct_first    (ON,)   int64    inner: first of 8 children (global); leaf: first ref   8 B
  oct_count    (ON,)   int64    refs in a leaf; -1 for an inner node            8 B
  oct_loc      (ON, 3) int64    lower 28-bit address of the node's box         24 B
  oct_level    (ON,)   int64    level of the node's box                         8 B
  oct_slot     (ON,)   int64    level of the octant the node occupies in its parent   8 B
  oct_nbr      (ON, 6) int64    neighbour across -x, +x, -y, +y, -z, +z (global), -1: none   48 B
  oct_pass     (ON,)   int64    lazy octree leaf that may split: its pass counter column, else -1   8 B
  oct_root     (O,)    int64    root node                                       8 B an octree
  oct_origin   (O, 3)  float64  lower corner of the root box                   24 B
  oct_unit     (O, 3)  float64  side of one address unit                       24 B
  oct_scale    (O, 3)  float64  1 / oct_unit                                   24 B
  oct_walk     (O,)    int64    0 point, 1 neighbor, 2 parametric, 3 wall       8 B
  oct_quad     (Q, 4)  int64    wall quadtree nodes (walk=wall; see Walls)     32 B a quad node
  oct_mailbox  (O,)    int64    1: skip refs already tested in an earlier leaf  8 B
The aggregate's agg_start is its octree index. The point and neighbor walks
keep the address of the point they go on from in their frame (POINT).

Root box and addresses
----------------------
The root box is the union of the item boxes, with flat axes padded as the
uniform grid pads them (grid.grid_box). It is not made cubic: every cell is a
scaled copy of the root box, so a flat or long scene is not wrapped in mostly
empty space, and Lathrop's integer addressing works per axis anyway. Each
axis of the root box is mapped to integer addresses [0, 2**28); a node at
level L spans 2**(28 - L) addresses per axis, and bit 27 - L of a point's
address picks the child octant (bit 0 of the octant: x, bit 1: y, bit 2: z).
Every box coordinate is computed as ``origin + unit * address`` (unit =
side / 2**28), so neighbouring cells share bit-identical walls.

Subdivision (centre split, objects go into every child their box overlaps,
closed intervals, boxes widened by a tiny margin as in the grid)
------------------------------------------------------------------------------
A node is a leaf when any of these holds:
  * its level is ``depth``;
  * it holds at most ``leaf`` items, counting polygon/patch vertices and 3 per
    triangle instead of 1 when ``vertexcount`` is on (Glassner's measure);
  * ``density`` > 0 and the summed volume of its items' boxes clipped to the
    cell, over the cell volume, is at least ``density`` (Glassner's criterion:
    subdivide only while the cell is sparsely filled);
  * ``rule60`` is on and the largest child list would still hold at least 60%
    of the node's items (Haines's problem-voxel rule), unless that child is
    the only occupied one: items that all fall into one octant are separated
    by splitting further (a small cluster in a big box, the teapot in a
    stadium), and collapse removes the chain this makes;
  * ``budget`` > 0 and splitting it would take the references held by all
    leaves past ``budget`` times the item count, plus 4096.

Nodes are split in order of items times the surface area of their box (the
number of items a random ray crossing the box would meet), the largest
first, ties by node number. Without a budget the order changes nothing (each
criterion looks at one node only); with one, the references go where rays
meet the most items: a crowded cell near the root before the neighbourhood
of a shared vertex deep down. A split the budget cannot pay for is skipped
and cheaper ones may still follow, so the result is deterministic.

Defaults, and why
-----------------
depth=16, leaf=3, budget=16, rule60 off, density off, collapse on. Items that
no split separates (the triangles around a shared mesh vertex, spheres that
overlap each other) keep a node above ``leaf`` at every level, so depth and
leaf alone let the tree grow as 8**depth around them: at the old defaults
(depth 8, no budget) SPD shells (overlapping spheres) took gigabytes and
minutes to build, and meshes such as tetra and sample hundreds to thousands
of references per item. The budget keeps memory proportional to the item
count (fewer nodes than references), so the depth limit can be deep enough
for a small cluster in a big box: at the stadium's default ratio the teapot
is resolved many levels down, with far fewer tests per ray than the old
defaults made (the tree scene gains too). The price is paid on meshes, whose
finest cells the old octree could afford only by the hundreds of references
per item: tetra, sample and gears test more items per ray; budget=32
narrows the gap for up to twice the memory. At a ratio of 10**6 the
teapot lies in one deep cell with the field; no budget or depth fixes that,
a BVH nested around the teapot does (see pathological.stadium, teapot_bvh).
rule60 stays off: wherever a large floor or backdrop polygon reaches into
the other octants it stops the subdivision within a few levels (SPD balls
and teapot stay shallow trees that test many times more items per ray).
bench/structures.py measures these variants (docs/benchmarks/structures.md,
"Octree criteria and traversals").

Collapse
--------
With ``collapse`` on, an inner node with exactly one non-empty child takes
that child's subtree, and its box shrinks to the child's box; repeated, this
removes whole chains. Each node keeps its *slot* (the octant of its parent
it occupies, level ``slot``) next to its own box (level ``level``, lower
address ``loc``). A point inside a slot but outside the node's box lies in an
empty octant the collapse removed: the walks find it from the address bits
and step through it as an empty leaf (see traverse.py).

Neighbours
----------
``nbr[n, 2 * axis + (1 if towards +axis else 0)]`` is the node whose slot is
adjacent to n's slot across that wall and of equal or larger size (the
deepest such node), or -1 on the root's boundary.

Walls (walk=wall)
-----------------
Glassner's answer to a ray leaving a cell into smaller ones (Haines reports it
in RTN 1(2), 1988: "quadtree-like structures on the cube faces of the octree
cubes"; Kaplan's faces "immediately access the next voxel"): across a wall
whose neighbour of the leaf's size is subdivided, a quadtree of the cells
behind that wall. Its nodes are the neighbour's inner nodes that touch the
wall, each with the four children on the wall's side, in order of their bits
on the wall's two axes (lower axis first); a child is a leaf (its node) or the
next quad node (tagged -2 - q). A wall-walk octree keeps these in nbr itself:
the leaf's node when the neighbour is a leaf, -2 - q when it is subdivided,
-1 at the root's boundary. The walk leaves a leaf across its nearest wall and
reaches the next leaf from that wall alone: no descent from the root (point)
and no descent in three dimensions from the neighbour (neighbor), two address
bits of the exit point a quad level, counted as octree.wall_steps (the leaves
themselves count as cells.visited). Built without collapse: the quadtrees
index the octants themselves.
"""

from __future__ import annotations

import numpy as np

from ..geometry import counters as C
from ..geometry.config import njit
from .octbuild import OctreeArrays, build_octree, wall_quadtrees
from .octpoint import point_walk
from .octwalk import CODE, COUNTERS, PARAM, PARAMETRIC_WALK, PASS, TRAVERSALS, WALL_WALK, parametric
from .spec import Kind, Param, Search
from .walk import FI_AGG, START, Cells, Field, Walk, answer, mailbox_reset

__all__ = ["append_octree", "octree_step", "CODE"]


# ----------------------------------------------------------------- flat layout (see the module docstring) and walk

FIELDS = (
    Field("oct_bounds", np.float64, (6,)), Field("oct_first", np.int64, ()), Field("oct_count", np.int64, ()),
    Field("oct_loc", np.int64, (3,)), Field("oct_level", np.int64, ()), Field("oct_slot", np.int64, ()),
    Field("oct_nbr", np.int64, (6,)), Field("oct_pass", np.int64, ()), Field("oct_root", np.int64, ()),
    Field("oct_origin", np.float64, (3,)), Field("oct_unit", np.float64, (3,)), Field("oct_scale", np.float64, (3,)),
    Field("oct_walk", np.int64, ()), Field("oct_mailbox", np.int64, ()), Field("oct_quad", np.int64, (4,)),
)


def append_octree(flat, tree: OctreeArrays, refs, walk: str, mailbox: bool, box) -> int:
    """Store a built octree whose leaves hold refs[tree.order] as the next aggregate."""
    n0 = flat.size("oct_count")
    first_ref = flat.add_refs(refs[tree.order])
    inner = tree.count < 0
    o = flat.size("oct_root")
    nbr = tree.nbr
    if walk == TRAVERSALS[WALL_WALK]:
        nbr, quads = wall_quadtrees(tree.first, tree.count, tree.nbr)
        q0 = flat.size("oct_quad")
        flat.append(oct_quad=np.where(quads >= 0, quads + n0, quads - q0))
        nbr = np.where(nbr >= 0, nbr + n0, np.where(nbr <= -2, nbr - q0, -1))
    else:
        nbr = np.where(nbr >= 0, nbr + n0, -1)
    flat.append(oct_bounds=tree.bounds, oct_first=np.where(inner, tree.first + n0, tree.first + first_ref),
                oct_count=tree.count, oct_loc=tree.loc, oct_level=tree.level, oct_slot=tree.slot, oct_nbr=nbr,
                oct_pass=np.full(len(tree.count), -1), oct_root=[n0], oct_origin=tree.origin[None],
                oct_unit=tree.unit[None], oct_scale=1.0 / tree.unit[None], oct_walk=[TRAVERSALS.index(walk)],
                oct_mailbox=[int(mailbox)])
    return flat.add_aggregate(CODE, o, len(tree.count), box)


@njit(inline="always")
def walk_step(geo, step, a, te, ray, lo, best_t, f, sp, ws, cnt):
    """walk.py's step contract: the octree's walk (oct_walk) from its START, NEXT or PARAM entries."""
    sp, s, e = octree_step(geo.oct_bounds, geo.oct_count, geo.oct_first, geo.oct_level, geo.oct_loc, geo.oct_mailbox,
                           geo.oct_nbr, geo.oct_origin, geo.oct_pass, geo.oct_quad, geo.oct_root, geo.oct_scale,
                           geo.oct_slot, geo.oct_unit, geo.oct_walk, step, a, te, geo.agg_start[ws.frame_i[f, FI_AGG]],
                           ray, lo, best_t, ws.frame_f, f, ws, sp, cnt)
    return answer(sp, s, e, ray, best_t)


@njit(inline="always")   # the choice of walk only: the walks are compiled apart (their IR inlined would add a lot of compile time)
def octree_step(oct_bounds, oct_count, oct_first, oct_level, oct_loc, oct_mailbox, oct_nbr, oct_origin, oct_pass,
                oct_quad, oct_root, oct_scale, oct_slot, oct_unit, oct_walk, kind_step, a, te, oi, ray, tmin, best_t,
                frame_f, f, ws, sp, cnt):
    """One step of octree `oi`'s walk (ws: the workspace, its stack and work); returns (sp, s, e), the references of the next
    non-empty leaf (none: s == e).

    point (Lathrop): the leaf holding a point is found from the root by the point's
    28-bit address, its exit distance computed, and the point moved just past the exit
    wall. neighbor: the same, but the next descent starts from the neighbour across the
    exit wall (Glassner's pointers). wall: the next leaf is found from the exit wall alone, down
    its wall quadtree (Walls, above). All three put a NEXT entry back before a non-empty leaf's
    references. A point outside a collapsed node's shrunk box lies in an empty octant the
    collapse removed; its address bits give that octant, visited as an empty leaf.
    parametric (Revelles et al. 2000): PARAM entries with their entry distance, the
    children a ray crosses pushed farthest first. A lazy octree's candidate leaf gets a
    PASS entry at its exit distance above the walk's continuation. ray: (ox, oy, oz, dx, dy,
    dz, ix, iy, iz), one argument so that the call stays under 30 (CPython passes longer
    calls as *args, which numba cannot inline)."""
    if kind_step == PASS:
        if te <= best_t:
            cnt[C.N_COUNTERS + a] += 1
        return sp, 0, 0
    if te > best_t:
        return sp, 0, 0
    if kind_step == START and oct_mailbox[oi] != 0:
        mailbox_reset(frame_f, f)
    if kind_step == PARAM or (kind_step == START and oct_walk[oi] == PARAMETRIC_WALK):
        return parametric(oct_bounds, oct_count, oct_first, oct_level, oct_loc, oct_origin, oct_pass, oct_root,
                          oct_unit, a if kind_step == PARAM else oct_root[oi], oi,
                          ray, tmin, best_t, ws.stack_a, ws.stack_b, ws.stack_t, sp, cnt, ws.work)
    return point_walk(oct_count, oct_first, oct_level, oct_loc, oct_nbr, oct_origin, oct_pass, oct_quad, oct_root,
                      oct_scale, oct_slot, oct_unit, oct_walk, kind_step, a, te, oi,
                      ray, best_t, frame_f, f, ws.stack_a, ws.stack_b, ws.stack_t, sp, cnt, ws.work)


def flatten(builder, params, refs, bounds, name, box):
    weights = builder.vertex_weights(refs) if params["vertexcount"] else None
    collapse = params["collapse"] and params["walk"] != TRAVERSALS[WALL_WALK]     # walls index the octants
    tree, stats = build_octree(bounds, depth=params["depth"], leaf=params["leaf"], rule60=params["rule60"],
                               density=params["density"], vertexcount=params["vertexcount"], weights=weights,
                               collapse=collapse, budget=params["budget"], name=name,
                               max_bytes=builder.max_bytes)
    return append_octree(builder.flat, tree, refs, params["walk"], params["mailbox"], box), dict(stats)


def stats_rows(stats) -> list:
    """Its rows of the statistics table (rendering/stats.py): the wall walk's quadtree steps."""
    n = stats.get("octree.wall_steps", 0)
    if not n:
        return []
    leaves = max(1, stats.get("cells.leaves", 0))
    return [("octree", "wall steps", f"{n:,}", f"{n / leaves:.2f} wall quadtree levels per leaf reached")]


def cells(geo, a) -> Cells:
    """The tree's nodes, level by level from the root (Walk.cells)."""
    level, found, depths = np.array([geo.oct_root[geo.agg_start[a]]], np.int64), [], []
    depth = 0
    while len(level):
        found.append(level)
        depths.append(np.full(len(level), depth, np.int64))
        first = geo.oct_first[level[geo.oct_count[level] < 0]]
        level = (first[:, None] + np.arange(8)).ravel()
        depth += 1
    nodes = np.concatenate(found)
    leaf = geo.oct_count[nodes] >= 0
    b = geo.oct_bounds[nodes]
    return Cells(b[:, :3], b[:, 3:], np.concatenate(depths), np.where(leaf, geo.oct_first[nodes], 0),
                 np.where(leaf, geo.oct_count[nodes], -1), nodes)


WALK = Walk(code=CODE, name="octree", fields=FIELDS, step=walk_step, counters=COUNTERS, stats_rows=stats_rows,
            cells=cells, keys="oct_count")
KIND = Kind("octree", "octree (Glassner 1984): centre subdivision of the scene box (not made cubic), "
              "objects in every child their box overlaps; nodes with the most items times box area are split "
              "first, until depth, leaf, the criteria or the reference budget stop them. Defaults: depth 16 and "
              "budget 16 keep memory proportional to the items (without a budget, items no split separates grow "
              "the tree as 8^depth: gigabytes on SPD shells at depth 8) "
              "while small clusters in big boxes still get resolved; rule60 stays off, as it stops subdivision "
              "early wherever a large floor polygon reaches into the other octants", (
    Param("depth", 16, "maximum subdivision depth (the root is level 0)", int, 0, 24),
    Param("leaf", 3, "a node holding at most this many items (or vertices, see vertexcount) is a leaf", int, 1,
          1 << 20),
    Param("rule60", False, "Haines's problem-voxel rule: keep a node a leaf when its largest child would "
          "still hold >= 60% of its items (unless it is the only occupied child)", bool),
    Param("density", 0.0, "Glassner's density criterion: subdivide only while the items' volume clipped to "
          "the cell, over the cell volume, is under this ratio (0: off)", float, 0.0, 1e6),
    Param("vertexcount", False, "count polygon/patch vertices and 3 per triangle instead of items against "
          "leaf (Glassner's measure)", bool),
    Param("collapse", True, "a node with one non-empty child takes that child's subtree and box; the walks "
          "step through the removed empty octants using the address bits", bool),
    Param("walk", "neighbor", "traversal: point (top-down point location with Lathrop's 28-bit addresses), "
          "neighbor (Glassner's 6 neighbour pointers per node, then descent), parametric (Revelles, Urena and "
          "Lastra 2000), wall (Glassner's wall quadtrees: the next leaf found from the exit wall alone; builds "
          "without collapse)", str, choices=TRAVERSALS),
    Param("mailbox", True, "skip items already tested against the ray in an earlier leaf", bool),
    Param("budget", 16.0, "the leaves together hold at most budget * items + 4096 references; a split that "
          "would exceed it is skipped (0: no limit)", float, 0.0, 1e6),
), flatten=flatten, walk=WALK, search=Search(start=True, candidates=("octree", "octree(depth=8)", "octree(leaf=8)")))

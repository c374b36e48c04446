"""Ray classification (Arvo and Kirk 1987) over axis-aligned item boxes, as flat arrays.

    from raykernel.aggregates.rcbuild import build_rc, face_of
    tree, stats = build_rc(item_bounds, leaf=8, depth=40, budget_mb=256)   # eager: the whole trees now
    node = tree.face_root[face_of(dx, dy, dz)[0]]  # then descend with node_b / split
    items, keys = tree.items[s:s + n], tree.keys[s:s + n]   # leaf: s = node_a, n = node_b
    geo, build = flatten(scene, "rc")              # lazy (the default): six root leaves, grown by
    geo = build["lazy"].refine(geo, pass_counts)   # LazyRC between passes of rays (render, RayScene)

Modules: rc.py (this one) is the kind: its flat layout, the Geometry fields,
flatten and the cost model's features. rcbuild.py builds the trees eagerly
(build_rc, start_rc, the beam test meets_beam), rclazy.py splits them lazily
(LazyRC), rcwalk.py is what a ray runs (classify, walk_step).

Flat layout (the Geometry fields it owns)
-----------------------------------------
RC aggregates, RN nodes, RK candidates of all of them:
  rc_face_root  (RC, 6) int64    root hypercube of each direction-cube face    48 B an aggregate
  rc_node_a     (RN,)   int64    inner: first child (global); leaf: first candidate in keyed_ref   8 B a node
  rc_node_b     (RN,)   int64    inner: -(split dimension + 1) of x, y, z, u, v; leaf: candidates   8 B
  rc_split      (RN,)   float64  inner: split coordinate                        8 B
  rc_pass       (RN,)   int64    lazy leaf that may split: its row of rc_vinfo, else -1   8 B
  keyed_key        (RK,)   float64  near-face key of each candidate, rising within a leaf   8 B a candidate
  keyed_ref        (RK,)   int64    tagged reference of each candidate             8 B
  rc_vinfo      (RP, 3) int64    lazy candidate: first pass counter column, levels K, first entry
                                 in rc_vdim/rc_vsplit
  rc_vdim       (RS,)   int64    split dimension of each inner node of the virtual subtrees
  rc_vsplit     (RS,)   float64  split coordinate of each inner node of those subtrees
The aggregate's agg_start is its row of rc_face_root. A leaf's candidates are a
keyed list (aggregates/walk.py): the driver stops it once the next key puts the
earliest possible hit past the closest one.

Rays as points in 5D
--------------------
A ray is classified by its origin (x, y, z) and its direction. The direction
picks a face of the direction cube: its dominant axis a (largest |d_a|,
ties to the lower axis) and the sign s of d_a, face = 2 * a + (s < 0). On
that face the direction is (u, v) = (d_b, d_c) / |d_a| in [-1, 1]^2 with
b = (a + 1) % 3, c = (a + 2) % 3. A ray that starts outside the aggregate's
box is first moved to its entry point (the traversal does this with the
box's entry distance), so the origin always lies in the box.

The tree
--------
Each of the six faces has its own 5D bisection tree over (x, y, z, u, v).
Its root is the whole hypercube (the aggregate's box, flat axes padded as in
the uniform grid, times [-1, 1]^2). A hypercube is split in the middle of its
longest dimension, measured in units of the root's side along that
dimension (ties: x, y, z, u, v in that order). A node is stored in three
flat entries:

    node_a[i]  int64   inner: first child (second child = node_a + 1); leaf: first entry in items/keys
    node_b[i]  int64   inner: -(dimension + 1); leaf: number of candidates (0: empty)
    split[i]   float64 inner: the split coordinate; a point below it goes to the first child

so a node costs 24 bytes and a candidate 16 (an item index and its key).

Candidate lists
---------------
A hypercube's candidates are the items whose box meets its beam: every
point p + t * w with p in the xyz box, w = s * e_a + u * e_b + v * e_c for
(u, v) in the cell and t >= 0. The beam is the Minkowski sum of the origin
box and the polyhedral cone spanned by the cell's four corner directions,
so it is convex, and "item box A meets the beam" is the same as "the box
A - B (A minus the origin box, itself a box) meets the cone". With
h = s * w_a the cone is h >= 0, u0 h <= w_b <= u1 h, v0 h <= w_c <= v1 h;
intersected with the box that is a system of linear inequalities in the
one unknown h, solved exactly as an interval. This is the paper's convex
hull of the beam without approximating it by a bounding cone; every item
box is widened by 1e-8 of the aggregate's size and every cell by 1e-9 in
u and v, so rounding in the classification can only add candidates.

Every list is sorted by the key of its items along the face's dominant
axis: the near face of the item's box (s * box_min_a for s > 0, -box_max_a
for s < 0, widened by the margin). For a ray of this face no hit with the
item can lie before t = (key - s * o_a) / |d_a|, and the keys rise along the
list, so the traversal stops the list once that bound passes the closest
hit so far.

Subdivision and the memory budget
---------------------------------
A hypercube is split while it holds more than `leaf` candidates, lies less
than `depth` splits below its face root, and splitting still helps: a child
that keeps more than KEEP (3/4) of its parent's candidates is a split without
progress, and after five such splits in a row (one round over the five
dimensions) a hypercube is not split further. Without that rule a 5D tree
of depth 20 grows to about a million hypercubes per face for a few hundred
items. The size of the tree (24 bytes a node, 16 a candidate of a leaf) is
kept under `budget_mb` MiB: the first split that would pass it stops all
further subdivision, the remaining hypercubes stay leaves with their
(longer, still complete) candidate lists, and a warning (RcBudgetWarning)
says so once; stats["budget_exceeded"] is set. Results stay exact; only the
speed suffers. The six roots are always kept, even when they alone exceed
the budget.

Eager (lazy=off, build_rc) builds the trees before any ray is cast, breadth
first over all six faces together, so the budget is spent evenly over the
5D space, most of which no ray ever visits.

Lazy (lazy=on, the default), as Arvo and Kirk subdivide: each face's root
starts as one leaf holding every item, and a leaf is split only where rays
arrive. The trees change only between passes of rays (those of
aggregates/lazyoctree.py, as render.py and RayScene cut them; boundaries
depend only on tile and ray indices), never while rays are in flight. A
leaf that may still split (more than `leaf` candidates, above the depth
limit, not stopped by the progress rule or the budget) is a *candidate*:
during a pass, each ray that reaches it adds one to a counter column of its
tile's or chunk's row. So that one pass can deepen the tree by more than
one level, a candidate counts not only arrivals but where in it they fall:
its cell is split K times more in thought (its *virtual* subtree, split
exactly as real splits would be) and each of the 2**K virtual cells has its
column. K follows the arrivals expected in the next pass: VIRTUAL_LEVELS
for the six roots, else 0 for none and about log2(arrivals / rays) + 2 (at
most VIRTUAL_LEVELS), from the candidate's arrivals in the last pass or,
for a child below its parent's virtual subtree, half of the parent's. So
the columns stay about as many as the candidates plus the rays of a pass.

Between passes, refine() sums the rows (integer sums: any order, any thread
count) and walks each candidate's virtual subtree top down, in node order:
a cell at which at least `rays` rays arrived (counted since it became a
leaf) is split for real, its children's lists taken from its own by the
beam test, and a child's arrivals are those of its virtual cell in this
pass; a cell at the bottom of the virtual subtree may still split once,
its children waiting for rays of their own. Every other leaf waits for
later passes, keeping its count. So a region no ray reaches is never
split, and images, hits and counters are the same at any thread count.
Refinement appends nodes and lists in candidate order, one split after
another; only the beam tests of a list of at least PARALLEL_LIST (256)
candidates are shared among the threads, each writing its own entries of a
mask, so the trees do not depend on the thread count either (on SPD balls
this shortened refinement markedly against one split at a time, moving the
lists together in compiled code included).

The progress rule allows LAZY_STALE_SPLITS (40, eight rounds) splits in a
row without progress instead of five: near the root of a scene with a large
floor no single split separates anything yet (a beam from half of a 24-unit
floor still sweeps the whole cluster of balls), in a cluster of thousands
of items a split keeps most of them until the beams are narrow, and lazily
the rule only guards paths rays actually take, where the budget bounds the
cost anyway. With five, lazy trees stopped there and tested more candidates
per ray than the eager ones (SPD teapot); with 15 and depth 20, SPD balls
made many more tests per ray than with 40 and depth 40 (the default).

Storage: LazyRC keeps the scene's rc node and candidate arrays with room to
grow (doubling); the Geometry handed back views the used part. A split
leaf's list stays behind unused until the unused entries outnumber the
leaves' lists; then, between passes, the lists are moved together (not
while a checkpoint of an all-hits query is out, which needs them in place).
The budget counts the trees' nodes and leaves' lists, as eagerly;
build.bytes counts the arrays as they are, unused entries included.
"""

from __future__ import annotations

import math

import numpy as np

from ..geometry.primitives import PRIMITIVE_KINDS
from .rcbuild import RcArrays, build_rc, start_rc
from .rclazy import LazyRC
from .rcwalk import walk_step
from .spec import Kind, Param
from .walk import Cells, Field, Walk, one_cell

__all__ = ["append_rc", "CODE", "TESTS_PER_STEP"]


# ----------------------------------------------------------------- flat layout (see the module docstring); the walk: rcwalk.py


CODE = 4
FIELDS = (   # and the driver's keyed lists, keyed_key and keyed_ref (walk.py): the candidate lists
    Field("rc_face_root", np.int64, (6,)), Field("rc_node_a", np.int64, ()), Field("rc_node_b", np.int64, ()),
    Field("rc_split", np.float64, ()), Field("rc_pass", np.int64, ()), Field("rc_vinfo", np.int64, (3,)),
    Field("rc_vdim", np.int64, ()), Field("rc_vsplit", np.float64, ()),
)


def append_rc(flat, tree: RcArrays, refs, box) -> int:
    """Store rc trees over refs as the next aggregate."""
    n0, k0 = flat.size("rc_node_b"), flat.size("keyed_key")
    r = flat.size("rc_face_root")
    flat.append(rc_face_root=tree.face_root[None] + n0,
                rc_node_a=np.where(tree.node_b < 0, tree.node_a + n0, tree.node_a + k0), rc_node_b=tree.node_b,
                rc_split=tree.split, rc_pass=np.full(len(tree.node_b), -1), keyed_key=tree.keys, keyed_ref=refs[tree.items])
    return flat.add_aggregate(CODE, r, len(tree.node_b), box)


def flatten(builder, params, refs, bounds, name, box):
    flat = builder.flat
    if params["lazy"]:
        # six root leaves now, split between passes where rays arrive (LazyRC)
        tree, stats, boxes, keys = start_rc(bounds, leaf=params["leaf"], depth=params["depth"],
                                            budget_mb=params["budget_mb"], rays=params["rays"], name=name)
        flat.lazy[KIND.name].append(dict(params, node=flat.size("rc_node_b"), cand=flat.size("keyed_key"),
                                         items=tree.items, boxes=boxes, box=tree.box, stats=stats, name=name,
                                         max_bytes=builder.max_bytes))
    else:
        tree, stats = build_rc(bounds, leaf=params["leaf"], depth=params["depth"], budget_mb=params["budget_mb"],
                               name=name, max_bytes=builder.max_bytes)
    return append_rc(flat, tree, refs, box), stats


TESTS_PER_STEP = 8       # test.rc: the first tests of each hypercube's list; test.rc.more: the rest


def features(stats, f, used) -> None:
    """The cost model's features. In a render walked by ray classification alone, the first
    TESTS_PER_STEP ray/primitive tests of each hypercube visited (test.rc): its candidate lists,
    sorted by distance, send them to primitives scattered in memory (clearly more a test than a
    grid's in the reference costs); the tests further down a long list (test.rc.more) cost no
    more than a grid's (priced as the first, SPD balls' and shells' long lists of spheres were
    much over-predicted); and the corners its tests walked (polygon.corner.rc). A lazy one's
    rays weighted by log2(1 + MiB of its structure) (ray.lazy.rc_mb: a ray's hypercube and
    candidates are found in memory that grows with the refinement), and its refinement's
    references by the MiB themselves (refine.rc.ref_size: past the caches, at the hundreds of
    MiB rc reaches on a 256-pixel render, a reference costs markedly more than at a few MiB)."""
    if used == {"rc"}:
        tests = sum(float(stats.get(f"tests.{k}", 0)) for k in PRIMITIVE_KINDS)
        f["test.rc"] = min(tests, TESTS_PER_STEP * f["step.rc"])
        f["test.rc.more"] = tests - f["test.rc"]
        f["polygon.corner.rc"] = float(stats.get("polygon.corners", 0))
    rays = f["ray.shaded"] + f["ray.shadow"]
    for a in getattr(stats, "aggregates", []):
        if "subdivisions" in a and a.get("kind", "").split("(")[0] == "rc":
            megabytes = math.log2(1.0 + a.get("bytes", 0) / 2 ** 20)
            f["ray.lazy.rc_mb"] = f.get("ray.lazy.rc_mb", 0.0) + rays * megabytes
            f["refine.rc.ref_size"] = f.get("refine.rc.ref_size", 0.0) + float(a.get("refs", 0)) * a.get("bytes", 0) / 2 ** 20


def references(geo, a) -> np.ndarray:
    """Every reference of rc aggregate a's candidate lists, once (Walk.references)."""
    todo, found = list(geo.rc_face_root[geo.agg_start[a]]), []
    seen = set()
    while todo:
        node = int(todo.pop())
        if node in seen:
            continue
        seen.add(node)
        nb = int(geo.rc_node_b[node])
        if nb < 0:
            todo += [int(geo.rc_node_a[node]), int(geo.rc_node_a[node]) + 1]
        elif nb:
            found.append(geo.keyed_ref[geo.rc_node_a[node]:geo.rc_node_a[node] + nb])
    return np.unique(np.concatenate(found)) if found else np.zeros(0, np.int64)


def cells(geo, a) -> Cells:
    """The aggregate's box (its beams live in the space of rays), holding its candidates (Walk.cells)."""
    return one_cell(geo.agg_bounds[a], 0, len(references(geo, a)))


WALK = Walk(code=CODE, name="rc", fields=FIELDS, step=walk_step, features=features, cells=cells,
            references=references)
# the annealer does not offer it: a sample of rays would price the lazy one as the coarse trees it
# leaves, and the eager one costs more to build, on scenes of thousands of items, than a search has
# time for
KIND = Kind("rc", "ray classification (Arvo-Kirk 1987): rays as 5D points (origin, direction-cube face and "
              "u, v), six 5D bisection trees, candidate lists tested near first; lazy (default): each face's root "
              "starts as one leaf, and between passes of rays (those of lazyoctree) a leaf where at least `rays` "
              "rays arrived is split, several levels where the arrivals go on; lazy=off builds the whole trees "
              "before any ray", (
    Param("leaf", 8, "a hypercube with at most this many candidates is not split", int, 1, 1 << 20),
    Param("depth", 40, "most splits below a face's root hypercube", int, 0, 200),
    Param("budget_mb", 256.0, "MiB the trees and candidate lists may take; reaching it stops subdivision "
          "with a warning (hits stay exact)", float, 0.0, 1 << 20),
    Param("lazy", True, "on: subdivide lazily where rays arrive (Arvo and Kirk), a hypercube stopping after 40 "
          "splits in a row that each keep more than 3/4 of its candidates; off: eagerly, breadth first over all "
          "of 5D space until leaf, depth, 5 such splits or the budget stop it", bool),
    Param("rays", 1, "lazy: rays that must arrive at a leaf before it is split", int, 1, 1 << 40),
), flatten=flatten, walk=WALK, lazy=LazyRC)

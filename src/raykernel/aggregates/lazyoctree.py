"""Lazy octree (Lathrop, Ray Tracing News 2(1), 1988): one leaf at first,
subdivided between passes of rays where rays pass.

    geo, build = flatten(scene, default_accel="lazyoctree(rays=2, k=0)")
    lazy = build.get("lazy")     # LazyOctrees of the scene, None without lazy octrees
    geo = lazy.refine(geo, pass_counts)   # after each pass: (work items, lazy.columns) int64

render() and RayScene do this themselves; cast_rays (traverse.py) counts no
passes and so never refines.

Tree and walks
--------------
A lazy octree is an octree (aggregates/octree.py) stored in the same arrays
and walked by the same code (walk=point, neighbor or parametric, mailbox),
without collapse. It starts as one leaf over the octree's root box holding
every item. Subdividing a leaf makes its 8 children with the octree's own
insertion: centre split on the 28-bit addresses, each item into every child
its box (widened by the octree's margin) overlaps. Neighbour pointers of the
new children and of smaller nodes that pointed at the split leaf are found
again by descent from the root, as the octree builder finds them.

Criteria
--------
A leaf is subdivided when all of these hold:
  I    its level is below ``depth`` (the root is level 0; depth=0 never refines);
  II   it is not empty;
  III  it holds more than one item (M > 1);
  IV   at least ``rays`` rays have passed through it without a hit in it since
       it was made (N >= rays);
  V    M * k < N: a leaf of many items needs more evidence (``k`` weighs one
       item against one ray pass; k=0, the default, leaves criterion IV alone);
  VI   with ``rule60`` on, Haines's problem-voxel rule: not when its largest
       child would still hold at least 60% of its items, unless that child is
       the only occupied one. A leaf this keeps stays a leaf for good.
and, as for the octree, ``budget``: the split does not take the references
held by the tree's leaves past budget * items + 4096 (0: no budget); a leaf
the budget cannot pay for stays a leaf for good.

Defaults: depth 16, rays 2, k 0, budget 16, rule60 off. Criterion V is off
by default because it delays exactly the leaves that cost most: every ray
that reaches a leaf of M items tests M of them, so waiting for k*M passes
costs about k*M^2 tests (even a small k makes SPD balls test many times
more items per ray than k=0). The budget stands in for it: where two items'
boxes overlap, no split separates them, and rays passing between them would
split their cells down to the depth limit (SPD balls at 512x512 without a
budget reach MAX_NODES and gigabytes; with it, a tree of the eager
`octree`'s order of size: bench/structures.py measures both, docs/benchmarks/
structures.md, "Lazy structures and image size").
A ray *passes through* a leaf when, after the leaf's items are tested, its
closest hit so far (or its tmax) is not before the leaf's exit distance; a
ray that stops in the leaf, meets its end there or, as an any-hit ray, finds
a hit there does not count. The walk counts this with an OCT_PASS stack
entry (traverse.py) above the leaf's continuation. Only *candidates*
(leaves meeting I-III, not kept by VI) have a counter column, so leaves that
can never split cost nothing.

Several levels in one refinement
--------------------------------
Lathrop applies the criteria ray by ray: once a leaf meets them it is split,
and the next ray to come already meets its children. Between passes we read
this so: of a leaf's N passes, the first need = max(rays, floor(M*k) + 1)
were what it took to split it; the N - need after them would have met its
children. Each of those rays hit nothing in the leaf, so it passed through
every child it crossed, and it crossed at least one: the children together
had at least N - need passes, we do not know where. Each child starts with
an equal share, (N - need) // CHILD_SHARE (8), never more in total than they
surely had. A child whose share meets the criteria splits in the same
refinement and shares its own surplus the same way, down to ``depth``; later
passes add to the shares. The shares are an estimate: rays that all crossed
one side of a leaf credit the children on the other side too, so children
(and, dividing by 8 a level, their children) of a leaf passed by many rays
may split where no ray went. Without the shares each pass deepens the tree
by one level at most, and the rays of a region seen for the first time meet
its coarse leaves pass after pass.

Passes and determinism
----------------------
The tree changes only between passes, never while rays are in flight.
The renderer traces its image coarse to fine (render.lazy_passes): first
one sample per 16 x 16 tile, in passes of 1, 1, 2, 4, ... tiles up to a
batch of n_tiles // 32, so the tree is deepened over the whole view
by a few rays at a time; then the samples halfway between those traced,
level by level (steps of 8, 4, 2 and 1 sample), in batches of tiles. Each
ray then meets a tree that the rays of its neighbours have already
refined; traced tile by tile instead, each new tile's rays met the coarse
leaves of a region seen for the first time (on SPD balls and the stadium,
tile by tile tested many times more items per ray). RayScene takes its rays coarse to fine
too (rayqueries.coarse_to_fine: ray 0, then every odd multiple of 2^k for k
from high to low) in passes (pass_ranges) of FIRST_PASS = 16 rays, 16, 32,
... up to PASS_CHUNKS chunks of CHUNK rays (8192). Boundaries depend only
on tile and ray indices. During a pass, every tile or chunk counts passes into its
own columns after the N_COUNTERS ordinary counters; refine() sums them
(integer sums: any order) and splits every leaf that meets the criteria, in
node order. So images, hits and every counter are the same at any thread
count, and the same scene and rays give the same tree. RayScene keeps its
trees refined from one query to the next; an all-hits query, which runs
its rays twice, puts the trees back (checkpoint/restore) before the second
run so that both meet the same trees.

Storage
-------
Nodes and references are appended to the scene's global octree and
reference arrays, which are kept with room to grow (doubling) so that a
refinement writes only its new nodes in place; the Geometry handed back
views the used part. A split leaf's old references stay behind unused
(counted in build.bytes, not in the aggregate's refs). Nested lazy octrees
and lazy octrees shown by many instances refine like top-level ones: an
aggregate is built once and every frame that walks it counts into the same
columns. A scene's lazy octrees together stop subdividing at MAX_NODES nodes
(octbuild.MAX_NODES); hits stay exact, the aggregate reports budget_reached.

Statistics per aggregate: nodes (N_IN + N_V), inner, leaves, empty_leaves
(N_EV), refs (N_OIV), bytes, max_depth of the final tree; passes
(refinement points gone through), subdivisions (leaves split) and
refine_seconds. build.refine_passes, build.subdivisions and
build.refine_seconds sum them for the scene.
"""

from __future__ import annotations

import time

import numpy as np

from ..errors import OptionError
from ..geometry.config import njit
from ..options import number
from .lazyset import scene_totals, tree_counts
from .memory import check, grown
from .octbuild import ADDRESS_BITS, BUDGET_SLACK, MAX_DEPTH, MAX_NODES, OctreeArrays, octree_frame, overlaps
from .octree import WALK, append_octree
from .spec import Kind, Param

__all__ = ["LazyOctrees", "build_lazy"]
CHILD_SHARE = 8            # a split leaf's surplus passes are shared out among its 8 children
# bytes of one node in the octree arrays: bounds 48, first 8, count 8, loc 24,
# level 8, slot 8, neighbours 48, pass column 8
NODE_BYTES = 160
_KEPT, _SPLIT, _BUDGET = 0, 1, 2   # _split's status of a chosen leaf
_NODE_FIELDS = ("oct_bounds", "oct_first", "oct_count", "oct_loc", "oct_level", "oct_slot", "oct_nbr", "oct_pass")


def build_lazy(bounds, *, depth=16, rays=2, k=0.0, rule60=False, budget=16.0, name=None):
    """The one-leaf start of a lazy octree over item boxes (at least one finite box).

    Returns (OctreeArrays with one node, stats, widened item boxes for later splits)."""
    t0 = time.perf_counter()
    number(depth, "lazyoctree depth", 0, MAX_DEPTH, integer=True)
    budget = float(number(budget, "lazyoctree budget", 0.0, 1e6))
    number(rays, "lazyoctree rays", 1, 1 << 40, integer=True)
    k = float(number(k, "lazyoctree k", 0.0, 1e9))
    if not isinstance(rule60, (bool, np.bool_)):
        raise OptionError(f"lazyoctree rule60 must be on or off, got {rule60!r}")
    # the octree's frame, so a fully refined lazy octree holds what octree(leaf=1, collapse=off) holds
    items, _, origin, unit, widened = octree_frame(bounds, depth, "a lazy octree")
    n = len(items)
    full = float(1 << ADDRESS_BITS)
    tree = OctreeArrays(origin=origin, unit=unit, first=np.zeros(1, np.int64), count=np.full(1, n, np.int64),
                        loc=np.zeros((1, 3), np.int64), level=np.zeros(1, np.int64), slot=np.zeros(1, np.int64),
                        nbr=np.full((1, 6), -1, np.int64),
                        bounds=np.concatenate([origin, origin + unit * full])[None, :],
                        order=np.arange(n, dtype=np.int64))
    stats = {"nodes": 1, "inner": 0, "leaves": 1, "empty_leaves": 0, "refs": n,
             "bytes": NODE_BYTES + 8 * n + 48, "max_depth": 0, "passes": 0, "subdivisions": 0,
             "refine_seconds": 0.0, "budget_reached": False, "seconds": time.perf_counter() - t0,
             "budget_refs": int(budget * n) + BUDGET_SLACK if budget > 0 else 0}
    return tree, stats, np.ascontiguousarray(widened)


# ----------------------------------------------------------------- kernels

@njit
def _split(nodes, owner, origin, unit, rule60, live_refs, max_refs, boxes, item_ref, ref_item, refs, first, count,
           loc, level, slot, bounds, n_nodes, n_refs):
    """Subdivide each leaf of `nodes` one level in place, appending its 8 children at
    n_nodes and their references at n_refs. Returns (status per node: _SPLIT, _KEPT by
    rule60, or _BUDGET when the children would take its tree's leaf references,
    live_refs, past max_refs), the new n_nodes and n_refs."""
    n_split = nodes.shape[0]
    status = np.zeros(n_split, np.int64)
    clo = np.empty((8, 3))
    chi = np.empty((8, 3))
    child_n = np.zeros(8, np.int64)
    for s in range(n_split):
        node = nodes[s]
        r = owner[node]
        st = first[node]
        m = count[node]
        lv = level[node]
        half = np.int64(1) << (ADDRESS_BITS - 1 - lv)
        for c in range(8):
            for a in range(3):
                lo = loc[node, a] + ((c >> a) & 1) * half
                clo[c, a] = origin[r, a] + unit[r, a] * lo
                chi[c, a] = origin[r, a] + unit[r, a] * (lo + half)
        # the children each item's box overlaps (closed intervals, as in octbuild._subdivide)
        mask = np.zeros(m, np.int64)
        for c in range(8):
            child_n[c] = 0
        for p in range(m):
            it = ref_item[st + p]
            bits = 0
            for c in range(8):
                if overlaps(boxes, it, clo, chi, c):
                    bits |= 1 << c
                    child_n[c] += 1
            mask[p] = bits
        if rule60[r]:
            biggest = 0
            occupied = 0
            for c in range(8):
                biggest = max(biggest, child_n[c])
                occupied += child_n[c] > 0
            if biggest * 10 >= 6 * m and occupied > 1:
                status[s] = _KEPT
                continue
        added = -m
        for c in range(8):
            added += child_n[c]
        if max_refs[r] > 0 and live_refs[r] + added > max_refs[r]:
            status[s] = _BUDGET
            continue
        live_refs[r] += added
        base = n_nodes
        n_nodes += 8
        pos = n_refs
        for c in range(8):
            kid = base + c
            owner[kid] = r
            first[kid] = pos
            count[kid] = child_n[c]
            level[kid] = lv + 1
            slot[kid] = lv + 1
            for a in range(3):
                lo = loc[node, a] + ((c >> a) & 1) * half
                loc[kid, a] = lo
                bounds[kid, a] = origin[r, a] + unit[r, a] * lo
                bounds[kid, a + 3] = origin[r, a] + unit[r, a] * (lo + half)
            for p in range(m):
                if (mask[p] >> c) & 1:
                    it = ref_item[st + p]
                    refs[pos] = item_ref[it]
                    ref_item[pos] = it
                    pos += 1
        n_refs = pos
        first[node] = base
        count[node] = -1
        status[s] = _SPLIT
    return status, n_nodes, n_refs


@njit
def _link(new_lo, new_hi, scan_lo, split_mask, roots, owner, first, count, loc, level, slot, nbr):
    """Neighbour pointers (octree.py) of the new nodes [new_lo, new_hi), and of the older
    lazy nodes [scan_lo, new_lo) that pointed at a split node larger than themselves."""
    full = np.int64(1) << ADDRESS_BITS
    q = np.empty(3, np.int64)
    for j in range(scan_lo, new_hi):
        for wall in range(6):
            if j < new_lo:
                m = nbr[j, wall]
                if m < 0 or not split_mask[m] or slot[j] <= level[m]:
                    continue
            a = wall >> 1
            sh = ADDRESS_BITS - slot[j]
            side = np.int64(1) << sh
            for b in range(3):
                q[b] = (loc[j, b] >> sh) << sh
            q[a] += side if wall & 1 else -side
            if q[a] < 0 or q[a] >= full:
                nbr[j, wall] = -1
                continue
            # descend from the root to the adjacent cell of j's size, or the leaf holding it
            node = roots[owner[j]]
            while count[node] < 0 and level[node] < slot[j]:
                bit = ADDRESS_BITS - 1 - level[node]
                node = first[node] + ((q[0] >> bit) & 1) + 2 * ((q[1] >> bit) & 1) + 4 * ((q[2] >> bit) & 1)
            nbr[j, wall] = node


# ----------------------------------------------------------------- the scene's lazy octrees

class LazyOctrees:
    """Every lazy octree of one built scene, with room to grow its arrays.

    columns: pass counter columns a pass must provide after counters.N_COUNTERS
    (one per candidate leaf); refine() takes their counts and returns the
    Geometry to use next."""

    def __init__(self):
        raise TypeError("use LazyOctrees.attach(geo, records)")

    @classmethod
    def attach(cls, geo, records, base=0):
        """Take over geo's octree and reference arrays for the lazy octrees in `records`
        (from flatten: octree index, root node, first ref, widened boxes, refs, params,
        stats dict), their pass columns numbered from `base`. Returns (geo viewing the growable
        arrays, LazyOctrees)."""
        self = object.__new__(cls)
        self.records = records
        self.base = int(base)
        self.max_bytes = min(rec["max_bytes"] for rec in records)
        n, nr = len(geo.oct_count), len(geo.refs)
        self.n0, self.n_nodes, self.n_refs = n, n, nr
        self.buf = {}
        cap = n + max(1024, n)
        for name in _NODE_FIELDS:
            a = getattr(geo, name)
            b = np.empty((cap,) + a.shape[1:], a.dtype)
            b[:n] = a
            self.buf[name] = b
        self.owner = np.full(cap, -1, np.int64)
        self.acc = np.zeros(cap, np.int64)
        self.final = np.zeros(cap, np.bool_)
        rcap = nr + max(4096, nr)
        self.refs = np.empty(rcap, np.int64)
        self.refs[:nr] = geo.refs
        self.ref_item = np.full(rcap, -1, np.int64)
        boxes, item_refs = [], []
        n_items = 0
        for r, rec in enumerate(records):
            root, start, m = rec["node"], rec["ref"], len(rec["refs"])
            self.owner[root] = r
            self.ref_item[start:start + m] = np.arange(n_items, n_items + m)
            boxes.append(rec["boxes"])
            item_refs.append(rec["refs"])
            n_items += m
        self.boxes = np.ascontiguousarray(np.concatenate(boxes))
        self.item_ref = np.ascontiguousarray(np.concatenate(item_refs), np.int64)
        self.roots = np.array([rec["node"] for rec in records], np.int64)
        self.origin = np.array([geo.oct_origin[rec["octree"]] for rec in records], np.float64).reshape(-1, 3)
        self.unit = np.array([geo.oct_unit[rec["octree"]] for rec in records], np.float64).reshape(-1, 3)
        self.depth = np.array([rec["depth"] for rec in records], np.int64)
        self.rays = np.array([rec["rays"] for rec in records], np.int64)
        self.k = np.array([rec["k"] for rec in records], np.float64)
        self.rule60 = np.array([rec["rule60"] for rec in records], np.int64)
        self.subdivisions = np.zeros(len(records), np.int64)
        self.budget_reached = np.zeros(len(records), np.bool_)
        self.live_refs = np.array([len(rec["refs"]) for rec in records], np.int64)
        self.max_refs = np.array([rec["stats"]["budget_refs"] for rec in records], np.int64)
        self.passes = 0
        self.seconds = 0.0
        roots = self.roots
        self.cand = roots[(self.buf["oct_count"][roots] > 1) & (self.depth > 0)]
        self._number()
        return self._view(geo), self

    # ------------------------------------------------------------- passes

    @property
    def columns(self) -> int:
        return len(self.cand)

    def refine(self, geo, pass_counts, base=None):
        """Add a pass's counts ((work items, columns) int64, one row per tile or chunk)
        to the candidates and subdivide those that meet the criteria; number the columns of
        the next pass from `base` (columns of other lazy structures before these). Returns
        the Geometry to trace the next pass with."""
        t0 = time.perf_counter()
        if base is not None and base != self.base:
            self.base = int(base)
            self._number()
            geo = self._view(geo)
        pass_counts = np.asarray(pass_counts)
        if pass_counts.ndim != 2 or pass_counts.shape[1] != len(self.cand):
            raise ValueError(f"pass counts must have {len(self.cand)} columns, got shape {pass_counts.shape}")
        self.passes += 1
        cand = self.cand
        if len(cand):
            self.acc[cand] += pass_counts.sum(axis=0, dtype=np.int64)
            chosen = self._ready(cand)
            if len(chosen):
                # children that inherit enough passes split at once, and so on down
                while len(chosen):
                    old_n = self.n_nodes
                    self._subdivide(chosen)
                    chosen = self._ready(self.cand[self.cand >= old_n])
                geo = self._view(geo)
        self.seconds += time.perf_counter() - t0
        return geo

    def _need(self, nodes):
        """The passes after which each leaf of `nodes` meets IV and V: max(rays, floor(M*k) + 1)."""
        own = self.owner[nodes]
        m = self.buf["oct_count"][nodes]
        return np.maximum(self.rays[own], np.floor(m * self.k[own]).astype(np.int64) + 1)

    def _ready(self, nodes):
        """The candidates among `nodes` that meet IV and V."""
        return nodes[self.acc[nodes] >= self._need(nodes)]

    def _subdivide(self, chosen):
        room = max(0, MAX_NODES - self.n_nodes) // 8
        if len(chosen) > room:
            # the node budget: the first in node order split, every other candidate stays a leaf for good
            self.final[self.cand] = True
            self.budget_reached[np.unique(self.owner[self.cand])] = True
            chosen = chosen[:room]
            if not len(chosen):
                self._retire()
                return
        b = self.buf
        self._reserve(8 * len(chosen), 8 * int(b["oct_count"][chosen].sum()))
        b = self.buf
        old_n = self.n_nodes
        surplus = self.acc[chosen] - self._need(chosen)
        status, n_nodes, n_refs = _split(chosen, self.owner, self.origin, self.unit, self.rule60, self.live_refs,
                                         self.max_refs, self.boxes, self.item_ref, self.ref_item, self.refs,
                                         b["oct_first"], b["oct_count"], b["oct_loc"], b["oct_level"], b["oct_slot"],
                                         b["oct_bounds"], np.int64(self.n_nodes), np.int64(self.n_refs))
        self.n_nodes, self.n_refs = int(n_nodes), int(n_refs)
        split = chosen[status == _SPLIT]
        self.final[chosen[status != _SPLIT]] = True
        self.budget_reached[np.unique(self.owner[chosen[status == _BUDGET]])] = True
        np.add.at(self.subdivisions, self.owner[split], 1)
        # the passes after the one that split it would have met the children (split's order is theirs)
        self.acc[old_n:self.n_nodes] = np.repeat(surplus[status == _SPLIT] // CHILD_SHARE, 8)
        self.final[old_n:self.n_nodes] = False
        b["oct_pass"][old_n:self.n_nodes] = -1
        mask = np.zeros(self.n_nodes, np.bool_)
        mask[split] = True
        _link(np.int64(old_n), np.int64(self.n_nodes), np.int64(self.n0), mask, self.roots, self.owner,
              b["oct_first"], b["oct_count"], b["oct_loc"], b["oct_level"], b["oct_slot"], b["oct_nbr"])
        kids = np.arange(old_n, self.n_nodes, dtype=np.int64)
        kids = kids[(b["oct_count"][kids] > 1) & (b["oct_level"][kids] < self.depth[self.owner[kids]])]
        if MAX_NODES - self.n_nodes < 8:
            self.final[kids] = True
            self.budget_reached[np.unique(self.owner[kids])] = True
            kids = kids[:0]
        self._retire(extra=kids)

    def _retire(self, extra=None):
        """Candidates from now on: the old ones still leaves and not kept for good, and `extra`."""
        b = self.buf
        keep = self.cand[(b["oct_count"][self.cand] > 1) & ~self.final[self.cand]]
        b["oct_pass"][self.cand] = -1
        self.cand = keep if extra is None else np.concatenate([keep, extra])
        self._number()

    def _number(self):
        # columns in node order, from base
        self.cand = np.sort(self.cand)
        self.buf["oct_pass"][self.cand] = self.base + np.arange(len(self.cand), dtype=np.int64)

    def _reserve(self, nodes, refs):
        node_cap = max(len(self.owner), self.n_nodes + nodes)
        ref_cap = max(len(self.refs), self.n_refs + refs)
        if node_cap > len(self.owner):
            node_cap = max(node_cap, 2 * len(self.owner))
        if ref_cap > len(self.refs):
            ref_cap = max(ref_cap, 2 * len(self.refs))
        node_bytes = sum(a.itemsize * (a.size // len(a)) for a in self.buf.values()) + 17
        check(node_cap * node_bytes * 2 + ref_cap * 16 * 2, self.max_bytes, "the lazy octrees' refinement",
              "lower depth or give them a reference budget (budget=16)")
        need = self.n_nodes + nodes
        if need > len(self.owner):
            cap = max(need, 2 * len(self.owner))
            for name, a in list(self.buf.items()):
                self.buf[name] = grown(a, cap, self.n_nodes)
            self.owner = grown(self.owner, cap, self.n_nodes)
            self.acc = grown(self.acc, cap, self.n_nodes)
            self.final = grown(self.final, cap, self.n_nodes)
        need = self.n_refs + refs
        if need > len(self.refs):
            cap = max(need, 2 * len(self.refs))
            self.refs = grown(self.refs, cap, self.n_refs)
            self.ref_item = grown(self.ref_item, cap, self.n_refs)

    def _view(self, geo):
        n, b = self.n_nodes, self.buf
        return geo._replace(refs=self.refs[:self.n_refs], **{name: b[name][:n] for name in _NODE_FIELDS})

    # ------------------------------------------------------------- all-hits queries run twice

    def checkpoint(self):
        """The state to go back to, so that a second run over the same rays makes the same tree."""
        n, b = self.n_nodes, self.buf
        return dict(n_nodes=n, n_refs=self.n_refs, cand=self.cand.copy(), passes=self.passes,
                    subdivisions=self.subdivisions.copy(), budget=self.budget_reached.copy(),
                    live_refs=self.live_refs.copy(),
                    arrays={name: b[name][:n].copy() for name in ("oct_first", "oct_count", "oct_nbr", "oct_pass")},
                    acc=self.acc[:n].copy(), final=self.final[:n].copy())

    def restore(self, mark, geo):
        """Back to `mark` (from checkpoint); returns the Geometry to use."""
        n = mark["n_nodes"]
        for name, a in mark["arrays"].items():
            self.buf[name][:n] = a
        self.acc[:n] = mark["acc"]
        self.final[:n] = mark["final"]
        self.n_nodes, self.n_refs = n, mark["n_refs"]
        self.cand = mark["cand"]
        self.passes = mark["passes"]
        self.subdivisions = mark["subdivisions"]
        self.budget_reached = mark["budget"]
        self.live_refs = mark["live_refs"].copy()
        return self._view(geo)

    # ------------------------------------------------------------- statistics

    def update_stats(self, build, geo):
        """Write the trees as they now stand into the build statistics of flatten()."""
        n, b = self.n_nodes, self.buf
        owner = self.owner[:n]
        count = b["oct_count"][:n]
        level = b["oct_level"][:n]
        for r, rec in enumerate(self.records):
            sel = owner == r
            tree = tree_counts(count[sel])
            rec["stats"].update(tree, bytes=tree["nodes"] * NODE_BYTES + 8 * tree["refs"] + 48,
                                max_depth=int(level[sel].max()), passes=self.passes,
                                subdivisions=int(self.subdivisions[r]), refine_seconds=self.seconds,
                                budget_reached=bool(self.budget_reached[r]))
        scene_totals(build, geo, self.passes, int(self.subdivisions.sum()), self.seconds)


def flatten(builder, params, refs, bounds, name, box):
    # Lathrop's lazy octree: one leaf now, subdivided between passes of rays
    flat = builder.flat
    tree, stats, boxes = build_lazy(bounds, depth=params["depth"], rays=params["rays"], k=params["k"],
                                    rule60=params["rule60"], budget=params["budget"], name=name)
    flat.lazy[KIND.name].append(dict(params, octree=flat.size("oct_root"), node=flat.size("oct_count"),
                                     ref=flat.size("refs"), refs=refs, boxes=boxes, stats=stats,
                                     max_bytes=builder.max_bytes))
    return append_octree(flat, tree, refs, params["walk"], params["mailbox"], box), stats


KIND = Kind("lazyoctree", "lazy octree (Lathrop 1988): one leaf at first; between passes of rays (passes "
              "that trace a render coarse to fine: one sample per tile, then the samples between, level by "
              "level; RayScene from 16 rays up to 8 chunks of 8192) a leaf is split, as the octree splits, when "
              "it meets I-V (and VI with rule60) and the reference budget allows: I level < depth, II not empty, "
              "III more than one item (M > 1), IV at least `rays` rays passed through it "
              "without a hit in it since it was made (N >= rays), V M*k < N; passes beyond what a split needed "
              "are shared among the children, which may split in the same refinement", (
    Param("depth", 16, "criterion I: most levels (the root is level 0; 0 never refines)", int, 0, 24),
    Param("rays", 2, "criterion IV: rays that must pass through a leaf without a hit in it before it may split",
          int, 1, 1 << 40),
    Param("k", 0.0, "criterion V: a leaf of M items splits only after more than k*M passes (0: off)", float,
          0.0, 1e9),
    Param("rule60", False, "criterion VI, Haines's problem-voxel rule: a leaf whose largest child would still "
          "hold >= 60% of its items (unless the only occupied one) stays a leaf for good", bool),
    Param("budget", 16.0, "the leaves hold at most budget * items + 4096 references; a split past it is not made "
          "and its leaf stays a leaf (0: no budget)", float, 0.0, 1e6),
    Param("walk", "neighbor", "traversal: point, neighbor or parametric (see octree)", str,
          choices=("point", "neighbor", "parametric")),
    Param("mailbox", True, "skip items already tested against the ray in an earlier leaf", bool),
), flatten=flatten, walk=WALK, lazy=LazyOctrees)

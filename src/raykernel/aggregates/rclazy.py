"""Lazy ray classification: every lazy rc aggregate of a scene, its leaves split between passes where rays arrive.

    geo, build = flatten(scene, "rc")              # rc.py's flatten records start_rc's six root leaves
    geo = build["lazy"].refine(geo, pass_counts)   # LazyRC (through lazyset.LazySet) between passes of rays
    geo, lazy = LazyRC.attach(geo, records)        # what the LazySet does with the records
    mark = lazy.checkpoint(); geo = lazy.restore(mark, geo)   # an all-hits query's second run

rc.py's docstring says how (virtual subtrees, the counter columns, the progress
rule, storage); rcbuild.py holds the beam test and the split rule the eager
build shares with it.
"""

from __future__ import annotations

import time

import numpy as np
from numba import prange

from ..geometry.config import njit
from .lazyset import scene_totals, tree_counts
from .memory import grown, over_budget
from .rcbuild import (CANDIDATE_BYTES, KEEP, NODE_BYTES, PEAK_FACTOR, budget_warning, longest, meets_beam,
                      memory_budget)

__all__ = ["LazyRC", "VIRTUAL_LEVELS", "LAZY_STALE_SPLITS"]

LAZY_STALE_SPLITS = 40      # rcbuild.STALE_SPLITS, lazy: eight rounds over x, y, z, u, v (rc.py's docstring)
VIRTUAL_LEVELS = 5          # lazy: most levels of a candidate's virtual subtree (one round over x, y, z, u, v)
PARALLEL_LIST = 256        # lazy: a list at least this long is beam-tested by all threads when split
# lazy: per-node state columns (owner aggregate, face, depth, progress-free splits in a row, arrivals,
# arrivals expected in a pass)
_OWNER, _FACE, _DEPTH, _STALE, _ARRIVED, _RATE = range(6)


# ----------------------------------------------------------------- lazy subdivision

@njit(parallel=True)
def _beam_sides(bx, item, st, m, lo, hi, face, side_mask):
    """side_mask[p] for the p-th candidate of a list at st: bit s set if it meets the beam of
    side s of a split (lo[s], hi[s]); all threads, for long lists."""
    for p in prange(m):
        it = item[st + p]
        side_mask[p] = (1 if meets_beam(bx, it, lo[0], hi[0], face) else 0) | \
            (2 if meets_beam(bx, it, lo[1], hi[1], face) else 0)


@njit
def _refine_kernel(cand, levels, hoff, hist, node_a, node_b, split, key, ref, item, state, cell, n_nodes, n_cands,
                   bx, norm, p_leaf, p_depth, p_rays, p_stale, budget, used, exhausted, subdivisions, keep):
    """Split candidates where their arrivals say so (rc.py's docstring), in candidate order.
    cand: candidate leaves, in node order; levels: K of each; hist[hoff[j]:hoff[j] + 2**K]:
    arrivals of this pass in each virtual cell of candidate j. Appends nodes at n_nodes and
    lists at n_cands, growing the arrays as needed. Returns the arrays, n_nodes, n_cands."""
    heap = np.zeros(2 << VIRTUAL_LEVELS, np.int64)
    st_node = np.empty(2 * VIRTUAL_LEVELS + 2, np.int64)
    st_h = np.empty(2 * VIRTUAL_LEVELS + 2, np.int64)
    lo2 = np.empty((2, 5))      # the two children's cells
    hi2 = np.empty((2, 5))
    side_mask = np.zeros(0, np.int64)
    counts = np.zeros(2, np.int64)
    for j in range(cand.shape[0]):
        c = cand[j]
        r = state[c, _OWNER]
        k = levels[j]
        v = 1 << k
        # arrivals per virtual node (heap order: node h has children 2h and 2h + 1, cells at v..2v-1)
        for q in range(v):
            heap[v + q] = hist[hoff[j] + q]
        for h in range(v - 1, 0, -1):
            heap[h] = heap[2 * h] + heap[2 * h + 1]
        state[c, _ARRIVED] += heap[1]
        state[c, _RATE] = heap[1]
        st_node[0] = c
        st_h[0] = 1
        sp = 1
        while sp > 0:
            sp -= 1
            nd = st_node[sp]
            h = st_h[sp]
            m = node_b[nd]
            if exhausted[r] or state[nd, _ARRIVED] < p_rays[r] or m <= p_leaf[r] or \
                    state[nd, _DEPTH] >= p_depth[r] or state[nd, _STALE] >= p_stale[r]:
                continue
            face = state[nd, _FACE]
            dim = longest(cell[nd, :5], cell[nd, 5:], norm[r])
            mid = 0.5 * (cell[nd, dim] + cell[nd, 5 + dim])
            # the children's lists from the parent's, in the same (key) order
            key = grown(key, n_cands + 2 * m, key.shape[0])
            ref = grown(ref, n_cands + 2 * m, ref.shape[0])
            item = grown(item, n_cands + 2 * m, item.shape[0])
            start0 = n_cands
            st = node_a[nd]
            for side in range(2):
                for q in range(5):
                    lo2[side, q] = cell[nd, q]
                    hi2[side, q] = cell[nd, 5 + q]
            hi2[0, dim] = mid
            lo2[1, dim] = mid
            if m >= PARALLEL_LIST:
                side_mask = grown(side_mask, m, side_mask.shape[0])
                _beam_sides(bx, item, st, m, lo2, hi2, face, side_mask)
            for side in range(2):
                counts[side] = 0
                for q in range(st, st + m):
                    it = item[q]
                    if m >= PARALLEL_LIST:
                        inside = (side_mask[q - st] >> side) & 1 == 1
                    else:
                        inside = meets_beam(bx, it, lo2[side], hi2[side], face)
                    if inside:
                        key[n_cands] = key[q]
                        ref[n_cands] = ref[q]
                        item[n_cands] = it
                        n_cands += 1
                        counts[side] += 1
            delta = 2 * NODE_BYTES + CANDIDATE_BYTES * (counts[0] + counts[1] - m)
            if used[r] + delta > budget[r]:
                # the budget: this aggregate's trees stop growing here
                exhausted[r] = True
                n_cands = start0
                continue
            used[r] += delta
            subdivisions[r] += 1
            node_a = grown(node_a, n_nodes + 2, node_a.shape[0])
            node_b = grown(node_b, n_nodes + 2, node_b.shape[0])
            split = grown(split, n_nodes + 2, split.shape[0])
            state = grown(state, n_nodes + 2, state.shape[0])
            cell = grown(cell, n_nodes + 2, cell.shape[0])
            node_a[nd] = n_nodes
            node_b[nd] = -(dim + 1)
            split[nd] = mid
            pos = start0
            for side in range(2):
                kid = n_nodes + side
                node_a[kid] = pos
                node_b[kid] = counts[side]
                split[kid] = 0.0
                pos += counts[side]
                state[kid, _OWNER] = r
                state[kid, _FACE] = face
                state[kid, _DEPTH] = state[nd, _DEPTH] + 1
                state[kid, _STALE] = state[nd, _STALE] + 1 if counts[side] > keep * m else 0
                # arrivals of this pass in the child's virtual cell, if it is one; beyond the virtual
                # subtree only the parent's are known: half of them are expected next time
                if h < v:
                    state[kid, _ARRIVED] = heap[2 * h + side]
                    state[kid, _RATE] = heap[2 * h + side]
                else:
                    state[kid, _ARRIVED] = 0
                    state[kid, _RATE] = state[nd, _RATE] // 2
                for q in range(10):
                    cell[kid, q] = cell[nd, q]
                if side == 0:
                    cell[kid, 5 + dim] = mid
                else:
                    cell[kid, dim] = mid
            # children inside the virtual subtree (their arrivals known) may split further now, first child first
            if h < v:
                st_node[sp], st_h[sp] = n_nodes + 1, 2 * h + 1
                st_node[sp + 1], st_h[sp + 1] = n_nodes, 2 * h
                sp += 2
            n_nodes += 2
    return node_a, node_b, split, key, ref, item, state, cell, n_nodes, n_cands


@njit
def _virtual_subtrees(cand, levels, cell, state, norm, vdim, vsplit, voff):
    """Split dimension and coordinate of every inner node of each candidate's virtual subtree
    (heap order, node h at vsplit[voff[j] + h - 1]), computed exactly as _refine_kernel splits."""
    lo = np.empty((2 << VIRTUAL_LEVELS, 5))
    hi = np.empty((2 << VIRTUAL_LEVELS, 5))
    for j in range(cand.shape[0]):
        c = cand[j]
        v = 1 << levels[j]
        r = state[c, _OWNER]
        for q in range(5):
            lo[1, q] = cell[c, q]
            hi[1, q] = cell[c, 5 + q]
        for h in range(1, v):
            dim = longest(lo[h], hi[h], norm[r])
            mid = 0.5 * (lo[h, dim] + hi[h, dim])
            vdim[voff[j] + h - 1] = dim
            vsplit[voff[j] + h - 1] = mid
            if 2 * h < v:
                for q in range(5):
                    lo[2 * h, q] = lo[h, q]
                    hi[2 * h, q] = hi[h, q]
                    lo[2 * h + 1, q] = lo[h, q]
                    hi[2 * h + 1, q] = hi[h, q]
                hi[2 * h, dim] = mid
                lo[2 * h + 1, dim] = mid


def _levels(arrived, rays):
    """K of each candidate's virtual subtree: none without arrivals, else about log2(arrivals / rays) + 2."""
    ratio = arrived // rays
    bits = np.zeros(len(ratio), np.int64)
    nz = ratio > 0
    bits[nz] = np.floor(np.log2(ratio[nz].astype(np.float64))).astype(np.int64) + 1
    return np.where(arrived > 0, np.minimum(VIRTUAL_LEVELS, 1 + bits), 0)


@njit
def _move_lists(leaves, node_a, node_b, key, ref, item, key_out, ref_out, item_out):
    """Copy the lists of `leaves` (in their order) to the front of the *_out arrays and point
    the leaves at their new places."""
    pos = 0
    for leaf in leaves:
        s = node_a[leaf]
        for q in range(s, s + node_b[leaf]):
            key_out[pos] = key[q]
            ref_out[pos] = ref[q]
            item_out[pos] = item[q]
            pos += 1
        node_a[leaf] = pos - node_b[leaf]


_NODE_ARRAYS = ("node_a", "node_b", "split", "state", "cell", "pass_")
_CAND_ARRAYS = ("key", "ref", "item")


class LazyRC:
    """Every lazy ray classification of one built scene, with room to grow its arrays.

    columns: pass counter columns a pass must provide (after counters.N_COUNTERS and
    `base` columns of other lazy structures); refine() takes their counts and returns
    the Geometry to use next. See rc.py's docstring."""

    def __init__(self):
        raise TypeError("use LazyRC.attach(geo, records)")

    @classmethod
    def attach(cls, geo, records, base=0):
        """Take over geo's rc arrays for the lazy rc aggregates in `records` (from flatten: first
        root node, first candidate, items of the root lists, widened boxes, keys, tagged refs,
        box, params, stats dict). Returns (geo viewing the growable arrays, LazyRC)."""
        self = object.__new__(cls)
        self.records = records
        self.base = int(base)
        n, nc = len(geo.rc_node_a), len(geo.keyed_key)
        self.n_nodes, self.n_cands = n, nc
        cap, ccap = n + max(1024, n), nc + max(4096, nc)
        b = self.buf = {}
        for name, a in (("node_a", geo.rc_node_a), ("node_b", geo.rc_node_b), ("split", geo.rc_split),
                        ("key", geo.keyed_key), ("ref", geo.keyed_ref)):
            b[name] = np.empty(ccap if name in _CAND_ARRAYS else cap, a.dtype)
            b[name][:len(a)] = a
        b["state"] = np.zeros((cap, 6), np.int64)
        b["state"][:, _OWNER] = -1
        b["cell"] = np.zeros((cap, 10))
        b["pass_"] = np.full(cap, -1, np.int64)
        b["item"] = np.full(ccap, -1, np.int64)
        boxes = []
        n_items = 0
        for r, rec in enumerate(records):
            node, start, items = rec["node"], rec["cand"], rec["items"]
            b["item"][start:start + len(items)] = items + n_items
            boxes.append(rec["boxes"])
            n_items += len(rec["boxes"])
            root_lo = np.concatenate([rec["box"][:3], [-1.0, -1.0]])
            root_hi = np.concatenate([rec["box"][3:], [1.0, 1.0]])
            for f in range(6):
                b["state"][node + f] = (r, f, 0, 0, 0, 0)
                b["cell"][node + f] = np.concatenate([root_lo, root_hi])
        self.boxes = np.ascontiguousarray(np.concatenate(boxes))
        self.norm = np.array([1.0 / (c[5:] - c[:5]) for c in (b["cell"][rec["node"]] for rec in records)])
        self.leaf = np.array([rec["leaf"] for rec in records], np.int64)
        self.depth = np.array([rec["depth"] for rec in records], np.int64)
        self.rays = np.array([rec["rays"] for rec in records], np.int64)
        self.stale = np.full(len(records), LAZY_STALE_SPLITS, np.int64)
        self.budget_mb = [rec["budget_mb"] for rec in records]
        budgets = [memory_budget(rec["budget_mb"], rec["max_bytes"]) for rec in records]
        self.budget = np.array([b for b, _ in budgets], np.int64)
        self.by_memory = np.array([m for _, m in budgets], np.bool_)
        self.used = np.array([rec["stats"]["bytes"] for rec in records], np.int64)
        self.exhausted = np.array([rec["stats"]["budget_exceeded"] for rec in records], np.bool_)
        self.warned = self.exhausted.copy()      # start_rc warned already
        self.held = False                        # a checkpoint is out: keep the lists in place
        self.subdivisions = np.zeros(len(records), np.int64)
        self.passes = 0
        self.seconds = 0.0
        roots = np.concatenate([rec["node"] + np.arange(6) for rec in records])
        self.cand = roots[self._may_split(roots)]
        self.levels = np.full(len(self.cand), VIRTUAL_LEVELS, np.int64)   # no arrivals seen yet: look deep
        return self._number(geo), self

    # ------------------------------------------------------------- passes

    @property
    def columns(self) -> int:
        return int(self._widths.sum())

    def _may_split(self, nodes):
        b = self.buf
        own = b["state"][nodes, _OWNER]
        return (b["node_b"][nodes] > self.leaf[own]) & (b["state"][nodes, _DEPTH] < self.depth[own]) & \
            (b["state"][nodes, _STALE] < self.stale[own]) & ~self.exhausted[own]

    def refine(self, geo, pass_counts, base=None):
        """Add a pass's counts ((work items, columns) int64, one row per tile or chunk) and split
        the candidates where rays arrived; number the columns of the next pass from `base`
        (columns of other lazy structures before these). Returns the Geometry to trace with."""
        t0 = time.perf_counter()
        pass_counts = np.asarray(pass_counts)
        if pass_counts.ndim != 2 or pass_counts.shape[1] != self.columns:
            raise ValueError(f"pass counts must have {self.columns} columns, got shape {pass_counts.shape}")
        if base is not None:
            self.base = int(base)
        self.passes += 1
        if len(self.cand):
            b = self.buf
            hist = pass_counts.sum(axis=0, dtype=np.int64)
            hoff = np.concatenate([[0], np.cumsum(self._widths)[:-1]]).astype(np.int64)
            old_n = self.n_nodes
            out = _refine_kernel(self.cand, self.levels, hoff, hist, b["node_a"], b["node_b"], b["split"], b["key"],
                                 b["ref"], b["item"], b["state"], b["cell"], np.int64(self.n_nodes),
                                 np.int64(self.n_cands), self.boxes, self.norm, self.leaf, self.depth, self.rays,
                                 self.stale, self.budget, self.used, self.exhausted, self.subdivisions, KEEP)
            for name, a in zip(("node_a", "node_b", "split", "key", "ref", "item", "state", "cell"), out[:8]):
                b[name] = a
            self.n_nodes, self.n_cands = int(out[8]), int(out[9])
            if len(b["pass_"]) < len(b["node_a"]):
                grown = np.full(len(b["node_a"]), -1, np.int64)
                grown[:old_n] = b["pass_"][:old_n]
                b["pass_"] = grown
            b["pass_"][self.cand] = -1
            # candidates now: old ones still leaves, and the new leaves, in node order
            new = np.arange(old_n, self.n_nodes, dtype=np.int64)
            nodes = np.concatenate([self.cand[b["node_b"][self.cand] >= 0], new[b["node_b"][new] >= 0]])
            self.cand = nodes[self._may_split(nodes)]
            self.levels = _levels(b["state"][self.cand, _RATE], self.rays[b["state"][self.cand, _OWNER]])
            self._warn()
            self._compact()
        self.seconds += time.perf_counter() - t0
        return self._number(geo)

    def _compact(self):
        """Move the leaves' lists together once the split leaves' old lists outnumber them."""
        b, n = self.buf, self.n_nodes
        leaves = np.flatnonzero(b["node_b"][:n] >= 0)
        count = b["node_b"][leaves]
        live = int(count.sum())
        if self.held or self.n_cands <= 2 * live:
            return
        cap = live + max(4096, live)
        moved = [np.empty(cap, b[name].dtype) for name in _CAND_ARRAYS]
        _move_lists(leaves, b["node_a"], b["node_b"], b["key"], b["ref"], b["item"], *moved)
        for name, a in zip(_CAND_ARRAYS, moved):
            b[name] = a
        self.n_cands = live

    def _warn(self):
        for r in np.flatnonzero(self.exhausted & ~self.warned):
            rec = self.records[r]
            if self.by_memory[r]:
                over_budget(int(self.budget[r]) * PEAK_FACTOR,
                      f"the lazy ray classification of group {rec['name'] or '(unnamed)'}",
                      f"give it a budget_mb under {self.budget[r] / (1 << 20):.0f} (hits stay exact) or lower depth")
            sel = self.buf["state"][:self.n_nodes, _OWNER] == r
            refs = int(self.buf["node_b"][:self.n_nodes][sel & (self.buf["node_b"][:self.n_nodes] >= 0)].sum())
            budget_warning(rec["name"], self.budget_mb[r], int(sel.sum()), refs, int(self.used[r]))
            self.warned[r] = True

    def _number(self, geo):
        """Columns of the candidates (in node order, 2**K each, from base) and their virtual subtrees."""
        b = self.buf
        self._widths = np.left_shift(1, self.levels).astype(np.int64)
        n_cand = len(self.cand)
        b["pass_"][self.cand] = np.arange(n_cand, dtype=np.int64)
        vinfo = np.empty((n_cand, 3), np.int64)
        vinfo[:, 0] = self.base + np.concatenate([[0], np.cumsum(self._widths)[:-1]]).astype(np.int64)
        vinfo[:, 1] = self.levels
        vinfo[:, 2] = np.concatenate([[0], np.cumsum(self._widths - 1)[:-1]]).astype(np.int64)
        n_split = int((self._widths - 1).sum())
        vdim = np.zeros(n_split, np.int64)
        vsplit = np.zeros(n_split)
        _virtual_subtrees(self.cand, self.levels, b["cell"], b["state"], self.norm, vdim, vsplit, vinfo[:, 2].copy())
        self.vinfo, self.vdim, self.vsplit = vinfo, vdim, vsplit
        return self._view(geo)

    def _view(self, geo):
        n, nc, b = self.n_nodes, self.n_cands, self.buf
        return geo._replace(rc_node_a=b["node_a"][:n], rc_node_b=b["node_b"][:n], rc_split=b["split"][:n],
                            keyed_key=b["key"][:nc], keyed_ref=b["ref"][:nc], rc_pass=b["pass_"][:n],
                            rc_vinfo=self.vinfo, rc_vdim=self.vdim, rc_vsplit=self.vsplit)

    # ------------------------------------------------------------- all-hits queries run twice

    def checkpoint(self):
        """The state to go back to, so that a second run over the same rays meets the same trees."""
        n, b = self.n_nodes, self.buf
        self.held = True
        return dict(n_nodes=n, n_cands=self.n_cands, arrays={name: b[name][:n].copy() for name in _NODE_ARRAYS},
                    cand=self.cand.copy(), levels=self.levels.copy(), base=self.base, passes=self.passes,
                    used=self.used.copy(), exhausted=self.exhausted.copy(), warned=self.warned.copy(),
                    subdivisions=self.subdivisions.copy())

    def restore(self, mark, geo):
        """Back to `mark` (from checkpoint); returns the Geometry to use."""
        n = mark["n_nodes"]
        for name, a in mark["arrays"].items():
            self.buf[name][:n] = a
        self.buf["pass_"][n:] = -1
        self.n_nodes, self.n_cands = n, mark["n_cands"]
        self.cand, self.levels, self.base = mark["cand"], mark["levels"], mark["base"]
        self.passes = mark["passes"]
        self.used, self.exhausted = mark["used"], mark["exhausted"]
        self.warned, self.subdivisions = mark["warned"], mark["subdivisions"]
        self.held = False
        return self._number(geo)

    # ------------------------------------------------------------- statistics

    def update_stats(self, build, geo):
        """Write the trees as they now stand into the build statistics of flatten()."""
        n, b = self.n_nodes, self.buf
        owner = b["state"][:n, _OWNER]
        node_b = b["node_b"][:n]
        for r, rec in enumerate(self.records):
            sel = owner == r
            tree = tree_counts(node_b[sel])
            rec["stats"].update(tree, bytes=NODE_BYTES * tree["nodes"] + CANDIDATE_BYTES * tree["refs"],
                                max_depth=int(b["state"][:n, _DEPTH][sel].max()), passes=self.passes,
                                subdivisions=int(self.subdivisions[r]), refine_seconds=self.seconds,
                                budget_exceeded=bool(self.exhausted[r]))
        scene_totals(build, geo, self.passes, int(self.subdivisions.sum()), self.seconds)

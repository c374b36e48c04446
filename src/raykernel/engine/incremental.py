"""Structures kept between the frames of an animation: only what moved is touched.

    hierarchy = Hierarchy(rebuild_threshold=1.5)
    for t in animation.times(24):
        scene = animation.at(scene, t)
        result = render(scene, builder=hierarchy)    # build.refit_nodes, build.rebuilt_nodes, ...

The first frame is built from scratch (flatten.flatten), and every top-level aggregate build
is recorded: its spec, its references and its items' boxes. A later frame walks the scene
the same way; each aggregate whose spec and references are unchanged is then

- reused as it is when its items' boxes are the same (a static subspace);
- refit when they moved and its kind can be refit in place (Kind.refit): a BVH keeps its
  tree and recomputes the boxes of the nodes above the moved items from the leaves up
  (build.refit_nodes), or is rebuilt when the refit tree's SAH cost has grown past
  `rebuild_threshold` times the cost it had when it was built; a list keeps its references;
- rebuilt otherwise (grids, octrees and the rest depend on where their items lie), its new
  arrays appended and the old ones left unused (build.rebuilt_nodes).

A moved instance changes only its matrix: its group's aggregate is reused and the boxes
of the aggregates above it are refit. A scene whose structure changed (other groups,
primitive counts, specs) is built from scratch, and so is every frame of a scene with
lazy structures (which refine while they are traced) and every frame after the unused
arrays have grown past the size of a from-scratch build. Primitives' own arrays are always
rewritten: they are what moved.

A BVH that was refit holds the same items as a rebuilt one; the closest-hit rule breaks
ties by reference, not by the order of the walk, so each frame's image and ray counts are
those of a from-scratch build; the bound tests and steps differ with the tree.
"""

from __future__ import annotations

import time

import numpy as np

from ..aggregates.registry import DEFAULT, EMPTY, KINDS
from .flatten import AGGREGATE_FIELDS, Builder, flatten

__all__ = ["Hierarchy"]

_FRAME_FIELDS = ("inst_agg", "inst_to_local", "inst_class")   # rewritten every frame by the walk
_AGG_ROW_FIELDS = ("agg_kind", "agg_bounds", "agg_start", "agg_count")
DEFAULT_REBUILD_THRESHOLD = 1.5


class _Changed(Exception):
    """The scene's structure differs from the recorded frame's."""


def _box_of(bounds: np.ndarray) -> np.ndarray:
    """The box around item boxes; an empty item's (+inf..-inf) adds nothing, as in Builder.build."""
    if not len(bounds):
        return np.array([np.inf] * 3 + [-np.inf] * 3)
    return np.concatenate([bounds[:, :3].min(axis=0), bounds[:, 3:].max(axis=0)])


class _Record:
    """One top-level aggregate build of a frame: what it was built from."""

    __slots__ = ("spec", "refs", "bounds", "agg", "stats", "refit")

    def __init__(self, spec, refs, bounds, agg, stats):
        self.spec, self.refs, self.bounds, self.agg, self.stats = spec, refs, bounds, agg, stats
        self.refit = {}         # what its kind's refit keeps between frames (Kind.refit)


class _RecordingBuilder(Builder):
    """A from-scratch build that records each top-level aggregate it builds."""

    def __init__(self, default_accel, max_bytes):
        super().__init__(default_accel, max_bytes)
        self.records: list[_Record] = []
        self._inside = 0

    def build(self, spec, refs, bounds, name) -> int:
        self._inside += 1
        try:
            agg = super().build(spec, refs, bounds, name)
        finally:
            self._inside -= 1
        if self._inside == 0:
            self.records.append(_Record(spec, refs.copy(), bounds.copy(), agg, self.agg_stats[-1]))
        return agg


class _ReplayBuilder(Builder):
    """A frame built over the previous frame's aggregates (see the module docstring)."""

    def __init__(self, default_accel, max_bytes, state=None, threshold=DEFAULT_REBUILD_THRESHOLD):
        super().__init__(default_accel, max_bytes)
        self.state = state
        self.threshold = threshold
        self.flat.seed(state["fields"])       # the state's own arrays (no frame's Geometry shares them)
        self.agg_stats = [dict(r.stats) for r in state["records"]]
        self.calls = 0
        self._inside = 0
        self.work = dict(reused=0, refit=0, rebuilt=0, refit_nodes=0, rebuilt_nodes=0)

    def build(self, spec, refs, bounds, name) -> int:
        if self._inside:        # an aggregate built inside a rebuilt one (hybrid's BVHs)
            return super().build(spec, refs, bounds, name)
        records = self.state["records"]
        k = self.calls
        self.calls += 1
        if k >= len(records):
            raise _Changed
        rec = records[k]
        if rec.spec != spec or len(rec.refs) != len(refs) or not np.array_equal(rec.refs, refs):
            raise _Changed
        if np.array_equal(rec.bounds, bounds):
            self.work["reused"] += 1
            return rec.agg
        box = _box_of(bounds)
        kind = KINDS[spec[0]] if len(refs) else EMPTY       # what the aggregate was stored as
        touched = None if kind.refit is None else kind.refit(self.flat, rec.agg, rec.refit, rec.refs, rec.bounds,
                                                             bounds, spec[1], self.threshold)
        if touched is not None:
            self._set_box(rec.agg, box)
            self.work["refit"] += 1
            self.work["refit_nodes"] += touched
        else:
            self._rebuild(rec, spec, refs, bounds, name)
            self.work["rebuilt"] += 1
        rec.bounds = bounds.copy()
        return rec.agg

    def _set_box(self, agg: int, box) -> None:
        self.flat.parts["agg_bounds"][0][agg] = box

    def _rebuild(self, rec: _Record, spec, refs, bounds, name) -> None:
        """Build rec's aggregate anew at the end of the arrays, then give it rec's index."""
        flat = self.flat
        self._inside += 1
        try:
            new = super().build(spec, refs, bounds, name)
        finally:
            self._inside -= 1
        stats = self.agg_stats.pop()
        del self.agg_stats[len(self.state["records"]):]     # aggregates built inside it are counted in its own
        for f in _AGG_ROW_FIELDS:       # the new aggregate's row is the last part of each: move it to rec.agg
            part = flat.parts[f].pop()
            flat.rows[f] -= 1
            flat.parts[f][0][rec.agg] = part[0]
        assert new == flat.rows["agg_kind"], "the rebuilt aggregate is the last one appended"
        self.agg_stats[self.calls - 1] = stats
        rec.stats, rec.refit = stats, {}
        self.work["rebuilt_nodes"] += int(stats.get("nodes", 0)) or 1

    def finish(self) -> None:
        if self.calls != len(self.state["records"]):
            raise _Changed


class Hierarchy:
    """The structures of an animation's frames, each frame built from the one before
    (see the module docstring). Pass it as `render(..., builder=hierarchy)`.

    rebuild_threshold: a refit BVH whose SAH cost exceeds this times its cost when built is
    rebuilt instead (1.5 by default; 1 rebuilds whatever moved, inf always refits).
    incremental: False builds every frame from scratch (for comparison), counting the same way."""

    def __init__(self, rebuild_threshold: float = DEFAULT_REBUILD_THRESHOLD, incremental: bool = True):
        if not rebuild_threshold >= 1.0:
            from ..errors import OptionError
            raise OptionError(f"rebuild_threshold must be at least 1, got {rebuild_threshold!r}")
        self.threshold = float(rebuild_threshold)
        self.incremental = incremental
        self.state = None
        self.frames = 0

    def flatten(self, scene, default_accel=DEFAULT, max_memory=None):
        t0 = time.perf_counter()
        key = (default_accel, max_memory)
        replay = None
        if self.incremental and self.state is not None and self.state["key"] == key:
            made = {}

            def replaying(accel_spec, max_bytes):
                made["b"] = _ReplayBuilder(accel_spec, max_bytes, self.state, self.threshold)
                return made["b"]
            try:
                geo, stats = flatten(scene, default_accel, max_memory, builder=replaying)
                made["b"].finish()
                replay = made["b"]
            except _Changed:
                replay = None
        if replay is not None and stats["build.bytes"] <= 2 * self.state["full_bytes"]:
            work = replay.work
            self._keep(replay, key, self.state["full_bytes"], self.state["records"])
        else:
            made = {}

            def recording(accel_spec, max_bytes):
                made["b"] = _RecordingBuilder(accel_spec, max_bytes)
                return made["b"]
            geo, stats = flatten(scene, default_accel, max_memory, builder=recording)
            nodes = int(sum(max(1, int(r.stats.get("nodes", 0))) for r in made["b"].records))
            work = dict(reused=0, refit=0, rebuilt=len(made["b"].records), refit_nodes=0, rebuilt_nodes=nodes)
            if "lazy" in stats:
                self.state = None       # lazy structures change as they are traced: never kept
            else:
                self._keep(made["b"], key, stats["build.bytes"], made["b"].records)
        self.frames += 1
        stats.update({"build.refit_nodes": work["refit_nodes"], "build.rebuilt_nodes": work["rebuilt_nodes"],
                      "build.reused_aggregates": work["reused"], "build.refit_aggregates": work["refit"],
                      "build.rebuilt_aggregates": work["rebuilt"], "build.seconds": time.perf_counter() - t0})
        return geo, stats

    def _keep(self, builder, key, full_bytes, records) -> None:
        flat = builder.flat
        fields = {}
        for f in AGGREGATE_FIELDS:
            if f.name in _FRAME_FIELDS:
                continue
            parts = flat.parts[f.name]
            one = parts[0] if len(parts) == 1 else None     # kept as it is where it already has the layout
            ok = one is not None and one.dtype == f.dtype and one.shape[1:] == f.shape and one.flags.c_contiguous
            fields[f.name] = one if ok else flat.field(f)
        self.state = {"key": key, "fields": fields, "records": records, "full_bytes": full_bytes}

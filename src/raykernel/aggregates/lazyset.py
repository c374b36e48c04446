"""The lazily refined structures of one scene as one, whatever their kinds.

    lazy = build["lazy"]               # from flatten: a LazySet of every kind's part, None without any
    passes = np.zeros((rows, lazy.columns), np.int64)   # one row per tile or chunk of the pass
    geo = lazy.refine(geo, passes)     # between passes, never while rays are in flight

A kind with lazy parts (Kind.lazy: lazy octrees, lazy ray classification) gives
a class whose `attach(geo, records, base)` takes over the arrays its
aggregates' records name and returns (the Geometry viewing them, the part);
a part has `columns` (the pass counters it needs after counters.N_COUNTERS,
numbered from `base`), `refine(geo, counts, base)`, `checkpoint()`,
`restore(mark, geo)` and `update_stats(build, geo)`. Each part counts into its
own block of pass columns, in registry order, renumbered from `base` after
each refinement; every part refines at the same ray indices, RayScene's
passes (`ranges`) and the renderer's.
"""

from __future__ import annotations

import numpy as np

FIRST_PASS = 16            # RayScene: rays in the first pass
PASS_CHUNKS = 8            # RayScene: at most this many chunks of rays (of rayqueries.CHUNK) per pass


class LazySet:
    """The lazy parts of a scene (see the module docstring), with the interface of each."""

    def __init__(self, parts):
        self.parts = list(parts)

    @classmethod
    def attach(cls, geo, kinds, records: dict):
        """The parts of the `kinds` (lazy ones, in registry order) whose aggregates have records
        (kind name -> records, from flatten); returns (geo viewing their arrays, LazySet or None)."""
        parts, base = [], 0
        for kind in kinds:
            if records.get(kind.name):
                geo, part = kind.lazy.attach(geo, records[kind.name], base)
                parts.append(part)
                base += part.columns
        return geo, (cls(parts) if parts else None)

    @property
    def columns(self) -> int:
        return sum(part.columns for part in self.parts)

    @staticmethod
    def ranges(n: int, chunk: int):
        """RayScene's passes over n rays: FIRST_PASS rays, then as many as went before, up to
        PASS_CHUNKS chunks of `chunk` rays (a power of two at least FIRST_PASS)."""
        return pass_ranges(n, FIRST_PASS, PASS_CHUNKS * chunk)

    def refine(self, geo, pass_counts):
        """Each part refines from its own columns and numbers its next ones after the parts before
        it; returns the Geometry to trace the next pass with."""
        pass_counts = np.asarray(pass_counts)
        if pass_counts.ndim != 2 or pass_counts.shape[1] != self.columns:
            raise ValueError(f"pass counts must have {self.columns} columns, got shape {pass_counts.shape}")
        start = base = 0
        for part in self.parts:
            k = part.columns
            geo = part.refine(geo, pass_counts[:, start:start + k], base=base)
            start += k
            base += part.columns
        return geo

    def checkpoint(self):
        return [part.checkpoint() for part in self.parts]

    def restore(self, mark, geo):
        for part, m in zip(self.parts, mark):
            geo = part.restore(m, geo)
        return geo

    def update_stats(self, build, geo):
        """Every part's statistics; the scene's refinement figures add up over the parts."""
        subdivisions, seconds = 0, 0.0
        for part in self.parts:
            part.update_stats(build, geo)
            subdivisions += build["build.subdivisions"]
            seconds += build["build.refine_seconds"]
        build["build.subdivisions"] = subdivisions
        build["build.refine_seconds"] = seconds


def tree_counts(count) -> dict:
    """N_IN + N_V, N_IN, N_V, N_EV and N_OIV of a lazy tree from its nodes' counts (a leaf's
    item count, negative for an inner node)."""
    leaves = count >= 0
    return {"nodes": len(count), "inner": int(np.count_nonzero(~leaves)), "leaves": int(np.count_nonzero(leaves)),
            "empty_leaves": int(np.count_nonzero(count == 0)), "refs": int(count[leaves].sum())}


def scene_totals(build, geo, passes, subdivisions, seconds):
    """The scene's build figures once its lazy aggregates' own statistics are up to date."""
    aggs = build.get("aggregates", [])
    for key, name in (("build.nodes", "nodes"), ("build.empty_leaves", "empty_leaves"), ("build.refs", "refs")):
        build[key] = int(sum(s.get(name, 0) for s in aggs))
    build["build.bytes"] = int(sum(a.nbytes for a in geo if isinstance(a, np.ndarray)))
    build["build.refine_passes"] = passes
    build["build.subdivisions"] = subdivisions
    build["build.refine_seconds"] = seconds


def pass_ranges(n: int, first: int, most: int) -> list[tuple[int, int]]:
    """Passes over n units of work, as [start, end) ranges: `first` units, then as many as
    all the passes before (first, first, 2 first, 4 first, ...), at most `most`.

    Boundaries depend only on n, first and most (never on threads or timing). When
    B = first * 2**j and most is a multiple of B, the passes before unit B cut the first
    block of B units (a render tile's rows, RayScene's first chunk) and every later
    boundary is a multiple of B, so later passes are whole tiles or chunks."""
    if first < 1 or most < first:
        raise ValueError(f"pass sizes need 1 <= first <= most, got first={first}, most={most}")
    out, a = [], 0
    while a < n:
        b = min(n, a + min(most, max(first, a)))
        out.append((a, b))
        a = b
    return out

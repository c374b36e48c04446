"""The lazily refined structures of one scene as one: lazy octrees and lazy ray classification.

    lazy = build["lazy"]               # from flatten: LazyOctrees alone, or a LazySet with lazy rc
    passes = np.zeros((rows, lazy.columns), np.int64)   # one row per tile or chunk of the pass
    geo = lazy.refine(geo, passes)     # between passes, never while rays are in flight

Each part counts into its own block of pass columns, the octrees' first
(their leaves know their column from 0), the rc's after them (LazyRC numbers
its columns from `base`, the octrees' count after each of their refinements).
Passes are the lazy octrees' (LazyOctrees.ranges), so every part refines at
the same ray indices.
"""

from __future__ import annotations

from .lazyoctree import LazyOctrees


class LazySet:
    """LazyOctrees (or None) and LazyRC with the interface of either: columns, ranges,
    refine, checkpoint, restore, update_stats."""

    def __init__(self, octrees, rc):
        self.octrees = octrees
        self.rc = rc

    @property
    def columns(self) -> int:
        return self._octree_columns() + self.rc.columns

    def _octree_columns(self) -> int:
        return 0 if self.octrees is None else self.octrees.columns

    @staticmethod
    def ranges(n: int, chunk: int):
        """RayScene's passes over n rays: those of the lazy octrees."""
        return LazyOctrees.ranges(n, chunk)

    def refine(self, geo, pass_counts):
        """Each part refines from its own columns; returns the Geometry to trace the next pass with."""
        k = self._octree_columns()
        if self.octrees is not None:
            geo = self.octrees.refine(geo, pass_counts[:, :k])
        return self.rc.refine(geo, pass_counts[:, k:], base=self._octree_columns())

    def checkpoint(self):
        return (None if self.octrees is None else self.octrees.checkpoint(), self.rc.checkpoint())

    def restore(self, mark, geo):
        if self.octrees is not None:
            geo = self.octrees.restore(mark[0], geo)
        return self.rc.restore(mark[1], geo)

    def update_stats(self, build, geo):
        """Both parts' statistics; the scene's refinement figures add up over the parts."""
        subdivisions, seconds = 0, 0.0
        for part in (self.octrees, self.rc):
            if part is not None:
                part.update_stats(build, geo)
                subdivisions += build["build.subdivisions"]
                seconds += build["build.refine_seconds"]
        build["build.subdivisions"] = subdivisions
        build["build.refine_seconds"] = seconds

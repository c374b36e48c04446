"""Hierarchical grid: a uniform grid whose crowded cells hold a grid of their own.

    spec "hgrid(res=regular, density=2, threshold=8, depth=2, mailbox=on)"
    grid, stats = build_grid(bounds, ...)                 # the level's uniform grid
    cells = dense_cells(grid, threshold)                  # cells with more than threshold references
    sub = clipped_bounds(grid, bounds, cell, items)       # the items' boxes cut to the cell

A cell of a uniform grid that holds more than ``threshold`` references is
given a sub-grid over just those items, built with the same resolution rule
and density (about density x items cells over the cell), and the cell then
holds a single reference to that sub-grid aggregate instead of its items.
Sub-grids are refined the same way, down to ``depth`` levels below the top
grid. There is no special traversal: a sub-grid is an ordinary grid
aggregate nested in a cell, which the one intersection routine already
walks with its own 3D-DDA (`flatten` builds the levels and links them).

The items' boxes are cut to the cell (widened by twice the grid's insertion
margin) before the sub-grid is built, so a large item that crosses many
crowded cells does not stretch every sub-grid over its whole extent. This
loses no hits: a hit point lies in a cell that holds the item, and that
cell's sub-grid covers the item's part inside the cell.

Each level adds one aggregate to the nesting along a ray's path; flatten
clamps ``depth`` so that no path nests more than MAX_NESTING aggregates
(the statistics record the depth used).

Two guards keep the build finite on any input. A crowded cell of a
sub-grid that still holds every item of that sub-grid (coincident or
mutually covering items) made no progress and keeps its items. And all
levels of one hgrid together hold at most BUDGET times
the top grid's references plus 4096; once that is spent, the remaining
crowded cells keep their items.
"""

from __future__ import annotations

import time

import numpy as np

from ..geometry.primitives import AGGREGATE, make_ref
from .grid import WALK, GridArrays, append_grid, build_grid
from .spec import Kind, Param, Search, format_spec
from .walk import MAX_NESTING

__all__ = ["dense_cells", "clipped_bounds", "replace_cells", "cell_margin"]

BUDGET = 8          # all levels of one hgrid hold at most this many references per top-level one (+ 4096)


def dense_cells(grid: GridArrays, threshold: int) -> np.ndarray:
    """Linear indices of the cells holding more than `threshold` references."""
    return np.flatnonzero(np.diff(grid.cell_start) > threshold)


def cell_margin(grid: GridArrays) -> np.ndarray:
    """Twice the margin build_grid widens item boxes by, per axis."""
    extent = grid.cell_size * grid.res
    return 2.0 * (1e-9 * max(float(extent.max()), float(np.abs(grid.origin).max())) + 1e-7 * grid.cell_size)


def clipped_bounds(grid: GridArrays, bounds: np.ndarray, cell: int, items: np.ndarray) -> np.ndarray:
    """Boxes of `items` cut to cell `cell` widened by cell_margin; never empty for items of the cell."""
    rx, ry = int(grid.res[0]), int(grid.res[1])
    idx = np.array([cell % rx, (cell // rx) % ry, cell // (rx * ry)], np.float64)
    m = cell_margin(grid)
    lo = grid.origin + idx * grid.cell_size - m
    hi = grid.origin + (idx + 1.0) * grid.cell_size + m
    b = bounds[items]
    out_lo = np.maximum(b[:, :3], lo)
    out_hi = np.minimum(b[:, 3:], hi)
    # an item in the cell overlaps the widened cell; keep min <= max against rounding anyway
    return np.hstack([np.minimum(out_lo, out_hi), np.maximum(out_lo, out_hi)])


def replace_cells(cell_start: np.ndarray, cell_refs: np.ndarray, cells: np.ndarray,
                  new_refs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """CSR cells where each cell in `cells` holds only the matching entry of `new_refs`."""
    counts = np.diff(cell_start)
    keep = np.ones(len(cell_refs), bool)
    for c in cells:
        keep[cell_start[c]:cell_start[c + 1]] = False
    new_counts = counts.copy()
    new_counts[cells] = 1
    start = np.zeros(len(counts) + 1, np.int64)
    np.cumsum(new_counts, out=start[1:])
    out = np.empty(int(start[-1]), np.int64)
    mask = np.ones(len(out), bool)
    mask[start[cells]] = False
    out[start[cells]] = new_refs
    out[mask] = cell_refs[keep]
    return start, out


def flatten(builder, params, refs, bounds, name, box):
    # every level is one more aggregate on a ray's path: stay within MAX_NESTING
    levels = max(0, min(params["depth"], MAX_NESTING - builder.nesting))
    return _level(builder, params, refs, bounds, name, 0, levels, [None])


def _level(builder, params, refs, bounds, name, level, levels, budget):
    """One level: a grid whose cells holding more than `threshold` references hold one reference
    to a sub-grid over those items instead; returns (aggregate, statistics). Sub-levels record
    their statistics themselves. budget[0]: references the levels may still take."""
    grid, stats = build_grid(bounds, res_rule=params["res"], density=params["density"], max_res=params["max_res"],
                             name=name or "(unnamed)", max_bytes=builder.max_bytes)
    if budget[0] is None:
        budget[0] = BUDGET * len(grid.items) + 4096
    cells = dense_cells(grid, params["threshold"]) if level < levels else np.zeros(0, np.int64)
    if level > 0:
        # a cell that kept every item of its grid made no progress: refining it again could go on forever
        cells = cells[np.diff(grid.cell_start)[cells] < len(refs)]
    cell_start, cell_refs = grid.cell_start, refs[grid.items]
    budget[0] -= len(cell_refs)
    subs = []
    for c in cells:
        if budget[0] <= 0:
            break           # out of references: the remaining crowded cells keep their items
        items = grid.items[grid.cell_start[c]:grid.cell_start[c + 1]]
        sub_start = time.perf_counter()
        sub, sub_stats = _level(builder, params, refs[items], clipped_bounds(grid, bounds, c, items), name,
                                level + 1, levels, budget)
        sub_stats.update(kind=format_spec(KIND.name, params, {KIND.name: KIND}), name=name, items=len(items),
                         seconds=time.perf_counter() - sub_start)
        builder.agg_stats.append(sub_stats)
        subs.append(sub)
    cells = cells[:len(subs)]
    if len(subs):
        cell_start, cell_refs = replace_cells(cell_start, cell_refs, cells, make_ref(AGGREGATE, subs))
        builder.extra_nesting = max(builder.extra_nesting, level + 1)
    box = np.concatenate([bounds[:, :3].min(axis=0), bounds[:, 3:].max(axis=0)])
    agg = append_grid(builder.flat, grid, cell_start, cell_refs, params["mailbox"], box)
    stats = dict(stats, refs=len(cell_refs), empty_leaves=int(np.count_nonzero(np.diff(cell_start) == 0)),
                 bytes=int(cell_start.nbytes + cell_refs.nbytes + 72), level=level, levels=levels,
                 subgrids=len(cells))
    return agg, stats


KIND = Kind("hgrid", "hierarchical grid: a uniform grid whose cells with more than threshold references hold "
              "a sub-grid over those items instead, recursively", (
    Param("res", "regular", "resolution rule of every level: regular, woo or klimaszewski (see grid)", str,
          choices=("regular", "woo", "klimaszewski")),
    Param("density", 2.0, "cells per item at every level (see grid)", float, 0.001, 1000.0),
    Param("max_res", 256, "most cells along any axis of any level", int, 1, 4096),
    Param("threshold", 8, "a cell holding more references than this gets a sub-grid", int, 1, 1 << 30),
    Param("depth", 2, "most levels of sub-grids below the top grid (clamped so that no ray path nests more "
          "than 16 aggregates)", int, 0, 15),
    Param("mailbox", True, "skip items already tested against the ray in an earlier cell of the same grid", bool),
), flatten=flatten, walk=WALK, search=Search(start=True, candidates=("hgrid",)))

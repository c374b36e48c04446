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
walks with its own 3D-DDA (flatten.py builds the levels and links them).

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
levels of one hgrid together hold at most HGRID_BUDGET (flatten.py) times
the top grid's references plus 4096; once that is spent, the remaining
crowded cells keep their items.
"""

from __future__ import annotations

import numpy as np

from .grid import GridArrays

__all__ = ["dense_cells", "clipped_bounds", "replace_cells", "cell_margin"]


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

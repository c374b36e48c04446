"""Uniform grid (Fujimoto 1986) over axis-aligned item boxes, as flat arrays.

    grid, stats = build_grid(item_bounds, res_rule="regular", density=2.0)   # or "woo", "klimaszewski"
    # grid.origin (3,), grid.cell_size (3,), grid.res (3,), grid.cell_start (ncells + 1,), grid.items (R,)
    items_of_cell = grid.items[grid.cell_start[c]:grid.cell_start[c + 1]]

Layout
------
The grid covers the union of the item boxes, split into res[0] x res[1] x
res[2] equal cells. Cell (x, y, z) has the linear index
``(z * res[1] + y) * res[0] + x``. The cells are stored in CSR form:
``cell_start`` holds ncells + 1 offsets into ``items``, the item indices of
every cell one after the other (ascending within a cell).

Insertion
---------
An item goes into every cell its box overlaps (closed intervals, so a box
that ends exactly on a cell boundary is in both cells), after widening the
box by a tiny margin (1e-9 of the grid's size plus 1e-7 of a cell): a ray
that crosses a cell corner within rounding error of a hit point then still
finds the item in the cell the 3D-DDA chooses. Box overlap is conservative:
a sphere is also put into the cells at the corners of its box that it does
not touch.

An axis along which the items have no extent (all items in a plane) is
padded to a thickness of 1e-6 of the longest side and gets one cell.

Resolution rules
----------------
``regular``: cells roughly cubic, about ``density * n`` cells in all:
    n_i = round(extent_i * (density * n / volume) ** (1/k))
    over the k axes that are not flat (volume: the product of their extents).
``woo``: Woo's rule: the longest side gets ``density * n ** (1/3)`` cells,
    the other sides proportionally many (rounded, at least 1).
``klimaszewski``: cells follow the size of the objects, not only their
    number, as K. Klimaszewski's heterogeneous rule for adaptive grids
    (1994/1997) asks. His formula is not at hand, so this is our reading:
    per axis, cells about as long as the items' mean extent along it,
        n_i = extent_i / mean item extent_i   (at least 1),
    then, if that makes more than ``density * n`` cells, every axis above
    one cell scaled down by the same factor (axes that would fall below one
    cell keep one), so the proportions between the axes stay. Long thin
    items along x thus give short cells along y and z and long ones along x.
    The ratio is the same at every scale. When the items have no extent
    along an axis that is not flat (points, or all items flat in parallel
    planes), their size says nothing there and the rule is ``regular``.
Every axis is clamped to [1, max_res]. More than ``max_cells`` cells or
``max_refs`` references is an error that names the limit.
"""

from __future__ import annotations

import math
import time
from typing import NamedTuple

import numpy as np

from ..config import njit
from ..errors import OptionError, SceneError

__all__ = ["GridArrays", "RULES", "build_grid", "grid_resolution"]

RULES = ("regular", "woo", "klimaszewski")
MAX_CELLS = 16_000_000
MAX_REFS = 64_000_000
FLAT = 1e-6                 # an axis thinner than this fraction of the longest is flat


class GridArrays(NamedTuple):
    """A uniform grid as flat arrays; see the module docstring."""

    origin: np.ndarray      # (3,) float64 lower corner
    cell_size: np.ndarray   # (3,) float64 side of a cell per axis
    res: np.ndarray         # (3,) int64 cells per axis
    cell_start: np.ndarray  # (ncells + 1,) int64 offsets into items
    items: np.ndarray       # (R,) int64 item indices, cell after cell


def grid_box(bounds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lower corner and extent of the grid over `bounds`, flat axes padded."""
    lo = bounds[:, :3].min(axis=0)
    hi = bounds[:, 3:].max(axis=0)
    ext = hi - lo
    longest = float(ext.max())
    if longest == 0.0:
        longest = max(1e-300, 1e-9 * float(np.abs(lo).max()))
    thin = ext < FLAT * longest
    pad = np.where(thin, FLAT * longest, ext)
    lo = np.where(thin, lo - 0.5 * (pad - ext), lo)
    return lo, pad


def grid_resolution(extent, n: int, rule: str, density: float, max_res: int, item_size=None) -> np.ndarray:
    """Cells per axis for `n` items in a box of `extent` (see the module docstring);
    `item_size`, the items' mean extent per axis, is needed by the klimaszewski rule."""
    extent = np.asarray(extent, np.float64)
    longest = float(extent.max())
    flat = extent < 2.0 * FLAT * longest
    res = np.ones(3, np.int64)
    if rule == "regular":
        live = np.flatnonzero(~flat)
        k = len(live)
        log_per_unit = (math.log(density * n) - float(np.log(extent[live]).sum())) / k
        for a in live:
            res[a] = _clamp_round(math.exp(math.log(extent[a]) + log_per_unit), max_res)
    elif rule == "woo":
        along = density * n ** (1.0 / 3.0)
        for a in range(3):
            if not flat[a]:
                res[a] = _clamp_round(along * extent[a] / longest, max_res)
    elif rule == "klimaszewski":
        if item_size is None:
            raise ValueError("the klimaszewski rule needs the items' mean extent per axis (item_size)")
        cells = _size_cells(extent, np.asarray(item_size, np.float64), flat, density * n)
        if cells is None:
            return grid_resolution(extent, n, "regular", density, max_res)
        for a in range(3):
            res[a] = _clamp_round(cells[a], max_res)
    else:
        raise OptionError(f"grid resolution rule must be one of {', '.join(RULES)}, got {rule!r}")
    return res


def _size_cells(extent, size, flat, target):
    """Cells per axis (floats) of the klimaszewski rule, or None where the items'
    size gives no cell length along a live axis. Worked in logarithms: the
    ratios can be as large as the scene's range of scales."""
    log_want = np.zeros(3)
    for a in np.flatnonzero(~flat):
        if not (0.0 < size[a] < math.inf):
            return None
        log_want[a] = max(0.0, math.log(extent[a]) - math.log(size[a]))      # at least one cell
    log_target = math.log(target)
    free = [a for a in range(3) if log_want[a] > 0.0]
    while free and float(log_want.sum()) > log_target:
        # one common factor for the axes above one cell; an axis it would take below one cell keeps one
        log_scale = (log_target - float(sum(log_want[a] for a in free))) / len(free)
        pinned = [a for a in free if log_want[a] + log_scale <= 0.0]
        if not pinned:
            for a in free:
                log_want[a] += log_scale
            break
        for a in pinned:
            log_want[a] = 0.0
            free.remove(a)
    return np.exp(log_want)


def _clamp_round(x: float, max_res: int) -> int:
    if not x < max_res:
        return max_res
    return max(1, int(round(x)))


@njit
def _cell_ranges(bounds, origin, inv_size, res, margin, lo_out, hi_out):
    """Per item and axis, the first and last cell its widened box overlaps."""
    for i in range(bounds.shape[0]):
        for a in range(3):
            lo = (bounds[i, a] - margin[a] - origin[a]) * inv_size[a]
            hi = (bounds[i, a + 3] + margin[a] - origin[a]) * inv_size[a]
            c0 = int(math.floor(lo)) if lo > 0.0 else 0
            c1 = int(math.floor(hi)) if hi > 0.0 else 0
            if c0 > res[a] - 1:
                c0 = res[a] - 1
            if c1 > res[a] - 1:
                c1 = res[a] - 1
            lo_out[i, a] = c0
            hi_out[i, a] = c1


@njit
def _fill(lo, hi, res, ncells):
    """CSR cells: count the references per cell, prefix-sum, then place the items."""
    rx, ry = res[0], res[1]
    start = np.zeros(ncells + 1, np.int64)
    n = lo.shape[0]
    for i in range(n):
        for z in range(lo[i, 2], hi[i, 2] + 1):
            for y in range(lo[i, 1], hi[i, 1] + 1):
                row = (z * ry + y) * rx
                for x in range(lo[i, 0], hi[i, 0] + 1):
                    start[row + x + 1] += 1
    for c in range(ncells):
        start[c + 1] += start[c]
    items = np.empty(start[ncells], np.int64)
    fill = start[:ncells].copy()
    for i in range(n):
        for z in range(lo[i, 2], hi[i, 2] + 1):
            for y in range(lo[i, 1], hi[i, 1] + 1):
                row = (z * ry + y) * rx
                for x in range(lo[i, 0], hi[i, 0] + 1):
                    items[fill[row + x]] = i
                    fill[row + x] += 1
    return start, items


def _check_bounds(bounds) -> np.ndarray:
    arr = np.ascontiguousarray(np.asarray(bounds, np.float64))
    if arr.ndim == 1 and arr.size == 0:
        arr = arr.reshape(0, 6)
    if arr.ndim != 2 or arr.shape[1] != 6:
        raise ValueError(f"bounds must have shape (n, 6), got {arr.shape}")
    empty = np.all(arr[:, :3] == np.inf, axis=1) & np.all(arr[:, 3:] == -np.inf, axis=1)
    if not np.all(np.isfinite(arr[~empty])):
        raise ValueError("bounds must be finite (or the empty box +inf..-inf)")
    if np.any(arr[~empty, :3] > arr[~empty, 3:]):
        raise ValueError("bounds has a box with a minimum above its maximum")
    return arr, ~empty


def build_grid(bounds, *, res_rule="regular", density=2.0, max_res=256, max_cells=MAX_CELLS,
               max_refs=MAX_REFS, name=None):
    """Build a uniform grid over item boxes.

    bounds: (n, 6) item boxes (xmin, ymin, zmin, xmax, ymax, zmax), finite,
    n >= 1; an item with the empty box (+inf, +inf, +inf, -inf, -inf, -inf)
    is in no cell. res_rule: one of RULES. density > 0, max_res >= 1 (cells per
    axis). Returns (GridArrays, stats) with stats = {"nodes" (cells),
    "empty_leaves" (N_EV), "refs" (N_OIV), "bytes", "seconds", "res"}.
    """
    t0 = time.perf_counter()
    items, solid = _check_bounds(bounds)
    n = items.shape[0]
    what = f"group {name}" if name else "grid"
    if n == 0:
        raise ValueError("a grid needs at least one item")
    if res_rule not in RULES:
        raise OptionError(f"grid resolution rule must be one of {', '.join(RULES)}, got {res_rule!r}")
    if not (isinstance(density, (int, float)) and math.isfinite(density) and density > 0.0):
        raise OptionError(f"grid density must be a positive number, got {density!r}")
    if isinstance(max_res, bool) or not isinstance(max_res, (int, np.integer)) or max_res < 1:
        raise OptionError(f"grid max_res must be a positive integer, got {max_res!r}")

    if solid.any():
        origin, extent = grid_box(items[solid])
        size = np.mean(items[solid, 3:] - items[solid, :3], axis=0)
        res = grid_resolution(extent, int(solid.sum()), res_rule, float(density), int(max_res), item_size=size)
    else:
        origin, extent, res = np.zeros(3), np.ones(3), np.ones(3, np.int64)
    ncells = int(np.prod(res))
    if ncells > max_cells:
        raise SceneError(f"{what}: a {res[0]}x{res[1]}x{res[2]} grid has {ncells} cells, more than the "
                         f"limit of {max_cells}; lower density or max_res")
    cell_size = extent / res
    inv_size = 1.0 / cell_size
    margin = 1e-9 * np.maximum(extent.max(), np.abs(origin).max()) + 1e-7 * cell_size
    lo = np.empty((n, 3), np.int64)
    hi = np.empty((n, 3), np.int64)
    _cell_ranges(np.where(solid[:, None], items, 0.0), origin, inv_size, res, margin, lo, hi)
    lo[~solid] = 0
    hi[~solid] = -1
    n_refs = int(np.prod(hi - lo + 1, axis=1).sum())
    if n_refs > max_refs:
        raise SceneError(f"{what}: the grid would hold {n_refs} references, more than the limit of "
                         f"{max_refs}; lower density or max_res")
    start, cell_items = _fill(lo, hi, res, ncells)
    grid = GridArrays(origin, cell_size, res, start, cell_items)
    stats = {
        "nodes": ncells,
        "inner": 0,
        "leaves": ncells,
        "empty_leaves": int(np.count_nonzero(np.diff(start) == 0)),
        "refs": int(len(cell_items)),
        "bytes": int(sum(a.nbytes for a in grid)),
        "seconds": time.perf_counter() - t0,
        "res": tuple(int(r) for r in res),
    }
    return grid, stats

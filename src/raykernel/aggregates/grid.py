"""Uniform grid (Fujimoto 1986) over axis-aligned item boxes, as flat arrays.

    grid, stats = build_grid(item_bounds, res_rule="regular", density=2.0)   # or "woo", "klimaszewski"
    # grid.origin (3,), grid.cell_size (3,), grid.res (3,), grid.cell_start (ncells + 1,), grid.items (R,)
    items_of_cell = grid.items[grid.cell_start[c]:grid.cell_start[c + 1]]

Flat layout (the Geometry fields it owns)
-----------------------------------------
G grids, C cells of all grids:
  grid_origin       (G, 3) float64  lower corner                              24 B a grid
  grid_cell_size    (G, 3) float64  cell side per axis                         24 B
  grid_inv_cell     (G, 3) float64  1 / cell side                              24 B
  grid_res          (G, 3) int64    cells per axis                             24 B
  grid_cell_offset  (G,)   int64    first entry of the grid's cells in grid_cells  8 B
  grid_mailbox      (G,)   int64    1: skip refs already tested in an earlier cell  8 B
  grid_cells        (C + G,) int64  cell c of grid g holds refs[grid_cells[o + c]:grid_cells[o + c + 1]],
                                    o = grid_cell_offset[g]                    8 B a cell
The aggregate's agg_start is its grid index. The walk keeps the current cell and
the next crossing per axis in its frame (CELL, TNEXT), so a child aggregate found
in a cell can open frames above it.

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

from ..errors import OptionError, SceneError
from ..geometry import counters as C
from ..geometry.config import njit
from .memory import check, memory_limit
from .spec import Kind, Param, Search
from .walk import F_STATE, START, Cells, Field, Walk, answer, entry_tag, mailbox_reset, note_visit, push

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
               max_refs=MAX_REFS, name=None, max_bytes=None, cells=None):
    """Build a uniform grid over item boxes.

    bounds: (n, 6) item boxes (xmin, ymin, zmin, xmax, ymax, zmax), finite,
    n >= 1; an item with the empty box (+inf, +inf, +inf, -inf, -inf, -inf)
    is in no cell. res_rule: one of RULES. density > 0, max_res >= 1 (cells per
    axis). cells: (nx, ny, nz) cells per axis instead of a rule's (a published
    grid's resolution, bench/havran.py). Returns (GridArrays, stats) with stats = {"nodes" (cells),
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
        if cells is not None:
            res = np.asarray(cells, np.int64)
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
    # cell offsets and references: the builder's, the flat arrays' and a copy of each
    check(24.0 * (ncells + 1) + 24.0 * n_refs, memory_limit() if max_bytes is None else int(max_bytes),
          f"the grid of {what}", "lower density or max_res")
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


# ----------------------------------------------------------------- flat layout (see the module docstring) and walk


CODE = 2
FIELDS = (
    Field("grid_origin", np.float64, (3,)), Field("grid_cell_size", np.float64, (3,)),
    Field("grid_inv_cell", np.float64, (3,)), Field("grid_res", np.int64, (3,)),
    Field("grid_cell_offset", np.int64, ()), Field("grid_mailbox", np.int64, ()),
    Field("grid_cells", np.int64, ()),
)
NEXT = 1                    # step: visit the frame's next cell (stack_a: the grid), entered at stack_t
CELL, TNEXT = F_STATE, F_STATE + 3
INF = np.inf


def append_grid(flat, grid, cell_start, cell_refs, mailbox: bool, box) -> int:
    """Store a built grid whose cell c holds cell_refs[cell_start[c]:cell_start[c + 1]] as the next aggregate."""
    ncells = len(cell_start) - 1
    first = flat.add_refs(cell_refs)
    g = flat.size("grid_res")
    flat.append(grid_origin=grid.origin[None], grid_cell_size=grid.cell_size[None],
                grid_inv_cell=1.0 / grid.cell_size[None], grid_res=grid.res[None],
                grid_cell_offset=[flat.size("grid_cells")], grid_mailbox=[int(mailbox)], grid_cells=cell_start + first)
    return flat.add_aggregate(CODE, g, ncells, box)


def flatten(builder, params, refs, bounds, name, box):
    grid, stats = build_grid(bounds, res_rule=params["res"], density=params["density"], max_res=params["max_res"],
                             name=name or "(unnamed)", max_bytes=builder.max_bytes, cells=_cells(params["cells"]))
    return append_grid(builder.flat, grid, grid.cell_start, refs[grid.items], params["mailbox"], box), dict(stats)


def _cells(text: str):
    """The cells parameter, "NXxNYxNZ", as three positive integers (None when empty)."""
    if not text:
        return None
    parts = text.lower().split("x")
    if len(parts) != 3 or not all(p.strip().isdigit() and int(p) > 0 for p in parts):
        raise OptionError(f"grid cells must be three positive whole numbers as NXxNYxNZ (e.g. 46x46x3), got {text!r}")
    return tuple(int(p) for p in parts)


@njit(inline="always")
def walk_step(geo, step, a, te, ray, lo, best_t, f, sp, ws, cnt):
    """walk.py's step contract: START at the grid's entry point, NEXT at the frame's next cell."""
    ox, oy, oz, dx, dy, dz, ix, iy, iz = ray
    sp, s, e = dda(geo.grid_cell_offset, geo.grid_cell_size, geo.grid_cells, geo.grid_inv_cell, geo.grid_mailbox,
                   geo.grid_origin, geo.grid_res, step, a, te, ox, oy, oz, dx, dy, dz, ix, iy, iz, best_t, ws.frame_f,
                   f, ws.stack_a, ws.stack_b, ws.stack_t, sp, cnt, ws.work)
    return answer(sp, s, e, ray, best_t)


@njit(private=True)
def dda(grid_cell_offset, grid_cell_size, grid_cells, grid_inv_cell, grid_mailbox, grid_origin, grid_res,
        kind_step, gi, gt, ox, oy, oz, dx, dy, dz, ix, iy, iz, best_t, frame_f, f,
        stack_a, stack_b, stack_t, sp, cnt, work):
    """The 3D-DDA (Amanatides and Woo 1987) from the entry point (START) or the frame's
    next cell (NEXT) to the next non-empty cell; empty cells are stepped over in one go.
    Returns (sp, s, e): that cell's references, with a NEXT entry pushed below them
    unless it is the last cell. work: as for walk.note_visit."""
    if gt > best_t:
        return sp, 0, 0
    rx, ry, rz = grid_res[gi, 0], grid_res[gi, 1], grid_res[gi, 2]
    gox, goy, goz = grid_origin[gi, 0], grid_origin[gi, 1], grid_origin[gi, 2]
    csx, csy, csz = grid_cell_size[gi, 0], grid_cell_size[gi, 1], grid_cell_size[gi, 2]
    sx = 1 if dx > 0.0 else (-1 if dx < 0.0 else 0)
    sy = 1 if dy > 0.0 else (-1 if dy < 0.0 else 0)
    sz = 1 if dz > 0.0 else (-1 if dz < 0.0 else 0)
    if kind_step == START:
        # the cell holding the entry point, clamped into the grid
        u = (ox + gt * dx - gox) * grid_inv_cell[gi, 0]
        cx = np.int64(u) if u >= 0.0 and u < rx else (rx - 1 if u >= rx else 0)
        u = (oy + gt * dy - goy) * grid_inv_cell[gi, 1]
        cy = np.int64(u) if u >= 0.0 and u < ry else (ry - 1 if u >= ry else 0)
        u = (oz + gt * dz - goz) * grid_inv_cell[gi, 2]
        cz = np.int64(u) if u >= 0.0 and u < rz else (rz - 1 if u >= rz else 0)
        # crossings are computed from the boundary planes, so they never drift
        tx = (gox + (cx + (sx > 0)) * csx - ox) * ix if sx != 0 else INF
        ty = (goy + (cy + (sy > 0)) * csy - oy) * iy if sy != 0 else INF
        tz = (goz + (cz + (sz > 0)) * csz - oz) * iz if sz != 0 else INF
        if grid_mailbox[gi] != 0:
            mailbox_reset(frame_f, f)
    else:
        cx = np.int64(frame_f[f, CELL])
        cy = np.int64(frame_f[f, CELL + 1])
        cz = np.int64(frame_f[f, CELL + 2])
        tx, ty, tz = frame_f[f, TNEXT], frame_f[f, TNEXT + 1], frame_f[f, TNEXT + 2]
    off = grid_cell_offset[gi]
    while True:
        cnt[C.CELLS_VISITED] += 1
        cnt[C.CELLS_LEAVES] += 1
        cell = off + (cz * ry + cy) * rx + cx
        note_visit(work, CODE, cell)
        s = grid_cells[cell]
        e = grid_cells[cell + 1]
        # leave the cell across its nearest boundary
        if tx <= ty and tx <= tz:
            texit = tx
            cx += sx
            out = cx < 0 or cx >= rx
            tx = (gox + (cx + (sx > 0)) * csx - ox) * ix
        elif ty <= tz:
            texit = ty
            cy += sy
            out = cy < 0 or cy >= ry
            ty = (goy + (cy + (sy > 0)) * csy - oy) * iy
        else:
            texit = tz
            cz += sz
            out = cz < 0 or cz >= rz
            tz = (goz + (cz + (sz > 0)) * csz - oz) * iz
        if texit == INF:
            out = True
        if s == e:
            cnt[C.CELLS_EMPTY] += 1
            if out or texit > best_t:
                return sp, 0, 0
            continue
        if not out:
            # come back for the next cell after this one's references
            frame_f[f, CELL], frame_f[f, CELL + 1], frame_f[f, CELL + 2] = cx, cy, cz
            frame_f[f, TNEXT], frame_f[f, TNEXT + 1], frame_f[f, TNEXT + 2] = tx, ty, tz
            sp = push(stack_a, stack_b, stack_t, sp, gi, entry_tag(CODE, NEXT), texit)
        return sp, s, e


def features(stats, f, used) -> None:
    """The cost model's features: a grid's first entry and bound test of a ray move with the ray
    count (its set-up); those beyond (an hgrid's inner grids, the boxes of instances and structures
    in its cells) are cheaper, and priced apart (entry.grid.more, bound.grid.more)."""
    rays = f["ray.shaded"] + f["ray.shadow"]
    for what in ("entry", "bound"):
        count = f[f"{what}.grid"]
        f[f"{what}.grid"] = min(count, rays)
        f[f"{what}.grid.more"] = count - f[f"{what}.grid"]


def cells(geo, a) -> Cells:
    """Every cell of the grid, in its index order (cz * ry + cy) * rx + cx (Walk.cells)."""
    g = geo.agg_start[a]
    rx, ry, rz = (int(r) for r in geo.grid_res[g])
    cz, cy, cx = np.meshgrid(np.arange(rz), np.arange(ry), np.arange(rx), indexing="ij")
    lo = geo.grid_origin[g] + np.stack([cx.ravel(), cy.ravel(), cz.ravel()], axis=1) * geo.grid_cell_size[g]
    o, n = geo.grid_cell_offset[g], rx * ry * rz
    first = geo.grid_cells[o:o + n]
    return Cells(lo, lo + geo.grid_cell_size[g], np.zeros(n, np.int64), first, geo.grid_cells[o + 1:o + n + 1] - first,
                 o + np.arange(n, dtype=np.int64))


WALK = Walk(code=CODE, name="grid", fields=FIELDS, step=walk_step, features=features, cells=cells,
            keys="grid_cells")
KIND = Kind("grid", "uniform grid (Fujimoto) traversed with the 3D-DDA (Amanatides-Woo)", (
    Param("res", "regular", "resolution rule: regular (about density*N cubic cells), woo "
          "(longest side density*N^(1/3) cells) or klimaszewski (our reading of Klimaszewski's heterogeneous "
          "rule: per axis, cells about the items' mean extent, scaled down to at most density*N cells; "
          "regular where the items have no extent)", str, choices=("regular", "woo", "klimaszewski")),
    Param("density", 2.0, "cells per item (regular) or per cube root of the item count (woo)", float, 0.001, 1000.0),
    Param("max_res", 256, "most cells along any axis", int, 1, 4096),
    Param("mailbox", True, "skip items already tested against the ray in an earlier cell", bool),
    Param("cells", "", "cells per axis as NXxNYxNZ (e.g. 46x46x3), instead of the resolution rule's; "
          "empty: the rule's", str),
), flatten=flatten, walk=WALK, search=Search(start=True, candidates=("grid", "grid(density=0.5)", "grid(density=8)",
                                                                   "grid(res=woo, density=16)")))

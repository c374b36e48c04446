"""Which cells of a closed mesh's box lie wholly inside or outside it: `contains` without a ray there.

    grid = occupancy_grid(vertices, faces, classify)   # classify(points) -> bool, one parity ray each
    inside, known = grid.lookup(points, threads=2)     # known: False where a ray must still decide

A grid over the mesh's box marks every cell that a triangle may touch: the cells its box
overlaps (widened by a millionth of a cell, so a triangle on a cell's face marks both cells)
whose box the triangle's plane meets. The unmarked cells fall into connected regions (through
shared faces); no surface lies in a region, so all of it is inside or all outside, and one
parity ray from one cell's centre decides it (`classify`, the same ray cast `contains` makes).
A point in an unmarked cell takes its region's answer; a point outside the box is outside; a
point in a marked cell, or on the box, is left to its own ray. The grid holds about
CELLS_PER_TRIANGLE cells a triangle, between MIN_CELLS and MAX_CELLS.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..geometry.config import njit
from ..geometry.parallel import for_ranges
from .rayinput import read_only

CELLS_PER_TRIANGLE = 8
MIN_CELLS = 32 ** 3
MAX_CELLS = 128 ** 3
WIDEN = 1e-6            # cells a triangle's box and a cell's box are widened by when marking


class OccupancyGrid(NamedTuple):
    lo: np.ndarray          # (3,) the box's low corner
    cell: np.ndarray        # (3,) a cell's size on each axis
    res: np.ndarray         # (3,) int64 cells on each axis
    region: np.ndarray      # (nx * ny * nz,) int32: the region of an unmarked cell, -1 where marked
    inside: np.ndarray      # (regions,) bool: each region's answer

    def lookup(self, points: np.ndarray, threads=None) -> tuple[np.ndarray, np.ndarray]:
        """(inside, known) of (N, 3) float64 points: the answer where the grid gives one."""
        n = len(points)
        points = read_only(points)      # one compiled kernel whatever the caller's flags
        inside, known = np.zeros(n, np.bool_), np.zeros(n, np.bool_)
        for_ranges(lambda i0, i1: _lookup(points, self.lo, self.cell, self.res, self.region, self.inside,
                                          inside, known, np.int64(i0), np.int64(i1)),
                   n, threads, kernel=_lookup, min_size=1 << 15)
        return inside, known


def occupancy_grid(vertices: np.ndarray, faces: np.ndarray, classify) -> OccupancyGrid:
    """The grid of the closed mesh (vertices (V, 3) float64, faces (F, 3) int); classify: a
    function of (R, 3) points giving (R,) bool, inside by one parity ray each."""
    v = np.ascontiguousarray(vertices, np.float64)
    f = np.ascontiguousarray(faces, np.int64)
    lo, hi = v.min(axis=0), v.max(axis=0)
    extent = np.maximum(hi - lo, 1e-300)
    cells = min(MAX_CELLS, max(MIN_CELLS, CELLS_PER_TRIANGLE * len(f)))
    side = (cells / np.prod(extent)) ** (1.0 / 3.0) if np.all(hi > lo) else 0.0
    res = np.array([max(1, min(int(math.ceil(e * side)), 1024)) for e in extent], np.int64)
    cell = extent / res
    region = np.zeros(int(np.prod(res)), np.int32)
    _mark(v, f, lo, cell, res, region)
    seeds = np.empty(len(region), np.int64)
    count = _regions(res, region, seeds)
    seeds = seeds[:count]
    centres = np.empty((count, 3))
    nx, ny = res[0], res[1]
    centres[:, 0] = lo[0] + (seeds % nx + 0.5) * cell[0]
    centres[:, 1] = lo[1] + (seeds // nx % ny + 0.5) * cell[1]
    centres[:, 2] = lo[2] + (seeds // (nx * ny) + 0.5) * cell[2]
    inside = np.asarray(classify(centres), np.bool_) if count else np.zeros(0, np.bool_)
    return OccupancyGrid(lo, cell, res, region, inside)


@njit
def _mark(v, f, lo, cell, res, region):
    """region[c] = -1 for every cell c a triangle may touch."""
    nx, ny = res[0], res[1]
    first = np.empty(3, np.int64)
    last = np.empty(3, np.int64)
    for t in range(f.shape[0]):
        a, b, c = f[t, 0], f[t, 1], f[t, 2]
        ex0 = v[b, 0] - v[a, 0]
        ex1 = v[b, 1] - v[a, 1]
        ex2 = v[b, 2] - v[a, 2]
        ey0 = v[c, 0] - v[a, 0]
        ey1 = v[c, 1] - v[a, 1]
        ey2 = v[c, 2] - v[a, 2]
        n0 = ex1 * ey2 - ex2 * ey1
        n1 = ex2 * ey0 - ex0 * ey2
        n2 = ex0 * ey1 - ex1 * ey0
        d = n0 * v[a, 0] + n1 * v[a, 1] + n2 * v[a, 2]
        for k in range(3):
            mn = min(v[a, k], v[b, k], v[c, k])
            mx = max(v[a, k], v[b, k], v[c, k])
            first[k] = max(0, int(math.floor((mn - lo[k]) / cell[k] - WIDEN)))
            last[k] = min(res[k] - 1, int(math.floor((mx - lo[k]) / cell[k] + WIDEN)))
        # the plane may meet a cell when |n . (centre - a)| <= sum |n_k| half_k, both widened
        h0, h1, h2 = 0.5 * cell[0] * (1 + 4 * WIDEN), 0.5 * cell[1] * (1 + 4 * WIDEN), 0.5 * cell[2] * (1 + 4 * WIDEN)
        reach = abs(n0) * h0 + abs(n1) * h1 + abs(n2) * h2
        slack = 1e-9 * (abs(n0) * (abs(v[a, 0]) + cell[0]) + abs(n1) * (abs(v[a, 1]) + cell[1])
                        + abs(n2) * (abs(v[a, 2]) + cell[2]))
        for z in range(first[2], last[2] + 1):
            cz = lo[2] + (z + 0.5) * cell[2]
            for y in range(first[1], last[1] + 1):
                cy = lo[1] + (y + 0.5) * cell[1]
                for x in range(first[0], last[0] + 1):
                    cx = lo[0] + (x + 0.5) * cell[0]
                    if abs(n0 * cx + n1 * cy + n2 * cz - d) <= reach + slack:
                        region[x + nx * (y + ny * z)] = -1


@njit
def _regions(res, region, seeds):
    """Number the unmarked cells' regions (6-connected) 0, 1, ... in place; seeds[r] = the first
    cell of region r. Returns the number of regions."""
    nx, ny, nz = res[0], res[1], res[2]
    total = nx * ny * nz
    for c in range(total):
        if region[c] == 0:
            region[c] = -2                      # unmarked, not numbered yet
    queue = np.empty(total, np.int64)
    count = 0
    for c in range(total):
        if region[c] != -2:
            continue
        seeds[count] = c
        region[c] = count
        head, tail = 0, 1
        queue[0] = c
        while head < tail:
            q = queue[head]
            head += 1
            x = q % nx
            y = q // nx % ny
            z = q // (nx * ny)
            for k in range(6):
                xx, yy, zz = x, y, z
                if k == 0:
                    xx -= 1
                elif k == 1:
                    xx += 1
                elif k == 2:
                    yy -= 1
                elif k == 3:
                    yy += 1
                elif k == 4:
                    zz -= 1
                else:
                    zz += 1
                if xx < 0 or yy < 0 or zz < 0 or xx >= nx or yy >= ny or zz >= nz:
                    continue
                nb = xx + nx * (yy + ny * zz)
                if region[nb] == -2:
                    region[nb] = count
                    queue[tail] = nb
                    tail += 1
        count += 1
    return count


@njit
def _lookup(points, lo, cell, res, region, answer, inside, known, i0, i1):
    for i in range(i0, i1):
        out = False
        on_box = False
        cell_index = 0
        stride = 1
        for k in range(3):
            f = (points[i, k] - lo[k]) / cell[k]
            if f < 0.0 or f > res[k]:
                out = True
            elif f == 0.0 or f == res[k]:
                on_box = True
            else:
                cell_index += stride * min(res[k] - 1, int(math.floor(f)))
            stride *= res[k]
        if out:
            known[i] = True                     # outside the mesh's box: outside the mesh
            continue
        if on_box:
            continue
        r = region[cell_index]
        if r >= 0:
            inside[i] = answer[r]
            known[i] = True

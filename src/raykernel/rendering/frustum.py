"""A tile's eye rays against the scene's box, all at once: when none can enter it, none is traced.

    if tile_misses_box(cam, i0, i1, j0, j1, boxes, b):    # cam as render.camera_vectors
        ...     # every eye ray through the samples i0..i1 x j0..j1 misses box b

The eye rays of a tile fill the pyramid from the eye over the quadrilateral of its corner
samples' directions (a sample's direction is affine in its column and row). A box wholly
beyond one of the pyramid's four side planes is missed by every ray of the tile. The box must
clear the plane by MARGIN of its distance from the eye, an angle far above the rounding of the
rays' directions and of their slab tests (some 1e-16 of the distances), so that each ray's own
test would have missed it too: a culled tile gets exactly the colours and counts it would have
had, for the work of one test. Boxes that are empty or not finite are never culled.
"""

import math

from ..geometry.config import njit

MARGIN = 1e-9


@njit(inline="always")
def _direction(cam, i, j):
    """The direction (not unit) of the eye ray through sample (i, j), as render.py computes it."""
    return (cam[3] + i * cam[6] + j * cam[9], cam[4] + i * cam[7] + j * cam[10],
            cam[5] + i * cam[8] + j * cam[11])


@njit(inline="always")
def _corner(cam, k, i0, i1, j0, j1):
    """The direction of the tile's corner k, counted around it: (i0, j0), (i1, j0), (i1, j1), (i0, j1)."""
    k = k % 4
    return _direction(cam, i1 if k == 1 or k == 2 else i0, j1 if k >= 2 else j0)


@njit      # compiled apart, once: inlined, its planes' loops cost the renderer's compile seconds
def tile_misses_box(cam, i0, i1, j0, j1, boxes, b):
    """True when every eye ray through the samples of columns i0..i1 and rows j0..j1 misses box b
    of `boxes` (rows xmin, ymin, zmin, xmax, ymax, zmax); False when some may enter it."""
    for k in range(6):
        if not math.isfinite(boxes[b, k]):
            return False
    if not (boxes[b, 0] <= boxes[b, 3] and boxes[b, 1] <= boxes[b, 4] and boxes[b, 2] <= boxes[b, 5]):
        return False
    for side in range(4):
        if _beyond(cam, side, i0, i1, j0, j1, boxes, b):
            return True
    return False


@njit(inline="always")
def _beyond(cam, side, i0, i1, j0, j1, boxes, b):
    """True when box b lies wholly beyond the side plane through the eye and the directions of
    corners `side` and side + 1, on the side away from the other two corners."""
    px, py, pz = _corner(cam, side, i0, i1, j0, j1)
    qx, qy, qz = _corner(cam, side + 1, i0, i1, j0, j1)
    rx, ry, rz = _corner(cam, side + 2, i0, i1, j0, j1)
    sx, sy, sz = _corner(cam, side + 3, i0, i1, j0, j1)
    nx, ny, nz = py * qz - pz * qy, pz * qx - px * qz, px * qy - py * qx
    side_r = nx * rx + ny * ry + nz * rz
    side_s = nx * sx + ny * sy + nz * sz
    if side_r < 0.0 and side_s < 0.0:
        nx, ny, nz = -nx, -ny, -nz
    elif not (side_r >= 0.0 and side_s >= 0.0):
        return False        # r and s on different sides: not a side plane of the tile's rays
    norm = math.sqrt(nx * nx + ny * ny + nz * nz)
    if not norm > 0.0:
        return False        # p and q the same direction (a tile one sample wide)
    for k in range(8):
        wx = (boxes[b, 3] if k & 1 else boxes[b, 0]) - cam[0]
        wy = (boxes[b, 4] if k & 2 else boxes[b, 1]) - cam[1]
        wz = (boxes[b, 5] if k & 4 else boxes[b, 2]) - cam[2]
        if not (nx * wx + ny * wy + nz * wz + MARGIN * norm * math.sqrt(wx * wx + wy * wy + wz * wz) < 0.0):
            return False
    return True

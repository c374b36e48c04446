"""Ray against axis-aligned box: the slab test every walk and the mesh kernel use.

    ix, iy, iz = inverse(dx), inverse(dy), inverse(dz)
    te = box_entry(boxes, i, ox, oy, oz, ix, iy, iz, tmin, tmax)   # inf: missed

Boxes are rows xmin, ymin, zmin, xmax, ymax, zmax. The exit distance is
widened by CONSERVATIVE (Ize 2013: 2 gamma(3)) so that rounding never
rejects a box the ray crosses.
"""

import numpy as np

from .config import njit

INF = np.inf
CONSERVATIVE = 1.0 + 2.0 * (3 * 2.0 ** -53) / (1.0 - 3 * 2.0 ** -53)
STILL = 1e300                # inverse(0.0): the ray does not move along that axis
CULL_MARGIN = 1e-9           # culling boxes grow by this much of their aggregate's size or distance from the origin


@njit(inline="always")
def inverse(d):
    # a huge finite reciprocal keeps 0 * (1/d) from becoming NaN at slab planes
    if d == 0.0:
        return STILL
    return 1.0 / d


@njit(inline="always")
def slab(lo, hi, o, inv):
    """(entry, exit) t of the ray in the slab lo <= x <= hi, inv = inverse(direction).
    A ray that does not move along the axis is in the closed slab for every t or for
    none: on the wall x = hi the products would give (-huge, 0), as if it left at t = 0."""
    if inv == STILL:
        if lo <= o <= hi:
            return -INF, INF
        return INF, -INF
    t0 = (lo - o) * inv
    t1 = (hi - o) * inv
    if t0 > t1:
        return t1, t0
    return t0, t1


@njit(inline="always")
def box_entry(b, i, ox, oy, oz, ix, iy, iz, tmin, tmax):
    """Entry distance of the ray into box i of `b` within [tmin, tmax], or inf."""
    t0, t1 = slab(b[i, 0], b[i, 3], ox, ix)
    t2, t3 = slab(b[i, 1], b[i, 4], oy, iy)
    t4, t5 = slab(b[i, 2], b[i, 5], oz, iz)
    tnear = max(max(t0, t2), max(t4, tmin))
    tfar = min(min(t1, t3), min(t5, tmax)) * CONSERVATIVE if min(min(t1, t3), t5) > 0.0 else \
        min(min(t1, t3), min(t5, tmax))
    if tnear <= tfar:
        return tnear
    return INF


def cull_margin(box) -> float:
    """How much an aggregate's culling boxes grow: CULL_MARGIN of its size or distance from the
    origin, the margin the grid and the octree give their cells. A ray through a vertex on a
    box's wall, rounded by an instance's map, can pass just outside the box while the
    primitive test still reports the hit: without the margin a BVH or a nested aggregate
    would miss a hit that a list finds. 0 for an empty box."""
    if not np.all(np.isfinite(box)):
        return 0.0
    return CULL_MARGIN * max(float((box[3:] - box[:3]).max()), float(np.abs(box).max()))

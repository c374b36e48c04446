"""Shadow rays that let light through transparent surfaces (`--shadows filtered`).

    lr, lg, lb = light_through(geo, mats, ox, oy, oz, tx, ty, tz, reach, medium, filtered, ws, cnt)

Unfiltered, any surface between a point and a light blocks it (one any-hit query). Filtered, the
ray walks the surfaces in order: an opaque one (T = 0) blocks the light, a transparent one passes
it times T; inside a transparent object (entered through a surface facing the ray, left through
one facing away) the light is also filtered by the object's colour to the power of the distance
(Hall's filtering; Whitted shading starts every shadow ray in air, medium -1, and so only
multiplies by T). Refraction does not bend shadow rays.
"""

import math

import numpy as np

from ..engine.traverse import ANY_HIT, ANY_OPAQUE, CLOSEST, intersect
from ..geometry import counters as C
from ..geometry.config import njit
from ..geometry.surface import dot, hit_normals
from .tricks import TRANSPARENTLAST, cached_block, remember_blocker
from .tricks import blocked as tricks_blocked

MAX_CROSSINGS = 64      # a filtered shadow ray gives up (blocked) after passing this many surfaces


@njit(inline="always")
def filter_by_distance(mats, medium, distance, wr, wg, wb):
    """Weights filtered by `distance` travelled inside material `medium` (-1: air, no change)."""
    if medium < 0:
        return wr, wg, wb
    return wr * mats[medium, 0] ** distance, wg * mats[medium, 1] ** distance, wb * mats[medium, 2] ** distance


@njit(inline="always")    # inlined, as tricks.closest and for the same reason
def light_through(geo, mats, ox, oy, oz, tx, ty, tz, reach, medium, filtered, slot, tricks, state, ws, cnt):
    """Fraction of a light's colour that reaches (ox, oy, oz) along (tx, ty, tz) (to the light, t in
    [0, reach]), starting in `medium`: 0 when an opaque surface (any surface, unless filtered) is in
    the way. slot, tricks, state: the shadow cache and trick 4 (tricks.py)."""
    length = math.sqrt(dot(tx, ty, tz, tx, ty, tz))
    if not filtered:
        if tricks_blocked(geo, ox, oy, oz, tx, ty, tz, reach, ANY_HIT, slot, tricks, state, ws, cnt):
            return 0.0, 0.0, 0.0
        return filter_by_distance(mats, medium, reach * length, 1.0, 1.0, 1.0)
    if tricks & TRANSPARENTLAST:
        # trick 4: opaque surfaces first, in one any-hit query; the walk below meets only clear ones
        if tricks_blocked(geo, ox, oy, oz, tx, ty, tz, reach, ANY_OPAQUE, slot, tricks, state, ws, cnt):
            return 0.0, 0.0, 0.0
    elif cached_block(geo, ox, oy, oz, tx, ty, tz, reach, slot, True, tricks, state, cnt):
        return 0.0, 0.0, 0.0
    fr, fg, fb = 1.0, 1.0, 1.0
    t0 = 0.0
    for _ in range(MAX_CROSSINGS):
        cnt[C.SHADOW_STEPS] += 1
        if not intersect(geo, ox, oy, oz, tx, ty, tz, t0, reach, CLOSEST, ws, cnt):
            return filter_by_distance(mats, medium, (reach - t0) * length, fr, fg, fb)
        hit_f, hit_i = ws.hit_f, ws.hit_i
        t = hit_f[0]
        px, py, pz = ox + t * tx, oy + t * ty, oz + t * tz
        gx, gy, gz, _, _, _, mat = hit_normals(geo, hit_f, hit_i, px, py, pz)
        kt = mats[mat, 6]
        if kt <= 0.0:
            remember_blocker(slot, tricks, state, ws)
            return 0.0, 0.0, 0.0
        fr, fg, fb = filter_by_distance(mats, medium, (t - t0) * length, fr * kt, fg * kt, fb * kt)
        medium = mat if dot(gx, gy, gz, tx, ty, tz) < 0.0 else np.int64(-1)
        t0 = t + 1e-9 * max(1.0, t)
    return 0.0, 0.0, 0.0

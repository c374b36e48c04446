"""The octree walks' shared codes and entry steps, and the parametric walk (Revelles, Urena and Lastra 2000).

    sp, s, e = parametric(oct_bounds, ..., node, oi, ray, tmin, best_t, stack_a, stack_b, stack_t, sp, cnt, work)
    sp = push(stack_a, stack_b, stack_t, sp, node, entry_tag(CODE, PARAM), t)   # the entries it pushes
    TRAVERSALS[oct_walk[oi]]                # "point", "neighbor", "parametric" or "wall"

octree.py's walk_step (octree_step) chooses the walk; the point, neighbor and
wall walks are octpoint.py's. octree.py's docstring gives the layout.
"""

from __future__ import annotations

import numpy as np

from ..geometry import counters as C
from ..geometry.boxes import CONSERVATIVE, INF, STILL, slab
from ..geometry.config import njit
from ..geometry.counters import own_columns
from .octbuild import ADDRESS_BITS
from .walk import entry_tag, note_visit, push

__all__ = ["parametric", "CODE", "TRAVERSALS", "POINT_WALK", "NEIGHBOR_WALK", "PARAMETRIC_WALK", "WALL_WALK",
           "COUNTERS", "WALL_STEPS", "NEXT", "PARAM", "PASS"]

TRAVERSALS = ("point", "neighbor", "parametric", "wall")   # oct_walk codes 0, 1, 2, 3
POINT_WALK, NEIGHBOR_WALK, PARAMETRIC_WALK, WALL_WALK = 0, 1, 2, 3
CODE = 3                   # the octree walk's code (octree.py's WALK; its entries are tagged with it)
# its own counter: the wall quadtrees' nodes the wall walk went through (cost model: not priced)
COUNTERS = (("octree.wall_steps", None),)
WALL_STEPS, = own_columns(CODE, len(COUNTERS))
NEXT = 1        # step: go on with the point/neighbor walk by descending from node stack_a
PARAM = 2       # step: the parametric walk visits node stack_a, entered at stack_t
PASS = 3        # step: a lazy octree leaf left at stack_t without a closer hit: count a pass in
#                 cnt[N_COUNTERS + stack_a] (aggregates/lazyoctree.py)


@njit(inline="always")
def _node_margins(oct_origin, oct_unit, oi, level):
    """cell_margin on each axis for a node at `level` of octree oi: at least the items' margin,
    whose depth is the node's or deeper."""
    big = 0.0
    for k in range(3):
        big = max(big, max(oct_unit[oi, k] * float(1 << ADDRESS_BITS), abs(oct_origin[oi, k])))
    size = float(np.int64(1) << (ADDRESS_BITS - level))
    return (1e-9 * big + 1e-7 * oct_unit[oi, 0] * size, 1e-9 * big + 1e-7 * oct_unit[oi, 1] * size,
            1e-9 * big + 1e-7 * oct_unit[oi, 2] * size)


@njit(inline="always")
def _cell_slab(lo, hi, o, inv, top):
    """slab for an octree cell: a still ray on the wall between two cells is in the upper
    one only, as a point's address puts it (the items there are in both), unless the wall is
    the octree's upper wall `top`."""
    if inv == STILL:
        if lo <= o and (o < hi or o == top):
            return -INF, INF
        return INF, -INF
    return slab(lo, hi, o, inv)


@njit(private=True)
def parametric(oct_bounds, oct_count, oct_first, oct_level, oct_loc, oct_origin, oct_pass, oct_root, oct_unit,
               node, oi, ray, tmin, best_t,
               stack_a, stack_b, stack_t, sp, cnt, work):
    ox, oy, oz, _, _, _, ix, iy, iz = ray
    # Revelles, Urena and Lastra 2000: node parameters with the ray reflected
    # onto positive directions (amask: the reflected axes)
    while True:
        cnt[C.CELLS_VISITED] += 1
        note_visit(work, CODE, node)
        cnt[C.BOUNDS_TESTS] += 1
        nb = oct_bounds
        top = oct_root[oi]
        amask = 0
        # the node's box widened by the margin its items got, so that a ray meeting an item within
        # it (through an edge on the node's wall, rounded by an instance's map) meets the node too
        mx, my, mz = _node_margins(oct_origin, oct_unit, oi, oct_level[node])
        if ix >= 0.0:
            tx0, tx1 = _cell_slab(nb[node, 0] - mx, nb[node, 3] + mx, ox, ix, nb[top, 3] + mx)
        else:
            tx0, tx1 = (nb[node, 3] + mx - ox) * ix, (nb[node, 0] - mx - ox) * ix
            amask |= 1
        if iy >= 0.0:
            ty0, ty1 = _cell_slab(nb[node, 1] - my, nb[node, 4] + my, oy, iy, nb[top, 4] + my)
        else:
            ty0, ty1 = (nb[node, 4] + my - oy) * iy, (nb[node, 1] - my - oy) * iy
            amask |= 2
        if iz >= 0.0:
            tz0, tz1 = _cell_slab(nb[node, 2] - mz, nb[node, 5] + mz, oz, iz, nb[top, 5] + mz)
        else:
            tz0, tz1 = (nb[node, 5] + mz - oz) * iz, (nb[node, 2] - mz - oz) * iz
            amask |= 4
        ot0 = max(max(tx0, ty0), tz0)
        ot1 = min(min(tx1, ty1), tz1)
        if ot0 > (ot1 * CONSERVATIVE if ot1 > 0.0 else ot1) or ot1 < tmin or ot0 > best_t:
            return sp, 0, 0     # a collapsed node's shrunk box the ray misses
        n_items = oct_count[node]
        if n_items >= 0:
            cnt[C.CELLS_LEAVES] += 1
            if n_items == 0:
                cnt[C.CELLS_EMPTY] += 1
                return sp, 0, 0
            s = oct_first[node]
            col = oct_pass[node]
            if col >= 0 and C.N_COUNTERS + col < cnt.shape[0]:
                sp = push(stack_a, stack_b, stack_t, sp, col, entry_tag(CODE, PASS), ot1)
            return sp, s, s + n_items
        # the centre planes
        half = np.int64(1) << (ADDRESS_BITS - 1 - oct_level[node])
        txm = (oct_origin[oi, 0] + oct_unit[oi, 0] * (oct_loc[node, 0] + half) - ox) * ix
        tym = (oct_origin[oi, 1] + oct_unit[oi, 1] * (oct_loc[node, 1] + half) - oy) * iy
        tzm = (oct_origin[oi, 2] + oct_unit[oi, 2] * (oct_loc[node, 2] + half) - oz) * iz
        # first child (their table 1): entry plane, then the centre planes crossed before it
        cur = 0
        if tx0 >= ty0 and tx0 >= tz0:
            cur = (2 if tym < tx0 else 0) | (4 if tzm < tx0 else 0)
        elif ty0 >= tz0:
            cur = (1 if txm < ty0 else 0) | (4 if tzm < ty0 else 0)
        else:
            cur = (1 if txm < tz0 else 0) | (2 if tym < tz0 else 0)
        child0 = oct_first[node]
        sp0 = sp
        tag = entry_tag(CODE, PARAM)
        while True:
            # child interval per axis: [t0, tm] below the centre plane, [tm, t1] above
            cx0, cx1 = (txm, tx1) if cur & 1 else (tx0, txm)
            cy0, cy1 = (tym, ty1) if cur & 2 else (ty0, tym)
            cz0, cz1 = (tzm, tz1) if cur & 4 else (tz0, tzm)
            centry = max(max(cx0, cy0), cz0)
            if centry > best_t:
                break
            if min(min(cx1, cy1), cz1) >= tmin:
                sp = push(stack_a, stack_b, stack_t, sp, child0 + (cur ^ amask), tag, centry)
            # next child (their table 3): across the nearest exit plane; the node's own wall ends it
            if cx1 <= cy1 and cx1 <= cz1:
                if cur & 1:
                    break
                cur |= 1
            elif cy1 <= cz1:
                if cur & 2:
                    break
                cur |= 2
            else:
                if cur & 4:
                    break
                cur |= 4
        # nearest child on top
        lo_i, hi_i = sp0, sp - 1
        while lo_i < hi_i:
            stack_a[lo_i], stack_a[hi_i] = stack_a[hi_i], stack_a[lo_i]
            stack_t[lo_i], stack_t[hi_i] = stack_t[hi_i], stack_t[lo_i]
            lo_i += 1
            hi_i -= 1
        if sp == sp0:
            return sp, 0, 0
        # go on with the nearest child at once (its entry is within best_t), as the driver would
        sp -= 1
        node = stack_a[sp]

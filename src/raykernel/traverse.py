"""The one intersection routine that drives every aggregate, nested to any depth.

    ws = workspace()                    # per thread: stacks, frames, hit record
    found = intersect(geo, ox, oy, oz, dx, dy, dz, 0.0, np.inf, False, ws, cnt)
    t = ws[5][0]; kind, index, instance = ws[6]

An explicit stack replaces recursion. Its entries are a BVH node, a grid
to start or to continue, or a range of references still to be tested. When
a reference names an aggregate or an instance, the rest of the current range is pushed, a frame is opened
for the child (the ray mapped into its space for an instance), and the
child's first entry is pushed above. A frame ends when the stack falls to
its base. Instance maps are affine and the direction is not renormalised,
so t means the same in every frame and one closest t shrinks through all.

A uniform grid is walked with the 3D-DDA (Amanatides and Woo 1987). Its
state (cell, next boundary crossings) lives in the frame's row of frame_f, so
a child aggregate found in a cell can open frames above it. A GRID entry on
the stack means "visit the grid's next cell"; its t is that cell's entry
distance, so once the closest hit lies before it the entry is dropped and
the walk stops. Empty cells are stepped over in one go; a non-empty cell
puts the GRID entry back and then tests the cell's references. With the
mailbox on, each frame of a grid keeps a direct-mapped cache of 64 tagged
references already tested (primitives and child aggregates alike) and skips
them in later cells: their result for this ray is already in best_t.

A ray-classification aggregate (aggregates/rc.py) is entered with an
RC_START entry: the ray is classified (direction-cube face, u, v, and its
entry point as origin), its face's 5D tree descended to one hypercube, and
that hypercube's candidate list tested in order, near first. The list's end
and the early-exit terms live in the frame (RF_*), so a child aggregate can
interrupt it; the rest is put back as an RC_NEXT entry. The walk stops once
the next candidate's key puts its earliest possible hit past the closest.
A lazy rc leaf that may still split (rc_pass >= 0) counts the ray's arrival
in cnt[N_COUNTERS + column], the column of the cell of its virtual subtree
the ray's 5D point falls in, where the kernel gave cnt room for it.

An octree (aggregates/octree.py) is walked one of three ways. point: the
leaf holding a point is found from the root by the point's 28-bit address
(Lathrop), its exit distance computed, and the point moved just past the
exit wall. neighbor: the same, but the next descent starts from the
neighbour across the exit wall (Glassner's pointers) rather than the root.
Both keep the point's address in the frame (OF_POINT) and put an OCT_NEXT
entry back before a non-empty leaf's references, like the grid. A point
outside a collapsed node's shrunk box lies in an empty octant the collapse
removed; its address bits give that octant, visited as an empty leaf.
parametric (Revelles et al.): node entries with their entry distance, the
children a ray crosses pushed farthest first, ordered by the first-child
and next-child rules over the centre-plane parameters. The grid's mailbox
serves octree frames too. A lazy octree's candidate leaf (see
aggregates/lazyoctree.py) gets an OCT_PASS entry at its exit distance above
the walk's continuation: popped with no closer hit found, it counts a pass
through the leaf into cnt[N_COUNTERS + column], where the kernel gave cnt
room for it (cast_rays does not: it never counts passes).
"""


import numpy as np
from numba import prange

from . import counters as C
from .config import njit
from .flatten import GRID, LIST, MAX_NESTING, STACK_SIZE
from .flatten import RC
from .flatten import OCTREE
from .primitives import (AGGREGATE, CONE, INDEX_MASK, INSTANCE, KIND_SHIFT, PATCH, POLYGON, SPHERE, TRIANGLE,
                         hit_cone, hit_polygon, hit_sphere, hit_triangle)

INF = np.inf
NODE = -1                    # stack entry tag: a BVH node rather than a ref range
GRID_NEXT = -2               # stack entry tag: continue the frame's grid walk (stack_a: grid index)
GRID_START = -3              # stack entry tag: start a grid walk at the entry distance stack_t
# Ize 2013: widen the exit distance by 2*gamma(3) so that rounding never
# rejects a box the ray actually crosses.
_CONSERVATIVE = 1.0 + 2.0 * (3 * 2.0 ** -53) / (1.0 - 3 * 2.0 ** -53)
GF_CELL = 18                 # per frame: current grid cell x, y, z
GF_TNEXT = 21                # per frame: t of the next cell boundary along x, y, z
GF_MBOX_ON = 24              # per frame: 1.0 when the frame's grid uses the mailbox
GF_MBOX = 25                 # per frame: MBOX_SLOTS tagged refs already tested (-1: free)
MBOX_SLOTS = 64
FRAME_F = GF_MBOX + MBOX_SLOTS  # per frame: ray origin, direction, world-to-local 3x4, grid state
HIT_F = 13                   # t, world-to-local 3x4 of the frame that was hit
HIT_I = 3                    # kind, index, innermost instance (-1: none)
RC_START = -16               # stack entry tag: classify the ray in rc aggregate stack_a, entered at stack_t
RC_NEXT = -17                # stack entry tag: continue the frame's rc candidate list at refs[stack_a]
RF_END, RF_O, RF_D = GF_CELL, GF_CELL + 1, GF_CELL + 2  # per rc frame: list end, s * origin and |direction|
#                              along the face's axis
RC_SLACK = 1.0 + 1e-7        # the early exit widens the closest hit by this factor (hit-point rounding)
OCT_START = -4               # stack entry tag: start an octree walk (stack_a: octree index) at stack_t
OCT_NEXT = -5                # stack entry tag: continue the point/neighbor walk by descending from node stack_a
OCT_PARAM = -6               # stack entry tag: parametric walk, visit node stack_a (entry distance stack_t)
OCT_PASS = -7                # stack entry tag: a lazy octree leaf left at stack_t; if the ray gets there without
#                              a closer hit, count a pass in cnt[N_COUNTERS + stack_a] (aggregates/lazyoctree.py)
OF_POINT = GF_CELL           # per frame: 28-bit address of the point the octree walk continues from
OCT_BITS = 28
OCT_FULL = 1 << OCT_BITS
ALL_HITS = 2                 # any_hit mode of intersect: record every hit (hit_i[0] must be 0 on entry)


@njit
def workspace():
    """Scratch arrays for one thread, allocated once per tile or chunk:
    (stack_a, stack_b, stack_t, frame_f, frame_i, hit_f, hit_i)."""
    return (np.zeros(STACK_SIZE, np.int64), np.zeros(STACK_SIZE, np.int64), np.zeros(STACK_SIZE),
            np.zeros((MAX_NESTING + 1, FRAME_F)), np.zeros((MAX_NESTING + 1, 3), np.int64),
            np.zeros(HIT_F), np.zeros(HIT_I, np.int64))


STILL = 1e300                # _inverse(0.0): the ray does not move along that axis


@njit(inline="always")
def _inverse(d):
    # a huge finite reciprocal keeps 0 * (1/d) from becoming NaN at slab planes
    if d == 0.0:
        return STILL
    return 1.0 / d


@njit(inline="always")
def _slab(lo, hi, o, inv):
    """(entry, exit) t of the ray in the slab lo <= x <= hi, inv = _inverse(direction).
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
def _cell_slab(lo, hi, o, inv, top):
    """_slab for an octree cell: a still ray on the wall between two cells is in the upper
    one only, as a point's address puts it (the items there are in both), unless the wall is
    the octree's upper wall `top`."""
    if inv == STILL:
        if lo <= o and (o < hi or o == top):
            return -INF, INF
        return INF, -INF
    return _slab(lo, hi, o, inv)


@njit(inline="always")
def _mailbox_reset(frame_f, f):
    """Turn the frame's mailbox on and empty it; returns True (the kernel's `mbox`)."""
    frame_f[f, GF_MBOX_ON] = 1.0
    for k in range(MBOX_SLOTS):
        frame_f[f, GF_MBOX + k] = -1.0
    return True


@njit(inline="always")
def _address(x, origin, scale, lo, hi):
    """The octree address of coordinate x, clamped to [lo, hi]."""
    u = (x - origin) * scale
    q = np.int64(u) if u >= 0.0 and u < OCT_FULL else (np.int64(OCT_FULL - 1) if u >= OCT_FULL else np.int64(0))
    return min(max(q, lo), hi)


@njit(inline="always")
def box_entry(b, i, ox, oy, oz, ix, iy, iz, tmin, tmax):
    """Entry distance of the ray into box i of `b` within [tmin, tmax], or inf."""
    t0, t1 = _slab(b[i, 0], b[i, 3], ox, ix)
    t2, t3 = _slab(b[i, 1], b[i, 4], oy, iy)
    t4, t5 = _slab(b[i, 2], b[i, 5], oz, iz)
    tnear = max(max(t0, t2), max(t4, tmin))
    tfar = min(min(t1, t3), min(t5, tmax)) * _CONSERVATIVE if min(min(t1, t3), t5) > 0.0 else \
        min(min(t1, t3), min(t5, tmax))
    if tnear <= tfar:
        return tnear
    return INF


@njit(inline="always")
def _push_aggregate(geo, a, ox, oy, oz, ix, iy, iz, tmin, tmax, stack_a, stack_b, stack_t, sp, cnt):
    """Test the aggregate's bounds and push its first entry; returns the new stack pointer."""
    cnt[C.BOUNDS_TESTS] += 1
    te = box_entry(geo.agg_bounds, a, ox, oy, oz, ix, iy, iz, tmin, tmax)
    if te == INF:
        return sp
    kind = geo.agg_kind[a]
    if kind == LIST:
        stack_a[sp] = geo.agg_start[a]
        stack_b[sp] = geo.agg_start[a] + geo.agg_count[a]
    elif kind == GRID:
        stack_a[sp] = geo.agg_start[a]
        stack_b[sp] = GRID_START
    elif kind == RC:
        stack_a[sp] = geo.agg_start[a]
        stack_b[sp] = RC_START
    elif kind == OCTREE:
        stack_a[sp] = geo.agg_start[a]
        stack_b[sp] = OCT_START
    else:
        stack_a[sp] = geo.agg_start[a]
        stack_b[sp] = NODE
    stack_t[sp] = te
    return sp + 1


@njit
def intersect(geo, ox, oy, oz, dx, dy, dz, tmin, tmax, any_hit,
              ws, cnt):
    """Closest hit (or, with any_hit, the first hit found) of the ray with
    the scene in [tmin, tmax]. On a hit returns True and fills hit_f
    (t, world-to-local map of the hit's frame) and hit_i (kind, index,
    innermost instance). Counts tests, bounds tests and steps into cnt.
    any_hit == ALL_HITS records every hit instead (see the hit-recording block)."""
    stack_a, stack_b, stack_t, frame_f, frame_i, hit_f, hit_i = ws
    best_t = tmax
    found = False
    best_ref = np.int64(-1)
    best_inst = np.int64(-1)
    ix, iy, iz = _inverse(dx), _inverse(dy), _inverse(dz)
    # frame 0: the root aggregate in world space
    f = 0
    frame_f[0, 0], frame_f[0, 1], frame_f[0, 2] = ox, oy, oz
    frame_f[0, 3], frame_f[0, 4], frame_f[0, 5] = dx, dy, dz
    for k in range(12):
        frame_f[0, 6 + k] = 0.0
    frame_f[0, 6] = frame_f[0, 11] = frame_f[0, 16] = 1.0
    frame_i[0, 0] = geo.root
    frame_i[0, 1] = 0
    frame_i[0, 2] = -1
    frame_f[0, GF_MBOX_ON] = 0.0
    mbox = False
    rc_on = False
    rc_o = rc_d = 0.0
    base = 0
    sp = _push_aggregate(geo, geo.root, ox, oy, oz, ix, iy, iz, tmin, best_t, stack_a, stack_b, stack_t, 0, cnt)
    while True:
        if sp == base:
            if f == 0:
                break
            # this frame is done: back to the parent's ray
            f -= 1
            base = frame_i[f, 1]
            ox, oy, oz = frame_f[f, 0], frame_f[f, 1], frame_f[f, 2]
            dx, dy, dz = frame_f[f, 3], frame_f[f, 4], frame_f[f, 5]
            ix, iy, iz = _inverse(dx), _inverse(dy), _inverse(dz)
            mbox = frame_f[f, GF_MBOX_ON] != 0.0
            continue
        sp -= 1
        a = stack_a[sp]
        b = stack_b[sp]
        rc_on = False
        if stack_t[sp] > best_t and (b != NODE or stack_t[sp] > best_t * _CONSERVATIVE):
            # entered beyond the closest hit so far; a BVH node entered within rounding of it
            # may hold a primitive hit at exactly best_t (coplanar faces), which the tie rule needs
            continue
        if b == NODE:
            node = a
            cnt[C.CELLS_VISITED] += 1
            n_items = geo.node_count[node]
            if n_items == 0:
                # inner node: test both children, visit the nearer first
                left = geo.node_first[node]
                right = left + 1
                cnt[C.BOUNDS_TESTS] += 2
                tl = box_entry(geo.node_bounds, left, ox, oy, oz, ix, iy, iz, tmin, best_t)
                tr = box_entry(geo.node_bounds, right, ox, oy, oz, ix, iy, iz, tmin, best_t)
                if tl <= tr:
                    if tr != INF:
                        stack_a[sp], stack_b[sp], stack_t[sp] = right, NODE, tr
                        sp += 1
                    if tl != INF:
                        stack_a[sp], stack_b[sp], stack_t[sp] = left, NODE, tl
                        sp += 1
                else:
                    if tl != INF:
                        stack_a[sp], stack_b[sp], stack_t[sp] = left, NODE, tl
                        sp += 1
                    stack_a[sp], stack_b[sp], stack_t[sp] = right, NODE, tr
                    sp += 1
                continue
            cnt[C.CELLS_LEAVES] += 1
            if n_items == 0:
                cnt[C.CELLS_EMPTY] += 1
                continue
            s = geo.node_first[node]
            e = s + n_items
        elif b == RC_START or b == RC_NEXT:
            # ray classification: the ray's face, (u, v) and entry point pick one hypercube
            if b == RC_START:
                rgt = stack_t[sp]
                rax, ray_, raz = abs(dx), abs(dy), abs(dz)
                if rax >= ray_ and rax >= raz:
                    rface = 0 if dx > 0.0 else 1
                    rc_d, rc_o, rcu, rcv = rax, (ox if dx > 0.0 else -ox), dy / rax, dz / rax
                elif ray_ >= raz:
                    rface = 2 if dy > 0.0 else 3
                    rc_d, rc_o, rcu, rcv = ray_, (oy if dy > 0.0 else -oy), dz / ray_, dx / ray_
                else:
                    rface = 4 if dz > 0.0 else 5
                    rc_d, rc_o, rcu, rcv = raz, (oz if dz > 0.0 else -oz), dx / raz, dy / raz
                rpx, rpy, rpz = ox + rgt * dx, oy + rgt * dy, oz + rgt * dz
                rnode = geo.rc_face_root[a, rface]
                while True:
                    cnt[C.CELLS_VISITED] += 1
                    rnb = geo.rc_node_b[rnode]
                    if rnb >= 0:
                        break
                    rq = rpx if rnb == -1 else (rpy if rnb == -2 else (rpz if rnb == -3 else
                                                                      (rcu if rnb == -4 else rcv)))
                    rnode = geo.rc_node_a[rnode] + (0 if rq < geo.rc_split[rnode] else 1)
                rpj = geo.rc_pass[rnode]
                if rpj >= 0:
                    # a lazy rc leaf that may split: count the arrival in its virtual cell (aggregates/rc.py)
                    rcol = C.N_COUNTERS + geo.rc_vinfo[rpj, 0]
                    rk = geo.rc_vinfo[rpj, 1]
                    if rcol + (1 << rk) <= cnt.shape[0]:
                        roff = geo.rc_vinfo[rpj, 2] - 1
                        rh = 1
                        for _ in range(rk):
                            rdim = geo.rc_vdim[roff + rh]
                            rq = rpx if rdim == 0 else (rpy if rdim == 1 else (rpz if rdim == 2 else
                                                                              (rcu if rdim == 3 else rcv)))
                            rh = 2 * rh + (0 if rq < geo.rc_vsplit[roff + rh] else 1)
                        cnt[rcol + rh - (1 << rk)] += 1
                cnt[C.CELLS_LEAVES] += 1
                if rnb == 0:
                    cnt[C.CELLS_EMPTY] += 1
                    continue
                s = geo.rc_node_a[rnode]
                e = s + rnb
                frame_f[f, RF_END], frame_f[f, RF_O], frame_f[f, RF_D] = e, rc_o, rc_d
            else:
                s = a
                e = np.int64(frame_f[f, RF_END])
                rc_o, rc_d = frame_f[f, RF_O], frame_f[f, RF_D]
            rc_on = True
        elif b <= OCT_START:
            if b == OCT_PASS:
                cnt[C.N_COUNTERS + a] += 1
                continue
            # octree: the parametric walk, or a walk of leaves by point location
            oi = geo.agg_start[frame_i[f, 0]]
            if b == OCT_START and geo.oct_mailbox[oi] != 0:
                mbox = _mailbox_reset(frame_f, f)
            s = e = 0
            if b == OCT_PARAM or (b == OCT_START and geo.oct_walk[oi] == 2):
                # Revelles, Urena and Lastra 2000: node parameters with the ray reflected
                # onto positive directions (amask: the reflected axes)
                node = a if b == OCT_PARAM else geo.oct_root[oi]
                cnt[C.CELLS_VISITED] += 1
                cnt[C.BOUNDS_TESTS] += 1
                nb = geo.oct_bounds
                top = geo.oct_root[oi]
                amask = 0
                if ix >= 0.0:
                    tx0, tx1 = _cell_slab(nb[node, 0], nb[node, 3], ox, ix, nb[top, 3])
                else:
                    tx0, tx1 = (nb[node, 3] - ox) * ix, (nb[node, 0] - ox) * ix
                    amask |= 1
                if iy >= 0.0:
                    ty0, ty1 = _cell_slab(nb[node, 1], nb[node, 4], oy, iy, nb[top, 4])
                else:
                    ty0, ty1 = (nb[node, 4] - oy) * iy, (nb[node, 1] - oy) * iy
                    amask |= 2
                if iz >= 0.0:
                    tz0, tz1 = _cell_slab(nb[node, 2], nb[node, 5], oz, iz, nb[top, 5])
                else:
                    tz0, tz1 = (nb[node, 5] - oz) * iz, (nb[node, 2] - oz) * iz
                    amask |= 4
                ot0 = max(max(tx0, ty0), tz0)
                ot1 = min(min(tx1, ty1), tz1)
                if ot0 > (ot1 * _CONSERVATIVE if ot1 > 0.0 else ot1) or ot1 < tmin or ot0 > best_t:
                    continue    # a collapsed node's shrunk box the ray misses
                n_items = geo.oct_count[node]
                if n_items >= 0:
                    cnt[C.CELLS_LEAVES] += 1
                    if n_items == 0:
                        cnt[C.CELLS_EMPTY] += 1
                        continue
                    s = geo.oct_first[node]
                    e = s + n_items
                    col = geo.oct_pass[node]
                    if col >= 0 and C.N_COUNTERS + col < cnt.shape[0]:
                        stack_a[sp], stack_b[sp], stack_t[sp] = col, OCT_PASS, ot1
                        sp += 1
                else:
                    # the centre planes
                    half = np.int64(1) << (OCT_BITS - 1 - geo.oct_level[node])
                    txm = (geo.oct_origin[oi, 0] + geo.oct_unit[oi, 0] * (geo.oct_loc[node, 0] + half) - ox) * ix
                    tym = (geo.oct_origin[oi, 1] + geo.oct_unit[oi, 1] * (geo.oct_loc[node, 1] + half) - oy) * iy
                    tzm = (geo.oct_origin[oi, 2] + geo.oct_unit[oi, 2] * (geo.oct_loc[node, 2] + half) - oz) * iz
                    # first child (their table 1): entry plane, then the centre planes crossed before it
                    cur = 0
                    if tx0 >= ty0 and tx0 >= tz0:
                        cur = (2 if tym < tx0 else 0) | (4 if tzm < tx0 else 0)
                    elif ty0 >= tz0:
                        cur = (1 if txm < ty0 else 0) | (4 if tzm < ty0 else 0)
                    else:
                        cur = (1 if txm < tz0 else 0) | (2 if tym < tz0 else 0)
                    child0 = geo.oct_first[node]
                    sp0 = sp
                    while True:
                        # child interval per axis: [t0, tm] below the centre plane, [tm, t1] above
                        cx0, cx1 = (txm, tx1) if cur & 1 else (tx0, txm)
                        cy0, cy1 = (tym, ty1) if cur & 2 else (ty0, tym)
                        cz0, cz1 = (tzm, tz1) if cur & 4 else (tz0, tzm)
                        centry = max(max(cx0, cy0), cz0)
                        if centry > best_t:
                            break
                        if min(min(cx1, cy1), cz1) >= tmin:
                            stack_a[sp], stack_b[sp], stack_t[sp] = child0 + (cur ^ amask), OCT_PARAM, centry
                            sp += 1
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
                    continue
            else:
                # point (Lathrop) or neighbor (Glassner): find the leaf holding the point p
                # by its 28-bit address, leave it across its nearest wall, repeat
                walk = geo.oct_walk[oi]
                gox, goy, goz = geo.oct_origin[oi, 0], geo.oct_origin[oi, 1], geo.oct_origin[oi, 2]
                gux, guy, guz = geo.oct_unit[oi, 0], geo.oct_unit[oi, 1], geo.oct_unit[oi, 2]
                gsx, gsy, gsz = geo.oct_scale[oi, 0], geo.oct_scale[oi, 1], geo.oct_scale[oi, 2]
                top = np.int64(OCT_FULL - 1)
                if b == OCT_START:
                    gt = stack_t[sp]
                    px = _address(ox + gt * dx, gox, gsx, 0, top)
                    py = _address(oy + gt * dy, goy, gsy, 0, top)
                    pz = _address(oz + gt * dz, goz, gsz, 0, top)
                    node = geo.oct_root[oi]
                else:
                    px = np.int64(frame_f[f, OF_POINT])
                    py = np.int64(frame_f[f, OF_POINT + 1])
                    pz = np.int64(frame_f[f, OF_POINT + 2])
                    node = a
                while True:
                    # descend from node; it stays the container of the cell found
                    leaf = np.int64(-1)
                    while True:
                        cnt[C.CELLS_VISITED] += 1
                        sh = OCT_BITS - geo.oct_level[node]
                        lx, ly, lz = geo.oct_loc[node, 0], geo.oct_loc[node, 1], geo.oct_loc[node, 2]
                        diff = (px ^ lx) | (py ^ ly) | (pz ^ lz)
                        if diff >> sh != 0:
                            # p lies in an empty octant a collapse removed: the one its highest
                            # differing address bit selects
                            sh = 0
                            while diff >> (sh + 1) != 0:
                                sh += 1
                            break
                        if geo.oct_count[node] >= 0:
                            leaf = node
                            break
                        bit = sh - 1
                        node = geo.oct_first[node] + ((px >> bit) & 1) + 2 * ((py >> bit) & 1) + \
                            4 * ((pz >> bit) & 1)
                    side = np.int64(1) << sh
                    clx, cly, clz = (px >> sh) << sh, (py >> sh) << sh, (pz >> sh) << sh
                    cnt[C.CELLS_LEAVES] += 1
                    if leaf >= 0 and geo.oct_count[leaf] > 0:
                        s = geo.oct_first[leaf]
                        e = s + geo.oct_count[leaf]
                    else:
                        s = e = 0
                        cnt[C.CELLS_EMPTY] += 1
                    # leave the cell across its nearest wall
                    cnt[C.BOUNDS_TESTS] += 1
                    tx = (gox + gux * (clx + side) - ox) * ix if dx > 0.0 else \
                        ((gox + gux * clx - ox) * ix if dx < 0.0 else INF)
                    ty = (goy + guy * (cly + side) - oy) * iy if dy > 0.0 else \
                        ((goy + guy * cly - oy) * iy if dy < 0.0 else INF)
                    tz = (goz + guz * (clz + side) - oz) * iz if dz > 0.0 else \
                        ((goz + guz * clz - oz) * iz if dz < 0.0 else INF)
                    axis = 0 if tx <= ty and tx <= tz else (1 if ty <= tz else 2)
                    texit = min(min(tx, ty), tz)
                    out = texit == INF
                    # the point just past the exit: across the wall on the exit axis, in the cell on the others
                    px = _address(ox + texit * dx, gox, gsx, clx, clx + side - 1)
                    py = _address(oy + texit * dy, goy, gsy, cly, cly + side - 1)
                    pz = _address(oz + texit * dz, goz, gsz, clz, clz + side - 1)
                    if axis == 0:
                        px = clx + side if dx > 0.0 else clx - 1
                        out = out or px < 0 or px > top
                        pa = px
                    elif axis == 1:
                        py = cly + side if dy > 0.0 else cly - 1
                        out = out or py < 0 or py > top
                        pa = py
                    else:
                        pz = clz + side if dz > 0.0 else clz - 1
                        out = out or pz < 0 or pz > top
                        pa = pz
                    if walk == 0:
                        node = geo.oct_root[oi]
                    elif not out:
                        # still inside the container's slot, or across its wall to the neighbour
                        ssh = OCT_BITS - geo.oct_slot[node]
                        if pa >> ssh != geo.oct_loc[node, axis] >> ssh:
                            up = (dx > 0.0) if axis == 0 else ((dy > 0.0) if axis == 1 else (dz > 0.0))
                            node = geo.oct_nbr[node, 2 * axis + (1 if up else 0)]
                            out = node < 0
                    if s == e:
                        if out or texit > best_t:
                            break
                        continue
                    if not out:
                        # come back for the next leaf after this one's references
                        frame_f[f, OF_POINT], frame_f[f, OF_POINT + 1], frame_f[f, OF_POINT + 2] = px, py, pz
                        stack_a[sp], stack_b[sp], stack_t[sp] = node, OCT_NEXT, texit
                        sp += 1
                    col = geo.oct_pass[leaf]
                    if col >= 0 and C.N_COUNTERS + col < cnt.shape[0]:
                        # a lazy octree's candidate leaf: see whether the ray leaves it without a hit
                        stack_a[sp], stack_b[sp], stack_t[sp] = col, OCT_PASS, texit
                        sp += 1
                    break
                if s == e:
                    continue
        elif b < NODE:
            # grid: step the 3D-DDA to the next non-empty cell
            gi = a
            gt = stack_t[sp]
            rx, ry, rz = geo.grid_res[gi, 0], geo.grid_res[gi, 1], geo.grid_res[gi, 2]
            gox, goy, goz = geo.grid_origin[gi, 0], geo.grid_origin[gi, 1], geo.grid_origin[gi, 2]
            csx, csy, csz = geo.grid_cell_size[gi, 0], geo.grid_cell_size[gi, 1], geo.grid_cell_size[gi, 2]
            sx = 1 if dx > 0.0 else (-1 if dx < 0.0 else 0)
            sy = 1 if dy > 0.0 else (-1 if dy < 0.0 else 0)
            sz = 1 if dz > 0.0 else (-1 if dz < 0.0 else 0)
            if b == GRID_START:
                # the cell holding the entry point, clamped into the grid
                u = (ox + gt * dx - gox) * geo.grid_inv_cell[gi, 0]
                cx = np.int64(u) if u >= 0.0 and u < rx else (rx - 1 if u >= rx else 0)
                u = (oy + gt * dy - goy) * geo.grid_inv_cell[gi, 1]
                cy = np.int64(u) if u >= 0.0 and u < ry else (ry - 1 if u >= ry else 0)
                u = (oz + gt * dz - goz) * geo.grid_inv_cell[gi, 2]
                cz = np.int64(u) if u >= 0.0 and u < rz else (rz - 1 if u >= rz else 0)
                # crossings are computed from the boundary planes, so they never drift
                tx = (gox + (cx + (sx > 0)) * csx - ox) * ix if sx != 0 else INF
                ty = (goy + (cy + (sy > 0)) * csy - oy) * iy if sy != 0 else INF
                tz = (goz + (cz + (sz > 0)) * csz - oz) * iz if sz != 0 else INF
                if geo.grid_mailbox[gi] != 0:
                    mbox = _mailbox_reset(frame_f, f)
            else:
                cx = np.int64(frame_f[f, GF_CELL])
                cy = np.int64(frame_f[f, GF_CELL + 1])
                cz = np.int64(frame_f[f, GF_CELL + 2])
                tx, ty, tz = frame_f[f, GF_TNEXT], frame_f[f, GF_TNEXT + 1], frame_f[f, GF_TNEXT + 2]
            off = geo.grid_cell_offset[gi]
            s = e = 0
            while True:
                cnt[C.CELLS_VISITED] += 1
                cnt[C.CELLS_LEAVES] += 1
                cell = off + (cz * ry + cy) * rx + cx
                s = geo.grid_cells[cell]
                e = geo.grid_cells[cell + 1]
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
                        break
                    gt = texit
                    continue
                if not out:
                    # come back for the next cell after this one's references
                    frame_f[f, GF_CELL], frame_f[f, GF_CELL + 1], frame_f[f, GF_CELL + 2] = cx, cy, cz
                    frame_f[f, GF_TNEXT], frame_f[f, GF_TNEXT + 1], frame_f[f, GF_TNEXT + 2] = tx, ty, tz
                    stack_a[sp], stack_b[sp], stack_t[sp] = gi, GRID_NEXT, texit
                    sp += 1
                break
            if s == e:
                continue
        else:
            s = a
            e = b
        i = s
        while i < e:
            if rc_on:
                if geo.rc_key[i] > rc_o + best_t * rc_d * RC_SLACK + 1e-9 * abs(rc_o):
                    break       # rc: this and every later candidate lies beyond the closest hit
                ref = geo.rc_ref[i]
            else:
                ref = geo.refs[i]
            kind = ref >> KIND_SHIFT
            idx = ref & INDEX_MASK
            i += 1
            if mbox:
                slot = GF_MBOX + ((idx + 37 * kind) & (MBOX_SLOTS - 1))
                tag = np.float64(ref)
                if frame_f[f, slot] == tag:
                    cnt[C.MAILBOX_SAVED] += 1
                    continue
                frame_f[f, slot] = tag
            if kind == SPHERE:
                cnt[C.TESTS + SPHERE] += 1
                t = hit_sphere(geo.sph_center[idx, 0], geo.sph_center[idx, 1], geo.sph_center[idx, 2],
                               geo.sph_radius[idx], ox, oy, oz, dx, dy, dz, tmin, best_t)
            elif kind == POLYGON or kind == PATCH:
                cnt[C.TESTS + kind] += 1
                t = hit_polygon(geo.poly_normal, geo.poly_d, geo.poly_start, geo.poly_count, geo.poly_axis,
                                geo.poly_verts, idx, ox, oy, oz, dx, dy, dz, tmin, best_t)
            elif kind == TRIANGLE:
                cnt[C.TESTS + TRIANGLE] += 1
                fa, fb, fc = geo.tri_faces[idx, 0], geo.tri_faces[idx, 1], geo.tri_faces[idx, 2]
                v = geo.tri_verts
                t = hit_triangle(v[fa, 0], v[fa, 1], v[fa, 2], v[fb, 0], v[fb, 1], v[fb, 2],
                                 v[fc, 0], v[fc, 1], v[fc, 2], ox, oy, oz, dx, dy, dz, tmin, best_t)
            elif kind == CONE:
                cnt[C.TESTS + CONE] += 1
                t = hit_cone(geo.cone_base[idx, 0], geo.cone_base[idx, 1], geo.cone_base[idx, 2],
                             geo.cone_axis[idx, 0], geo.cone_axis[idx, 1], geo.cone_axis[idx, 2],
                             geo.cone_length[idx], geo.cone_r0[idx], geo.cone_r1[idx],
                             ox, oy, oz, dx, dy, dz, tmin, best_t)
            else:
                # a child aggregate: keep the rest of this range, open a frame for the child
                if i < e:
                    stack_a[sp], stack_b[sp], stack_t[sp] = i, (RC_NEXT if rc_on else e), -INF
                    sp += 1
                if kind == AGGREGATE:
                    child = idx
                    inst = frame_i[f, 2]
                    nox, noy, noz, ndx, ndy, ndz = ox, oy, oz, dx, dy, dz
                else:
                    child = geo.inst_agg[idx]
                    inst = idx
                    m = geo.inst_to_local[idx]
                    nox = m[0] * ox + m[1] * oy + m[2] * oz + m[3]
                    noy = m[4] * ox + m[5] * oy + m[6] * oz + m[7]
                    noz = m[8] * ox + m[9] * oy + m[10] * oz + m[11]
                    ndx = m[0] * dx + m[1] * dy + m[2] * dz
                    ndy = m[4] * dx + m[5] * dy + m[6] * dz
                    ndz = m[8] * dx + m[9] * dy + m[10] * dz
                nix, niy, niz = _inverse(ndx), _inverse(ndy), _inverse(ndz)
                nsp = _push_aggregate(geo, child, nox, noy, noz, nix, niy, niz, tmin, best_t,
                                      stack_a, stack_b, stack_t, sp, cnt)
                if nsp == sp:
                    break       # missed the child's bounds
                g = f + 1
                frame_f[g, 0], frame_f[g, 1], frame_f[g, 2] = nox, noy, noz
                frame_f[g, 3], frame_f[g, 4], frame_f[g, 5] = ndx, ndy, ndz
                if kind == INSTANCE:
                    # compose: child map after the parent's world-to-local map
                    m = geo.inst_to_local[idx]
                    for r in range(3):
                        for c in range(4):
                            acc = m[4 * r + 3] if c == 3 else 0.0
                            for k in range(3):
                                acc += m[4 * r + k] * frame_f[f, 6 + 4 * k + c]
                            frame_f[g, 6 + 4 * r + c] = acc
                else:
                    for k in range(12):
                        frame_f[g, 6 + k] = frame_f[f, 6 + k]
                frame_i[g, 0] = child
                frame_i[g, 1] = sp
                frame_i[g, 2] = inst
                frame_f[g, GF_MBOX_ON] = 0.0
                mbox = False
                f = g
                base = sp
                sp = nsp
                ox, oy, oz, dx, dy, dz = nox, noy, noz, ndx, ndy, ndz
                ix, iy, iz = nix, niy, niz
                break
            if t != INF:
                inst = frame_i[f, 2]
                if any_hit == ALL_HITS:
                    # every hit: hit_i[0] counts them; hit k is t = hit_f[HIT_F + k] and
                    # (kind, index, instance) = hit_i[HIT_I + 3k ..], stored while they fit
                    k = hit_i[0]
                    if HIT_F + k < hit_f.shape[0] and HIT_I + 3 * k + 2 < hit_i.shape[0]:
                        hit_f[HIT_F + k] = t
                        hit_i[HIT_I + 3 * k] = kind
                        hit_i[HIT_I + 3 * k + 1] = idx
                        hit_i[HIT_I + 3 * k + 2] = inst
                    hit_i[0] = k + 1
                    found = True
                    continue
                # t <= best_t here; ties at equal t go to the smaller
                # (ref, instance), so every traversal order reports the same primitive
                if not found or t < best_t or ref < best_ref or (ref == best_ref and inst < best_inst):
                    found = True
                    best_t = t
                    best_ref = ref
                    best_inst = inst
                    hit_f[0] = t
                    for k in range(12):
                        hit_f[1 + k] = frame_f[f, 6 + k]
                    hit_i[0] = kind
                    hit_i[1] = idx
                    hit_i[2] = inst
                    if any_hit:
                        return True
    return found


@njit(parallel=True)
def _cast_chunks(geo, origins, directions, tmin, tmax, any_hit, chunk, t_out, kind_out, index_out, inst_out,
                 counters):
    n = origins.shape[0]
    n_chunks = (n + chunk - 1) // chunk
    for ci in prange(n_chunks):
        c = np.int64(ci)
        ws = workspace()
        hit_f, hit_i = ws[5], ws[6]
        cnt = np.zeros(C.N_COUNTERS, np.int64)
        for r in range(c * chunk, min(n, (c + 1) * chunk)):
            cnt[C.RAYS_CAST] += 1
            if intersect(geo, origins[r, 0], origins[r, 1], origins[r, 2], directions[r, 0], directions[r, 1],
                         directions[r, 2], tmin[r], tmax[r], any_hit,
                         ws, cnt):
                t_out[r] = hit_f[0]
                kind_out[r] = hit_i[0]
                index_out[r] = hit_i[1]
                inst_out[r] = hit_i[2]
            else:
                t_out[r] = np.inf
                kind_out[r] = -1
                index_out[r] = -1
                inst_out[r] = -1
        for k in range(C.N_COUNTERS):
            counters[c, k] = cnt[k]


CHUNK = 1024


def cast_rays(geo, origins, directions, tmin=0.0, tmax=np.inf, any_hit=False):
    """Cast a batch of rays against built geometry (see flatten.flatten).

    Returns (t, kind, index, instance, counter totals); misses have t = inf
    and kind = index = -1. Results do not depend on the thread count.
    """
    origins = np.ascontiguousarray(origins, np.float64).reshape(-1, 3)
    directions = np.ascontiguousarray(directions, np.float64).reshape(-1, 3)
    n = len(origins)
    if directions.shape != origins.shape:
        raise ValueError(f"origins and directions differ in shape: {origins.shape} vs {directions.shape}")
    tmin = np.ascontiguousarray(np.broadcast_to(np.asarray(tmin, np.float64), (n,)))
    tmax = np.ascontiguousarray(np.broadcast_to(np.asarray(tmax, np.float64), (n,)))
    t = np.empty(n)
    kind = np.empty(n, np.int64)
    index = np.empty(n, np.int64)
    inst = np.empty(n, np.int64)
    counters = np.zeros((max(1, (n + CHUNK - 1) // CHUNK), C.N_COUNTERS), np.int64)
    if n:
        _cast_chunks(geo, origins, directions, tmin, tmax, bool(any_hit), CHUNK, t, kind, index, inst, counters)
    return t, kind, index, inst, counters.sum(axis=0)

"""The octree's point walks: point (Lathrop), neighbor (Glassner's pointers) and wall (his wall quadtrees).

    sp, s, e = point_walk(oct_count, ..., oct_walk, kind_step, a, te, oi, ray, best_t, frame_f, f,
                          stack_a, stack_b, stack_t, sp, cnt, work)      # START or NEXT: the next leaf's refs
    px = frame_f[f, POINT]                      # the address of the point it goes on from (and POINT + 1, + 2)

Each finds the leaf holding a point by its 28-bit address, leaves it across
its nearest wall and goes on from the point just past it: from the root
(point), from the neighbour across the wall (neighbor) or down the wall's
quadtree (wall). octree.py's walk_step (octree_step) chooses the walk; its
docstring gives the layout, addresses, collapse, neighbours and walls.
"""

from __future__ import annotations

import numpy as np

from ..geometry import counters as C
from ..geometry.boxes import INF
from ..geometry.config import njit
from .octbuild import ADDRESS_BITS
from .octwalk import CODE, NEXT, PASS, POINT_WALK, WALL_STEPS, WALL_WALK
from .walk import F_STATE, START, entry_tag, note_visit, push

__all__ = ["point_walk", "POINT", "FULL"]

POINT = F_STATE
FULL = 1 << ADDRESS_BITS


@njit(inline="always")
def _address(x, origin, scale, lo, hi):
    """The octree address of coordinate x, clamped to [lo, hi]."""
    u = (x - origin) * scale
    q = np.int64(u) if u >= 0.0 and u < FULL else (np.int64(FULL - 1) if u >= FULL else np.int64(0))
    return min(max(q, lo), hi)


@njit(inline="always")
def _across_wall(oct_nbr, oct_quad, leaf, axis, up, level, px, py, pz):
    """The leaf behind `leaf`'s wall on `axis` (towards +axis if up), where the point p (its
    address, just past the wall) lies: down the wall's quadtree by p's two address bits on the
    wall's axes a level; -1 at the root's boundary. Returns (node, quad levels gone down)."""
    entry = oct_nbr[leaf, 2 * axis + (1 if up else 0)]
    pu = py if axis == 0 else px
    pv = pz if axis != 2 else py
    steps = 0
    while entry <= -2:
        bit = ADDRESS_BITS - 1 - level
        entry = oct_quad[-2 - entry, ((pu >> bit) & 1) + 2 * ((pv >> bit) & 1)]
        level += 1
        steps += 1
    return entry, steps


@njit(private=True)
def point_walk(oct_count, oct_first, oct_level, oct_loc, oct_nbr, oct_origin, oct_pass, oct_quad, oct_root,
               oct_scale, oct_slot, oct_unit, oct_walk, kind_step, a, te, oi, ray, best_t, frame_f, f, stack_a,
               stack_b, stack_t, sp, cnt, work):
    ox, oy, oz, dx, dy, dz, ix, iy, iz = ray
    # point (Lathrop) or neighbor (Glassner): find the leaf holding the point p
    # by its 28-bit address, leave it across its nearest wall, repeat
    walk = oct_walk[oi]
    gox, goy, goz = oct_origin[oi, 0], oct_origin[oi, 1], oct_origin[oi, 2]
    gux, guy, guz = oct_unit[oi, 0], oct_unit[oi, 1], oct_unit[oi, 2]
    gsx, gsy, gsz = oct_scale[oi, 0], oct_scale[oi, 1], oct_scale[oi, 2]
    top = np.int64(FULL - 1)
    if kind_step == START:
        px = _address(ox + te * dx, gox, gsx, 0, top)
        py = _address(oy + te * dy, goy, gsy, 0, top)
        pz = _address(oz + te * dz, goz, gsz, 0, top)
        node = oct_root[oi]
    else:
        px = np.int64(frame_f[f, POINT])
        py = np.int64(frame_f[f, POINT + 1])
        pz = np.int64(frame_f[f, POINT + 2])
        node = a
    while True:
        # descend from node; it stays the container of the cell found
        leaf = np.int64(-1)
        while True:
            cnt[C.CELLS_VISITED] += 1
            note_visit(work, CODE, node)
            sh = ADDRESS_BITS - oct_level[node]
            lx, ly, lz = oct_loc[node, 0], oct_loc[node, 1], oct_loc[node, 2]
            diff = (px ^ lx) | (py ^ ly) | (pz ^ lz)
            if diff >> sh != 0:
                # p lies in an empty octant a collapse removed: the one its highest
                # differing address bit selects
                sh = 0
                while diff >> (sh + 1) != 0:
                    sh += 1
                break
            if oct_count[node] >= 0:
                leaf = node
                break
            bit = sh - 1
            node = oct_first[node] + ((px >> bit) & 1) + 2 * ((py >> bit) & 1) + 4 * ((pz >> bit) & 1)
        side = np.int64(1) << sh
        clx, cly, clz = (px >> sh) << sh, (py >> sh) << sh, (pz >> sh) << sh
        cnt[C.CELLS_LEAVES] += 1
        if leaf >= 0 and oct_count[leaf] > 0:
            s = oct_first[leaf]
            e = s + oct_count[leaf]
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
        if walk == POINT_WALK:
            node = oct_root[oi]
        elif walk == WALL_WALK:
            if not out:
                up = (dx > 0.0) if axis == 0 else ((dy > 0.0) if axis == 1 else (dz > 0.0))
                node, steps = _across_wall(oct_nbr, oct_quad, leaf, axis, up, oct_level[leaf], px, py, pz)
                cnt[WALL_STEPS] += steps
                out = node < 0
        elif not out:
            # still inside the container's slot, or across its wall to the neighbour
            ssh = ADDRESS_BITS - oct_slot[node]
            if pa >> ssh != oct_loc[node, axis] >> ssh:
                up = (dx > 0.0) if axis == 0 else ((dy > 0.0) if axis == 1 else (dz > 0.0))
                node = oct_nbr[node, 2 * axis + (1 if up else 0)]
                out = node < 0
        if s == e:
            if out or texit > best_t:
                return sp, 0, 0
            continue
        if not out:
            # come back for the next leaf after this one's references
            frame_f[f, POINT], frame_f[f, POINT + 1], frame_f[f, POINT + 2] = px, py, pz
            sp = push(stack_a, stack_b, stack_t, sp, node, entry_tag(CODE, NEXT), texit)
        col = oct_pass[leaf]
        if col >= 0 and C.N_COUNTERS + col < cnt.shape[0]:
            # a lazy octree's candidate leaf: see whether the ray leaves it without a hit
            sp = push(stack_a, stack_b, stack_t, sp, col, entry_tag(CODE, PASS), texit)
        return sp, s, e

"""The binary BVH's walk: the kernels rays and queries run through bvh.py's flat node arrays.

    sp, s, e = descend(node_bounds, node_first, node_count, node, ox, oy, oz, ix, iy, iz, tmin, best_t,
                       stack_a, stack_b, stack_t, sp, cnt, work)   # the nearest leaf entered: refs s..e-1
    walk_step(geo, step, a, te, ray, lo, best_t, f, sp, ws, cnt)  # bvh.WALK's step (walk.py's contract)

CODE is the walk's code: an aggregate's agg_kind in the flat arrays (bvh.append_bvh stores it)
and the walk every stack entry of a BVH is tagged with (entry_tag(CODE, START): a node to
descend from, entered at stack_t). bvh.py declares the walk (WALK) with it; the mesh kernel
(casting/meshcast.py) calls descend itself, and the 4-wide walk (widebvh.py) takes this one's place
in a scene that is one BVH of width 4 over primitives (aggregates/widewalk.py, bvh.walked_wide).
"""

from __future__ import annotations

from ..geometry import counters as C
from ..geometry.boxes import INF, box_entry
from ..geometry.config import njit
from .walk import START, answer, entry_tag, note_visit, push

CODE = 1


@njit(private=True)
def descend(node_bounds, node_first, node_count, node, ox, oy, oz, ix, iy, iz, tmin, best_t, stack_a, stack_b,
            stack_t, sp, cnt, work):
    """The binary walk: descend from `node` to the nearest leaf the ray enters, pushing the
    farther child of every inner node passed (a START entry); returns (sp, s, e): the leaf's
    references (none: s == e). work: a render's per-sample work, or None (walk.note_visit)."""
    while True:
        cnt[C.CELLS_VISITED] += 1
        note_visit(work, CODE, node)
        n_items = node_count[node]
        if n_items > 0:
            cnt[C.CELLS_LEAVES] += 1
            s = node_first[node]
            return sp, s, s + n_items
        # inner node: test both children, go on with the nearer
        left = node_first[node]
        right = left + 1
        cnt[C.BOUNDS_TESTS] += 2
        tl = box_entry(node_bounds, left, ox, oy, oz, ix, iy, iz, tmin, best_t)
        tr = box_entry(node_bounds, right, ox, oy, oz, ix, iy, iz, tmin, best_t)
        if tl <= tr:
            if tl == INF:
                return sp, 0, 0
            if tr != INF:
                sp = push(stack_a, stack_b, stack_t, sp, right, entry_tag(CODE, START), tr)
            node = left
        else:
            if tl != INF:
                sp = push(stack_a, stack_b, stack_t, sp, left, entry_tag(CODE, START), tl)
            node = right


@njit(inline="always")
def walk_step(geo, step, a, te, ray, lo, best_t, f, sp, ws, cnt):
    """Every entry is a node to descend from (walk.py's step contract)."""
    ox, oy, oz, _, _, _, ix, iy, iz = ray
    sp, s, e = descend(geo.node_bounds, geo.node_first, geo.node_count, a, ox, oy, oz, ix, iy, iz, lo, best_t,
                       ws.stack_a, ws.stack_b, ws.stack_t, sp, cnt, ws.work)
    return answer(sp, s, e, ray, best_t)

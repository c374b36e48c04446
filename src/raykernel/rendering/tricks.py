"""Haines's efficiency tricks ("Ray Tracing News" 2(1)), each switched on or off and counted.

    render(scene, tricks="all")                     # or "none", or "closest,shadowcache,..."
    raykernel render SCENE --tricks raytree,shadowcache

Every trick changes only the work, never the image or the ray counts (trick 4 changes nothing
unless shadows are filtered); what it saved shows in the counters:

1. closest: the search interval shrinks to the closest hit so far. Off, the search visits every
   candidate over the full interval (an all-hits walk, counted; the hit itself then comes from an
   uncounted closest search): compare tests.per_ray on and off. tricks.full_walks counts them.
2. raytree: each tile remembers the object hit at each node of the previous pixel's ray tree
   (nodes numbered 1 for the eye ray, 2n for the reflection and 2n + 1 for the refraction of
   node n, up to MEMO_NODES) and tests it first at the same node: its distance bounds the search
   (raytree.tries, raytree.hits: searches it bounded; the search still finds the true closest).
3. shadowcache: per light and node, the last opaque blocker is tested first; when it blocks,
   no search (shadow_cache.tries, shadow_cache.hits).
4. transparentlast: with filtered shadows, one any-hit query over opaque surfaces first; the
   front-to-back walk through transparent ones only when none blocks (shadow.steps: closest
   queries of those walks).
5. lazynormals: normals only for the final closest hit; off, at every closer hit as the search
   finds it (normals.computed).
6. startlists: a ray that leaves an object tests the object's start list first: its neighbours
   in its BVH (startlists.py); the nearest hit bounds the search, an opaque one settles a shadow
   ray (start_lists.used, start_lists.hits, start_lists.built).

A cached object is tested through the map of the frame it was hit in, and only ever bounds a
search or settles a shadow ray where rounding cannot matter: a hint that misses, or a blocker
within 1e-9 of either end of the shadow ray, falls back to the full query. Surfaces of CSG
results are never cached (their primitive alone is not the solid).
"""

from __future__ import annotations

import numpy as np

from ..geometry.hitrule import hit_primitive
from ..engine.traverse import ALL_HITS, ANY_OPAQUE, CLOSEST, CLOSEST_EAGER, OPERATOR_SURFACE, clear_material, intersect
from ..geometry.work import pause_use
from ..errors import OptionError
from ..geometry import counters as C
from ..geometry.boxes import INF
from ..geometry.config import njit
from ..geometry.primitives import INDEX_MASK, KIND_SHIFT
from . import startlists

CLOSEST_CUT, RAYTREE, SHADOWCACHE, TRANSPARENTLAST, LAZYNORMALS, STARTLISTS = 1, 2, 4, 8, 16, 32
NAMES = {"closest": CLOSEST_CUT, "raytree": RAYTREE, "shadowcache": SHADOWCACHE,
         "transparentlast": TRANSPARENTLAST, "lazynormals": LAZYNORMALS, "startlists": STARTLISTS}
ALL = sum(NAMES.values())
DEFAULT = CLOSEST_CUT | LAZYNORMALS
# the tricks a render without any per-tile state does (closest's cut-off, lazy normals): render.py's
# own kernel then runs with state None, and the first render compiles no other trick's code
LEAN = CLOSEST_CUT | LAZYNORMALS
MEMO_NODES = 64          # ray-tree nodes remembered: every node of a tree of depth 6
MEMO_COLUMNS = 15        # kind, index (-1: nothing), then the frame's world-to-local 3x4 map
MARGIN = 1e-9            # relative: hints and cached blockers keep this far from the ends of an interval
ORIGIN = 13              # the columns of a ray stack row (whitted.py) that hold the object the ray leaves


def parse(spec) -> int:
    """The trick bits of "all", "none" or a comma-separated list of NAMES (or an int of bits)."""
    if isinstance(spec, (int, np.integer)) and not isinstance(spec, bool):
        if not 0 <= spec <= ALL:
            raise OptionError(f"tricks must be between 0 and {ALL} as bits, got {spec}")
        return int(spec)
    if not isinstance(spec, str):
        raise OptionError(f"tricks must be a comma-separated list of names, got {spec!r}")
    text = spec.strip().lower()
    if text == "all":
        return ALL
    if text in ("none", ""):
        return 0
    bits = 0
    for name in (part.strip() for part in text.split(",")):
        if name not in NAMES:
            raise OptionError(f"unknown trick {name!r}; tricks: {', '.join(NAMES)}, all, none")
        bits |= NAMES[name]
    return bits


def names(bits: int) -> list[str]:
    return [name for name, bit in NAMES.items() if bits & bit]


@njit
def memo(n_lights, starts):
    """Per-tile state: the ray-tree memory (MEMO_NODES rows), the shadow cache (MEMO_NODES x
    n_lights rows), scratch counters for the uncounted searches of trick 1 off, the start-list
    table, the object the current hit is on (a row laid out as the others), a use counter and
    a walk stack for the start lists, and startlists.prepare()'s arrays."""
    rays = np.full((MEMO_NODES, MEMO_COLUMNS), -1.0)
    shadows = np.full((MEMO_NODES * max(1, n_lights), MEMO_COLUMNS), -1.0)
    origin = np.full((1, MEMO_COLUMNS), -1.0)
    return (rays, shadows, np.zeros(C.N_COUNTERS, np.int64), startlists.table(), origin,
            np.zeros(1, np.int64), np.zeros(startlists.WALK_STACK, np.int64), starts)


@njit(inline="always")
def shadow_slot(node, n_lights, light):
    """The shadow cache's row for a light at ray-tree node `node`; -1 past MEMO_NODES."""
    return node * n_lights + light if node < MEMO_NODES else np.int64(-1)


@njit(inline="always")
def _remember(table, row, hit_f, hit_i):
    if hit_i[3] & OPERATOR_SURFACE:
        table[row, 0] = -1.0
        return
    table[row, 0], table[row, 1] = hit_i[0], hit_i[1]
    for k in range(12):
        table[row, 3 + k] = hit_f[1 + k]


@njit(inline="always")
def hold_origin(state, ws):
    """Trick 6: the hit intersect just found is the object the next rays leave (its start list)."""
    if state is None:
        return
    _remember(state[4], 0, ws.hit_f, ws.hit_i)


@njit(inline="always")
def pass_origin(state, rays, row):
    """Trick 6: a ray pushed at rays[row] leaves the held object: its columns ORIGIN.. ORIGIN + 15."""
    if state is None:
        return
    for k in range(MEMO_COLUMNS):
        rays[row, ORIGIN + k] = state[4][0, k]


@njit(private=True)
def test_ref(geo, kind, idx, table, row, col, ox, oy, oz, dx, dy, dz, tmin, tmax, cnt):
    """t of primitive (kind, idx) for the world ray, mapped through the 3x4 map at
    table[row, col + 3:col + 15], in [tmin, tmax]; INF for a miss."""
    m = table[row, col + 3:col + 15]
    lx = m[0] * ox + m[1] * oy + m[2] * oz + m[3]
    ly = m[4] * ox + m[5] * oy + m[6] * oz + m[7]
    lz = m[8] * ox + m[9] * oy + m[10] * oz + m[11]
    ex = m[0] * dx + m[1] * dy + m[2] * dz
    ey = m[4] * dx + m[5] * dy + m[6] * dz
    ez = m[8] * dx + m[9] * dy + m[10] * dz
    cnt[C.TESTS + kind] += 1
    t = hit_primitive(geo, kind, idx, lx, ly, lz, ex, ey, ez, tmin, tmax, cnt)
    if t != INF:
        cnt[C.HITS + kind] += 1
    return t


@njit(inline="always")
def test_one(geo, table, row, col, ox, oy, oz, dx, dy, dz, tmin, tmax, cnt):
    """t of the object remembered in table[row, col:col + 15] (kind, index, _, map) for the world ray."""
    return test_ref(geo, np.int64(table[row, col]), np.int64(table[row, col + 1]), table, np.int64(row),
                    np.int64(col), ox, oy, oz, dx, dy, dz, tmin, tmax, cnt)


@njit(inline="always")
def _list_row(geo, table, row, col, state, cnt):
    """Trick 6: the start-list row of the object in table[row, col:], -1 when it has none."""
    if table[row, col] < 0.0:
        return np.int64(-1)
    state[5][0] += 1
    ref = (np.int64(table[row, col]) << KIND_SHIFT) | np.int64(table[row, col + 1])
    return startlists.start_list(ref, state[7], geo, state[3], state[5][0], state[6], cnt)


@njit(private=True)
def list_hint(geo, table, row, col, ox, oy, oz, dx, dy, dz, tmin, tmax, opaque_only, state, cnt):
    """Trick 6: the nearest t in [tmin, tmax] of the start list of the object in table[row, col:]
    (opaque primitives only if asked), INF when none is hit or there is no list. Its callers pass
    row, col and opaque_only as int64: a constant (a literal) would have numba compile it again."""
    lists = state[3]
    at = _list_row(geo, table, row, col, state, cnt)
    if at < 0:
        return INF
    cnt[C.START_LISTS] += 1
    best = INF
    for k in range(lists[at, 2]):
        ref = lists[at, 3 + k]
        kind, idx = ref >> KIND_SHIFT, ref & INDEX_MASK
        if opaque_only and clear_material(geo, kind, idx):
            continue
        t = test_ref(geo, kind, idx, table, row, col, ox, oy, oz, dx, dy, dz, tmin, min(tmax, best), cnt)
        if t < best:
            best = t
    return best


@njit(inline="always")    # inlined: each kernel compiled apart that calls intersect pays for linking it again
def closest(geo, ox, oy, oz, dx, dy, dz, tmin, tmax, node, tricks, state, rays, top, ws, cnt):
    """traverse.intersect's closest hit (hit record in ws) of the ray rays[top] (a ray stack row,
    its origin object at ORIGIN) at ray-tree node `node`, with `tricks`; state: memo()'s, or None
    for LEAN (numba then compiles none of the tricks' code)."""
    if state is None:
        return intersect(geo, ox, oy, oz, dx, dy, dz, tmin, tmax, CLOSEST, ws, cnt)
    memory, scratch = state[0], state[2]
    mode = CLOSEST if tricks & LAZYNORMALS else CLOSEST_EAGER
    if not tricks & CLOSEST_CUT:
        # the work of a search without the cut-off, then the hit from one that has it, uncounted
        cnt[C.FULL_WALKS] += 1
        intersect(geo, ox, oy, oz, dx, dy, dz, tmin, tmax, ALL_HITS, ws, cnt)
        before = scratch[C.NORMALS_COMPUTED]
        pause_use(ws.work, True)
        found = intersect(geo, ox, oy, oz, dx, dy, dz, tmin, tmax, mode, ws, scratch)
        pause_use(ws.work, False)
        cnt[C.NORMALS_COMPUTED] += scratch[C.NORMALS_COMPUTED] - before
        return found
    memorable = tricks & RAYTREE and node < MEMO_NODES
    hint, from_tree = INF, False
    if memorable and memory[node, 0] >= 0.0:
        cnt[C.RAYTREE_TRIES] += 1
        hint = test_one(geo, memory, node, 0, ox, oy, oz, dx, dy, dz, tmin, tmax, cnt)
        from_tree = hint < INF
    if tricks & STARTLISTS:
        t = list_hint(geo, rays, np.int64(top), np.int64(ORIGIN), ox, oy, oz, dx, dy, dz, tmin, min(tmax, hint),
                      np.int64(False), state, cnt)
        if t < hint:
            hint, from_tree = t, False
    if hint < INF and intersect(geo, ox, oy, oz, dx, dy, dz, tmin, min(tmax, hint + MARGIN * abs(hint)), mode, ws,
                                cnt):
        cnt[C.RAYTREE_HITS if from_tree else C.START_LISTS_HITS] += 1
        if memorable:
            _remember(memory, node, ws.hit_f, ws.hit_i)
        return True
    found = intersect(geo, ox, oy, oz, dx, dy, dz, tmin, tmax, mode, ws, cnt)
    if memorable:
        if found:
            _remember(memory, node, ws.hit_f, ws.hit_i)
        else:
            memory[node, 0] = -1.0
    return found


@njit(inline="always")
def cached_block(geo, ox, oy, oz, tx, ty, tz, reach, slot, opaque_only, tricks, state, cnt):
    """Tricks 3 and 6: True when the last opaque blocker of this light and ray-tree slot (-1: none),
    or a primitive of the start list of the object the ray leaves (opaque ones only if asked), lies
    on the shadow ray well inside [0, reach]."""
    if state is None:
        return False
    shadows = state[1]
    if tricks & SHADOWCACHE and slot >= 0 and shadows[slot, 0] >= 0.0:
        cnt[C.SHADOW_CACHE_TRIES] += 1
        t = test_one(geo, shadows, slot, 0, ox, oy, oz, tx, ty, tz, 0.0, reach, cnt)
        if MARGIN * reach < t < reach * (1.0 - MARGIN):
            cnt[C.SHADOW_CACHE_HITS] += 1
            return True
    if tricks & STARTLISTS:
        t = list_hint(geo, state[4], np.int64(0), np.int64(0), ox, oy, oz, tx, ty, tz, MARGIN * reach,
                      reach * (1.0 - MARGIN), np.int64(opaque_only), state, cnt)
        if MARGIN * reach < t < reach * (1.0 - MARGIN):
            cnt[C.START_LISTS_HITS] += 1
            return True
    return False


@njit(inline="always")
def remember_blocker(slot, tricks, state, ws):
    """Trick 3: the blocker intersect just found (ws's hit record) becomes the slot's."""
    if state is None:
        return
    if tricks & SHADOWCACHE and slot >= 0:
        _remember(state[1], slot, ws.hit_f, ws.hit_i)


@njit(inline="always")
def blocked(geo, ox, oy, oz, tx, ty, tz, reach, mode, slot, tricks, state, ws, cnt):
    """intersect(mode: ANY_HIT or ANY_OPAQUE) of a shadow ray over [0, reach], the cached blocker
    of its light and ray-tree slot and the start list of the object it leaves tested first."""
    if cached_block(geo, ox, oy, oz, tx, ty, tz, reach, slot, mode == ANY_OPAQUE, tricks, state, cnt):
        return True
    if intersect(geo, ox, oy, oz, tx, ty, tz, 0.0, reach, mode, ws, cnt):
        remember_blocker(slot, tricks, state, ws)
        return True
    return False

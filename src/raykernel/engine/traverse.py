"""The intersection driver: one routine for every aggregate, nested to any depth.

    ws = workspace()                    # per thread: stacks, frames, hit record (walk.Workspace)
    found = intersect(geo, ox, oy, oz, dx, dy, dz, 0.0, np.inf, CLOSEST, ws, cnt)
    t = ws.hit_f[0]; kind, index, instance = ws.hit_i[:3]

The driver owns the stack, the frames, the reference loop, instances and
the hit rule; each aggregate kind owns its walk, a step function in its
module under aggregates/, which the driver calls in one line through the
registry (aggregates/registry.py: walk_step; aggregates/walk.py is the
contract). An explicit stack replaces recursion: a range of references, or a
step of a kind's walk (aggregates/walk.py says how entries are tagged). When a reference names an aggregate or an instance, the rest of
the current range is pushed, a frame is opened for the child (the ray mapped
into its space for an instance) and the child's START entry pushed above. A
frame ends when the stack falls to its base. Instance maps are affine and
the direction is not renormalised, so t means the same in every frame and
one closest t shrinks through all. A scene that is one 4-wide BVH over
primitives skips all of that: `intersect` hands it to the walk of a whole
scene that a kind declares (registry.SCENE_WALK: the BVH's, aggregates/widewalk.py),
and kernels given its geometry compile no general driver at all (its type says so).
"""

import numpy as np
from numba.extending import overload

from ..aggregates import collect
from ..aggregates.registry import CROSSINGS, SCENE_WALK, walk_resolve, walk_step
from ..aggregates.walk import (
    DRIVER,
    F_DIR,
    F_KEY_D,
    F_KEY_END,
    F_KEY_O,
    F_MAP,
    F_MBOX,
    F_MBOX_ON,
    F_ORIGIN,
    FI_AGG,
    FI_BASE,
    FI_INST,
    FI_OPERAND,
    FI_SINK,
    FRAME_F,
    FRAME_I,
    KEY_SLACK,
    KEYED_STEP,
    MAX_NESTING,
    MBOX_SLOTS,
    STACK_SIZE,
    START,
    Workspace,
    entry_kind,
    entry_step,
    entry_tag,
    push,
)
from ..geometry import counters as C
from ..geometry.boxes import CONSERVATIVE, INF, box_entry, inverse
from ..geometry.config import njit
from ..geometry.primitives import (
    AGGREGATE,
    INDEX_MASK,
    INSTANCE,
    KIND_SHIFT,
    SPHERE,
    sphere_roots,
)
from ..geometry.hitrule import (  # noqa: F401  (the modes and the hit record's layout, for intersect's callers)
    ALL_HITS,
    ANY_HIT,
    ANY_OPAQUE,
    CLOSEST,
    CLOSEST_EAGER,
    FLIP,
    HIT_F,
    HIT_I,
    OPERATOR_SURFACE,
    clear_material,
    eager_normal,
    hit_primitive,
    take,
)
from ..geometry.parallel import for_ranges
from .transforms import compose_map, map_ray
from ..geometry.work import ENTER, STEP, TEST, level_charge, level_mark, note, note_found, note_search

# stack entry: go on with the frame's keyed list at stack_a (py_func: calling the kernel would load it at import)
KEYED = entry_tag.py_func(DRIVER, KEYED_STEP)
DONE = np.int64(-2)          # _finish's sink when an ANY_HIT query is answered
scene_walks, scene_intersect = SCENE_WALK.walks, SCENE_WALK.intersect


@njit
def workspace(hits=0, work=None):
    """Scratch arrays for one thread, allocated once per tile or chunk (walk.Workspace); `hits`:
    room in the hit record for as many hits of an ALL_HITS query (hitrule.take); `work`: a
    render's per-sample work (geometry/work.py), None without work layers."""
    buf_t, buf_i, buf_m, buf_n = collect.buffers()
    return Workspace(np.zeros(STACK_SIZE, np.int64), np.zeros(STACK_SIZE, np.int64), np.zeros(STACK_SIZE),
                     np.zeros(STACK_SIZE), np.zeros((MAX_NESTING + 1, FRAME_F)),
                     np.zeros((MAX_NESTING + 1, FRAME_I), np.int64), np.zeros(HIT_F + max(3, hits)),
                     np.zeros(HIT_I + 3 * hits, np.int64), buf_t, buf_i, buf_m, buf_n, np.empty(4), work)


@njit(inline="always")
def _enter(agg_bounds, agg_kind, agg_start, a, ox, oy, oz, ix, iy, iz, tmin, tmax, stack_a, stack_b, stack_t, sp,
           cnt):
    """Test aggregate a's bounds and push its walk's START entry; returns the new stack pointer."""
    kind = agg_kind[a]
    cnt[C.BOUNDS_TESTS] += 1
    cnt[C.WALK_BOUNDS + kind] += 1
    te = box_entry(agg_bounds, a, ox, oy, oz, ix, iy, iz, tmin, tmax)
    if te == INF:
        return sp
    cnt[C.WALK_ENTRIES + kind] += 1
    return push(stack_a, stack_b, stack_t, sp, agg_start[a], entry_tag(kind, START), te)


@njit(private=True)
def _finish(geo, f, ws, tmin, mode, found, best_ref, best_inst, cnt):
    """End sink frame f: its operator's surfaces (its walk's resolve, collect.py) go to the
    enclosing sink, or, from the outermost, to the hit rule. Returns (found, best_t, best_ref,
    best_inst, enclosing sink), the sink DONE when an ANY_HIT query has its hit."""
    frame_f, frame_i, buf_t, buf_i, buf_n = ws.frame_f, ws.frame_i, ws.buf_t, ws.buf_i, ws.buf_n
    region = np.int64(frame_f[f, collect.SLOT_REGION])
    agg = frame_i[f, FI_AGG]
    n = walk_resolve(geo.agg_kind[agg], geo, geo.agg_start[agg], region, frame_f[f, collect.SLOT_SHIFT],
                     np.int64(frame_f[f, collect.SLOT_OPERAND]), ws, cnt)
    best_t = frame_f[f, collect.SLOT_BEST]
    sink = np.int64(frame_f[f, collect.SLOT_SINK])
    frame_i[f, FI_SINK] = sink      # done: the frame may be reused
    if sink >= 0:
        buf_n[0] = region + n       # crossings of the enclosing sink's operand
        return found, best_t, best_ref, best_inst, sink
    buf_n[0] = region
    for k in range(region, region + n):
        t = buf_t[k]
        if tmin <= t <= best_t and not (mode == ANY_OPAQUE and clear_material(geo, buf_i[k, 1], buf_i[k, 2])):
            found, best_t, best_ref, best_inst = take(mode, t, buf_i[k, 1], buf_i[k, 2], buf_i[k, 3],
                                                      buf_i[k, 4] | OPERATOR_SURFACE, ws.buf_m, k, np.int64(0),
                                                      ws.hit_f, ws.hit_i, found, best_t, best_ref, best_inst)
            if found and (mode == ANY_HIT or mode == ANY_OPAQUE):
                return found, best_t, best_ref, best_inst, DONE
    return found, best_t, best_ref, best_inst, sink


@njit(private=True)
def _record_sphere(geo, idx, ox, oy, oz, dx, dy, dz, best_t, operand, inst, frame_f, f, buf_t, buf_i, buf_m, buf_n,
                   cnt, counter):
    """Below a sink a sphere records both of the line's crossings (up to best_t)."""
    t0, t1 = sphere_roots(geo.sph_center[idx, 0], geo.sph_center[idx, 1], geo.sph_center[idx, 2],
                          geo.sph_radius[idx], ox, oy, oz, dx, dy, dz)
    if t0 <= best_t and t0 != INF:
        cnt[C.HITS + SPHERE] += 1
        collect.record(buf_t, buf_i, buf_m, buf_n, t0, operand, np.int64(SPHERE), idx, inst, np.int64(0), frame_f, f,
                       cnt, counter)
    if t1 <= best_t and t1 != INF:
        collect.record(buf_t, buf_i, buf_m, buf_n, t1, operand, np.int64(SPHERE), idx, inst, np.int64(1), frame_f, f,
                       cnt, counter)


@njit(inline="always")
def intersect(geo, ox, oy, oz, dx, dy, dz, tmin, tmax, mode, ws, cnt):
    """Closest hit (mode CLOSEST) or the first hit found (ANY_HIT) of the ray with the
    scene in [tmin, tmax]. On a hit returns True and fills hit_f (t, world-to-local map
    of the hit's frame) and hit_i (kind, index, innermost instance, flip). Counts tests,
    bounds tests and steps into cnt. ALL_HITS records every hit instead (see take).
    A scene that is one BVH over primitives goes to its kind's walk of a whole scene
    (registry.SCENE_WALK), which takes only the arrays it reads; every other to the general one, `walk`."""
    note_search(ws.work, mode, ox, oy, oz, dx, dy, dz, tmin, tmax, cnt)     # nothing unless one sample is probed
    if scene_walks(geo) and mode != CLOSEST_EAGER:
        found = scene_intersect(geo, ox, oy, oz, dx, dy, dz, tmin, tmax, mode, ws, cnt)
    else:
        found = _driver(geo, ox, oy, oz, dx, dy, dz, tmin, tmax, mode, ws, cnt)
    note_found(ws.work, found, ws.hit_f, ws.hit_i, cnt)
    return found


def _driver(geo, ox, oy, oz, dx, dy, dz, tmin, tmax, mode, ws, cnt):
    """`walk`, in kernels whose geometry may need it: chosen by geo's type as numba compiles."""


@overload(_driver, inline="always")
def _driver_for_type(geo, ox, oy, oz, dx, dy, dz, tmin, tmax, mode, ws, cnt):
    if SCENE_WALK.alone(geo):
        # intersect gets here only for eager normals, and RenderJob gives renders with tricks a
        # geometry typed with the driver (SCENE_WALK.with_driver)
        def no_driver(geo, ox, oy, oz, dx, dy, dz, tmin, tmax, mode, ws, cnt):
            raise ValueError("CLOSEST_EAGER on a geometry typed for its scene walk alone: pass with_driver(geo)")
        return no_driver

    def driver(geo, ox, oy, oz, dx, dy, dz, tmin, tmax, mode, ws, cnt):
        return walk(geo, ox, oy, oz, dx, dy, dz, tmin, tmax, mode, ws, cnt)
    return driver


@njit(inline="always")
def _root_frame(root, ox, oy, oz, dx, dy, dz, frame_f, frame_i, buf_n):
    """Frame 0: the root aggregate in world space, identity map, no mailbox, no crossings yet."""
    frame_f[0, F_ORIGIN], frame_f[0, F_ORIGIN + 1], frame_f[0, F_ORIGIN + 2] = ox, oy, oz
    frame_f[0, F_DIR], frame_f[0, F_DIR + 1], frame_f[0, F_DIR + 2] = dx, dy, dz
    for k in range(12):
        frame_f[0, F_MAP + k] = 1.0 if k == 0 or k == 5 or k == 10 else 0.0
    frame_i[0, FI_AGG], frame_i[0, FI_BASE], frame_i[0, FI_INST] = root, 0, -1
    frame_i[0, FI_SINK], frame_i[0, FI_OPERAND] = -1, 0
    frame_f[0, F_MBOX_ON] = 0.0
    buf_n[0] = 0


@njit(private=True)
def walk(geo, ox, oy, oz, dx, dy, dz, tmin, tmax, mode, ws, cnt):
    """intersect through the general driver: any nesting of any kinds, instances, operators.
    Below an operator the frames collect crossings instead (aggregates/collect.py): `sink` is
    the frame that gathers them, -1 above every operator, and `lo` the lower end of the
    tested interval, -inf there, since a solid's inside depends on crossings behind tmin."""
    stack_a, stack_b, stack_t, frame_f, frame_i = ws.stack_a, ws.stack_b, ws.stack_t, ws.frame_f, ws.frame_i
    best_t = tmax
    found = np.bool_(False)     # typed, not literal: numba compiles a private callee once per literal
    best_ref = np.int64(-1)
    best_inst = np.int64(-1)
    ix, iy, iz = inverse(dx), inverse(dy), inverse(dz)
    f = np.int64(0)     # not the literal 0: that too would be compiled apart
    _root_frame(geo.root, ox, oy, oz, dx, dy, dz, frame_f, frame_i, ws.buf_n)
    sink = np.int64(-1)
    lo = tmin
    base = 0
    sp = _enter(geo.agg_bounds, geo.agg_kind, geo.agg_start, geo.root, ox, oy, oz, ix, iy, iz, tmin, best_t, stack_a,
                stack_b, stack_t, base, cnt)
    note(ws.work, ENTER, 0, geo.root, -1, 1 if sp > base else 0, 0, 0, 0, 0, 0)
    level_mark(ws.work, cnt)        # work layers by nesting level (geometry/work.py); nothing without them
    while True:
        if sp == base:
            if frame_i[f, FI_SINK] == f:
                # an operator's crossings are all in: its own surfaces, on the enclosing ray
                found, best_t, best_ref, best_inst, sink = _finish(geo, f, ws, tmin, mode, found, best_ref,
                                                                   best_inst, cnt)
                if sink == DONE:
                    level_charge(ws.work, f, cnt)
                    return True
            if f == 0:
                break
            # this frame is done: back to the parent's ray
            level_charge(ws.work, f, cnt)
            f -= 1
            base = frame_i[f, FI_BASE]
            ox, oy, oz = frame_f[f, F_ORIGIN], frame_f[f, F_ORIGIN + 1], frame_f[f, F_ORIGIN + 2]
            dx, dy, dz = frame_f[f, F_DIR], frame_f[f, F_DIR + 1], frame_f[f, F_DIR + 2]
            ix, iy, iz = inverse(dx), inverse(dy), inverse(dz)
            sink = frame_i[f, FI_SINK]
            lo = tmin if sink < 0 else -INF
            continue
        sp -= 1
        a, b, te = stack_a[sp], stack_b[sp], stack_t[sp]
        if te > best_t and te > best_t * CONSERVATIVE:
            continue        # entered beyond the closest hit (BVH nodes within rounding of it are kept: ties)
        keyed = False
        key_o = key_d = 0.0
        if b >= 0:
            s, e = a, b
        elif b == KEYED:
            s, e = a, np.int64(frame_f[f, F_KEY_END])
            key_o, key_d, keyed = frame_f[f, F_KEY_O], frame_f[f, F_KEY_D], True
        else:
            # a step of the frame's walk (aggregates/walk.py), its share of the work charged to it
            kind = entry_kind(b)
            visited, tested = cnt[C.CELLS_VISITED], cnt[C.BOUNDS_TESTS]
            sp, s, e, keyed, key_o, key_d, ray, best_t, opened = walk_step(
                kind, geo, entry_step(b), a, te, (ox, oy, oz, dx, dy, dz, ix, iy, iz), lo, best_t, f, sp, ws, cnt)
            ox, oy, oz = ray[0], ray[1], ray[2]
            if opened:
                sink, lo = f, -INF      # an operator's START: this frame collects crossings from now on
            cnt[C.WALK_STEPS + kind] += cnt[C.CELLS_VISITED] - visited
            cnt[C.WALK_BOUNDS + kind] += cnt[C.BOUNDS_TESTS] - tested
            note(ws.work, STEP, f, frame_i[f, FI_AGG], kind, cnt[C.CELLS_VISITED] - visited,
                 cnt[C.BOUNDS_TESTS] - tested, s, e, 1 if keyed else 0, 0)
        mbox = frame_f[f, F_MBOX_ON] != 0.0
        # the reference loop
        i = s
        while i < e:
            if keyed:
                if geo.keyed_key[i] > key_o + best_t * key_d * KEY_SLACK + 1e-9 * abs(key_o):
                    break       # this and every later candidate lies beyond the closest hit
                ref = geo.keyed_ref[i]
            else:
                ref = geo.refs[i]
            kind = ref >> KIND_SHIFT
            idx = ref & INDEX_MASK
            i += 1
            if mbox:
                slot = F_MBOX + ((idx + 37 * kind) & (MBOX_SLOTS - 1))
                tag = np.float64(ref)
                if frame_f[f, slot] == tag:
                    cnt[C.MAILBOX_SAVED] += 1
                    continue
                frame_f[f, slot] = tag
            if mode == ANY_OPAQUE and sink < 0 and kind < AGGREGATE and clear_material(geo, kind, idx):
                continue        # transparent: left to the walk that filters light through it
            if kind >= AGGREGATE:
                # a child aggregate: keep the rest of this range, open a frame for the child
                if i < e:
                    sp = push(stack_a, stack_b, stack_t, sp, i, KEYED if keyed else e, -INF)
                g = f + 1
                if kind == AGGREGATE:
                    child = idx
                    inst = frame_i[f, FI_INST]
                    nox, noy, noz, ndx, ndy, ndz = ox, oy, oz, dx, dy, dz
                else:
                    child = geo.inst_agg[idx]
                    inst = idx
                    nox, noy, noz, ndx, ndy, ndz = map_ray(geo.inst_to_local, geo.inst_class, idx, ox, oy, oz, dx, dy,
                                                           dz, cnt)
                nix, niy, niz = inverse(ndx), inverse(ndy), inverse(ndz)
                nsp = _enter(geo.agg_bounds, geo.agg_kind, geo.agg_start, child, nox, noy, noz, nix, niy, niz, lo,
                             best_t, stack_a, stack_b, stack_t, sp, cnt)
                note(ws.work, ENTER, g, child, inst, 1 if nsp > sp else 0, 0, 0, 0, 0, 0)
                if nsp == sp:
                    break       # missed the child's bounds
                frame_f[g, F_ORIGIN], frame_f[g, F_ORIGIN + 1], frame_f[g, F_ORIGIN + 2] = nox, noy, noz
                frame_f[g, F_DIR], frame_f[g, F_DIR + 1], frame_f[g, F_DIR + 2] = ndx, ndy, ndz
                compose_map(geo.inst_to_local, geo.inst_class, kind == INSTANCE, idx, frame_f, f, g, cnt)
                frame_i[g, FI_AGG], frame_i[g, FI_BASE], frame_i[g, FI_INST] = child, sp, inst
                # below an operator the child's crossings go to the same sink, as the same operand
                frame_i[g, FI_SINK] = sink
                frame_i[g, FI_OPERAND] = collect.operand(frame_f, frame_i, f, sink, i - 1)
                frame_f[g, F_MBOX_ON] = 0.0
                level_charge(ws.work, f, cnt)
                f = g
                base = sp
                sp = nsp
                ox, oy, oz, dx, dy, dz = nox, noy, noz, ndx, ndy, ndz
                ix, iy, iz = nix, niy, niz
                break
            cnt[C.TESTS + kind] += 1
            if kind == SPHERE and sink >= 0:
                # below a sink a sphere records both of the line's crossings (logged with t = -inf)
                note(ws.work, TEST, f, frame_i[f, FI_AGG], kind, idx, -INF, frame_i[f, FI_INST], 0, 0, 0)
                _record_sphere(geo, idx, ox, oy, oz, dx, dy, dz, best_t,
                               collect.operand(frame_f, frame_i, f, sink, i - 1), frame_i[f, FI_INST], frame_f, f,
                               ws.buf_t, ws.buf_i, ws.buf_m, ws.buf_n, cnt, np.int64(CROSSINGS))
                continue
            t = hit_primitive(geo, kind, idx, ox, oy, oz, dx, dy, dz, lo, best_t, cnt)
            note(ws.work, TEST, f, frame_i[f, FI_AGG], kind, idx, t, frame_i[f, FI_INST], 0, 0, 0)
            if t != INF:
                cnt[C.HITS + kind] += 1
                if sink >= 0:
                    collect.record(ws.buf_t, ws.buf_i, ws.buf_m, ws.buf_n, t,
                                   collect.operand(frame_f, frame_i, f, sink, i - 1), kind, idx, frame_i[f, FI_INST],
                                   np.int64(0), frame_f, f, cnt, np.int64(CROSSINGS))
                    continue
                found, best_t, best_ref, best_inst = take(mode, t, kind, idx, frame_i[f, FI_INST], np.int64(0),
                                                          frame_f, f, np.int64(F_MAP), ws.hit_f, ws.hit_i, found,
                                                          best_t, best_ref, best_inst)
                if found and (mode == ANY_HIT or mode == ANY_OPAQUE):
                    level_charge(ws.work, f, cnt)
                    return True
                if mode == CLOSEST_EAGER and best_t == t and ws.hit_i[0] == kind and ws.hit_i[1] == idx:
                    eager_normal(geo, kind, idx, ox + t * dx, oy + t * dy, oz + t * dz, ws.hit_f, cnt)
    level_charge(ws.work, f, cnt)
    return found


@njit
def _cast_chunks(geo, origins, directions, tmin, tmax, mode, chunk, t_out, kind_out, index_out, inst_out,
                 counters, c0, c1):
    n = origins.shape[0]
    for c in range(c0, c1):
        ws = workspace()
        hit_f, hit_i = ws.hit_f, ws.hit_i
        cnt = np.zeros(C.N_COUNTERS, np.int64)
        for r in range(c * chunk, min(n, (c + 1) * chunk)):
            cnt[C.RAYS_CAST] += 1
            if intersect(geo, origins[r, 0], origins[r, 1], origins[r, 2], directions[r, 0], directions[r, 1],
                         directions[r, 2], tmin[r], tmax[r], mode, ws, cnt):
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
        mode = ANY_HIT if any_hit else CLOSEST
        for_ranges(lambda c0, c1: _cast_chunks(geo, origins, directions, tmin, tmax, mode, CHUNK, t, kind, index,
                                               inst, counters, c0, c1), len(counters), kernel=_cast_chunks)
    return t, kind, index, inst, counters.sum(axis=0)

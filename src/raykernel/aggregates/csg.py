"""Arvo's boolean operators as aggregates: difference, intersection and union of closed solids.

    {"difference": {"base": [items], "subtract": [items]}}        # JSON scene items
    {"intersection": {"items": [items]}}, {"union": {"items": [items]}}
    Group(accel="difference(base=1)", children=[lens_a, lens_b])  # the same as a group spec

A CSG group's operands are its children, in order (child groups without a
spec of their own are built with the default structure, not merged); for
`difference` the first `base` of them are the base, the rest are taken away.
Each operand is a closed solid: spheres, closed meshes, closed polygon sets,
groups, instances and other CSG nodes of them.

How a ray is answered
---------------------
An operator kind (collect.py): entering a CSG node (step START), the ray's
origin moves back to before where the line enters the box of all operands,
and its frame becomes a sink that collects every operand surface the line
crosses, from the box entry up to the closest hit so far. When the frame
ends (`resolve`), the crossings are sorted, duplicates (an item a grid or
octree tested twice) dropped, and each operand's inside state toggled at its
crossings (parity, so the winding of a mesh does not matter); where the
operator's result changes from outside to inside or back, the crossing is a
surface of the result (two that cancel at one t, a graze or two operands
touching, are none). Those go to the enclosing sink if the node is itself
an operand, else to the hit rule (closest, any or all hits, within the
ray's [tmin, tmax]). A surface of a subtracted operand has its normal
reversed (`hit_i[3]`), so shading and refraction see the cut surface from
the right side.

Counted (COUNTERS): csg.crossings (operand surfaces collected), csg.resolves
(nodes evaluated, once per ray that enters one) and csg.surfaces (result
surfaces found, offered as hits or to an enclosing node).

Flat layout (the Geometry fields it owns)
-----------------------------------------
K CSG nodes:
  csg_op      (K,)   int64    DIFFERENCE, INTERSECTION or UNION                       8 B a node
  csg_base    (K,)   int64    difference: operands in the base (the rest subtract)     8 B
  csg_first   (K,)   int64    first operand reference in Geometry.refs                8 B
  csg_count   (K,)   int64    operands (at most MAX_OPERANDS: one bit of an int64 each)  8 B
  csg_bounds  (K, 6) float64  box of all operands, widened: where crossings are collected from  48 B
The aggregate's agg_start is its node; its agg_bounds the box the result can
lie in (the base's for a difference, the overlap of the operands' for an
intersection), which is what the parent culls with.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import SceneError
from ..geometry.boxes import INF, box_entry, cull_margin
from ..geometry.config import njit
from ..geometry.counters import own_columns
from .collect import CAPACITY, COLUMNS, begin
from .spec import Kind, Param
from .walk import Field, Walk, one_cell

CODE = 5
DIFFERENCE, INTERSECTION, UNION = 0, 1, 2
OPERATORS = ("difference", "intersection", "union")
MAX_OPERANDS = 63            # one bit of an int64 per operand (resolve's inside mask)

FIELDS = (Field("csg_op", np.int64), Field("csg_base", np.int64), Field("csg_first", np.int64),
          Field("csg_count", np.int64), Field("csg_bounds", np.float64, (6,)))

# its own counters (the first, crossings, is counted by the driver: collect.py), and their cost-model features
COUNTERS = (("csg.crossings", "csg.crossing"), ("csg.resolves", "csg.resolve"), ("csg.surfaces", None))
CROSSINGS, RESOLVES, SURFACES = own_columns(CODE, len(COUNTERS))


def stats_rows(stats) -> list:
    """Its rows of the statistics table (rendering/stats.py)."""
    n = stats.get("csg.resolves", 0)
    if not n:
        return []
    return [("csg", "nodes entered", f"{n:,}", "rays evaluated by a boolean operator"),
            ("csg", "crossings", f"{stats['csg.crossings']:,}",
             f"{stats['csg.crossings'] / n:.2f} operand surfaces per node"),
            ("csg", "surfaces", f"{stats['csg.surfaces']:,}", f"{stats['csg.surfaces'] / n:.2f} per node")]


# ---------------------------------------------------------------- building

def _result_box(op, base, bounds):
    """Where the result can lie: the base's box, the operands' overlap, or all of them."""
    solid = np.all(bounds[:, :3] <= bounds[:, 3:], axis=1)
    if op == DIFFERENCE:
        bounds, solid = bounds[:base], solid[:base]
    if op == INTERSECTION:
        if not solid.all():
            return np.array([np.inf] * 3 + [-np.inf] * 3)
        box = np.concatenate([bounds[:, :3].max(axis=0), bounds[:, 3:].min(axis=0)])
        return box if np.all(box[:3] <= box[3:]) else np.array([np.inf] * 3 + [-np.inf] * 3)
    if not solid.any():
        return np.array([np.inf] * 3 + [-np.inf] * 3)
    return np.concatenate([bounds[solid, :3].min(axis=0), bounds[solid, 3:].max(axis=0)])


def _flatten(op):
    def flatten(builder, params, refs, bounds, name, box):
        n = len(refs)
        where = f"{OPERATORS[op]} {name!r}" if name else OPERATORS[op]
        if n > MAX_OPERANDS:
            raise SceneError(f"{where} has {n} operands; at most {MAX_OPERANDS}: gather some in a union")
        base = params["base"] if op == DIFFERENCE else n
        if op == DIFFERENCE and base > n:
            raise SceneError(f"{where}: base={base} but it has only {n} operands")
        flat = builder.flat
        node = flat.size("csg_op")
        widened = np.asarray(box, np.float64).copy()
        if np.all(np.isfinite(widened)):
            m = 4.0 * cull_margin(widened)
            widened[:3] -= m
            widened[3:] += m
        flat.append(csg_op=[op], csg_base=[base], csg_first=[flat.add_refs(refs)], csg_count=[n],
                    csg_bounds=widened.reshape(1, 6))
        agg = flat.add_aggregate(CODE, node, n, _result_box(op, base, bounds))
        return agg, {"nodes": 1, "inner": 1, "leaves": 0, "empty_leaves": 0, "refs": n, "bytes": 80 + 8 * n,
                     "operands": n}
    return flatten


# ---------------------------------------------------------------- the walk

@njit(inline="always")
def walk_step(geo, step, a, te, ray, lo, best_t, f, sp, ws, cnt):
    """walk.py's step contract: START makes the frame a sink, the ray's origin moved before the
    operands' box, and answers the operand references."""
    ox, oy, oz, dx, dy, dz, ix, iy, iz = ray
    ox, oy, oz, best_t, s, e = start(geo.csg_bounds, geo.csg_first, geo.csg_count, a, ox, oy, oz, dx, dy, dz, ix,
                                     iy, iz, best_t, ws.frame_f, ws.frame_i, f, ws.buf_n)
    return sp, s, e, False, 0.0, 0.0, (ox, oy, oz, dx, dy, dz, ix, iy, iz), best_t, True


@njit(inline="always")
def walk_resolve(geo, node, region, shift, operand, ws, cnt):
    """collect.py's resolve contract: node `node`'s surfaces among the crossings from `region` on."""
    return resolve(geo.csg_op[node], geo.csg_base[node], geo.csg_count[node], ws.buf_t, ws.buf_i, ws.buf_m, ws.buf_n,
                   region, shift, operand, cnt)


@njit(private=True)
def start(csg_bounds, csg_first, csg_count, node, ox, oy, oz, dx, dy, dz, ix, iy, iz, best_t, frame_f, frame_i, f,
          buf_n):
    """Enter CSG node `node` in frame f: a sink (collect.begin) whose ray starts before the
    operands' box. Returns the new origin, the closest-hit bound on the moved ray and the
    operand references to test, refs[s:e]."""
    te = box_entry(csg_bounds, node, ox, oy, oz, ix, iy, iz, -INF, INF)
    if te == INF:
        te = 0.0
    else:
        # as far again before the box as it is wide: the walks below then see a ray from
        # outside, as every other ray they meet, not one starting on their boxes' walls
        b = csg_bounds
        size = max(max(b[node, 3] - b[node, 0], b[node, 4] - b[node, 1]), b[node, 5] - b[node, 2])
        te -= size / math.sqrt(dx * dx + dy * dy + dz * dz)
    return begin(frame_f, frame_i, f, te, csg_first[node], csg_count[node], best_t, buf_n, ox, oy, oz, dx, dy, dz)


@njit(inline="always")
def _before(csg_t, csg_i, a, b):
    """Row a sorts before row b: by t, then operand, kind, index, instance, root."""
    if csg_t[a] != csg_t[b]:
        return csg_t[a] < csg_t[b]
    for k in (0, 1, 2, 3, 5):
        if csg_i[a, k] != csg_i[b, k]:
            return csg_i[a, k] < csg_i[b, k]
    return False


@njit(inline="always")
def _inside(op, mask, base_bits, all_bits):
    if op == DIFFERENCE:
        return (mask & base_bits) != 0 and (mask & ~base_bits) == 0
    if op == INTERSECTION:
        return mask == all_bits
    return mask != 0


@njit(private=True)
def _move(csg_t, csg_i, csg_m, src, dst):
    csg_t[dst] = csg_t[src]
    for k in range(COLUMNS):
        csg_i[dst, k] = csg_i[src, k]
    for k in range(12):
        csg_m[dst, k] = csg_m[src, k]


@njit(private=True)
def resolve(op, base, count, csg_t, csg_i, csg_m, csg_n, region, shift, operand, cnt):
    """The node's result surfaces from its crossings in rows region.. of the buffer:
    written back from row `region` in order of t, on the enclosing frame's ray (t + shift),
    as crossings of `operand` of the enclosing sink; returns how many."""
    n = csg_n[0]
    # insertion sort by the full key; the spare row at n holds the row being placed
    if n >= CAPACITY:
        raise ValueError("a ray crossed more operand surfaces than the crossing buffer holds (collect.CAPACITY)")
    for i in range(region + 1, n):
        if not _before(csg_t, csg_i, i, i - 1):
            continue
        _move(csg_t, csg_i, csg_m, i, n)
        j = i
        while j > region and _before(csg_t, csg_i, n, j - 1):
            _move(csg_t, csg_i, csg_m, j - 1, j)
            j -= 1
        _move(csg_t, csg_i, csg_m, n, j)
    all_bits = (np.int64(1) << count) - 1
    base_bits = (np.int64(1) << base) - 1
    mask = np.int64(0)
    inside = False
    out = region
    for i in range(region, n):
        if i > region and not _before(csg_t, csg_i, i - 1, i):
            continue        # the same crossing again: an item tested twice
        k = csg_i[i, 0]
        mask ^= np.int64(1) << k
        now = _inside(op, mask, base_bits, all_bits)
        if now == inside:
            continue
        inside = now
        if out > region and csg_t[out - 1] == csg_t[i]:
            out -= 1        # in and out again at one t (a graze, two solids touching): no surface
            continue
        flip = csg_i[i, 4]
        if op == DIFFERENCE and k >= base:
            flip ^= 1       # a subtracted surface faces into its operand, out of the result
        _move(csg_t, csg_i, csg_m, i, out)
        csg_i[out, 4] = flip        # not part of the sort key, which later rows are compared by
        out += 1
    for i in range(region, out):
        csg_t[i] += shift
        csg_i[i, 0] = operand
    cnt[RESOLVES] += 1
    cnt[SURFACES] += out - region
    return out - region


def cells(geo, a):
    """The node's box around its operands, which are drawn below it (Walk.cells)."""
    k = geo.agg_start[a]
    return one_cell(geo.csg_bounds[k], geo.csg_first[k], geo.csg_count[k])


WALK = Walk(code=CODE, name="csg", fields=FIELDS, step=walk_step, resolve=walk_resolve, counters=COUNTERS,
            stats_rows=stats_rows, cells=cells)
_BASE = Param("base", 1, "operands that form the base; the rest are subtracted", int, 0, MAX_OPERANDS)
KINDS = (
    Kind("difference", "CSG: the first `base` operands less the rest", (_BASE,), flatten=_flatten(DIFFERENCE),
         walk=WALK, operands=True, operand_lists=("base", "subtract"), max_operands=MAX_OPERANDS,
         operand_spec=lambda counts: f"difference(base={counts['base']})"),
    Kind("intersection", "CSG: where every operand is", flatten=_flatten(INTERSECTION), walk=WALK, operands=True,
         max_operands=MAX_OPERANDS),
    Kind("union", "CSG: where any operand is (one solid: inner surfaces removed)", flatten=_flatten(UNION),
         walk=WALK, operands=True, max_operands=MAX_OPERANDS),
)

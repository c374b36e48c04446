"""Operators: kinds whose walk answers for the primitives below it (the driver's collection mode).

    ox, oy, oz, best_t, s, e = begin(frame_f, frame_i, f, te, first, count, best_t, buf_n, ox, oy, oz, dx, dy, dz)
    record(buf_t, buf_i, buf_m, buf_n, t, operand, kind, idx, inst, root, frame_f, f, cnt, counter)

A kind with operands (`Kind(operands=True)`, such as the boolean operators in
csg.py) calls `begin` in its START step: its frame becomes a *sink*
(FI_SINK), the ray's origin moves to `te` on its line, and every primitive
found below the frame, in any nested aggregate or instance, records its
crossings with the line (both roots of a sphere, one crossing of a triangle
or polygon) in the workspace's crossing buffer instead of offering a hit.
When the frame ends, the driver calls the kind's resolve, which rewrites the
frame's rows (from SLOT_REGION on) as the operator's own surfaces, and
offers them to the enclosing sink or, from the outermost, to the hit rule
(a hit flagged OPERATOR_SURFACE, geometry/hitrule.py).

The crossing buffer (workspace rows): buf_t (t), buf_i (COLUMNS: operand,
kind, index, instance, flip, root), buf_m (the world-to-local map of the
crossing's frame), buf_n[0] the rows in use. Nested sinks share it as a
stack: each sink's rows start where its `begin` found the buffer.

The driver counts each crossing in the counter column it passes
(traverse.CROSSINGS, the CSG kinds' first own counter).
"""

import numpy as np

from ..geometry.config import njit
from .walk import F_MAP, F_ORIGIN, F_STATE, FI_OPERAND, FI_SINK

CAPACITY = 512               # crossings one ray may hold in the buffer at once (all nested sinks together)
COLUMNS = 6                  # buf_i columns: operand, kind, index, instance, flip, root

# a sink frame's state slots
SLOT_REGION = F_STATE        # first buffer row of this sink
SLOT_SHIFT = F_STATE + 1     # t of the new origin on the frame's original ray
SLOT_BEST = F_STATE + 2      # the enclosing frame's closest-hit bound, restored at the end
SLOT_SINK = F_STATE + 3      # the enclosing frame's sink and operand: where the result goes
SLOT_OPERAND = F_STATE + 4
SLOT_FIRST = F_STATE + 5     # the sink's first operand reference: operand = position - SLOT_FIRST


@njit(inline="always")
def buffers():
    """The crossing buffer of one workspace (see the module docstring)."""
    return (np.empty(CAPACITY), np.empty((CAPACITY, COLUMNS), np.int64), np.empty((CAPACITY, 12)),
            np.zeros(1, np.int64))


@njit(inline="always")
def begin(frame_f, frame_i, f, te, first, count, best_t, buf_n, ox, oy, oz, dx, dy, dz):
    """Make frame f a sink whose operands are the references refs[first:first + count], with
    the ray's origin moved to te on its line. Returns the new origin, the closest-hit bound on
    the moved ray and the operand references to test, refs[s:e]."""
    frame_f[f, SLOT_REGION] = buf_n[0]
    frame_f[f, SLOT_SHIFT] = te
    frame_f[f, SLOT_BEST] = best_t
    frame_f[f, SLOT_SINK] = frame_i[f, FI_SINK]
    frame_f[f, SLOT_OPERAND] = frame_i[f, FI_OPERAND]
    frame_f[f, SLOT_FIRST] = first
    frame_i[f, FI_SINK] = f
    ox, oy, oz = ox + te * dx, oy + te * dy, oz + te * dz
    frame_f[f, F_ORIGIN], frame_f[f, F_ORIGIN + 1], frame_f[f, F_ORIGIN + 2] = ox, oy, oz
    return ox, oy, oz, best_t - te, first, first + count


@njit(private=True)
def record(buf_t, buf_i, buf_m, buf_n, t, operand, kind, idx, inst, root, frame_f, f, cnt, counter):
    """Add one crossing, with the map of frame f, to the buffer; counts it in cnt[counter]."""
    n = buf_n[0]
    if n >= CAPACITY:
        raise ValueError("a ray crossed more operand surfaces than the crossing buffer holds (collect.CAPACITY)")
    buf_t[n] = t
    buf_i[n, 0], buf_i[n, 1], buf_i[n, 2], buf_i[n, 3], buf_i[n, 4], buf_i[n, 5] = operand, kind, idx, inst, 0, root
    for k in range(12):
        buf_m[n, k] = frame_f[f, F_MAP + k]
    buf_n[0] = n + 1
    cnt[counter] += 1


@njit(inline="always")
def operand(frame_f, frame_i, f, sink, position):
    """Which operand of the sink the reference at `position` of frame f belongs to: in the
    sink's frame itself its place among the operands, below it the frame's own."""
    if sink == f:
        return position - np.int64(frame_f[f, SLOT_FIRST])
    return frame_i[f, FI_OPERAND]

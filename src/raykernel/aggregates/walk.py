"""What every aggregate's traversal step shares with the driver (traverse.py):
stack-entry tags, frame slots and the mailbox.

    stack_b[sp] = entry_tag(GRID, 1)          # "continue this frame's grid walk"
    kind, step = entry_kind(stack_b[sp]), entry_step(stack_b[sp])
    frame_f[f, F_STATE + 0]                   # the walk's own state in its frame

The stack
---------
Three parallel arrays. An entry with ``stack_b >= 0`` is a range of
references ``refs[stack_a:stack_b]``. An entry with ``stack_b < 0`` is a step
of an aggregate kind's walk: ``stack_b = -1 - (kind << STEP_BITS | step)``,
``stack_a`` the step's argument (a node, a grid, a list position) and
``stack_t`` the distance at which the entry begins, so entries beyond the
closest hit are dropped unseen. Step 0 of every kind is START: enter the
aggregate, ``stack_a`` = its ``agg_start``.

Frames
------
One row of ``frame_f`` (floats) and ``frame_i`` (ints) per aggregate on the
ray's current path, row 0 the root. frame_f holds the ray in the frame's
space (F_ORIGIN, F_DIR), the world-to-local map of the frame (F_MAP, 3x4
row-major), STATE_SLOTS slots a walk may keep its state in across the
children it opens (F_STATE), and the mailbox (F_MBOX_ON, F_MBOX). frame_i
holds the aggregate (FI_AGG), the stack base of the frame (FI_BASE), the
innermost instance (FI_INST, -1: none), and, below a CSG node, the frame
that collects the crossings found here and as which of its operands
(FI_SINK, -1: none, and FI_OPERAND; see csg.py).

The mailbox
-----------
A walk whose cells share items (grid, octree) turns its frame's mailbox on
at START with `mailbox_reset`: a direct-mapped cache of MBOX_SLOTS tagged
references already tested, which the driver's reference loop consults.

Keyed lists
-----------
A step may hand the driver a candidate list sorted by a key (ray
classification): the driver stops the list once ``key > key_o + best_t *
key_d * KEY_SLACK + 1e-9 * |key_o|`` and, interrupted by a child aggregate,
pushes the step's resume tag at the next candidate instead of a plain range.
"""

from typing import NamedTuple

from ..geometry.config import njit
from ..scene.model import MAX_NESTING  # noqa: F401  (aggregates along any path from the root: the frames)

MAX_TREE_DEPTH = 96       # nodes along any path within one hierarchy (the stack)
STACK_SIZE = MAX_NESTING * (MAX_TREE_DEPTH + 2)
STEP_BITS = 4
F_ORIGIN, F_DIR, F_MAP = 0, 3, 6      # frame_f slots: ray origin (3), direction (3), world-to-local map (12)
F_STATE = 18                          # a walk's own state
STATE_SLOTS = 6
F_MBOX_ON = F_STATE + STATE_SLOTS     # 1.0 when the frame's walk uses the mailbox
F_MBOX = F_MBOX_ON + 1                # MBOX_SLOTS tagged references already tested (-1: free)
MBOX_SLOTS = 64
FRAME_F = F_MBOX + MBOX_SLOTS
FI_AGG, FI_BASE, FI_INST = 0, 1, 2    # frame_i slots
FI_SINK, FI_OPERAND = 3, 4            # the CSG frame collecting this frame's crossings (-1: none), and as which operand
FRAME_I = 5
F_KEY_END, F_KEY_O, F_KEY_D = F_STATE, F_STATE + 1, F_STATE + 2  # a keyed list's end, key_o, key_d
KEY_SLACK = 1.0 + 1e-7                # a keyed list's early exit widens the closest hit by this (hit-point rounding)
START = 0                             # step 0 of every kind


@njit(inline="always")
def entry_tag(kind, step):
    return -1 - ((kind << STEP_BITS) | step)


@njit(inline="always")
def entry_kind(tag):
    return (-1 - tag) >> STEP_BITS


@njit(inline="always")
def entry_step(tag):
    return (-1 - tag) & ((1 << STEP_BITS) - 1)


@njit(inline="always")
def mailbox_reset(frame_f, f):
    """Turn the frame's mailbox on and empty it."""
    frame_f[f, F_MBOX_ON] = 1.0
    for k in range(MBOX_SLOTS):
        frame_f[f, F_MBOX + k] = -1.0


@njit(inline="always")
def push(stack_a, stack_b, stack_t, sp, a, b, t):
    stack_a[sp] = a
    stack_b[sp] = b
    stack_t[sp] = t
    return sp + 1



class Field(NamedTuple):
    """One array of Geometry that an aggregate kind owns: rows of `shape` items of `dtype`."""
    name: str
    dtype: type
    shape: tuple = ()

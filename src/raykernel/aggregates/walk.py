"""What every aggregate kind's walk shares with the driver (engine/traverse.py): the step
contract, stack-entry tags, frame slots, the workspace and the mailbox.

    WALK = Walk(code=1, name="bvh", fields=FIELDS, step=walk_step)      # a kind's module declares its walk
    sp, s, e, keyed, key_o, key_d, ray, best_t, sink = step(geo, step, a, te, ray, lo, best_t, f, sp, ws, cnt)
    return answer(sp, s, e, ray, best_t)      # the common answer of a step: test refs[s:e] (none: s == e)

The step contract
-----------------
A walk is one compiled function, `step`, called by the driver (inline: it
should only unpack what it reads of the Geometry and call the walk's own
kernel with those arrays) whenever the driver pops a stack entry of the
walk's code:

  geo      the scene's Geometry (engine/flatten.py), the walk's FIELDS among its arrays
  step     which step of the walk: START (0) when the ray enters an aggregate of the walk, else a
           step number of the walk's own, as it pushed it (entry_tag(code, step))
  a        the entry's argument: at START the aggregate's agg_start, else what the walk pushed
  te       the distance at which the entry begins (the aggregate's box entry at START)
  ray      (ox, oy, oz, dx, dy, dz, ix, iy, iz) in the frame's space, ix.. = boxes.inverse(dx)..
  lo       the lower end of the tested interval (tmin; -inf below an operator)
  best_t   the closest hit so far (entries beyond it are never popped)
  f        the frame (ws.frame_f[f], ws.frame_i[f]: the walk may keep state in F_STATE slots)
  sp       the stack pointer, at the entry just popped: the walk may push entries of its own above
           it (push, entry_tag), and read what it kept with the popped one (ws.stack_u[sp])
  ws       the workspace (Workspace below)
  cnt      the counter row: cells.visited, cells.leaves, cells.empty, bounds.tests, and the walk's
           own counters (Walk.counters); the driver charges the visits and bound tests a step
           made to the walk (walk.<name>.steps, .bounds)

and returns (sp, s, e, keyed, key_o, key_d, ray, best_t, sink): the new stack pointer, the
references refs[s:e] to test next (none: s == e), whether they are a keyed list (below),
the ray and closest-hit bound to go on with (an operator moves the origin), and whether the
frame became a sink (an operator's START, collect.py). `answer` makes the common return.
A walk that is a plain range of references (the brute-force list) answers START with it.

The stack
---------
Three parallel arrays (and stack_u, a second distance a walk may keep with its own entries). An entry with ``stack_b >= 0`` is a range of
references ``refs[stack_a:stack_b]``. An entry with ``stack_b < 0`` is a step
of a walk: ``stack_b = -1 - (code << STEP_BITS | step)``, ``stack_a`` the
step's argument (a node, a grid, a list position) and ``stack_t`` the
distance at which the entry begins, so entries beyond the closest hit are
dropped unseen. Code DRIVER is the driver's own (KEYED: go on with a
frame's keyed list).

Frames
------
One row of ``frame_f`` (floats) and ``frame_i`` (ints) per aggregate on the
ray's current path, row 0 the root. frame_f holds the ray in the frame's
space (F_ORIGIN, F_DIR), the world-to-local map of the frame (F_MAP, 3x4
row-major), STATE_SLOTS slots a walk may keep its state in across the
children it opens (F_STATE), and the mailbox (F_MBOX_ON, F_MBOX). frame_i
holds the aggregate (FI_AGG), the stack base of the frame (FI_BASE), the
innermost instance (FI_INST, -1: none), and, below an operator, the frame
that collects the crossings found here and as which of its operands
(FI_SINK, -1: none, and FI_OPERAND; see collect.py).

The mailbox
-----------
A walk whose cells share items (grid, octree) turns its frame's mailbox on
at START with `mailbox_reset`: a direct-mapped cache of MBOX_SLOTS tagged
references already tested, which the driver's reference loop consults.

Keyed lists
-----------
A step may hand the driver a candidate list sorted by a key: references
keyed_ref[s:e] with keys keyed_key[s:e] (Geometry fields of every walk's, in
KEYED_FIELDS), stopped once ``key > key_o + best_t * key_d * KEY_SLACK +
1e-9 * |key_o|``; interrupted by a child aggregate, the driver pushes a KEYED
entry at the next candidate instead of a plain range (the list's end and
keys kept in the frame, F_KEY_*). Ray classification's candidate lists are
such lists.
"""

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numba.core import types
from numba.core.types import NamedTuple as NamedTupleType
from numba.extending import overload

from ..geometry import counters as C
from ..geometry.config import njit
from ..geometry.limits import MAX_NESTING

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
FI_SINK, FI_OPERAND = 3, 4            # the operator's frame collecting this frame's crossings (-1: none), and as which operand
FRAME_I = 5
F_KEY_END, F_KEY_O, F_KEY_D = F_STATE, F_STATE + 1, F_STATE + 2  # a keyed list's end, key_o, key_d
KEY_SLACK = 1.0 + 1e-7                # a keyed list's early exit widens the closest hit by this (hit-point rounding)
START = 0                             # step 0 of every kind
DRIVER = C.MAX_WALKS                  # the code of the driver's own entries (no walk's)
KEYED_STEP = 1                        # its step: go on with the frame's keyed list at stack_a


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


KEYED_FIELDS = (Field("keyed_key", np.float64), Field("keyed_ref", np.int64))   # the keyed lists (see above)


class Cells(NamedTuple):
    """An aggregate's cells or nodes, as a walk's `cells(geo, a)` gives them (rendering/structure.py
    draws them): boxes lo, hi (n, 3) in the aggregate's space, each one's depth in the structure
    (0: the root or, for a grid, every cell), its references refs[first:first + count] (count
    -1: an inner node, which holds none of its own), and the key its walk notes a visit of it
    with (note_visit; -1: a box the walk does not note, whose aggregate's box is charged)."""
    lo: np.ndarray
    hi: np.ndarray
    depth: np.ndarray
    first: np.ndarray
    count: np.ndarray
    key: np.ndarray


def one_cell(box, first: int, count: int) -> Cells:
    """An aggregate drawn as its box alone, holding refs[first:first + count] (count 0: none drawn below)."""
    box = np.asarray(box, np.float64)
    return Cells(box[None, :3].copy(), box[None, 3:].copy(), np.zeros(1, np.int64), np.array([first], np.int64),
                 np.array([count], np.int64), np.array([-1], np.int64))


def note_visit(work, code, key):
    """A walk of code `code` enters its cell or node `key` (as its Cells give the key): counted
    when a render measures how rays use the structure (geometry/work.py, Use); nothing otherwise,
    and without work layers nothing is compiled."""


def _measures_use(work) -> bool:
    return (isinstance(work, NamedTupleType) and "use" in work.fields
            and not isinstance(work.types[work.fields.index("use")], types.NoneType))


@overload(note_visit, inline="always")
def _note_visit(work, code, key):
    if not _measures_use(work):
        return lambda work, code, key: None

    def visit(work, code, key):
        use = work.use
        if use.state[1] == 0:       # not paused (geometry/work.py: Use.state, NOTED and PAUSED)
            row = use.offset[code] + key
            use.counts[row, 0] += 1
            use.state[0] = row
    return visit


@dataclass(frozen=True)
class Walk:
    """A walk, as its module declares it (WALK): `code`, its number (agg_kind, counter columns:
    0, 1, ... below counters.MAX_WALKS, none twice), `name` (walk.<name>.* counters), the
    Geometry `fields` it owns, its compiled `step` (the contract above), for an operator its
    compiled `resolve` (collect.py), its `counters` of its own ((name, cost-model feature or
    None), in counters.own_columns(code)), `stats_rows(stats)`, its rows of the statistics
    table, `features(stats, f)`, which prices what the cost model's features for every walk
    (entry.W, step.W, bound.W and its own counters') do not (analysis/costmodel.py), and
    `cells(geo, a)`, aggregate a's cells or nodes as Cells (None: drawn as its box), and `keys`,
    the Geometry field whose rows number the keys its kernel notes visits with (note_visit;
    None: it notes none, and the aggregate's box takes its visits), and `references(geo, a)`,
    the references aggregate a holds where they are not ranges of geo.refs given by its Cells
    (ray classification's candidate lists), so that what is nested below it is drawn."""
    code: int
    name: str
    fields: tuple = ()
    step: object = field(default=None, compare=False)
    resolve: object = field(default=None, compare=False)
    counters: tuple = ()
    stats_rows: object = field(default=None, compare=False)
    features: object = field(default=None, compare=False)
    cells: object = field(default=None, compare=False)
    keys: str | None = None
    references: object = field(default=None, compare=False)


class Workspace(NamedTuple):
    """One thread's scratch arrays for the walks (traverse.workspace makes them)."""
    stack_a: np.ndarray     # the stack (see above)
    stack_b: np.ndarray
    stack_t: np.ndarray
    stack_u: np.ndarray     # a second distance an entry may carry, for the walk that pushed it (the end of
                            # an interval: a k-d tree's far child); the driver neither writes nor reads it
    frame_f: np.ndarray     # the frames
    frame_i: np.ndarray
    hit_f: np.ndarray       # the hit record (geometry/hitrule.py)
    hit_i: np.ndarray
    buf_t: np.ndarray       # the operators' crossing buffer (collect.py)
    buf_i: np.ndarray
    buf_m: np.ndarray
    buf_n: np.ndarray
    t4: np.ndarray          # the 4-wide walk's entry distances (widebvh.py)
    work: object            # None, or what a render asked for work layers keeps per sample (geometry/work.py)


@njit(inline="always")
def answer(sp, s, e, ray, best_t):
    """A step's common return: test refs[s:e] next (none: s == e), nothing else changed."""
    return sp, s, e, False, 0.0, 0.0, ray, best_t, False

"""The 4-wide BVH: a binary SAH tree collapsed into nodes of up to four children.

    wide = collapse(node_bounds, node_first, node_count, root)     # WideBVH of one binary tree
    wx, wy, wz, vx, vy, vz, near = wide_ray(wide.center, ox, oy, oz, ix, iy, iz)   # once per ray
    stack[0], stack_t[0], sp = 0, te, 1                            # the root, entered at te
    while sp > 0:                                                  # the 4-wide walk, written once
        leaf, sp, n_nodes, n_bounds = next_leaf(wide.nodes, wx, wy, wz, vx, vy, vz, near, tmin, best_t, t4,
                                                stack, stack_t, sp, n_nodes, n_bounds)
        if leaf == NO_CHILD:
            continue
        first, end = leaf_range(wide.nodes, leaf)                  # test refs first..end-1, lower best_t

Why: a binary node visit tests two boxes one after the other; a wide node
tests its four children's boxes in one vector slab test (four lanes of
double arithmetic, `box4_entries`), so a ray visits about half the nodes and
spends a quarter of the box-test instructions per child. The tree is the
binary tree with levels taken out (Wald et al. 2008's collapse): every inner
node takes over the children of its largest-area inner child until it has
four, so the leaves, and so the triangle tests of a ray, stay exactly those
of the binary tree.

Layout (W nodes; node 0 is the root, children stored after their parent)
-----------------------------------------------------------------------
One record of 32 int32 words a node, 128 bytes, aligned to 64 bytes so that a
visit reads two cache lines:
  words  0..23  float32 bits  the children's boxes as structure of arrays:
                xmin[4] ymin[4] zmin[4] xmax[4] ymax[4] zmax[4], rounded
                outwards from the binary tree's float64 boxes (so every box
                contains its float64 original and the triangle test's
                watertightness holds); an unused slot holds the empty box
                (+inf .. -inf), which no ray enters
  words 24..27  int32  child: an inner child's node, a leaf's first reference
  words 28..31  int32  count: 0 inner child, > 0 a leaf of that many references,
                -1 an unused slot (used slots come first)
`WideBVH.nodes` is that int32 array (`WideBVH.boxes` the same memory seen as
float32). Nodes and references are therefore limited to 2**31 - 1.

The boxes are stored relative to `WideBVH.center`, the centre of the root box,
and the walk moves the ray origin by it (in float64): float32 keeps 24 bits,
so a mesh far from the origin (at 1e7, where float32's step is 1) would
otherwise get boxes a unit wider than the mesh. The float64 subtraction that
moves a box rounds by far less than the culling margin the binary tree's
boxes carry (flatten's CULL_MARGIN, 1e-9 of the box's size or position).

Counting: one `cells.visited` per wide node visited and one `bounds.tests`
per child box tested (each used slot of the node), so a 4-wide walk shows
about half the visits of the binary one and a similar number of box tests.

The slab test takes each axis's near and far planes by the sign of the ray's
direction (`near` offsets, from `wide_ray`), subtracts the origin and
multiplies by the inverse direction in float64, and widens the exit distance
by CONSERVATIVE as the scalar `box_entry` does (Ize 2013). A ray that does not
move along an axis takes the same vector test with an infinite inverse there
(`wide_ray`): a product is then -inf or +inf by the side of the plane the
origin lies on, and NaN for an origin on the plane, which the test skips (its
maxima and minima keep the other operand), so the ray is in the closed slab or
outside it for every t, as the scalar `slab` decides. One test for every ray
keeps a branch and a second box test out of the walk's inner loop, which made
the mesh kernel faster (BENCHMARKS.md, "Ray casting").
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from ..errors import SceneError
from ..geometry.boxes import CONSERVATIVE, INF, STILL
from ..geometry.config import njit
from ..geometry.unchecked import load, prefetch, store



CHILD, COUNT = 24, 28          # first words of the child and count fields


class WideBVH(NamedTuple):
    nodes: np.ndarray    # (W, 32) int32 records (see the layout above)
    center: np.ndarray   # (3,) float64 the point the boxes are stored relative to

    @property
    def boxes(self) -> np.ndarray:
        """The records as float32, for their box words."""
        return self.nodes.view(np.float32)

    @property
    def nbytes(self) -> int:
        return self.nodes.nbytes


@njit(inline="always")
def _down(x):
    """The largest float32 at or below x (x - center in float64): x rounded, then one step down
    by its bits where that went up (np.nextafter is a library call per value). Both candidates are
    computed and one chosen, with no branch: which way a value rounds is a coin toss."""
    y = np.float32(x)
    b = y.view(np.int32)
    stepped = b - 1 if y > 0 else (b + 1 if y < 0 else np.int32(-2147483647))
    return np.int32(stepped if np.float64(y) > x else b).view(np.float32)


@njit(inline="always")
def _up(x):
    """The smallest float32 at or above x, as _down."""
    y = np.float32(x)
    b = y.view(np.int32)
    stepped = b + 1 if y > 0 else (b - 1 if y < 0 else np.int32(1))
    return np.int32(stepped if np.float64(y) < x else b).view(np.float32)


@njit(private=True)
def _is_inner(first, count, c):
    return count[c] == 0 and first[c] > c


@njit(private=True)
def _area(bounds, c, margin):
    """Half the surface area of binary node c's box widened by margin on every side."""
    ex = bounds[c, 3] - bounds[c, 0] + 2.0 * margin
    ey = bounds[c, 4] - bounds[c, 1] + 2.0 * margin
    ez = bounds[c, 5] - bounds[c, 2] + 2.0 * margin
    return ex * ey + ey * ez + ez * ex


@njit
def _collapse_kernel(bounds, first, count, root, margin, center, nodes, boxes):
    """Write the wide nodes' records (see above; boxes widened by margin, then moved by center and
    rounded outwards) into nodes / boxes (the same memory as int32 and float32), each node's inner
    children side by side and the subtrees depth first. Returns (wide nodes made, the binary
    tree's SAH cost: the areas of its nodes, a leaf's times its references, over the root's, and
    the largest reference a leaf names, which must fit the int32 child word).
    Depth first so that the binary nodes are read in about the order the build wrote them (a
    level-by-level order reads them all over memory)."""
    cap = nodes.shape[0]
    todo = np.empty(cap, np.int64)            # binary inner node of each wide node not yet filled
    stack = np.empty(cap, np.int64)           # wide nodes made but not yet filled, the next on top
    slots = np.empty(4, np.int64)
    todo[0] = root
    made = 1
    stack[0] = 0
    sp = 1
    largest_ref = 0
    root_area = _area(bounds, root, margin)
    total = root_area * (count[root] if not _is_inner(first, count, root) and count[root] > 0 else 1)
    if not root_area > 0.0:
        root_area = 1.0
    while sp > 0:
        sp -= 1
        w = stack[sp]
        b = todo[w]
        if not _is_inner(first, count, b):      # a leaf at the root: one leaf child
            slots[0] = b
            k = 1
        else:
            slots[0] = first[b]
            slots[1] = first[b] + 1
            k = 2
        while k < 4:                            # open the largest inner child
            pick = -1
            largest = -1.0
            for s in range(k):
                c = slots[s]
                if _is_inner(first, count, c):
                    a = _area(bounds, c, 0.0)
                    if a > largest:
                        largest = a
                        pick = s
            if pick < 0:
                break
            c = slots[pick]
            total += _area(bounds, c, margin)
            slots[pick] = first[c]
            slots[k] = first[c] + 1
            k += 1
        top = sp
        for s in range(4):
            if s >= k:
                for a in range(3):
                    boxes[w, 4 * a + s] = INF
                    boxes[w, 12 + 4 * a + s] = -INF
                nodes[w, CHILD + s] = -1
                nodes[w, COUNT + s] = -1
                continue
            c = slots[s]
            for a in range(3):
                boxes[w, 4 * a + s] = _down(bounds[c, a] - margin - center[a])
                boxes[w, 12 + 4 * a + s] = _up(bounds[c, 3 + a] + margin - center[a])
            if _is_inner(first, count, c):
                nodes[w, CHILD + s] = made
                nodes[w, COUNT + s] = 0
                todo[made] = c
                made += 1
                sp += 1
                total += _area(bounds, c, margin)
            else:
                nodes[w, CHILD + s] = first[c]
                nodes[w, COUNT + s] = count[c]
                largest_ref = max(largest_ref, first[c])
                if c != root:
                    total += _area(bounds, c, margin) * count[c]
        for j in range(sp - top):               # the first inner child on top: filled next
            stack[sp - 1 - j] = made - (sp - top) + j
    return made, total / root_area, largest_ref


def _aligned(rows: int) -> np.ndarray:
    """An uninitialised (rows, 32) int32 array whose rows start on 64-byte boundaries."""
    raw = np.empty(rows * 128 + 64, np.uint8)
    skip = -raw.ctypes.data % 64
    return raw[skip:skip + rows * 128].view(np.int32).reshape(rows, 32)


def collapse(node_bounds, node_first, node_count, root: int, margin: float = 0.0) -> tuple[WideBVH, float]:
    """The 4-wide tree of the binary BVH rooted at `root` (flatten's node arrays: inner nodes
    have count 0 and children first, first + 1; leaves hold references first .. first + count;
    the arrays may hold unused rows, which no node refers to), its boxes widened by margin; and
    the binary tree's SAH cost (traversal 1, a reference 1) on the widened boxes."""
    root_box = node_bounds[root]
    center = np.where(np.isfinite(root_box[:3] + root_box[3:]), (root_box[:3] + root_box[3:]) / 2, 0.0)
    # a wide node for the root and at most one for each inner node (at most half the nodes): the
    # rows not made are never touched, so hold no memory
    nodes = _aligned(len(node_count) // 2 + 1)
    if len(nodes) >= 2 ** 31:
        raise SceneError(f"a 4-wide BVH holds at most 2**31 - 1 nodes; this one may need {len(nodes):,}: "
                         f"use bvh(width=2)")
    made, cost, largest_ref = _collapse_kernel(node_bounds, node_first, node_count, np.int64(root), float(margin),
                                               center, nodes, nodes.view(np.float32))
    if largest_ref >= 2 ** 31:
        raise SceneError(f"a 4-wide BVH names at most 2**31 - 1 references; this one needs {largest_ref + 1:,}: "
                         f"use bvh(width=2)")
    return WideBVH(nodes[:made], center), cost


@njit(inline="always")
def wide_ray(center, ox, oy, oz, ix, iy, iz):
    """A ray as box4_entries and visit take it, from its origin and boxes.inverse's inverse
    direction: the origin relative to the tree's center; the inverse, infinite where it is
    STILL (see above); and `near`, the column offsets in a node's box row of the planes each
    axis enters first (the minimum for a positive direction, else the maximum; the far plane
    is 12 columns away)."""
    near = (0 if ix >= 0.0 else 12), (4 if iy >= 0.0 else 16), (8 if iz >= 0.0 else 20)
    return (ox - center[0], oy - center[1], oz - center[2], INF if ix == STILL else ix, INF if iy == STILL else iy,
            INF if iz == STILL else iz, near)


@intrinsic
def box4_entries(typingctx, box, node, ox, oy, oz, ix, iy, iz, near, tmin, tmax, t4):
    """Slab test of node's four child boxes in one <4 x double> pass: returns the bit mask of
    the children the ray enters within [tmin, tmax] (bits 0-3) and of the used slots (bits 4-7),
    and writes their entry distances to t4.
    box: the nodes (int32 records) or their float32 view; the origin, inverse and `near` as
    wide_ray gives them."""
    sig = types.int64(box, node, ox, oy, oz, ix, iy, iz, near, tmin, tmax, t4)

    def codegen(context, builder, signature, args):
        boxes = context.make_array(signature.args[0])(context, builder, args[0])
        out = context.make_array(signature.args[11])(context, builder, args[11])
        f4, d4 = ir.VectorType(ir.FloatType(), 4), ir.VectorType(ir.DoubleType(), 4)
        i64 = ir.IntType(64)

        def splat(x):
            v = ir.Constant(d4, ir.Undefined)
            for lane in range(4):
                v = builder.insert_element(v, x, ir.Constant(ir.IntType(32), lane))
            return v

        row = builder.mul(args[1], ir.Constant(i64, 32))
        words = builder.bitcast(boxes.data, ir.FloatType().as_pointer())    # int32 records or their float view

        def plane(offset):
            p = builder.gep(words, [builder.add(row, offset)])
            return builder.fpext(builder.load(builder.bitcast(p, f4.as_pointer()), align=4), d4)

        def larger(acc, x):        # a NaN lane of x keeps acc: the test never rejects on NaN
            return builder.select(builder.fcmp_ordered(">", x, acc), x, acc)

        def smaller(acc, x):
            return builder.select(builder.fcmp_ordered("<", x, acc), x, acc)

        origin = (args[2], args[3], args[4])
        inverse = (args[5], args[6], args[7])
        tnear, tfar = splat(args[9]), ir.Constant(d4, [INF] * 4)     # NaN products are skipped (see above)
        for axis in range(3):
            off = builder.extract_value(args[8], axis)
            o, inv = splat(origin[axis]), splat(inverse[axis])
            enter = builder.fmul(builder.fsub(plane(off), o), inv)
            far = builder.urem(builder.add(off, ir.Constant(i64, 12)), ir.Constant(i64, 24))
            leave = builder.fmul(builder.fsub(plane(far), o), inv)
            tnear = larger(tnear, enter)
            tfar = smaller(tfar, leave)
        zero = ir.Constant(d4, [0.0] * 4)
        limited = smaller(splat(args[10]), tfar)
        widened = builder.fmul(limited, ir.Constant(d4, [CONSERVATIVE] * 4))
        tfar = builder.select(builder.fcmp_ordered(">", tfar, zero), widened, limited)
        builder.store(tnear, builder.bitcast(out.data, d4.as_pointer()), align=8)
        hit = builder.zext(builder.bitcast(builder.fcmp_ordered("<=", tnear, tfar), ir.IntType(4)), i64)
        # the used slots (count >= 0) as bits 4-7, from the node's four count words in one vector compare
        counts = builder.load(builder.bitcast(builder.gep(builder.bitcast(words, ir.IntType(32).as_pointer()),
                                                          [builder.add(row, ir.Constant(i64, COUNT))]),
                                              ir.VectorType(ir.IntType(32), 4).as_pointer()), align=4)
        used = builder.icmp_signed(">=", counts, ir.Constant(ir.VectorType(ir.IntType(32), 4), [0] * 4))
        used = builder.zext(builder.bitcast(used, ir.IntType(4)), i64)
        return builder.or_(hit, builder.shl(used, ir.Constant(i64, 4)))

    return sig, codegen


NO_WIDE = WideBVH(np.zeros((0, 32), np.int32), np.zeros(3))   # "no wide tree" (width 2)


NO_CHILD = -2 ** 62     # visit's answer when the ray enters no child (every stack entry is larger)


@njit(inline="always")
def visit(nodes, v, ox, oy, oz, ix, iy, iz, near, tmin, tmax, t4, stack, stack_t, sp):
    """Test node v's children: return the nearest the ray enters (NO_CHILD if none), for the
    walk to take next, and push the others on the stack above sp, the nearest of them on top.
    A child is an inner node as its index (>= 0), a leaf as -(v * 4 + slot) - 1 (leaf_range
    decodes it). Among children entered at the same distance the later slot comes first, so the
    order is that of pushing every child and popping the top. The ray as wide_ray gives it.
    Returns the nearest child, the new sp and the child boxes tested (the node's used slots)."""
    mask = box4_entries(nodes, v, ox, oy, oz, ix, iy, iz, near, tmin, tmax, t4)
    row = v * 32
    bottom = sp
    used = mask >> 4
    tested = (used & 1) + (used >> 1 & 1) + (used >> 2 & 1) + (used >> 3)      # used slots come first
    nearest = np.int64(NO_CHILD)
    t_nearest = INF
    for s in range(4):
        if mask & (1 << s) == 0:
            continue
        t = load(t4, s)
        child = np.int64(load(nodes, row + CHILD + s))
        if load(nodes, row + COUNT + s) != 0:
            child = -(v * 4 + s) - 1        # a leaf
        else:       # its record's two lines, asked for now: the children a ray enters come from memory together
            prefetch(nodes, child * 32)
            prefetch(nodes, child * 32 + 16)
        if t <= t_nearest:
            if nearest == NO_CHILD:
                nearest, t_nearest = child, t
                continue
            child, nearest = nearest, child     # the nearest so far goes on the stack, on top
            t, t_nearest = t_nearest, t
        j = sp              # insertion: the farthest deepest
        while j > bottom and load(stack_t, j - 1) < t:
            store(stack, j, load(stack, j - 1))
            store(stack_t, j, load(stack_t, j - 1))
            j -= 1
        store(stack, j, child)
        store(stack_t, j, t)
        sp += 1
    return nearest, sp, tested


@njit(inline="always")
def leaf_range(nodes, entry):
    """The references first .. end of the leaf a stack entry < 0 names (see visit)."""
    slot = -entry - 1
    word = (slot >> 2) * 32 + (slot & 3)
    first = np.int64(load(nodes, word + CHILD))
    return first, first + load(nodes, word + COUNT)


@njit(inline="always")
def next_leaf(nodes, ox, oy, oz, ix, iy, iz, near, tmin, best_t, t4, stack, stack_t, sp, n_nodes, n_bounds):
    """The 4-wide walk, one stack entry at a time (every caller's: the fast render walk,
    aggregates/widewalk.py, and the mesh kernel, casting/meshcast.py): pop the top entry and, unless
    it was entered beyond the closest hit best_t (beyond rounding: ties need the node), go down
    the nearest children to a leaf the ray enters. Returns (that leaf as visit names it, or
    NO_CHILD; sp; n_nodes and n_bounds with the nodes visited and child boxes tested added).
    The ray as wide_ray gives it. Callers loop `while sp > 0`."""
    sp -= 1
    te = load(stack_t, sp)
    if te > best_t and te > best_t * CONSERVATIVE:
        return np.int64(NO_CHILD), sp, n_nodes, n_bounds
    v = load(stack, sp)
    while v >= 0:
        n_nodes += 1
        v, sp, tested = visit(nodes, v, ox, oy, oz, ix, iy, iz, near, tmin, best_t, t4, stack, stack_t, sp)
        n_bounds += tested
    return v, sp, n_nodes, n_bounds

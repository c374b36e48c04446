"""Boxes as rows of eight float64, each half one <4 x double> vector, for the BVH builder's loops.

    grow(box, 0, data, p * ROW)             # box = box united with row p's box
    grow_centre(cbox, 0, data, p * ROW)     # cbox = cbox united with row p's centre
    bx, by, bz = bin3(data, p * ROW, cmin, scale, last)
    swap(data, i * ROW, j * ROW)            # rows i and j exchanged
    empty(box, 0)                           # box = the empty box

A row is  x_lo y_lo z_lo w | x_hi y_hi z_hi 0  (w: the item's weight, or anything in a box or a
bin): the low corner and the high corner each fill one vector, so a box is united with another,
or a row moved, in two vector operations instead of six or eight scalar ones. numba does not
make such code itself (its straight-line vectorizer is off), hence these intrinsics. The fourth
lane of each half is carried along and never read as a coordinate.

Every argument is a C-contiguous float64 array and a flat element offset (a multiple of ROW for a
row's start), which the caller keeps in bounds; nothing is checked. Each lane computes exactly
what the scalar code would: the centre is 0.5 lo + 0.5 hi (two products and a sum, never fused),
so a bin found here is the bin the scalar formula finds.
"""

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

ROW = 8         # float64 a row
HI = 4          # the column of the high corner's x
_D4 = ir.VectorType(ir.DoubleType(), 4)
_I64 = ir.IntType(64)


def _float_array(t):
    return isinstance(t, types.Array) and t.layout == "C" and t.dtype == types.float64


def _half(context, builder, array_type, array, offset_type, offset, lane0):
    """A <4 x double>* to the array's elements offset + lane0 .. + 3."""
    data = context.make_array(array_type)(context, builder, array).data
    at = builder.add(context.cast(builder, offset, offset_type, types.int64), ir.Constant(_I64, lane0))
    return builder.bitcast(cgutils.gep(builder, data, at), _D4.as_pointer())


def _splat(builder, x, vector_type):
    v = ir.Constant(vector_type, ir.Undefined)
    for lane in range(vector_type.count):
        v = builder.insert_element(v, x, ir.Constant(ir.IntType(32), lane))
    return v


def _lower(builder, a, b):
    return builder.select(builder.fcmp_ordered("<", b, a), b, a)


def _upper(builder, a, b):
    return builder.select(builder.fcmp_ordered(">", b, a), b, a)


def _centre(builder, lo, hi):
    half = ir.Constant(_D4, [0.5] * 4)
    return builder.fadd(builder.fmul(half, lo), builder.fmul(half, hi))


def _box_and_row(box, b, data, d):
    return _float_array(box) and _float_array(data) and isinstance(b, types.Integer) and isinstance(d, types.Integer)


def _unite(context, builder, sig, args, low, high):
    """box[b:b+8] (args 0, 1) united with the vectors low (its low half by min) and high (by max)."""
    for lane0, unite, value in ((0, _lower, low), (HI, _upper, high)):
        target = _half(context, builder, sig.args[0], args[0], sig.args[1], args[1], lane0)
        builder.store(unite(builder, builder.load(target, align=8), value), target, align=8)
    return context.get_dummy_value()


def _row(context, builder, sig, args, k=2):
    """The low and high halves of data[d:d+8] (data args[k], d args[k + 1])."""
    return [builder.load(_half(context, builder, sig.args[k], args[k], sig.args[k + 1], args[k + 1], lane0), align=8)
            for lane0 in (0, HI)]


@intrinsic
def grow(typingctx, box, b, data, d):
    """box[b:b+8] united with the box of data[d:d+8]: low half by min, high half by max."""
    if not _box_and_row(box, b, data, d):
        return None

    def codegen(context, builder, sig, args):
        return _unite(context, builder, sig, args, *_row(context, builder, sig, args))

    return types.none(box, b, data, d), codegen


@intrinsic
def grow_centre(typingctx, box, b, data, d):
    """box[b:b+8] united with the centre of data[d:d+8]'s box (a point: both halves)."""
    if not _box_and_row(box, b, data, d):
        return None

    def codegen(context, builder, sig, args):
        centre = _centre(builder, *_row(context, builder, sig, args))
        return _unite(context, builder, sig, args, centre, centre)

    return types.none(box, b, data, d), codegen


@intrinsic
def bin3(typingctx, data, d, cmin, scale, last):
    """The bins of data[d:d+8]'s centre on the three axes: (centre - cmin) * scale truncated, or
    `last` where that is not below last (cmin and scale: 4 float64 each, the fourth unused)."""
    if not (_float_array(data) and _float_array(cmin) and _float_array(scale) and isinstance(d, types.Integer)
            and isinstance(last, types.Integer)):
        return None
    result = types.UniTuple(types.uint64, 3)

    def codegen(context, builder, sig, args):
        lo, hi = _row(context, builder, sig, args, 0)
        zero = ir.Constant(_I64, 0)
        c0 = builder.load(_half(context, builder, sig.args[2], args[2], types.int64, zero, 0), align=8)
        s = builder.load(_half(context, builder, sig.args[3], args[3], types.int64, zero, 0), align=8)
        f = builder.fmul(builder.fsub(_centre(builder, lo, hi), c0), s)
        top = context.cast(builder, args[4], sig.args[4], types.int64)
        i4 = ir.VectorType(_I64, 4)
        below = builder.fcmp_ordered("<", f, _splat(builder, builder.sitofp(top, ir.DoubleType()), _D4))
        b = builder.select(below, builder.fptoui(f, i4), _splat(builder, top, i4))
        lanes = [builder.extract_element(b, ir.Constant(ir.IntType(32), k)) for k in range(3)]
        return context.make_tuple(builder, sig.return_type, lanes)

    return result(data, d, cmin, scale, last), codegen


@intrinsic
def swap(typingctx, data, i, j):
    """Exchange data[i:i+8] and data[j:j+8]."""
    if not (_float_array(data) and isinstance(i, types.Integer) and isinstance(j, types.Integer)):
        return None

    def codegen(context, builder, sig, args):
        halves = [[_half(context, builder, sig.args[0], args[0], sig.args[k], args[k], lane0) for lane0 in (0, HI)]
                  for k in (1, 2)]
        values = [[builder.load(p, align=8) for p in row] for row in halves]
        for row, value in zip(halves, reversed(values)):
            for p, v in zip(row, value):
                builder.store(v, p, align=8)
        return context.get_dummy_value()

    return types.none(data, i, j), codegen


@intrinsic
def empty(typingctx, box, b):
    """box[b:b+8] = the empty box: +inf in the low half, -inf in the high half."""
    if not (_float_array(box) and isinstance(b, types.Integer)):
        return None

    def codegen(context, builder, sig, args):
        for lane0, value in ((0, float("inf")), (HI, float("-inf"))):
            target = _half(context, builder, sig.args[0], args[0], sig.args[1], args[1], lane0)
            builder.store(ir.Constant(_D4, [value] * 4), target, align=8)
        return context.get_dummy_value()

    return types.none(box, b), codegen

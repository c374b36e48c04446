"""Array element access for a walk's inner loop, without numba's negative-index handling.

    x = load(stack_t, sp - 1)           # stack_t[sp - 1], for an index known to be >= 0
    store(stack, j, node)               # stack[j] = node
    k = load(nodes, row * 32 + column)  # a C-contiguous array by its flat element index

Why: numba indexes with a signed integer as Python does, so every `a[i]` whose
index LLVM cannot prove non-negative adds `i < 0 ? i + len : i` (a compare and
a conditional move on the address, and the length kept live in a register or
reloaded from the stack). In the 4-wide walk's loop that shifts stack entries
to insert a child, that came to a large share of its instructions. These read
and write the element at the flat index directly: the caller guarantees
0 <= i < a.size, as a walk does for its stack (bounded by its depth) and for
the nodes it reads (indices the builder wrote). Neither checks bounds, as
numba's own indexing does not.
"""

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic


def _element(context, builder, array_type, array, index_type, index):
    data = context.make_array(array_type)(context, builder, array).data
    return cgutils.gep(builder, data, context.cast(builder, index, index_type, types.int64))


@intrinsic
def load(typingctx, array, index):
    """array.flat[index] of a C-contiguous array, for 0 <= index < array.size."""
    if not isinstance(array, types.Array) or array.layout != "C" or not isinstance(index, types.Integer):
        return None

    def codegen(context, builder, signature, args):
        return builder.load(_element(context, builder, signature.args[0], args[0], signature.args[1], args[1]))

    return array.dtype(array, index), codegen


@intrinsic
def store(typingctx, array, index, value):
    """array.flat[index] = value (converted to the array's dtype), for 0 <= index < array.size."""
    if not isinstance(array, types.Array) or array.layout != "C" or not isinstance(index, types.Integer):
        return None

    def codegen(context, builder, signature, args):
        builder.store(args[2], _element(context, builder, signature.args[0], args[0], signature.args[1], args[1]))
        return context.get_dummy_value()

    return types.none(array, index, array.dtype), codegen


@intrinsic
def prefetch(typingctx, array, index):
    """Ask the processor to bring the cache line of array.flat[index] in, without waiting for it
    (LLVM's prefetch: read, kept in every cache level), for 0 <= index < array.size: a walk names
    the nodes it will visit next, so their lines come from memory side by side, not one by one."""
    if not isinstance(array, types.Array) or array.layout != "C" or not isinstance(index, types.Integer):
        return None

    def codegen(context, builder, signature, args):
        address = builder.bitcast(_element(context, builder, signature.args[0], args[0], signature.args[1], args[1]),
                                  ir.IntType(8).as_pointer())
        i32 = ir.IntType(32)
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.VoidType(), [address.type, i32, i32, i32]),
                                            "llvm.prefetch.p0")
        builder.call(fn, [address, ir.Constant(i32, 0), ir.Constant(i32, 3), ir.Constant(i32, 1)])
        return context.get_dummy_value()

    return types.none(array, index), codegen

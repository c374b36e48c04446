"""A leaf's triangles in blocks of four, tested against a ray four at a time.

    blocks, lane_prims, start = leaf_blocks(verts, faces, prims, leaf_first, leaf_count)   # the 4-wide tree's leaves
    blocks, lane_prims, start = leaf_blocks(..., dtype=np.float32)     # precision="single": half the bytes
    mask = hit4(blocks, b, kx, ky, kz, okx, oky, okz, sx, sy, sz, tmin, tmax, t4)
    x = corner(blocks, b * 4 + lane, i)     # coordinate i (v0x, v0y, ... v2z) of a block's triangle

Layout: `blocks` is (B, 36) float64, one row a block of up to four triangles
as structure of arrays: column (3 * corner + axis) * 4 + lane holds that
corner's coordinate along that axis (x, y, z) for the block's lane-th
triangle, so one corner's coordinate along one axis for all four triangles
is one <4 x double> load. A leaf of k references takes ceil(k / 4) blocks,
from lane start[leaf] = 4 * its first block on, its references in order
(lane start + i is reference first + i); unused lanes hold zeros and are
masked off by the caller. 288 bytes a block (144 in float32, for meshes of
precision "single", whose corners are float32 numbers: raybuild.py), and
`lane_prims` names the triangle of each lane (4 bytes a lane).

`hit4` is primitives.hit_sheared for four triangles in one pass of
<4 x double> arithmetic, the same operations in the same order, so a lane's
t is bit for bit the scalar test's. float32 blocks are widened to double as
they are loaded (exactly), so a lane's t is still the scalar test's on the
same corners. Lanes where an edge function is exactly
zero (a ray through an edge or vertex) are left to the scalar test and its
tie rule: the returned mask has bit i set when lane i hits in [tmin, tmax]
(its t in t4[i]) and bit 4 + i when lane i needs the scalar test.
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from ..geometry.parallel import for_ranges
from ..geometry.config import njit

BLOCK = 4           # triangles in a block
COLUMNS = 36        # 3 corners x 3 axes x 4 lanes


def leaf_blocks(verts, faces, prims, first, count, threads=None,
                dtype=np.float64) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The blocks of the leaves (first reference, count) whose references are the triangles `prims`
    (faces (T, 3) into verts (V, 3), float64): (blocks, the triangle in each lane (-1 where
    unused), each leaf's first lane). A leaf's lanes start a block: leaf i takes lanes
    start[i] .. start[i] + count[i] - 1. dtype: the blocks' (float32 where every corner is a
    float32 number, which it then holds exactly)."""
    first = np.ascontiguousarray(first, np.int64)
    count = np.ascontiguousarray(count, np.int64)
    per_leaf = (count + BLOCK - 1) // BLOCK
    start = np.zeros(len(first) + 1, np.int64)
    np.cumsum(per_leaf, out=start[1:])
    # every lane is written on the threads (unused ones too), so nothing is cleared first on this one
    blocks = np.empty((int(start[-1]), COLUMNS), dtype)
    lane_prims = np.empty(BLOCK * len(blocks), np.int32)
    start *= BLOCK
    for_ranges(lambda i0, i1: _fill_blocks(verts, faces, prims, first, count, start, blocks, lane_prims, i0, i1),
               len(first), threads, kernel=_fill_blocks, min_size=4096)
    return blocks, lane_prims, start[:-1]


@njit
def _fill_blocks(verts, faces, prims, first, count, start, blocks, lane_prims, i0, i1):
    """Leaves i0..i1-1 of leaf_blocks: each reference's corners into its lane, the lanes after
    them in the leaf's last block -1 with zero corners (a triangle no ray hits)."""
    for i in range(i0, i1):
        used = count[i]
        for k in range((used + BLOCK - 1) // BLOCK * BLOCK):
            lane = start[i] + k
            b = lane >> 2
            if k >= used:
                lane_prims[lane] = -1
                for c in range(9):
                    blocks[b, c * BLOCK + (lane & 3)] = 0.0
                continue
            p = prims[first[i] + k]
            lane_prims[lane] = p
            for c in range(3):
                v = faces[p, c]
                for axis in range(3):
                    blocks[b, (3 * c + axis) * BLOCK + (lane & 3)] = verts[v, axis]


@njit(inline="always")
def corner(src, row, i):
    """Coordinate i (v0x, v0y, v0z, v1x, ... v2z) of a triangle, as float64: row `row` of a corners array
    ((R, 9 or more): v0, v1, v2), or lane row % 4 of block row // 4 of a blocks array (B, 36)."""
    if src.shape[1] == COLUMNS:     # (float32 blocks: widened here, so that arithmetic on corners stays double)
        return np.float64(src[row >> 2, i * BLOCK + (row & 3)])
    return np.float64(src[row, i])


@intrinsic
def hit4(typingctx, blocks, b, kx, ky, kz, okx, oky, okz, sx, sy, sz, tmin, tmax, t4):
    """hit_sheared for the four lanes of block b: the ray's axes (kx, ky, kz) and shear from
    ray_shear, its origin's coordinates along those axes. Returns the hit lanes (bits 0-3, t
    in t4) and the lanes with a zero edge function, for the scalar test (bits 4-7)."""
    sig = types.int64(blocks, b, kx, ky, kz, okx, oky, okz, sx, sy, sz, tmin, tmax, t4)

    def codegen(context, builder, signature, args):
        rows = context.make_array(signature.args[0])(context, builder, args[0])
        out = context.make_array(signature.args[13])(context, builder, args[13])
        d4 = ir.VectorType(ir.DoubleType(), BLOCK)
        single = signature.args[0].dtype == types.float32
        stored = ir.VectorType(ir.FloatType(), BLOCK) if single else d4
        i64 = ir.IntType(64)
        data = builder.bitcast(rows.data, stored.element.as_pointer())
        base = builder.mul(args[1], ir.Constant(i64, COLUMNS))

        def splat(x):
            v = ir.Constant(d4, ir.Undefined)
            for lane in range(BLOCK):
                v = builder.insert_element(v, x, ir.Constant(ir.IntType(32), lane))
            return v

        def coordinate(corner, axis):       # <4 x double> of corner's coordinate along `axis` (an i64)
            column = builder.add(ir.Constant(i64, 3 * BLOCK * corner), builder.mul(axis, ir.Constant(i64, BLOCK)))
            p = builder.gep(data, [builder.add(base, column)])
            x = builder.load(builder.bitcast(p, stored.as_pointer()), align=4 if single else 8)
            return builder.fpext(x, d4) if single else x

        o = [splat(args[5]), splat(args[6]), splat(args[7])]
        shear_x, shear_y, shear_z = splat(args[8]), splat(args[9]), splat(args[10])
        # corners moved to the origin and permuted: p[corner] = (x, y, z) along (kx, ky, kz)
        p = [[builder.fsub(coordinate(k, args[2 + a]), o[a]) for a in range(3)] for k in range(3)]
        # shear: the ray becomes the +z axis through the origin
        a = [(builder.fsub(p[k][0], builder.fmul(shear_x, p[k][2])),
              builder.fsub(p[k][1], builder.fmul(shear_y, p[k][2]))) for k in range(3)]

        def edge(i, j):     # p_i x p_j in the sheared plane, as _edge_sign computes it
            return builder.fsub(builder.fmul(a[i][0], a[j][1]), builder.fmul(a[i][1], a[j][0]))

        u, v, w = edge(1, 2), edge(2, 0), edge(0, 1)
        zero = ir.Constant(d4, [0.0] * BLOCK)

        def all3(op):
            return builder.and_(builder.and_(builder.fcmp_ordered(op, u, zero), builder.fcmp_ordered(op, v, zero)),
                                builder.fcmp_ordered(op, w, zero))

        tie = builder.or_(builder.or_(builder.fcmp_ordered("==", u, zero), builder.fcmp_ordered("==", v, zero)),
                          builder.fcmp_ordered("==", w, zero))
        same_side = builder.or_(all3(">"), all3("<"))
        det = builder.fadd(builder.fadd(u, v), w)
        t = builder.fadd(builder.fadd(builder.fmul(u, p[0][2]), builder.fmul(v, p[1][2])), builder.fmul(w, p[2][2]))
        t = builder.fdiv(builder.fmul(t, shear_z), det)
        inside = builder.and_(builder.fcmp_ordered("<=", splat(args[11]), t),
                              builder.fcmp_ordered("<=", t, splat(args[12])))
        hit = builder.and_(builder.and_(same_side, builder.fcmp_ordered("!=", det, zero)), inside)
        builder.store(t, builder.bitcast(out.data, d4.as_pointer()), align=8)
        lanes = builder.zext(builder.bitcast(hit, ir.IntType(BLOCK)), i64)
        ties = builder.zext(builder.bitcast(tie, ir.IntType(BLOCK)), i64)
        return builder.or_(lanes, builder.shl(ties, ir.Constant(i64, BLOCK)))

    return sig, codegen

"""Blocks of four triangles (casting/triangles4.py) against the scalar watertight test.

hit4 must give, lane for lane, the scalar hit_sheared's answer bit for bit
wherever no edge function is zero, and flag the lanes where one is (the
caller gives those to the scalar test and its tie rule)."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from raykernel.casting.triangles4 import BLOCK, corner, hit4, leaf_blocks
from raykernel.geometry.primitives import INCLUSIVE, WATERTIGHT, hit_sheared, ray_shear


def _blocks(corners, first, count, prims=None):
    """leaf_blocks over triangles given by their corners: each its own three vertices."""
    n = len(corners)
    verts = np.ascontiguousarray(corners[:, :9].reshape(-1, 3))
    faces = np.arange(3 * n, dtype=np.int64).reshape(n, 3)
    return leaf_blocks(verts, faces, np.arange(n) if prims is None else prims, first, count)


@njit
def _block_test(blocks, b, o, d, tmin, tmax, t4):
    kx, ky, kz, sx, sy, sz = ray_shear(d[0], d[1], d[2])
    return hit4(blocks, b, kx, ky, kz, o[kx], o[ky], o[kz], sx, sy, sz, tmin, tmax, t4)


@njit
def _scalar(c, o, d, tmin, tmax, edges):
    kx, ky, kz, sx, sy, sz = ray_shear(d[0], d[1], d[2])
    return hit_sheared(c[kx] - o[kx], c[ky] - o[ky], c[kz] - o[kz], c[3 + kx] - o[kx], c[3 + ky] - o[ky],
                       c[3 + kz] - o[kz], c[6 + kx] - o[kx], c[6 + ky] - o[ky], c[6 + kz] - o[kz], sx, sy, sz,
                       tmin, tmax, edges)


def assert_lanes_agree(corners, origins, directions, tmin=0.0, tmax=np.inf):
    """Every ray against every block of `corners` (rows of v0, v1, v2, four per block): hit
    lanes and their t as the scalar test's under both edge rules, ties flagged. Returns how
    many lanes hit and how many were ties."""
    n = len(corners)
    blocks, _, _ = _blocks(corners, np.arange(0, n, BLOCK), np.minimum(BLOCK, n - np.arange(0, n, BLOCK)))
    t4 = np.empty(BLOCK)
    hits = ties = 0
    for o, d in zip(origins, directions):
        for b in range(len(blocks)):
            mask = _block_test(blocks, b, o, d, tmin, tmax, t4)
            for lane in range(min(BLOCK, n - BLOCK * b)):
                c = corners[BLOCK * b + lane]
                want = [_scalar(c, o, d, tmin, tmax, edges) for edges in (WATERTIGHT, INCLUSIVE)]
                if mask >> (BLOCK + lane) & 1:
                    ties += 1
                    continue
                if mask >> lane & 1:
                    hits += 1
                    assert want[0] == want[1] == t4[lane], (b, lane)
                else:
                    assert want[0] == want[1] == np.inf, (b, lane)
    return hits, ties


def test_random_triangles_and_rays():
    rng = np.random.default_rng(3)
    corners = rng.uniform(-1, 1, (23, 9))               # 23: the last block has three lanes
    o = rng.uniform(-3, 3, (150, 3))
    d = rng.uniform(-1, 1, (150, 3)) - 0.3 * o
    hits, ties = assert_lanes_agree(corners, o, d, 0.0, 5.0)
    assert hits > 30 and ties == 0


def test_rays_through_shared_edges_and_vertices_are_ties():
    """A grid of triangles with rays straight down through its vertices, edges and faces:
    the edge functions there are exactly zero, so those lanes go to the scalar test."""
    xs = np.arange(4.0)
    tris = []
    for i in range(3):
        for j in range(3):
            a, b, c, e = (xs[i], xs[j]), (xs[i + 1], xs[j]), (xs[i], xs[j + 1]), (xs[i + 1], xs[j + 1])
            tris += [[*a, 0, *b, 0, *e, 0], [*a, 0, *e, 0, *c, 0]]
    corners = np.array(tris, float)
    pts = np.array([(x, y) for x in np.arange(0, 3.25, 0.25) for y in np.arange(0, 3.25, 0.25)])
    o = np.c_[pts, np.full(len(pts), 2.0)]
    d = np.tile([0.0, 0.0, -1.0], (len(pts), 1))
    hits, ties = assert_lanes_agree(corners, o, d)
    assert ties > 0 and hits > 0


@pytest.mark.parametrize("scale, shift", [(1e-6, 0.0), (1e7, 0.0), (1.0, 1e7)])
def test_huge_and_tiny_scales(scale, shift):
    rng = np.random.default_rng(4)
    corners = rng.uniform(-1, 1, (16, 9)) * scale + shift
    o = rng.uniform(-3, 3, (100, 3)) * scale + shift
    d = (rng.uniform(-1, 1, (100, 3)) * 0.5 * scale + shift) - o
    hits, _ = assert_lanes_agree(corners, o, d)
    assert hits > 20


def test_grazing_rays_in_the_plane_of_a_face():
    corners = np.array([[0, 0, 0, 1, 0, 0, 0, 1, 0]] * 4, float) + np.arange(4)[:, None] * np.tile([1, 0, 0], 3)
    o = np.array([[-1.0, 0.25, 0.0], [-1.0, 0.0, 0.0], [0.25, -1.0, 1e-300]])
    d = np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    assert_lanes_agree(corners, o, d)


def test_leaf_blocks_layout():
    rng = np.random.default_rng(6)
    corners = rng.normal(size=(11, 9))
    first, count = np.array([0, 5, 6]), np.array([5, 1, 4])       # leaves of 5, 1 and 4 references
    blocks, lanes, start = _blocks(corners, first, count)
    assert blocks.shape == (4, 36) and start.tolist() == [0, 8, 12]
    assert lanes.tolist() == [0, 1, 2, 3, 4, -1, -1, -1, 5, -1, -1, -1, 6, 7, 8, 9]
    for ref, (block, lane) in {0: (0, 0), 3: (0, 3), 4: (1, 0), 5: (2, 0), 9: (3, 3)}.items():
        for column in range(9):
            assert blocks[block, column * BLOCK + lane] == corners[ref, column]
    for block in (1, 2):        # the lanes after a leaf's references: zero corners (made so, not found so)
        assert (blocks[block, [c * BLOCK + lane for c in range(9) for lane in (1, 2, 3)]] == 0).all()
    # corner() reads a triangle's coordinates from either form: block * 4 + lane, or its row
    for ref, slot in {0: 0, 3: 3, 4: 4, 5: 8, 9: 15}.items():
        assert [_corner(blocks, slot, i) for i in range(9)] == corners[ref, :9].tolist()
        assert [_corner(corners, ref, i) for i in range(9)] == corners[ref, :9].tolist()


def test_every_lane_of_a_leafs_blocks_is_written_whatever_the_memory_held():
    from raykernel.casting.triangles4 import COLUMNS, _fill_blocks
    rng = np.random.default_rng(7)
    verts, faces = rng.normal(size=(30, 3)), np.arange(30, dtype=np.int64).reshape(10, 3)
    first, count = np.array([0, 5, 6]), np.array([5, 1, 4])
    start = np.array([0, 8, 12, 16])        # each leaf's first lane, as leaf_blocks lays them out
    blocks = np.full((4, COLUMNS), np.nan)          # what np.empty may hand over
    lanes = np.full(16, 12345, np.int32)
    _fill_blocks(verts, faces, np.arange(10), first, count, start, blocks, lanes, 0, 3)
    assert lanes.tolist() == [0, 1, 2, 3, 4, -1, -1, -1, 5, -1, -1, -1, 6, 7, 8, 9]
    unused = [(1, lane) for lane in (1, 2, 3)] + [(2, lane) for lane in (1, 2, 3)]
    assert all((blocks[b, [c * BLOCK + lane for c in range(9)]] == 0).all() for b, lane in unused)
    assert not np.isnan(blocks).any()


@njit
def _corner(src, row, i):
    return corner(src, row, i)

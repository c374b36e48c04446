"""Early split clipping (aggregates/presplit.py, `bvh(split=N)`): the pieces cover their
primitives, stay inside their boxes, and a tree over them answers as the plain BVH does.
Hits against the brute-force list on random scenes are in test_nesting.py (its VARIANTS),
shared edges and vertices of closed meshes in test_watertight.py."""

from __future__ import annotations

import numpy as np
import pytest

import raykernel
from raykernel.aggregates.bvhbuild import build_bvh
from raykernel.aggregates.bvhtree import BVHArrays
from raykernel.aggregates.presplit import leaves_of_items, split_boxes
from raykernel.scene.specs import without_specs
from raykernel.errors import OptionError


def _points_on(poly: np.ndarray, rng, n: int) -> np.ndarray:
    """Points of a planar polygon (concave ones too): points of its bounding rectangle in its
    plane, kept where a crossing test puts them inside, plus its corners and edge midpoints."""
    origin, u = poly[0], poly[1] - poly[0]
    normal = np.cross(poly[1] - poly[0], poly[2] - poly[0])
    for k in range(3, len(poly)):
        if np.linalg.norm(normal) > 0:
            break
        normal = np.cross(poly[1] - poly[0], poly[k] - poly[0])
    u = u / np.linalg.norm(u)
    v = np.cross(normal / np.linalg.norm(normal), u)
    flat = np.c_[(poly - origin) @ u, (poly - origin) @ v]
    lo, hi = flat.min(axis=0), flat.max(axis=0)
    cand = lo + rng.uniform(size=(n, 2)) * (hi - lo)
    inside = np.zeros(n, bool)
    for i in range(len(flat)):
        a, b = flat[i], flat[(i + 1) % len(flat)]
        crosses = (a[1] > cand[:, 1]) != (b[1] > cand[:, 1])
        x = a[0] + (cand[:, 1] - a[1]) * (b[0] - a[0]) / np.where(b[1] != a[1], b[1] - a[1], 1.0)
        inside ^= crosses & (cand[:, 0] < x)
    pts = origin + cand[inside, :1] * u + cand[inside, 1:] * v
    mids = 0.5 * (poly + np.roll(poly, -1, axis=0))
    return np.vstack([pts, poly, mids])


def _star(rng, k=7, scale=1.0, shift=0.0):
    """A concave star polygon tilted across the axes."""
    a = np.linspace(0, 2 * np.pi, 2 * k, endpoint=False)
    r = np.where(np.arange(2 * k) % 2, 0.35, 1.0)
    flat = np.c_[r * np.cos(a), r * np.sin(a), np.zeros(2 * k)]
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return shift + scale * flat @ q.T


@pytest.mark.parametrize("scale", [1e-6, 1.0, 1e7])
@pytest.mark.parametrize("pieces", [2, 8, 64])
def test_pieces_cover_their_polygons_and_stay_in_their_boxes(scale, pieces):
    rng = np.random.default_rng(int(np.log10(scale)) + 11 * pieces)
    polys = [_star(rng, scale=scale, shift=scale * 3.0) for _ in range(4)]
    polys += [scale * np.array([[0, 0, 0], [1, 1, 1], [1, 0.9, 0.95]]) for _ in range(2)]    # a sliver across the axes
    polys += [scale * np.array([[0, 0, 0], [1, 0, 0], [1, 2, 0], [0, 2, 0]])]               # along the axes
    verts = np.vstack(polys)
    count = np.array([len(p) for p in polys] + [0])       # the last item: no outline (a sphere)
    start = np.r_[0, np.cumsum(count)[:-1]]
    boxes = np.array([np.r_[p.min(axis=0), p.max(axis=0)] for p in polys] + [[-1, -1, -1, 1, 1, 1]])
    item, box = split_boxes(verts, start, count, boxes, pieces)
    assert np.array_equal(np.unique(item), np.arange(len(boxes)))       # every item, in order
    assert np.all(np.diff(item) >= 0)
    per_item = np.bincount(item)
    assert per_item.max() <= pieces and per_item[-1] == 1 and per_item[-2] == 1     # whole: sphere, rectangle
    assert per_item[4] >= min(pieces, 8)         # the sliver: cut while its pieces stay long and thin
    assert np.all(box[:, :3] >= boxes[item, :3]) and np.all(box[:, 3:] <= boxes[item, 3:])
    tol = 1e-12 * scale
    for i, p in enumerate(polys):
        mine = box[item == i]
        pts = _points_on(p, rng, 400)
        covered = np.any(np.all((pts[:, None, :] >= mine[None, :, :3] - tol) &
                                (pts[:, None, :] <= mine[None, :, 3:] + tol), axis=2), axis=1)
        assert covered.all(), f"polygon {i}: {np.sum(~covered)} points in no piece's box"
    # the pieces' boxes add up to less surface than the whole's where they were cut
    area = lambda b: 2 * ((b[:, 3] - b[:, 0]) * (b[:, 4] - b[:, 1]) + (b[:, 4] - b[:, 1]) * (b[:, 5] - b[:, 2])
                          + (b[:, 5] - b[:, 2]) * (b[:, 3] - b[:, 0]))
    assert area(box[item == 4]).sum() < 0.75 * area(boxes[4:5]).sum()


def test_a_leaf_holds_each_item_once():
    # 6 pieces of 3 items, all in one leaf: each item once there
    piece_item = np.array([0, 0, 1, 1, 2, 2])
    bounds = np.array([[0, 0, 0, 1, 1, 1]] * 6, float)
    tree, _ = build_bvh(bounds, leaf_size=8)
    assert tree.count[0] == 6
    out = leaves_of_items(tree, piece_item)
    assert isinstance(out, BVHArrays) and out.count[0] == 3 and sorted(out.order.tolist()) == [0, 1, 2]
    # one piece a leaf: every piece's item kept, each in its own leaf
    tree, _ = build_bvh(np.array([[i, 0, 0, i + 1, 1, 1] for i in range(6)], float), leaf_size=1)
    out = leaves_of_items(tree, piece_item)
    leaves = out.count > 0
    assert out.count[leaves].sum() == 6 and np.array_equal(np.sort(out.order), np.sort(piece_item))


def test_the_diamond_renders_the_same_with_fewer_tests():
    scene = without_specs(raykernel.load("scene:diamond:facets=200"))
    plain = raykernel.render(scene, accel="bvh", resolution=48, spd=True)
    split = raykernel.render(scene, accel="bvh(split=16)", resolution=48, spd=True)
    assert split.image.tobytes() == plain.image.tobytes()
    assert all(split.stats[k] == plain.stats[k] for k in plain.stats if k.startswith("rays."))
    assert split.stats["tests.per_ray"] < 0.5 * plain.stats["tests.per_ray"]
    assert split.stats["build.refs"] > plain.stats["build.refs"]


def test_split_is_a_checked_parameter():
    scene = raykernel.load("spd:balls:1")
    for bad in ("bvh(split=0)", "bvh(split=65)", "bvh(split=two)"):
        with pytest.raises(OptionError, match="split"):
            raykernel.render(scene, accel=bad, resolution=8)

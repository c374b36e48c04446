"""Goldsmith-Salmon BVH: structure, insertion orders, quality against the SAH build, traversal, renders."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from support import box_area, fill_group_large, new_scene, rays_outside_and_inside, same_arrays

from raykernel.aggregates.bvhbuild import build_bvh
from raykernel.aggregates.bvhtree import BVHArrays, is_leaf
from raykernel.aggregates.bvhwalk import CODE as BVH
from raykernel.aggregates.gsbvh import MAX_DEPTH, ORDERS, build_gs, insertion_order, morton_codes
from raykernel.engine.flatten import flatten
from raykernel.engine.traverse import cast_rays
from raykernel.errors import OptionError
from raykernel.scene import Group
from raykernel.aggregates.registry import parse_spec

EMPTY_BOX = np.array([np.inf, np.inf, np.inf, -np.inf, -np.inf, -np.inf])


# ---------------------------------------------------------------- helpers

def random_boxes(rng, n, size=0.02, span=1.0):
    lo = rng.random((n, 3)) * span
    return np.hstack([lo, lo + rng.random((n, 3)) * size])


def built(items, *args, **kw):
    """build_gs(items, ...) and the wall-clock seconds measured around the call."""
    t0 = time.perf_counter()
    bvh, stats = build_gs(items, *args, **kw)
    return bvh, stats, time.perf_counter() - t0


def check_tree(bvh, stats, items, wall=None):
    """The layout's invariants for a tree with one item per leaf; the statistics (if given) those of
    the tree, built in `wall` seconds."""
    items = np.asarray(items, np.float64).reshape(-1, 6)
    n = len(items)
    bounds, first, count, order = bvh
    m = len(count)
    assert isinstance(bvh, BVHArrays)
    assert bounds.dtype == np.float64 and bounds.shape == (m, 6)
    assert first.dtype == count.dtype == order.dtype == np.int64
    assert np.array_equal(np.sort(order), np.arange(n))
    leaf = (count > 0) | (first <= np.arange(m))
    assert np.array_equal(is_leaf(bvh), leaf)
    inner = np.flatnonzero(~leaf)
    leaves = np.flatnonzero(leaf)
    depth = np.zeros(m, np.int64)
    for i in inner:
        depth[first[i]] = depth[first[i] + 1] = depth[i] + 1
    if n == 0:
        assert m == 1 and count[0] == 0 and first[0] == 0 and np.array_equal(bounds[0], EMPTY_BOX)
    else:
        assert m == 2 * n - 1
        left = first[inner]
        assert np.all(count[inner] == 0) and np.all(left > inner) and np.all(left + 1 < m)
        assert np.array_equal(np.sort(np.concatenate([left, left + 1])), np.arange(1, m))
        union = np.hstack([np.minimum(bounds[left, :3], bounds[left + 1, :3]),
                           np.maximum(bounds[left, 3:], bounds[left + 1, 3:])])
        assert np.array_equal(bounds[inner], union)
        assert np.all(count[leaves] == 1)
        assert np.array_equal(np.sort(first[leaves]), np.arange(n))
        assert np.array_equal(bounds[leaves], items[order[first[leaves]]])
    if stats is not None:
        assert stats["nodes"] == m and stats["inner"] == len(inner) and stats["leaves"] == len(leaves)
        assert stats["empty_leaves"] == int(n == 0) and stats["refs"] == n
        assert stats["bytes"] == sum(a.nbytes for a in bvh)
        assert stats["max_depth"] == int(depth.max()) <= MAX_DEPTH
        assert 0.0 < stats["seconds"] <= wall


def sah_cost(bvh):
    area = box_area(bvh.bounds)
    leaf = is_leaf(bvh)
    return float((area * np.where(leaf, bvh.count, 1.0)).sum() / area[0])


def chain_cost(items):
    """SAH cost of the list-order chain: each item hung beside everything inserted before it."""
    lo = np.minimum.accumulate(items[:, :3])
    hi = np.maximum.accumulate(items[:, 3:])
    prefix = box_area(np.hstack([lo, hi]))
    return float((prefix[1:].sum() + box_area(items).sum()) / prefix[-1])


# ---------------------------------------------------------------- structure

@pytest.mark.parametrize("order", ORDERS)
@pytest.mark.parametrize("kind", ["uniform", "clustered", "slivers", "mixed"])
def test_structure_on_random_scenes(order, kind):
    rng = np.random.default_rng(len(kind))
    n = 2000
    if kind == "uniform":
        items = random_boxes(rng, n)
    elif kind == "clustered":
        c = rng.random((6, 3))[rng.integers(0, 6, n)] * 100 + rng.normal(0, 0.5, (n, 3))
        items = np.hstack([c - 0.01, c + 0.01])
    elif kind == "slivers":
        lo = rng.random((n, 3))
        ext = np.zeros((n, 3))
        ext[np.arange(n), rng.integers(0, 3, n)] = rng.random(n) * 10
        items = np.hstack([lo, lo + ext])
    else:
        items = random_boxes(rng, n, size=1.0) * rng.choice([1e-3, 1.0, 1e3], (n, 1))
    bvh, stats, wall = built(items, order, seed=3)
    check_tree(bvh, stats, items, wall)
    assert stats["order"] == order


@pytest.mark.parametrize("n", [0, 1, 2, 3, 17])
def test_small_inputs(n):
    items = random_boxes(np.random.default_rng(n), n)
    bvh, stats, wall = built(items, "shuffle")
    check_tree(bvh, stats, items, wall)
    if n == 1:
        assert stats["nodes"] == 1 and bvh.count[0] == 1
        assert np.array_equal(bvh.bounds[0], items[0])


@pytest.mark.parametrize("items", [
    np.tile([[1.0, 2.0, 3.0, 1.5, 2.5, 3.0]], (1000, 1)),                      # identical boxes
    np.hstack([np.random.default_rng(1).random((1000, 3))] * 2),                # points: all areas zero
    np.column_stack([np.arange(1024.0), np.zeros((1024, 2)), np.arange(1024.0), np.zeros((1024, 2))]),
], ids=["identical", "points", "collinear"])
def test_degenerate_input_stays_balanced(items):
    for order in ORDERS:
        bvh, stats, wall = built(items, order)
        check_tree(bvh, stats, items, wall)
        assert stats["max_depth"] <= 3 * math.ceil(math.log2(len(items)))


def test_depth_guard_on_nested_boxes():
    """Boxes around one centre, inserted from small to large, would make a chain 100 deep."""
    r = np.arange(1, 201, dtype=np.float64)[:, None]
    items = np.hstack([-r * np.ones(3), r * np.ones(3)])
    bvh, stats, wall = built(items, "file")
    check_tree(bvh, stats, items, wall)
    assert stats["max_depth"] == MAX_DEPTH
    _, small = build_gs(items, "file", max_depth=12)
    assert small["max_depth"] <= 12
    with pytest.raises(OptionError):
        build_gs(items, max_depth=5)


@pytest.mark.parametrize("magnitude", [1e-300, 1e300, 1.5e308])
def test_extreme_magnitudes(magnitude):
    rng = np.random.default_rng(4)
    c = (rng.random((300, 3)) * 2 - 1) * magnitude
    items = np.hstack([c, c + np.abs(c) * 0.1])
    bvh, stats, wall = built(items, "shuffle")
    check_tree(bvh, stats, items, wall)
    assert stats["max_depth"] <= 40


def test_deterministic_for_a_seed_and_input_untouched():
    items = random_boxes(np.random.default_rng(5), 3000)
    copy = items.copy()
    for order in ORDERS:
        a, _ = build_gs(items, order, seed=7)
        b, _ = build_gs(items, order, seed=7)
        assert same_arrays(a, b)
    assert np.array_equal(items, copy)


def test_seeds_give_different_trees():
    items = random_boxes(np.random.default_rng(6), 3000)
    a, _ = build_gs(items, "shuffle", seed=1)
    b, _ = build_gs(items, "shuffle", seed=2)
    assert not same_arrays(a, b)
    check_tree(b, None, items)
    # the seed means nothing to the other orders
    assert same_arrays(build_gs(items, "file", seed=1)[0], build_gs(items, "file", seed=2)[0])


def test_insertion_orders():
    items = random_boxes(np.random.default_rng(8), 500)
    assert np.array_equal(insertion_order(items, "file", 1), np.arange(500))
    shuffled = insertion_order(items, "shuffle", 1)
    assert np.array_equal(np.sort(shuffled), np.arange(500)) and not np.array_equal(shuffled, np.arange(500))
    curve = insertion_order(items, "curve", 1)
    codes = morton_codes(items)
    assert np.all(np.diff(codes[curve].astype(np.float64)) >= 0)
    # Morton order interleaves x, y, z bits: x is the lowest bit
    corners = np.array([[x, y, z] * 2 for z in (0, 1) for y in (0, 1) for x in (0, 1)], np.float64)
    assert morton_codes(corners).tolist() == [0] + [int("111" * 21, 2) // 7 * k for k in range(1, 8)]
    with pytest.raises(OptionError):
        build_gs(items, "random")


def test_file_order_is_the_given_order():
    """A file-order tree depends on the order of the boxes; shuffling the input changes it."""
    items = random_boxes(np.random.default_rng(9), 1000)
    a, _ = build_gs(items, "file")
    b, _ = build_gs(items[::-1].copy(), "file")
    assert not np.array_equal(a.first, b.first) or not np.array_equal(a.order, b.order[::-1])


# ---------------------------------------------------------------- quality

@pytest.mark.parametrize("order", ["file", "shuffle"])
def test_cost_near_binned_sah_and_far_below_a_chain(order):
    rng = np.random.default_rng(10)
    items = random_boxes(rng, 10000, size=0.02)
    gs, _ = build_gs(items, order)
    sah, _ = build_bvh(items, leaf_size=1)
    assert sah_cost(gs) < 2.0 * sah_cost(sah)
    assert sah_cost(gs) < 0.01 * chain_cost(items)


def test_curve_order_is_sane():
    items = random_boxes(np.random.default_rng(11), 10000, size=0.02)
    gs, stats = build_gs(items, "curve")
    sah, _ = build_bvh(items, leaf_size=1)
    assert sah_cost(gs) < 5.0 * sah_cost(sah)
    assert sah_cost(gs) < 0.05 * chain_cost(items)


# ---------------------------------------------------------------- accelerator spec and flatten

def test_spec_parameters():
    assert parse_spec("bvh")[1] == {"leaf": 4, "bins": 16, "block": 1, "build": "sah", "order": "file", "seed": 1,
                                    "optimize": "none", "corners": 1, "split": 1, "width": 4, "precision": "double"}
    assert parse_spec("bvh(build=gs, order=curve, seed=9)")[1]["order"] == "curve"
    assert parse_spec("bvh(corners=0)")[1]["corners"] == 0
    assert parse_spec("bvh(width=2)")[1]["width"] == 2
    assert parse_spec("bvh(block=4)")[1]["block"] == 4
    assert parse_spec("bvh(split=16)")[1]["split"] == 16
    assert parse_spec("bvh(precision=single)")[1]["precision"] == "single"
    for bad in ("bvh(precision=float32)", "bvh(build=gsx)", "bvh(order=zorder)", "bvh(seed=-1)", "bvh(width=8)", "bvh(width=3)", "bvh(block=0)", "bvh(corners=2)",
                "bvh(block=17)"):
        with pytest.raises(OptionError):
            parse_spec(bad)


def test_flatten_uses_the_gs_build():
    scene = new_scene()
    fill_group_large(scene.root, np.random.default_rng(12))
    geo, stats = flatten(scene, default_accel="bvh(build=gs, order=shuffle, seed=4)")
    assert geo.agg_kind[geo.root] == BVH
    agg = stats["aggregates"][0]
    assert agg["kind"] == "bvh(build=gs, order=shuffle, seed=4)" and agg["order"] == "shuffle"
    n = agg["items"]
    assert agg["nodes"] == 2 * n - 1 == stats["build.nodes"] and agg["refs"] == n


@pytest.mark.parametrize("order", ORDERS)
@pytest.mark.parametrize("seed", [0, 1])
def test_cast_rays_match_list(order, seed):
    rng = np.random.default_rng(100 + seed)
    scene = new_scene()
    fill_group_large(scene.root, rng)
    inner = fill_group_large(Group(name="inner", accel=f"bvh(build=gs, order={order})"), rng, n=12, spread=2.0)
    scene.root.add(inner)
    o, d = rays_outside_and_inside(rng, 2000)
    ref = cast_rays(flatten(scene, "list")[0], o, d)
    assert np.isfinite(ref[0]).sum() > 300
    got = cast_rays(flatten(scene, f"bvh(build=gs, order={order}, seed={seed})")[0], o, d)
    for a, b in zip(got[:4], ref[:4]):
        np.testing.assert_array_equal(a, b)
    shadow = cast_rays(flatten(scene, f"bvh(build=gs, order={order})")[0], o, d, tmax=0.5, any_hit=True)
    np.testing.assert_array_equal(np.isfinite(shadow[0]),
                                  np.isfinite(cast_rays(flatten(scene, "list")[0], o, d, tmax=0.5)[0]))



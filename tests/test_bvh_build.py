"""Binned-SAH BVH builder: structure, degenerate inputs, refit, quality, traversal."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from support import box_area, same_arrays

from raykernel.aggregates.bvhbuild import FEW_BINS, FEW_BINS_ITEMS, FEWEST_BINS, FEWEST_BINS_ITEMS, build_bvh, refit
from raykernel.aggregates.bvhtree import BVHArrays, is_leaf
from raykernel.errors import OptionError

EMPTY_BOX = np.array([np.inf, np.inf, np.inf, -np.inf, -np.inf, -np.inf])


# ---------------------------------------------------------------- helpers


def random_boxes(rng, n, size=0.01, span=1.0):
    lo = rng.random((n, 3)) * span
    return np.hstack([lo, lo + rng.random((n, 3)) * size])


def leaf_mask(bvh):
    """Leaves by the documented rule, computed here independently of is_leaf."""
    idx = np.arange(bvh.count.size)
    return (bvh.count > 0) | (bvh.first <= idx)


def node_depths(bvh):
    depth = np.zeros(bvh.count.size, dtype=np.int64)
    leaf = leaf_mask(bvh)
    for i in range(bvh.count.size):  # parents come before their children
        if not leaf[i]:
            depth[bvh.first[i]] = depth[bvh.first[i] + 1] = depth[i] + 1
    return depth


def built(items, **options):
    """build_bvh(items, **options) and the wall-clock seconds measured around the call."""
    t0 = time.perf_counter()
    bvh, stats = build_bvh(items, **options)
    return bvh, stats, time.perf_counter() - t0


def check_tree(bvh, stats, items, leaf_size, wall=None):
    """Every structural invariant of the layout; items are the boxes the node boxes must fit. The
    statistics (if given) must be those of the tree, built in `wall` seconds (see built)."""
    items = np.asarray(items, dtype=np.float64).reshape(-1, 6)
    n = items.shape[0]
    bounds, first, count, order = bvh
    n_nodes = count.size
    assert isinstance(bvh, BVHArrays)
    assert bounds.dtype == np.float64 and bounds.shape == (n_nodes, 6)
    assert first.dtype == np.int64 and first.shape == (n_nodes,)
    assert count.dtype == np.int64 and order.dtype == np.int64
    assert all(a.flags.c_contiguous for a in bvh)
    assert np.all(count >= 0)

    # each item exactly once
    assert order.shape == (n,)
    assert np.array_equal(np.sort(order), np.arange(n))

    leaf = leaf_mask(bvh)
    assert np.array_equal(is_leaf(bvh), leaf)
    inner = np.nonzero(~leaf)[0]
    leaves = np.nonzero(leaf)[0]

    # inner nodes: adjacent children after the parent, every non-root node has one parent
    left = first[inner]
    assert np.all(count[inner] == 0)
    assert np.all(left > inner)
    assert np.all(left + 1 < n_nodes)
    assert np.array_equal(np.sort(np.concatenate([left, left + 1])), np.arange(1, n_nodes))
    lb, rb = bounds[left], bounds[left + 1]
    union = np.hstack([np.minimum(lb[:, :3], rb[:, :3]), np.maximum(lb[:, 3:], rb[:, 3:])])
    assert np.array_equal(bounds[inner], union)

    if n == 0:
        assert n_nodes == 1 and leaf[0] and count[0] == 0 and first[0] == 0
        assert np.array_equal(bounds[0], EMPTY_BOX)
    else:
        # leaves hold 1..leaf_size items and their ranges tile order exactly
        assert np.all(count[leaves] >= 1)
        assert np.all(count[leaves] <= leaf_size)
        by_start = leaves[np.argsort(first[leaves], kind="stable")]
        starts = first[by_start]
        ends = starts + count[by_start]
        assert starts[0] == 0 and ends[-1] == n
        assert np.array_equal(starts[1:], ends[:-1])
        # leaf boxes contain their items and are their exact union
        item_boxes = items[order]
        owner = np.repeat(by_start, count[by_start])
        assert np.all(bounds[owner, :3] <= item_boxes[:, :3])
        assert np.all(bounds[owner, 3:] >= item_boxes[:, 3:])
        assert np.array_equal(bounds[by_start, :3], np.minimum.reduceat(item_boxes[:, :3], starts))
        assert np.array_equal(bounds[by_start, 3:], np.maximum.reduceat(item_boxes[:, 3:], starts))

    if stats is not None:
        assert stats["nodes"] == n_nodes
        assert stats["inner"] == inner.size
        assert stats["leaves"] == leaves.size
        assert stats["empty_leaves"] == int(np.count_nonzero(count[leaves] == 0))
        assert stats["refs"] == int(count[leaves].sum()) == n
        assert stats["bytes"] == sum(a.nbytes for a in bvh)
        assert stats["max_depth"] == int(node_depths(bvh).max())
        assert 0.0 < stats["seconds"] <= wall


def tree_sah_cost(bvh, ct=1.0, ci=1.0):
    area = box_area(bvh.bounds)
    cost = np.where(leaf_mask(bvh), bvh.count * ci, ct)
    return float((area * cost).sum() / area[0])


def median_split_sah_cost(items, leaf_size, axis=0, ct=1.0, ci=1.0):
    """SAH cost of a tree that always splits at the centroid median along one fixed axis."""

    def union_area(idx):
        b = items[idx]
        return float(box_area(np.concatenate([b[:, :3].min(0), b[:, 3:].max(0)])))

    root_area = union_area(np.arange(len(items)))
    total = 0.0
    stack = [np.arange(len(items))]
    while stack:
        idx = stack.pop()
        area = union_area(idx)
        if idx.size <= leaf_size:
            total += area * idx.size * ci
            continue
        total += area * ct
        srt = idx[np.argsort(items[idx, axis] + items[idx, axis + 3], kind="stable")]
        half = srt.size // 2
        stack += [srt[:half], srt[half:]]
    return total / root_area


def ray_hits_box(o, d, box):
    t0, t1 = 0.0, math.inf
    for k in range(3):
        lo, hi = box[k], box[k + 3]
        if d[k] == 0.0:
            if o[k] < lo or o[k] > hi:
                return False
            continue
        inv = 1.0 / d[k]
        tn, tf = (lo - o[k]) * inv, (hi - o[k]) * inv
        if inv < 0.0:
            tn, tf = tf, tn
        t0, t1 = max(t0, tn), min(t1, tf)
        if t0 > t1:
            return False
    return True


def walk(bvh, items, o, d):
    """Items whose boxes the ray hits, visiting a child only when the ray hits its box."""
    boxes = np.asarray(items, dtype=np.float64).reshape(-1, 6).tolist()
    found, stack = set(), [0]
    bounds, first, count, order = (a.tolist() for a in bvh)
    while stack:
        node = stack.pop()
        if not ray_hits_box(o, d, bounds[node]):
            continue
        if count[node] > 0 or first[node] <= node:
            found.update(i for i in order[first[node]:first[node] + count[node]] if ray_hits_box(o, d, boxes[i]))
        else:
            stack += [first[node], first[node] + 1]
    return found


# ---------------------------------------------------------------- property tests

lattice_rows = st.lists(
    st.tuples(*[st.integers(-3, 3)] * 3, *[st.sampled_from([0, 0, 1, 2, 5])] * 3), max_size=60
)


@settings(max_examples=150, deadline=None)
@given(
    rows=lattice_rows,
    scale=st.sampled_from([1.0, 0.37, 1e-12, 1e12]),
    leaf_size=st.integers(1, 6),
    bins=st.integers(2, 24),
)
def test_lattice_boxes_property(rows, scale, leaf_size, bins):
    """Integer lattices give many coincident centroids, flat boxes and points."""
    arr = np.array(rows, dtype=np.float64).reshape(-1, 6)
    items = np.hstack([arr[:, :3] * scale, arr[:, :3] * scale + arr[:, 3:] * (0.5 * scale)])
    bvh, stats, wall = built(items, leaf_size=leaf_size, bins=bins)
    check_tree(bvh, stats, items, leaf_size, wall)
    moved = items[::-1].copy()
    refit(bvh, moved)
    check_tree(bvh, None, moved, leaf_size)


finite = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False)
extent = st.one_of(st.just(0.0), st.floats(0.0, 1e4, allow_nan=False, allow_infinity=False))


@settings(max_examples=100, deadline=None)
@given(
    rows=st.lists(st.tuples(finite, finite, finite, extent, extent, extent), min_size=0, max_size=50),
    leaf_size=st.integers(1, 5),
    traversal_cost=st.sampled_from([0.0, 0.125, 1.0, 10.0]),
    block=st.sampled_from([1, 4]),
)
def test_float_boxes_property(rows, leaf_size, traversal_cost, block):
    arr = np.array(rows, dtype=np.float64).reshape(-1, 6)
    items = np.hstack([arr[:, :3], arr[:, :3] + arr[:, 3:]])
    bvh, stats, wall = built(items, leaf_size=leaf_size, traversal_cost=traversal_cost, block=block)
    check_tree(bvh, stats, items, leaf_size, wall)


def test_leaves_priced_in_blocks_fill_them():
    """block=4 counts items in blocks of four: leaves of 1-3 items cost as much as leaves of
    four, so the tree keeps fuller leaves and fewer nodes, within the same leaf size."""
    rng = np.random.default_rng(5)
    items = random_boxes(rng, 4000)
    one, _ = build_bvh(items, leaf_size=4)
    four, stats, wall = built(items, leaf_size=4, block=4)
    check_tree(four, stats, items, 4, wall)
    mean = [b.count[b.count > 0].mean() for b in (one, four)]
    assert mean[1] > mean[0] + 0.5 and len(four.count) < len(one.count)


@pytest.mark.parametrize("block", [1, 4])
def test_unit_weights_give_the_unweighted_tree_bit_for_bit(block):
    items = random_boxes(np.random.default_rng(8), 3000)
    plain, _ = build_bvh(items, leaf_size=4, block=block)
    weighed, _ = build_bvh(items, leaf_size=4, block=block, weights=np.ones(len(items)))
    assert all(np.array_equal(a, b) for a, b in zip(plain, weighed))


def test_a_heavy_item_gets_a_leaf_of_its_own():
    """Items in a row, four to a leaf unweighted; weighed 40 times the others, one of them is
    split off into a leaf alone (testing it costs as much as testing 40 neighbours)."""
    x = np.arange(64, dtype=np.float64)
    items = np.column_stack([x, np.zeros(64), np.zeros(64), x + 0.9, np.ones(64), np.ones(64)])
    heavy = 21
    weights = np.ones(64)
    weights[heavy] = 40.0

    def leaf_of(tree):
        leaves = np.flatnonzero(leaf_mask(tree) & (tree.count > 0))
        return next(tree.count[i] for i in leaves if heavy in tree.order[tree.first[i]:tree.first[i] + tree.count[i]])

    plain, _ = build_bvh(items, leaf_size=4, traversal_cost=2.0)
    weighed, stats, wall = built(items, leaf_size=4, traversal_cost=2.0, weights=weights)
    check_tree(weighed, stats, items, 4, wall)
    assert leaf_of(plain) == 4 and leaf_of(weighed) == 1


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("kind", ["uniform", "clustered", "slivers", "mixed_sizes"])
def test_random_scenes_fixed_seeds(seed, kind):
    rng = np.random.default_rng(seed)
    n = 3000
    if kind == "uniform":
        items = random_boxes(rng, n)
    elif kind == "clustered":
        centres = rng.random((8, 3)) * 100
        c = centres[rng.integers(0, 8, n)] + rng.normal(0, 0.5, (n, 3))
        items = np.hstack([c - 0.01, c + 0.01])
    elif kind == "slivers":
        lo = rng.random((n, 3))
        ext = np.zeros((n, 3))
        ext[np.arange(n), rng.integers(0, 3, n)] = rng.random(n) * 10
        items = np.hstack([lo, lo + ext])
    else:
        items = random_boxes(rng, n, size=1.0) * rng.choice([1e-3, 1.0, 1e3], (n, 1))
    leaf_size = int(rng.integers(1, 9))
    bvh, stats, wall = built(items, leaf_size=leaf_size, bins=int(rng.choice([2, 8, 16, 64])))
    check_tree(bvh, stats, items, leaf_size, wall)
    assert stats["max_depth"] <= 4 * math.log2(n)


# ---------------------------------------------------------------- edge cases


@pytest.mark.parametrize("empty", [np.empty((0, 6)), [], np.empty((0, 6), dtype=np.float32)])
def test_no_items_is_one_empty_leaf(empty):
    bvh, stats, wall = built(empty)
    check_tree(bvh, stats, np.empty((0, 6)), 4, wall)
    assert stats == dict(stats, nodes=1, inner=0, leaves=1, empty_leaves=1, refs=0, max_depth=0)
    assert bvh.order.shape == (0,)
    # the empty box is missed by every ray, including axis-parallel ones
    rng = np.random.default_rng(5)
    for d in [*rng.normal(size=(20, 3)), (1.0, 0.0, 0.0), (0.0, 0.0, -1.0)]:
        assert not ray_hits_box(rng.normal(size=3), d, bvh.bounds[0])
    assert walk(bvh, np.empty((0, 6)), (0.0, 0.0, 0.0), (1.0, 1.0, 1.0)) == set()
    refit(bvh, np.empty((0, 6)))
    assert np.array_equal(bvh.bounds[0], EMPTY_BOX)


def test_one_item():
    item = [[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]]
    bvh, stats, wall = built(item)
    check_tree(bvh, stats, item, 4, wall)
    assert stats["nodes"] == 1 and bvh.count[0] == 1 and bvh.first[0] == 0
    assert bvh.bounds[0].tolist() == item[0]


def test_two_items():
    far = [[0, 0, 0, 1, 1, 1], [100, 0, 0, 101, 1, 1]]
    bvh, stats, wall = built(far)
    check_tree(bvh, stats, far, 4, wall)
    assert stats["nodes"] == 3 and bvh.first[0] == 1  # splitting two distant boxes is cheaper
    assert sorted(bvh.count[1:].tolist()) == [1, 1]
    same = [[0, 0, 0, 1, 1, 1]] * 2
    bvh, stats, wall = built(same)
    check_tree(bvh, stats, same, 4, wall)
    assert stats["nodes"] == 1 and bvh.count[0] == 2


@pytest.mark.parametrize("leaf_size", [1, 4, 7])
def test_identical_boxes_still_give_small_leaves(leaf_size):
    items = np.tile([[1.0, 2.0, 3.0, 1.5, 2.5, 3.0]], (1000, 1))
    bvh, stats, wall = built(items, leaf_size=leaf_size)
    check_tree(bvh, stats, items, leaf_size, wall)
    assert bvh.count[leaf_mask(bvh)].max() <= leaf_size
    assert stats["max_depth"] <= math.ceil(math.log2(1000 / leaf_size)) + 1  # middle splits: balanced


def test_nested_boxes_with_one_centre():
    r = np.arange(1, 101, dtype=np.float64)[:, None]
    items = np.hstack([-r * np.ones(3), r * np.ones(3)])
    bvh, stats, wall = built(items, leaf_size=3)
    check_tree(bvh, stats, items, 3, wall)


def test_flat_boxes():
    rng = np.random.default_rng(7)
    xy = rng.random((2000, 2))
    one_plane = np.column_stack([xy, np.zeros(2000), xy + rng.random((2000, 2)) * 0.01, np.zeros(2000)])
    z = rng.integers(0, 5, 2000).astype(float)
    many_planes = one_plane.copy()
    many_planes[:, 2] = many_planes[:, 5] = z
    for items in (one_plane, many_planes):
        bvh, stats, wall = built(items)
        check_tree(bvh, stats, items, 4, wall)
        assert stats["max_depth"] <= 3 * math.log2(2000)
        assert tree_sah_cost(bvh) < median_split_sah_cost(items, 4)


def test_points():
    rng = np.random.default_rng(8)
    p = rng.random((2000, 3))
    items = np.hstack([p, p])
    bvh, stats, wall = built(items)
    check_tree(bvh, stats, items, 4, wall)
    assert stats["max_depth"] <= 3 * math.log2(2000)


def test_collinear_points_split_in_balance():
    """Zero-area parents fall back to the half-perimeter, which favours balanced splits."""
    x = np.arange(1024, dtype=np.float64)
    items = np.column_stack([x, np.zeros(1024), np.zeros(1024), x, np.zeros(1024), np.zeros(1024)])
    bvh, stats, wall = built(items, leaf_size=4)
    check_tree(bvh, stats, items, 4, wall)
    assert stats["max_depth"] <= 12


def test_mixed_scales():
    rng = np.random.default_rng(9)
    tiny = random_boxes(rng, 500, size=1e-12, span=1e-9)
    huge = random_boxes(rng, 500, size=1e12, span=1e13)
    tiny_far = random_boxes(rng, 200, size=1e-12, span=1.0) + 1e12
    items = np.vstack([tiny, huge, tiny_far])
    rng.shuffle(items)
    bvh, stats, wall = built(items, leaf_size=2)
    check_tree(bvh, stats, items, 2, wall)
    assert stats["max_depth"] <= 4 * math.log2(items.shape[0])


@pytest.mark.parametrize("magnitude", [1e307, 1.5e308, 1e-310])
def test_extreme_magnitudes(magnitude):
    """Centroid extents that overflow (inf) or whose bin scale overflows fall back to middle splits."""
    rng = np.random.default_rng(10)
    c = (rng.random((300, 3)) * 2 - 1) * magnitude
    items = np.hstack([c, c + np.abs(c) * rng.choice([0.0, 0.1], (300, 1))])
    bvh, stats, wall = built(items, leaf_size=3)
    check_tree(bvh, stats, items, 3, wall)


def test_float32_and_integer_input():
    rng = np.random.default_rng(11)
    items32 = random_boxes(rng, 1000).astype(np.float32)
    bvh32, stats, wall = built(items32)
    assert bvh32.bounds.dtype == np.float64
    check_tree(bvh32, stats, items32.astype(np.float64), 4, wall)
    bvh64, _ = build_bvh(items32.astype(np.float64))
    assert same_arrays(bvh32, bvh64)
    ints = rng.integers(0, 50, (300, 3))
    bvh, stats, wall = built(np.hstack([ints, ints + 1]))
    check_tree(bvh, stats, np.hstack([ints, ints + 1]), 4, wall)


def test_deterministic_and_input_untouched():
    rng = np.random.default_rng(12)
    items = random_boxes(rng, 5000)
    copy = items.copy()
    a, _ = build_bvh(items)
    b, _ = build_bvh(items)
    assert same_arrays(a, b)
    assert np.array_equal(items, copy)


@pytest.mark.parametrize(
    "bad",
    [
        np.zeros((3, 5)),
        np.zeros(6),
        np.array([[0, 0, 0, 1, 1, np.nan]]),
        np.array([[0, 0, 0, 1, 1, np.inf]]),
        np.array([[0, 0, 2, 1, 1, 1.0]]),
        np.array([["a"] * 6]),
    ],
)
def test_rejects_bad_bounds(bad):
    with pytest.raises(ValueError):
        build_bvh(bad)


@pytest.mark.parametrize(
    "options",
    [
        dict(leaf_size=0),
        dict(leaf_size=2.5),
        dict(leaf_size=True),
        dict(bins=1),
        dict(bins=100000),
        dict(traversal_cost=-1.0),
        dict(intersection_cost=0.0),
        dict(intersection_cost=float("nan")),
        dict(traversal_cost="x"),
        dict(block=0),
        dict(block=2.0),
        dict(weights=[1.0]),
        dict(weights=[1.0, 0.0]),
        dict(weights=[1.0, -2.0]),
        dict(weights=[1.0, float("nan")]),
        dict(weights=[1.0, float("inf")]),
    ],
)
def test_rejects_bad_options(options):
    with pytest.raises(OptionError):
        build_bvh(np.zeros((2, 6)), **options)


# ---------------------------------------------------------------- refit


def test_refit_after_moving_items():
    rng = np.random.default_rng(13)
    items = random_boxes(rng, 4000, size=0.02)
    bvh, stats = build_bvh(items, leaf_size=3)
    original = bvh.bounds.copy()
    inner = ~leaf_mask(bvh)
    assert np.all(bvh.first[inner] > np.nonzero(inner)[0])  # the reverse-loop layout property

    moved = items + rng.normal(0, 0.2, (4000, 1)) * np.array([1, 1, 1, 1, 1, 1])
    moved[:, 3:] += rng.random((4000, 3)) * 0.3  # items also grow
    topology = (bvh.first.copy(), bvh.count.copy(), bvh.order.copy())
    refit(bvh, moved)
    check_tree(bvh, None, moved, 3)
    assert not np.array_equal(bvh.bounds, original)
    assert all(np.array_equal(x, y) for x, y in zip(topology, bvh[1:]))

    refit(bvh, items.astype(np.float64))
    assert np.array_equal(bvh.bounds, original)


def test_refit_rejects_mismatched_items():
    bvh, _ = build_bvh(random_boxes(np.random.default_rng(14), 10))
    with pytest.raises(ValueError):
        refit(bvh, np.zeros((9, 6)))


# ---------------------------------------------------------------- quality and usability


def test_sah_beats_median_split():
    rng = np.random.default_rng(15)
    items = random_boxes(rng, 10000, size=0.02)
    bvh, stats = build_bvh(items, leaf_size=4)
    sah = tree_sah_cost(bvh)
    fixed_axis = median_split_sah_cost(items, 4, axis=0)
    assert sah < 0.2 * fixed_axis
    assert sah < min(median_split_sah_cost(items, 4, axis=a) for a in (1, 2))


def binned_split_costs(items, bins, block=1):
    """Every boundary between non-empty bins of `bins` equal centroid bins on every axis with a
    centroid extent (the builder's rule): the summed child cost, brute force."""
    centre = 0.5 * items[:, :3] + 0.5 * items[:, 3:]
    lo, ext = centre.min(0), centre.max(0) - centre.min(0)
    costs = []
    for a in range(3):
        if ext[a] == 0:
            continue
        b = np.minimum(((centre[:, a] - lo[a]) * (bins / ext[a])).astype(int), bins - 1)
        for j in np.unique(b)[1:]:
            sides = np.flatnonzero(b < j), np.flatnonzero(b >= j)
            costs.append(sum(float(box_area(np.concatenate([items[s, :3].min(0), items[s, 3:].max(0)])))
                             * math.ceil(len(s) / block) for s in sides))
    return costs


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("n, bins", [(5, FEWEST_BINS), (FEWEST_BINS_ITEMS, FEWEST_BINS),
                                     (FEWEST_BINS_ITEMS + 1, FEW_BINS), (40, FEW_BINS), (FEW_BINS_ITEMS, FEW_BINS)])
def test_a_node_of_few_items_bins_into_few_bins(seed, n, bins):
    rng = np.random.default_rng(seed)
    items = random_boxes(rng, n, size=0.05)
    bvh, _ = build_bvh(items, leaf_size=1, bins=16)
    chosen = sum(box_area(bvh.bounds[c]) * bvh_items(bvh, c).size for c in (bvh.first[0], bvh.first[0] + 1))
    assert chosen == pytest.approx(min(binned_split_costs(items, bins)), rel=1e-12)


def bvh_items(bvh, node):
    """The items under node."""
    if bvh.count[node] > 0:
        return bvh.order[bvh.first[node]:bvh.first[node] + bvh.count[node]]
    return np.concatenate([bvh_items(bvh, bvh.first[node]), bvh_items(bvh, bvh.first[node] + 1)])


def test_traversal_finds_exactly_the_boxes_a_ray_hits():
    rng = np.random.default_rng(16)
    items = random_boxes(rng, 500, size=0.15)
    items[:50, 5] = items[:50, 2]  # some flat boxes
    bvh, stats, wall = built(items, leaf_size=3)
    check_tree(bvh, stats, items, 3, wall)
    boxes = items.tolist()
    origins = rng.random((200, 3)) * 3 - 1
    targets = rng.random((200, 3))
    origins[:20, 1:] = targets[:20, 1:]  # rays parallel to the x axis
    origins[20:40, 2] = targets[20:40, 2]  # rays parallel to the xy plane
    dirs = targets - origins
    dirs[40:50] *= -1.0  # rays pointing away: hits only when the origin is inside a box
    total = 0
    for o, d in zip(origins.tolist(), dirs.tolist()):
        brute = {i for i, b in enumerate(boxes) if ray_hits_box(o, d, b)}
        assert walk(bvh, items, o, d) == brute
        total += len(brute)
    assert total > 400


def test_many_cornered_polygons_weighed_keep_the_hits_and_walk_fewer_corners():
    """Stars of 40 corners among quads: weighed by their corners (the default), the BVH finds
    the same hits as the brute-force list and as the unweighed tree, and its tests walk fewer
    corners."""
    from raykernel import RayScene, Scene
    rng = np.random.default_rng(4)
    scene = Scene()
    for k in range(300):
        c = rng.uniform(-2, 2, 3)
        if k % 10 == 0:
            a = np.linspace(0, 2 * math.pi, 40, endpoint=False)
            r = np.where(np.arange(40) % 2 == 0, 1.0, 0.5)
            scene.root.polygons.add(c + np.column_stack([r * np.cos(a), r * np.sin(a), np.zeros(40)]))
        else:
            scene.root.polygons.add(c + 0.3 * np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0.2], [0, 1, 0.2]]))
    origins = np.column_stack([rng.uniform(-6, 6, 4000), rng.uniform(-6, 6, 4000), np.full(4000, 9.0)])
    directions = np.column_stack([rng.uniform(-3, 3, 4000), rng.uniform(-3, 3, 4000), np.full(4000, -9.0)]) - \
        origins * np.array([1, 1, 0])
    runs = {}
    for spec in ("list", "bvh", "bvh(corners=0)", "bvh(width=2)"):
        rs = RayScene(scene, spec)
        hits = rs.intersect(origins, directions)
        runs[spec] = (hits.t, hits.prim_id, rs.last_stats["polygon.corners"])
    assert np.isfinite(runs["list"][0]).sum() > 300
    for spec in ("bvh", "bvh(corners=0)", "bvh(width=2)"):
        assert np.array_equal(runs[spec][0], runs["list"][0]) and np.array_equal(runs[spec][1], runs["list"][1])
    assert runs["bvh"][2] < runs["bvh(corners=0)"][2]


@pytest.mark.slow
def test_million_items_build_time():
    items = random_boxes(np.random.default_rng(17), 1_000_000)
    build_bvh(items[:1000])
    bvh, stats, wall = built(items)
    assert 0.0 < stats["seconds"] <= wall < 15.0
    assert stats["refs"] == 1_000_000 and np.array_equal(np.sort(bvh.order), np.arange(1_000_000))

"""Ray classification aggregate: builder, beam test, traversal against list and bvh, nesting, budget, renders."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import raykernel
from raykernel import counters as C
from raykernel.accel import parse_spec
from raykernel.aggregates.rc import NODE_BYTES, RcBudgetWarning, build_rc, face_of, meets_beam
from raykernel.errors import OptionError
from raykernel.flatten import RC, flatten
from raykernel.scene import Group, Instance
from raykernel.traverse import cast_rays
from test_grid import (assert_same_hits, axis_and_boundary_rays, cast, fill_group, lattice_scene, nested_scene,
                       new_scene, random_rays, rotation_scale)

RC_SPECS = ["rc", "rc(leaf=2, depth=30)", "rc(leaf=1, depth=6)", "rc(depth=0)"]
TESTS = slice(C.TESTS, C.TESTS + 5)


def random_boxes(rng, n=60):
    lo = rng.uniform(-5, 5, (n, 3))
    return np.hstack([lo, lo + rng.uniform(0, 1.5, (n, 3))])


def slab(box, o, d):
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = (box[:3] - o) / d
        t1 = (box[3:] - o) / d
    tn = np.nanmax(np.minimum(t0, t1))
    tf = np.nanmin(np.maximum(t0, t1))
    return max(tn, 0.0), tf


def leaf_of(tree, o, d):
    """The leaf a ray reaches, classified in Python as the kernel does."""
    te, tf = slab(tree.box, o, d)
    if te > tf:
        return None
    face, u, v = face_of(d)
    q = np.concatenate([o + te * d, [u, v]])
    node = tree.face_root[face]
    while tree.node_b[node] < 0:
        dim = -tree.node_b[node] - 1
        node = tree.node_a[node] + (0 if q[dim] < tree.split[node] else 1)
    return node


# ---------------------------------------------------------------- builder

def test_candidate_lists_hold_every_item_a_ray_of_the_hypercube_can_reach():
    rng = np.random.default_rng(1)
    boxes = random_boxes(rng)
    tree, stats = build_rc(boxes, leaf=4, depth=16)
    assert stats["nodes"] == len(tree.node_a) > 6 and stats["max_depth"] > 5
    for _ in range(2000):
        o = rng.uniform(-8, 8, 3)
        d = rng.normal(size=3)
        node = leaf_of(tree, o, d)
        if node is None:
            continue
        s, n = tree.node_a[node], tree.node_b[node]
        held = set(tree.items[s:s + n].tolist())
        assert np.all(np.diff(tree.keys[s:s + n]) >= 0)
        for i in range(len(boxes)):
            t0, t1 = slab(boxes[i], o, d)
            if t0 <= t1:
                assert i in held


def test_beam_test_is_exact_up_to_the_margin():
    # the beam of origins in the unit cube, directions +x with u, v in [0, 0.5]
    lo = np.array([0.0, 0.0, 0.0, 0.0, 0.0])
    hi = np.array([1.0, 1.0, 1.0, 0.5, 0.5])
    boxes = np.array([[3, 0, 0, 4, 1, 1],           # straight ahead
                      [-3, 0, 0, -2, 1, 1],         # behind
                      [3, 2.4, 0, 4, 3, 1],         # reachable: y up to 1 + 0.5 * 4 = 3
                      [3, 3.1, 0, 4, 4, 1],         # just out of reach
                      [3, -2, 0, 4, -0.1, 1],       # below, u >= 0 cannot go down
                      [0.5, 0.5, 0.5, 0.6, 0.6, 0.6]], np.float64)   # inside the origin box
    got = [meets_beam(boxes, i, lo, hi, 0) for i in range(len(boxes))]
    assert got == [True, False, True, False, False, True]
    # the same beam looking along -x sees the box behind instead
    got = [meets_beam(boxes, i, lo, hi, 1) for i in range(len(boxes))]
    assert got[:2] == [False, True] and got[5]


def test_face_classification_ties_go_to_the_lower_axis():
    assert face_of([1, 1, 0]) == (0, 1.0, 0.0)
    assert face_of([-1, -1, -1]) == (1, -1.0, -1.0)
    assert face_of([0, 2, -2]) == (2, -1.0, 0.0)
    assert face_of([0, 0, -3]) == (5, 0.0, 0.0)


def test_stats_are_consistent():
    boxes = random_boxes(np.random.default_rng(2), 80)
    tree, stats = build_rc(boxes, leaf=4, depth=12)
    leaves = tree.node_b >= 0
    assert stats["leaves"] == leaves.sum() and stats["inner"] == (~leaves).sum()
    assert stats["nodes"] == stats["leaves"] + stats["inner"] == 6 + 2 * stats["inner"]
    assert stats["empty_leaves"] == (tree.node_b == 0).sum()
    assert stats["refs"] == tree.node_b[leaves].sum() == len(tree.items) == len(tree.keys)
    assert stats["bytes"] == NODE_BYTES * stats["nodes"] + 16 * stats["refs"]
    assert stats["seconds"] >= 0 and not stats["budget_exceeded"]
    # children come after their parents, leaf lists tile the candidate array
    inner = np.flatnonzero(~leaves)
    assert np.all(tree.node_a[inner] > inner)
    order = np.argsort(tree.node_a[leaves])
    starts, counts = tree.node_a[leaves][order], tree.node_b[leaves][order]
    assert starts[0] == 0 and np.all(starts[1:] == starts[:-1] + counts[:-1])
    # a deeper tree never holds more candidates per leaf than leaf, unless it ran out of depth or progress
    again, stats2 = build_rc(boxes, leaf=4, depth=12)
    assert all(np.array_equal(x, y) for x, y in zip(tree, again))


def test_flatten_stores_rc_and_reports_stats():
    scene = new_scene()
    fill_group(scene.root, np.random.default_rng(2))
    geo, stats = flatten(scene, default_accel="rc(leaf=4)")
    assert geo.agg_kind[geo.root] == RC
    agg = stats["aggregates"][0]
    assert agg["kind"] == "rc(leaf=4)"
    assert stats["build.nodes"] == agg["nodes"] == len(geo.rc_node_a)
    assert stats["build.refs"] == agg["refs"] == len(geo.rc_key) == len(geo.refs)
    assert agg["empty_leaves"] == stats["build.empty_leaves"]
    assert agg["bytes"] > 0 and agg["seconds"] >= 0


@pytest.mark.parametrize("spec, allowed", [("rc(leaf=0)", "leaf"), ("rc(depth=-1)", "depth"),
                                           ("rc(depth=500)", "depth"), ("rc(budget_mb=-1)", "budget_mb"),
                                           ("rc(budget_mb=lots)", "budget_mb"),
                                           ("rc(cells=3)", "leaf, depth, budget_mb")])
def test_bad_parameters_are_option_errors(spec, allowed):
    with pytest.raises(OptionError, match=allowed):
        parse_spec(spec)


def test_bad_builder_arguments_are_option_errors():
    boxes = random_boxes(np.random.default_rng(0), 5)
    for kw in ({"leaf": 0}, {"depth": -2}, {"budget_mb": float("nan")}, {"leaf": 2.5}):
        with pytest.raises(OptionError):
            build_rc(boxes, **kw)


def test_rc_is_listed_with_its_help():
    text = raykernel.accel.describe()
    assert "rc: ray classification" in text and "budget_mb=256.0" in text


# ---------------------------------------------------------------- traversal against bvh and list

@pytest.mark.parametrize("spec", RC_SPECS)
@pytest.mark.parametrize("seed", [0, 1])
def test_random_scenes_match_bvh_and_list(spec, seed):
    rng = np.random.default_rng(seed)
    scene = new_scene()
    fill_group(scene.root, rng, n=25, big=seed == 1)
    o, d = random_rays(rng, 1500)
    oi, di = random_rays(rng, 500, inside=True)
    o, d = np.vstack([o, oi]), np.vstack([d, di])
    ref = cast(scene, "list", o, d)
    assert np.isfinite(ref[0]).sum() > 200
    assert_same_hits(cast(scene, "bvh", o, d), ref)
    got = cast(scene, spec, o, d)
    assert_same_hits(got, ref)
    cnt = got[4]
    assert cnt[C.CELLS_LEAVES] > 0 and cnt[C.CELLS_VISITED] >= cnt[C.CELLS_LEAVES] >= cnt[C.CELLS_EMPTY]
    assert cnt[TESTS].sum() < ref[4][TESTS].sum()
    shadow = cast(scene, spec, o, d, tmax=0.5, any_hit=True)
    np.testing.assert_array_equal(np.isfinite(shadow[0]), np.isfinite(cast(scene, "list", o, d, tmax=0.5)[0]))
    tmin = cast(scene, spec, o, d, tmin=0.3)
    assert_same_hits(tmin, cast(scene, "list", o, d, tmin=0.3))


def face_boundary_rays(rng, n=400):
    """Directions on the edges and corners of the direction cube, from outside and inside."""
    dirs = np.array([[1, 1, 0], [1, -1, 0], [-1, 1, 0], [0, 1, 1], [0, -1, 1], [1, 0, 1], [-1, 0, -1],
                     [1, 1, 1], [-1, -1, 1], [1, -1, -1], [1, 0, 0], [0, -1, 0], [0, 0, 1],
                     [2, 1, 0], [1, 2, -2]], np.float64)
    d = dirs[rng.integers(0, len(dirs), n)] * rng.uniform(0.5, 3.0, (n, 1))
    o = np.where(rng.uniform(size=(n, 1)) < 0.5, rng.uniform(-4, 4, (n, 3)), -d * 6.0 + rng.uniform(-3, 3, (n, 3)))
    return o, d


@pytest.mark.parametrize("spec", ["rc", "rc(leaf=1, depth=25)"])
def test_axis_parallel_and_face_boundary_rays(spec):
    scene = lattice_scene()
    o, d = axis_and_boundary_rays()
    ob, db = face_boundary_rays(np.random.default_rng(3))
    o, d = np.vstack([o, ob]), np.vstack([d, db])
    ref = cast(scene, "list", o, d)
    assert np.isfinite(ref[0]).sum() > 100
    assert_same_hits(cast(scene, spec, o, d), ref)
    assert_same_hits(cast(scene, "bvh", o, d), ref)
    rng = np.random.default_rng(4)
    mixed = new_scene()
    fill_group(mixed.root, rng, n=20)
    o, d = face_boundary_rays(rng, 1500)
    ref = cast(mixed, "list", o, d)
    assert np.isfinite(ref[0]).sum() > 100
    assert_same_hits(cast(mixed, spec, o, d), ref)


def test_early_exit_stops_at_the_first_hit():
    scene = new_scene()
    for x in range(40):
        scene.root.spheres.add((x, 0, 0), 0.3, 0)
    geo, _ = flatten(scene, default_accel="rc(depth=0)")
    t, kind, index, _, cnt = cast_rays(geo, [[-5.0, 0, 0], [45.0, 0, 0]], [[1.0, 0, 0], [-1.0, 0, 0]])
    assert index.tolist() == [0, 39] and t[0] == pytest.approx(4.7) and t[1] == pytest.approx(5.7)
    # the lists hold all 40 spheres, sorted near first: a handful of tests each
    assert cnt[TESTS].sum() <= 6
    assert cnt[C.CELLS_VISITED] == cnt[C.CELLS_LEAVES] == 2


def test_one_item_empty_groups_and_misses():
    scene = new_scene()
    scene.root.spheres.add((1, 2, 3), 1.0, 0)
    scene.root.add(Group(name="empty", accel="rc"))
    o = np.array([[1, 2, -5.0], [1, 2, 3.0], [5, 5, 5.0], [-9, -9, -9.0]])
    d = np.array([[0, 0, 1.0], [0, 1, 0.0], [1, 0, 0.0], [-1, 0, 0.0]])
    t, *_, cnt = cast(scene, "rc", o, d)
    assert t[0] == pytest.approx(7.0) and t[1] == pytest.approx(1.0) and np.isinf(t[2:]).all()
    empty = new_scene()
    empty.root.accel = "rc"
    assert np.all(np.isinf(cast(empty, "rc", o, d)[0]))


def test_planar_and_huge_extent_scenes():
    rng = np.random.default_rng(5)
    flat = new_scene()
    for _ in range(40):
        c = np.append(rng.uniform(-4, 4, 2), 1.0)
        flat.root.polygons.add([c, c + [1, 0, 0], c + [0.5, 1, 0]], 0)
    o, d = random_rays(rng, 1000, spread=4.0)
    ref = cast(flat, "list", o, d)
    assert np.isfinite(ref[0]).sum() > 20
    assert_same_hits(cast(flat, "rc", o, d), ref)
    huge = new_scene()
    fill_group(huge.root, rng, n=20, spread=2.0)
    huge.root.spheres.add((1e9, 3e8, -2e8), 1e7, 0)
    o, d = random_rays(rng, 1500, spread=2.0)
    o = np.vstack([o, np.zeros((2, 3))])
    d = np.vstack([d, [[1e9, 3e8, -2e8], [1e9, 3e8 + 5e6, -2e8]]])
    ref = cast(huge, "list", o, d)
    assert np.isfinite(ref[0][-2:]).all()
    assert_same_hits(cast(huge, "rc", o, d), ref)


# ---------------------------------------------------------------- nesting

@pytest.mark.parametrize("outer, inner, instanced", [
    ("rc", "bvh", False), ("bvh", "rc", False), ("rc", "rc", False), ("grid", "rc", False),
    ("rc", "grid", True), ("rc", "rc(leaf=2)", True), ("bvh", "rc", True), ("list", "rc", True)])
def test_nested_rc_matches_list(outer, inner, instanced):
    rng = np.random.default_rng(7)
    scene = nested_scene(rng, outer, inner, instanced)
    o, d = random_rays(rng, 1500)
    oi, di = random_rays(rng, 300, inside=True)
    o, d = np.vstack([o, oi]), np.vstack([d, di])
    got = cast(scene, "bvh", o, d)
    plain = nested_scene(np.random.default_rng(7), "list", "list", instanced)
    ref = cast(plain, "list", o, d)
    assert np.isfinite(ref[0]).sum() > 300
    assert_same_hits(got, ref)
    if instanced:
        assert np.any(ref[3] >= 0)


def test_rc_inside_instances_deep():
    rng = np.random.default_rng(11)
    leaf = fill_group(Group(name="leaf", accel="rc"), rng, n=10, spread=1.0)
    level = leaf
    for k in range(4):
        up = Group(name=f"l{k}", accel="rc" if k % 2 else "bvh")
        up.add(Instance(level, rotation_scale(rng)))
        up.add(Instance(level, rotation_scale(rng)))
        level = up
    scene = new_scene()
    scene.root.accel = "rc"
    scene.root.add(level)
    o, d = random_rays(rng, 2000, spread=12.0)
    ref = cast(scene, "list", o, d)
    assert np.isfinite(ref[0]).sum() > 50
    assert_same_hits(cast(scene, "rc", o, d), ref)


# ---------------------------------------------------------------- memory budget

def test_tiny_budget_warns_once_and_stays_exact():
    rng = np.random.default_rng(8)
    scene = new_scene()
    fill_group(scene.root, rng, n=25)
    o, d = random_rays(rng, 1500)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        geo, stats = flatten(scene, default_accel="rc(budget_mb=0.01)")
    budget = [w for w in caught if issubclass(w.category, RcBudgetWarning)]
    assert len(budget) == 1 and "memory budget of 0.01 MiB" in str(budget[0].message)
    agg = stats["aggregates"][0]
    assert agg["budget_exceeded"] and agg["bytes"] <= 0.01 * 2 ** 20
    assert_same_hits(cast_rays(geo, o, d), cast(scene, "list", o, d))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _, full = flatten(scene, default_accel="rc")
    assert not full["aggregates"][0]["budget_exceeded"] and full["build.nodes"] > stats["build.nodes"]


def test_zero_budget_keeps_the_roots():
    boxes = random_boxes(np.random.default_rng(9), 30)
    with pytest.warns(RcBudgetWarning, match="budget"):
        tree, stats = build_rc(boxes, budget_mb=0)
    assert stats["nodes"] == 6 and stats["refs"] == 6 * 30 and stats["budget_exceeded"]


# ---------------------------------------------------------------- renders

def test_spd_render_matches_bvh():
    scene = raykernel.load("spd:balls:1")
    bvh = raykernel.render(scene, accel="bvh", resolution=32, spd=True)
    rc = raykernel.render(scene, accel="rc", resolution=32, spd=True)
    np.testing.assert_array_equal(rc.image, bvh.image)
    rays = {k: v for k, v in bvh.stats.items() if k.startswith("rays.") and k != "rays.per_second"}
    assert rays and {k: rc.stats[k] for k in rays} == rays
    assert rc.stats["cells.visited"] > 0

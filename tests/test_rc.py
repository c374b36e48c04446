"""Ray classification aggregate, eager and lazy: builder, beam test, traversal against list and bvh,
lazy refinement where rays arrive (nested and instanced too), budget, renders. Every kind nested in
and around rc, and at one and two threads, is checked in test_nesting.py."""

from __future__ import annotations

import time
import warnings

import numpy as np
import pytest
from support import (
    assert_same_hits,
    axis_and_boundary_rays,
    cast_grown,
    fill_group,
    lattice_scene,
    nested_scene,
    new_scene,
    random_rays,
    ray_counts,
    same_hits_as_list,
)

import raykernel
from raykernel import RayScene
from raykernel.aggregates.lazyset import PASS_CHUNKS
from raykernel.aggregates.rcbuild import NODE_BYTES, RcBudgetWarning, build_rc, face_of, meets_beam, start_rc
from raykernel.aggregates.rclazy import VIRTUAL_LEVELS, LazyRC
from raykernel.casting.rayqueries import CHUNK
from raykernel.aggregates.rc import CODE as RC
from raykernel.engine.flatten import flatten
from raykernel.engine.traverse import cast_rays
from raykernel.errors import OptionError
from raykernel.geometry import counters as C
from raykernel.scene import Group
from raykernel.aggregates.registry import parse_spec

# lazy (the default) and eager alike
RC_SPECS = ["rc", "rc(lazy=off)", "rc(leaf=2, depth=30)", "rc(leaf=2, depth=30, lazy=off)", "rc(leaf=1, depth=6, rays=3)",
            "rc(leaf=1, depth=6, lazy=off)", "rc(depth=0)", "rc(depth=0, lazy=off)"]
TESTS = slice(C.TESTS, C.TESTS + 5)
PASS = PASS_CHUNKS * CHUNK          # rays of one RayScene pass


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
    t0 = time.perf_counter()
    tree, stats = build_rc(boxes, leaf=4, depth=12)
    wall = time.perf_counter() - t0
    leaves = tree.node_b >= 0
    assert stats["leaves"] == leaves.sum() and stats["inner"] == (~leaves).sum()
    assert stats["nodes"] == stats["leaves"] + stats["inner"] == 6 + 2 * stats["inner"]
    assert stats["empty_leaves"] == (tree.node_b == 0).sum()
    assert stats["refs"] == tree.node_b[leaves].sum() == len(tree.items) == len(tree.keys)
    assert stats["bytes"] == NODE_BYTES * stats["nodes"] + 16 * stats["refs"]
    assert 0.0 < stats["seconds"] <= wall and not stats["budget_exceeded"]
    # children come after their parents, leaf lists tile the candidate array
    inner = np.flatnonzero(~leaves)
    assert np.all(tree.node_a[inner] > inner)
    order = np.argsort(tree.node_a[leaves])
    starts, counts = tree.node_a[leaves][order], tree.node_b[leaves][order]
    assert starts[0] == 0 and np.all(starts[1:] == starts[:-1] + counts[:-1])
    # the same boxes build the same trees
    again, _ = build_rc(boxes, leaf=4, depth=12)
    assert all(np.array_equal(x, y) for x, y in zip(tree, again))


@pytest.mark.parametrize("spec", ["rc(leaf=4)", "rc(leaf=4, lazy=off)"])
def test_flatten_stores_rc_and_reports_stats(spec):
    scene = new_scene()
    fill_group(scene.root, np.random.default_rng(2))
    t0 = time.perf_counter()
    geo, stats = flatten(scene, default_accel=spec)
    wall = time.perf_counter() - t0
    assert geo.agg_kind[geo.root] == RC
    agg = stats["aggregates"][0]
    assert agg["kind"] == spec
    assert stats["build.nodes"] == agg["nodes"] == len(geo.rc_node_a) == len(geo.rc_pass)
    assert stats["build.refs"] == agg["refs"] == len(geo.keyed_key) == len(geo.keyed_ref)
    assert agg["empty_leaves"] == stats["build.empty_leaves"]
    assert agg["bytes"] > 0 and 0.0 < agg["seconds"] <= stats["build.seconds"] <= wall
    # the candidates are the tagged references of the group's primitives, as the list holds them
    listed, _ = flatten(scene, default_accel="list")
    assert set(geo.keyed_ref.tolist()) == set(listed.refs.tolist()) and len(listed.refs) == agg["items"]


@pytest.mark.parametrize("spec, allowed", [("rc(leaf=0)", "leaf"), ("rc(depth=-1)", "depth"),
                                           ("rc(depth=500)", "depth"), ("rc(budget_mb=-1)", "budget_mb"),
                                           ("rc(budget_mb=lots)", "budget_mb"),
                                           ("rc(lazy=maybe)", "lazy must be on or off"),
                                           ("rc(rays=0)", "rays must be an integer in \\[1, "),
                                           ("rc(rays=1.5)", "rays must be an integer"),
                                           ("rc(cells=3)", "leaf, depth, budget_mb, lazy, rays")])
def test_bad_parameters_are_option_errors(spec, allowed):
    with pytest.raises(OptionError, match=allowed):
        parse_spec(spec)


def test_bad_builder_arguments_are_option_errors():
    boxes = random_boxes(np.random.default_rng(0), 5)
    for kw in ({"leaf": 0}, {"depth": -2}, {"budget_mb": float("nan")}, {"leaf": 2.5}):
        with pytest.raises(OptionError):
            build_rc(boxes, **kw)
        with pytest.raises(OptionError):
            start_rc(boxes, **kw)
    for rays in (0, 2.0, True):
        with pytest.raises(OptionError, match="rc rays must be"):
            start_rc(boxes, rays=rays)


def test_rc_is_listed_with_its_help():
    text = raykernel.aggregates.registry.describe()
    assert "rc: ray classification" in text and "budget_mb=256.0" in text
    assert "lazy=on" in text and "rays=1" in text
    assert parse_spec("rc") == ("rc", {"leaf": 8, "depth": 40, "budget_mb": 256.0, "lazy": True, "rays": 1})


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
    ref = cast_grown(scene, "list", o, d)
    assert np.isfinite(ref[0]).sum() > 200
    assert_same_hits(cast_grown(scene, "bvh", o, d), ref)
    got = cast_grown(scene, spec, o, d)
    assert_same_hits(got, ref)
    cnt = got[4]
    assert cnt[C.CELLS_LEAVES] > 0 and cnt[C.CELLS_VISITED] >= cnt[C.CELLS_LEAVES] >= cnt[C.CELLS_EMPTY]
    assert cnt[TESTS].sum() < ref[4][TESTS].sum()
    shadow = cast_grown(scene, spec, o, d, tmax=0.5, any_hit=True)
    np.testing.assert_array_equal(np.isfinite(shadow[0]), np.isfinite(cast_grown(scene, "list", o, d, tmax=0.5)[0]))
    tmin = cast_grown(scene, spec, o, d, tmin=0.3)
    assert_same_hits(tmin, cast_grown(scene, "list", o, d, tmin=0.3))


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
    ref = cast_grown(scene, "list", o, d)
    assert np.isfinite(ref[0]).sum() > 100
    assert_same_hits(cast_grown(scene, spec, o, d), ref)
    assert_same_hits(cast_grown(scene, "bvh", o, d), ref)
    rng = np.random.default_rng(4)
    mixed = new_scene()
    fill_group(mixed.root, rng, n=20)
    o, d = face_boundary_rays(rng, 1500)
    ref = cast_grown(mixed, "list", o, d)
    assert np.isfinite(ref[0]).sum() > 100
    assert_same_hits(cast_grown(mixed, spec, o, d), ref)


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
    t, *_, cnt = cast_grown(scene, "rc", o, d)
    assert t[0] == pytest.approx(7.0) and t[1] == pytest.approx(1.0) and np.isinf(t[2:]).all()
    empty = new_scene()
    empty.root.accel = "rc"
    assert np.all(np.isinf(cast_grown(empty, "rc", o, d)[0]))


def test_planar_and_huge_extent_scenes():
    rng = np.random.default_rng(5)
    flat = new_scene()
    for _ in range(40):
        c = np.append(rng.uniform(-4, 4, 2), 1.0)
        flat.root.polygons.add([c, c + [1, 0, 0], c + [0.5, 1, 0]], 0)
    o, d = random_rays(rng, 1000, spread=4.0)
    ref = cast_grown(flat, "list", o, d)
    assert np.isfinite(ref[0]).sum() > 20
    assert_same_hits(cast_grown(flat, "rc", o, d), ref)
    huge = new_scene()
    fill_group(huge.root, rng, n=20, spread=2.0)
    huge.root.spheres.add((1e9, 3e8, -2e8), 1e7, 0)
    o, d = random_rays(rng, 1500, spread=2.0)
    o = np.vstack([o, np.zeros((2, 3))])
    d = np.vstack([d, [[1e9, 3e8, -2e8], [1e9, 3e8 + 5e6, -2e8]]])
    ref = cast_grown(huge, "list", o, d)
    assert np.isfinite(ref[0][-2:]).all()
    assert_same_hits(cast_grown(huge, "rc", o, d), ref)


# ---------------------------------------------------------------- memory budget

def test_tiny_budget_warns_once_and_stays_exact():
    rng = np.random.default_rng(8)
    scene = new_scene()
    fill_group(scene.root, rng, n=25)
    o, d = random_rays(rng, 1500)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        geo, stats = flatten(scene, default_accel="rc(budget_mb=0.01, lazy=off)")
    budget = [w for w in caught if issubclass(w.category, RcBudgetWarning)]
    assert len(budget) == 1 and "memory budget of 0.01 MiB" in str(budget[0].message)
    agg = stats["aggregates"][0]
    assert agg["budget_exceeded"] and agg["bytes"] <= 0.01 * 2 ** 20
    assert_same_hits(cast_rays(geo, o, d), cast_grown(scene, "list", o, d))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _, full = flatten(scene, default_accel="rc(lazy=off)")
    assert not full["aggregates"][0]["budget_exceeded"] and full["build.nodes"] > stats["build.nodes"]


def test_zero_budget_keeps_the_roots():
    boxes = random_boxes(np.random.default_rng(9), 30)
    with pytest.warns(RcBudgetWarning, match="budget"):
        tree, stats = build_rc(boxes, budget_mb=0)
    assert stats["nodes"] == 6 and stats["refs"] == 6 * 30 and stats["budget_exceeded"]
    with pytest.warns(RcBudgetWarning, match="budget"):
        tree, stats, _, _ = start_rc(boxes, budget_mb=0)
    assert stats["nodes"] == 6 and stats["refs"] == 6 * 30 and stats["budget_exceeded"]


# ---------------------------------------------------------------- lazy subdivision (Arvo and Kirk)

def sphere_cloud(n=150, seed=20, spread=4.0, radius=0.3):
    rng = np.random.default_rng(seed)
    scene = new_scene()
    centres = rng.uniform(-spread, spread, (n, 3))
    for c in centres:
        scene.root.spheres.add(c, radius, 0)
    return scene, np.hstack([centres - radius, centres + radius])


def tree_of(geo, box, rc=0):
    """Node arrays of rc aggregate `rc` as an RcArrays-like namespace for leaf_of (candidates as sphere
    indices), with the depth of every node reachable from the face roots."""
    from types import SimpleNamespace

    from raykernel.geometry.primitives import INDEX_MASK
    depth = {}
    for f in range(6):
        todo = [(int(geo.rc_face_root[rc, f]), 0)]
        while todo:
            node, k = todo.pop()
            depth[node] = k
            if geo.rc_node_b[node] < 0:
                todo += [(int(geo.rc_node_a[node]), k + 1), (int(geo.rc_node_a[node]) + 1, k + 1)]
    return SimpleNamespace(box=box, face_root=geo.rc_face_root[rc], node_a=geo.rc_node_a, node_b=geo.rc_node_b,
                           split=geo.rc_split, items=geo.keyed_ref & INDEX_MASK, keys=geo.keyed_key, depth=depth)


def root_box(bounds):
    from raykernel.aggregates.grid import grid_box
    origin, extent = grid_box(bounds)
    return np.concatenate([origin, origin + extent])


def visits(tree, o, d):
    """How many of the rays (origins inside the box) pass each node on their way to a leaf."""
    out = {}
    for oi, di in zip(o, d):
        face, u, v = face_of(di)
        q = np.concatenate([oi, [u, v]])
        node = int(tree.face_root[face])
        while True:
            out[node] = out.get(node, 0) + 1
            if tree.node_b[node] >= 0:
                break
            dim = -tree.node_b[node] - 1
            node = int(tree.node_a[node]) + (0 if q[dim] < tree.split[node] else 1)
    return out


def inside_rays(rng, n, half=3.5):
    o = rng.uniform(-half, half, (n, 3))
    d = rng.normal(size=(n, 3))
    return o, d


def test_lazy_trees_start_as_six_root_leaves():
    scene, bounds = sphere_cloud(40)
    geo, build = flatten(scene, "rc")
    roots = geo.rc_face_root[0]
    assert len(geo.rc_node_a) == 6 and np.all(geo.rc_node_b[roots] == 40)
    for f in range(6):
        s = geo.rc_node_a[roots[f]]
        assert sorted(geo.keyed_ref[s:s + 40].tolist()) == list(range(40))     # sphere refs: kind 0, index
        assert np.all(np.diff(geo.keyed_key[s:s + 40]) >= 0)
    # every root may split and looks VIRTUAL_LEVELS levels deep: 2**5 columns each
    assert np.array_equal(geo.rc_pass[roots], np.arange(6))
    assert build["lazy"].columns == 6 * 2 ** VIRTUAL_LEVELS
    agg = build["aggregates"][0]
    assert build["build.nodes"] == agg["nodes"] == 6 and agg["refs"] == 240 and agg["inner"] == 0
    assert build["build.refine_passes"] == 0 and build["build.subdivisions"] == 0
    # eager: the whole trees at once, no pass columns
    geo, build = flatten(scene, "rc(lazy=off)")
    assert len(geo.rc_node_a) > 6 and np.all(geo.rc_pass == -1) and build.get("lazy") is None


@pytest.mark.parametrize("rays", [1, 2])
def test_one_pass_splits_exactly_where_enough_rays_arrived(rays):
    """After one pass, a hypercube at most VIRTUAL_LEVELS below its root (a cell of the roots' virtual
    subtrees) is split if and only if at least `rays` rays fell in it and it held more than `leaf`
    candidates; the children of the deepest ones are leaves."""
    scene, bounds = sphere_cloud()
    rs = RayScene.from_scene(scene, f"rc(leaf=2, rays={rays})")
    n = rs.build_stats["lazy"].ranges(3000, CHUNK)[0][1]      # the rays of RayScene's first pass
    o, d = inside_rays(np.random.default_rng(21), n)
    h = rs.intersect(o, d)
    np.testing.assert_array_equal(h.t, RayScene.from_scene(scene, "list").intersect(o, d).t)
    assert rs.build_stats["build.refine_passes"] == 1
    tree = tree_of(rs.geo, root_box(bounds))
    seen = visits(tree, o, d)
    inner = [n for n in tree.depth if tree.node_b[n] < 0]
    assert len(inner) > 10 and max(tree.depth.values()) == VIRTUAL_LEVELS + 1
    for node, k in tree.depth.items():
        if tree.node_b[node] < 0:
            assert seen.get(node, 0) >= rays and k <= VIRTUAL_LEVELS
        elif k <= VIRTUAL_LEVELS:
            assert seen.get(node, 0) < rays or tree.node_b[node] <= 2, (node, k)
    # leaves no ray reached kept their place: some hypercubes were never split for lack of rays
    assert any(seen.get(n, 0) == 0 and tree.node_b[n] > 2 for n in tree.depth if tree.node_b[n] >= 0)


def test_rays_along_plus_x_leave_the_other_faces_unsplit():
    scene, bounds = sphere_cloud()
    rng = np.random.default_rng(22)
    n = 2000
    o = rng.uniform(-3.5, 3.5, (n, 3))
    d = np.column_stack([np.ones(n), rng.uniform(-0.9, 0.9, (n, 2))])
    rs = same_hits_as_list(scene, "rc(rays=4)", o, d, repeats=3)
    geo = rs.geo
    roots = geo.rc_face_root[0]
    assert geo.rc_node_b[roots[0]] < 0 and np.all(geo.rc_node_b[roots[1:]] == len(bounds))
    tree = tree_of(geo, root_box(bounds))
    seen = visits(tree, o, d)
    inner = [n for n in tree.depth if tree.node_b[n] < 0]
    assert len(inner) > 20 and rs.build_stats["build.subdivisions"] == len(inner)
    # every split hypercube had rays arrive (each query cast the rays three times that count: intersect,
    # occluded and the second run of intersect_all, the first being undone)
    assert all(seen.get(node, 0) >= 1 for node in inner)


def lazy_rc(build):
    return next(part for part in build["lazy"].parts if isinstance(part, LazyRC))


def lazy_of(rs):
    return rs.build_stats["lazy"]


def test_refine_follows_the_arrivals_through_the_virtual_subtree():
    """Arrivals put in one virtual cell of face 0 split exactly the path to it and that cell, six levels
    in one pass; arrivals add up over passes until `rays` is reached."""
    scene, _ = sphere_cloud(200, radius=0.5)
    geo, build = flatten(scene, "rc(leaf=1, rays=10)")
    lazy = build["lazy"]
    cell = 0b00101                       # path from the root: first, first, second, first, second child
    counts = np.zeros((2, lazy.columns), np.int64)
    counts[1, cell] = 10                 # face 0's columns come first; two rows add up
    geo = lazy.refine(geo, counts)
    node = geo.rc_face_root[0, 0]
    for bit in (0, 0, 1, 0, 1):
        assert geo.rc_node_b[node] < 0 and geo.rc_node_b[geo.rc_node_a[node] + 1 - bit] >= 0
        node = geo.rc_node_a[node] + bit
    # the cell itself had 10 arrivals: split once more, its children wait for rays of their own
    assert geo.rc_node_b[node] < 0 and np.all(geo.rc_node_b[geo.rc_node_a[node] + np.arange(2)] >= 0)
    assert np.all(geo.rc_node_b[geo.rc_face_root[0, 1:]] >= 0)
    lazy.update_stats(build, geo)
    assert build["build.subdivisions"] == 6 and build["aggregates"][0]["max_depth"] == 6
    assert build["build.nodes"] == 6 + 2 * 6
    # one arrival short of `rays`: nothing splits, but the count stays for the next pass
    geo, build = flatten(scene, "rc(leaf=1, rays=15)")
    lazy = build["lazy"]
    counts = np.zeros((1, lazy.columns), np.int64)
    counts[0, cell] = 10
    geo = lazy.refine(geo, counts)
    lazy.update_stats(build, geo)
    assert build["build.subdivisions"] == 0 and np.all(geo.rc_node_b >= 0)
    # face 0's root saw 10 < 15 arrivals: two cells next (K = 1), the other roots none: one each
    assert lazy.columns == 2 + 5
    counts = np.zeros((1, lazy.columns), np.int64)
    counts[0, 1] = 10                    # all in the second half: 20 arrivals at the root in all
    geo = lazy.refine(geo, counts)
    lazy.update_stats(build, geo)
    assert build["build.subdivisions"] == 1 and build["build.refine_passes"] == 2
    with pytest.raises(ValueError, match="columns"):
        lazy.refine(geo, np.zeros((1, lazy.columns + 1), np.int64))


def test_lazy_candidate_lists_hold_every_item_a_ray_can_reach():
    scene, bounds = sphere_cloud(120)
    rng = np.random.default_rng(23)
    o, d = inside_rays(rng, 4000)
    rs = RayScene.from_scene(scene, "rc(leaf=2, rays=2)")
    for _ in range(3):
        rs.count_hits(o, d)
    tree = tree_of(rs.geo, root_box(bounds))
    assert rs.build_stats["build.subdivisions"] > 50
    checked = 0
    for _ in range(1500):
        oi = rng.uniform(-8, 8, 3)
        di = rng.normal(size=3)
        node = leaf_of(tree, oi, di)
        if node is None:
            continue
        s, n = tree.node_a[node], tree.node_b[node]
        held = set(tree.items[s:s + n].tolist())
        assert np.all(np.diff(tree.keys[s:s + n]) >= 0)
        for i in range(len(bounds)):
            t0, t1 = slab(bounds[i], oi, di)
            if t0 <= t1:
                assert i in held
                checked += 1
    assert checked > 150


@pytest.mark.parametrize("extra", ["", ", rays=5", ", leaf=1, depth=40"])
def test_passes_within_one_query_match_list(extra):
    """More than one pass inside each query, all hits included (its two runs must meet the same trees)."""
    rng = np.random.default_rng(24)
    scene = new_scene()
    fill_group(scene.root, rng, n=40)
    o, d = random_rays(rng, 2 * PASS + 500)
    rs = same_hits_as_list(scene, f"rc(lazy=on{extra})", o, d, repeats=1)
    # intersect, occluded and the second run of intersect_all (the first is undone), each in passes
    passes = rs.build_stats["lazy"].ranges(len(o), CHUNK)
    assert len(passes) >= 3 and rs.build_stats["build.refine_passes"] == 3 * len(passes)
    assert rs.build_stats["build.subdivisions"] > 0


def test_lazy_budget_stops_refining_with_a_warning_and_exact_hits():
    rng = np.random.default_rng(25)
    scene = new_scene()
    fill_group(scene.root, rng, n=25)
    o, d = random_rays(rng, 3000)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rs = same_hits_as_list(scene, "rc(budget_mb=0.02)", o, d, repeats=3)
    budget = [w for w in caught if issubclass(w.category, RcBudgetWarning)]
    assert len(budget) == 1 and "memory budget of 0.02 MiB" in str(budget[0].message)
    agg = rs.build_stats["aggregates"][0]
    assert agg["budget_exceeded"] and agg["subdivisions"] > 0 and agg["bytes"] <= 0.02 * 2 ** 20
    assert lazy_rc(rs.build_stats).columns == 0 and np.all(rs.geo.rc_pass == -1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        full = same_hits_as_list(scene, "rc", o, d, repeats=3)
    assert not full.build_stats["aggregates"][0]["budget_exceeded"]
    assert full.build_stats["build.nodes"] > rs.build_stats["build.nodes"]


def test_lazy_stats_describe_the_grown_trees():
    scene, bounds = sphere_cloud(80)
    rs = RayScene.from_scene(scene, "rc(rays=2)")
    o, d = inside_rays(np.random.default_rng(26), 3000)
    for _ in range(3):
        rs.count_hits(o, d)
    tree = tree_of(rs.geo, root_box(bounds))
    nodes = list(tree.depth)
    leaves = [n for n in nodes if tree.node_b[n] >= 0]
    refs = int(sum(tree.node_b[n] for n in leaves))
    agg = rs.build_stats["aggregates"][0]
    assert agg["nodes"] == len(nodes) == rs.build_stats["build.nodes"] > 6
    assert agg["leaves"] == len(leaves) and agg["inner"] == len(nodes) - len(leaves) == agg["subdivisions"]
    assert agg["refs"] == refs == rs.build_stats["build.refs"]
    assert agg["empty_leaves"] == sum(1 for n in leaves if tree.node_b[n] == 0)
    assert agg["bytes"] == NODE_BYTES * len(nodes) + 16 * refs
    assert agg["max_depth"] == max(tree.depth.values())
    # three all-hits queries, of which the second runs count
    assert agg["passes"] == rs.build_stats["build.refine_passes"] == 3 * len(lazy_of(rs).ranges(3000, CHUNK))
    assert rs.build_stats["build.bytes"] == sum(a.nbytes for a in rs.geo if isinstance(a, np.ndarray))
    # split leaves' old lists are dropped once they outnumber the live ones
    assert agg["refs"] <= len(rs.geo.keyed_key) <= 2 * agg["refs"]


@pytest.mark.parametrize("outer, inner, instanced", [
    ("rc", "bvh", False), ("bvh", "rc(rays=2)", False), ("rc", "rc(lazy=off)", False),
    ("rc(lazy=off)", "rc", True), ("grid", "rc", True), ("rc", "rc(leaf=2)", True),
    ("lazyoctree(rays=1, k=0)", "rc", True), ("rc", "lazyoctree(rays=1, k=0)", False)])
def test_lazy_nested_and_instanced_match_list(outer, inner, instanced):
    rng = np.random.default_rng(7)
    scene = nested_scene(rng, outer, inner, instanced)
    o, d = random_rays(rng, 2000)
    oi, di = random_rays(rng, 500, inside=True)
    o, d = np.vstack([o, oi]), np.vstack([d, di])
    plain = nested_scene(np.random.default_rng(7), "list", "list", instanced)
    rs = same_hits_as_list(scene, "bvh", o, d, repeats=2, plain=plain)
    aggs = rs.build_stats["aggregates"]
    lazy = [a for a in aggs if a["kind"].startswith("lazyoctree") or
            (a["kind"].startswith("rc") and "lazy=off" not in a["kind"])]
    # every lazy structure, rc or octree, nested or instanced, grew where the rays went
    assert lazy and all(a["subdivisions"] > 0 for a in lazy)
    assert rs.build_stats["build.subdivisions"] == sum(a["subdivisions"] for a in lazy)


# ---------------------------------------------------------------- renders

@pytest.mark.parametrize("name", ["spd:balls:1", "spd:gears:1"])
def test_lazy_spd_render_matches_bvh(name):
    scene = raykernel.load(name)
    bvh = raykernel.render(scene, accel="bvh", resolution=48, spd=True)
    rays = ray_counts(bvh.stats)
    got = raykernel.render(scene, accel="rc", resolution=48, spd=True)
    np.testing.assert_array_equal(got.image, bvh.image)
    assert {k: got.stats[k] for k in rays} == rays
    agg = got.stats.aggregates[0]
    assert agg["subdivisions"] > 0 and agg["passes"] == got.stats["build.refine_passes"] > 1
    assert agg["nodes"] == got.stats["build.nodes"] == 6 + 2 * agg["subdivisions"]
    eager = raykernel.render(scene, accel="rc(lazy=off)", resolution=48, spd=True)
    assert got.stats["tests.total"] < eager.stats["tests.total"]



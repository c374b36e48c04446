"""Octree aggregate: builder criteria, the four walks against list and bvh, wall quadtrees, each walk in
rotated and scaled instances, degenerate scenes, the reference budget, and the defaults on every SPD
scene and the stadium. Octrees nested in and around every other kind are checked in test_nesting.py."""

from __future__ import annotations

import numpy as np
import pytest
from support import (
    assert_same_hits,
    axis_and_boundary_rays,
    cast,
    fill_group,
    lattice_scene,
    new_scene,
    random_rays,
    rotation_scale,
    stadium_rays,
)

import raykernel
from raykernel.aggregates.octbuild import ADDRESS_BITS, BUDGET_SLACK, build_octree, wall_quadtrees
from raykernel.aggregates.octree import CODE as OCTREE
from raykernel.engine.flatten import flatten
from raykernel.engine.traverse import cast_rays
from raykernel.errors import OptionError
from raykernel.geometry import counters as C
from raykernel.scene import Group, Instance, pathological, spd
from raykernel.aggregates.registry import parse_spec

WALKS = ("point", "neighbor", "parametric", "wall")
CRITERIA = ["", "collapse=off", "mailbox=off", "rule60=on", "density=0.3", "vertexcount=on, leaf=8",
            "depth=3", "depth=12, leaf=1, rule60=on"]


def spec(walk, extra=""):
    return f"octree(walk={walk}{', ' + extra if extra else ''})"


def leaves_of(tree):
    return np.flatnonzero(tree.count >= 0)


# ---------------------------------------------------------------- builder

def random_boxes(rng, n=300, size=1.0):
    lo = rng.uniform(-5, 5, (n, 3))
    return np.hstack([lo, lo + rng.uniform(0, size, (n, 3))])


@pytest.mark.parametrize("collapse", [True, False])
def test_every_item_is_in_every_leaf_its_box_overlaps(collapse):
    boxes = random_boxes(np.random.default_rng(1))
    tree, stats = build_octree(boxes, depth=6, leaf=2, collapse=collapse)
    assert stats["nodes"] == len(tree.count) == stats["inner"] + stats["leaves"]
    assert stats["leaves"] == len(leaves_of(tree))
    assert stats["empty_leaves"] == int(np.sum(tree.count == 0))
    assert stats["refs"] == len(tree.order) == int(tree.count[tree.count > 0].sum())
    assert stats["bytes"] == sum(a.nbytes for a in tree)
    assert stats["max_depth"] <= 6 and np.all(tree.level <= 6)
    for n in leaves_of(tree):
        b = tree.bounds[n]
        overlap = np.all((boxes[:, :3] <= b[3:]) & (boxes[:, 3:] >= b[:3]), axis=1)
        held = tree.order[tree.first[n]:tree.first[n] + tree.count[n]]
        assert set(np.flatnonzero(overlap)) <= set(held.tolist())
        for i in set(held.tolist()) - set(np.flatnonzero(overlap)):
            assert np.maximum(boxes[i, :3] - b[3:], b[:3] - boxes[i, 3:]).max() < 1e-6
    # boxes follow the addresses; children of an inner node are its octants
    side = 2.0 ** (ADDRESS_BITS - tree.level)
    np.testing.assert_array_equal(tree.bounds[:, :3], tree.origin + tree.unit * tree.loc)
    np.testing.assert_array_equal(tree.bounds[:, 3:], tree.origin + tree.unit * (tree.loc + side[:, None]))
    for n in np.flatnonzero(tree.count < 0):
        kids = tree.first[n] + np.arange(8)
        assert np.all(tree.slot[kids] == tree.level[n] + 1)


def test_neighbours_are_adjacent_and_not_smaller():
    tree, _ = build_octree(random_boxes(np.random.default_rng(2)), depth=5, leaf=2, collapse=False)
    full = 1 << ADDRESS_BITS
    for n in range(1, len(tree.count)):
        side = 1 << (ADDRESS_BITS - tree.slot[n])
        for wall in range(6):
            a, up = wall >> 1, wall & 1
            m = tree.nbr[n, wall]
            edge = tree.loc[n, a] + side if up else tree.loc[n, a]
            if edge in (0, full):
                assert m == -1
                continue
            assert tree.slot[m] <= tree.slot[n]
            mside = 1 << (ADDRESS_BITS - tree.slot[m])
            assert (tree.loc[m, a] if up else tree.loc[m, a] + mside) == edge


def test_rule60_keeps_a_problem_voxel_a_leaf():
    # 5 boxes around the centre (in all 8 children) and k boxes in k different corners:
    # each child that holds a corner box holds 6 of the 5 + k items
    centre = [[-1, -1, -1, 1, 1, 1]] * 5
    corners = [[9 * sx - 0.5, 9 * sy - 0.5, 9 * sz - 0.5, 9 * sx + 0.5, 9 * sy + 0.5, 9 * sz + 0.5]
               for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]
    two = np.array(centre + corners[:2], float)             # 6 of 7 = 86% >= 60%: stays a leaf
    _, s_on = build_octree(two, depth=4, leaf=1, rule60=True, collapse=False)
    _, s_off = build_octree(two, depth=4, leaf=1, rule60=False, collapse=False)
    assert s_on["nodes"] == 1 and s_on["leaves"] == 1
    assert s_off["nodes"] > 1
    six = np.array(centre + corners[:6], float)              # 6 of 11 = 55% < 60%: subdivided
    _, s6 = build_octree(six, depth=1, leaf=1, rule60=True, collapse=False)
    assert s6["nodes"] == 9
    five = np.array(centre + corners[:5], float)             # 6 of 10 = 60%: a leaf
    _, s5 = build_octree(five, depth=1, leaf=1, rule60=True, collapse=False)
    assert s5["nodes"] == 1


def test_collapse_removes_a_chain_of_single_children():
    # two small boxes near one corner of the root box [0.1, 8]^3 and one at the far corner:
    # the octant of the two is split with one occupied child per level until level 6 separates them
    boxes = np.array([[0.1, 0.1, 0.1, 0.2, 0.2, 0.2], [0.25, 0.25, 0.25, 0.3, 0.3, 0.3], [7.99, 7.99, 7.99, 8, 8, 8]])
    loose, sl = build_octree(boxes, depth=6, leaf=1, collapse=False)
    tree, sc = build_octree(boxes, depth=6, leaf=1, collapse=True)
    assert sl["inner"] == 6 and sl["nodes"] == 1 + 8 * 6
    # the chain from level 1 to level 5 is one node: its slot is level 1, its box level 5
    assert sc["inner"] == 2 and sc["nodes"] == 1 + 8 + 8
    chain = tree.first[0]
    assert tree.slot[chain] == 1 and tree.level[chain] == 5 and tree.count[chain] == -1
    assert sorted(tree.order.tolist()) == sorted(loose.order.tolist()) == [0, 1, 2]


def test_density_criterion_uses_clipped_volume():
    # three 0.8-cubes in octant 0 of the root box [0, 2]^3 (spanned by two point boxes):
    # root ratio 3 * 0.512 / 8 = 0.192, octant 0 ratio 1.536
    cubes = [[0.1, 0.1, 0.1, 0.9, 0.9, 0.9]] * 3 + [[0, 0, 0, 0, 0, 0], [2, 2, 2, 2, 2, 2]]
    _, split = build_octree(np.array(cubes, float), depth=3, leaf=1, density=0.3, collapse=False)
    _, kept = build_octree(np.array(cubes, float), depth=3, leaf=1, density=0.15, collapse=False)
    assert kept["nodes"] == 1
    assert split["nodes"] == 9
    # two boxes reaching from octant 0 into octant 4: clipped volumes 2 * 0.576 and 2 * 0.32,
    # so at density 0.7 octant 0 stays a leaf and octant 4 splits (unclipped, both would stay)
    tall = [[0.1, 0.1, 0.1, 0.9, 0.9, 1.5]] * 2 + [[0, 0, 0, 0, 0, 0], [2, 2, 2, 2, 2, 2]]
    tree, st = build_octree(np.array(tall, float), depth=2, leaf=1, density=0.7, collapse=False)
    assert st["nodes"] == 17
    assert tree.count[tree.first[0] + 0] == 3 and tree.count[tree.first[0] + 4] == -1


def test_vertexcount_counts_polygon_vertices():
    scene = new_scene()
    rng = np.random.default_rng(3)
    for _ in range(4):
        c = rng.uniform(-4, 4, 3)
        scene.root.polygons.add(c + rng.normal(0, 0.3, (6, 3)) * [1, 1, 0], 0)
    _, by_items = flatten(scene, "octree(leaf=5)")
    _, by_verts = flatten(scene, "octree(leaf=5, vertexcount=on)")
    assert by_items["build.nodes"] == 1
    assert by_verts["build.nodes"] > 1


@pytest.mark.parametrize("text, allowed", [("octree(walk=sideways)", "point, neighbor, parametric, wall"),
                                           ("octree(depth=30)", "depth"), ("octree(leaf=0)", "leaf"),
                                           ("octree(rule60=maybe)", "on or off"), ("octree(density=-1)", "density"),
                                           ("octree(size=3)", "depth, leaf, rule60, density, vertexcount, "
                                                              "collapse, walk, mailbox")])
def test_bad_parameters_are_option_errors(text, allowed):
    with pytest.raises(OptionError, match=allowed):
        parse_spec(text)


def test_flatten_stores_octrees_and_sums_stats():
    scene = new_scene()
    fill_group(scene.root, np.random.default_rng(2))
    geo, stats = flatten(scene, default_accel="octree")
    assert geo.agg_kind[geo.root] == OCTREE
    a = stats["aggregates"][0]
    assert a["kind"] == "octree" and stats["build.nodes"] == a["nodes"] == len(geo.oct_count)
    assert stats["build.refs"] == a["refs"] == len(geo.refs)
    assert stats["build.empty_leaves"] == int(np.sum(geo.oct_count == 0))


# ---------------------------------------------------------------- walks against list and bvh

@pytest.mark.parametrize("walk", WALKS)
@pytest.mark.parametrize("extra", CRITERIA)
def test_random_scenes_match_list_and_bvh(walk, extra):
    for seed in (0, 1):
        rng = np.random.default_rng(seed)
        scene = new_scene()
        fill_group(scene.root, rng, n=25, big=seed == 1)
        o, d = random_rays(rng, 800)
        oi, di = random_rays(rng, 300, inside=True)
        o, d = np.vstack([o, oi]), np.vstack([d, di])
        ref = cast(scene, "list", o, d)
        assert np.isfinite(ref[0]).sum() > 150
        assert_same_hits(cast(scene, "bvh", o, d), ref)
        if seed == 1 and "rule60" not in extra and "density" not in extra:
            # depth 4 in place of the case's own depth (a key may be given once)
            kept = [kv for kv in extra.split(", ") if kv and not kv.startswith("depth=")]
            extra_b = ", ".join(kept + ["depth=4"])
        else:
            extra_b = extra
        got = cast(scene, spec(walk, extra_b), o, d)
        assert_same_hits(got, ref)
        cnt = got[4]
        assert cnt[C.CELLS_VISITED] >= cnt[C.CELLS_LEAVES] >= cnt[C.CELLS_EMPTY] and cnt[C.CELLS_LEAVES] > 0
        if "mailbox=off" in extra:
            assert cnt[C.MAILBOX_SAVED] == 0
        shadow = cast(scene, spec(walk, extra_b), o, d, tmax=0.5, any_hit=True)
        np.testing.assert_array_equal(np.isfinite(shadow[0]), np.isfinite(cast(scene, "list", o, d, tmax=0.5)[0]))


def test_walks_visit_the_same_leaves_and_mailbox_only_saves_tests():
    rng = np.random.default_rng(5)
    scene = new_scene()
    fill_group(scene.root, rng, n=40)
    o, d = random_rays(rng, 2000)
    runs = {w: cast(scene, spec(w), o, d) for w in WALKS[:3]}
    for w in WALKS[1:3]:
        assert_same_hits(runs[w], runs["point"])
        assert runs[w][4][C.CELLS_LEAVES] == runs["point"][4][C.CELLS_LEAVES]
    # point location starts every step at the root, neighbour pointers do not
    assert runs["neighbor"][4][C.CELLS_VISITED] < runs["point"][4][C.CELLS_VISITED]
    off = cast(scene, spec("neighbor", "mailbox=off"), o, d)
    tests = slice(C.TESTS, C.TESTS + 5)
    on = runs["neighbor"][4]
    assert on[tests].sum() + on[C.MAILBOX_SAVED] == off[4][tests].sum()
    assert on[C.CELLS_VISITED] == off[4][C.CELLS_VISITED]


def test_wall_quadtrees_tile_every_wall_with_the_leaves_behind_it():
    tree, _ = build_octree(random_boxes(np.random.default_rng(7)), depth=6, leaf=1, collapse=False)
    walls, quads = wall_quadtrees(tree.first, tree.count, tree.nbr)
    assert len(quads) > 0
    for n in np.flatnonzero(tree.count >= 0):
        side = 1 << (ADDRESS_BITS - tree.level[n])
        for wall in range(6):
            a, up = wall >> 1, wall & 1
            entry = walls[n, wall]
            if tree.nbr[n, wall] < 0 or tree.count[tree.nbr[n, wall]] >= 0:
                assert entry == tree.nbr[n, wall]       # nothing behind, or one leaf: the pointer itself
                continue
            # the quadtree's leaves: each behind the wall, touching it, and together the whole wall
            found, todo = [], [entry]
            while todo:
                e = todo.pop()
                if e <= -2:
                    todo += list(quads[-2 - e])
                else:
                    found.append(e)
            plane = tree.loc[n, a] + side if up else tree.loc[n, a]
            area = 0
            for leaf in found:
                assert tree.count[leaf] >= 0
                lside = 1 << (ADDRESS_BITS - tree.level[leaf])
                assert (tree.loc[leaf, a] if up else tree.loc[leaf, a] + lside) == plane
                u, v = [k for k in range(3) if k != a]
                for k in (u, v):
                    assert tree.loc[n, k] <= tree.loc[leaf, k] and tree.loc[leaf, k] + lside <= tree.loc[n, k] + side
                area += lside * lside
            assert area == side * side and len(set(found)) == len(found)


def test_the_wall_walk_meets_the_neighbour_walks_leaves_without_descending_in_three_dimensions():
    rng = np.random.default_rng(9)
    scene = new_scene()
    fill_group(scene.root, rng, n=40)
    o, d = random_rays(rng, 2000)
    wall = cast(scene, spec("wall", "depth=8, leaf=1"), o, d)
    neighbor = cast(scene, spec("neighbor", "depth=8, leaf=1, collapse=off"), o, d)
    assert_same_hits(wall, neighbor)
    a, b = wall[4], neighbor[4]
    for column in (C.CELLS_LEAVES, C.CELLS_EMPTY, C.MAILBOX_SAVED, C.BOUNDS_TESTS):
        assert a[column] == b[column]
    assert np.array_equal(a[C.TESTS:C.TESTS + 5], b[C.TESTS:C.TESTS + 5])
    from raykernel.aggregates.octwalk import WALL_STEPS
    # the neighbour walk descends from a subdivided neighbour through inner octree nodes; the wall
    # walk goes down the wall's quadtree instead, and visits no inner node after the first leaf
    assert a[WALL_STEPS] > 0 and b[WALL_STEPS] == 0
    assert a[C.CELLS_VISITED] < b[C.CELLS_VISITED]


@pytest.mark.parametrize("walk", WALKS)
@pytest.mark.parametrize("extra", ["depth=3, leaf=1", "depth=5, leaf=1, collapse=off", "mailbox=off"])
def test_axis_parallel_and_cell_boundary_rays(walk, extra):
    scene = lattice_scene()
    o, d = axis_and_boundary_rays()
    ref = cast(scene, "list", o, d)
    geo, _ = flatten(scene, default_accel=spec(walk, extra))
    # the root box is [0, 8]^3 less the sphere margins... the lattice is dyadic
    assert np.all(geo.oct_origin == 0.0) and np.all(geo.oct_unit * 2 ** ADDRESS_BITS == 8.0)
    assert_same_hits(cast_rays(geo, o, d), ref)


@pytest.mark.parametrize("walk", WALKS)
def test_rays_starting_inside_stop_at_the_first_hit(walk):
    scene = new_scene()
    for x in range(20):
        scene.root.spheres.add((x, 0, 0), 0.3, 0)
    # no reference budget: every sphere straddles the centre planes y = 0 and z = 0, so separating
    # them takes 3,600 references each, far past the default budget
    geo, _ = flatten(scene, default_accel=spec(walk, "mailbox=off, leaf=1, budget=0"))
    t, kind, index, _, cnt = cast_rays(geo, [[4.5, 0, 0], [4.5, 0, 0]], [[1.0, 0, 0], [-1.0, 0, 0]])
    assert index.tolist() == [5, 4] and t[0] == pytest.approx(0.2)
    # of 40 for a list; along the centre planes a walk may meet a cell or two more (widened nodes: parametric)
    assert cnt[C.TESTS + 0] <= 10


# ---------------------------------------------------------------- instances

@pytest.mark.parametrize("walk", WALKS)
def test_octree_in_rotated_scaled_instances(walk):
    rng = np.random.default_rng(11)
    leaf = fill_group(Group(name="leaf", accel=spec(walk)), rng, n=10, spread=1.0)
    level = leaf
    for k in range(3):
        up = Group(name=f"l{k}", accel=spec(walk) if k % 2 else "bvh")
        up.add(Instance(level, rotation_scale(rng)))
        up.add(Instance(level, rotation_scale(rng)))
        level = up
    scene = new_scene()
    scene.root.accel = spec(walk)
    scene.root.add(level)
    o, d = random_rays(rng, 1500, spread=10.0)
    ref = cast(scene, "list", o, d)
    assert np.isfinite(ref[0]).sum() > 50
    assert_same_hits(cast(scene, spec(walk), o, d), ref)


# ---------------------------------------------------------------- degenerate scenes

@pytest.mark.parametrize("walk", WALKS)
def test_flat_one_item_and_empty_scenes(walk):
    scene = new_scene()
    rng = np.random.default_rng(3)
    for _ in range(40):
        c = np.append(rng.uniform(-4, 4, 2), 1.0)
        scene.root.polygons.add([c, c + [1, 0, 0], c + [0.5, 1, 0]], 0)
    o, d = random_rays(rng, 1000, spread=4.0)
    ref = cast(scene, "list", o, d)
    assert np.isfinite(ref[0]).sum() > 20
    assert_same_hits(cast(scene, spec(walk), o, d), ref)
    one = new_scene()
    one.root.spheres.add((1, 2, 3), 1.0, 0)
    one.root.add(Group(name="empty", accel=spec(walk)))
    o = np.array([[1, 2, -5.0], [1, 2, 3.0], [5, 5, 5.0]])
    d = np.array([[0, 0, 1.0], [0, 1, 0.0], [1, 0, 0.0]])
    t = cast(one, spec(walk), o, d)[0]
    assert t[0] == pytest.approx(7.0) and t[1] == pytest.approx(1.0) and np.isinf(t[2])
    empty = new_scene()
    empty.root.accel = spec(walk)
    assert np.all(np.isinf(cast(empty, spec(walk), o, d)[0]))


@pytest.mark.parametrize("walk", WALKS)
def test_teapot_in_a_stadium(walk):
    rng = np.random.default_rng(5)
    scene = new_scene()
    fill_group(scene.root, rng, n=20, spread=2.0)
    scene.root.spheres.add((1e4, 3e3, -2e3), 1e2, 0)
    scene.root.polygons.add([(-10, -10, -3), (2e4, -10, -3), (2e4, 5e3, -3)], 0)
    o, d = random_rays(rng, 1500, spread=2.0)
    far = np.array([[0.0, 0.0, 0.0]] * 3)
    fd = np.array([[1e4, 3e3, -2e3], [1e4, 3e3 + 50, -2e3], [-1.0, 0.0, 0.0]])
    o, d = np.vstack([o, far]), np.vstack([d, fd])
    ref = cast(scene, "list", o, d)
    assert np.isfinite(ref[0][-3:-1]).all()
    for extra in ("", "collapse=off", "depth=16, leaf=1"):
        got = cast(scene, spec(walk, extra), o, d)
        assert_same_hits(got, ref)
    geo, st = flatten(scene, spec(walk, "depth=16"))
    assert st["aggregates"][0]["max_depth"] > 8


def test_counts_do_not_depend_on_chunking():
    rng = np.random.default_rng(6)
    scene = new_scene()
    fill_group(scene.root, rng, n=30)
    o, d = random_rays(rng, 3000)
    for walk in WALKS:
        geo, _ = flatten(scene, default_accel=spec(walk))
        a = cast_rays(geo, o, d)[4]
        parts = [cast_rays(geo, o[k:k + 700], d[k:k + 700])[4] for k in range(0, 3000, 700)]
        np.testing.assert_array_equal(np.sum(parts, axis=0)[:C.RAYS_CAST], a[:C.RAYS_CAST])


# ---------------------------------------------------------------- the reference budget and the defaults

@pytest.mark.parametrize("text, words", [("octree(budget=-1)", "budget must be a number in"),
                                         ("octree(budget=lots)", "budget must be a number"),
                                         ("octree(depth=25)", "depth must be an integer in")])
def test_octree_budget_and_depth_are_checked(text, words):
    with pytest.raises(OptionError, match=words):
        parse_spec(text)
    with pytest.raises(OptionError, match="budget"):
        build_octree(np.zeros((1, 6)), budget=-1.0)


def test_octree_budget_caps_references_where_no_split_separates_the_items():
    """400 boxes around one point: every split keeps them all together in 8 children,
    so without a budget the tree would grow as 8**depth."""
    rng = np.random.default_rng(3)
    boxes = np.hstack([rng.uniform(-1.0, -0.5, (400, 3)), rng.uniform(0.5, 1.0, (400, 3))])
    boxes = np.vstack([boxes, [[-8, -8, -8, -7, -7, -7], [7, 7, 7, 8, 8, 8]]])
    tree, stats = build_octree(boxes, depth=24, budget=2.0)
    assert stats["budget_refs"] == 2 * len(boxes) + BUDGET_SLACK
    assert stats["refs"] <= stats["budget_refs"] and stats["nodes"] < 20 * stats["budget_refs"]
    again, _ = build_octree(boxes, depth=24, budget=2.0)
    assert all(np.array_equal(a, b) for a, b in zip(tree, again))
    # every leaf still holds every item its box overlaps
    for n in np.flatnonzero(tree.count >= 0):
        b = tree.bounds[n]
        overlap = set(np.flatnonzero(np.all((boxes[:, :3] <= b[3:]) & (boxes[:, 3:] >= b[:3]), axis=1)).tolist())
        assert overlap <= set(tree.order[tree.first[n]:tree.first[n] + tree.count[n]].tolist())


def test_a_budget_that_does_not_bind_changes_nothing():
    rng = np.random.default_rng(4)
    lo = rng.uniform(-5, 5, (1000, 3))
    boxes = np.hstack([lo, lo + rng.uniform(0, 1.0, (1000, 3))])
    free, s_free = build_octree(boxes, depth=6, leaf=2, budget=0.0)
    loose, s_loose = build_octree(boxes, depth=6, leaf=2, budget=1e6)
    assert s_free["budget_refs"] == 0 and s_loose["refs"] < s_loose["budget_refs"]
    assert all(np.array_equal(a, b) for a, b in zip(free, loose))
    tight, s_tight = build_octree(boxes, depth=6, leaf=2, budget=1.0)
    assert s_tight["refs"] <= s_tight["budget_refs"] == 1000 + BUDGET_SLACK < s_free["refs"]
    assert s_tight["nodes"] < s_free["nodes"]


@pytest.mark.parametrize("name", [f"spd:{n}" for n in spd.NAMES] + ["scene:stadium", "scene:stadium:ratio=1"])
def test_default_octree_stays_small_on_every_spd_scene_and_the_stadium(name):
    scene = raykernel.load(name)
    _, stats = flatten(scene, "octree")
    a = stats["aggregates"][0]
    assert a["kind"] == "octree" and a["items"] == scene.count_primitives()
    assert a["refs"] <= 16 * a["items"] + BUDGET_SLACK == a["budget_refs"]
    assert a["bytes"] < 20 * 2 ** 20 and a["nodes"] < a["refs"]


def test_default_octree_resolves_the_teapot_in_the_stadium():
    """Depth 16 with the budget reaches the teapot at the default ratio; depth 8 leaves it
    in a few cells of hundreds of facets (Haines's problem voxel)."""
    scene = pathological.stadium()
    o, d, *_ = stadium_rays(scene, np.random.default_rng(8), 400)
    tests = slice(C.TESTS, C.TESTS + 5)
    per_ray = {}
    for accel in ("octree", "octree(depth=8)"):
        geo, stats = flatten(scene, accel)
        counts = cast_rays(geo, o, d)[4]
        per_ray[accel] = counts[tests].sum() / len(o)
    assert stats["aggregates"][0]["max_depth"] == 8
    assert per_ray["octree"] < 30 and per_ray["octree(depth=8)"] > 300


@pytest.mark.parametrize("walk", WALKS)
def test_every_face_at_a_grazed_edge_is_found(walk):
    """All hits of rays that graze an edge of a box (from outside both faces' planes to outside the
    box): rounding puts each ray a hair off the edge, where the faces' tests still report both
    faces, and every walk must reach the cells that hold them (the parametric walk tests its nodes'
    boxes widened by the margin the faces got when they were put in cells)."""
    lo, hi = np.array([-0.42241697, -0.98081173, 0.16123369]), np.array([0.84137433, 0.35837896, 0.77204955])

    def box_scene(accel):
        scene = new_scene()
        scene.root.accel = accel
        for axis in range(3):
            for side in (lo, hi):
                quad = []
                for u, v in ((0, 0), (1, 0), (1, 1), (0, 1)):
                    corner = lo.copy()
                    corner[axis] = side[axis]
                    corner[(axis + 1) % 3] = (hi if u else lo)[(axis + 1) % 3]
                    corner[(axis + 2) % 3] = (hi if v else lo)[(axis + 2) % 3]
                    quad.append(corner)
                scene.root.polygons.add(quad)
        return scene

    edge = np.array([0.2, lo[1], lo[2]])                     # on the edge y = lo, z = lo
    d = np.array([7.4268202210410195, -0.04714429305371814, 5.456349010347257])    # in from y > lo, z < lo
    o = edge[None] - np.linspace(0.5, 1.99, 20001)[:, None] * d[None]
    d = np.broadcast_to(d, o.shape)
    want = raykernel.RayScene.from_scene(box_scene("list"), "list").intersect_all(o, d, ids=True)
    got = raykernel.RayScene.from_scene(box_scene(spec(walk, "leaf=1")), "list").intersect_all(o, d, ids=True)
    assert len(want[0]) > len(o)                    # most rays report both faces at the edge
    for a, b in zip(got, want):
        np.testing.assert_array_equal(a, b)

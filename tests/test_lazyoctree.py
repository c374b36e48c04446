"""Lazy octree (Lathrop): starts as one leaf, refines between passes only where rays pass,
each criterion, the passes' schedule and the children's share of a split leaf's passes,
hits against list on random, stadium, nested and instanced scenes, renders against bvh,
and results that do not depend on the thread count."""

from __future__ import annotations

import importlib

import numpy as np
import pytest
from support import (
    child,
    fill_group,
    nested_scene,
    new_scene,
    points,
    random_rays,
    ray_counts,
    rotation_scale,
    same_hits_as_list,
)

import raykernel
from raykernel import RayScene
from raykernel.aggregates import lazyoctree
from raykernel.aggregates.lazyoctree import build_lazy
from raykernel.aggregates.lazyset import PASS_CHUNKS, pass_ranges
from raykernel.aggregates.octbuild import ADDRESS_BITS, BUDGET_SLACK
from raykernel.casting.rayqueries import CHUNK, coarse_to_fine
from raykernel.aggregates.octree import CODE as OCTREE
from raykernel.engine.flatten import flatten
from raykernel.errors import OptionError
from raykernel.geometry import counters as C
from raykernel.scene import Group, Instance
from raykernel.scene import pathological as P
from raykernel.aggregates.registry import describe, parse_spec

WALKS = ("point", "neighbor", "parametric")
PASS = PASS_CHUNKS * CHUNK          # rays of RayScene's longest pass (8192)
RENDER = importlib.import_module("raykernel.rendering.render")


def lazy_of(rs: RayScene):
    return rs.build_stats["lazy"]


def tree_of(geo, octree=0):
    """{(level, loc): ("inner" | sorted refs of the leaf)} of the nodes reachable from the root,
    and {(level, loc): {wall: (level, loc) of the neighbour}}: read from the flat arrays."""
    nodes, nbrs = {}, {}
    todo = [int(geo.oct_root[octree])]
    while todo:
        n = todo.pop()
        key = (int(geo.oct_level[n]), tuple(int(x) for x in geo.oct_loc[n]))
        if geo.oct_count[n] < 0:
            nodes[key] = "inner"
            todo.extend(int(geo.oct_first[n]) + c for c in range(8))
        else:
            s = int(geo.oct_first[n])
            nodes[key] = tuple(sorted(geo.refs[s:s + geo.oct_count[n]].tolist()))
        nbrs[key] = {w: (int(geo.oct_level[m]), tuple(int(x) for x in geo.oct_loc[m]))
                     for w, m in enumerate(geo.oct_nbr[n]) if m >= 0}
    return nodes, nbrs


def root_box(geo, octree=0):
    lo = geo.oct_origin[octree]
    return lo, lo + geo.oct_unit[octree] * float(1 << ADDRESS_BITS)


def lattice_rays(lo, hi, n):
    """Rays along +x, +y and +z through the centres of an n x n lattice over the box's faces:
    with n = 2**depth, every cell of that depth is crossed along every axis."""
    o, d = [], []
    u = (np.arange(n) + 0.5) / n
    for a in range(3):
        b, c = (a + 1) % 3, (a + 2) % 3
        for i in u:
            for j in u:
                p = np.empty(3)
                p[a] = lo[a] - 1.0
                p[b] = lo[b] + i * (hi[b] - lo[b])
                p[c] = lo[c] + j * (hi[c] - lo[c])
                o.append(p)
                d.append(np.eye(3)[a])
    return np.array(o), np.array(d)


# ---------------------------------------------------------------- parameters

@pytest.mark.parametrize("text, allowed", [
    ("lazyoctree(depth=25)", "depth must be an integer in \\[0, 24\\]"),
    ("lazyoctree(depth=-1)", "depth"),
    ("lazyoctree(rays=0)", "rays must be an integer in \\[1, "),
    ("lazyoctree(rays=2.5)", "rays must be an integer"),
    ("lazyoctree(k=-0.5)", "k must be a number in \\[0.0, "),
    ("lazyoctree(k=lots)", "k must be a number"),
    ("lazyoctree(rule60=maybe)", "rule60 must be on or off"),
    ("lazyoctree(walk=sideways)", "point, neighbor, parametric"),
    ("lazyoctree(budget=-1)", "budget must be a number in \\[0.0, "),
    ("lazyoctree(leaf=3)", "its parameters: depth, rays, k, rule60, budget, walk, mailbox")])
def test_bad_parameters_are_option_errors(text, allowed):
    with pytest.raises(OptionError, match=allowed):
        parse_spec(text)


@pytest.mark.parametrize("kw, name", [({"depth": 30}, "depth"), ({"depth": 2.0}, "depth"), ({"rays": 0}, "rays"),
                                      ({"rays": True}, "rays"), ({"k": -1.0}, "k"), ({"k": "x"}, "k"),
                                      ({"rule60": "on"}, "rule60")])
def test_build_lazy_checks_its_arguments(kw, name):
    with pytest.raises(OptionError, match=f"lazyoctree {name} must be"):
        build_lazy(np.array([[0, 0, 0, 1, 1, 1.0]]), **kw)


def test_defaults_and_description():
    assert parse_spec("lazyoctree") == ("lazyoctree", {"depth": 16, "rays": 2, "k": 0.0, "rule60": False,
                                                       "budget": 16.0, "walk": "neighbor", "mailbox": True})
    text = describe()
    assert "lazyoctree:" in text and "M*k < N" in text


# ---------------------------------------------------------------- the tree

def test_starts_as_one_leaf_holding_every_item():
    scene = new_scene()
    fill_group(scene.root, np.random.default_rng(1), n=20)
    geo, build = flatten(scene, "lazyoctree")
    assert geo.agg_kind[geo.root] == OCTREE
    root = geo.oct_root[0]
    n_items = build["aggregates"][0]["items"]
    assert len(geo.oct_count) == 1 and geo.oct_count[root] == n_items > 1
    assert sorted(geo.refs[geo.oct_first[root]:geo.oct_first[root] + n_items].tolist()) == sorted(geo.refs.tolist())
    assert np.all(geo.oct_nbr[root] == -1) and geo.oct_pass[root] == 0
    assert build["lazy"].columns == 1
    assert build["build.nodes"] == 1 and build["build.refine_passes"] == 0 and build["build.subdivisions"] == 0
    # the root box is the octree's
    octree_geo, _ = flatten(scene, "octree")
    np.testing.assert_array_equal(geo.oct_bounds[root], octree_geo.oct_bounds[octree_geo.oct_root[0]])


@pytest.mark.parametrize("depth", [2, 3])
def test_refined_everywhere_it_is_the_octree_with_leaf_1(depth):
    """Rays through every cell of the finest level, all hits (every leaf crossed counts a
    pass): the lazy octree becomes octree(leaf=1, collapse=off), neighbours included."""
    scene = new_scene()
    fill_group(scene.root, np.random.default_rng(4), n=24)
    rs = RayScene.from_scene(scene, f"lazyoctree(depth={depth}, rays=1, k=0)")
    o, d = lattice_rays(*root_box(rs.geo), 2 ** (depth + 1))
    assert len(o) < PASS
    for _ in range(depth + 1):
        rs.count_hits(o, d)
    eager, _ = flatten(scene, f"octree(depth={depth}, leaf=1, collapse=off)")
    got_nodes, got_nbrs = tree_of(rs.geo)
    want_nodes, want_nbrs = tree_of(eager)
    assert len(want_nodes) > 9
    assert got_nodes == want_nodes
    assert got_nbrs == want_nbrs
    # one more pass changes nothing: the criteria are all spent
    stats = dict(rs.build_stats)
    rs.count_hits(o, d)
    assert rs.build_stats["build.nodes"] == stats["build.nodes"] == len(want_nodes)
    assert lazy_of(rs).columns == 0


def test_refines_only_where_rays_pass():
    """Rays in the -x half only. The root splits after the first pass of 16 rays, so its
    children's share of its passes is at most (16 - 2) // 8 = 1, below the 2 a child needs:
    only children that rays pass through split, and their shares go to their own children."""
    scene = new_scene()
    rng = np.random.default_rng(2)
    for x in np.linspace(-4, 4, 9):
        for y in np.linspace(-4, 4, 5):
            scene.root.spheres.add((x, y, rng.uniform(-4, 4)), 0.3, 0)
    rs = RayScene.from_scene(scene, "lazyoctree(rays=2, k=0)")
    lo, hi = root_box(rs.geo)
    mid = 0.5 * (lo[0] + hi[0])
    # rays along y and z, all in the -x half of the box
    n = 3000
    o = np.column_stack([rng.uniform(lo[0], mid - 0.5, n), np.full(n, lo[1] - 1), rng.uniform(lo[2], hi[2], n)])
    d = np.tile([0.0, 1.0, 0.0], (n, 1))
    o2 = np.column_stack([rng.uniform(lo[0], mid - 0.5, n), rng.uniform(lo[1], hi[1], n), np.full(n, lo[2] - 1)])
    d2 = np.tile([0.0, 0.0, 1.0], (n, 1))
    for _ in range(4):
        rs.count_hits(np.vstack([o, o2]), np.vstack([d, d2]))
    geo = rs.geo
    inner = np.flatnonzero(geo.oct_count < 0)
    assert len(inner) > 8
    # inner nodes: the root, and nodes of the -x half only
    assert all(geo.oct_bounds[n, 0] < mid for n in inner)
    assert sorted(n for n in inner if geo.oct_bounds[n, 3] > mid) == [geo.oct_root[0]]
    # the +x half is four leaves of the first split, each holding many spheres
    kids = geo.oct_first[geo.oct_root[0]] + np.arange(8)
    plus = kids[geo.oct_bounds[kids, 0] >= mid]
    assert len(plus) == 4 and np.all(geo.oct_count[plus] >= 2)


# ---------------------------------------------------------------- criteria

def sphere_row(n):
    scene = new_scene()
    for x in range(n):
        scene.root.spheres.add((2.0 * x, 0.0, 0.0), 0.5, 0)
    return scene


def rays_past(n, rng):
    """Rays along +y that cross the box of sphere_row(5) between its spheres (x = 1, 3, 5, 7) and miss them all."""
    xs = 2.0 * rng.integers(0, 4, n) + 1.0
    o = np.column_stack([xs, np.full(n, -3.0), rng.uniform(-0.4, 0.4, n)])
    return o, np.tile([0.0, 1.0, 0.0], (n, 1))


def test_budget_bounds_the_references_of_items_no_split_separates():
    """Two equal spheres: every cell of their common box holds both, and rays through its corners
    miss them, so without a budget those cells split down to the depth limit."""
    scene = new_scene()
    for _ in range(2):
        scene.root.spheres.add((0.0, 0.0, 0.0), 1.0, 0)
    rng = np.random.default_rng(21)
    n = 4000
    yz = rng.uniform(0.75, 1.0, (n, 2)) * rng.choice([-1.0, 1.0], (n, 2))   # |y|, |z| >= 0.75: outside the sphere
    o = np.column_stack([np.full(n, -3.0), yz])
    d = np.tile([1.0, 0.0, 0.0], (n, 1))
    aim = np.column_stack([np.full(500, -3.0), rng.uniform(-0.5, 0.5, (500, 2))])   # and some that hit
    o, d = np.vstack([o, aim]), np.vstack([d, np.tile([1.0, 0.0, 0.0], (500, 1))])
    cap = 1 * 2 + BUDGET_SLACK
    free = RayScene.from_scene(scene, "lazyoctree(rays=1, depth=10, budget=0)")
    free.intersect(o, d)
    free_stats = free.build_stats["aggregates"][0]
    assert free_stats["refs"] > cap and not free_stats["budget_reached"]
    held = same_hits_as_list(scene, "lazyoctree(rays=1, depth=10, budget=1)", o, d)
    held_stats = held.build_stats["aggregates"][0]
    assert held_stats["budget_refs"] == cap
    assert held_stats["budget_reached"] and 0 < held_stats["refs"] <= cap
    assert held.build_stats["build.refs"] == held_stats["refs"] == stats_of_tree(held.geo)["refs"]


def test_depth_0_never_refines():
    scene = new_scene()
    fill_group(scene.root, np.random.default_rng(3), n=20)
    rs = RayScene.from_scene(scene, "lazyoctree(depth=0, rays=1, k=0)")
    assert lazy_of(rs).columns == 0
    o, d = random_rays(np.random.default_rng(4), 3 * PASS // 2)
    rs.count_hits(o, d)
    rs.intersect(o, d)
    assert rs.build_stats["build.nodes"] == 1 and rs.build_stats["build.subdivisions"] == 0
    # 12,288 rays: 16, 16, 32, ..., 4096 (to 8192), then 4096: 11 passes a query
    assert rs.build_stats["build.refine_passes"] == 2 * 11


def test_a_leaf_of_one_object_never_refines():
    one = new_scene()
    one.root.spheres.add((0, 0, 0), 1.0, 0)
    rs = RayScene.from_scene(one, "lazyoctree(rays=1, k=0)")
    assert lazy_of(rs).columns == 0
    o, d = random_rays(np.random.default_rng(5), 2000, spread=1.0)
    rs.count_hits(o, d)
    assert rs.build_stats["build.nodes"] == 1
    # in a refined tree, leaves of one item or none hold no pass column
    rs = RayScene.from_scene(sphere_row(5), "lazyoctree(rays=1, k=0)")
    o, d = random_rays(np.random.default_rng(6), 4000, spread=5.0)
    o = o + [4.0, 0, 0]
    for _ in range(4):
        rs.count_hits(o, d)
    geo = rs.geo
    leaves = np.flatnonzero(geo.oct_count >= 0)
    assert np.all(geo.oct_pass[leaves[geo.oct_count[leaves] <= 1]] == -1)
    assert np.all(geo.oct_pass[geo.oct_count < 0] == -1)
    assert rs.build_stats["build.subdivisions"] > 1


def test_rays_criterion_counts_passes_without_a_hit():
    """Criterion IV: the root splits once `rays` rays passed through it without a hit,
    counted over passes; rays that hit something do not count."""
    scene = sphere_row(5)
    rng = np.random.default_rng(7)
    miss_o, miss_d = rays_past(30, rng)
    hit_o = np.column_stack([2.0 * rng.integers(0, 5, 50), np.full(50, -3.0), rng.uniform(-0.2, 0.2, 50)])
    o, d = np.vstack([miss_o, hit_o]), np.vstack([miss_d, np.tile([0.0, 1.0, 0.0], (50, 1))])
    ref = RayScene.from_scene(scene, "list").intersect(o, d)
    assert np.isinf(ref.t[:30]).all() and np.isfinite(ref.t[30:]).all()
    for rays, queries in ((30, 1), (31, 2), (60, 2), (61, 3)):
        rs = RayScene.from_scene(scene, f"lazyoctree(rays={rays}, k=0)")
        for q in range(queries):
            assert rs.build_stats["build.subdivisions"] == 0
            rs.intersect(o, d)
        assert rs.build_stats["build.subdivisions"] == 1, (rays, queries)


def test_k_criterion_asks_more_passes_of_a_dense_leaf():
    """Criterion V: M * k < N, with M = 5 spheres and N = 30 passes per query."""
    scene = sphere_row(5)
    o, d = rays_past(30, np.random.default_rng(8))
    for k, splits_after in ((5.9, 1), (6.0, 2), (11.9, 2), (12.0, 3)):
        rs = RayScene.from_scene(scene, f"lazyoctree(rays=1, k={k})")
        for q in range(splits_after):
            assert rs.build_stats["build.subdivisions"] == 0
            rs.intersect(o, d)
        assert rs.build_stats["build.subdivisions"] >= 1, (k, splits_after)


def test_rule60_keeps_a_problem_voxel_a_leaf_for_good():
    # five big spheres around the centre in all 8 children, two small ones in two corners:
    # each child with a corner sphere holds 6 of the 7 items
    scene = new_scene()
    for _ in range(5):
        scene.root.spheres.add((0, 0, 0), 1.0, 0)
    scene.root.spheres.add((-9, -9, -9), 0.5, 0)
    scene.root.spheres.add((9, 9, 9), 0.5, 0)
    o, d = random_rays(np.random.default_rng(9), 3000, spread=9.0)
    on = RayScene.from_scene(scene, "lazyoctree(rays=1, k=0, rule60=on)")
    off = RayScene.from_scene(scene, "lazyoctree(rays=1, k=0, rule60=off)")
    for _ in range(3):
        on.count_hits(o, d)
        off.count_hits(o, d)
    assert on.build_stats["build.nodes"] == 1 and lazy_of(on).columns == 0
    assert off.build_stats["build.subdivisions"] >= 2
    np.testing.assert_array_equal(on.count_hits(o, d), off.count_hits(o, d))


def test_node_budget_stops_refining_with_exact_hits(monkeypatch):
    monkeypatch.setattr(lazyoctree, "MAX_NODES", 1 + 8 * 3)
    scene = new_scene()
    fill_group(scene.root, np.random.default_rng(10), n=30)
    o, d = random_rays(np.random.default_rng(11), 3000)
    rs = same_hits_as_list(scene, "lazyoctree(rays=1, k=0)", o, d, repeats=3)
    agg = rs.build_stats["aggregates"][0]
    assert agg["nodes"] == 25 and agg["subdivisions"] == 3 and agg["budget_reached"]
    assert lazy_of(rs).columns == 0


# ---------------------------------------------------------------- a split leaf's surplus passes

def octant_clusters():
    """Three spheres near each corner of [-5, 5]^3: every child of the root holds 3 items, all
    in its outer grandchild ([2.5, 5] on each axis, signs as the child's)."""
    scene = new_scene()
    for sx in (-1, 1):
        for sy in (-1, 1):
            for sz in (-1, 1):
                s = np.array([sx, sy, sz], float)
                for c in ((4.5, 4.5, 4.5), (3.5, 4.5, 4.5), (4.5, 3.5, 4.5)):
                    scene.root.spheres.add(s * c, 0.5, 0)
    return scene


def refined_with(spec, n_root):
    """octant_clusters' lazy octree after one pass in which n_root rays passed through the root;
    returns (build statistics, lazy octrees, Geometry)."""
    geo, build = flatten(octant_clusters(), spec)
    lazy = build["lazy"]
    assert lazy.columns == 1
    geo = lazy.refine(geo, np.array([[n_root]], np.int64))
    lazy.update_stats(build, geo)
    return build, lazy, geo


@pytest.mark.parametrize("n_root, subdivisions", [
    (13, 1),                 # root: M = 24, k = 0.5: needs max(2, 12 + 1) = 13 passes
    (13 + 8 * 1 + 7, 1),     # surplus 15: each child 15 // 8 = 1 pass, a child of 3 items needs 2
    (13 + 8 * 2, 1 + 8),     # each child 2: all eight split, with nothing left for theirs
    (13 + 8 * (2 + 8 * 2), 1 + 8 + 8)])   # each child 18, 16 over: the outer grandchildren (3 items) get 2
def test_children_share_the_surplus_of_a_split_leaf(n_root, subdivisions):
    build, lazy, geo = refined_with("lazyoctree(rays=2, k=0.5)", n_root)
    assert build["build.subdivisions"] == subdivisions and build["build.refine_passes"] == 1
    assert build["build.nodes"] == 1 + 8 * subdivisions
    root = geo.oct_root[0]
    kids = geo.oct_first[root] + np.arange(8)
    assert np.all(geo.oct_count[kids] == (-1 if subdivisions > 1 else 3))
    # one pass fewer and the root stays a leaf
    build, _, _ = refined_with("lazyoctree(rays=2, k=0.5)", 12)
    assert build["build.subdivisions"] == 0


def test_shares_stop_at_the_depth_limit_and_add_to_later_passes():
    build, _, _ = refined_with("lazyoctree(depth=2, rays=2, k=0.5)", 13 + 8 * (2 + 8 * 2))
    assert build["build.subdivisions"] == 1 + 8 and build["build.nodes"] == 73
    # a child credited 1 pass needs 1 more of its own, not 2
    build, lazy, geo = refined_with("lazyoctree(rays=2, k=0.5)", 13 + 8)
    assert build["build.subdivisions"] == 1 and lazy.columns == 8
    one = np.zeros((1, 8), np.int64)
    one[0, 3] = 1
    geo = lazy.refine(geo, one)
    lazy.update_stats(build, geo)
    assert build["build.subdivisions"] == 2
    kids = geo.oct_first[geo.oct_root[0]] + np.arange(8)
    assert [int(geo.oct_count[k] < 0) for k in kids] == [0, 0, 0, 1, 0, 0, 0, 0]


# ---------------------------------------------------------------- hits against list

@pytest.mark.parametrize("walk", WALKS)
@pytest.mark.parametrize("extra", ["", "mailbox=off", "rule60=on", "depth=3", "rays=50, k=2"])
def test_random_scenes_match_list(walk, extra):
    for seed in (0, 1):
        rng = np.random.default_rng(seed)
        scene = new_scene()
        fill_group(scene.root, rng, n=25, big=seed == 1)
        o, d = random_rays(rng, 1500)
        oi, di = random_rays(rng, 500, inside=True)
        o, d = np.vstack([o, oi]), np.vstack([d, di])
        spec = f"lazyoctree(walk={walk}{', ' + extra if extra else ''})"
        rs = same_hits_as_list(scene, spec, o, d, repeats=2)
        if "rays=50" not in extra and not (seed == 1 and "rule60" in extra):
            # (big items in every octant keep the root a problem voxel under rule60)
            assert rs.build_stats["build.subdivisions"] > 0


@pytest.mark.parametrize("walk", WALKS)
def test_passes_within_one_query_match_list(walk):
    """More than one pass inside each query, all-hits included (its two runs must meet the same trees)."""
    rng = np.random.default_rng(12)
    scene = new_scene()
    fill_group(scene.root, rng, n=40)
    o, d = random_rays(rng, 2 * PASS + 500)
    rs = same_hits_as_list(scene, f"lazyoctree(walk={walk}, mailbox=off, rays=1, k=0)", o, d)
    # intersect, occluded and two runs of intersect_all (the first run's passes are undone), then
    # cast_rays; 16,884 rays: 16, 16, 32, ..., 4096 (to 8192), 8192, 500: 12 passes a run
    assert rs.build_stats["build.refine_passes"] == 3 * 12


@pytest.mark.parametrize("ratio", [1.0, 1e6])
def test_stadium_matches_list(ratio):
    scene = P.stadium(ratio=ratio, stadium_prims=600, teapot_prims=200)
    rng = np.random.default_rng(13)
    eye = scene.camera.eye
    pts = points(child(scene.root, "teapot"))
    tlo, thi = pts.min(axis=0), pts.max(axis=0)
    targets = np.vstack([rng.uniform(tlo, thi, (2000, 3)),
                         rng.uniform([-150, -210, 0], [450, 210, 80], (1000, 3))])
    o = np.vstack([np.tile(eye, (2000, 1)), rng.uniform([-150, -210, 1], [450, 210, 80], (1000, 3))])
    rs = same_hits_as_list(scene, "lazyoctree", o, targets - o, repeats=2)
    assert rs.build_stats["build.subdivisions"] > 0


@pytest.mark.parametrize("outer, inner, instanced", [
    ("lazyoctree", "bvh", False), ("bvh", "lazyoctree(rays=1, k=0)", False),
    ("lazyoctree(walk=point)", "lazyoctree(walk=parametric)", False),
    ("grid", "lazyoctree(rays=1, k=0)", True), ("lazyoctree(walk=parametric)", "octree", True),
    ("lazyoctree", "lazyoctree(mailbox=off, rays=1, k=0)", True)])
def test_nested_and_instanced_match_list(outer, inner, instanced):
    rng = np.random.default_rng(7)
    scene = nested_scene(rng, outer, inner, instanced)
    o, d = random_rays(rng, 2000)
    oi, di = random_rays(rng, 500, inside=True)
    o, d = np.vstack([o, oi]), np.vstack([d, di])
    plain = nested_scene(np.random.default_rng(7), "list", "list", instanced)
    rs = same_hits_as_list(scene, "bvh", o, d, repeats=2, plain=plain)
    aggs = rs.build_stats["aggregates"]
    lazy = [a for a in aggs if a["kind"].startswith("lazyoctree")]
    assert lazy and len(lazy) == len(lazy_of(rs).parts[0].records)
    # nested ones refine too (every inner lazy octree here gets plenty of rays)
    assert all(a["subdivisions"] > 0 for a in lazy if "rays=1" in a["kind"])
    assert rs.build_stats["build.subdivisions"] == sum(a["subdivisions"] for a in lazy)


def instanced_scene(spec, seed=11):
    """A group shown through rotated, scaled instances, three levels deep; groups alternate spec and bvh."""
    rng = np.random.default_rng(seed)
    leaf = fill_group(Group(name="leaf", accel=spec), rng, n=10, spread=1.0)
    level = leaf
    for k in range(3):
        up = Group(name=f"l{k}", accel=spec if k % 2 else "bvh")
        up.add(Instance(level, rotation_scale(rng)))
        up.add(Instance(level, rotation_scale(rng)))
        level = up
    scene = new_scene()
    scene.root.accel = spec
    scene.root.add(level)
    return scene


@pytest.mark.parametrize("walk", WALKS)
def test_in_rotated_scaled_instances(walk):
    spec = f"lazyoctree(walk={walk}, rays=1, k=0)"
    o, d = random_rays(np.random.default_rng(12), 2500, spread=10.0)
    rs = same_hits_as_list(instanced_scene(spec), spec, o, d, repeats=2, plain=instanced_scene("list"))
    lazy = [a for a in rs.build_stats["aggregates"] if a["kind"].startswith("lazyoctree")]
    # the root holds one item (criterion III keeps it a leaf); the instanced ones refine
    assert [a["subdivisions"] > 0 for a in lazy] == [a["items"] > 1 for a in lazy] == [True, True, False]


def test_flat_and_empty_groups():
    scene = new_scene()
    rng = np.random.default_rng(3)
    for _ in range(40):
        c = np.append(rng.uniform(-4, 4, 2), 1.0)
        scene.root.polygons.add([c, c + [1, 0, 0], c + [0.5, 1, 0]], 0)
    scene.root.add(Group(name="empty", accel="lazyoctree"))
    o, d = random_rays(rng, 2000, spread=4.0)
    same_hits_as_list(scene, "lazyoctree(rays=1, k=0)", o, d, repeats=2)


# ---------------------------------------------------------------- renders

def test_pass_ranges():
    assert pass_ranges(100, 16, 64) == [(0, 16), (16, 32), (32, 64), (64, 100)]
    assert pass_ranges(300, 16, 64) == [(0, 16), (16, 32), (32, 64), (64, 128), (128, 192), (192, 256),
                                        (256, 300)]
    assert pass_ranges(10, 16, 64) == [(0, 10)]
    assert pass_ranges(0, 16, 64) == []
    assert pass_ranges(5, 1, 1) == [(0, 1), (1, 2), (2, 3), (3, 4), (4, 5)]
    # a render of 4 tiles of 16 rows, batches of one tile: the first tile cut into rows
    assert pass_ranges(64, 1, 16) == [(0, 1), (1, 2), (2, 4), (4, 8), (8, 16), (16, 32), (32, 48), (48, 64)]
    # RayScene: within the first chunk of 1024 rays, then whole chunks
    bounds = [b for _, b in pass_ranges(50000, 16, PASS)]
    assert bounds[:7] == [16, 32, 64, 128, 256, 512, 1024]
    assert all(b % CHUNK == 0 for b in bounds[6:-1]) and bounds[-1] == 50000
    for first, most in ((0, 4), (8, 4), (-1, 1)):
        with pytest.raises(ValueError, match="first"):
            pass_ranges(10, first, most)


def test_lazy_passes_go_coarse_to_fine():
    # 40 tiles in batches of 2: one sample per tile in runs of 1, 1, 2, 2, ...; then each finer level
    passes = RENDER.lazy_passes(40, 2)
    level0 = [p for p in passes if p[0] == RENDER.TILE]
    assert [(a, b) for _, _, a, b in level0] == [(0, 1), (1, 2)] + [(a, a + 2) for a in range(2, 40, 2)]
    assert all(coarse == 0 for _, coarse, _, _ in level0)
    for step in (8, 4, 2, 1):
        level = [(a, b) for s, coarse, a, b in passes if s == step and coarse == 2 * step]
        assert level == [(a, a + 2) for a in range(0, 40, 2)]
    assert len(passes) == len(level0) + 4 * 20
    assert RENDER.lazy_passes(1, 1) == [(16, 0, 0, 1), (8, 16, 0, 1), (4, 8, 0, 1), (2, 4, 0, 1), (1, 2, 0, 1)]


def test_render_passes_trace_every_sample_once_coarse_to_fine(monkeypatch):
    """The eye rays of each pass of a 48 x 48 SPD render: 49 x 49 corner samples in 4 x 4 tiles (three
    of 16 wide, then one 1 wide; likewise in height), one tile per batch; counted here from the tiles'
    sample lattices, and every sample traced once."""
    seen = []
    kernel = RENDER._render_tiles

    def recording(*args):
        # (geo, mats, lights, background, cam, w, h, tile_x, tile_y, counter, last, row0, max_depth, cutoff,
        #  filtered, tricks, starts, out, counters, passes, step, coarse, cull); the call claims tiles from
        # counter[0] up to last (a pass this small runs on one thread, so from its first tile)
        first = int(args[9][0])
        rows = args[18][first:args[10], C.RAYS_EYE]
        before = rows.sum()
        kernel(*args)
        seen.append((args[20], args[21], first, args[10], int(rows.sum() - before)))

    monkeypatch.setattr(RENDER, "_render_tiles", recording)
    scene = raykernel.load("spd:balls:1")
    got = raykernel.render(scene, accel="lazyoctree", resolution=48, spd=True)
    traced = np.zeros((49, 49), np.int64)
    for step, coarse, first, last, eye in seen:
        assert last == first + 1
        y0, x0 = divmod(first, 4)
        mine = [(j, i) for j in range(16 * y0, min(16 * y0 + 16, 49), step)
                for i in range(16 * x0, min(16 * x0 + 16, 49), step)
                if not (coarse and (j - 16 * y0) % coarse == 0 and (i - 16 * x0) % coarse == 0)]
        assert eye == len(mine)
        for j, i in mine:
            traced[j, i] += 1
    assert (traced == 1).all()
    assert [s[0] for s in seen] == [16] * 16 + [8] * 16 + [4] * 16 + [2] * 16 + [1] * 16
    assert [s[4] for s in seen[:16]] == [1] * 16      # one sample per tile first
    assert got.stats["rays.eye"] == 49 * 49 and got.stats["build.refine_passes"] == len(seen)
    # other structures trace whole tiles in one pass, every sample at once, each sample once
    seen.clear()
    whole = raykernel.render(scene, accel="bvh", resolution=48, spd=True, threads=1)
    assert [s[:4] for s in seen] == [(1, 0, 0, 16)] and seen[0][4] == 49 * 49 == whole.stats["rays.eye"]


@pytest.mark.parametrize("spec", ["lazyoctree", "bvh"])
def test_render_progress_counts_samples(spec):
    """48 x 48 SPD: 4 x 4 tiles of 256 samples (counted whole); one sample per tile first when lazy."""
    seen = []
    raykernel.render(raykernel.load("spd:balls:1"), accel=spec, resolution=48, spd=True,
                     progress=lambda done, total: seen.append((done, total)))
    assert all(total == 16 * 256 for _, total in seen) and seen[-1][0] == 16 * 256
    assert all(a[0] < b[0] for a, b in zip(seen, seen[1:]))
    if spec == "lazyoctree":
        assert seen[0][0] == 1          # one sample per tile first
    else:
        assert seen[0][0] % 256 == 0    # whole tiles (as many per pass as keep every thread busy)


def test_rayscene_casts_lazy_queries_coarse_to_fine():
    assert coarse_to_fine(8).tolist() == [0, 4, 2, 6, 1, 3, 5, 7]
    assert coarse_to_fine(1).tolist() == [0] and coarse_to_fine(0).tolist() == []
    for n in (2, 3, 13, 1000, 4097):
        order = coarse_to_fine(n)
        assert sorted(order.tolist()) == list(range(n))
        # every prefix of 2^k indices spreads over the whole array, one in each run of n / 2^k
        for k in range(1, n.bit_length()):
            head = np.sort(order[:1 << k])
            assert np.diff(head).max() <= 2 * -(-n // (1 << k))


def test_rayscene_lazy_passes_take_the_rays_coarse_to_fine(monkeypatch):
    """The rays each pass casts are those of coarse_to_fine, in pass_ranges' cuts; the hits come
    back in the rays' own order (checked against list)."""
    module = importlib.import_module("raykernel.casting.rayqueries")
    kernel = module._query
    passes = []

    def recording(geo, o, *rest):
        passes.append(o.copy())
        return kernel(geo, o, *rest)

    monkeypatch.setattr(module, "_query", recording)
    o, d = rays_past(100, np.random.default_rng(16))
    o[:, 2] = np.arange(100) * 0.008 - 0.4          # tell the rays apart
    o[::3, 0] = 2.0 * (np.arange(34) % 5)           # a third through the spheres, at different t
    rs = RayScene.from_scene(sphere_row(5), "lazyoctree(rays=1)")
    got = rs.intersect(o, d)
    order = coarse_to_fine(100)
    assert [len(p) for p in passes] == [b - a for a, b in pass_ranges(100, 16, PASS)] == [16, 16, 32, 36]
    np.testing.assert_array_equal(np.vstack(passes), o[order])
    want = RayScene.from_scene(sphere_row(5), "list").intersect(o, d)
    assert np.isfinite(want.t).sum() == 34 and len(np.unique(want.t)) > 20
    np.testing.assert_array_equal(got.t, want.t)
    np.testing.assert_array_equal(got.prim_id, want.prim_id)


def test_rayscene_passes_shorter_than_a_chunk_count_every_ray():
    """1000 rays, fewer than a chunk, in 7 passes; each crosses the one leaf (depth=0) of 5
    spheres and tests them all."""
    rs = RayScene.from_scene(sphere_row(5), "lazyoctree(depth=0)")
    o, d = rays_past(1000, np.random.default_rng(14))
    rs.intersect(o, d)
    assert rs.last_stats["tests.sphere"] == 1000 * 5
    assert rs.build_stats["build.refine_passes"] == 7


def test_rayscene_refines_after_its_first_16_rays():
    """32 rays between the spheres: the first 16 meet the one leaf of 5 spheres (80 tests), the
    next 16 a split tree."""
    rs = RayScene.from_scene(sphere_row(5), "lazyoctree(rays=1, k=0)")
    o, d = rays_past(32, np.random.default_rng(15))
    rs.intersect(o[:16], d[:16])
    assert rs.last_stats["tests.sphere"] == 16 * 5
    rs = RayScene.from_scene(sphere_row(5), "lazyoctree(rays=1, k=0)")
    rs.intersect(o, d)
    assert rs.build_stats["build.refine_passes"] == 2 and rs.build_stats["build.subdivisions"] >= 1
    assert rs.last_stats["tests.sphere"] < 16 * 5 + 16 * 5


def stats_of_tree(geo, octree=0):
    """N_IN, N_V, N_EV, N_OIV of the tree reachable from the root, counted from the arrays."""
    nodes, _ = tree_of(geo, octree)
    leaves = [v for v in nodes.values() if v != "inner"]
    return {"nodes": len(nodes), "inner": len(nodes) - len(leaves), "leaves": len(leaves),
            "empty_leaves": sum(1 for v in leaves if not v), "refs": sum(len(v) for v in leaves)}


@pytest.mark.parametrize("name", ["spd:balls:1", "spd:gears:1"])
def test_spd_render_matches_bvh(name):
    scene = raykernel.load(name)
    bvh = raykernel.render(scene, accel="bvh", resolution=48, spd=True)
    rays = ray_counts(bvh.stats)
    # 49 x 49 corner samples: 4 x 4 tiles of 16, fewer than 32, so one tile per batch, at each of
    # the five lattice steps 16, 8, 4, 2, 1
    batches = 5 * 16
    for walk in WALKS:
        got = raykernel.render(scene, accel=f"lazyoctree(walk={walk})", resolution=48, spd=True)
        np.testing.assert_array_equal(got.image, bvh.image)
        assert {k: got.stats[k] for k in rays} == rays
        agg = got.stats.aggregates[0]
        assert agg["subdivisions"] > 0 and agg["passes"] == got.stats["build.refine_passes"] == batches
        assert agg["nodes"] == got.stats["build.nodes"] == 1 + 8 * agg["subdivisions"]
        assert agg["nodes"] == agg["inner"] + agg["leaves"] and agg["inner"] == agg["subdivisions"]
        assert got.stats["build.refs"] == agg["refs"] and got.stats["build.empty_leaves"] == agg["empty_leaves"]


def test_render_stats_are_the_final_tree():
    scene = raykernel.load("spd:balls:1")
    res = raykernel.render(scene, accel="lazyoctree(rays=1, k=0)", resolution=32, spd=True)
    # the same render again: the same image, tree and counters
    again = raykernel.render(scene, accel="lazyoctree(rays=1, k=0)", resolution=32, spd=True)
    assert res.image.tobytes() == again.image.tobytes()
    keys = [k for k, v in res.stats.items() if isinstance(v, int)]
    assert {k: res.stats[k] for k in keys} == {k: again.stats[k] for k in keys}
    rs = RayScene.from_scene(scene, "lazyoctree(rays=1, k=0)")
    o, d = random_rays(np.random.default_rng(1), 3000, spread=2.0)
    for _ in range(3):
        rs.count_hits(o, d)
    want = stats_of_tree(rs.geo)
    agg = rs.build_stats["aggregates"][0]
    assert {k: agg[k] for k in want} == want
    assert agg["bytes"] == want["nodes"] * lazyoctree.NODE_BYTES + 8 * want["refs"] + 48
    assert rs.build_stats["build.bytes"] == sum(a.nbytes for a in rs.geo if isinstance(a, np.ndarray))



"""Haines's hybrid: octree with a Goldsmith-Salmon BVH in every problem voxel, against the list."""

from __future__ import annotations

import copy
import time

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
    ray_counts,
)

import raykernel
from raykernel.aggregates.hybrid import clip_margin, clipped_bounds, problem_voxels, replace_leaves
from raykernel.aggregates.octbuild import build_octree
from raykernel.casting.rayscene import RayScene
from raykernel.aggregates.bvhwalk import CODE as BVH
from raykernel.aggregates.walk import MAX_NESTING
from raykernel.aggregates.octree import CODE as OCTREE
from raykernel.engine.flatten import flatten
from raykernel.engine.traverse import cast_rays
from raykernel.errors import OptionError, SceneError
from raykernel.geometry import counters as C
from raykernel.geometry.primitives import AGGREGATE, INDEX_MASK, KIND_SHIFT, POLYGON, SPHERE
from raykernel.scene import Group, pathological
from raykernel.aggregates.registry import describe, parse_spec
from raykernel.scene.jsonscene import scene_from_json

WALKS = ("point", "neighbor", "parametric")


def hybrid_stats(stats):
    """The build statistics of every (non-empty) hybrid in the scene."""
    return [a for a in stats["aggregates"] if a["kind"].startswith("hybrid") and "problem_voxels" in a]


def crowd(group, rng, centre, n=60, spread=0.3, size=0.05):
    """Small spheres and triangles packed around `centre`: a dense object in a small region."""
    centre = np.asarray(centre, np.float64)
    for _ in range(n):
        group.spheres.add(centre + rng.normal(0, spread, 3), rng.uniform(0.2, 1.0) * size, 0)
    for _ in range(n // 2):
        c = centre + rng.normal(0, spread, 3)
        group.polygons.add(c + rng.normal(0, 2 * size, (3, 3)), 0)
    return group


def mixed_scene(seed, n=25, big=False):
    rng = np.random.default_rng(seed)
    scene = new_scene()
    fill_group(scene.root, rng, n=n, big=big)
    crowd(scene.root, rng, rng.uniform(-2, 2, 3))
    return scene, rng


# ---------------------------------------------------------------- the module's helpers

def random_boxes(rng, n=200):
    lo = rng.uniform(-5, 5, (n, 3))
    boxes = np.hstack([lo, lo + rng.uniform(0, 2.5, (n, 3))])
    # a dense cluster that depth 3 cannot separate
    c = rng.uniform(-1, 1, (40, 3))
    return np.vstack([boxes, np.hstack([c, c + 0.01])])


def leaf_items(tree, node):
    return tree.order[tree.first[node]:tree.first[node] + tree.count[node]].tolist()


def test_problem_voxels_are_the_leaves_over_threshold():
    tree, _ = build_octree(random_boxes(np.random.default_rng(1)), depth=3, leaf=2)
    for threshold in (1, 4, 20):
        got = problem_voxels(tree, threshold)
        want = [n for n in range(len(tree.count)) if tree.count[n] >= 0 and tree.count[n] > threshold]
        assert got.tolist() == want
    assert len(problem_voxels(tree, 20)) > 0
    assert len(problem_voxels(tree, 10 ** 6)) == 0


@pytest.mark.parametrize("collapse", [True, False])
def test_replace_leaves_keeps_other_leaves_and_puts_one_entry_in_each_voxel(collapse):
    tree, _ = build_octree(random_boxes(np.random.default_rng(2)), depth=3, leaf=2, collapse=collapse)
    voxels = problem_voxels(tree, 6)
    assert 0 < len(voxels) < int(np.sum(tree.count >= 0))
    new = replace_leaves(tree, voxels, 1000)
    for field in ("origin", "unit", "loc", "level", "slot", "nbr", "bounds"):
        np.testing.assert_array_equal(getattr(new, field), getattr(tree, field))
    inner = tree.count < 0
    np.testing.assert_array_equal(new.count[inner], tree.count[inner])
    np.testing.assert_array_equal(new.first[inner], tree.first[inner])
    for j, n in enumerate(voxels):
        assert new.count[n] == 1 and leaf_items(new, n) == [1000 + j]
    others = [n for n in np.flatnonzero(~inner) if n not in set(voxels.tolist())]
    for n in others:
        assert leaf_items(new, n) == leaf_items(tree, n)
    # the lists tile the new order exactly, in node order
    leaves = np.flatnonzero(~inner)
    assert new.first[leaves].tolist() == np.concatenate([[0], np.cumsum(new.count[leaves])[:-1]]).tolist()
    assert len(new.order) == int(new.count[leaves].sum())
    # no voxel: the same tree
    same = replace_leaves(tree, voxels[:0], 1000)
    np.testing.assert_array_equal(same.order, tree.order)
    np.testing.assert_array_equal(same.first, tree.first)


def test_clipped_bounds_cover_the_items_inside_the_voxel():
    boxes = random_boxes(np.random.default_rng(3))
    depth = 3
    tree, _ = build_octree(boxes, depth=depth, leaf=2)
    voxels = problem_voxels(tree, 4)
    assert len(voxels)
    for n in voxels:
        items = np.array(leaf_items(tree, n))
        cut = clipped_bounds(tree, boxes, n, items, depth)
        m = clip_margin(tree, n, depth)
        assert np.all(m > 0)
        assert np.all(cut[:, :3] <= cut[:, 3:])
        # inside the item's box and inside the voxel widened by the margin
        assert np.all(cut[:, :3] >= boxes[items, :3]) and np.all(cut[:, 3:] <= boxes[items, 3:])
        assert np.all(cut[:, :3] >= tree.bounds[n, :3] - m) and np.all(cut[:, 3:] <= tree.bounds[n, 3:] + m)
        # and holding all of the item that lies in the voxel
        lo = np.maximum(boxes[items, :3], tree.bounds[n, :3])
        hi = np.minimum(boxes[items, 3:], tree.bounds[n, 3:])
        solid = np.all(lo <= hi, axis=1)
        assert np.all(cut[solid, :3] <= lo[solid]) and np.all(cut[solid, 3:] >= hi[solid])


# ---------------------------------------------------------------- spec and build statistics

def test_spec_defaults_and_listing():
    kind, params = parse_spec("hybrid")
    assert kind == "hybrid"
    assert params == {"depth": 8, "leaf": 3, "rule60": True, "density": 0.0, "vertexcount": False,
                      "collapse": True, "budget": 16.0, "threshold": 8, "order": "file", "seed": 1,
                      "walk": "neighbor", "mailbox": True}
    text = describe()
    assert "hybrid: " in text and "threshold=8" in text and "Goldsmith-Salmon" in text


@pytest.mark.parametrize("text, words", [
    ("hybrid(threshold=0)", ["threshold", "[1, 1073741824]", "got 0"]), ("hybrid(depth=25)", ["depth", "[0, 24]"]),
    ("hybrid(leaf=0)", ["leaf"]), ("hybrid(order=random)", ["order", "file, shuffle, curve"]),
    ("hybrid(walk=sideways)", ["walk", "point, neighbor, parametric"]), ("hybrid(rule60=maybe)", ["on or off"]),
    ("hybrid(seed=-1)", ["seed"]), ("hybrid(density=-1)", ["density"]), ("hybrid(threshold=many)", ["threshold"]),
    ("hybrid(budget=-1)", ["budget", "[0.0, "]),
    ("hybrid(bins=4)", ["depth, leaf, rule60, density, vertexcount, collapse, budget, threshold, order, seed, "
                        "walk, mailbox"]),
    ("hybrid(threshold)", ["key=value"])])
def test_bad_parameters_are_option_errors(text, words):
    with pytest.raises(OptionError) as err:
        parse_spec(text)
    for w in words:
        assert w in str(err.value)


def test_flatten_stores_an_octree_with_bvhs_in_its_problem_voxels():
    scene, _ = mixed_scene(4)
    spec = "hybrid(depth=3, threshold=6)"
    t0 = time.perf_counter()
    geo, stats = flatten(scene, spec)
    wall = time.perf_counter() - t0
    (h,) = hybrid_stats(stats)
    assert geo.agg_kind[geo.root] == OCTREE
    n_bvh = int(np.sum(geo.agg_kind == BVH))
    assert h["bvhs"] == h["problem_voxels"] == n_bvh > 0
    assert stats["build.aggregates"] == 1 + n_bvh and stats["build.nesting"] == 2
    # the octree part is exactly what the octree kind builds with the same criteria
    _, plain = flatten(scene, "octree(depth=3, rule60=on)")
    assert h["octree_nodes"] == plain["build.nodes"] == len(geo.oct_count)
    assert h["octree_empty_leaves"] == plain["build.empty_leaves"]
    assert h["bvh_nodes"] == len(geo.node_count)
    for key in ("nodes", "inner", "leaves", "empty_leaves", "refs", "bytes"):
        assert h[key] == h[f"octree_{key}"] + h[f"bvh_{key}"]
    assert stats["build.nodes"] == h["nodes"] and stats["build.refs"] == h["refs"] == len(geo.refs)
    assert stats["build.empty_leaves"] == h["empty_leaves"]
    # both parts took time, together within the hybrid's build (measured around it), within the call's
    assert h["octree_seconds"] > 0.0 and h["bvh_seconds"] > 0.0
    assert h["octree_seconds"] + h["bvh_seconds"] <= h["seconds"] <= stats["build.seconds"] <= wall
    assert h["bvh_max_depth"] > 0
    # every problem voxel holds one reference to its own BVH, over exactly the voxel's items
    # (the plain octree has the same nodes, numbered alike)
    plain_geo, _ = flatten(scene, "octree(depth=3, rule60=on)")
    voxels = np.flatnonzero(plain_geo.oct_count > 6)
    assert len(voxels) == n_bvh
    small = plain_geo.oct_count <= 6
    np.testing.assert_array_equal(geo.oct_count[small], plain_geo.oct_count[small])
    seen = set()
    for n in voxels:
        s, c = geo.oct_first[n], geo.oct_count[n]
        assert c == 1
        ref = geo.refs[s]
        agg = int(ref & INDEX_MASK)
        assert ref >> KIND_SHIFT == AGGREGATE and geo.agg_kind[agg] == BVH and agg not in seen
        seen.add(agg)
        leaves = [k for k in range(geo.agg_start[agg], geo.agg_start[agg] + geo.agg_count[agg])
                  if geo.node_count[k] > 0]
        held = sorted(int(r) for k in leaves for r in geo.refs[geo.node_first[k]:geo.node_first[k]
                                                               + geo.node_count[k]])
        first = plain_geo.oct_first[n]
        assert held == sorted(plain_geo.refs[first:first + plain_geo.oct_count[n]].tolist())
        # the BVH's box lies within the voxel (cut boxes), not over its items' whole boxes
        box = geo.oct_bounds[n]
        slack = 1e-6 * (box[3:] - box[:3]).max()
        assert np.all(geo.agg_bounds[agg, :3] >= box[:3] - slack)
        assert np.all(geo.agg_bounds[agg, 3:] <= box[3:] + slack)


def test_no_problem_voxel_is_a_plain_octree():
    scene, _ = mixed_scene(5)
    geo, stats = flatten(scene, "hybrid(threshold=100000)")
    (h,) = hybrid_stats(stats)
    assert h["problem_voxels"] == h["bvhs"] == h["bvh_nodes"] == 0
    assert stats["build.aggregates"] == 1 and stats["build.nesting"] == 1
    _, plain = flatten(scene, "octree(rule60=on)")
    assert stats["build.nodes"] == plain["build.nodes"] and stats["build.refs"] == plain["build.refs"]


# ---------------------------------------------------------------- hits against the list

SPECS = ["hybrid", "hybrid(depth=3, threshold=4)", "hybrid(depth=2, leaf=1, threshold=1, mailbox=off)",
         "hybrid(rule60=off, depth=4, threshold=2, order=shuffle, seed=7)", "hybrid(order=curve, threshold=3)",
         "hybrid(density=0.5, threshold=2)", "hybrid(vertexcount=on, leaf=6, depth=3, threshold=5)",
         "hybrid(collapse=off, depth=3, threshold=3)"]


@pytest.mark.parametrize("walk", WALKS)
@pytest.mark.parametrize("spec", SPECS)
def test_random_scenes_match_list(walk, spec):
    spec = spec[:-1] + f", walk={walk})" if "(" in spec else f"{spec}(walk={walk})"
    for seed in (0, 1):
        scene, rng = mixed_scene(seed, big=seed == 1)
        o, d = random_rays(rng, 800)
        oi, di = random_rays(rng, 300, inside=True)
        aim = rng.uniform(-2, 2, (200, 3))
        o, d = np.vstack([o, oi, aim + 8.0]), np.vstack([d, di, -8.0 + rng.normal(0, 0.3, (200, 3))])
        ref = cast(scene, "list", o, d)
        assert np.isfinite(ref[0]).sum() > 300
        geo, stats = flatten(scene, spec)
        if "threshold" in spec:
            assert hybrid_stats(stats)[0]["bvhs"] > 0
        got = cast_rays(geo, o, d)
        assert_same_hits(got, ref)
        cnt = got[4]
        assert cnt[C.CELLS_VISITED] >= cnt[C.CELLS_LEAVES] >= cnt[C.CELLS_EMPTY] and cnt[C.CELLS_LEAVES] > 0
        if "mailbox=off" in spec:
            assert cnt[C.MAILBOX_SAVED] == 0
        for tmax in (0.5, np.inf):
            shadow = cast_rays(geo, o, d, tmax=tmax, any_hit=True)
            np.testing.assert_array_equal(np.isfinite(shadow[0]), np.isfinite(cast(scene, "list", o, d,
                                                                                    tmax=tmax)[0]))


def test_all_hits_match_list():
    scene, rng = mixed_scene(2, big=True)
    o, d = random_rays(rng, 1500)
    ref = RayScene(scene, "list")
    want = ref.intersect_all(o, d, ids=True)
    assert len(want[0]) > 1000
    for spec in ("hybrid(depth=3, threshold=3)", "hybrid(depth=2, threshold=1, mailbox=off, walk=parametric)"):
        rs = RayScene(scene, spec)
        assert hybrid_stats(rs.build_stats)[0]["bvhs"] > 0
        got = rs.intersect_all(o, d, ids=True)
        for a, b in zip(got, want):
            np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(rs.count_hits(o, d), ref.count_hits(o, d))


def test_closest_hit_ties_go_to_the_smallest_reference():
    """Coincident copies of a sphere and a square, crowded into problem voxels: every structure
    reports the first copy, whichever voxel's BVH finds a copy first."""
    scene = new_scene()
    rng = np.random.default_rng(9)
    for _ in range(6):
        scene.root.spheres.add((0.5, 0.5, 0.5), 0.4, 0)
    for _ in range(6):
        scene.root.polygons.add([(2, 0, 0), (3, 0, 0), (3, 1, 0), (2, 1, 0)], 0)
    crowd(scene.root, rng, (1.5, 3.0, 0.5), n=30, spread=0.2)      # beside the rays
    o = np.column_stack([rng.uniform(0.2, 0.8, 400), rng.uniform(0.2, 0.8, 400), np.full(400, -3.0)])
    o[200:, 0] += 2.0
    o[200:, 2] = 3.0
    d = np.tile([0.0, 0.0, 1.0], (400, 1))
    d[200:, 2] = -1.0
    ref = cast(scene, "list", o, d)
    assert np.all(np.isfinite(ref[0][200:]))
    for walk in WALKS:
        geo, stats = flatten(scene, f"hybrid(depth=2, leaf=1, threshold=2, walk={walk})")
        assert hybrid_stats(stats)[0]["bvhs"] > 0
        got = cast_rays(geo, o, d)
        assert_same_hits(got, ref)
        assert set(got[1][:200][np.isfinite(got[0][:200])].tolist()) == {SPHERE}
        assert set(got[2][:200][np.isfinite(got[0][:200])].tolist()) == {0}      # sphere 0 of the six copies
        assert set(got[1][200:].tolist()) == {POLYGON} and set(got[2][200:].tolist()) == {0}


@pytest.mark.parametrize("walk", WALKS)
def test_axis_parallel_and_cell_boundary_rays(walk):
    scene = lattice_scene()
    o, d = axis_and_boundary_rays()
    ref = cast(scene, "list", o, d)
    for extra in ("depth=2, leaf=1, threshold=1", "depth=1, leaf=1, threshold=2, collapse=off"):
        geo, stats = flatten(scene, f"hybrid(walk={walk}, {extra})")
        assert hybrid_stats(stats)[0]["bvhs"] > 0
        assert_same_hits(cast_rays(geo, o, d), ref)


def test_mailbox_only_saves_tests():
    scene, rng = mixed_scene(6, big=True)
    o, d = random_rays(rng, 2000)
    on = cast(scene, "hybrid(rule60=off, depth=3, threshold=4)", o, d)
    off = cast(scene, "hybrid(rule60=off, depth=3, threshold=4, mailbox=off)", o, d)
    assert_same_hits(on, off)
    tests = slice(C.TESTS, C.TESTS + 5)
    assert on[4][C.MAILBOX_SAVED] > 0 and off[4][C.MAILBOX_SAVED] == 0
    assert on[4][tests].sum() + on[4][C.MAILBOX_SAVED] == off[4][tests].sum()
    assert on[4][C.CELLS_VISITED] == off[4][C.CELLS_VISITED]
    assert on[4][C.BOUNDS_TESTS] == off[4][C.BOUNDS_TESTS]


def test_counts_are_the_same_across_runs_and_chunkings():
    scene, rng = mixed_scene(7)
    o, d = random_rays(rng, 3000)
    geo, _ = flatten(scene, "hybrid(depth=3, threshold=3)")
    a = cast_rays(geo, o, d)
    b = cast_rays(geo, o, d)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
    parts = [cast_rays(geo, o[k:k + 700], d[k:k + 700])[4] for k in range(0, 3000, 700)]
    np.testing.assert_array_equal(np.sum(parts, axis=0)[:C.RAYS_CAST], a[4][:C.RAYS_CAST])


# ---------------------------------------------------------------- the teapot in a stadium

def teapot_rays(scene, ratio, rng, n=600):
    """Rays from the camera at the teapot, from the stands at the teapot, and across the stadium."""
    size = pathological.STADIUM_LENGTH / ratio
    target = scene.camera.look_at + rng.normal(0, 0.3 * size, (n, 3))
    eye = np.tile(scene.camera.eye, (n, 1))
    stands = rng.uniform([-150, -210, 1], [450, 210, 60], (n, 3))
    across_o = rng.uniform([-150, -210, 0], [450, 210, 80], (n, 3))
    across_t = rng.uniform([-150, -210, 0], [450, 210, 10], (n, 3))
    o = np.vstack([eye, stands, across_o])
    d = np.vstack([target - eye, target - stands, across_t - across_o])
    return o, d


@pytest.mark.parametrize("ratio", [1.0, 1e6])
def test_stadium_matches_list(ratio):
    scene = pathological.stadium(ratio=ratio, stadium_prims=800, teapot_prims=300)
    rng = np.random.default_rng(int(ratio) % 97)
    o, d = teapot_rays(scene, ratio, rng)
    ref = cast(scene, "list", o, d)
    assert np.isfinite(ref[0][:600]).sum() > 300
    for spec in ("hybrid", "hybrid(walk=point)", "hybrid(walk=parametric, mailbox=off)",
                 "hybrid(depth=12, leaf=1, threshold=4)"):
        geo, stats = flatten(scene, spec)
        assert hybrid_stats(stats)[0]["bvhs"] > 0
        assert_same_hits(cast_rays(geo, o, d), ref)


def test_stadium_hybrid_tests_far_fewer_than_the_octree():
    """At a ratio of 1e6 the whole teapot falls into one voxel of the depth-8 octree; the hybrid's
    BVH there cuts the tests per ray by more than ten times (counts, not time)."""
    scene = pathological.stadium(ratio=1e6, stadium_prims=800, teapot_prims=300)
    rng = np.random.default_rng(3)
    o, d = teapot_rays(scene, 1e6, rng)
    o, d = o[:600], d[:600]
    tests = slice(C.TESTS, C.TESTS + 5)
    octree = cast(scene, "octree", o, d)
    hybrid = cast(scene, "hybrid", o, d)
    assert_same_hits(hybrid, octree)
    assert hybrid[4][tests].sum() * 10 < octree[4][tests].sum()
    # and the same holds against the octree with the same criteria (rule60 on)
    octree60 = cast(scene, "octree(rule60=on)", o, d)
    assert hybrid[4][tests].sum() * 10 < octree60[4][tests].sum()
    # the teapot's voxel is a problem voxel of the plain octree
    geo, stats = flatten(scene, "octree")
    assert geo.oct_count.max() > 100
    _, hstats = flatten(scene, "hybrid")
    assert hybrid_stats(hstats)[0]["problem_voxels"] >= 1


def test_teapot_in_a_stadium_by_hand():
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
    for walk in WALKS:
        geo, stats = flatten(scene, f"hybrid(walk={walk}, threshold=4)")
        assert hybrid_stats(stats)[0]["bvhs"] > 0
        assert_same_hits(cast_rays(geo, o, d), ref)


# ---------------------------------------------------------------- nesting (JSON scenes)

def crowd_items(rng, centre, n=40, spread=0.25, size=0.06):
    out = []
    for _ in range(n):
        out.append({"sphere": {"center": (centre + rng.normal(0, spread, 3)).tolist(),
                               "radius": float(rng.uniform(0.3, 1.0) * size)}})
    for _ in range(n // 2):
        c = centre + rng.normal(0, spread, 3)
        out.append({"polygon": (c + rng.normal(0, 2 * size, (3, 3))).tolist()})
    return out


def scatter_items(rng, n=12, spread=4.0):
    out = [{"sphere": {"center": rng.uniform(-spread, spread, 3).tolist(), "radius": float(rng.uniform(0.2, 0.7))}}
           for _ in range(n)]
    base = rng.uniform(-spread, spread, 3)
    out.append({"cone": {"base": base.tolist(), "base_radius": 0.3, "apex": (base + [0, 0, 1.5]).tolist(),
                         "apex_radius": 0.1}})
    out.append({"polygon": [[-6, -6, -4.5], [6, -6, -4.5], [6, 6, -4.5], [-6, 6, -4.5]]})
    return out


def as_list(doc):
    """The same scene with every structure a list: the reference."""
    doc = copy.deepcopy(doc)

    def visit(x):
        if isinstance(x, dict):
            for k, v in x.items():
                if k == "accel":
                    x[k] = "list"
                else:
                    visit(v)
        elif isinstance(x, list):
            for v in x:
                visit(v)
    visit(doc)
    return doc


def hybrid_in_bvh(rng, walk):
    return {"scene": {"accel": "bvh", "items": scatter_items(rng) + [
        {"group": {"accel": f"hybrid(depth=3, threshold=4, walk={walk})",
                   "items": crowd_items(rng, np.array([1.0, 0.5, 0.0])) + scatter_items(rng, 4, 2.0)}},
        {"group": {"accel": "bvh", "items": [
            {"group": {"accel": f"hybrid(depth=2, threshold=2, walk={walk}, mailbox=off)",
                       "items": crowd_items(rng, np.array([-2.0, -1.0, 1.0]), n=20)}}]}}]}}


def grid_in_hybrid(rng, walk):
    groups = [{"group": {"accel": ["grid", "grid(res=woo)", "bvh", "list"][k % 4],
                         "items": crowd_items(rng, rng.uniform(-0.5, 0.5, 3), n=12, spread=0.3)}}
              for k in range(8)]
    return {"scene": {"accel": f"hybrid(depth=2, leaf=1, threshold=3, walk={walk})",
                      "items": scatter_items(rng) + groups + crowd_items(rng, np.zeros(3), n=20)}}


def instanced_hybrid(rng, walk):
    transforms = [[{"rotate": {"axis": rng.normal(0, 1, 3).tolist(), "degrees": float(rng.uniform(0, 360))}},
                   {"scale": rng.uniform(0.5, 2.0, 3).tolist()}, {"translate": rng.uniform(-3, 3, 3).tolist()}]
                  for _ in range(4)]
    return {"groups": {"thing": {"accel": f"hybrid(depth=3, threshold=3, walk={walk})",
                                 "items": crowd_items(rng, np.zeros(3), n=30) + scatter_items(rng, 5, 1.5)}},
            "scene": {"accel": f"hybrid(threshold=2, walk={walk})",
                      "items": scatter_items(rng) + [{"instance": "thing", "transform": t} for t in transforms]
                      + [{"instance": "thing"}]}}


@pytest.mark.parametrize("walk", WALKS)
@pytest.mark.parametrize("make", [hybrid_in_bvh, grid_in_hybrid, instanced_hybrid])
def test_nested_json_scenes_match_list(make, walk):
    rng = np.random.default_rng(11)
    doc = make(rng, walk)
    scene = scene_from_json(doc)
    ref_scene = scene_from_json(as_list(doc))
    o, d = random_rays(rng, 1500)
    aim = rng.normal(0, 1.0, (500, 3))
    o2 = rng.normal(0, 1, (500, 3)) * 8.0
    o, d = np.vstack([o, o2]), np.vstack([d, aim - o2])
    ref = cast(ref_scene, "list", o, d)
    assert np.isfinite(ref[0]).sum() > 400
    geo, stats = flatten(scene, "list")
    hy = hybrid_stats(stats)
    assert hy and all(h["bvhs"] > 0 for h in hy)
    got = cast_rays(geo, o, d)
    assert_same_hits(got, ref)
    if make is instanced_hybrid:
        assert np.any(ref[3] >= 0)
        assert len(hy) == 2                  # the instanced group is built once
    if make is grid_in_hybrid:
        # some problem voxel's BVH holds grids, so a path runs octree -> BVH -> grid
        assert stats["build.nesting"] == 3
    shadow = cast_rays(geo, o, d, tmax=0.5, any_hit=True)
    np.testing.assert_array_equal(np.isfinite(shadow[0]), np.isfinite(cast(ref_scene, "list", o, d, tmax=0.5)[0]))


def nested_chain(levels, inner_spec):
    """`levels` aggregates one inside the next; the innermost (level `levels`) is a crowd under inner_spec."""
    rng = np.random.default_rng(12)
    scene = new_scene()
    scene.root.accel = "list"
    group = scene.root
    for k in range(levels - 1):
        group.spheres.add((0.0, 5.0, 3.0 * k), 0.5, 0)
        child = Group(name=f"level{k + 1}", accel="bvh")
        group.add(child)
        group = child
    group.accel = inner_spec
    crowd(group, rng, (0.0, 0.0, 0.0), n=40, spread=0.2)
    return scene


def test_nesting_limit():
    spec = "hybrid(depth=1, leaf=1, threshold=2)"
    _, stats = flatten(nested_chain(MAX_NESTING - 1, spec), "bvh")
    assert stats["build.nesting"] == MAX_NESTING and hybrid_stats(stats)[0]["bvhs"] > 0
    # one level deeper, the innermost hybrid's BVHs would be the 17th aggregate on a path
    with pytest.raises(SceneError, match=f"the limit is {MAX_NESTING}"):
        flatten(nested_chain(MAX_NESTING, spec), "bvh")
    assert flatten(nested_chain(MAX_NESTING, "octree(depth=1, leaf=1)"), "bvh")[1]["build.nesting"] == MAX_NESTING


def test_hybrid_over_children_nested_to_the_limit_keeps_its_items():
    """A hybrid whose own children already nest MAX_NESTING - 1 deep has no room for a BVH: its
    problem voxels keep their items, and hits stay exact."""
    chain = nested_chain(MAX_NESTING - 1, "bvh")
    scene = new_scene()
    rng = np.random.default_rng(13)
    crowd(scene.root, rng, (0.0, 0.0, 0.0), n=40, spread=0.2)
    scene.root.add(chain.root)
    chain.root.accel = "bvh"
    geo, stats = flatten(scene, "hybrid(depth=1, leaf=1, threshold=2)")
    (h,) = hybrid_stats(stats)
    assert h["problem_voxels"] > 0 and h["bvhs"] == 0
    assert stats["build.nesting"] == MAX_NESTING
    o = rng.normal(0, 1, (800, 3)) * 10.0
    d = rng.normal(0, 0.3, (800, 3)) - o
    ref = cast(scene, "list", o, d)
    assert np.isfinite(ref[0]).sum() > 100
    assert_same_hits(cast_rays(geo, o, d), ref)


# ---------------------------------------------------------------- degenerate scenes

@pytest.mark.parametrize("walk", WALKS)
def test_flat_one_item_and_empty_scenes(walk):
    scene = new_scene()
    rng = np.random.default_rng(3)
    for _ in range(60):
        c = np.append(rng.uniform(-1, 1, 2), 1.0)
        scene.root.polygons.add([c, c + [1, 0, 0], c + [0.5, 1, 0]], 0)
    o, d = random_rays(rng, 1000, spread=2.0)
    ref = cast(scene, "list", o, d)
    assert np.isfinite(ref[0]).sum() > 20
    geo, stats = flatten(scene, f"hybrid(walk={walk}, depth=2, threshold=4)")
    assert hybrid_stats(stats)[0]["bvhs"] > 0
    assert_same_hits(cast_rays(geo, o, d), ref)

    one = new_scene()
    one.root.spheres.add((1, 2, 3), 1.0, 0)
    one.root.add(Group(name="empty", accel=f"hybrid(walk={walk})"))
    o = np.array([[1, 2, -5.0], [1, 2, 3.0], [5, 5, 5.0]])
    d = np.array([[0, 0, 1.0], [0, 1, 0.0], [1, 0, 0.0]])
    for threshold in (1, 8):
        geo, stats = flatten(one, f"hybrid(walk={walk}, threshold={threshold})")
        t, _, index, _, _ = cast_rays(geo, o, d)
        assert t[0] == pytest.approx(7.0) and t[1] == pytest.approx(1.0) and np.isinf(t[2])
        assert index[:2].tolist() == [0, 0]
        assert hybrid_stats(stats)[0]["bvhs"] == 0      # one item: no leaf holds more than one
    coincident = new_scene()
    for _ in range(5):
        coincident.root.spheres.add((1, 2, 3), 1.0, 0)
    geo, stats = flatten(coincident, f"hybrid(walk={walk}, threshold=1)")
    assert hybrid_stats(stats)[0]["bvhs"] == 1
    t, _, index, _, _ = cast_rays(geo, o, d)
    assert t[0] == pytest.approx(7.0) and index[0] == 0 and np.isinf(t[2])

    empty = new_scene()
    empty.root.accel = f"hybrid(walk={walk})"
    geo, stats = flatten(empty, "list")
    assert np.all(np.isinf(cast_rays(geo, o, d)[0]))
    assert stats["build.nodes"] == 0 and stats["aggregates"][0]["kind"].startswith("hybrid")


# ---------------------------------------------------------------- renders

@pytest.mark.parametrize("name", ["spd:balls:1", "spd:gears:1"])
def test_spd_render_matches_bvh(name):
    scene = raykernel.load(name)
    bvh = raykernel.render(scene, accel="bvh", resolution=32, spd=True)
    rays = ray_counts(bvh.stats)
    assert rays
    for spec in ("hybrid", "hybrid(depth=3, threshold=2, walk=parametric)"):
        got = raykernel.render(scene, accel=spec, resolution=32, spd=True)
        np.testing.assert_array_equal(got.image, bvh.image)
        assert {k: got.stats[k] for k in rays} == rays
        assert got.stats["cells.visited"] > 0
    _, stats = flatten(scene, "hybrid(depth=3, threshold=2)")
    assert hybrid_stats(stats)[0]["bvhs"] > 0


def test_budget_is_the_octrees():
    """The stadium's octree without rule60 at depth 10: a budget of 1 reference per item (+ 4096)
    keeps it smaller than no budget, and the hits stay those of the list."""
    scene = pathological.stadium()
    plain = copy.deepcopy(scene)
    _, free = flatten(scene, "hybrid(depth=10, rule60=off, budget=0)")
    geo, held = flatten(scene, "hybrid(depth=10, rule60=off, budget=1)")
    (f,), (h,) = hybrid_stats(free), hybrid_stats(held)
    items = f["items"]
    assert f["octree_refs"] > items + 4096 and h["octree_nodes"] < f["octree_nodes"]
    ref, _ = flatten(plain, "list")
    o, d = random_rays(np.random.default_rng(31), 3000, spread=300.0)
    assert_same_hits(cast_rays(geo, o, d), cast_rays(ref, o, d))

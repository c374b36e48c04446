"""The k-d tree (aggregates/kdtree.py) and Octree-R, stored as one: their builds against the item
boxes, their walk against the brute-force list on rays that graze, lie in and start on its planes,
Octree-R's planes against its cost estimate, its centre planes against the octree's, the counts, the
options, and what adding the k-d tree took outside its module."""

from __future__ import annotations

import io
import tokenize
from pathlib import Path

import numpy as np
import pytest
from support import assert_same_hits, cast, fill_group, new_scene, random_rays, work_counts

import raykernel
from raykernel.aggregates import kdtree
from raykernel.aggregates.memory import MemoryBudgetError
from raykernel.aggregates.registry import parse_spec
from raykernel.errors import OptionError
from raykernel.scene import Group, Instance, TriangleMesh

ROOT = Path(raykernel.__file__).resolve().parents[2]


def leaf_regions(tree):
    """(box, items) of every leaf, walking the tree from its root box."""
    out, todo = [], [(0, tree.box.copy())]
    while todo:
        node, box = todo.pop()
        m = tree.count[node]
        if m >= 0:
            out.append((box, set(tree.order[tree.child[node]:tree.child[node] + m].tolist())))
            continue
        axis, s = -1 - m, tree.split[node]
        below, above = box.copy(), box.copy()
        below[axis + 3] = s
        above[axis] = s
        assert box[axis] < s < box[axis + 3]        # a plane strictly inside its node
        todo += [(node + 1, below), (tree.child[node], above)]
    return out


BUILDERS = {"kdtree": lambda boxes: kdtree.build_kdtree(boxes, leaf=2),
            "octree-r": lambda boxes: kdtree.build_octree_r(boxes, depth=4),
            "octree-r centre": lambda boxes: kdtree.build_octree_r(boxes, depth=3, split="centre")}


@pytest.mark.parametrize("builder", BUILDERS)
@pytest.mark.parametrize("seed", range(4))
def test_every_leaf_holds_every_item_its_region_meets(seed, builder):
    rng = np.random.default_rng(seed)
    lo = rng.uniform(-5, 5, (80, 3))
    boxes = np.hstack([lo, lo + rng.exponential(0.8, (80, 3))])
    boxes[:5, 3:] = boxes[:5, :3]                   # points: zero-extent boxes
    boxes[5:10, 0] = boxes[5:10, 3] = 1.0           # flat boxes, all in one plane
    tree, stats = BUILDERS[builder](boxes)
    regions = leaf_regions(tree)
    assert stats["nodes"] == len(tree.count) and stats["leaves"] == len(regions)
    assert stats["refs"] == len(tree.order) == sum(len(items) for _, items in regions)
    assert stats["max_depth"] <= stats["depth_limit"]
    for box, items in regions:
        meets = np.all((boxes[:, :3] <= box[3:]) & (boxes[:, 3:] >= box[:3]), axis=1)
        assert set(np.flatnonzero(meets).tolist()) <= items
        for i in items - set(np.flatnonzero(meets).tolist()):     # only within the tiny margin
            assert np.maximum(boxes[i, :3] - box[3:], box[:3] - boxes[i, 3:]).max() < 1e-7


def test_the_sah_cuts_off_empty_space_and_stops_on_coincident_items():
    # two clusters far apart: the first plane separates them, leaving no item on both sides
    boxes = np.array([[0, 0, 0, 1, 1, 1], [0.2, 0, 0, 1.2, 1, 1], [50, 0, 0, 51, 1, 1], [50.5, 0, 0, 51.5, 1, 1]],
                     float)
    tree, _ = kdtree.build_kdtree(boxes)
    assert tree.count[0] == -1 and 1.2 < tree.split[0] < 50
    # a hundred copies of one box: no plane separates them, the root stays a leaf
    same, stats = kdtree.build_kdtree(np.tile([0.0, 0, 0, 1, 1, 1], (100, 1)))
    assert stats["nodes"] == 1 and stats["refs"] == 100


@pytest.mark.parametrize("spec", ["kdtree", "kdtree(leaf=4)", "kdtree(mailbox=off)", "kdtree(depth=3)",
                                  "kdtree(empty_bonus=0, traversal=20)", "octree-r",
                                  "octree-r(split=centre, depth=3, mailbox=off)", "octree-r(leaf=4, candidates=1)"])
@pytest.mark.parametrize("seed", [0, 1])
def test_random_scenes_match_the_list(spec, seed):
    rng = np.random.default_rng(seed)
    scene = new_scene()
    fill_group(scene.root, rng, n=30)
    o, d = random_rays(rng, 2000)
    inside_o, inside_d = random_rays(rng, 500, inside=True)
    for origins, directions in ((o, d), (inside_o, inside_d)):
        assert_same_hits(cast(scene, spec, origins, directions), cast(scene, "list", origins, directions))
        hit = np.isfinite(cast(scene, spec, origins, directions, any_hit=True)[0])     # any hit: which one varies
        assert np.array_equal(hit, np.isfinite(cast(scene, "list", origins, directions, any_hit=True)[0]))


def test_rays_on_and_along_its_planes_match_the_list():
    # a lattice of unit cubes (triangles): planes fall on the cubes' faces; rays run along the
    # axes in those planes, start on them, and cross shared edges and corners
    verts, faces = [], []
    for x in range(3):
        for y in range(3):
            for z in range(2):
                base = len(verts)
                verts += [(x + i, y + j, z + k) for i in (0, 0.8) for j in (0, 0.8) for k in (0, 0.8)]
                for a, b, c in ((0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5), (0, 4, 5), (0, 5, 1),
                                (2, 3, 7), (2, 7, 6), (0, 2, 6), (0, 6, 4), (1, 5, 7), (1, 7, 3)):
                    faces.append((base + a, base + b, base + c))
    scene = new_scene()
    scene.root.add(TriangleMesh(np.array(verts, float), np.array(faces), 0))
    origins, directions = [], []
    for u in np.arange(-0.2, 3.2, 0.2):
        for v in np.arange(-0.2, 2.2, 0.2):
            for axis in range(3):
                o = np.insert(np.array([u, v]), axis, -1.0)
                d = np.zeros(3)
                d[axis] = 1.0
                origins += [o, o + 5 * d]
                directions += [d, -d]
            origins.append((u, v, 0.8))                  # starting on a plane, along it and off it
            directions.append((1.0, 0.0, 0.0))
            origins.append((u, 0.8, v))
            directions.append((0.3, 1.0, 0.2))
    o, d = np.array(origins, float), np.array(directions, float)
    for spec in ("kdtree", "kdtree(leaf=2, mailbox=off)", "octree-r(depth=4)", "octree-r(split=centre, depth=4)"):
        assert_same_hits(cast(scene, spec, o, d), cast(scene, "list", o, d))


def test_huge_and_tiny_scales_match_the_list():
    rng = np.random.default_rng(3)
    for scale in (1e-6, 1e7):
        scene = new_scene()
        fill_group(scene.root, rng, n=20)
        s = Group()
        s.add(Instance(scene.root, np.diag([scale, scale, scale, 1.0])))
        big = new_scene()
        big.root = s
        o, d = random_rays(rng, 800)
        for spec in ("kdtree", "octree-r"):
            assert_same_hits(cast(big, spec, o * scale, d), cast(big, "list", o * scale, d))


def test_nested_in_and_around_other_kinds_matches_the_list():
    rng = np.random.default_rng(5)
    scene = new_scene()
    inner = Group(accel="grid")
    fill_group(inner, rng, n=15)
    outer = Group(accel="kdtree")
    fill_group(outer, rng, n=15)
    outer.add(inner)
    outer.add(Instance(Group(accel="bvh", children=[fill_group(Group(), rng, n=10)]), np.eye(4)))
    scene.root.add(outer)
    o, d = random_rays(rng, 1500)
    assert_same_hits(cast(scene, "octree", o, d), cast(scene, "list", o, d))
    assert_same_hits(cast(scene, "kdtree", o, d), cast(scene, "list", o, d))


@pytest.mark.parametrize("spec", ["kdtree", "octree-r(depth=4)"])
def test_counts_are_its_walks_and_do_not_depend_on_threads(spec):
    scene = raykernel.load("spd:gears:1")
    runs = [raykernel.render(scene, accel=spec, resolution=24, spd=True, threads=t) for t in (1, 2)]
    a, b = (r.stats for r in runs)
    assert runs[0].image.tobytes() == runs[1].image.tobytes()
    assert work_counts(a) == work_counts(b)
    assert a["walk.kdtree.steps"] == a["cells.visited"] > 0
    assert a["walk.kdtree.bounds"] == a["bounds.tests"] > 0
    assert a["cells.leaves"] <= a["cells.visited"] and a["mailbox.saved"] > 0
    plain = raykernel.render(scene, accel="bvh", resolution=24, spd=True)
    assert plain.image.tobytes() == runs[0].image.tobytes()


@pytest.mark.parametrize("spec, words", [("kdtree(leaf=0)", "leaf"), ("kdtree(depth=200)", "depth"),
                                         ("kdtree(isect=0)", "isect"), ("kdtree(empty_bonus=2)", "empty_bonus"),
                                         ("kdtree(split=3)", "no parameter 'split'"),
                                         ("octree-r(split=median)", "split"), ("octree-r(depth=40)", "depth"),
                                         ("octree-r(candidates=0)", "candidates"), ("octree-r(leaf=0)", "leaf")])
def test_bad_parameters_are_option_errors(spec, words):
    with pytest.raises(OptionError, match=words):
        parse_spec(spec)


def test_bad_arguments_and_the_memory_budget():
    with pytest.raises(OptionError, match="kdtree leaf"):
        kdtree.build_kdtree(np.zeros((3, 6)), leaf=0)
    with pytest.raises(ValueError, match="at least one item"):
        kdtree.build_kdtree(np.array([[np.inf] * 3 + [-np.inf] * 3]))
    rng = np.random.default_rng(0)
    lo = rng.uniform(0, 10, (3000, 3))
    with pytest.raises(MemoryBudgetError, match="k-d tree"):
        kdtree.build_kdtree(np.hstack([lo, lo + 3.0]), max_bytes=200_000)
    with pytest.raises(OptionError, match="octree-r split"):
        kdtree.build_octree_r(np.zeros((3, 6)), split="median")
    with pytest.raises(MemoryBudgetError, match="octree-r"):
        kdtree.build_octree_r(np.hstack([lo, lo + 3.0]), depth=8, max_bytes=200_000)


def octree_r_cost(boxes, box, axis, x):
    """Octree-R's estimate for a plane at x (Havran 1999): items wholly below, wholly above, cut."""
    lo, hi = np.maximum(boxes[:, axis], box[axis]), np.minimum(boxes[:, axis + 3], box[axis + 3])
    left, right = np.sum(hi < x), np.sum((hi >= x) & (lo > x))
    cut = len(boxes) - left - right
    b, c = (box[(axis + k) % 3 + 3] - box[(axis + k) % 3] for k in (1, 2))
    return (left + cut) * ((x - box[axis]) * 2 * (b + c) + b * c) + (right + cut) * ((box[axis + 3] - x) * 2 * (b + c)
                                                                                   + b * c)


@pytest.mark.parametrize("seed", range(3))
def test_octree_r_planes_are_the_cheapest_of_its_candidates(seed):
    rng = np.random.default_rng(seed)
    lo = np.vstack([rng.uniform(0, 2, (60, 3)), rng.uniform(0, 10, (20, 3))])      # a cluster in a corner
    boxes = np.hstack([lo, lo + rng.exponential(0.3, (80, 3))])
    tree, _ = kdtree.build_octree_r(boxes, depth=1, candidates=10)
    box = tree.box
    centres = 0.5 * (np.maximum(boxes[:, :3], box[:3]) + np.minimum(boxes[:, 3:], box[3:]))
    # the root's x plane, the y plane of its lower half, the z plane of that half's lower half
    for axis, node in ((0, 0), (1, 1), (2, 2)):
        assert tree.count[node] == -1 - axis
        centre, mean = 0.5 * (box[axis] + box[axis + 3]), centres[:, axis].mean()
        places = [centre + (mean - centre) * i / 10 for i in range(10)]
        costs = [octree_r_cost(boxes, box, axis, x) for x in places]
        assert tree.split[node] == pytest.approx(places[int(np.argmin(costs))], rel=1e-12)
        assert tree.split[node] != pytest.approx(centre)          # the cluster pulls every plane off the centre
    # the same plane across both halves, as an octree cuts: every y node holds the root's y plane
    ys = tree.split[tree.count == -2]
    assert len(ys) == 2 and ys[0] == ys[1]


@pytest.mark.parametrize("scene", ["spd:balls:2", "spd:teapot:6", "spd:lattice:4"])
def test_octree_r_centre_planes_build_the_octrees_leaves(scene):
    from raykernel.engine.flatten import flatten
    loaded = raykernel.load(scene)
    for depth in (2, 4):
        _, st = flatten(loaded, f"octree(depth={depth}, leaf=1, collapse=off, budget=0)")
        _, sr = flatten(loaded, f"octree-r(depth={depth}, split=centre)")
        a, b = st["aggregates"][0], sr["aggregates"][0]
        assert (a["inner"], a["leaves"], a["empty_leaves"], a["refs"]) == (
            b["octree_inner"], b["leaves"], b["empty_leaves"], b["refs"])
        assert b["inner"] == 7 * b["octree_inner"]


def test_its_cells_tile_its_box_and_hold_every_item():
    from raykernel.engine.flatten import flatten
    from raykernel.geometry.primitives import INDEX_MASK, KIND_SHIFT, SPHERE
    from raykernel.rendering.structure import boxes_of
    geo, _ = flatten(raykernel.load("spd:balls:1"), "kdtree")
    boxes = boxes_of(geo)
    cells = kdtree.cells(geo, geo.root)
    assert len(boxes) == len(cells.lo) == geo.agg_count[geo.root]      # every node
    size = cells.hi - cells.lo
    leaves = cells.count >= 0
    whole = np.prod(geo.kd_box[0][3:] - geo.kd_box[0][:3])
    assert np.prod(size[leaves], axis=1).sum() == pytest.approx(whole, rel=1e-9)   # the leaves tile the box
    spheres = np.hstack([geo.sph_center - geo.sph_radius[:, None], geo.sph_center + geo.sph_radius[:, None]])
    held = set()
    for k in np.flatnonzero(leaves):
        for ref in geo.refs[cells.first[k]:cells.first[k] + cells.count[k]]:
            if ref >> KIND_SHIFT == SPHERE:
                b = spheres[ref & INDEX_MASK]
                assert np.all(b[:3] <= cells.hi[k] + 1e-6) and np.all(b[3:] >= cells.lo[k] - 1e-6)   # (boxes padded)
                held.add(int(ref & INDEX_MASK))
    assert held == set(range(len(geo.sph_radius)))


def _files_naming(word: str) -> set[str]:
    """The repository's code and data files (src, tests, bench) that name `word` in code: as a
    name, or inside a string (not in comments)."""
    found = set()
    for folder in ("src", "tests", "bench"):
        for path in (ROOT / folder).rglob("*"):
            if path.suffix == ".json" and word in path.read_text():
                found.add(path.relative_to(ROOT).as_posix())
            if path.suffix != ".py":
                continue
            for t in tokenize.generate_tokens(io.StringIO(path.read_text()).readline):
                if (t.type == tokenize.NAME and t.string == word) or (t.type == tokenize.STRING and word in t.string):
                    found.add(path.relative_to(ROOT).as_posix())
                    break
    return found


def test_adding_the_kdtree_touched_at_most_three_files_outside_its_module_and_test():
    # docs/adding-a-kind.md states this count
    outside = _files_naming("kdtree") - {"src/raykernel/aggregates/kdtree.py", "tests/test_kdtree.py"}
    assert outside <= {"src/raykernel/aggregates/registry.py", "src/raykernel/analysis/reference_costs.json"}
    assert len(outside) <= 3

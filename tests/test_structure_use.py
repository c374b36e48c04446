"""The structure drawn by its use: every box's visits, tests and futile visits, measured by a render,
against the render's own counters, a brute-force walk of the grid, the BVH's shape and the PLY file."""

from __future__ import annotations

import numpy as np
import pytest

from raykernel.aggregates.registry import KINDS
from raykernel.engine.flatten import flatten
from raykernel.rendering.explain import explain
from raykernel.rendering.structure import USE, boxes_of, structure_use, write_ply
from raykernel.scene.jsonscene import scene_from_json
from raykernel.scene.loading import load

from support import nested_scene

SPECS = [name for name, kind in KINDS.items() if not kind.operands]


@pytest.fixture(scope="module")
def balls():
    return load("spd:balls:1")


def _dark(scene):
    """The scene without lights: its rays are eye and reflected rays, closest-hit searches all."""
    scene.lights = []
    return scene


def _once(boxes):
    """One box of each cell: an aggregate under several instances is drawn (with its use) once for each."""
    ids = np.stack([boxes.walk, np.where(boxes.key >= 0, boxes.key, -1 - boxes.aggregate)], axis=1)
    return np.unique(ids, axis=0, return_index=True)[1]


def _assert_sums_to_counters(boxes, use, result, tricks_outside=False):
    once = _once(boxes)
    assert int(use["visits"][once].sum()) == result.stats["cells.visited"]
    if tricks_outside:      # the shadow cache and the ray tree test outside any search
        assert int(use["tests"][once].sum()) <= result.stats["tests.total"]
    else:
        assert int(use["tests"][once].sum()) == result.stats["tests.total"]
    futile = use["futile"]
    assert np.all((futile >= 0) | (futile == -1))


@pytest.mark.parametrize("accel", SPECS)
def test_every_kind_sums_to_the_render_counters(balls, accel):
    boxes, use, result = structure_use(balls, accel, resolution=12, tricks="none")
    assert set(use) == set(USE) and all(len(v) == len(boxes) for v in use.values())
    _assert_sums_to_counters(boxes, use, result)
    assert result.stats["cells.visited"] > 0 or accel == "list"
    # a leaf is futile at most as often as it was visited, and never negative
    leaves = boxes.leaf == 1
    cellular = leaves & (boxes.key >= 0)
    assert np.all(use["futile"][cellular] <= use["visits"][cellular])
    assert np.all(use["futile"][~leaves] == -1)


def test_the_same_render_gives_the_same_counts(balls):
    first = structure_use(balls, "octree", resolution=10)[1]
    again = structure_use(balls, "octree", resolution=10)[1]
    assert all(np.array_equal(first[k], again[k]) for k in USE)


@pytest.mark.parametrize("outer,inner,instanced", [("grid", "bvh", False), ("bvh", "octree", True),
                                                    ("hgrid", "list", True), ("octree", "rc", False)])
def test_nested_and_instanced_scenes_sum_to_the_counters(outer, inner, instanced):
    scene = nested_scene(np.random.default_rng(3), outer, inner, instanced)
    scene.camera.eye, scene.camera.look_at = np.array([0.0, -14.0, 6.0]), np.zeros(3)
    boxes, use, result = structure_use(scene, "bvh", resolution=12, tricks="none")
    assert boxes.level.max() >= 1
    _assert_sums_to_counters(boxes, use, result)
    # the cells of the nested aggregates were used too
    assert use["tests"][boxes.level >= 1].sum() > 0


def test_operators_antialiasing_and_tricks():
    data = {"camera": {"eye": [3, -4, 3], "look_at": [0, 0, 0], "resolution": 16},
            "lights": [{"position": [5, -5, 8]}],
            "scene": {"accel": "grid", "items": [
                {"difference": {"base": [{"sphere": {"center": [0, 0, 0], "radius": 1}}],
                                "subtract": [{"sphere": {"center": [0.6, -0.6, 0.6], "radius": 0.5}}]}},
                {"intersection": {"items": [{"sphere": {"center": [0, 0.5, 0], "radius": 1}},
                                            {"group": {"accel": "octree", "items": [
                                                {"sphere": {"center": [0, -0.5, 0], "radius": 1}}]}}]},
                 "transform": {"translate": [3, 0, 0]}},
                {"union": {"items": [{"sphere": {"center": [0, 0, 3], "radius": 0.5}},
                                     {"sphere": {"center": [0.3, 0, 3], "radius": 0.5}}]}}]}}
    scene = scene_from_json(data)
    boxes, use, result = structure_use(scene, "bvh", tricks="none", aa="jitter", samples=4)
    _assert_sums_to_counters(boxes, use, result)
    assert result.stats["tests.total"] > 0 and boxes.level.max() >= 1
    boxes, use, result = structure_use(scene, "bvh", tricks="all")
    _assert_sums_to_counters(boxes, use, result, tricks_outside=True)


def test_a_lazy_octree_marks_the_cells_this_render_made(balls):
    boxes, use, result = structure_use(balls, "lazyoctree", resolution=16, tricks="none")
    _assert_sums_to_counters(boxes, use, result)
    geo, _ = flatten(balls, "lazyoctree")
    before = len(boxes_of(geo))
    # the render made every box the tree has beyond its one unrefined leaf, and marked those
    assert before == 1 and len(boxes) > 100
    assert int(use["refined"].sum()) == len(boxes) - before
    assert use["refined"][boxes.depth == 0].tolist() == [0]
    # a cell split during the render keeps the tests made in it while it was a leaf
    assert use["tests"][boxes.depth == 0][0] > 0


def test_grid_visits_equal_a_brute_force_walk(balls):
    """Every eye ray's cells, found by testing the segment it walked against every cell's box."""
    scene = _dark(load("spd:balls:1"))
    size = 6
    boxes, use, _ = structure_use(scene, "grid", resolution=size, max_depth=1)
    lo, hi = boxes.corners[:, 0], boxes.corners[:, 7]
    grid_lo, grid_hi = lo.min(axis=0), hi.max(axis=0)
    expected = np.zeros(len(boxes), np.int64)
    for y in range(size):
        for x in range(size):
            ray, = explain(scene, x, y, accel="grid", resolution=size, max_depth=1)["rays"]
            o, d = np.array(ray["origin"]), np.array(ray["direction"])
            with np.errstate(divide="ignore"):
                inv = 1.0 / d
            t_in, t_out = _slabs(grid_lo, grid_hi, o, inv)
            if t_in > t_out:
                continue
            end = ray["hit"]["t"] if ray["hit"] else t_out      # the walk stops in the cell of the hit
            for k in range(len(boxes)):
                a, b = _slabs(lo[k], hi[k], o, inv)
                if a < b and a <= end and b >= max(t_in, 0.0):
                    expected[k] += 1
    assert expected.sum() > 50
    assert np.array_equal(use["visits"], expected)


def _slabs(lo, hi, o, inv):
    t0, t1 = (lo - o) * inv, (hi - o) * inv
    return float(np.max(np.minimum(t0, t1))), float(np.min(np.maximum(t0, t1)))


def test_bvh_use_follows_the_tree(balls):
    """Closest-hit rays: a node is entered only through its parent, and a leaf tests all it holds."""
    scene = _dark(load("spd:balls:1"))
    boxes, use, _ = structure_use(scene, "bvh", resolution=16, tricks="none")
    depth, visits = boxes.depth, use["visits"]
    assert visits[depth == 0][0] > 0
    # no level is entered more often than twice the level above (two children a node)
    for k in range(1, depth.max() + 1):
        assert visits[depth == k].sum() <= 2 * visits[depth == k - 1].sum()
    leaves = boxes.leaf == 1
    assert np.array_equal(use["tests"][leaves], boxes.items[leaves] * visits[leaves])
    assert np.all(use["tests"][~leaves] == 0)


def test_ply_file_carries_the_use(balls, tmp_path):
    trimesh = pytest.importorskip("trimesh")
    boxes, use, _ = structure_use(balls, "octree", resolution=8)
    path = tmp_path / "used.ply"
    write_ply(boxes, path, use)
    mesh = trimesh.load(path, process=False)
    assert len(mesh.faces) == 12 * len(boxes)
    raw = mesh.metadata["_ply_raw"]["face"]["data"]
    for name in USE:
        assert np.array_equal(raw[name][::12].ravel(), use[name])


def test_command_line(tmp_path, capsys):
    trimesh = pytest.importorskip("trimesh")
    from raykernel.cli import main
    out = tmp_path / "u.ply"
    assert main(["structure", "spd:balls:1", "--accel", "lazyoctree", "--use", "--resolution", "8", "--leaves",
                 "-o", str(out)]) == 0
    text = capsys.readouterr().out.replace("\n", "")
    assert "visits" in text and "refined" in text
    raw = trimesh.load(out, process=False).metadata["_ply_raw"]["face"]["data"]
    assert raw["refined"].sum() > 0 and raw["leaf"].min() == 1

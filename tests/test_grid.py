"""Uniform grid aggregate: builder, 3D-DDA traversal, degenerate scenes, mailbox and counters.

Grids nested in and around every other kind, and instanced, are checked against the list in
test_nesting.py."""

from __future__ import annotations

import numpy as np
import pytest
from support import assert_same_hits, axis_and_boundary_rays, cast, fill_group, lattice_scene, new_scene, random_rays

from raykernel.aggregates.grid import build_grid, grid_resolution
from raykernel.aggregates.grid import CODE as GRID
from raykernel.engine.flatten import flatten
from raykernel.engine.traverse import cast_rays
from raykernel.errors import OptionError, SceneError
from raykernel.geometry import counters as C
from raykernel.scene import Group
from raykernel.aggregates.registry import parse_spec

GRID_SPECS = ["grid", "grid(mailbox=off)", "grid(res=woo)", "grid(res=woo, mailbox=off)",
              "grid(density=0.25)", "grid(density=8, max_res=7)", "grid(res=klimaszewski)",
              "grid(res=klimaszewski, mailbox=off, density=0.5)", "hgrid(res=klimaszewski, threshold=4)"]


# ---------------------------------------------------------------- builder

def test_build_grid_cells_hold_exactly_the_overlapping_items():
    rng = np.random.default_rng(1)
    lo = rng.uniform(-5, 5, (60, 3))
    boxes = np.hstack([lo, lo + rng.uniform(0, 2, (60, 3))])
    grid, stats = build_grid(boxes, res_rule="regular", density=2.0, max_res=256)
    res = grid.res
    assert stats["nodes"] == np.prod(res) == len(grid.cell_start) - 1
    assert stats["refs"] == len(grid.items)
    assert stats["empty_leaves"] == int(np.sum(np.diff(grid.cell_start) == 0))
    assert np.all(np.diff(grid.cell_start) >= 0)
    for c in range(np.prod(res)):
        x, y, z = c % res[0], (c // res[0]) % res[1], c // (res[0] * res[1])
        cell_lo = grid.origin + np.array([x, y, z]) * grid.cell_size
        cell_hi = cell_lo + grid.cell_size
        overlap = np.all((boxes[:, :3] <= cell_hi) & (boxes[:, 3:] >= cell_lo), axis=1)
        held = set(grid.items[grid.cell_start[c]:grid.cell_start[c + 1]].tolist())
        # every overlapping item is held; anything else only touches within the tiny margin
        assert set(np.flatnonzero(overlap).tolist()) <= held
        for i in held - set(np.flatnonzero(overlap).tolist()):
            gap = np.maximum(boxes[i, :3] - cell_hi, cell_lo - boxes[i, 3:]).max()
            assert gap < 1e-6


def test_resolution_rules():
    ext = np.array([8.0, 4.0, 2.0])
    reg = grid_resolution(ext, 1000, "regular", 2.0, 256)
    assert 0.6 * 2000 < np.prod(reg) < 1.6 * 2000
    assert reg[0] / reg[2] == pytest.approx(4.0, rel=0.25)
    woo = grid_resolution(ext, 1000, "woo", 3.0, 256)
    assert woo[0] == 30 and woo[1] == 15 and woo[2] in (7, 8)
    assert grid_resolution(ext, 10 ** 9, "woo", 3.0, 64).tolist() == [64, 64, 64]
    flat = grid_resolution(np.array([4.0, 4.0, 0.0]), 50, "regular", 2.0, 256)
    assert flat[2] == 1 and flat[0] == flat[1] == 10


def test_klimaszewski_rule_by_hand():
    """Worked examples of our reading of the rule (grid.py): per axis extent / mean item extent,
    scaled down uniformly to at most density * n cells, axes below one cell pinned at one."""
    def k(extent, n, size, density=2.0, max_res=256):
        return grid_resolution(np.array(extent, float), n, "klimaszewski", density, max_res,
                               item_size=np.array(size, float)).tolist()
    # unit cubes in an 8-cube: 8 cells per axis while 512 <= density * n ...
    assert k([8, 8, 8], 300, [1, 1, 1]) == [8, 8, 8]
    # ... else all axes scaled by (200 / 512) ** (1/3): 5.85 -> 6
    assert k([8, 8, 8], 100, [1, 1, 1]) == [6, 6, 6]
    # long thin items along x: want 4 x 160 x 160 cells, 400 allowed; x would fall to 0.63
    # cells and keeps one, y and z share the rest: sqrt(400 / 160^2) * 160 = 20
    assert k([16, 16, 16], 200, [4, 0.1, 0.1]) == [1, 20, 20]
    # thin along y only: the proportions between x and z stay (1 : 2)
    assert k([16, 16, 32], 100, [0.5, 16, 0.5]) == [10, 1, 20]
    # the same ratios at any scale
    for scale in (1e-250, 1e-6, 1e6, 1e250):
        assert k(np.array([16, 16, 16]) * scale, 200, np.array([4, 0.1, 0.1]) * scale) == [1, 20, 20]
    # a flat axis gets one cell and does not count; items bigger than the box give one cell
    assert k([8, 8, 0], 300, [1, 2, 0]) == [8, 4, 1]
    assert k([8, 8, 8], 300, [10, 10, 10]) == [1, 1, 1]
    # fewer cells allowed than one: one cell
    assert k([8, 8, 8], 10, [1, 1, 1], density=0.01) == [1, 1, 1]
    # clamped to max_res after scaling
    assert k([1000, 1, 1], 10 ** 6, [0.001, 1, 1]) == [256, 1, 1]
    assert k([1000, 1, 1], 10 ** 6, [0.001, 1, 1], max_res=4096) == [4096, 1, 1]
    # a subnormal mean extent is still a size: every cell goes to that axis, no overflow on the way
    assert k([8, 4, 2], 1000, [5e-324, 1, 1]) == [256, 1, 1]


def test_klimaszewski_falls_back_to_regular_without_item_extent():
    ext = np.array([8.0, 4.0, 2.0])
    regular = grid_resolution(ext, 1000, "regular", 2.0, 256).tolist()
    sized = grid_resolution(ext, 1000, "klimaszewski", 2.0, 256, item_size=np.array([2.0, 0.1, 0.1])).tolist()
    assert sized != regular
    for size in ([0.0, 0.1, 0.1], [0.0, 0.0, 0.0], [1.0, 1.0, 0.0]):
        assert grid_resolution(ext, 1000, "klimaszewski", 2.0, 256, item_size=np.array(size)).tolist() == regular
    with pytest.raises(ValueError, match="item_size"):
        grid_resolution(ext, 1000, "klimaszewski", 2.0, 256)
    # points: boxes of no extent
    points = np.random.default_rng(2).uniform(-5, 5, (500, 3))
    boxes = np.hstack([points, points])
    assert build_grid(boxes, res_rule="klimaszewski")[0].res.tolist() == \
        build_grid(boxes, res_rule="regular")[0].res.tolist()


def test_klimaszewski_grids_follow_the_items():
    rng = np.random.default_rng(4)
    # rods 3 long along x, 0.05 thick, in a 10-cube: more cells across the rods than along them
    lo = rng.uniform(0, 7, (400, 3))
    rods = np.hstack([lo, lo + [3.0, 0.05, 0.05]])
    grid, stats = build_grid(rods, res_rule="klimaszewski", density=2.0)
    assert grid.res[1] > 3 * grid.res[0] and grid.res[2] > 3 * grid.res[0]
    assert np.prod(grid.res) <= 1.2 * 2.0 * 400
    assert stats["res"] == tuple(grid.res.tolist())
    # and the cells still hold exactly the overlapping items
    for c in range(0, int(np.prod(grid.res)), 7):
        x, y, z = c % grid.res[0], (c // grid.res[0]) % grid.res[1], c // (grid.res[0] * grid.res[1])
        cell_lo = grid.origin + np.array([x, y, z]) * grid.cell_size
        overlap = np.all((rods[:, :3] <= cell_lo + grid.cell_size) & (rods[:, 3:] >= cell_lo), axis=1)
        assert set(np.flatnonzero(overlap).tolist()) <= set(grid.items[grid.cell_start[c]:grid.cell_start[c + 1]]
                                                             .tolist())
    # a few big items among many small ones: the mean extent, so fewer cells than the small ones alone ask
    small = np.hstack([lo, lo + 0.1])
    alone, _ = build_grid(small, res_rule="klimaszewski", density=100.0)
    big = np.vstack([small, [[0, 0, 0, 10, 10, 10]] * 40])
    mixed, _ = build_grid(big, res_rule="klimaszewski", density=100.0)
    assert np.all(mixed.res < alone.res)


def test_flat_scene_is_padded_and_single_item_works():
    boxes = np.array([[0, 0, 1, 2, 2, 1], [1, 1, 1, 3, 3, 1.0]])
    for rule in ("regular", "woo", "klimaszewski"):
        grid, _ = build_grid(boxes, res_rule=rule)
        assert grid.res[2] == 1 and grid.cell_size[2] > 0
    one, stats = build_grid(np.array([[0, 0, 0, 1, 1, 1.0]]))
    assert stats["refs"] >= 1 and len(one.items) == np.prod(one.res)


def test_too_many_cells_is_a_scene_error():
    boxes = np.random.default_rng(0).uniform(0, 1, (1000, 6))
    boxes = np.hstack([np.minimum(boxes[:, :3], boxes[:, 3:]), np.maximum(boxes[:, :3], boxes[:, 3:])])
    with pytest.raises(SceneError, match="limit"):
        build_grid(boxes, density=1000.0, max_res=256, max_cells=100_000)
    with pytest.raises(SceneError, match="references"):
        build_grid(boxes, density=50.0, max_refs=1000)


@pytest.mark.parametrize("spec, allowed", [("grid(res=foo)", "regular, woo, klimaszewski"),
                                           ("hgrid(res=foo)", "regular, woo, klimaszewski"),
                                           ("grid(density=-1)", "density"),
                                           ("grid(mailbox=maybe)", "on or off"),
                                           ("grid(max_res=0)", "max_res"),
                                           ("grid(size=3)", "res, density, max_res, mailbox, cells")])
def test_bad_parameters_are_option_errors(spec, allowed):
    with pytest.raises(OptionError, match=allowed):
        parse_spec(spec)


def test_flatten_stores_grids():
    scene = new_scene()
    fill_group(scene.root, np.random.default_rng(2))
    geo, stats = flatten(scene, default_accel="grid")
    assert geo.agg_kind[geo.root] == GRID
    g = geo.agg_start[geo.root]
    ncells = int(np.prod(geo.grid_res[g]))
    assert geo.agg_count[geo.root] == ncells
    assert len(geo.grid_cells) == ncells + 1
    assert geo.grid_cells[-1] == len(geo.refs)
    assert stats["build.nodes"] == ncells
    assert stats["aggregates"][0]["kind"] == "grid"


# ---------------------------------------------------------------- traversal against bvh and list

@pytest.mark.parametrize("spec", GRID_SPECS)
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
    assert got[4][C.CELLS_VISITED] > 0
    shadow = cast(scene, spec, o, d, tmax=0.5, any_hit=True)
    np.testing.assert_array_equal(np.isfinite(shadow[0]), np.isfinite(cast(scene, "list", o, d, tmax=0.5)[0]))


@pytest.mark.parametrize("spec, res", [("grid(density=64, max_res=8)", 8), ("grid(density=64, max_res=4)", 4),
                                       ("grid(density=64, max_res=8, mailbox=off)", 8),
                                       ("grid", None), ("grid(res=woo)", None), ("grid(density=0.1)", None),
                                       ("grid(res=klimaszewski)", None)])
def test_axis_parallel_and_cell_boundary_rays(spec, res):
    scene = lattice_scene()
    o, d = axis_and_boundary_rays()
    ref = cast(scene, "list", o, d)
    assert np.isfinite(ref[0]).sum() > 50
    geo, _ = flatten(scene, default_accel=spec)
    assert np.all(geo.grid_origin == 0.0)
    if res is not None:
        # cell boundaries fall exactly on the rays and polygon edges
        assert np.all(geo.grid_res == res) and np.all(geo.grid_cell_size == 8.0 / res)
    got = cast_rays(geo, o, d)
    assert_same_hits(got, ref)
    assert got[4][C.CELLS_LEAVES] == got[4][C.CELLS_VISITED] >= got[4][C.CELLS_EMPTY]
    if res == 8:
        assert got[4][C.CELLS_EMPTY] > 0


def test_rays_that_miss_count_no_cells_and_cost_one_bounds_test():
    scene = lattice_scene()
    o = np.array([[-5.0, -5.0, -5.0], [20.0, 0.0, 0.0]])
    d = np.array([[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    t, kind, *_, cnt = cast(scene, "grid", o, d)
    assert np.all(np.isinf(t)) and np.all(kind == -1)
    assert cnt[C.CELLS_VISITED] == 0 and cnt[C.BOUNDS_TESTS] == 2


def test_ray_inside_grid_stops_at_the_first_hit():
    scene = new_scene()
    for x in range(20):
        scene.root.spheres.add((x, 0, 0), 0.3, 0)
    geo, _ = flatten(scene, default_accel="grid(mailbox=off)")
    t, kind, index, _, cnt = cast_rays(geo, [[4.5, 0, 0]], [[1.0, 0, 0]])
    assert index[0] == 5 and t[0] == pytest.approx(0.2)
    assert cnt[C.TESTS + 0] <= 3
    assert cnt[C.CELLS_VISITED] < 10


# ---------------------------------------------------------------- degenerate scenes

def test_planar_scene_has_zero_thickness_padded():
    scene = new_scene()
    rng = np.random.default_rng(3)
    for _ in range(40):
        c = np.append(rng.uniform(-4, 4, 2), 1.0)
        scene.root.polygons.add([c, c + [1, 0, 0], c + [0.5, 1, 0]], 0)
    o, d = random_rays(rng, 1000, spread=4.0)
    geo, stats = flatten(scene, default_accel="grid")
    assert geo.grid_res[0, 2] == 1 and geo.grid_res[0, 0] > 1
    got = cast_rays(geo, o, d)
    ref = cast(scene, "list", o, d)
    assert np.isfinite(ref[0]).sum() > 20
    assert_same_hits(got, ref)


def test_one_item_and_empty_groups():
    scene = new_scene()
    scene.root.spheres.add((1, 2, 3), 1.0, 0)
    scene.root.add(Group(name="empty", accel="grid"))
    o = np.array([[1, 2, -5.0], [1, 2, 3.0], [5, 5, 5.0]])
    d = np.array([[0, 0, 1.0], [0, 1, 0.0], [1, 0, 0.0]])
    got = cast(scene, "grid", o, d)
    assert got[0][0] == pytest.approx(7.0) and got[0][1] == pytest.approx(1.0) and np.isinf(got[0][2])
    empty = new_scene()
    empty.root.accel = "grid"
    t, *_ = cast(empty, "grid", o, d)
    assert np.all(np.isinf(t))


def test_huge_extent_scene():
    rng = np.random.default_rng(5)
    scene = new_scene()
    fill_group(scene.root, rng, n=20, spread=2.0)
    scene.root.spheres.add((1e9, 3e8, -2e8), 1e7, 0)
    o, d = random_rays(rng, 1500, spread=2.0)
    far = np.array([[0.0, 0.0, 0.0]] * 3)
    fd = np.array([[1e9, 3e8, -2e8], [1e9, 3e8 + 5e6, -2e8], [-1.0, 0.0, 0.0]])
    o, d = np.vstack([o, far]), np.vstack([d, fd])
    ref = cast(scene, "list", o, d)
    assert np.isfinite(ref[0][-3:-1]).all()
    for spec in ("grid", "grid(res=woo)", "grid(mailbox=off)", "grid(res=klimaszewski)"):
        assert_same_hits(cast(scene, spec, o, d), ref)


# ---------------------------------------------------------------- mailbox and counters

def big_objects_scene():
    scene = new_scene()
    rng = np.random.default_rng(9)
    for _ in range(200):
        scene.root.spheres.add(rng.uniform(-8, 8, 3), 0.1, 0)
    scene.root.polygons.add([(-9, -9, -1), (9, -9, -1), (9, 9, -1), (-9, 9, -1)], 0)
    scene.root.spheres.add((0, 0, 0), 6.0, 0)
    scene.root.cones.add((-8, -8, -8), 1.0, (8, 8, 8), 1.0, 0)
    return scene


def test_mailbox_saves_tests_without_changing_hits():
    scene = big_objects_scene()
    rng = np.random.default_rng(4)
    o, d = random_rays(rng, 2000, spread=9.0)
    on = cast(scene, "grid(density=4)", o, d)
    off = cast(scene, "grid(density=4, mailbox=off)", o, d)
    assert_same_hits(on, off)
    assert on[4][C.MAILBOX_SAVED] > 0
    assert off[4][C.MAILBOX_SAVED] == 0
    tests = slice(C.TESTS, C.TESTS + 5)
    assert on[4][tests].sum() + on[4][C.MAILBOX_SAVED] == off[4][tests].sum()
    assert on[4][C.CELLS_VISITED] == off[4][C.CELLS_VISITED]
    # the cells counters are consistent: every cell visited is a leaf
    assert on[4][C.CELLS_LEAVES] == on[4][C.CELLS_VISITED] >= on[4][C.CELLS_EMPTY]


def test_counters_identical_across_runs_and_chunkings():
    scene = big_objects_scene()
    rng = np.random.default_rng(6)
    o, d = random_rays(rng, 3000, spread=9.0)
    geo, _ = flatten(scene, default_accel="grid")
    a = cast_rays(geo, o, d)
    b = cast_rays(geo, o, d)
    np.testing.assert_array_equal(a[4], b[4])
    # ray by ray, the counts add up to the batch's
    parts = [cast_rays(geo, o[k:k + 700], d[k:k + 700])[4] for k in range(0, 3000, 700)]
    np.testing.assert_array_equal(np.sum(parts, axis=0)[:C.RAYS_CAST], a[4][:C.RAYS_CAST])


@pytest.mark.parametrize("cells", ["1x1x1", "7x3x11", "40x40x2"])
def test_explicit_cells_give_that_resolution_and_the_list_hits(cells):
    from support import same_hits_as_list
    rng = np.random.default_rng(4)
    scene = new_scene()
    fill_group(scene.root, rng, n=40)
    o, d = random_rays(rng, 400)
    got = same_hits_as_list(scene, f"grid(cells={cells}, mailbox=off)", o, d)
    assert got.build_stats["aggregates"][0]["res"] == tuple(int(x) for x in cells.split("x"))

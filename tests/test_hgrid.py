"""Hierarchical grid: sub-grids in crowded cells, depth limits, hits against the list.

Hierarchical grids nested in and around every other kind, and instanced, are checked against the
list in test_nesting.py."""

from __future__ import annotations

import numpy as np
import pytest
from support import assert_same_hits, fill_group_large, new_scene, rays_outside_and_inside

from raykernel.aggregates.grid import build_grid
from raykernel.aggregates.hgrid import clipped_bounds, dense_cells, replace_cells
from raykernel.aggregates.grid import CODE as GRID
from raykernel.aggregates.walk import MAX_NESTING
from raykernel.engine.flatten import flatten
from raykernel.engine.traverse import cast_rays
from raykernel.errors import OptionError, SceneError
from raykernel.geometry import counters as C
from raykernel.scene import Group
from raykernel.aggregates.registry import parse_spec


def subgrids(stats, level=None):
    return [a for a in stats["aggregates"] if a["kind"].startswith("hgrid") and a["level"] > 0
            and (level is None or a["level"] == level)]


# ---------------------------------------------------------------- helpers of the module

def test_replace_cells_keeps_other_cells_in_order():
    start = np.array([0, 2, 2, 5, 6])
    refs = np.array([10, 11, 20, 21, 22, 30])
    s, r = replace_cells(start, refs, np.array([2]), np.array([99]))
    assert s.tolist() == [0, 2, 2, 3, 4] and r.tolist() == [10, 11, 99, 30]
    s, r = replace_cells(start, refs, np.array([0, 3]), np.array([7, 8]))
    assert s.tolist() == [0, 1, 1, 4, 5] and r.tolist() == [7, 20, 21, 22, 8]


def test_clipped_bounds_stay_in_the_cell_and_are_never_empty():
    rng = np.random.default_rng(1)
    lo = rng.uniform(0, 10, (300, 3))
    boxes = np.hstack([lo, lo + rng.uniform(0, 3, (300, 3))])
    grid, _ = build_grid(boxes, density=1.0)
    for c in dense_cells(grid, 3):
        items = grid.items[grid.cell_start[c]:grid.cell_start[c + 1]]
        cut = clipped_bounds(grid, boxes, c, items)
        assert np.all(cut[:, :3] <= cut[:, 3:])
        assert np.all(cut[:, :3] >= boxes[items, :3]) and np.all(cut[:, 3:] <= boxes[items, 3:])
        assert np.all(cut[:, 3:] - cut[:, :3] <= grid.cell_size * 1.001)


def test_spec_parameters():
    kind, params = parse_spec("hgrid")
    assert kind == "hgrid" and params == {"res": "regular", "density": 2.0, "max_res": 256, "threshold": 8,
                                          "depth": 2, "mailbox": True}
    for bad in ("hgrid(threshold=0)", "hgrid(depth=16)", "hgrid(res=octree)", "hgrid(levels=2)"):
        with pytest.raises(OptionError):
            parse_spec(bad)


# ---------------------------------------------------------------- structure on hand-made clusters

def cluster_scene():
    """Two corner spheres fix the top grid to [0, 8]^3 in 8^3 unit cells (with max_res=8). Inside,
    cluster A: 30 small spheres in cell (2, 2, 2) whose own box is [2.19, 2.81]^3, holding a tighter
    cluster A' of 20 tiny spheres; cluster B: 12 spheres in cell (5, 1, 3); cluster C: 5 in (1, 6, 6)."""
    rng = np.random.default_rng(3)
    scene = new_scene()
    s = scene.root.spheres
    s.add((0.5, 0.5, 0.5), 0.5, 0)
    s.add((7.5, 7.5, 7.5), 0.5, 0)
    s.add((2.2, 2.2, 2.2), 0.01, 0)
    s.add((2.8, 2.8, 2.8), 0.01, 0)
    for p in rng.uniform(2.25, 2.75, (28, 3)):
        s.add(p, 0.01, 0)
    for p in rng.uniform(2.525, 2.535, (20, 3)):
        s.add(p, 0.001, 0)
    for p in rng.uniform(5.3, 5.7, (12, 3)) - (0, 4, 2):
        s.add(p, 0.02, 0)
    for p in rng.uniform(0.3, 0.7, (5, 3)) + (1, 6, 6):
        s.add(p, 0.02, 0)
    return scene


def test_subgrid_counts_on_a_dense_cluster():
    scene = cluster_scene()
    spec = "hgrid(density=1000, max_res=8, threshold=10, depth={})"
    geo, stats = flatten(scene, spec.format(0))
    assert subgrids(stats) == [] and stats["build.aggregates"] == 1 and stats["build.nesting"] == 1

    geo, stats = flatten(scene, spec.format(1))
    top = stats["aggregates"][-1]
    assert top["level"] == 0 and top["res"] == (8, 8, 8) and top["subgrids"] == 2
    level1 = subgrids(stats, 1)
    assert sorted(a["items"] for a in level1) == [12, 50]
    assert stats["build.nesting"] == 2

    geo, stats = flatten(scene, spec.format(2))
    assert len(subgrids(stats, 1)) == 2
    level2 = subgrids(stats, 2)
    assert [a["items"] for a in level2] == [20]
    assert stats["build.nesting"] == 3
    # the top grid's crowded cells hold one aggregate reference each
    assert geo.agg_kind[geo.root] == GRID
    g = geo.agg_start[geo.root]
    o = geo.grid_cell_offset[g]
    cell = o + (2 * 8 + 2) * 8 + 2
    held = geo.refs[geo.grid_cells[cell]:geo.grid_cells[cell + 1]]
    assert len(held) == 1

    o, d = rays_outside_and_inside(np.random.default_rng(4), 1500, spread=4.0)
    o = o + 4.0
    aim = np.vstack([np.full((300, 3), 2.53) + np.random.default_rng(5).normal(0, 0.01, (300, 3)),
                     np.full((200, 3), 2.5) + np.random.default_rng(6).normal(0, 0.2, (200, 3))])
    o2 = np.full((500, 3), -1.0)
    o, d = np.vstack([o, o2]), np.vstack([d, aim - o2])
    ref = cast_rays(flatten(scene, "list")[0], o, d)
    assert np.isfinite(ref[0]).sum() > 200
    assert_same_hits(cast_rays(geo, o, d), ref)


def test_coincident_items_stop_refining():
    """A sub-grid whose crowded cell kept every item made no progress and is not refined again."""
    scene = new_scene()
    for _ in range(20):
        scene.root.spheres.add((1.0, 1.0, 1.0), 0.5, 0)
    scene.root.spheres.add((5.0, 5.0, 5.0), 0.5, 0)
    geo, stats = flatten(scene, "hgrid(threshold=4, depth=15)")
    assert max(a["level"] for a in stats["aggregates"]) == 1
    o = np.array([[1.0, 1.0, -5.0], [5.0, 5.0, -5.0], [0.0, 0.0, 0.0]])
    d = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [1.0, 1.0, 1.0]])
    t, kind, index, inst, cnt = cast_rays(geo, o, d)
    assert t[0] == pytest.approx(5.5) and index[0] == 0 and t[1] == pytest.approx(9.5) and index[1] == 20
    assert_same_hits((t, kind, index, inst), cast_rays(flatten(scene, "list")[0], o, d))


def self_similar(group, levels=20):
    """Seven spheres on the corners (all but the origin) of a cube of side 16^-k for every k: each level
    has a crowd of all the finer levels in the cell at the origin."""
    for k in range(levels):
        s = 16.0 ** -k
        for corner in np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)][1:], np.float64):
            group.spheres.add(corner * s, 0.05 * s, 0)
    return group


def test_depth_is_clamped_to_the_nesting_limit():
    scene = new_scene()
    self_similar(scene.root)
    geo, stats = flatten(scene, "hgrid(threshold=4, depth=15)")
    assert stats["build.nesting"] == MAX_NESTING
    assert max(a["level"] for a in stats["aggregates"]) == MAX_NESTING - 1
    assert all(a["levels"] == MAX_NESTING - 1 for a in stats["aggregates"])
    rng = np.random.default_rng(8)
    o = rng.uniform(-1, 2, (500, 3)) + (0, 0, 5)
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)][1:], np.float64)
    size = 16.0 ** -rng.integers(0, 8, (500, 1))
    target = (corners[rng.integers(0, 7, 500)] + rng.normal(0, 0.02, (500, 3))) * size
    got = cast_rays(geo, o, target - o)
    ref = cast_rays(flatten(scene, "list")[0], o, target - o)
    assert np.isfinite(ref[0]).sum() > 50
    assert_same_hits(got, ref)
    _, stats = flatten(scene, "hgrid(threshold=4, depth=3)")
    assert stats["build.nesting"] == 4


def test_depth_clamp_counts_the_levels_above():
    """A crowd nested in a list may go 14 levels down, not 15; above it, nesting too deep is an error."""
    scene = new_scene()
    scene.root.accel = "list"
    scene.root.spheres.add((5.0, 5.0, 5.0), 0.5, 0)
    child = self_similar(Group(name="crowd", accel="hgrid(threshold=4, depth=14)"))
    scene.root.add(child)
    _, stats = flatten(scene, "list")
    assert stats["build.nesting"] == MAX_NESTING
    child.accel = "hgrid(threshold=4, depth=15)"
    with pytest.raises(SceneError, match="nest"):
        flatten(scene, "list")


# ---------------------------------------------------------------- hits against the list

@pytest.mark.parametrize("spec", ["hgrid", "hgrid(threshold=2, depth=3)", "hgrid(mailbox=off, threshold=4)",
                                  "hgrid(res=woo, density=1.5)", "hgrid(density=0.3, threshold=3, depth=4)"])
@pytest.mark.parametrize("seed", [0, 1])
def test_random_scenes_match_list(spec, seed):
    rng = np.random.default_rng(20 + seed)
    scene = new_scene()
    fill_group_large(scene.root, rng, patches=False, crowd=True)
    o, d = rays_outside_and_inside(rng, 2000)
    ref = cast_rays(flatten(scene, "list")[0], o, d)
    assert np.isfinite(ref[0]).sum() > 300
    geo, stats = flatten(scene, spec)
    if "depth" not in spec or "depth=0" not in spec:
        assert subgrids(stats)
    got = cast_rays(geo, o, d)
    assert_same_hits(got, ref)
    assert got[4][C.CELLS_VISITED] > 0
    shadow = cast_rays(geo, o, d, tmax=0.5, any_hit=True)
    np.testing.assert_array_equal(np.isfinite(shadow[0]),
                                  np.isfinite(cast_rays(flatten(scene, "list")[0], o, d, tmax=0.5)[0]))


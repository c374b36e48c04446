"""A built structure as boxes: every kind's cells against its own build, nesting, instances, the PLY file."""

from __future__ import annotations

import numpy as np
import pytest

from raykernel.aggregates.registry import KINDS
from raykernel.engine.flatten import flatten
from raykernel.errors import RayKernelError
from raykernel.geometry.primitives import INDEX_MASK, KIND_SHIFT, SPHERE
from raykernel.rendering.structure import CORNERS, FACES, boxes_of, select, structure_boxes, write_ply
from raykernel.scene import Group, Instance
from raykernel.scene.loading import load


def _volume(boxes, keep):
    c = boxes.corners[keep]
    return float(np.prod(c[:, 7] - c[:, 0], axis=1).sum())


def _sphere_boxes(geo):
    return np.hstack([geo.sph_center - geo.sph_radius[:, None], geo.sph_center + geo.sph_radius[:, None]])


@pytest.fixture(scope="module")
def balls():
    return load("spd:balls:1")


def test_faces_point_outwards():
    corners = CORNERS.astype(float)
    centre = corners.mean(axis=0)
    for a, b, c in FACES:
        normal = np.cross(corners[b] - corners[a], corners[c] - corners[a])
        assert np.dot(normal, corners[a] - centre) > 0
    # closed: every directed edge appears once, and its reverse once
    edges = [(f[i], f[(i + 1) % 3]) for f in FACES.tolist() for i in range(3)]
    assert len(set(edges)) == 36 and all((b, a) in set(edges) for a, b in edges)


@pytest.mark.parametrize("accel", [name for name, kind in KINDS.items() if not kind.operands])
def test_leaves_hold_what_overlaps_them(balls, accel):
    geo, _ = flatten(balls, accel)
    boxes = boxes_of(geo)
    spheres = _sphere_boxes(geo)
    leaves = np.flatnonzero((boxes.leaf == 1) & (boxes.level == boxes.level.max()))
    assert len(leaves)
    # each item a leaf refers to overlaps the leaf's box (the build put it there for that)
    for k in leaves:
        lo, hi = boxes.corners[k, 0], boxes.corners[k, 7]
        cells = boxes_of_leaf_refs(geo, boxes, k)
        for ref in cells:
            if ref >> KIND_SHIFT == SPHERE:
                b = spheres[ref & INDEX_MASK]
                assert np.all(b[:3] <= hi + 1e-6) and np.all(b[3:] >= lo - 1e-6), (accel, k)


def boxes_of_leaf_refs(geo, boxes, k):
    """The references of box k, found by matching it to its walk's cells again (brute force)."""
    from raykernel.rendering.structure import WALKS_BY_CODE, _walk_cells
    a = boxes.aggregate[k]
    walk = WALKS_BY_CODE[int(geo.agg_kind[a])]
    if walk.references is not None:         # held outside geo.refs (ray classification's candidate lists)
        return walk.references(geo, a)
    cells = _walk_cells(geo, a)
    lo = boxes.corners[k, 0]
    match = np.flatnonzero(np.all(np.isclose(cells.lo, lo), axis=1) & np.all(np.isclose(cells.hi, boxes.corners[k, 7]),
                                                                             axis=1) & (cells.count >= 0))
    assert len(match) >= 1
    c = match[0]
    return geo.refs[cells.first[c]:cells.first[c] + cells.count[c]]


@pytest.mark.parametrize("accel", ["grid", "octree"])      # (the k-d tree's own test checks its cells)
def test_space_subdivisions_tile_their_box(balls, accel):
    geo, _ = flatten(balls, accel)
    boxes = boxes_of(geo)
    leaves = boxes.leaf == 1
    root = np.flatnonzero(boxes.depth == 0)[0] if accel != "grid" else None
    whole = boxes.corners[:, 7].max(axis=0) - boxes.corners[:, 0].min(axis=0)
    assert _volume(boxes, leaves) == pytest.approx(float(np.prod(whole)), rel=1e-9)
    if root is not None:
        assert _volume(boxes, [root]) == pytest.approx(float(np.prod(whole)), rel=1e-9)
    # every item is in some leaf
    held = np.concatenate([boxes_of_leaf_refs(geo, boxes, k) for k in np.flatnonzero(leaves & (boxes.items > 0))])
    spheres = held[held >> KIND_SHIFT == SPHERE] & INDEX_MASK
    assert set(spheres.tolist()) == set(range(len(geo.sph_radius)))


def test_bvh_nodes_are_the_build_and_nest(balls):
    geo, _ = flatten(balls, "bvh")
    boxes = boxes_of(geo)
    assert len(boxes) == geo.agg_count[geo.root] > 1                      # every node of the tree
    assert int((boxes.leaf == 1).sum()) == (len(boxes) + 1) // 2          # a binary tree
    # the leaves share out the items, each once
    assert int(boxes.items[boxes.leaf == 1].sum()) == len(geo.sph_radius) + len(geo.poly_d)
    # each node lies inside its parent: the deepest node is inside the root
    root = boxes.corners[boxes.depth == 0][0]
    assert np.all(boxes.corners[:, 0] >= root[0] - 1e-9) and np.all(boxes.corners[:, 7] <= root[7] + 1e-9)


def test_nested_and_instanced_levels_are_drawn_in_world_space():
    from raykernel.scene import Scene
    scene = Scene()
    inner = Group(name="inner", accel="octree")
    inner.spheres.add([0.0, 0.0, 0.0], 1.0, 0)
    inner.spheres.add([3.0, 0.0, 0.0], 1.0, 0)
    turn = np.eye(4)
    turn[:3, :3] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]      # 90 degrees about z
    turn[:3, 3] = [10.0, 0.0, 0.0]
    scene.root.children += [Instance(inner, np.eye(4)), Instance(inner, turn)]
    scene.root.accel = "grid"
    boxes = structure_boxes(scene, "bvh")
    assert set(boxes.level) == {0, 1}
    deep = boxes.level == 1
    lo = boxes.corners[deep].reshape(-1, 3).min(axis=0)
    hi = boxes.corners[deep].reshape(-1, 3).max(axis=0)
    # the first instance spans x in [-1, 4]; the turned one is moved to x = 10 and runs along y
    assert lo[0] == pytest.approx(-1.0, abs=1e-3) and hi[0] == pytest.approx(11.0, abs=1e-3)
    assert hi[1] == pytest.approx(4.0, abs=1e-3) and lo[2] == pytest.approx(-1.0, abs=1e-3)
    assert int(((boxes.level == 1) & (boxes.depth == 0)).sum()) == 2        # the octree drawn once per instance


def test_ply_file_loads_in_trimesh_with_every_box(balls, tmp_path):
    trimesh = pytest.importorskip("trimesh")
    boxes = structure_boxes(balls, "octree")
    path = tmp_path / "octree.ply"
    write_ply(boxes, path)
    mesh = trimesh.load(path, process=False)
    assert len(mesh.faces) == 12 * len(boxes) and len(mesh.vertices) == 8 * len(boxes)
    raw = mesh.metadata["_ply_raw"]["face"]["data"]
    assert np.array_equal(raw["depth"][::12].ravel(), boxes.depth)
    assert np.array_equal(raw["items"][::12].ravel(), boxes.items)
    leaves = select(boxes, boxes.leaf == 1)
    assert len(leaves) == int((boxes.leaf == 1).sum()) and np.all(leaves.items >= 0)


def test_command_line(tmp_path, capsys):
    from raykernel.cli import main
    out = tmp_path / "g.ply"
    assert main(["structure", "spd:balls:1", "--accel", "grid", "--leaves", "--no-empty", "-o", str(out)]) == 0
    assert out.stat().st_size > 1000 and str(out) in capsys.readouterr().out.replace("\n", "")
    assert main(["structure", "spd:balls:1", "-o", str(tmp_path / "g.obj")]) == 2
    assert "name a .ply file" in capsys.readouterr().err
    assert main(["structure", "spd:balls:1", "--accel", "nosuch", "-o", str(out)]) == 2
    capsys.readouterr()
    assert main(["structure", "spd:balls:1", "--accel", "auto", "-o", str(out)]) == 2
    assert "raykernel anneal" in capsys.readouterr().err


def test_rc_and_list_are_their_box(balls):
    for accel in ("rc", "list"):
        boxes = structure_boxes(balls, accel)
        assert len(boxes) == 1 and boxes.level[0] == 0 and boxes.depth[0] == 0
    with pytest.raises(RayKernelError, match="nonexistent-folder"):
        write_ply(boxes, "/nonexistent-folder/x.ply")

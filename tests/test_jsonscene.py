"""The JSON scene format: every item kind, transforms, instancing, NFF
includes, errors located by file and JSON pointer, nesting limits, cycles
and the writer's round trip."""

from __future__ import annotations

import copy
import json
import math
import shutil
import sys
import types
from pathlib import Path

import numpy as np
import pytest

from raykernel.errors import SceneError
from raykernel.scene import Camera, Group, Instance, Material, Scene, TriangleMesh
from raykernel.scene.jsonscene import (
    MAX_NESTING,
    parse_json,
    read_json,
    scene_from_json,
    scene_to_json,
    transform_matrix,
    write_json,
)

REPO = Path(__file__).resolve().parents[1]
from support import SPD_DIR
BALLS = SPD_DIR / "balls-sf1.nff"

TRIANGLE = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]


def load(doc, path="scene.json", base_dir=None) -> Scene:
    """Parse `doc` (a dict, or JSON text) as the file `path`."""
    text = doc if isinstance(doc, str) else json.dumps(doc)
    return parse_json(text, path=path, base_dir=base_dir)


def items(*entries, **top):
    return dict(top, scene={"items": list(entries)})


def error(doc, *fragments, path="scene.json", base_dir=None) -> str:
    """The message of the SceneError `doc` raises; it must contain every fragment."""
    with pytest.raises(SceneError) as info:
        load(doc, path=path, base_dir=base_dir)
    message = str(info.value)
    for fragment in fragments:
        assert fragment in message, f"{fragment!r} not in {message!r}"
    return message


def apply(matrix, point):
    return (np.asarray(matrix) @ np.append(np.asarray(point, float), 1.0))[:3]


def apply_normal(matrix, normal):
    n = np.linalg.inv(np.asarray(matrix)[:3, :3]).T @ np.asarray(normal, float)
    return n / np.linalg.norm(n)


def only_instance(scene) -> Instance:
    (child,) = scene.root.children
    assert isinstance(child, Instance)
    return child


# ---- item kinds ------------------------------------------------------------------------------


def test_every_item_kind():
    doc = {
        "materials": {"gold": {"color": [1, 0.8, 0.3], "kd": 0.5, "ks": 0.5, "shine": 20, "t": 0, "ior": 1},
                      "glass": {"color": [1, 1, 1], "t": 0.9, "ior": 1.5}},
        "groups": {"blob": {"accel": "bvh", "items": [{"sphere": {"center": [0, 0, 0], "radius": 2}}]}},
        "scene": {"accel": "list", "items": [
            {"sphere": {"center": [1, 2, 3], "radius": 0.5}, "material": "gold"},
            {"sphere": {"center": [0, 0, 0], "radius": -4}},
            {"cone": {"base": [0, 0, 0], "base_radius": 1, "apex": [0, 0, 2], "apex_radius": 0}, "material": "glass"},
            {"polygon": [[0, 0, 0], [2, 0, 0], [2, 2, 0], [0, 2, 0]]},
            {"patch": {"vertices": TRIANGLE, "normals": [[0, 0, 1], [0, 0.1, 1], [0.1, 0, 1]]},
             "material": {"color": [0, 1, 0], "kd": 0.7}},
            {"mesh": {"vertices": [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]],
                      "faces": [[0, 1, 2], [0, 1, 3]], "normals": [[0, 0, 1]] * 4}, "material": "gold"},
            {"group": {"accel": "bvh", "material": "glass",
                       "items": [{"sphere": {"center": [5, 5, 5], "radius": 1}}]}},
            {"instance": "blob"},
        ]},
    }
    scene = load(doc)
    root = scene.root
    assert root.accel == "list"
    mats = scene.materials
    gold = Material(color=(1, 0.8, 0.3), kd=0.5, ks=0.5, shine=20)
    glass = Material(t=0.9, ior=1.5)

    np.testing.assert_array_equal(root.spheres.freeze().center, [[1, 2, 3], [0, 0, 0]])
    np.testing.assert_array_equal(root.spheres.radius, [0.5, -4])
    assert mats[root.spheres.material[0]] == gold
    assert mats[root.spheres.material[1]] == Material()          # the default material

    cones = root.cones.freeze()
    np.testing.assert_array_equal(cones.apex, [[0, 0, 2]])
    assert cones.base_radius[0] == 1 and cones.apex_radius[0] == 0
    assert mats[cones.material[0]] == glass

    vertices, normals = root.polygons.polygon(0)
    np.testing.assert_array_equal(vertices, [[0, 0, 0], [2, 0, 0], [2, 2, 0], [0, 2, 0]])
    assert normals is None
    vertices, normals = root.patches.polygon(0)
    np.testing.assert_array_equal(vertices, TRIANGLE)
    np.testing.assert_array_equal(normals, [[0, 0, 1], [0, 0.1, 1], [0.1, 0, 1]])
    assert mats[root.patches.material[0]] == Material(color=(0, 1, 0), kd=0.7)

    (mesh,) = root.meshes
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 2], [0, 1, 3]])
    assert mesh.vertices.shape == (4, 3) and mesh.normals.shape == (4, 3)
    assert all(mats[m] == gold for m in mesh.material)

    inline, blob = root.children
    assert isinstance(inline, Group) and inline.accel == "bvh"
    assert mats[inline.spheres.freeze().material[0]] == glass    # the group's default material
    assert isinstance(blob, Instance) and blob.group.name == "blob" and blob.group.accel == "bvh"
    np.testing.assert_array_equal(blob.matrix, np.eye(4))
    assert scene.count_primitives() == 9


def test_top_level_settings_and_defaults():
    scene = load({"camera": {"eye": [0, -5, 1], "look_at": [0, 0, 0], "angle": 30, "resolution": [320, 200]},
                  "background": [0.1, 0.2, 0.3],
                  "lights": [{"position": [1, 2, 3]}, {"position": [0, 0, 9], "color": [1, 0, 0]}]})
    assert scene.camera.angle == 30 and (scene.camera.width, scene.camera.height) == (320, 200)
    np.testing.assert_array_equal(scene.camera.up, [0, 0, 1])
    np.testing.assert_array_equal(scene.background, [0.1, 0.2, 0.3])
    assert scene.lights[0].color is None
    np.testing.assert_array_equal(scene.lights[1].color, [1, 0, 0])
    assert load({"camera": {"eye": [0, -5, 0], "look_at": [0, 0, 0], "resolution": 64}}).camera.height == 64


def test_empty_scene_is_allowed():
    for doc in ({}, {"scene": {}}, {"scene": {"items": []}}, {"comment": "nothing yet"}):
        scene = load(doc)
        assert scene.count_primitives() == 0
        assert scene.lights == [] and scene.materials == []


def test_group_material_inherits_into_inline_groups_but_not_instances():
    doc = {"materials": {"red": {"color": [1, 0, 0]}, "blue": {"color": [0, 0, 1]}},
           "groups": {"g": {"items": [{"sphere": {"center": [0, 0, 0], "radius": 1}}]}},
           "scene": {"material": "red", "items": [
               {"group": {"items": [{"sphere": {"center": [0, 0, 0], "radius": 1}},
                                    {"sphere": {"center": [1, 0, 0], "radius": 1}, "material": "blue"}]}},
               {"instance": "g"}]}}
    scene = load(doc)
    inline, inst = scene.root.children
    colours = [scene.materials[m].color for m in inline.spheres.freeze().material]
    assert colours == [(1, 0, 0), (0, 0, 1)]
    assert scene.materials[inst.group.spheres.freeze().material[0]] == Material()


def test_mesh_file_needs_trimesh(tmp_path, monkeypatch):
    (tmp_path / "bunny.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    monkeypatch.setitem(sys.modules, "trimesh", None)        # import trimesh -> ImportError
    message = error(items({"mesh": "bunny.obj"}), "/scene/items/0/mesh", "bunny.obj", "trimesh",
                    "pip install raykernel[mesh]", path=str(tmp_path / "s.json"))
    assert message.startswith(str(tmp_path / "s.json"))


def test_mesh_file_loaded_with_trimesh(tmp_path, monkeypatch):
    (tmp_path / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    loaded = []

    def fake_load(name, **kwargs):
        loaded.append(Path(name))
        return types.SimpleNamespace(vertices=np.array(TRIANGLE, float), faces=np.array([[0, 1, 2]]))

    monkeypatch.setitem(sys.modules, "trimesh", types.SimpleNamespace(load=fake_load))
    scene = load(items({"mesh": "tri.obj", "material": {"color": [1, 0, 0]}}), path=str(tmp_path / "s.json"))
    assert loaded == [tmp_path / "tri.obj"]
    (mesh,) = scene.root.meshes
    np.testing.assert_array_equal(mesh.vertices, TRIANGLE)
    assert scene.materials[mesh.material[0]].color == (1, 0, 0)


# ---- transforms -------------------------------------------------------------------------------


def test_each_transform_op_moves_a_sphere_centre():
    centre = [1, 0, 0]
    cases = [
        ({"translate": [1, 2, 3]}, [2, 2, 3]),
        ({"rotate": {"axis": [0, 0, 1], "degrees": 90}}, [0, 1, 0]),
        ({"rotate": {"axis": [0, 1, 0], "degrees": 90}}, [0, 0, -1]),
        ({"rotate": {"axis": [0, 0, 2], "degrees": 30}}, [math.cos(math.pi / 6), 0.5, 0]),
        ({"scale": 3}, [3, 0, 0]),
        ({"scale": [2, 5, 7]}, [2, 0, 0]),
        ({"matrix": [[0, -1, 0, 1], [1, 0, 0, 2], [0, 0, 1, 3], [0, 0, 0, 1]]}, [1, 3, 3]),
    ]
    for op, expected in cases:
        scene = load(items({"sphere": {"center": centre, "radius": 1}, "transform": op}))
        inst = only_instance(scene)
        np.testing.assert_array_equal(inst.group.spheres.freeze().center, [centre])   # kept in local space
        np.testing.assert_allclose(apply(inst.matrix, centre), expected, atol=1e-12, err_msg=str(op))
        assert len(scene.root.spheres) == 0


def test_quarter_turns_are_exact():
    np.testing.assert_array_equal(transform_matrix({"rotate": {"axis": [0, 0, 1], "degrees": 90}})[:3, :3],
                                  [[0, -1, 0], [1, 0, 0], [0, 0, 1]])
    np.testing.assert_array_equal(apply(transform_matrix({"rotate": {"axis": [1, 0, 0], "degrees": -270}}),
                                        [0, 1, 0]), [0, 0, 1])


def test_transformed_patch_normal():
    # Non-uniform scale then a quarter turn about z: a normal (1, 1, 0) at 45 degrees becomes
    # (1/2, 1/1, 0) under the inverse transpose of diag(2, 1, 1), normalised, then rotated: (-1, 0.5, 0).
    doc = items({"patch": {"vertices": TRIANGLE, "normals": [[1, 1, 0], [0, 0, 1], [0, 0, 1]]},
                 "transform": [{"scale": [2, 1, 1]}, {"rotate": {"axis": [0, 0, 1], "degrees": 90}}]})
    inst = only_instance(load(doc))
    _, normals = inst.group.patches.polygon(0)
    np.testing.assert_allclose(apply_normal(inst.matrix, normals[0]), np.array([-1, 0.5, 0]) / math.sqrt(1.25),
                               atol=1e-12)
    np.testing.assert_allclose(apply_normal(inst.matrix, normals[1]), [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(apply(inst.matrix, [1, 0, 0]), [0, 2, 0], atol=1e-12)


def test_transform_order_first_op_acts_first():
    scale_then_move = transform_matrix([{"scale": 2}, {"translate": [1, 0, 0]}])
    move_then_scale = transform_matrix([{"translate": [1, 0, 0]}, {"scale": 2}])
    np.testing.assert_allclose(apply(scale_then_move, [1, 0, 0]), [3, 0, 0])
    np.testing.assert_allclose(apply(move_then_scale, [1, 0, 0]), [4, 0, 0])
    turn_then_move = transform_matrix([{"rotate": {"axis": [0, 0, 1], "degrees": 90}}, {"translate": [5, 0, 0]}])
    np.testing.assert_allclose(apply(turn_then_move, [1, 0, 0]), [5, 1, 0], atol=1e-15)
    np.testing.assert_array_equal(transform_matrix([]), np.eye(4))
    axis = transform_matrix({"rotate": {"axis": [1, 1, 1], "degrees": 120}})
    np.testing.assert_allclose(apply(axis, [1, 0, 0]), [0, 1, 0], atol=1e-12)


def test_transform_on_groups_includes_and_instances():
    doc = {"groups": {"g": {"items": [{"sphere": {"center": [0, 0, 0], "radius": 1}}]}},
           "scene": {"items": [
               {"group": {"accel": "bvh", "items": [{"sphere": {"center": [0, 0, 0], "radius": 1}}]},
                "transform": {"translate": [0, 0, 1]}},
               {"instance": "g", "transform": {"scale": 2}},
               {"mesh": {"vertices": TRIANGLE, "faces": [[0, 1, 2]]}, "transform": {"translate": [1, 1, 1]}}]}}
    a, b, c = load(doc).root.children
    assert isinstance(a, Instance) and a.group.accel == "bvh" and a.matrix[2, 3] == 1
    assert isinstance(b, Instance) and b.group.name == "g" and b.matrix[0, 0] == 2
    assert isinstance(c, Instance) and len(c.group.meshes) == 1


def test_transform_errors():
    def bad(transform, *fragments):
        return error(items({"sphere": {"center": [0, 0, 0], "radius": 1}, "transform": transform}), *fragments)

    bad({"rotate": {"axis": [0, 0, 0], "degrees": 5}}, "/scene/items/0/transform/rotate/axis", "zero")
    bad([{"translate": [1, 2, 3]}, {"scale": 0}], "/scene/items/0/transform/1/scale", "zero")
    bad({"scale": [1, 0, 1]}, "/transform/scale/1", "zero")
    bad({"scale": "big"}, "/transform/scale", "expected a number or a list of 3 numbers, got 'big'")
    bad({"rotate": {"axis": [0, 0, 1]}}, "/transform/rotate", "missing required key 'degrees'")
    bad({"rotate": {"axis": [0, 0, 1], "degrees": 5, "radians": 1}}, "/transform/rotate/radians",
        "allowed keys: axis, degrees")
    bad({"translate": [1, 2]}, "/transform/translate", "expected a list of 3 numbers, got a list of 2 items")
    bad({"translate": [1, 2, 3], "scale": 2}, "/transform", "exactly one of", "'translate' and 'scale'")
    bad({"shear": 1}, "/transform/shear", "unknown key 'shear'", "allowed keys: translate, rotate, scale, matrix")
    bad({"matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]]}, "/transform/matrix/3", "affine")
    bad({"matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 0], [0, 0, 0, 1]]}, "/transform/matrix", "singular")
    bad({"matrix": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}, "/transform/matrix", "4 rows of 4 numbers")
    bad("spin", "/scene/items/0/transform", "expected a transform operation")
    with pytest.raises(SceneError, match=r"transform/1/rotate/degrees: expected a number, got 'x'"):
        transform_matrix([{"scale": 1}, {"rotate": {"axis": [1, 0, 0], "degrees": "x"}}])


# ---- instancing, includes ---------------------------------------------------------------------


def test_instancing_three_times_shares_one_group():
    doc = {"groups": {"teapot": {"accel": "bvh", "items": [{"sphere": {"center": [0, 0, 0], "radius": 1}}]}},
           "scene": {"items": [{"instance": "teapot", "transform": {"translate": [x, 0, 0]}} for x in (0, 3, 6)]}}
    scene = load(doc)
    instances = scene.root.children
    assert len(instances) == 3 and all(isinstance(i, Instance) for i in instances)
    assert instances[0].group is instances[1].group is instances[2].group
    assert [i.matrix[0, 3] for i in instances] == [0, 3, 6]
    assert scene.count_primitives() == 3


def test_named_group_built_once_across_groups():
    doc = {"groups": {"leaf": {"items": [{"sphere": {"center": [0, 0, 0], "radius": 1}}]},
                      "branch": {"items": [{"instance": "leaf"}, {"instance": "leaf", "transform": {"scale": 2}}]}},
           "scene": {"items": [{"instance": "branch"}, {"instance": "leaf"}]}}
    branch, leaf = load(doc).root.children
    assert branch.group.children[0].group is branch.group.children[1].group is leaf.group


def test_unused_groups_are_still_checked():
    error({"groups": {"spare": {"items": [{"sphere": {"center": [0, 0, 0], "radius": 0}}]}}},
          "/groups/spare/items/0/sphere/radius", "zero")


def test_include_nff_takes_camera_lights_background(tmp_path):
    scene = load(items({"include": str(BALLS)}))
    (child,) = scene.root.children
    assert isinstance(child, Group) and child.name == "balls-sf1"
    np.testing.assert_allclose(scene.camera.eye, [2.1, 1.3, 1.7])
    assert scene.camera.hither == 0.01
    np.testing.assert_allclose(scene.background, [0.078, 0.361, 0.753])
    assert len(scene.lights) == 3
    assert len(child.spheres) == 10 and len(child.polygons) == 1


def test_include_relative_path_remaps_materials_and_keeps_json_settings(tmp_path):
    shutil.copy(BALLS, tmp_path / "balls.nff")
    doc = {"camera": {"eye": [0, -9, 0], "look_at": [0, 0, 0]},
           "lights": [{"position": [0, 0, 10]}],
           "materials": {"red": {"color": [1, 0, 0]}},
           "scene": {"items": [{"sphere": {"center": [0, 0, 5], "radius": 1}, "material": "red"},
                               {"include": "balls.nff"},
                               {"include": {"file": "balls.nff", "accel": "bvh"}, "transform": {"scale": 2}}]}}
    (tmp_path / "scene.json").write_text(json.dumps(doc))
    scene = read_json(tmp_path / "scene.json")
    np.testing.assert_array_equal(scene.camera.eye, [0, -9, 0])          # the JSON's own camera wins
    assert len(scene.lights) == 1
    np.testing.assert_allclose(scene.background, [0.078, 0.361, 0.753])   # none in the JSON: from the NFF
    plain, placed = scene.root.children
    assert plain.accel is None and isinstance(placed, Instance) and placed.group.accel == "bvh"
    mats = scene.materials
    assert mats[0].color == (1, 0, 0)
    floor = mats[plain.polygons.freeze().material[0]]
    ball = mats[plain.spheres.freeze().material[0]]
    assert floor.color == (1, 0.75, 0.33) and floor.kd == 0.8
    assert ball.color == (1, 0.9, 0.7) and ball.ks == 0.5
    assert len(mats) == 3                                               # the second include shares them
    with pytest.raises(SceneError, match=r"scene.json: /scene/items/0/include: include file not found: 'nope.nff'"):
        parse_json(json.dumps(items({"include": "nope.nff"})), path=tmp_path / "scene.json")


def test_include_nff_error_names_both_files(tmp_path):
    (tmp_path / "bad.nff").write_text("v\nfrom 0 0 0\n")
    message = error(items({"include": "bad.nff"}), "bad.nff:", "included from", "/scene/items/0/include",
                    path=str(tmp_path / "s.json"))
    assert "Traceback" not in message


# ---- errors ------------------------------------------------------------------------------------


def test_malformed_json_names_file_and_line(tmp_path):
    path = tmp_path / "broken.json"
    path.write_text('{\n  "background": [0, 0, 0],\n  "lights": [\n    {"position": [1, 2, 3]},,\n  ]\n}\n')
    with pytest.raises(SceneError) as info:
        read_json(path)
    assert info.value.path == str(path) and info.value.line == 4
    assert str(info.value).startswith(f"{path}:4: invalid JSON")
    assert info.value.__cause__ is None and info.value.__suppress_context__


def test_empty_or_non_object_files(tmp_path):
    for text in ("", "  \n"):
        (tmp_path / "e.json").write_text(text)
        with pytest.raises(SceneError, match="empty"):
            read_json(tmp_path / "e.json")
    error("[]", "scene.json: expected a JSON object at the top level, got an empty list")
    error("42", "got 42")
    error('"scene"', "got 'scene'")
    with pytest.raises(SceneError, match="file not found"):
        read_json(tmp_path / "missing.json")
    (tmp_path / "bin.json").write_bytes(b"{\xff}")
    with pytest.raises(SceneError, match="UTF-8"):
        read_json(tmp_path / "bin.json")


def test_semantic_errors_are_located_by_pointer():
    message = error(items({"sphere": {"center": [0, 0, 0], "radius": 1}}, {"sphere": {"center": [0, 0, 0]}},
                          {"polygon": TRIANGLE}, {"sphere": {"center": [0, 0, 0], "radius": "abc"}}))
    assert message == "scene.json: /scene/items/1/sphere: missing required key 'radius'"
    assert error(items({"sphere": {"center": [0, 0, 0], "radius": "abc"}})) == \
        "scene.json: /scene/items/0/sphere/radius: expected a number, got 'abc'"


def test_unknown_keys_list_the_allowed_ones():
    error(items({"sphere": {"centre": [0, 0, 0], "radius": 1}}), "/scene/items/0/sphere/centre",
          "unknown key 'centre'", "did you mean 'center'", "allowed keys: center, radius")
    error({"camra": {}}, "/camra", "did you mean 'camera'",
          "allowed keys: camera, background, lights, materials, groups, scene")
    error(items({"sphre": {"center": [0, 0, 0], "radius": 1}}), "/scene/items/0/sphre", "did you mean 'sphere'")
    error({"scene": {"itemz": []}}, "/scene/itemz", "allowed keys: accel, items, material")
    error({"materials": {"m": {"colour": [1, 1, 1]}}}, "/materials/m/colour", "did you mean 'color'")
    error({"lights": [{"position": [0, 0, 0], "intensity": 2}]}, "/lights/0/intensity", "allowed keys: position, color")
    error({"camera": {"eye": [0, 0, 1], "look_at": [0, 0, 0], "fov": 40}}, "/camera/fov", "allowed keys: eye, look_at")
    error(items({"group": {"items": []}, "material": "x"}), "/scene/items/0/material", "group item takes no")
    error(items({"instance": "g", "accel": "bvh"}), "/scene/items/0/accel", "unknown key 'accel'")
    error(items({"sphere": {"center": [0, 0, 0], "radius": 1}, "cone": {}}), "/scene/items/0",
          "exactly one of", "'sphere' and 'cone'")
    error(items({"transform": {"scale": 2}}), "/scene/items/0", "exactly one of", "got none")


def test_duplicate_keys_are_errors():
    error('{"scene": {"items": [{"sphere": {"center": [0,0,0], "radius": 1, "radius": 2}}]}}',
          "/scene/items/0/sphere/radius", "duplicate key")


def test_wrong_types_and_lengths():
    error(items({"sphere": {"center": [0, 0], "radius": 1}}), "/scene/items/0/sphere/center",
          "expected a list of 3 numbers, got a list of 2 items")
    error(items({"sphere": {"center": [0, 0, "1"], "radius": 1}}), "/sphere/center/2", "got '1'")
    error(items({"sphere": {"center": [0, 0, 0], "radius": True}}), "/sphere/radius", "expected a number, got true")
    error(items({"sphere": {"center": [0, 0, 0], "radius": None}}), "got null")
    error(items({"polygon": [[0, 0, 0], [1, 0, 0]]}), "/scene/items/0/polygon", "at least 3 vertices")
    error(items({"polygon": [[0, 0, 0], [1, 0, 0], [0, 1]]}), "/scene/items/0/polygon/2", "3 numbers")
    error(items({"patch": {"vertices": TRIANGLE, "normals": [[0, 0, 1]] * 4}}), "/patch/normals",
          "one normal per vertex")
    error(items({"patch": {"vertices": TRIANGLE, "normals": [[0, 0, 1], [0, 0, 0], [0, 0, 1]]}}),
          "/patch/normals/1", "must not be zero")
    error(items({"mesh": {"vertices": TRIANGLE, "faces": [[0, 1, 3]]}}), "/mesh/faces/0/2", "out of range")
    error(items({"mesh": {"vertices": TRIANGLE, "faces": [[0, 1, 2.0]]}}), "/mesh/faces/0/2", "expected an integer")
    error(items({"mesh": {"vertices": TRIANGLE, "faces": [[0, 1, 2, 0]]}}), "/mesh/faces/0", "3 vertex indices")
    error(items({"mesh": {"vertices": TRIANGLE, "faces": []}}), "/mesh/faces", "at least 1 triangle")
    error(items({"mesh": {"vertices": TRIANGLE, "faces": [[0, 1, 2]], "normals": [[0, 0, 1]]}}),
          "/mesh/normals", "one normal per vertex")
    error(items({"mesh": 5}), "/scene/items/0/mesh", "expected a mesh object or a mesh file name")
    error({"camera": {"eye": [0, 0, 1], "look_at": [0, 0, 0], "resolution": [0, 10]}}, "/camera/resolution/0",
          "positive")
    error({"camera": {"eye": [0, 0, 1], "look_at": [0, 0, 0], "resolution": 12.5}}, "/camera/resolution",
          "integer")
    error({"camera": {"eye": [0, 0, 1], "look_at": [0, 0, 0], "angle": 180}}, "/camera/angle", "between 0 and 180")
    error({"camera": {"eye": [0, 0, 1], "look_at": [0, 0, 0]}}, "/camera", "parallel")
    error({"camera": {"look_at": [0, 0, 0]}}, "/camera", "missing required key 'eye'")
    error({"lights": {"position": [0, 0, 0]}}, "/lights", "expected a list of lights")
    error({"scene": {"items": {}}}, "/scene/items", "expected a list of items")
    error({"scene": []}, "/scene", "expected a group object")
    error(items(7), "/scene/items/0", "expected an item object")
    error({"scene": {"accel": "bhv"}}, "/scene/accel", "unknown accelerator 'bhv'")
    error({"scene": {"accel": 3}}, "/scene/accel", "accelerator spec")


def test_nan_and_infinity_are_rejected():
    error('{"background": [0, NaN, 0]}', "scene.json: /background/1: expected a finite number, got NaN")
    error('{"scene": {"items": [{"sphere": {"center": [0, 0, 0], "radius": Infinity}}]}}',
          "/scene/items/0/sphere/radius", "got Infinity")
    error('{"scene": {"items": [{"polygon": [[0, 0, 0], [1, 0, -Infinity], [0, 1, 0]]}]}}',
          "/scene/items/0/polygon/1/2", "-Infinity")
    error('{"materials": {"m": {"kd": NaN}}}', "/materials/m/kd", "NaN")


def test_radius_zero_rejected_negative_allowed():
    error(items({"sphere": {"center": [0, 0, 0], "radius": 0}}), "/scene/items/0/sphere/radius", "must not be zero")
    assert load(items({"sphere": {"center": [0, 0, 0], "radius": -2}})).root.spheres.freeze().radius[0] == -2
    cone = {"base": [0, 0, 0], "base_radius": 0, "apex": [0, 0, 1], "apex_radius": 0}
    error(items({"cone": cone}), "/scene/items/0/cone", "both be zero")
    error(items({"cone": dict(cone, apex=[0, 0, 0], apex_radius=1)}), "/scene/items/0/cone", "must differ")
    assert len(load(items({"cone": dict(cone, base_radius=-1)})).root.cones) == 1


def test_unknown_names_list_the_known_ones():
    doc = {"materials": {"gold": {}, "silver": {}}, "groups": {"teapot": {}, "cup": {}},
           "scene": {"items": [{"sphere": {"center": [0, 0, 0], "radius": 1}, "material": "gld"}]}}
    error(doc, "/scene/items/0/material", "unknown material 'gld'", "known materials: gold, silver")
    doc["scene"]["items"] = [{"instance": "teapto"}]
    error(doc, "/scene/items/0/instance", "unknown group 'teapto'", "known groups: teapot, cup")
    error(items({"instance": "x"}), "known groups: none")
    error(items({"sphere": {"center": [0, 0, 0], "radius": 1}, "material": 3}), "expected a material name")


def test_missing_include_file(tmp_path):
    error(items({"include": "gone.nff"}), "scene.json: /scene/items/0/include: include file not found: 'gone.nff'",
          str(tmp_path / "gone.nff"), path=str(tmp_path / "scene.json"))
    error(items({"include": {"file": "gone.nff"}}), "/scene/items/0/include/file", path=str(tmp_path / "s.json"))
    error(items({"include": {"path": "x.nff"}}), "/scene/items/0/include/path", "allowed keys: file, accel")
    error(items({"mesh": "gone.obj"}), "/scene/items/0/mesh", "mesh file not found", path=str(tmp_path / "s.json"))


def test_cycles_name_their_groups():
    error({"groups": {"a": {"items": [{"instance": "a"}]}}}, "/groups/a/items/0/instance", "cycle", "'a' -> 'a'")
    doc = {"groups": {"a": {"items": [{"group": {"items": [{"instance": "b"}]}}]},
                      "b": {"items": [{"instance": "c", "transform": {"scale": 2}}]},
                      "c": {"items": [{"instance": "a"}]}},
           "scene": {"items": [{"instance": "a"}]}}
    error(doc, "/groups/c/items/0/instance", "cycle", "'a' -> 'b' -> 'c' -> 'a'")


def _inline_chain(levels: int) -> dict:
    body = {"items": [{"sphere": {"center": [0, 0, 0], "radius": 1}}]}
    for _ in range(levels):
        body = {"items": [{"group": body}]}
    return {"scene": body}


def test_nesting_limit_inline_groups():
    assert MAX_NESTING == 16
    scene = load(_inline_chain(MAX_NESTING - 1))                 # root + 15 levels = 16 groups deep
    assert scene.count_primitives() == 1
    message = error(_inline_chain(MAX_NESTING), "MAX_NESTING = 16", "17 levels")
    assert "/scene" + "/items/0/group" * MAX_NESTING in message


def test_nesting_limit_named_groups_and_transforms():
    def chain(n):
        groups = {f"g{i}": {"items": [{"instance": f"g{i + 1}"}]} for i in range(n)}
        groups[f"g{n}"] = {"items": [{"sphere": {"center": [0, 0, 0], "radius": 1}}]}
        return {"groups": groups, "scene": {"items": [{"instance": "g0"}]}}

    assert load(chain(MAX_NESTING - 2)).count_primitives() == 1      # root, g0 .. g14: 16 levels
    error(chain(MAX_NESTING - 1), "MAX_NESTING")
    error(chain(500), "MAX_NESTING")                                     # no RecursionError
    deep = _inline_chain(MAX_NESTING - 1)
    body = deep["scene"]
    for _ in range(MAX_NESTING - 1):
        body = body["items"][0]["group"]
    body["items"][0]["transform"] = {"translate": [1, 0, 0]}          # a transformed primitive adds a level
    error(deep, "MAX_NESTING", "/transform")
    # A group that fits on its own but not where it is placed:
    nested = {"groups": {"g": _inline_chain(MAX_NESTING - 2)["scene"]}, "scene": {"items": [{"instance": "g"}]}}
    assert load(nested).count_primitives() == 1
    nested["scene"] = {"items": [{"group": {"items": [{"instance": "g"}]}}]}
    error(nested, "/scene/items/0/group/items/0/instance", "MAX_NESTING")


def test_limit_matches_the_renderer():
    flatten = pytest.importorskip("raykernel.engine.flatten")
    assert MAX_NESTING == flatten.MAX_NESTING


def test_deeply_nested_json_is_a_scene_error():
    error("[" * 100000 + "]" * 100000, "nested too deeply")


# ---- writing and the round trip ---------------------------------------------------------------


def _same_group(a: Group, b: Group, mats_a, mats_b, pairs: dict):
    if id(a) in pairs:
        assert pairs[id(a)] is b, "sharing differs"
        return
    pairs[id(a)] = b
    assert a.accel == b.accel
    for name in ("spheres", "cones", "polygons", "patches"):
        sa, sb = getattr(a, name).freeze(), getattr(b, name).freeze()
        assert len(sa) == len(sb), name
        for field in ("center", "radius", "base", "base_radius", "apex", "apex_radius",
                      "vertices", "normals", "start", "count"):
            if hasattr(sa, field) and getattr(sa, field) is not None:
                np.testing.assert_array_equal(getattr(sa, field), getattr(sb, field), err_msg=f"{name}.{field}")
        assert [mats_a[m] for m in sa.material] == [mats_b[m] for m in sb.material]
    assert len(a.meshes) == len(b.meshes)
    for ma, mb in zip(a.meshes, b.meshes):
        np.testing.assert_array_equal(ma.vertices, mb.vertices)
        np.testing.assert_array_equal(ma.faces, mb.faces)
        assert (ma.normals is None) == (mb.normals is None)
        if ma.normals is not None:
            np.testing.assert_array_equal(ma.normals, mb.normals)
        assert [mats_a[m] for m in ma.material] == [mats_b[m] for m in mb.material]
    assert len(a.children) == len(b.children)
    for ca, cb in zip(a.children, b.children):
        if isinstance(ca, Instance):
            assert isinstance(cb, Instance)
            np.testing.assert_array_equal(ca.matrix, cb.matrix)
            _same_group(ca.group, cb.group, mats_a, mats_b, pairs)
        else:
            assert isinstance(cb, Group)
            _same_group(ca, cb, mats_a, mats_b, pairs)


def assert_same_scene(a: Scene, b: Scene):
    for field in ("eye", "look_at", "up"):
        np.testing.assert_array_equal(getattr(a.camera, field), getattr(b.camera, field))
    assert (a.camera.angle, a.camera.hither, a.camera.width, a.camera.height) == \
           (b.camera.angle, b.camera.hither, b.camera.width, b.camera.height)
    np.testing.assert_array_equal(a.background, b.background)
    assert len(a.lights) == len(b.lights)
    for la, lb in zip(a.lights, b.lights):
        np.testing.assert_array_equal(la.position, lb.position)
        assert (la.color is None and lb.color is None) or np.array_equal(la.color, lb.color)
    _same_group(a.root, b.root, a.materials, b.materials, {})


ROUND_TRIP_DOC = {
    "camera": {"eye": [1.5, -7.25, 2], "look_at": [0, 0, 0.5], "up": [0, 0, 1], "angle": 37.5,
               "hither": 0.02, "resolution": [320, 240]},
    "background": [0.1, 0.2, 0.3],
    "lights": [{"position": [4, 3, 2]}, {"position": [-1, 2, 9], "color": [0.5, 0.5, 1]}],
    "materials": {"gold": {"color": [1, 0.8, 0.3], "kd": 0.5, "ks": 0.5, "shine": 20},
                  "glass": {"color": [0.9, 0.9, 1], "kd": 0.1, "t": 0.9, "ior": 1.52}},
    "groups": {
        "ball": {"accel": "bvh(leaf=2)", "material": "glass", "items": [
            {"sphere": {"center": [0, 0, 0.1], "radius": 1 / 3}},
            {"cone": {"base": [0, 0, 0], "base_radius": 0.2, "apex": [0, 0, -1], "apex_radius": 0.1}}]},
        "pair": {"items": [{"instance": "ball"}, {"instance": "ball", "transform": {"translate": [0, 2, 0]}}]},
    },
    "scene": {"accel": "list", "items": [
        {"sphere": {"center": [0.1, 0.2, 0.3], "radius": -2.5}, "material": "gold"},
        {"cone": {"base": [1, 1, 1], "base_radius": 0.5, "apex": [1, 1, 3], "apex_radius": 0.5}},
        {"polygon": [[-5, -5, 0], [5, -5, 0], [5, 5, 0], [-5, 5, 0.001]], "material": "gold"},
        {"patch": {"vertices": TRIANGLE, "normals": [[0, 0, 1], [0.1, 0, 1], [0, 0.1, 1]]}},
        {"mesh": {"vertices": [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.5]], "faces": [[0, 1, 2], [1, 3, 2]],
                  "normals": [[0, 0, 1]] * 4}, "material": "glass"},
        {"mesh": {"vertices": TRIANGLE, "faces": [[0, 2, 1]]}},
        {"sphere": {"center": [7, 7, 7], "radius": 0.7}, "transform": {"rotate": {"axis": [1, 2, 3], "degrees": 33}}},
        {"group": {"accel": "bvh", "items": [
            {"group": {"items": [{"polygon": TRIANGLE}, {"instance": "ball", "transform": {"scale": [1, 2, 3]}}]}}]},
         "transform": [{"scale": 0.5}, {"translate": [3, 0, 0]}]},
        {"instance": "ball"},
        {"instance": "ball", "transform": {"matrix": [[0, 0, 1, 1], [0, 1, 0, 2], [-1, 0, 0, 3], [0, 0, 0, 1]]}},
        {"instance": "pair", "transform": {"translate": [0, 0, 5]}},
        {"instance": "pair"},
    ]},
}


def test_round_trip_through_a_file(tmp_path):
    scene = load(ROUND_TRIP_DOC)
    path = write_json(scene, tmp_path / "out.json")
    assert path == tmp_path / "out.json"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.json"]      # no temporary file left behind
    again = read_json(path)
    assert_same_scene(scene, again)
    balls = [c.group for c in again.root.children if isinstance(c, Instance) and c.group.name == "ball"]
    assert len(balls) == 2 and balls[0] is balls[1]
    # Writing the copy gives the same document: the format is a fixed point after one pass.
    assert scene_to_json(again) == scene_to_json(scene)


def test_written_document_shape():
    doc = scene_to_json(load(ROUND_TRIP_DOC))
    assert list(doc) == ["camera", "background", "lights", "materials", "groups", "scene"]
    assert set(doc["groups"]) == {"ball", "pair"}
    assert list(doc["materials"]) == [f"m{i}" for i in range(len(doc["materials"]))]
    items_ = doc["scene"]["items"]
    assert all(isinstance(x, float) for x in items_[0]["sphere"]["center"])
    assert isinstance(items_[0]["sphere"]["radius"], float)
    placed = [i for i in items_ if "instance" in i]
    assert all(set(i["transform"]) == {"matrix"} for i in placed)
    json.dumps(doc, allow_nan=False)
    assert scene_from_json(doc).count_primitives() == load(ROUND_TRIP_DOC).count_primitives()


def test_round_trip_of_a_python_built_scene(tmp_path):
    scene = Scene(camera=Camera(eye=(0, -5, 1), look_at=(0, 0, 0)), background=(0.5, 0.5, 0.5))
    red = scene.add_material(Material(color=(1, 0, 0)))
    blue = scene.add_material(Material(color=(0, 0, 1), ks=0.3))
    scene.add_light((0, 0, 10))
    leaf = Group(name="leaf", accel="bvh")
    leaf.spheres.add((0, 0, 0), 1.0, red)
    leaf.add(TriangleMesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], [[0, 1, 2], [1, 3, 2], [0, 2, 3]],
                          material=[red, blue, red], normals=[[0, 0, 1]] * 4))
    twig = Group(name="twig")
    twig.add(Instance(leaf, np.diag([2.0, 2.0, 2.0, 1.0])))
    twig.add(leaf)                                                       # the same group placed directly too
    scene.root.add(twig)
    scene.root.add(Instance(twig, np.array([[1, 0, 0, 5], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])))
    scene.root.polygons.add([[0, 0, 0], [1, 0, 0], [1, 1, 0]], blue)
    write_json(scene, tmp_path / "py.json")
    again = read_json(tmp_path / "py.json")
    doc = json.loads((tmp_path / "py.json").read_text())
    assert set(doc["groups"]) == {"leaf", "twig"}
    # The mesh with two materials comes back as one mesh per material, with the same triangles.
    # twig was placed both directly and through an instance: both come back as instances of one group.
    plain, again_twig_inst = again.root.children
    assert isinstance(plain, Instance) and plain.group is again_twig_inst.group
    np.testing.assert_array_equal(plain.matrix, np.eye(4))
    again_leaf = again_twig_inst.group.children[0].group
    tris = sorted(tuple(map(tuple, m.vertices[f])) + (again.materials[m.material[k]].color,)
                  for m in again_leaf.meshes for k, f in enumerate(m.faces))
    original = leaf.meshes[0]
    expected = sorted(tuple(map(tuple, original.vertices[f])) + (scene.materials[original.material[k]].color,)
                      for k, f in enumerate(original.faces))
    assert tris == expected
    np.testing.assert_array_equal(again_twig_inst.matrix[:3, 3], [5, 0, 0])
    assert again.count_primitives() == scene.count_primitives()


def test_writer_rejects_cycles_and_bad_material_indices(tmp_path):
    scene = Scene()
    a, b = Group(name="a"), Group(name="b")
    a.add(Instance(b))
    b.add(a)
    scene.root.add(a)
    with pytest.raises(SceneError, match="cycle"):
        scene_to_json(scene)
    scene = Scene()
    scene.root.spheres.add((0, 0, 0), 1.0, 4)
    with pytest.raises(SceneError, match="material 4"):
        write_json(scene, tmp_path / "x.json")
    assert list(tmp_path.iterdir()) == []


def test_write_replaces_an_existing_file(tmp_path):
    target = tmp_path / "s.json"
    target.write_text("old")
    write_json(load(ROUND_TRIP_DOC), target)
    assert read_json(target).count_primitives() == load(ROUND_TRIP_DOC).count_primitives()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.json"]


def test_example_nested_scene():
    scene = read_json(REPO / "examples" / "nested.json")
    instances = [c for c in scene.root.children if isinstance(c, Instance)]
    assert len(instances) == 3 and len({id(i.group) for i in instances}) == 1
    assert instances[0].group.accel == "bvh"
    assert scene.root.accel is not None
    assert scene.count_primitives() > 3 * 10


def test_parse_does_not_modify_the_document():
    doc = copy.deepcopy(ROUND_TRIP_DOC)
    scene_from_json(doc)
    assert doc == ROUND_TRIP_DOC

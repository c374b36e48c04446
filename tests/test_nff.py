"""NFF reading and writing: the SPD files, every kind of bad input, and round trips."""

from __future__ import annotations

import functools
import os

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from raykernel.errors import SceneError
from raykernel.scene import Camera, Group, Instance, Material, Scene, TriangleMesh
from raykernel.scene.nff import parse_nff, read_nff, scene_to_nff, write_nff

from support import SPD_DIR

# Counted independently (README of the SPD directory): spheres, polygons, patches, cones, lights.
SPD_COUNTS = {
    "balls-sf1.nff": (10, 1, 0, 0, 3),
    "balls-sf4.nff": (7381, 1, 0, 0, 3),
    "gears-sf1.nff": (0, 147, 0, 0, 5),
    "gears-sf4.nff": (0, 9345, 0, 0, 5),
    "mount-sf1.nff": (4, 8, 0, 0, 1),
    "mount-sf6.nff": (4, 8192, 0, 0, 1),
    "rings-sf1.nff": (30, 1, 0, 30, 3),
    "rings-sf7.nff": (4200, 1, 0, 4200, 3),
    "teapot-sf1.nff": (0, 1, 56, 0, 2),
    "teapot-sf2.nff": (0, 4, 240, 0, 2),
    "teapot-sf6.nff": (0, 36, 2256, 0, 2),
    "teapot-sf12.nff": (0, 144, 9120, 0, 2),
    "tetra-sf1.nff": (0, 4, 0, 0, 1),
    "tetra-sf6.nff": (0, 4096, 0, 0, 1),
    "tree-sf1.nff": (3, 1, 0, 3, 7),
    "tree-sf11.nff": (4095, 1, 0, 4095, 7),
    "jacks-sf1.nff": (6, 0, 0, 3, 1),
    "jacks-sf4.nff": (3510, 0, 0, 1755, 1),
    "lattice-sf1.nff": (8, 0, 0, 12, 6),
    "lattice-sf12.nff": (2197, 0, 0, 6084, 6),
    "shells-sf1.nff": (361, 0, 0, 0, 1),
    "shells-sf5.nff": (5761, 0, 0, 0, 1),
    "sombrero-sf1.nff": (0, 1922, 0, 0, 1),
    "sample-sf1.nff": (0, 16, 864, 1, 1),
    "nurbtst-sf1.nff": (0, 0, 1500, 0, 1),
}

# file: (from, at, up, angle, hither, resolution), from the README's view table.
SPD_VIEWS = {
    "balls-sf4.nff": ((2.1, 1.3, 1.7), (0, 0, 0), (0, 0, 1), 45, 0.01, 512),
    "tetra-sf6.nff": ((1.02285, -3.17715, -2.17451), (-0.004103, -0.004103, 0.216539),
                      (-0.816497, -0.816497, 0.816497), 45, 1, 512),
    "jacks-sf1.nff": ((0, 0, -8), (0, 0, 0), (0, 1, 0), 25, 0.001, 256),
    "lattice-sf12.nff": ((0.541667, 1, 0.958333), (0.541667, -1, -1.04167), (0.2, 1, 0), 60, 0, 512),
    "rings-sf7.nff": ((-1, -2.61313, 0.5), (-1, -1.61313, 0.5), (0, 0, 1), 45, 1, 512),
    "nurbtst-sf1.nff": ((0, 5, -10), (0, 0, 0), (0, 1, 0), 30, 0.001, 256),
}

VIEW = "v\nfrom 0 -5 0\nat 0 0 0\nup 0 0 1\nangle 45\nhither 0.01\nresolution 64 64\n"  # lines 1-7


@functools.lru_cache(maxsize=None)
def spd(name: str) -> Scene:
    return read_nff(SPD_DIR / name)


def expect_error(text, line, *phrases, path="bad.nff"):
    with pytest.raises(SceneError) as info:
        parse_nff(text, path)
    message = str(info.value)
    assert message.startswith(f"{path}:{line}: "), message
    assert info.value.line == line
    for phrase in phrases:
        assert phrase in message, message
    return message


def materials_of(scene: Scene, prim_set) -> np.ndarray:
    return np.array([[*m.color, m.kd, m.ks, m.shine, m.t, m.ior]
                     for m in (scene.materials[i] for i in prim_set.material)]).reshape(-1, 8)


def assert_same_scene(a: Scene, b: Scene, rtol=1e-6, atol=0.0):
    def close(x, y):
        x, y = np.asarray(x, float), np.asarray(y, float)
        assert x.shape == y.shape
        np.testing.assert_allclose(x, y, rtol=rtol, atol=atol)

    for field in ("eye", "look_at", "up", "angle", "hither"):
        close(getattr(a.camera, field), getattr(b.camera, field))
    assert (a.camera.width, a.camera.height) == (b.camera.width, b.camera.height)
    close(a.background, b.background)
    assert len(a.lights) == len(b.lights)
    for la, lb in zip(a.lights, b.lights):
        close(la.position, lb.position)
        assert (la.color is None) == (lb.color is None)
        if la.color is not None:
            close(la.color, lb.color)
    ra, rb = a.root, b.root
    close(ra.spheres.center, rb.spheres.center)
    close(ra.spheres.radius, rb.spheres.radius)
    close(materials_of(a, ra.spheres), materials_of(b, rb.spheres))
    for f in ("base", "base_radius", "apex", "apex_radius"):
        close(getattr(ra.cones, f), getattr(rb.cones, f))
    close(materials_of(a, ra.cones), materials_of(b, rb.cones))
    for kind in ("polygons", "patches"):
        pa, pb = getattr(ra, kind), getattr(rb, kind)
        assert np.array_equal(pa.count, pb.count)
        assert np.array_equal(pa.start, pb.start)
        close(pa.vertices, pb.vertices)
        if pa.patches:
            close(pa.normals, pb.normals)
        close(materials_of(a, pa), materials_of(b, pb))


# ---------------------------------------------------------------------------------------------
# The SPD files


def test_table_covers_every_spd_file():
    assert sorted(p.name for p in SPD_DIR.glob("*.nff")) == sorted(SPD_COUNTS)


@pytest.mark.parametrize("name", sorted(SPD_COUNTS))
def test_spd_counts(name):
    scene = spd(name)
    r = scene.root
    assert (len(r.spheres), len(r.polygons), len(r.patches), len(r.cones), len(scene.lights)) == SPD_COUNTS[name]
    assert scene.source == str(SPD_DIR / name)
    assert all(light.color is None for light in scene.lights)
    assert r.patches.count.tolist() == [3] * len(r.patches)


@pytest.mark.parametrize("name", sorted(SPD_VIEWS))
def test_spd_views(name):
    eye, at, up, angle, hither, res = SPD_VIEWS[name]
    cam = spd(name).camera
    np.testing.assert_allclose(cam.eye, eye)
    np.testing.assert_allclose(cam.look_at, at)
    np.testing.assert_allclose(cam.up, up)
    assert cam.angle == angle and cam.hither == hither
    assert (cam.width, cam.height) == (res, res)


def test_spd_backgrounds():
    np.testing.assert_allclose(spd("balls-sf1.nff").background, [0.078, 0.361, 0.753])
    np.testing.assert_allclose(spd("jacks-sf1.nff").background, [0.2, 0.05, 0.2])
    np.testing.assert_allclose(spd("sample-sf1.nff").background, [0.8, 0.8, 0.8])
    np.testing.assert_allclose(spd("nurbtst-sf1.nff").background, [0, 0, 0])


def test_spd_material_line_values():
    # rings: "f 1 0 0 0.5 0.2 3.0827 0 0" precedes the first cylinder and sphere.
    scene = spd("rings-sf1.nff")
    m = scene.materials[scene.root.spheres.material[0]]
    assert m == Material((1, 0, 0), kd=0.5, ks=0.2, shine=3.0827, t=0, ior=0)
    assert scene.materials[scene.root.cones.material[0]] == m
    # gears: 13 of 64 gears transmit (Kd .2, Ks 0, T .8, ior 1.1), 1898 polygons in all.
    gears = spd("gears-sf4.nff")
    mats = materials_of(gears, gears.root.polygons)
    glass = mats[:, 6] > 0
    assert glass.sum() == 1898
    np.testing.assert_allclose(mats[glass][:, 3:], np.tile([0.2, 0, 100000, 0.8, 1.1], (1898, 1)))


def test_spd_materials_registered_once_and_only_when_used():
    # teapot-sf1's single check is grey, so its "f 1 1 1 ..." line is never used.
    scene = spd("teapot-sf1.nff")
    assert len(scene.materials) == 2
    assert len(set(scene.materials)) == len(scene.materials)
    assert Material((1, 1, 1), 0.5, 0.5, 4.81884, 0, 0) not in scene.materials


def test_spd_zero_area_teapot_patches_are_kept():
    patches = spd("teapot-sf1.nff").root.patches
    tri = patches.vertices.reshape(-1, 3, 3)
    area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    assert (area == 0).sum() == 4


@pytest.mark.parametrize("name", sorted(SPD_COUNTS))
def test_spd_round_trip(name):
    scene = spd(name)
    again = parse_nff(scene_to_nff(scene), "again.nff")
    assert_same_scene(scene, again)


def test_spd_round_trip_through_a_file(tmp_path):
    scene = spd("rings-sf1.nff")
    target = tmp_path / "rings.nff"
    write_nff(scene, target)
    assert_same_scene(scene, read_nff(target))


# ---------------------------------------------------------------------------------------------
# Grammar details


def test_cone_on_one_line_and_on_three_lines_parse_identically():
    one = parse_nff(VIEW + "c 0 0 0 1 0 0 2 0.5\n")
    three = parse_nff(VIEW + "c\n0 0 0 1\n0 0 2 0.5\n")
    for f in ("base", "base_radius", "apex", "apex_radius"):
        assert np.array_equal(getattr(one.root.cones, f), getattr(three.root.cones, f))
    np.testing.assert_array_equal(one.root.cones.apex, [[0, 0, 2]])
    assert one.root.cones.apex_radius.tolist() == [0.5]


def test_whole_file_on_one_line():
    text = VIEW.replace("\n", " ") + "s 0 0 0 1 p 3 0 0 0 1 0 0 0 1 0"
    scene = parse_nff(text)
    assert len(scene.root.spheres) == 1 and len(scene.root.polygons) == 1


def test_light_with_and_without_colour():
    scene = parse_nff(VIEW + "l 1 2 3\nl 4 5 6 0.5 0.25 1\nl 7 8 9\ns 0 0 0 1\n")
    assert [lt.position.tolist() for lt in scene.lights] == [[1, 2, 3], [4, 5, 6], [7, 8, 9]]
    assert scene.lights[0].color is None and scene.lights[2].color is None
    assert scene.lights[1].color.tolist() == [0.5, 0.25, 1]


def test_light_colour_cut_short():
    expect_error(VIEW + "l 1 2 3 0.5 0.5\ns 0 0 0 1\n", 9, "light colour blue", "got keyword 's'")


def test_comments_everywhere():
    text = ("# header\nb 0.1 0.2 0.3 # background\n#glued comment\nv # view\nfrom 0 -5 0#glued\n"
            "at 0 0 0\n  # indented\nup 0 0 1\nangle 45\nhither 0.01\nresolution 64 64\n"
            "f 1 0 0 1 0 0 0 1 #material\ns 0 0 # inside an entity\n 0 1\n"
            "p 3 # count\n0 0 0 #v1\n1 0 0\n#\n0 1 0\n# trailing")
    scene = parse_nff(text)
    np.testing.assert_allclose(scene.background, [0.1, 0.2, 0.3])
    np.testing.assert_allclose(scene.root.spheres.center, [[0, 0, 0]])
    assert len(scene.root.polygons) == 1
    assert scene.materials[0].color == (1.0, 0.0, 0.0)


def test_crlf_and_cr_line_ends_keep_line_numbers():
    expect_error((VIEW + "s 0 0 0 1\nq\n").replace("\n", "\r\n"), 9, "unknown keyword 'q'")
    expect_error((VIEW + "s 0 0 0 1\nq\n").replace("\n", "\r"), 9, "unknown keyword 'q'")


def test_view_parameters_in_any_order():
    text = "v\nresolution 32 16\nhither 1\nup 0 0 1\nangle 30\nat 1 1 1\nfrom 0 -5 0\ns 0 0 0 1\n"
    cam = parse_nff(text).camera
    assert (cam.width, cam.height, cam.angle, cam.hither) == (32, 16, 30, 1)
    np.testing.assert_allclose(cam.look_at, [1, 1, 1])


def test_background_light_and_material_before_view_are_accepted():
    scene = parse_nff("b 1 1 1\nl 1 1 1\nf 0 1 0 1 0 0 0 1\n" + VIEW + "s 0 0 0 1\n")
    assert scene.root.spheres.material.tolist() == [0]
    assert scene.materials[0].color == (0.0, 1.0, 0.0)


def test_lights_after_geometry_are_accepted():
    scene = parse_nff(VIEW + "s 0 0 0 1\nl 1 1 1\n")
    assert len(scene.lights) == 1


def test_default_material_before_any_f():
    scene = parse_nff(VIEW + "s 0 0 0 1\nf 1 0 0 0.5 0.5 10 0 1\ns 1 1 1 1\ns 2 2 2 1\n")
    assert scene.materials == [Material(), Material((1, 0, 0), 0.5, 0.5, 10, 0, 1)]
    assert scene.root.spheres.material.tolist() == [0, 1, 1]


def test_negative_radius_is_kept():
    scene = parse_nff(VIEW + "s 0 0 0 -2\nc 0 0 0 -1 0 0 1 -1\n")
    assert scene.root.spheres.radius.tolist() == [-2]
    assert scene.root.cones.base_radius.tolist() == [-1]


def test_primitives_keep_file_order_per_kind():
    scene = parse_nff(VIEW + "s 0 0 0 1\nc 0 0 0 1 0 0 1 1\ns 5 0 0 2\npp 3\n0 0 0 0 0 1\n1 0 0 0 0 1\n"
                      "0 1 0 0 0 2\ns 9 0 0 3\n")
    assert scene.root.spheres.radius.tolist() == [1, 2, 3]
    np.testing.assert_allclose(scene.root.patches.normals[2], [0, 0, 2])


def test_small_polygon_is_not_degenerate():
    scale = 1e-7
    scene = parse_nff(VIEW + f"p 3\n0 0 0\n{scale} 0 0\n0 {scale} 0\n")
    assert len(scene.root.polygons) == 1


def test_zero_area_patch_is_accepted():
    scene = parse_nff(VIEW + "pp 3\n0 0 0 0 0 1\n1 0 0 0 0 1\n2 0 0 0 0 1\n")
    assert len(scene.root.patches) == 1


def test_bytes_with_byte_order_mark():
    scene = parse_nff(b"\xef\xbb\xbf" + (VIEW + "s 0 0 0 1\n").encode())
    assert len(scene.root.spheres) == 1


def test_view_only_file_is_an_empty_scene():
    scene = parse_nff(VIEW)
    assert scene.count_primitives() == 0


# ---------------------------------------------------------------------------------------------
# Bad input: one SceneError naming file, line and what was expected


def test_unknown_keyword():
    expect_error(VIEW + "s 0 0 0 1\nsphere 0 0 0 1\n", 9, "unknown keyword 'sphere'", "expected one of")


def test_keywords_are_case_sensitive():
    expect_error(VIEW + "S 0 0 0 1\n", 8, "unknown keyword 'S'")


def test_missing_number_cut_short_by_next_keyword():
    expect_error(VIEW + "s 0 0 0\ns 1 1 1 1\n", 9, "expected a number for the sphere radius", "got keyword 's'",
                 "sphere starting at line 8 is cut short")


def test_missing_numbers_at_end_of_file():
    expect_error(VIEW + "\ns 0 0\n\n", 9, "unexpected end of file", "sphere centre z")


def test_extra_number_where_a_keyword_belongs():
    expect_error(VIEW + "s 0 0 0 1 5\n", 8, "expected a keyword", "'5'")


def test_text_where_a_number_belongs():
    expect_error(VIEW + "s 0 0 0 abc\n", 8, "expected a number for the sphere radius, got 'abc'")


@pytest.mark.parametrize("token", ["nan", "NaN", "inf", "-Infinity", "1e999"])
def test_non_finite_numbers(token):
    expect_error(VIEW + f"s 0 0 0 1\ns 0 {token} 0 1\n", 9, "expected a finite number for the sphere centre y",
                 repr(token))


@pytest.mark.parametrize("token", ["1_0", "0x10", "１"])
def test_numbers_only_in_plain_decimal(token):
    expect_error(VIEW + f"s 0 0 0 {token}\n", 8, "expected a number for the sphere radius", repr(token))


def test_polygon_with_fewer_than_three_vertices():
    expect_error(VIEW + "p 2\n0 0 0\n1 0 0\n", 8, "at least 3 vertices", "count of 2")


def test_negative_vertex_count():
    expect_error(VIEW + "p -3\n0 0 0\n1 0 0\n0 1 0\n", 8, "at least 3 vertices", "-3")


def test_absurd_vertex_count_is_a_truncated_file():
    expect_error(VIEW + "\np 99999999999\n0 0 0\n1 0 0\n0 1 0\n", 9, "declares 99999999999 vertices",
                 "truncated")
    expect_error(VIEW + "pp 1" + "0" * 40 + "\n", 8, "truncated")


def test_vertex_count_not_a_whole_number():
    expect_error(VIEW + "p 3.0\n0 0 0\n1 0 0\n0 1 0\n", 8, "whole number for the vertex count", "'3.0'")


def test_vertex_count_missing():
    expect_error(VIEW + "p\ns 0 0 0 1\n", 9, "vertex count of the polygon", "got keyword 's'")
    expect_error(VIEW + "pp\n", 8, "unexpected end of file", "vertex count of the patch")


def test_polygon_with_fewer_vertices_than_declared():
    expect_error(VIEW + "p 4\n0 0 0\n1 0 0\n0 1 0\ns 0 0 0 1\n", 12, "polygon vertex 4 x",
                 "got keyword 's'", "line 8 is cut short")


def test_polygon_collinear_first_corner():
    expect_error(VIEW + "p 4\n0 0 0\n1 1 1\n2 2 2\n0 1 0\n", 8, "first three vertices", "collinear")


def test_polygon_coincident_first_vertices():
    expect_error(VIEW + "p 3\n1 2 3\n1 2 3\n0 1 0\n", 8, "first three vertices", "coincident")


def test_polygon_corner_degenerate_relative_to_its_size():
    # The corner is 1e-6 across in a polygon a million units wide.
    expect_error(VIEW + "p 4\n0 0 0\n1e-6 0 0\n1e-6 1e-12 0\n1e6 1e6 0\n", 8, "first three vertices")


def test_patch_with_collinear_first_corner_but_area():
    expect_error(VIEW + "pp 4\n0 0 0 0 0 1\n1 0 0 0 0 1\n2 0 0 0 0 1\n0 1 0 0 0 1\n", 8, "first three vertices")


def test_patch_normal_of_zero_length():
    expect_error(VIEW + "pp 3\n0 0 0 0 0 1\n1 0 0 0 0 0\n0 1 0 0 0 1\n", 10, "patch normal at vertex 2",
                 "zero length")


def test_truncated_file():
    expect_error(VIEW + "c 0 0 0 1\n0 0 1", 9, "unexpected end of file", "cone apex radius",
                 "cone starting at line 8")


def test_empty_file():
    expect_error("", 1, "empty file")
    expect_error("# only\n# comments\n   \n", 3, "empty file")


def test_missing_file(tmp_path):
    missing = tmp_path / "nope.nff"
    with pytest.raises(SceneError) as info:
        read_nff(missing)
    assert str(info.value) == f"{missing}: no such file"


def test_directory_instead_of_file(tmp_path):
    with pytest.raises(SceneError, match="is a directory"):
        read_nff(tmp_path)


def test_binary_file_with_nul(tmp_path):
    path = tmp_path / "image.nff"
    path.write_bytes(b"v\nfrom 0 0 0\n\x89PNG\x00\x01\x02")
    with pytest.raises(SceneError) as info:
        read_nff(path)
    assert str(info.value).startswith(f"{path}:3: not a text NFF file")


def test_file_not_utf8(tmp_path):
    path = tmp_path / "latin.nff"
    path.write_bytes(VIEW.encode() + b"s 0 0 0 1 # caf\xe9\n")
    with pytest.raises(SceneError) as info:
        read_nff(path)
    assert str(info.value).startswith(f"{path}:8: not a text NFF file")
    assert "0xe9" in str(info.value)


def test_nul_in_text():
    expect_error(VIEW + "s 0 0 0 1\x00\n", 8, "not a text NFF file")


def test_no_view_at_all(tmp_path):
    expect_error("b 0 0 0\nl 1 1 1\n\n# end\n", 2, "no view block")
    # a file is read by the fast path first, which must hand such a file to the reading that names it
    for text, line in (("b 0 0 0\nl 1 1 1\n\n# end\n", 2), ("b 0.1 0.2 0.3\n", 1)):
        path = tmp_path / "noview.nff"
        path.write_text(text)
        with pytest.raises(SceneError, match=f"^{path}:{line}: no view block"):
            read_nff(path)


def test_geometry_before_view():
    expect_error("b 0 0 0\ns 0 0 0 1\n" + VIEW, 2, "a sphere before the view block")
    expect_error("p 3 0 0 0 1 0 0 0 1 0\n" + VIEW, 1, "a polygon before the view block")


def test_view_missing_a_parameter():
    text = "v\nfrom 0 -5 0\nat 0 0 0\nup 0 0 1\nangle 45\nresolution 64 64\ns 0 0 0 1\n"
    expect_error(text, 7, "view block at line 1 is missing 'hither'", "got 's'")
    expect_error("v\nfrom 0 -5 0\nat 0 0 0\n", 3, "unexpected end of file", "'up', 'angle', 'hither', 'resolution'")


def test_view_parameter_twice():
    expect_error("v\nfrom 0 -5 0\nfrom 0 -6 0\n", 3, "second 'from'", "first is at line 2")


def test_view_parameter_cut_short():
    expect_error("v\nfrom 0 -5\nat 0 0 0\n", 3, "view 'from' z", "got keyword 'at'")


def test_view_parameter_outside_view_block():
    expect_error(VIEW + "angle 30\n", 8, "'angle' outside a view block")


def test_second_view_block():
    expect_error(VIEW + VIEW, 8, "second view block", "line 1")


def test_view_eye_equals_at():
    expect_error(VIEW.replace("at 0 0 0", "at 0 -5 0"), 3, "same as 'from'")


def test_view_up_parallel_to_direction():
    expect_error(VIEW.replace("up 0 0 1", "up 0 2 0"), 4, "'up' vector", "parallel")


@pytest.mark.parametrize("angle", ["0", "180", "-10", "200"])
def test_view_angle_out_of_range(angle):
    expect_error(VIEW.replace("angle 45", f"angle {angle}"), 5, "angle must be between 0 and 180")


def test_view_negative_hither():
    expect_error(VIEW.replace("hither 0.01", "hither -1"), 6, "hither", "negative")


@pytest.mark.parametrize("res, col", [("0 64", "width"), ("64 -2", "height"), ("64 100000", "height")])
def test_view_resolution_out_of_range(res, col):
    expect_error(VIEW.replace("resolution 64 64", f"resolution {res}"), 7, f"resolution {col} must be from 1")


def test_view_resolution_not_an_integer():
    expect_error(VIEW.replace("resolution 64 64", "resolution 64 64.5"), 7, "whole number", "height", "'64.5'")
    cam = parse_nff(VIEW.replace("resolution 64 64", "resolution 64.0 32")).camera
    assert (cam.width, cam.height) == (64, 32)


def test_zero_radius_sphere():
    expect_error(VIEW + "s 0 0 0\n0\n", 9, "sphere radius must not be zero")


def test_degenerate_cones():
    expect_error(VIEW + "c 1 1 1 1 1 1 1 2\n", 8, "base and apex are the same point")
    expect_error(VIEW + "c 0 0 0 0 0 0 1 0\n", 8, "zero radius at both ends")


def test_material_line_cut_short():
    expect_error(VIEW + "f 1 1 1 1 0 0 0\ns 0 0 0 1\n", 9, "material ('f') ior", "got keyword 's'")


def test_error_is_one_line_without_chained_traceback(tmp_path):
    with pytest.raises(SceneError) as info:
        read_nff(tmp_path / "missing.nff")
    assert info.value.__cause__ is None and info.value.__suppress_context__


# ---------------------------------------------------------------------------------------------
# Fuzzing: only SceneError may escape

_SOUP = st.sampled_from(["v", "b", "l", "f", "c", "s", "p", "pp", "from", "at", "up", "angle", "hither",
                         "resolution", "0", "1", "-1", "3", "0.5", "1e3", "1e999", "nan", "-inf", "abc", "#",
                         "#x", "99999999999", "-3", "2", "4", "\n", "\r\n", "\x00", "é", "1_0", ""])
_SEPARATOR = st.sampled_from([" ", "\n", "\t", "  ", "\r"])


def _parse_or_scene_error(data):
    try:
        scene = parse_nff(data, "fuzz.nff")
    except SceneError as exc:
        assert str(exc).startswith("fuzz.nff")
        return None
    assert isinstance(scene, Scene)
    return scene


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(_SOUP, _SEPARATOR), max_size=60))
def test_fuzz_token_soup(parts):
    _parse_or_scene_error("".join(tok + sep for tok, sep in parts))


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(_SOUP, _SEPARATOR), max_size=30), st.integers(0, 40))
def test_fuzz_valid_file_with_soup_inserted(parts, where):
    tokens = (VIEW + "l 1 2 3\nf 1 0 0 1 0 0 0 1\ns 0 0 0 1\np 3 0 0 0 1 0 0 0 1 0\n"
              "pp 3 0 0 0 0 0 1 1 0 0 0 0 1 0 1 0 0 0 1\nc 0 0 0 1 0 0 1 1\n").split(" ")
    where = min(where, len(tokens))
    soup = "".join(tok + sep for tok, sep in parts)
    _parse_or_scene_error(" ".join(tokens[:where]) + " " + soup + " " + " ".join(tokens[where:]))


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=400))
def test_fuzz_random_bytes(data):
    _parse_or_scene_error(data)


@settings(max_examples=200, deadline=None)
@given(st.text(max_size=200))
def test_fuzz_random_text(text):
    _parse_or_scene_error(text)


# ---------------------------------------------------------------------------------------------
# Writing


def _rotation(axis, degrees):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    a = np.radians(degrees)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(a) * k + (1 - np.cos(a)) * k @ k


def _instance_scene(linear):
    scene = Scene(camera=Camera(eye=(0, -10, 2), look_at=(0, 0, 0)))
    red = scene.add_material(Material((1, 0, 0), kd=0.7, ks=0.3, shine=20))
    blue = scene.add_material(Material((0, 0, 1)))
    part = Group(name="part")
    part.spheres.add((1, 2, 3), 0.5, red)
    part.patches.add([(0, 0, 0), (2, 0, 0), (0, 1, 0)], blue, normals=[(0, 0, 1), (0, 1, 1), (1, 0, 1)])
    m = np.eye(4)
    m[:3, :3] = linear
    m[:3, 3] = (5, -1, 2)
    scene.root.add(Instance(part, m))
    scene.root.spheres.add((0, 0, -100), 99, blue)
    return scene, m


def test_round_trip_of_rotated_uniformly_scaled_instance():
    linear = 2.5 * _rotation((1, 2, 0.5), 37)
    scene, m = _instance_scene(linear)
    back = parse_nff(scene_to_nff(scene))
    a, t = m[:3, :3], m[:3, 3]
    spheres = back.root.spheres
    assert len(spheres) == 2
    np.testing.assert_allclose(spheres.center[1], a @ [1, 2, 3] + t, rtol=1e-5, atol=1e-9)
    np.testing.assert_allclose(spheres.radius, [99, 0.5 * 2.5], rtol=1e-5)
    assert back.materials[spheres.material[1]] == Material((1, 0, 0), kd=0.7, ks=0.3, shine=20)
    patches = back.root.patches
    assert len(patches) == 1
    verts, normals = patches.polygon(0)
    np.testing.assert_allclose(verts, np.array([(0, 0, 0), (2, 0, 0), (0, 1, 0)]) @ a.T + t, rtol=1e-5, atol=1e-9)
    expected = np.array([(0, 0, 1), (0, 1, 1), (1, 0, 1)]) @ np.linalg.inv(a)
    expected /= np.linalg.norm(expected, axis=1)[:, None]
    np.testing.assert_allclose(normals, expected, rtol=1e-5, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1, rtol=1e-5)
    assert back.materials[patches.material[0]] == Material((0, 0, 1))
    # And writing the flat scene again changes nothing.
    assert_same_scene(back, parse_nff(scene_to_nff(back)))


def test_instance_with_non_uniform_scale_cannot_hold_a_sphere():
    scene, _ = _instance_scene(np.diag([1.0, 2.0, 1.0]))
    with pytest.raises(SceneError, match="non-uniformly scaled or sheared sphere"):
        scene_to_nff(scene)


def test_non_uniform_scale_is_fine_for_polygons():
    scene = Scene()
    scene.add_material(Material())
    part = Group()
    part.polygons.add([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)])
    scene.root.add(Instance(part, np.diag([3.0, 0.5, 1.0, 1.0])))
    back = parse_nff(scene_to_nff(scene))
    np.testing.assert_allclose(back.root.polygons.vertices, [(0, 0, 0), (3, 0, 0), (3, 0.5, 0), (0, 0.5, 0)])


def test_mirroring_instance_keeps_the_front_side():
    scene = Scene()
    scene.add_material(Material())
    part = Group()
    square = np.array([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0.5, 1.5, 0)])
    part.polygons.add(square)
    mirror = np.diag([-1.0, 1.0, 1.0, 1.0])
    scene.root.add(Instance(part, mirror))
    verts, _ = parse_nff(scene_to_nff(scene)).root.polygons.polygon(0)
    normal = np.cross(verts[1] - verts[0], verts[2] - verts[0])
    assert normal[2] > 0  # the original faces +z; a mirror in x leaves that facing
    assert sorted(map(tuple, verts)) == sorted(map(tuple, square * [-1, 1, 1]))


def test_nested_groups_and_repeated_instances_are_flattened():
    scene = Scene()
    m = scene.add_material(Material())
    leaf = Group(name="leaf")
    leaf.spheres.add((0, 0, 0), 1, m)
    mid = Group(name="mid")
    for x in (0, 10, 20):
        tm = np.eye(4)
        tm[0, 3] = x
        mid.add(Instance(leaf, tm))
    top = np.eye(4)
    top[:3, :3] *= 2
    scene.root.add(Instance(mid, top))
    back = parse_nff(scene_to_nff(scene))
    np.testing.assert_allclose(back.root.spheres.center, [(0, 0, 0), (20, 0, 0), (40, 0, 0)])
    np.testing.assert_allclose(back.root.spheres.radius, [2, 2, 2])


def test_group_cycle_is_an_error():
    scene = Scene()
    g = Group(name="loop")
    g.add(Instance(g))
    scene.root.add(g)
    with pytest.raises(SceneError, match="cycle"):
        scene_to_nff(scene)


def test_triangle_meshes_become_polygons_or_patches():
    scene = Scene()
    m = scene.add_material(Material((0, 1, 0)))
    verts = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (2, 0, 0)]
    faces = [(0, 1, 2), (0, 2, 3), (0, 1, 4)]  # the last has no area and is left out
    scene.root.add(TriangleMesh(verts, faces, m))
    scene.root.add(TriangleMesh(verts, faces[:2], m, normals=[(0, 0, 1)] * 4 + [(0, 0, 0)]))
    text = scene_to_nff(scene)
    assert text.count("\np 3\n") == 2 and text.count("\npp 3\n") == 2
    back = parse_nff(text)
    np.testing.assert_allclose(back.root.polygons.polygon(1)[0], [(0, 0, 0), (1, 1, 0), (0, 1, 0)])
    np.testing.assert_allclose(back.root.patches.normals, [(0, 0, 1)] * 6)


def test_material_lines_only_when_the_material_changes():
    scene = Scene()
    a = scene.add_material(Material((1, 0, 0)))
    b = scene.add_material(Material((0, 1, 0)))
    for i, mat in enumerate([a, a, b, b, a]):
        scene.root.spheres.add((i, 0, 0), 0.5, mat)
    text = scene_to_nff(scene)
    assert [line for line in text.splitlines() if line.startswith("f ")] == [
        "f 1 0 0 1 0 0 0 1", "f 0 1 0 1 0 0 0 1", "f 1 0 0 1 0 0 0 1"]
    assert parse_nff(text).root.spheres.material.tolist() == [0, 0, 1, 1, 0]


def test_writer_rejects_what_nff_cannot_say():
    scene = Scene()
    scene.root.spheres.add((0, 0, 0), 1.0, 3)
    with pytest.raises(SceneError, match="uses material 3"):
        scene_to_nff(scene)
    scene = Scene()
    scene.add_material(Material())
    scene.root.polygons.add([(0, 0, 0), (1, 1, 1), (2, 2, 2)])
    with pytest.raises(SceneError, match="polygon 0"):
        scene_to_nff(scene)


def test_write_replaces_atomically_and_leaves_no_temporary(tmp_path):
    target = tmp_path / "out.nff"
    target.write_text("old contents\n")
    scene, _ = _instance_scene(np.diag([1.0, 2.0, 1.0]))
    with pytest.raises(SceneError):
        write_nff(scene, target)
    assert target.read_text() == "old contents\n"
    scene, _ = _instance_scene(np.eye(3))
    write_nff(scene, target)
    assert os.listdir(tmp_path) == ["out.nff"]
    assert target.read_text() == scene_to_nff(scene)


def test_write_failure_keeps_the_old_file(tmp_path, monkeypatch):
    target = tmp_path / "out.nff"
    target.write_text("old contents\n")
    scene, _ = _instance_scene(np.eye(3))

    def refuse(src, dst):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(os, "replace", refuse)
    with pytest.raises(SceneError, match="Permission denied"):
        write_nff(scene, target)
    assert target.read_text() == "old contents\n"
    assert os.listdir(tmp_path) == ["out.nff"]


def test_write_into_missing_directory(tmp_path):
    scene, _ = _instance_scene(np.eye(3))
    with pytest.raises(SceneError) as info:
        write_nff(scene, tmp_path / "no" / "such" / "dir.nff")
    assert str(info.value).startswith(str(tmp_path / "no" / "such" / "dir.nff"))


# ---------------------------------------------------------------- the fast reading of plain files

def _same_scene(a: Scene, b: Scene) -> None:
    """Every array, material, light and the view of two read scenes are identical."""
    assert a.materials == b.materials and a.source == b.source
    np.testing.assert_array_equal(a.background, b.background)
    assert [(list(x.position), x.color if x.color is None else list(x.color)) for x in a.lights] == \
        [(list(x.position), x.color if x.color is None else list(x.color)) for x in b.lights]
    for name in ("eye", "look_at", "up"):
        np.testing.assert_array_equal(getattr(a.camera, name), getattr(b.camera, name))
    assert (a.camera.angle, a.camera.hither, a.camera.width, a.camera.height) == \
        (b.camera.angle, b.camera.hither, b.camera.width, b.camera.height)
    ra, rb = a.root, b.root
    fields = {"spheres": ("center", "radius", "material"),
              "cones": ("base", "base_radius", "apex", "apex_radius", "material"),
              "polygons": ("vertices", "start", "count", "material"),
              "patches": ("vertices", "normals", "start", "count", "material")}
    for group, names in fields.items():
        x, y = getattr(ra, group).freeze(), getattr(rb, group).freeze()
        for name in names:
            u, v = getattr(x, name), getattr(y, name)
            assert u.dtype == v.dtype and u.shape == v.shape, (group, name)
            np.testing.assert_array_equal(u, v, err_msg=f"{group}.{name}")


def _slow(text: str, path: str = "<string>") -> Scene:
    from raykernel.scene.nff import _Reader
    return _Reader(text, path).parse()


def _reads_as_the_careful_reader(text: str, path: str) -> None:
    """parse_nff gives the token-by-token reader's scene, or its error word for word."""
    try:
        expected = _slow(text, path)
    except SceneError as err:
        with pytest.raises(SceneError) as got:
            parse_nff(text, path)
        assert str(got.value) == str(err)
    else:
        _same_scene(parse_nff(text, path), expected)


@pytest.mark.parametrize("name", ["balls", "gears", "mount", "rings", "teapot", "tetra", "tree", "jacks", "lattice",
                                  "shells", "sombrero", "sample", "nurbtst"])
def test_plain_files_read_fast_to_the_same_scene(name):
    """The SPD programs' output takes the fast reading, and gives what token-by-token reading gives."""
    from raykernel.scene import spd
    from raykernel.scene.nff import _Reader
    text = spd.generate(name, 2 if name in ("balls", "gears", "tetra", "tree", "jacks", "lattice", "teapot") else 1)
    fast = _Reader(text, "x.nff", fast=True).parse()        # no fallback: it must not raise
    _same_scene(fast, _slow(text, "x.nff"))
    _same_scene(parse_nff(text, "x.nff"), fast)


@pytest.mark.parametrize("path", sorted(SPD_DIR.glob("*.nff")), ids=lambda p: p.name)
def test_reference_files_read_fast_to_the_same_scene(path):
    text = path.read_text()
    _same_scene(read_nff(path), _slow(text, str(path)))


def test_what_the_fast_reading_leaves_to_the_careful_one():
    """Comments and non-ASCII text are not plain; a file with a zero-area patch (allowed) or an
    error reads as the token-by-token reader reads it, error messages and lines included."""
    from raykernel.scene.nff import _NotPlain, _Reader
    for text in (VIEW + "# a comment\ns 0 0 0 1\n", VIEW + "s 0 0 0 1 \u00e9\n", VIEW + "s 0 0 0 1_0\n"):
        with pytest.raises(_NotPlain):
            _Reader(text, "x", fast=True)
    zero_area = VIEW + "pp 3\n0 0 0 0 0 1\n1 0 0 0 0 1\n2 0 0 0 0 1\n"
    _same_scene(parse_nff(zero_area), _slow(zero_area))
    assert parse_nff(zero_area).root.patches.count.tolist() == [3]
    bad = {"s 0 0 0 0\n": 9, "c 0 0 0 1 0 0 0 1\n": 9, "c 0 0 0 0 0 0 1 0\n": 9,     # (the body starts on line 9)
           "p 3\n0 0 0\n1 0 0\n2 0 0\n": 9, "pp 3\n0 0 0 0 0 0\n1 0 0 0 0 1\n0 1 0 0 0 1\n": 10,
           "s 0 0 nan 1\n": 9, "s 0 0 1e999 1\n": 9, "p 3\n0 0 0\n1 0 0\n": 9, "s 0 0 0\np 3\n": 10,
           "s 0 0 0 1\n\nv\n": 11}
    for body, line in bad.items():
        text = VIEW + "l 1 1 1\n" + body
        with pytest.raises(SceneError) as fast_error:
            parse_nff(text, "bad.nff")
        with pytest.raises(SceneError) as slow_error:
            _slow(text, "bad.nff")
        assert str(fast_error.value) == str(slow_error.value)
        assert str(fast_error.value).startswith(f"bad.nff:{line}:"), (body, str(fast_error.value))


def test_fills_read_fast_register_materials_as_the_careful_reader_does():
    """Fills before the view, repeated, unused and interleaved with every kind: the fast reading
    (which takes fills in bulk) registers the same materials in the same order of first use."""
    from raykernel.scene.nff import _Reader
    red, blue, unused = "f 1 0 0 1 0 0 0 1\n", "f 0 0 1 0.5 0.5 3 0 1\n", "f 0 1 0 1 0 0 0 1\n"
    text = (blue + "b 0.1 0.2 0.3\n" + VIEW + "s 0 0 0 1\n" + red + "p 3\n0 0 0\n1 0 0\n0 1 0\n" + unused
            + blue + "c 0 0 0 1 0 0 1 0.5\n" + red + "pp 3\n0 0 0 0 0 1\n1 0 0 0 0 1\n0 1 0 0 0 1\n"
            + "l 1 2 3\nl 4 5 6 0.5 0.5 0.5\n" + red + "s 1 1 1 2\n")
    fast = _Reader(text, "x.nff", fast=True).parse()        # no fallback
    slow = _slow(text, "x.nff")
    _same_scene(fast, slow)
    assert len(fast.materials) == 2 and fast.root.spheres.material.tolist() == [0, 1]


@pytest.mark.parametrize("body", ["p 3.0\n0 0 0\n1 0 0\n0 1 0\n", "p 3\n0 0 0\n1 0 0\n0 1 0\n7\n",
                                  "f 1 0 0 1 0 0 0\ns 0 0 0 1\n", "s 0 0 0 1\nfrom 0 0 0\n", "s 0 0 0 1\nx 1\n",
                                  "s 0 0 0 1\np\n", "s 0 0 0 inf\n", "l 1 2 3 4\n"])
def test_what_the_fast_reading_cannot_take_reads_as_the_careful_reader_reads_it(body):
    """A non-integer vertex count, numbers left over, a short fill, a view keyword outside the view,
    an unknown keyword, a keyword cut short, a non-finite number, a light with 4 numbers: not
    plain, so parse_nff gives the token-by-token reader's scene or error."""
    from raykernel.scene.nff import _NotPlain, _Reader
    text = VIEW + body
    with pytest.raises((_NotPlain, SceneError)):
        _Reader(text, "x.nff", fast=True).parse()
    _reads_as_the_careful_reader(text, "x.nff")


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_fuzzed_plain_files_read_as_the_careful_reader_reads_them(data):
    """Tokens of a small SPD file swapped, dropped or replaced: parse_nff gives the token-by-token
    reader's scene or its error, whichever reading took it."""
    from raykernel.scene import spd
    tokens = spd.generate("rings", 1).split()
    for _ in range(data.draw(st.integers(1, 3))):
        k = data.draw(st.integers(0, len(tokens) - 1))
        tokens[k] = data.draw(st.sampled_from(["0", "1", "-2.5", "p", "s", "3", "nan", "1e400", "x", ""]))
    text = " ".join(t for t in tokens if t)
    _reads_as_the_careful_reader(text, "f.nff")

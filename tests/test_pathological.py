"""The pathological scenes of Ray Tracing News 2(1): sizes, scales, parameters, output."""

from __future__ import annotations

import inspect
import math

import numpy as np
import pytest
from PIL import Image
from support import child, groups, points

import raykernel
from raykernel.cli import main
from raykernel.engine.flatten import flatten
from raykernel.errors import OptionError
from raykernel.scene import Group
from raykernel.scene import pathological as P
from raykernel.scene.jsonscene import read_json, write_json
from raykernel.scene.nff import read_nff, write_nff

FT = P.FEET_PER_MILE


def extent(group: Group) -> np.ndarray:
    p = points(group)
    return p.max(axis=0) - p.min(axis=0)


def polygon_vertices(group: Group) -> np.ndarray:
    return np.vstack([g.polygons.freeze().vertices for g in groups(group)])


# ---- sizes --------------------------------------------------------------------------------------


@pytest.mark.parametrize("name, part, target", [
    ("stadium", "stadium", 5000), ("stadium", "teapot", 5000), ("satellite", "satellite", 3000),
    ("sun", None, 3000), ("teapot-room", "teapot", 1000), ("diamond", None, 2 * 1000 + 1 + 144),
])
def test_default_primitive_counts(name, part, target):
    scene = P.load(name)
    n = scene.count_primitives() if part is None else child(scene.root, part).count_primitives()
    assert abs(n - target) <= 0.03 * target, (name, part, n)


def test_teapot_room_furniture_count():
    scene = P.teapot_room(room_prims=2500)
    n = child(scene.root, "room").count_primitives() + child(scene.root, "furniture").count_primitives()
    assert abs(n - 2500) <= 0.03 * 2500


@pytest.mark.parametrize("name, params, part, target", [
    ("stadium", {"stadium_prims": 1500}, "stadium", 1500),
    ("stadium", {"stadium_prims": 40000}, "stadium", 40000),
    ("satellite", {"prims": 400}, "satellite", 400),
    ("satellite", {"prims": 20000}, "satellite", 20000),
    ("sun", {"prims": 600}, None, 600),
    ("sun", {"prims": 12000}, None, 12000),
])
def test_requested_primitive_counts(name, params, part, target):
    scene = P.load(name, **params)
    n = scene.count_primitives() if part is None else child(scene.root, part).count_primitives()
    assert abs(n - target) <= 0.05 * target, (name, params, n)


def test_teapot_facets_are_the_nearest_spd_size():
    for prims, n in ((5000, 9), (1000, 4), (100, 2), (20000, 18)):
        assert P._teapot_size_factor(prims) == n
        scene = P.stadium(teapot_prims=prims, stadium_prims=500)
        assert child(scene.root, "teapot").count_primitives() == 64 * n * n - 8 * n


# ---- scales -------------------------------------------------------------------------------------


@pytest.mark.parametrize("ratio", [1.0, 600.0, 1e6])
def test_stadium_to_teapot_ratio(ratio):
    scene = P.stadium(ratio=ratio, stadium_prims=800, teapot_prims=300)
    stadium_length = extent(child(scene.root, "stadium"))[0]
    teapot_size = extent(child(scene.root, "teapot")).max()
    assert stadium_length == pytest.approx(600.0, rel=1e-12)
    assert stadium_length / teapot_size == pytest.approx(ratio, rel=0.01)
    # the teapot stands on the goal line (x = 0) on the field (z = 0)
    teapot = points(child(scene.root, "teapot"))
    assert teapot[:, 2].min() == pytest.approx(0.0, abs=1e-12)
    assert (teapot[:, 0].min() + teapot[:, 0].max()) / 2 == pytest.approx(0.0, abs=1e-9 * teapot_size)


@pytest.mark.parametrize("ratio", [1.0, 1e6])
def test_stadium_camera_frames_the_teapot(ratio):
    scene = P.stadium(ratio=ratio, stadium_prims=800, teapot_prims=300)
    teapot = points(child(scene.root, "teapot"))
    center = (teapot.min(axis=0) + teapot.max(axis=0)) / 2
    cam = scene.camera
    np.testing.assert_allclose(cam.look_at, center)
    forward, right, up = cam.basis()
    rel = teapot - cam.eye
    depth = rel @ forward
    assert np.all(depth > cam.hither)
    half = math.tan(math.radians(cam.angle) / 2)
    x, y = np.abs(rel @ right) / depth, np.abs(rel @ up) / depth
    assert max(x.max(), y.max()) <= half          # all of the teapot is in view
    assert max(x.max(), y.max()) >= 0.5 * half    # and fills much of it


@pytest.mark.parametrize("name, params", [(n, {}) for n in P.NAMES] + [("stadium", {"ratio": 1e6}),
                                                                      ("sun", {"distance_miles": 1e12})])
def test_bounds_are_finite(name, params):
    scene = P.load(name, **params)
    geo, _ = flatten(scene, "bvh")
    assert np.all(np.isfinite(geo.agg_bounds))
    assert np.all(np.isfinite(geo.node_bounds))
    assert np.all(np.isfinite(points(scene.root)))


def test_sun_distance_and_radius():
    scene = P.sun()
    s = child(scene.root, "sun").spheres.freeze()
    assert len(s) == 1
    assert np.linalg.norm(s.center[0]) == pytest.approx(93e6 * 5280, rel=1e-9)
    assert s.radius[0] == pytest.approx(432450 * 5280, rel=1e-12)
    far = child(P.sun(distance_miles=2e9, prims=100).root, "sun").spheres.freeze()
    assert np.linalg.norm(far.center[0]) == pytest.approx(2e9 * 5280, rel=1e-9)


def test_sun_survives_flattening_and_is_inside_the_bounds():
    scene = P.sun()
    geo, _ = flatten(scene, "bvh")
    sun = child(scene.root, "sun").spheres.freeze()
    c, r = sun.center[0], sun.radius[0]
    assert np.all(np.isfinite(geo.agg_bounds))
    root = geo.agg_bounds[geo.root]
    tol = 1e-9 * np.linalg.norm(c)
    assert np.all(root[:3] <= c - r + tol) and np.all(root[3:] >= c + r - tol)
    # and so is everything near the origin
    near = np.vstack([polygon_vertices(child(scene.root, n)) for n in ("ground", "houses")])
    assert np.all(root[:3] <= near.min(axis=0)) and np.all(root[3:] >= near.max(axis=0))


def test_sun_light_is_not_blocked_by_the_sun():
    scene = P.sun(prims=100)
    sun = child(scene.root, "sun").spheres.freeze()
    c, r = sun.center[0], sun.radius[0]
    light = scene.lights[0].position
    # the light lies between the sun and the scene, outside the sphere, on the line to the origin
    assert np.linalg.norm(light - c) > r
    assert np.linalg.norm(np.cross(light, c)) <= 1e-9 * np.linalg.norm(light) * np.linalg.norm(c)
    assert np.linalg.norm(light) < np.linalg.norm(c)


def _orbit(scene):
    """Earth centre, earth radius and the centroid of the satellite's polygon vertices
    (a point fixed in the satellite, since it moves rigidly)."""
    earth = child(scene.root, "earth").spheres.freeze()
    centroid = polygon_vertices(child(scene.root, "satellite")).mean(axis=0)
    return earth.center[0], earth.radius[0], centroid


def test_satellite_moves_with_time_at_the_same_altitude():
    center, radius, c0 = _orbit(P.satellite(time=0.0))
    assert radius == pytest.approx(P.EARTH_RADIUS_MILES * FT)
    assert np.linalg.norm(c0) < 5.0                                   # the origin is at the satellite
    altitude0 = np.linalg.norm(c0 - center) - radius
    assert altitude0 == pytest.approx(200 * FT, abs=5.0)
    positions = [c0]
    for t in (600.0, 2700.0):
        center_t, _, c = _orbit(P.satellite(time=t))
        np.testing.assert_array_equal(center_t, center)             # the earth stays put
        assert np.linalg.norm(c - center) - radius == pytest.approx(altitude0, rel=1e-9)
        assert min(np.linalg.norm(c - p) for p in positions) > FT   # moved by more than a mile
        positions.append(c)


def test_satellite_orbit_has_the_real_period():
    center, _, c0 = _orbit(P.satellite(time=0.0))
    _, _, c1 = _orbit(P.satellite(time=600.0))
    a, b = c0 - center, c1 - center
    angle = math.acos(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)))
    period = 2 * math.pi * 600.0 / angle
    assert 5400.0 < period < 5600.0                    # about 91.5 minutes at 200 miles
    # after one full period it is back where it started
    _, _, c2 = _orbit(P.satellite(time=period))
    assert np.linalg.norm(c2 - c0) < 1e-3


def test_satellite_size_and_camera():
    scene = P.satellite()
    size = extent(child(scene.root, "satellite")).max()
    assert 4.0 < size < 6.0
    _, _, c = _orbit(scene)
    assert 2.0 < np.linalg.norm(scene.camera.eye - c) < 10.0
    big = P.satellite(scale=100.0, prims=200)
    assert extent(child(big.root, "satellite")).max() == pytest.approx(100 * size, rel=0.05)


@pytest.mark.parametrize("facets", [3, 1000, 5000])
def test_diamond_facets_share_the_apex(facets):
    scene = P.diamond(facets=facets)
    pavilion = child(child(scene.root, "diamond"), "pavilion").polygons.freeze()
    assert len(pavilion) == facets
    assert np.all(pavilion.count == 3)
    first = pavilion.vertices[pavilion.start]
    apex = first[0]
    assert np.array_equal(first, np.broadcast_to(apex, first.shape))
    # every other vertex differs from the apex: the fan really meets at one point only
    others = np.delete(pavilion.vertices, pavilion.start, axis=0)
    assert np.all(np.linalg.norm(others - apex, axis=1) > 0.5)


# ---- parameters ---------------------------------------------------------------------------------


def test_params_match_the_functions():
    functions = {"stadium": P.stadium, "satellite": P.satellite, "sun": P.sun, "teapot-room": P.teapot_room,
                 "diamond": P.diamond, "park": P.park}
    assert set(P.NAMES) == set(functions) == set(P.PARAMS)
    for name, fn in functions.items():
        sig = inspect.signature(fn)
        assert list(sig.parameters) == list(P.PARAMS[name])
        for key, (default, help_text) in P.PARAMS[name].items():
            assert sig.parameters[key].default == default
            assert help_text and "from" in help_text
            assert key in fn.__doc__


@pytest.mark.parametrize("name, params, words", [
    ("stadium", {"colour": "red"}, ["colour", "ratio"]),
    ("stadium", {"ratio": "abc"}, ["ratio", "1 to 1e6", "not a number"]),
    ("stadium", {"ratio": "0.5"}, ["ratio", "1 to 1e6", "out of range"]),
    ("stadium", {"ratio": "2e6"}, ["ratio", "out of range"]),
    ("stadium", {"ratio": "nan"}, ["ratio"]),
    ("stadium", {"ratio": True}, ["ratio"]),
    ("stadium", {"stadium_prims": "5000.5"}, ["stadium_prims", "whole number"]),
    ("stadium", {"teapot_prims": "10"}, ["teapot_prims", "100 to 1e6"]),
    ("satellite", {"altitude_miles": "-3"}, ["altitude_miles", "out of range"]),
    ("satellite", {"scale": ""}, ["scale", "not a number"]),
    ("sun", {"distance_miles": "inf"}, ["distance_miles"]),
    ("teapot-room", {"teapot_size": "5"}, ["teapot_size", "1e-6 to 4"]),
    ("diamond", {"facets": "2"}, ["facets", "3 to 1e6"]),
    ("diamond", {"facets": None}, ["facets", "not a number"]),
])
def test_bad_parameters(name, params, words):
    with pytest.raises(OptionError) as err:
        P.load(name, **params)
    for word in words:
        assert word in str(err.value)


def test_bad_parameters_in_direct_calls_and_names():
    with pytest.raises(OptionError, match="ratio"):
        P.stadium(ratio=0)
    with pytest.raises(OptionError, match="unknown scene 'stadion'"):
        P.load("stadion")
    with pytest.raises(OptionError, match="KEY=VALUE"):
        P.load("stadium:ratio")


def test_string_parameters_and_inline_parameters():
    a = P.load("diamond", facets="12")
    b = raykernel.load("scene:diamond:facets=12")
    c = P.diamond(facets=12)
    assert a.count_primitives() == b.count_primitives() == c.count_primitives() == 2 * 12 + 1 + 144
    assert b.source == "scene:diamond:facets=12"
    s = P.load("stadium", ratio="1e3", stadium_prims="600", teapot_prims="1e2")
    assert extent(child(s.root, "teapot")).max() == pytest.approx(0.6)


def test_groups_are_natural():
    names = {n: [c.name for c in P.load(n).root.children if isinstance(c, Group)] for n in P.NAMES}
    assert names["stadium"] == ["stadium", "teapot"]
    assert names["satellite"] == ["earth", "satellite"]
    assert "sun" in names["sun"] and "houses" in names["sun"]
    assert "teapot" in names["teapot-room"]
    assert names["diamond"] == ["diamond", "display"]
    assert names["park"] == [f"ride{k}" for k in range(6)] + ["mountain", "fence"]
    stadium = child(P.stadium(stadium_prims=600, teapot_prims=100).root, "stadium")
    assert {c.name for c in stadium.children} >= {"field", "stands", "goalposts", "towers"}


def test_every_scene_has_camera_lights_and_materials():
    for name in P.NAMES:
        scene = P.load(name)
        assert scene.lights, name
        assert scene.materials, name
        for g in groups(scene.root):
            for s in g.primitive_sets():
                assert s.material.max() < len(scene.materials)
        # the camera looks at something: its look_at is in front of the eye
        assert np.linalg.norm(scene.camera.look_at - scene.camera.eye) > 0


# ---- output -------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", P.NAMES)
def test_json_and_nff_round_trip(name, tmp_path):
    scene = P.load(name)
    n = scene.count_primitives()
    write_json(scene, tmp_path / "s.json")
    back = read_json(tmp_path / "s.json")
    assert back.count_primitives() == n
    # the groups are kept: the same children with the same primitives each
    assert [c.count_primitives() for c in back.root.children] == \
        [c.count_primitives() for c in scene.root.children]
    write_nff(scene, tmp_path / "s.nff")
    assert read_nff(tmp_path / "s.nff").count_primitives() == n


def test_cli_scene_writes_json_and_nff(tmp_path, capsys):
    out = tmp_path / "stadium.json"
    assert main(["scene", "stadium", "--param", "ratio=1000", "--param", "stadium_prims=700",
                 "-p", "teapot_prims=200", "-o", str(out)]) == 0
    scene = read_json(out)
    assert len([c for c in scene.root.children if isinstance(c, Group)]) == 2
    assert scene.count_primitives() == P.stadium(ratio=1000, stadium_prims=700, teapot_prims=200).count_primitives()
    nff = tmp_path / "gem.nff"
    assert main(["scene", "diamond", "--param", "facets=40", "-o", str(nff)]) == 0
    assert read_nff(nff).count_primitives() == 2 * 40 + 1 + 144
    assert sorted(p.name for p in tmp_path.iterdir()) == ["gem.nff", "stadium.json"]   # no temporary files


def test_cli_scene_list(capsys):
    for argv in (["scene", "--list"], ["scene", "list"]):
        assert main(argv) == 0
        text = capsys.readouterr().out
        for name in P.NAMES:
            assert name in text
        assert "ratio = 600" in text and "facets = 1000" in text and "distance_miles = 9.3e7" in text


@pytest.mark.parametrize("argv, words", [
    (["scene", "stadium", "-o", "x.txt"], [".txt", ".json", ".nff"]),
    (["scene", "stadium", "-o", "x"], ["no suffix"]),
    (["scene", "stadium", "--param", "ratio=zero", "-o", "x.json"], ["ratio", "not a number"]),
    (["scene", "stadium", "--param", "ratio", "-o", "x.json"], ["KEY=VALUE"]),
    (["scene", "stadium", "--param", "ratio=2", "--param", "ratio=3", "-o", "x.json"], ["twice"]),
    (["scene", "stadium", "--param", "speed=3", "-o", "x.json"], ["speed"]),
    (["scene", "stadium"], ["-o"]),
    (["scene"], ["--list"]),
    (["scene", "moon", "-o", "x.json"], ["moon"]),
])
def test_cli_scene_errors(argv, words, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = " ".join(capsys.readouterr().err.split())     # the console wraps long lines
    for word in words:
        assert word in err
    assert list(tmp_path.iterdir()) == []


def test_cli_scene_unwritable_directory(tmp_path, capsys):
    assert main(["scene", "diamond", "-o", str(tmp_path / "missing" / "gem.json")]) == 2
    assert "does not exist" in " ".join(capsys.readouterr().err.split())


def test_cli_renders_the_stadium(tmp_path):
    out = tmp_path / "stadium.png"
    assert main(["render", "scene:stadium", "--resolution", "32", "-o", str(out)]) == 0
    image = np.asarray(Image.open(out))
    assert image.shape == (32, 32, 3)
    assert image.std() > 0          # not a blank picture


def test_stadium_teapot_bvh_nests_a_bvh_and_keeps_the_hits():
    import numpy as np

    from raykernel.engine.flatten import flatten
    from raykernel.engine.traverse import cast_rays
    plain = P.load("stadium", ratio=1000, stadium_prims=600, teapot_prims=200)
    nested = P.load("stadium", ratio=1000, stadium_prims=600, teapot_prims=200, teapot_bvh=1)
    assert [g.accel for g in nested.root.children if g.name == "teapot"] == ["bvh"]
    rng = np.random.default_rng(3)
    eye = nested.camera.eye
    d = nested.camera.look_at - eye + rng.normal(scale=0.3 * np.linalg.norm(nested.camera.look_at - eye) / 10,
                                                  size=(400, 3))
    o = np.tile(eye, (400, 1))
    a = cast_rays(flatten(plain, "grid")[0], o, d)
    b = cast_rays(flatten(nested, "grid")[0], o, d)
    assert np.isfinite(a[0]).sum() > 100
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[2], b[2])
    with pytest.raises(raykernel.OptionError, match="teapot_bvh"):
        P.load("stadium", teapot_bvh=2)

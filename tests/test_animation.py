"""Animations: keyframe interpolation, JSON motion and camera paths, incremental structures
(each frame against a from-scratch build), and animate()'s output and resumption."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from PIL import Image

from raykernel.aggregates.bvh import sah_cost
from raykernel.engine.incremental import Hierarchy
from raykernel.errors import OptionError, SceneError
from raykernel.rendering.animate import RECORD_FILE, animate
from raykernel.rendering.render import render
from raykernel.scene import pathological
from raykernel.scene.animation import (
    Keyframe,
    Motion,
    axis_angle_quaternion,
    parameter_animation,
    quaternion_matrix,
    slerp,
)
from raykernel.scene.jsonscene import parse_json, scene_from_json, scene_to_json
from raykernel.scene.model import Group, Instance

RAY_KEYS = ("rays.eye", "rays.reflect", "rays.refract", "rays.shadow", "rays.eye_hit", "rays.shadow_blocked",
            "rays.total", "rays.cut_off", "rays.tir")


def rotation_z(degrees: float) -> np.ndarray:
    c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def ball_scene(parent_accel=None, motion=None, camera_path=None, extra_top=None):
    """A floor and a ball instance that moves; the parent group's accel as given."""
    doc = {
        "camera": {"eye": [0, -10, 3], "look_at": [0, 0, 0], "resolution": 24},
        "lights": [{"position": [5, -5, 10]}],
        "groups": {"ball": {"accel": "bvh", "items": [{"sphere": {"center": [0, 0, 0], "radius": 1}},
                                                        {"sphere": {"center": [0, 0, 1.2], "radius": 0.4}}]}},
        "scene": {"items": [
            {"polygon": [[-5, -5, -1], [5, -5, -1], [5, 5, -1], [-5, 5, -1]]},
            {"sphere": {"center": [3, 3, 0], "radius": 0.7}},
            {"instance": "ball", "transform": {"scale": 0.8},
             "motion": motion if motion is not None else [{"time": 0, "translate": [-2, 0, 0]},
                                  {"time": 1, "translate": [0, 0, 2], "rotate": {"axis": [0, 0, 1], "degrees": 90}},
                                  {"time": 2, "translate": [2, 0, 0], "scale": 1.5}]}]},
    }
    if parent_accel:
        doc["scene"]["accel"] = parent_accel
    if camera_path:
        doc["camera"]["path"] = camera_path
    doc.update(extra_top or {})
    return parse_json(json.dumps(doc))


# ---- interpolation -----------------------------------------------------------------------------

def test_slerp_turns_at_a_constant_rate_about_one_axis():
    q0, q1 = axis_angle_quaternion([0, 0, 1], 0.0), axis_angle_quaternion([0, 0, 2], 120.0)
    for u in (0.0, 0.25, 0.5, 0.9, 1.0):
        assert np.allclose(quaternion_matrix(slerp(q0, q1, u)), rotation_z(120.0 * u), atol=1e-12)


def test_slerp_takes_the_short_way_and_handles_equal_keys():
    q0 = axis_angle_quaternion([0, 0, 1], 10.0)
    q1 = -axis_angle_quaternion([0, 0, 1], 30.0)        # the same rotation as +q: slerp must not go round
    assert np.allclose(quaternion_matrix(slerp(q0, q1, 0.5)), rotation_z(20.0), atol=1e-12)
    assert np.allclose(slerp(q0, q0, 0.3), q0)


def test_motion_interpolates_and_holds_still_outside_its_keys():
    m = Motion([Keyframe(0.0, translate=np.array([0.0, 0, 0])),
                Keyframe(2.0, translate=np.array([4.0, 0, 0]), rotate=axis_angle_quaternion([0, 0, 1], 90),
                         scale=np.array([3.0, 3.0, 3.0]))])
    mid = m.matrix(1.0)
    assert np.allclose(mid[:3, 3], [2, 0, 0])
    assert np.allclose(mid[:3, :3], rotation_z(45.0) * 2.0)      # scale 1 -> 3 halfway: 2
    assert np.allclose(m.matrix(-5.0), np.eye(4))
    assert np.allclose(m.matrix(9.0), m.matrix(2.0))
    with pytest.raises(SceneError, match="increase"):
        Motion([Keyframe(1.0), Keyframe(1.0)])


# ---- JSON ---------------------------------------------------------------------------------------

def test_json_motion_places_the_instance_at_each_time():
    scene = ball_scene()
    anim = scene.animation
    assert anim.time == (0.0, 2.0) and anim.fps == 24.0
    inst = [c for c in scene.root.children if isinstance(c, Instance)][0]
    anim.at(scene, 1.0)
    expected = np.eye(4)
    expected[:3, :3] = rotation_z(90.0) * 0.8        # static scale first, then the key's rotation
    expected[:3, 3] = [0, 0, 2]
    assert np.allclose(inst.matrix, expected, atol=1e-12)
    anim.at(scene, 0.5)
    assert np.allclose(inst.matrix[:3, 3], [-1, 0, 1])


def test_json_camera_path_interpolates_the_fields_it_gives():
    scene = ball_scene(camera_path=[{"time": 0, "eye": [0, -10, 3]}, {"time": 4, "eye": [10, -10, 3], "angle": 30}])
    anim = scene.animation
    assert anim.time == (0.0, 4.0)
    anim.at(scene, 2.0)
    assert np.allclose(scene.camera.eye, [5, -10, 3])
    assert scene.camera.angle == 30.0          # one key gives the angle: it holds
    assert np.allclose(scene.camera.look_at, [0, 0, 0])


def test_json_animation_round_trips():
    scene = ball_scene(camera_path=[{"time": 0, "eye": [0, -10, 3]}, {"time": 2, "eye": [4, -9, 3]}],
                       extra_top={"animation": {"time": [0, 2], "fps": 12}})
    copy = scene_from_json(scene_to_json(scene))
    assert copy.animation.fps == 12.0 and copy.animation.time == (0.0, 2.0)
    for t in (0.0, 0.3, 1.0, 1.7, 2.0):
        scene.animation.at(scene, t)
        copy.animation.at(copy, t)
        a = [c for c in scene.root.children if isinstance(c, Instance)][0]
        b = [c for c in copy.root.children if isinstance(c, Instance)][0]
        assert np.allclose(a.matrix, b.matrix, atol=1e-12)
        assert np.allclose(scene.camera.eye, copy.camera.eye)


@pytest.mark.parametrize("motion, where, what", [
    ([], "/scene/items/2/motion", "keyframes"),
    ([{"translate": [1, 0, 0]}], "/scene/items/2/motion/0", "time"),
    ([{"time": 1}, {"time": 0}], "/scene/items/2/motion/1/time", "increase"),
    ([{"time": 0, "spin": 3}], "/scene/items/2/motion/0", "spin"),
    ([{"time": 0, "quaternion": [0, 0, 0, 0]}], "/scene/items/2/motion/0/quaternion", "zero"),
    ([{"time": 0, "quaternion": [1, 0, 0]}], "/scene/items/2/motion/0/quaternion", "w, x, y, z"),
    ([{"time": 0, "rotate": {"axis": [0, 0, 1], "degrees": 5}, "quaternion": [1, 0, 0, 0]}],
     "/scene/items/2/motion/0", "not both"),
    ([{"time": 0, "scale": 0}], "/scene/items/2/motion/0/scale", "zero"),
])
def test_bad_motion_names_where_and_what(motion, where, what):
    with pytest.raises(SceneError) as e:
        ball_scene(motion=motion)
    assert where in str(e.value) and what in str(e.value)


def test_bad_animation_and_camera_path():
    with pytest.raises(SceneError, match="/animation/time"):
        ball_scene(extra_top={"animation": {"time": [2, 1]}})
    with pytest.raises(SceneError, match="/animation/fps"):
        ball_scene(extra_top={"animation": {"fps": 0}})
    with pytest.raises(SceneError, match="/camera/path/1/angle"):
        ball_scene(camera_path=[{"time": 0}, {"time": 1, "angle": 190}])


def test_parameter_animation_needs_a_time_parameter():
    anim = parameter_animation("scene:satellite:prims=200")
    assert anim.time == pathological.TIME_SPANS["satellite"]
    a, b = anim.at(None, 0.0), anim.at(None, 300.0)
    assert not np.allclose(a.camera.eye, b.camera.eye)
    with pytest.raises(SceneError, match="no time parameter"):
        parameter_animation("scene:diamond")


# ---- incremental structures ---------------------------------------------------------------------

def same_frame(a, b):
    assert np.array_equal(a.image, b.image)
    for key in RAY_KEYS:
        assert a.stats[key] == b.stats[key], key


def test_satellite_frames_incremental_equal_from_scratch():
    anim = parameter_animation("scene:satellite:prims=300")
    hierarchy = Hierarchy()
    refit = 0
    for t in anim.times(24):
        scene = anim.at(None, t)
        a = render(scene, resolution=20, builder=hierarchy)
        b = render(scene, resolution=20)
        same_frame(a, b)
        refit += a.stats["build.refit_nodes"]
    assert refit > 0, "the moving satellite's BVH is refit, not rebuilt, between frames"


def test_moving_instance_refits_parents_and_reuses_its_group():
    scene = ball_scene()
    hierarchy = Hierarchy()
    for i, t in enumerate(scene.animation.times(5)):
        scene.animation.at(scene, t)
        a = render(scene, builder=hierarchy)
        same_frame(a, render(scene))
        if i:
            assert a.stats["build.reused_aggregates"] == 1      # the ball's own BVH
            assert a.stats["build.refit_aggregates"] == 1       # the root BVH over the instance
            assert a.stats["build.rebuilt_aggregates"] == 0


@pytest.mark.parametrize("accel", ["grid", "octree", "list", "hgrid", "bvh(split=8)"])
def test_parents_that_cannot_refit_are_rebuilt(accel):
    scene = ball_scene(parent_accel=accel)
    hierarchy = Hierarchy()
    for i, t in enumerate(scene.animation.times(4)):
        scene.animation.at(scene, t)
        a = render(scene, builder=hierarchy)
        same_frame(a, render(scene))
        if i and accel != "list":
            assert a.stats["build.rebuilt_aggregates"] == 1 and a.stats["build.reused_aggregates"] == 1


def test_a_still_frame_reuses_everything():
    scene = ball_scene()
    hierarchy = Hierarchy()
    render(scene, builder=hierarchy)
    again = render(scene, builder=hierarchy)
    assert again.stats["build.reused_aggregates"] == 2
    assert again.stats["build.refit_nodes"] == again.stats["build.rebuilt_nodes"] == 0


def test_sah_threshold_rebuilds_a_degraded_tree():
    """Items that swap places make the refit tree's boxes overlap: a low threshold rebuilds it."""
    rng = np.random.default_rng(3)
    from raykernel.scene import Scene
    from raykernel.scene.model import Camera

    def frame(k):
        scene = Scene(camera=Camera(eye=(0, -30, 0), look_at=(0, 0, 0), width=16, height=16))
        pts = base if k == 0 else base[perm]
        for p in pts:
            scene.root.spheres.add(p, 0.3, 0)
        return scene
    base = rng.uniform(-8, 8, (200, 3))
    perm = rng.permutation(200)
    strict, loose = Hierarchy(rebuild_threshold=1.0), Hierarchy(rebuild_threshold=1e9)
    for k in (0, 1):
        s = frame(k)
        a, b, c = render(s, builder=strict), render(s, builder=loose), render(s)
        same_frame(a, c)
        same_frame(b, c)
    assert a.stats["build.rebuilt_aggregates"] == 1 and a.stats["build.refit_nodes"] == 0
    assert b.stats["build.refit_aggregates"] == 1 and b.stats["build.rebuilt_nodes"] == 0
    assert b.stats["bounds.tests"] > c.stats["bounds.tests"]      # the refit tree does more work


def test_changed_structure_builds_from_scratch():
    scene = ball_scene()
    hierarchy = Hierarchy()
    render(scene, builder=hierarchy)
    scene.root.spheres.add((0, 3, 0), 0.5, 0)          # a new primitive: other references
    a = render(scene, builder=hierarchy)
    same_frame(a, render(scene))
    assert a.stats["build.reused_aggregates"] == 0 and a.stats["build.rebuilt_aggregates"] == 2


def test_lazy_structures_are_rebuilt_every_frame():
    scene = ball_scene(parent_accel="lazyoctree")
    hierarchy = Hierarchy()
    for t in (0.0, 0.5):
        scene.animation.at(scene, t)
        a = render(scene, builder=hierarchy)
        same_frame(a, render(scene))
        assert a.stats["build.reused_aggregates"] == 0


def test_sah_cost_of_a_two_leaf_tree():
    # root [0,2]^3 (area 12), two unit-cube leaves of 1 item each (area 3): (12 + 3 + 3) / 12
    b = np.array([[0, 0, 0, 2, 2, 2], [0, 0, 0, 1, 1, 1], [1, 1, 1, 2, 2, 2]], float)
    assert sah_cost(b, np.array([1, 0, 1]), np.array([0, 1, 1]), 0, 3) == pytest.approx(18 / 12)


def test_bad_threshold():
    with pytest.raises(OptionError, match="rebuild_threshold"):
        Hierarchy(rebuild_threshold=0.5)


# ---- animate() ----------------------------------------------------------------------------------

def test_animate_writes_frames_and_sums_their_counters(tmp_path):
    out = tmp_path / "orbit"
    stats = tmp_path / "stats.json"
    result = animate("scene:satellite:prims=300", frames=4, output=out, resolution=16, stats_json=stats)
    names = sorted(p.name for p in out.iterdir())
    assert names == ["frame-0000.png", "frame-0001.png", "frame-0002.png", "frame-0003.png", RECORD_FILE]
    anim = parameter_animation("scene:satellite:prims=300")
    for i, t in enumerate(anim.times(4)):
        alone = render(anim.at(None, t), resolution=16)
        assert np.array_equal(np.asarray(Image.open(out / f"frame-{i:04d}.png")), alone.to_uint8())
        assert result.frames[i]["counters"]["rays.total"] == alone.stats["rays.total"]
    doc = json.loads(stats.read_text())
    assert doc["totals"]["rays.total"] == sum(f["counters"]["rays.total"] for f in doc["frames"])
    assert len(doc["frames"]) == 4


def test_animate_movie_outputs(tmp_path):
    scene = ball_scene()
    apng = tmp_path / "ball.png"
    animate(scene, frames=3, output=apng)
    with Image.open(apng) as im:
        assert im.n_frames == 3
    assert not (tmp_path / "ball.png.frames").exists()
    pytest.importorskip("imageio_ffmpeg")
    mp4 = tmp_path / "ball.mp4"
    animate(ball_scene(), frames=3, output=mp4)
    assert mp4.stat().st_size > 0 and mp4.read_bytes()[4:8] == b"ftyp"


def test_interrupted_animation_resumes(tmp_path):
    out = tmp_path / "frames"

    def stop_after_two(done, total):
        if done == 2:
            raise KeyboardInterrupt
    with pytest.raises(KeyboardInterrupt):
        animate(ball_scene(), frames=5, output=out, progress=stop_after_two, segment=4)
    assert sorted(p.name for p in out.glob("*.png")) == ["frame-0000.png", "frame-0001.png"]
    lines = []
    resumed = animate(ball_scene(), frames=5, output=out, log=lines.append, segment=4)
    assert resumed.skipped == 2 and "2 of 5 frames already" in lines[0]
    whole = animate(ball_scene(), frames=5, output=tmp_path / "whole", segment=4)
    for i in range(5):
        name = f"frame-{i:04d}.png"
        assert (out / name).read_bytes() == (tmp_path / "whole" / name).read_bytes()
    for key in resumed.totals:      # the structures too: the resumed segment was built from its start
        if not key.startswith(("time.", "build.seconds")):
            assert resumed.totals[key] == whole.totals[key], key


def test_animate_refuses_frames_of_another_render(tmp_path):
    out = tmp_path / "frames"
    animate(ball_scene(), frames=2, output=out)
    with pytest.raises(OptionError, match="another render"):
        animate(ball_scene(), frames=3, output=out)


def test_animate_bad_input(tmp_path):
    with pytest.raises(SceneError, match="does not move"):
        animate("spd:balls:1", frames=2, output=tmp_path / "x")
    with pytest.raises(OptionError, match="not '.gif'"):
        animate(ball_scene(), frames=2, output=tmp_path / "x.gif")
    with pytest.raises(OptionError, match="frames"):
        animate(ball_scene(), frames=0, output=tmp_path / "x")
    with pytest.raises(OptionError, match="segment"):
        animate(ball_scene(), frames=2, output=tmp_path / "x", segment=0)
    with pytest.raises(OptionError, match="does not exist"):
        animate(ball_scene(), frames=2, output=tmp_path / "missing" / "x")
    with pytest.raises(OptionError, match="max_depth"):
        animate(ball_scene(), frames=2, output=tmp_path / "x", max_depth=0)
    assert not (tmp_path / "x").exists() or not any((tmp_path / "x").glob("*.png"))


def test_group_model_instances_move_with_the_animation():
    """An Animation built in Python (no JSON) moves its instances the same way."""
    from raykernel.scene.animation import Animation
    scene = ball_scene()
    group = Group(name="extra")
    group.spheres.add((0, 0, 0), 0.3, 0)
    inst = scene.root.add(Instance(group))
    motion = Motion([Keyframe(0.0), Keyframe(1.0, translate=np.array([0.0, 0.0, 3.0]))])
    anim = Animation(time=(0.0, 1.0), motions=[(inst, np.eye(4), motion)])
    anim.at(scene, 0.5)
    assert np.allclose(inst.matrix[:3, 3], [0, 0, 1.5])


# ---- the command line ---------------------------------------------------------------------------

def test_cli_animate_and_resume(tmp_path, capsys):
    from raykernel.cli import main
    path = tmp_path / "ball.json"
    path.write_text(json.dumps(scene_to_json(ball_scene())))
    out = tmp_path / "frames"
    assert main(["animate", str(path), "--frames", "3", "--resolution", "12", "-o", str(out),
                 "--stats-json", str(tmp_path / "s.json")]) == 0
    assert len(list(out.glob("frame-*.png"))) == 3
    assert "3 frames (3 rendered, 0 already written)" in capsys.readouterr().out
    assert main(["animate", str(path), "--frames", "3", "--resolution", "12", "-o", str(out), "--max-depth", "2"]) == 2
    assert "another render" in capsys.readouterr().err
    assert main(["animate", str(path), "--frames", "3", "--resolution", "12", "-o", str(out),
                 "--stats-json", str(tmp_path / "s.json")]) == 0
    assert "already in" in capsys.readouterr().out
    doc = json.loads((tmp_path / "s.json").read_text())
    assert [f["skipped"] for f in doc["frames"]] == [True, True, True]


def test_cli_bad_dask_address(capsys):
    from raykernel.cli import main
    assert main(["render", "spd:balls:1", "--resolution", "4", "--dask", "somewhere"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--dask takes local, local:N or a scheduler address" in err


def test_the_orbit_example_moves():
    from pathlib import Path

    from raykernel.scene.loading import load
    scene = load(Path(__file__).resolve().parents[1] / "examples" / "orbit.json")
    anim = scene.animation
    assert anim.time == (0.0, 4.0) and anim.fps == 12.0
    hierarchy = Hierarchy()
    images = []
    for t in (0.0, 2.0):
        anim.at(scene, t)
        a = render(scene, resolution=24, builder=hierarchy)
        same_frame(a, render(scene, resolution=24))
        images.append(a.image)
    assert not np.array_equal(images[0], images[1])


def test_animations_from_several_threads_at_once(tmp_path):
    """Each call keeps its own structures: two at once give what each gives alone."""
    from concurrent.futures import ThreadPoolExecutor
    alone = animate(ball_scene(), frames=3, output=tmp_path / "alone")
    with ThreadPoolExecutor(2) as pool:
        runs = list(pool.map(lambda k: animate(ball_scene(), frames=3, output=tmp_path / f"t{k}"), range(2)))
    for run in runs:
        for key, value in alone.totals.items():
            if not key.startswith(("time.", "build.seconds")):
                assert run.totals[key] == value, key
    for k in range(2):
        for i in range(3):
            name = f"frame-{i:04d}.png"
            assert (tmp_path / f"t{k}" / name).read_bytes() == (tmp_path / "alone" / name).read_bytes()

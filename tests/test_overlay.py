"""A structure drawn over a render: the render's own projection, surfaces hiding what lies behind them."""

from __future__ import annotations

import numpy as np
import pytest

from raykernel.errors import OptionError
from raykernel.rendering.overlay import draw_boxes, draw_structure, eye_depth, project_points
from raykernel.rendering.structure import select, structure_boxes
from raykernel.rendering.render import camera_vectors
from raykernel.scene import Camera, Group, Material, Scene

W = H = 48


def scene_behind_a_wall(accel: str = "grid") -> Scene:
    """Spheres around the origin in a group of their own (built with `accel`), seen from -y; a wall
    at y = -5 hides the left half (x < 0). The root is a list: the spheres' boxes are level 1."""
    scene = Scene(camera=Camera(eye=np.array([0.0, -12.0, 0.0]), look_at=np.zeros(3), up=np.array([0.0, 0.0, 1.0]),
                                angle=40.0, width=W, height=H))
    scene.materials = [Material()]
    rng = np.random.default_rng(4)
    balls = scene.root.add(Group(name="balls", accel=accel))
    for c in rng.uniform(-2.5, 2.5, (12, 3)):
        balls.spheres.add(c, 0.4, 0)
    scene.root.accel = "list"
    scene.root.polygons.add(np.array([[-30.0, -5.0, -30.0], [0.0, -5.0, -30.0], [0.0, -5.0, 30.0],
                                      [-30.0, -5.0, 30.0]]), 0)
    return scene


def test_points_on_eye_rays_project_to_their_pixels():
    scene = scene_behind_a_wall()
    v = camera_vectors(scene.camera, W, H, corners=False)
    eye, first, right, down = v[:3], v[3:6], v[6:9], v[9:12]
    rng = np.random.default_rng(1)
    rows, cols = rng.integers(0, H, 50), rng.integers(0, W, 50)
    far = rng.uniform(0.5, 40.0, 50)
    points = eye + far[:, None] * (first + cols[:, None] * right + rows[:, None] * down)
    x, y, z = project_points(scene.camera, W, H, points)
    assert np.allclose(x, cols, atol=1e-9) and np.allclose(y, rows, atol=1e-9)
    assert np.allclose(z, far, rtol=1e-12)         # the directions' forward part is 1: z is the multiple


def _drawn(scene, accel, depth=None):
    blank = np.zeros((H, W, 3), np.uint8)
    return np.any(draw_structure(blank, scene, accel, depth) != 0, axis=2)


@pytest.mark.parametrize("accel", ["grid", "octree", "bvh"])
def test_the_wall_hides_the_boxes_behind_it(accel):
    scene = scene_behind_a_wall(accel)
    depth = eye_depth(scene, "list", W, H)
    wall = depth < 7.5              # the wall lies 7 along the line of sight, every box beyond 9
    assert wall[:, : W // 2 - 1].all() and not wall[:, W // 2 + 1:].any()
    boxes = structure_boxes(scene, accel)
    boxes = select(boxes, boxes.level == 1)         # the spheres' structure, not the root's box around the wall
    assert (boxes.corners[:, 0, 0] < -1.0).any() and (boxes.corners[:, 0, 1] > -4.0).all()
    drawn = np.any(draw_boxes(np.zeros((H, W, 3), np.uint8), scene, boxes, depth) != 0, axis=2)
    assert drawn[:, W // 2 + 1:].sum() > 20         # boxes show right of the wall
    assert not (drawn & wall).any()
    # without the surfaces every box shows, behind the wall too
    bare = np.any(draw_boxes(np.zeros((H, W, 3), np.uint8), scene, boxes, np.full((H, W), np.inf)) != 0, axis=2)
    assert (bare & wall).sum() > 20 and not (drawn & ~bare).any()


def test_shallower_boxes_are_a_part_of_all():
    scene = scene_behind_a_wall("octree")
    roots, every = _drawn(scene, "octree", 0), _drawn(scene, "octree")
    assert roots.any() and not (roots & ~every).any() and every.sum() > roots.sum()
    with pytest.raises(OptionError, match="depth"):
        draw_structure(np.zeros((H, W, 3)), scene, "octree", -1)


def test_float_images_keep_their_scale():
    scene = scene_behind_a_wall()
    image = np.full((H, W, 3), 0.25)
    out = draw_structure(image, scene, "grid", 0)
    assert out.dtype == image.dtype and out.max() <= 1.0 and (out != image).any()


def test_command_line(tmp_path, capsys):
    from raykernel.cli import main
    plain, drawn = tmp_path / "a.png", tmp_path / "b.png"
    assert main(["render", "spd:balls:1", "--resolution", "32", "--accel", "octree", "-o", str(plain)]) == 0
    assert main(["render", "spd:balls:1", "--resolution", "32", "--accel", "octree", "--draw", "2",
                 "-o", str(drawn)]) == 0
    from PIL import Image
    a, b = np.asarray(Image.open(plain)), np.asarray(Image.open(drawn))
    changed = np.any(a != b, axis=2)
    assert 0 < changed.sum() < changed.size
    capsys.readouterr()
    for bad in (["--draw", "deep"], ["--draw", "1", "--accel", "auto"]):
        assert main(["render", "spd:balls:1", "--resolution", "8", "-o", str(tmp_path / "c.png"), *bad]) == 2
        assert "--draw" in capsys.readouterr().err
        assert not (tmp_path / "c.png").exists()

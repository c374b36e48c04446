"""Every scale answered or refused: hits exact from 1e-30 to 1e30 against the float64 reference, and
scenes, cameras and rays beyond that range refused with one error naming the offending item or ray,
with no numpy warning on the way."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import raykernel
from raykernel import RayScene
from raykernel.aggregates.registry import KINDS
from raykernel.casting.rayscene import RayInputError
from raykernel.errors import SceneError
from raykernel.geometry.primitives import MAX_COORDINATE, MIN_SIZE
from raykernel.scene import Group, Instance, Scene
from raykernel.scene.model import Camera

# scales from the smallest size to the largest coordinate the range allows (the scene spans about
# 1.5 times its scale; its rays start up to 8 times its scale out)
SCALES = [MIN_SIZE * 1.01] + [10.0 ** k for k in range(-25, 30, 5)] + [MAX_COORDINATE / 10]
MESH = (np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.3]]) + [0.5, 0.25, 0.0],
        np.array([[0, 1, 2], [1, 3, 2]]))


@pytest.fixture(autouse=True)
def no_numpy_warnings():
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        yield


def _rays_at_triangle(v, rng, n=64):
    """Rays from above to points inside triangle 0, each reaching it at t = 1 exactly in reals."""
    a, b = rng.uniform(0.05, 0.45, n), rng.uniform(0.05, 0.45, n)
    target = v[0] + a[:, None] * (v[1] - v[0]) + b[:, None] * (v[2] - v[0])
    o = target + np.array([0.1, 0.2, 2.0]) * np.max(np.abs(v))
    return o, target - o


@pytest.mark.parametrize("accel", [name for name, kind in KINDS.items() if not kind.operands and name != "auto"])
def test_mesh_hits_are_exact_across_the_range(accel):
    rng = np.random.default_rng(5)
    for s in SCALES:
        v = MESH[0] * s
        scene = RayScene.from_mesh(v, MESH[1], accel=accel) if accel != "bvh" else RayScene.from_mesh(v, MESH[1])
        o, d = _rays_at_triangle(v, rng)
        hits = scene.intersect(o, d)
        # the float64 reference: where the ray meets the triangle's plane (z = 0), t = 1 up to rounding
        reference = (0.0 - o[:, 2]) / d[:, 2]
        assert np.all(hits.prim_id == 0), s
        assert np.allclose(hits.t, reference, rtol=1e-12, atol=0), s


def test_spheres_and_polygons_hit_exactly_across_the_range():
    for s in SCALES:
        centres = np.array([[1.0, 2.0, 3.0]]) * s
        spheres = RayScene.from_spheres(centres, np.array([s]))
        hits = spheres.intersect(centres + np.array([0.0, 0.0, 5.0]) * s, np.array([[0.0, 0.0, -s]]))
        assert hits.t[0] == pytest.approx(4.0, rel=1e-12), s
        scene = Scene()
        scene.root.polygons.add(np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]]) * s,
                                0)
        polygon = RayScene(scene)
        hits = polygon.intersect(np.array([[0.3, 0.2, 3.0]]) * s, np.array([[0.0, 0.0, -1.0]]))
        assert hits.t[0] == pytest.approx(3.0 * s, rel=1e-12), s


def test_renders_at_the_ends_of_the_range_agree():
    """The same scene scaled by 1e-25 and by 1e25 renders the same image as at scale 1."""
    images = []
    for s in (1e-25, 1.0, 1e25):
        scene = Scene()
        scene.add_material(raykernel.scene.Material(color=(0.8, 0.3, 0.2)))
        scene.root.spheres.add(np.array([0.0, 0.0, 0.0]) * s, 1.0 * s, 0)
        scene.root.spheres.add(np.array([1.5, 0.5, 0.2]) * s, 0.5 * s, 0)
        scene.camera = Camera(eye=np.array([0.0, -6.0, 1.0]) * s, look_at=np.zeros(3), up=np.array([0.0, 0.0, 1.0]),
                              hither=1e-3 * s)
        scene.lights.append(raykernel.scene.Light(position=np.array([4.0, -5.0, 6.0]) * s))
        images.append(raykernel.render(scene, resolution=24).image)
    assert np.abs(images[0] - images[1]).max() < 1e-6 and np.abs(images[2] - images[1]).max() < 1e-6


@pytest.mark.parametrize("make,what", [
    (lambda: RayScene.from_mesh(MESH[0] * 1e31, MESH[1]), "triangle 0"),
    (lambda: RayScene.from_mesh(MESH[0] * 1e-32, MESH[1]), "triangle 0"),
    (lambda: RayScene.from_spheres(np.array([[0.0, 0.0, 2e30]]), np.array([1.0])), "sphere 0"),
    (lambda: RayScene.from_spheres(np.zeros((2, 3)), np.array([1.0, 1e-31])), "sphere 1"),
    (lambda: RayScene.from_spheres(np.zeros((1, 3)), np.array([1e300])), "sphere 0"),
])
def test_scenes_beyond_the_range_are_refused(make, what):
    with pytest.raises(SceneError, match=what):
        make()


def test_an_instance_that_scales_beyond_the_range_is_refused():
    scene = Scene()
    inner = Group(name="rock", accel="bvh")
    inner.spheres.add([0.0, 0.0, 0.0], 1e20, 0)
    big = np.diag([1e20, 1e20, 1e20, 1.0])
    scene.root.children.append(Instance(inner, big))
    with pytest.raises(SceneError, match="instance of group rock"):
        RayScene(scene)


@pytest.mark.parametrize("field,value", [("eye", [0.0, -1e31, 0.0]), ("look_at", [2e30, 0.0, 0.0])])
def test_a_camera_beyond_the_range_is_refused(field, value):
    with pytest.raises(SceneError, match=f"camera {field}"):
        Camera(**{field: np.array(value)})


@pytest.mark.parametrize("o,d,what", [
    ([0.0, 0.0, 2e30], [0.0, 0.0, -1.0], r"origins\[1\]"),
    ([0.0, 0.0, 5.0], [0.0, 0.0, -1e-31], r"directions\[1\]"),
    ([0.0, 0.0, 5.0], [0.0, 0.0, 1e31], r"directions\[1\]"),
])
def test_rays_beyond_the_range_are_refused_by_index(o, d, what):
    scene = RayScene.from_spheres(np.zeros((1, 3)), np.array([1.0]))
    origins = np.array([[0.0, 0.0, 5.0], o, [0.0, 0.0, 5.0]])
    directions = np.array([[0.0, 0.0, -1.0], d, [0.0, 0.0, -1.0]])
    with pytest.raises(RayInputError, match=what):
        scene.intersect(origins, directions)
    # tiny and huge directions inside the range give the same hit
    for scale in (MIN_SIZE * 2, 1.0, MAX_COORDINATE / 2):
        assert scene.intersect(np.array([[0.0, 0.0, 5.0]]), np.array([[0.0, 0.0, -scale]])).t[0] * scale == \
            pytest.approx(4.0, rel=1e-12)

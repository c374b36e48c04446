"""Arvo's sparse transforms: instance maps classified at build time, rays mapped with only
the multiplies each class needs, and the transforms.* counters."""

import numpy as np
import pytest

from raykernel.engine.flatten import flatten
from raykernel.engine.transforms import TRANSFORM_MULTIPLIES, transform_class
from raykernel.engine.traverse import cast_rays
from raykernel.geometry import counters as C
from raykernel.scene import Group, Instance, Material, Scene

IDENTITY, TRANSLATION, SCALE, AFFINE = range(4)


def matrix(linear=np.eye(3), translation=(0.0, 0.0, 0.0)):
    m = np.eye(4)
    m[:3, :3] = linear
    m[:3, 3] = translation
    return m


def rotation_z(degrees):
    a = np.radians(degrees)
    return np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])


@pytest.mark.parametrize("m,expected", [
    (matrix(), IDENTITY),
    (matrix(translation=(1.0, -2.0, 0.5)), TRANSLATION),
    (matrix(translation=(0.0, 0.0, 1e-300)), TRANSLATION),
    (matrix(np.diag([2.0, 2.0, 2.0])), SCALE),
    (matrix(np.diag([1.0, 1.0, -1.0]), (3.0, 0.0, 0.0)), SCALE),        # a mirror is a scale
    (matrix(np.diag([1.0, 1.0 + 2 ** -52, 1.0])), SCALE),              # not exactly the identity
    (matrix(rotation_z(30.0)), AFFINE),
    (matrix(np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])), AFFINE),   # an axis swap
    (matrix(np.array([[1.0, 1e-300, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])), AFFINE),  # a tiny shear
])
def test_classes(m, expected):
    assert transform_class(np.linalg.inv(m)[:3, :]) == expected


def unit_ball() -> Group:
    ball = Group(name="ball")
    ball.spheres.add((0.0, 0.0, 0.0), 1.0, 0)
    return ball


def scene_of(root: Group) -> Scene:
    scene = Scene(root=root)
    scene.add_material(Material())
    return scene


def one_instance_scene(m):
    root = Group(name="root", accel="list")
    root.add(Instance(unit_ball(), m))
    return scene_of(root)


@pytest.mark.parametrize("m,cls", [(matrix(), IDENTITY), (matrix(translation=(0.3, 0.1, -0.2)), TRANSLATION),
                                   (matrix(np.diag([1.5, 0.5, 2.0]), (0.1, 0.0, 0.0)), SCALE),
                                   (matrix(rotation_z(40.0) @ np.diag([1.2, 0.8, 1.0])), AFFINE)])
def test_counts_and_hits_per_class(m, cls):
    scene = one_instance_scene(m)
    geo, _ = flatten(scene)
    rng = np.random.default_rng(3)
    o = rng.uniform(-0.2, 0.2, (500, 3))            # inside the instance's box: every ray maps once
    d = rng.normal(size=(500, 3))
    t, kind, index, inst, cnt = cast_rays(geo, o, d)
    names = ("transforms.identity", "transforms.translation", "transforms.scale", "transforms.affine")
    by_class = [int(cnt[C.TRANSFORMS + k]) for k in range(4)]
    assert by_class == [500 if k == cls else 0 for k in range(4)], names
    assert cnt[C.TRANSFORM_MULTIPLIES] == 500 * TRANSFORM_MULTIPLIES[cls]
    # against the sphere in world space: centre m @ 0, the ray mapped by the inverse
    inv = np.linalg.inv(m)
    lo = o @ inv[:3, :3].T + inv[:3, 3]
    ld = d @ inv[:3, :3].T
    a = np.einsum("ij,ij->i", ld, ld)
    b = np.einsum("ij,ij->i", lo, ld)
    c = np.einsum("ij,ij->i", lo, lo) - 1.0
    expected = (-b + np.sqrt(b * b - a * c)) / a     # from inside: the far root
    np.testing.assert_allclose(t, expected, rtol=1e-12)
    assert np.all(inst == 0)


def test_nested_instances_count_each_mapping():
    mid = Group(name="mid", accel="list")
    mid.add(Instance(unit_ball(), matrix(np.diag([2.0, 2.0, 2.0]))))
    root = Group(name="root", accel="list")
    root.add(Instance(mid, matrix(translation=(0.5, 0.0, 0.0))))
    geo, _ = flatten(scene_of(root))
    o = np.tile([0.5, 0.0, 0.0], (10, 1))
    d = np.tile([1.0, 0.0, 0.0], (10, 1))
    t, *_, cnt = cast_rays(geo, o, d)
    np.testing.assert_allclose(t, 2.0)
    assert cnt[C.TRANSFORMS + TRANSLATION] == 10 and cnt[C.TRANSFORMS + SCALE] == 10
    assert cnt[C.TRANSFORM_MULTIPLIES] == 10 * TRANSFORM_MULTIPLIES[SCALE]

"""Culling a tile's eye rays against the scene's box (rendering/frustum.py, render._render_tiles).

A tile is culled only when every one of its eye rays misses the box in its own slab test, so a
render gives the same image bytes and every counter the same with culling and without, but for
frustum.culled, which counts the eye rays culled.
"""

from __future__ import annotations

import numpy as np
import pytest
from support import add_sphere, make_scene, work_counts

import raykernel
from raykernel.geometry.boxes import INF, box_entry, inverse
from raykernel.geometry.primitives import normalize
from raykernel.rendering import render as R
from raykernel.rendering.frustum import tile_misses_box


def camera(rng, size=17):
    """An SPD camera (corner samples) at a random eye, looking anywhere, as render.py makes it."""
    eye = rng.normal(size=3) * rng.choice([1e-3, 1.0, 1e4])
    look = eye + rng.normal(size=3)
    scene = make_scene(eye=tuple(eye), look_at=tuple(look), up=tuple(rng.normal(size=3)),
                       angle=float(rng.uniform(5.0, 120.0)), size=size)
    return R.camera_vectors(scene.camera, size, size, corners=True), size + 1


def enters(cam, i, j, box) -> bool:
    d = normalize(cam[3] + i * cam[6] + j * cam[9], cam[4] + i * cam[7] + j * cam[10],
                  cam[5] + i * cam[8] + j * cam[11])
    return box_entry(box, 0, cam[0], cam[1], cam[2], inverse(d[0]), inverse(d[1]), inverse(d[2]), 0.0, INF) != INF


def box_around(point, half) -> np.ndarray:
    return np.array([[*(point - half), *(point + half)]])


def test_a_culled_tile_has_no_ray_that_enters_the_box():
    """Random cameras, tiles and boxes, many of them just touching a sample's ray: wherever the
    tile is culled, every sample's ray misses the box in the renderer's own slab test."""
    rng = np.random.default_rng(5)
    culled = kept = 0
    for _ in range(300):
        cam, n = camera(rng)
        i0, j0 = rng.integers(0, n, 2)
        i1, j1 = i0 + rng.integers(0, n - i0), j0 + rng.integers(0, n - j0)
        samples = [(i, j) for i in range(i0, i1 + 1) for j in range(j0, j1 + 1)]
        scale = np.linalg.norm(cam[3:6])
        for _ in range(10):
            i, j = samples[rng.integers(len(samples))]
            ray = np.array(normalize(cam[3] + i * cam[6] + j * cam[9], cam[4] + i * cam[7] + j * cam[10],
                                     cam[5] + i * cam[8] + j * cam[11]))
            t = rng.uniform(0.1, 10.0) * max(1.0, np.abs(cam[:3]).max() / scale)
            # a box around a point on a sample's ray, or beside it at a distance from tiny to large
            aside = rng.normal(size=3) * t * rng.choice([0.0, 1e-12, 1e-6, 0.05, 1.0])
            box = box_around(cam[:3] + t * ray + aside, t * rng.choice([1e-9, 1e-3, 0.2]))
            if tile_misses_box(cam, i0, i1, j0, j1, box, 0):
                culled += 1
                assert not any(enters(cam, i, j, box) for i, j in samples)
            else:
                kept += 1
    assert culled > 300 and kept > 300      # both ways, many times


def test_a_box_far_to_one_side_is_culled_and_one_in_view_is_not():
    scene = make_scene(eye=(0.0, -5.0, 0.0), size=32)
    cam = R.camera_vectors(scene.camera, 32, 32, corners=True)
    left = box_around(np.array([-50.0, 0.0, 0.0]), 1.0)
    assert tile_misses_box(cam, 0, 15, 0, 15, left, 0)
    centre = box_around(np.zeros(3), 0.5)
    assert not tile_misses_box(cam, 8, 23, 8, 23, centre, 0)
    behind = box_around(np.array([0.0, -50.0, 0.0]), 1.0)
    assert tile_misses_box(cam, 8, 23, 8, 23, behind, 0)        # rays go forward only
    around_eye = box_around(np.array([0.0, -5.0, 0.0]), 1.0)
    assert not tile_misses_box(cam, 0, 15, 0, 15, around_eye, 0)


@pytest.mark.parametrize("box", [[[np.inf, np.inf, np.inf, -np.inf, -np.inf, -np.inf]],
                                 [[np.nan, 0.0, 0.0, 1.0, 1.0, 1.0]], [[1.0, 0.0, 0.0, -1.0, 1.0, 1.0]]])
def test_empty_or_not_finite_boxes_are_never_culled(box):
    scene = make_scene(size=32)
    cam = R.camera_vectors(scene.camera, 32, 32, corners=True)
    assert not tile_misses_box(cam, 0, 15, 0, 15, np.array(box), 0)


def renders_with_and_without_culling(monkeypatch, scene, **options):
    """The two renders, checked for the same image bytes and counts."""
    got = []
    for culling in (True, False):
        monkeypatch.setattr(R.RenderJob, "frustum_culling", culling)
        got.append(raykernel.render(scene, **options))
    on, off = got
    assert np.array_equal(on.image, off.image)
    culled = on.stats["frustum.culled"]
    assert off.stats["frustum.culled"] == 0
    assert work_counts(on.stats) == dict(work_counts(off.stats), **{"frustum.culled": culled})
    return on, off


def culled_tiles(scene, resolution) -> tuple[int, int]:
    """The tiles of an SPD render the renderer culls, and their samples."""
    job = R.RenderJob(scene, spd=True, resolution=resolution)
    culled = [(x, y) for x, y in zip(job.tile_x, job.tile_y) if R._culled(job.geo, job.cam, job.sw, job.sh, x, y)]
    return len(culled), sum((min(x + R.TILE, job.sw) - x) * (min(y + R.TILE, job.sh) - y) for x, y in culled)


@pytest.mark.parametrize("name", ["spd:jacks:1", "spd:sombrero:1"])
def test_spd_renders_are_the_same_with_and_without_culling(monkeypatch, name):
    scene = raykernel.load(name)
    on, off = renders_with_and_without_culling(monkeypatch, scene, spd=True, resolution=96, threads=2)
    tiles, samples = culled_tiles(scene, 96)
    assert on.stats["frustum.culled"] == samples
    if name == "spd:jacks:1":
        assert tiles > 10       # most of the picture is empty


@pytest.mark.parametrize("scale", [1e-6, 1.0, 1e7])
def test_a_sphere_at_a_tiles_edge_renders_the_same_with_and_without_culling(monkeypatch, scale):
    """A small sphere off to one side, at the corner between tiles, at tiny and huge scales; and a
    background that is not black (a culled sample gets it as a traced miss does)."""
    scene = make_scene(eye=(0.0, -5.0 * scale, 0.0), size=47, background=(0.2, -0.0, 0.7))
    add_sphere(scene, (0.95 * scale, 0.0, 0.95 * scale), 0.1 * scale, kd=1.0)
    add_sphere(scene, (-1.2 * scale, 0.0, -0.3 * scale), 0.02 * scale, kd=1.0, ks=0.5)
    scene.add_light((0.0, -5.0 * scale, 5.0 * scale))
    on, off = renders_with_and_without_culling(monkeypatch, scene, spd=True, threads=1)
    assert on.stats["rays.eye_hit"] > 0
    assert culled_tiles(scene, 47)[0] > 0

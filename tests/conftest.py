"""Shared fixtures and small scene builders for the render and CLI tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from raykernel.scene import Camera, Material, Scene

from support import SPD_DIR


@pytest.fixture
def spd_dir() -> Path:
    """The directory of the reference SPD files (tests/data/spd, unpacked)."""
    return SPD_DIR


def make_scene(eye=(0.0, -5.0, 0.0), look_at=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0), angle=45.0,
               size=1, background=(0.0, 0.0, 0.0)) -> Scene:
    """An empty scene with a square `size` x `size` camera."""
    return Scene(camera=Camera(eye=eye, look_at=look_at, up=up, angle=angle, hither=0.0,
                               width=size, height=size),
                 background=background)


def add_sphere(scene: Scene, center, radius, **material) -> int:
    m = scene.add_material(Material(**material))
    scene.root.spheres.add(center, radius, m)
    return m


def add_polygon(scene: Scene, vertices, **material) -> int:
    m = scene.add_material(Material(**material))
    scene.root.polygons.add(np.asarray(vertices, np.float64), m)
    return m


def add_square(scene: Scene, center, u, v, **material) -> int:
    """The square center +- u +- v (u, v: half-edge vectors), counter-clockwise around u x v."""
    c, u, v = (np.asarray(x, np.float64) for x in (center, u, v))
    return add_polygon(scene, [c - u - v, c + u - v, c + u + v, c - u + v], **material)


def ray_counts(stats) -> dict:
    """The rays.* counters (exact integers) of a render's statistics."""
    return {k: v for k, v in stats.items() if k.startswith("rays.")}


def work_counts(stats) -> dict:
    """Every integer counter: rays, tests, traversal and build figures; no times or rates."""
    return {k: v for k, v in stats.items()
            if isinstance(v, (int, np.integer)) and not k.startswith("time.") and k != "build.seconds"}

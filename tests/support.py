"""What several test modules share: the reference SPD files, small scenes, random rays, casts.

    from support import SPD_DIR          # the SPD programs' NFF files, unpacked from tests/data/spd
    from support import new_scene, fill_group, random_rays, cast, assert_same_hits
    from support import make_scene, add_sphere, ray_counts, work_counts
"""

from __future__ import annotations

import gzip
import hashlib
import os
import tempfile
from pathlib import Path

import numpy as np

from raykernel.engine.flatten import flatten
from raykernel.engine.traverse import cast_rays
from raykernel.scene import Camera, Group, Material, Scene, TriangleMesh

DATA = Path(__file__).resolve().parent / "data"


def _unpacked(folder: Path) -> Path:
    """The .gz files of `folder` unpacked into a folder of the system's temporary directory named
    by their contents, made once (atomically, for test processes running side by side)."""
    packed = sorted(folder.glob("*.gz"))
    digest = hashlib.sha256(b"".join(p.name.encode() + p.read_bytes() for p in packed)).hexdigest()[:16]
    target = Path(tempfile.gettempdir()) / f"raykernel-tests-{folder.name}-{digest}"
    if target.is_dir():
        return target
    staging = Path(tempfile.mkdtemp(prefix=target.name + ".", dir=target.parent))
    for p in packed:
        (staging / p.stem).write_bytes(gzip.decompress(p.read_bytes()))
    try:
        os.rename(staging, target)
    except OSError:         # another process made it first
        for f in staging.iterdir():
            f.unlink()
        staging.rmdir()
    return target


# Every NFF file the SPD programs wrote at size factor 1 and at their default size (and teapot at 2
# and 12, jacks at 4): tests/data/spd/README.md says where they come from.
SPD_DIR = _unpacked(DATA / "spd")


# ---------------------------------------------------------------- small random scenes and rays

def new_scene() -> Scene:
    """An empty scene with one default material (index 0)."""
    scene = Scene()
    scene.add_material(Material())
    return scene


def fill_group(group: Group, rng, n=12, spread=4.0, big=False) -> Group:
    """Spheres, cones, polygons, patches and a triangle mesh at random, material 0; the group."""
    size = 3.0 if big else 0.6
    for _ in range(n):
        group.spheres.add(rng.uniform(-spread, spread, 3), rng.uniform(0.1, size), 0)
    for _ in range(max(1, n // 3)):
        base = rng.uniform(-spread, spread, 3)
        group.cones.add(base, rng.uniform(0.05, 0.5), base + rng.normal(0, 1.0, 3), rng.uniform(0.05, 0.5), 0)
    for _ in range(max(1, n // 3)):
        c = rng.uniform(-spread, spread, 3)
        u, v = rng.normal(0, size, 3), rng.normal(0, size, 3)
        angles = np.linspace(0, 2 * np.pi, rng.integers(3, 7), endpoint=False)
        group.polygons.add(c + np.outer(np.cos(angles), u) + np.outer(np.sin(angles), v), 0)
    for _ in range(max(1, n // 4)):
        c = rng.uniform(-spread, spread, 3)
        u, v = rng.normal(0, size, 3), rng.normal(0, size, 3)
        verts = np.array([c, c + u, c + u + v, c + v])
        group.patches.add(verts, 0, normals=rng.normal(0, 1, (4, 3)) + np.cross(u, v))
    c = rng.uniform(-spread, spread, 3)
    verts = c + rng.normal(0, size, (10, 3))
    faces = rng.integers(0, 10, (8, 3))
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
    if len(faces):
        group.add(TriangleMesh(verts, faces, 0))
    return group


def random_rays(rng, n, spread=6.0, inside=False):
    """(origins, directions) of n rays: from outside a ball of 2.5 spread (or from inside, at most
    0.6 spread off the centre) towards points within 0.7 spread."""
    if inside:
        origins = rng.uniform(-spread * 0.6, spread * 0.6, (n, 3))
    else:
        origins = rng.normal(0, 1, (n, 3))
        origins *= 2.5 * spread / np.linalg.norm(origins, axis=1)[:, None]
    targets = rng.uniform(-spread * 0.7, spread * 0.7, (n, 3))
    return origins, targets - origins


def cast(scene, accel, origins, directions, **kw):
    """traverse.cast_rays of the scene built with `accel`: (t, kind, index, instance, counters)."""
    geo, _ = flatten(scene, default_accel=accel)
    return cast_rays(geo, origins, directions, **kw)


def assert_same_hits(a, b):
    """Two cast results' t, kind, index and instance are the same, array for array."""
    for x, y in zip(a[:4], b[:4]):
        np.testing.assert_array_equal(x, y)


# ---------------------------------------------------------------- small hand-made scenes and their counts

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

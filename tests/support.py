"""What several test modules share: the reference SPD files, small scenes, random rays, casts.

    from support import SPD_DIR          # the SPD programs' NFF files, unpacked from tests/data/spd
    from support import new_scene, fill_group, random_rays, cast, assert_same_hits
    from support import fill_box, random_scene, scene_rays, cast_interval, assert_close_hits
    from support import Node, random_solid, random_tree     # closed solids with their own crossing tests
    from support import MESHES, targets, rays_through        # closed meshes with dyadic vertices
    from support import make_scene, add_sphere, ray_counts, work_counts
    from support import entered_masks          # which samples' walks entered a box, traced one by one

Where two test modules used different random scenes or rays under one name,
each variant is kept here under a name of its own (fill_group and
fill_group_large, random_rays, rays_outside_and_inside and rays_into_box, ...),
so that every test still gets exactly the scene and rays it was written for.
"""

from __future__ import annotations

import gzip
import hashlib
import os
import tempfile
from pathlib import Path

import numpy as np
import pytest
import reference as ref

from raykernel.casting.rayscene import RayScene
from raykernel.engine.flatten import flatten
from raykernel.engine.traverse import cast_rays
from raykernel.scene import Camera, Group, Instance, Material, Polygons, Scene, TriangleMesh

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


def fill_group_large(group: Group, rng, n=30, spread=4.0, patches=True, crowd=False) -> Group:
    """n spheres (radius up to 0.8), n // 3 cones and polygons, n // 4 patches (with `patches`) and a
    30-vertex triangle mesh at random, material 0; with `crowd`, 3n small spheres packed around
    one point (grid cells overflow) and a floor polygon below. The group."""
    for _ in range(n):
        group.spheres.add(rng.uniform(-spread, spread, 3), rng.uniform(0.1, 0.8), 0)
    for _ in range(n // 3):
        base = rng.uniform(-spread, spread, 3)
        group.cones.add(base, rng.uniform(0.05, 0.5), base + rng.normal(0, 1.0, 3), rng.uniform(0.05, 0.5), 0)
    for _ in range(n // 3):
        c = rng.uniform(-spread, spread, 3)
        u, v = rng.normal(0, 0.6, 3), rng.normal(0, 0.6, 3)
        angles = np.linspace(0, 2 * np.pi, rng.integers(3, 7), endpoint=False)
        group.polygons.add(c + np.outer(np.cos(angles), u) + np.outer(np.sin(angles), v), 0)
    if patches:
        for _ in range(n // 4):
            c = rng.uniform(-spread, spread, 3)
            u, v = rng.normal(0, 0.6, 3), rng.normal(0, 0.6, 3)
            group.patches.add(np.array([c, c + u, c + u + v, c + v]), 0,
                              normals=rng.normal(0, 1, (4, 3)) + np.cross(u, v))
    verts = rng.uniform(-spread, spread, 3) + rng.normal(0, 0.8, (30, 3))
    faces = np.array([f for f in rng.integers(0, 30, (40, 3)) if len(set(f)) == 3])
    group.add(TriangleMesh(verts, faces, 0))
    if crowd:
        centre = rng.uniform(-spread / 2, spread / 2, 3)
        for _ in range(3 * n):
            group.spheres.add(centre + rng.normal(0, 0.3, 3), rng.uniform(0.02, 0.1), 0)
        group.polygons.add([(-9, -9, -spread), (9, -9, -spread), (9, 9, -spread), (-9, 9, -spread)], 0)
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


def rays_outside_and_inside(rng, n, spread=6.0):
    """(origins, directions) of n + n // 4 rays: n from outside a ball of 2.5 spread, then n // 4 from
    inside (at most 0.6 spread off the centre), all towards points within 0.7 spread."""
    origins = rng.normal(0, 1, (n, 3))
    origins *= 2.5 * spread / np.linalg.norm(origins, axis=1)[:, None]
    inside = rng.uniform(-spread * 0.6, spread * 0.6, (n // 4, 3))
    origins = np.vstack([origins, inside])
    targets = rng.uniform(-spread * 0.7, spread * 0.7, (len(origins), 3))
    return origins, targets - origins


def rays_into_box(rng, n=400, extent=2.0):
    """(origins, directions) of n rays from the box +-extent towards points of the box +-1."""
    o = rng.uniform(-extent, extent, (n, 3))
    target = rng.uniform(-1, 1, (n, 3))
    return o, target - o


def rotation_scale(rng) -> np.ndarray:
    """A 4x4 map: a random rotation (or reflection) after scales of 0.3 to 2.5 along the axes, then
    a shift of up to 3 along each axis."""
    q, _ = np.linalg.qr(rng.normal(0, 1, (3, 3)))
    m = np.eye(4)
    m[:3, :3] = q @ np.diag(rng.uniform(0.3, 2.5, 3))
    m[:3, 3] = rng.uniform(-3, 3, 3)
    return m


def nested_scene(rng, outer, inner, instanced=False) -> Scene:
    """A root (structure `outer`) of fill_group primitives holding four child groups (`inner`): each
    with a grandchild group (`inner`) of its own, or, with `instanced`, shown through two
    rotation_scale instances instead."""
    scene = new_scene()
    scene.root.accel = outer
    fill_group(scene.root, rng, n=6)
    for k in range(4):
        child = fill_group(Group(name=f"child{k}", accel=inner), rng, n=8, spread=1.5)
        if instanced:
            scene.root.add(Instance(child, rotation_scale(rng)))
            scene.root.add(Instance(child, rotation_scale(rng)))
        else:
            shift = Group(name=f"moved{k}", accel=inner)
            fill_group(shift, rng, n=5, spread=3.0)
            child.add(shift)
            scene.root.add(child)
    return scene


def cast(scene, accel, origins, directions, **kw):
    """traverse.cast_rays of the scene built with `accel`: (t, kind, index, instance, counters)."""
    geo, _ = flatten(scene, default_accel=accel)
    return cast_rays(geo, origins, directions, **kw)


def cast_grown(scene, accel, origins, directions, **kw):
    """As cast, but where `accel` makes lazy trees they are first grown by three RayScene queries
    with the same rays, so that the cast meets refined trees."""
    geo, build = flatten(scene, default_accel=accel)
    if build.get("lazy") is not None:
        rs = RayScene.from_scene(scene, accel)
        for _ in range(3):
            rs.count_hits(origins, directions)
        assert rs.build_stats["build.refine_passes"] >= 3
        geo = rs.geo
    return cast_rays(geo, origins, directions, **kw)


def assert_same_hits(a, b):
    """Two cast results' t, kind, index and instance are the same, array for array."""
    for x, y in zip(a[:4], b[:4]):
        np.testing.assert_array_equal(x, y)


def same_hits_as_list(scene, spec, o, d, repeats=1, plain=None):
    """RayScene(spec) against RayScene(list) (of `plain`, the same scene with list specs, if given):
    closest, any and all hits, `repeats` times (lazy trees refine during and between the
    queries), then the refined trees through cast_rays. Returns the RayScene of `spec`."""
    reference = RayScene.from_scene(scene if plain is None else plain, "list")
    got = RayScene.from_scene(scene, spec)
    want = reference.intersect(o, d)
    want_any = reference.occluded(o, d, tmax=0.5)
    want_all = reference.intersect_all(o, d, ids=True)
    assert np.isfinite(want.t).sum() > len(o) // 20
    for _ in range(repeats):
        h = got.intersect(o, d)
        for name in ("t", "prim_id", "geom_id", "inst_id"):
            np.testing.assert_array_equal(getattr(h, name), getattr(want, name))
        np.testing.assert_array_equal(h.normal, want.normal)
        np.testing.assert_array_equal(got.occluded(o, d, tmax=0.5), want_any)
        for a, b in zip(got.intersect_all(o, d, ids=True), want_all):
            np.testing.assert_array_equal(a, b)
    # the refined tree through the plain traversal too
    assert_same_hits(cast_rays(got.geo, o, d), cast_rays(reference.geo, o, d))
    return got


def same_arrays(a, b) -> bool:
    """Two tuples of arrays (two trees' arrays) are the same, dtype, shape and bytes."""
    return all(x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes() for x, y in zip(a, b))


def box_area(b):
    """Surface area of boxes (..., 6): min corner, then max corner."""
    e = b[..., 3:] - b[..., :3]
    return 2.0 * (e[..., 0] * e[..., 1] + e[..., 1] * e[..., 2] + e[..., 2] * e[..., 0])


# ---------------------------------------------------------------- a dyadic lattice and rays along its cells

def lattice_scene() -> Scene:
    """Unit spheres and axis-aligned squares on dyadic positions in [0, 8]^3: edges fall on cell
    boundaries."""
    scene = new_scene()
    for x in range(1, 8, 2):
        for y in range(1, 8, 3):
            for z in range(1, 8, 2):
                scene.root.spheres.add((x, y, z), 0.5, 0)
    for x in range(4):
        scene.root.polygons.add([(2 * x, 0, 2), (2 * x + 2, 0, 2), (2 * x + 2, 8, 2), (2 * x, 8, 2)], 0)
    scene.root.polygons.add([(0, 4, 0), (8, 4, 0), (8, 4, 8), (0, 4, 8)], 0)
    return scene


def axis_and_boundary_rays():
    """Rays along the axes and exactly along dyadic cell boundaries of a [0, 8]^3 grid."""
    origins, dirs = [], []
    for a in range(3):
        for u in (0.0, 1.0, 2.0, 4.0, 0.5, 3.25, 8.0):
            for v in (0.0, 2.0, 4.0, 6.5, 8.0):
                for sign in (1.0, -1.0):
                    o = np.zeros(3)
                    o[a] = -3.0 if sign > 0 else 11.0
                    o[(a + 1) % 3] = u
                    o[(a + 2) % 3] = v
                    d = np.zeros(3)
                    d[a] = sign
                    origins.append(o)
                    dirs.append(d)
    # diagonals through cell corners and rays from inside the grid
    for k in range(9):
        origins.append([k * 0.5, 0.0, -2.0])
        dirs.append([0.0, 1.0, 1.0])
        origins.append([4.0, 4.0, 4.0])
        dirs.append([np.cos(k), np.sin(k), 0.0])
    origins.append([-1.0, -1.0, -1.0])
    dirs.append([1.0, 1.0, 1.0])
    return np.array(origins), np.array(dirs)


# ---------------------------------------------------------------- every primitive kind in a box

RTOL = 1e-9     # assert_close_hits: the relative difference allowed between two t


def random_rotation(rng) -> np.ndarray:
    """A random 3x3 rotation (determinant +1)."""
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def similarity(rng, scale=(0.5, 2.0), shift=3.0) -> np.ndarray:
    """Rotation, uniform scale and translation."""
    m = np.eye(4)
    m[:3, :3] = rng.uniform(*scale) * random_rotation(rng)
    m[:3, 3] = rng.uniform(-shift, shift, 3)
    return m


def affine(rng, shift=3.0) -> np.ndarray:
    """Rotation, non-uniform scale, shear and translation."""
    m = np.eye(4)
    shear = np.eye(3)
    shear[0, 1], shear[1, 2], shear[0, 2] = rng.uniform(-0.6, 0.6, 3)
    m[:3, :3] = random_rotation(rng) @ np.diag(rng.uniform(0.4, 2.5, 3)) @ shear @ random_rotation(rng)
    m[:3, 3] = rng.uniform(-shift, shift, 3)
    return m


def polygon_outline(rng, concave: bool) -> np.ndarray:
    """A random polygon around the origin in the plane z = 0: convex with corners on the unit
    circle, or a concave star."""
    n = int(rng.integers(3, 9))
    if concave:
        a = rng.uniform(0, 2 * np.pi) + np.pi * np.arange(2 * n) / n
        r = np.where(np.arange(2 * n) % 2 == 0, 1.0, rng.uniform(0.25, 0.6))
    else:
        a = np.sort(rng.uniform(0, 2 * np.pi, n))
        r = np.ones(n)
    return np.column_stack([r * np.cos(a), r * np.sin(a), np.zeros(len(a))])


def fill_box(group: Group, rng, n=(6, 3, 4, 2, 10), center=(0, 0, 0), extent=1.0, curved=True) -> Group:
    """Random primitives of every kind in the box center +- extent: n = (spheres, cones,
    polygons incl. concave ones, patches, mesh triangles), with negative spheres, cylinders and
    a closed octahedron among them. Without `curved`: flat kinds only."""
    center = np.asarray(center, np.float64)
    n_sph, n_cone, n_poly, n_patch, n_tri = n
    if curved:
        for _ in range(n_sph):
            r = rng.uniform(0.05, 0.3) * extent * (-1 if rng.uniform() < 0.15 else 1)
            group.spheres.add(center + rng.uniform(-extent, extent, 3), r)
        for _ in range(n_cone):
            base = center + rng.uniform(-extent, extent, 3)
            axis = ref.unit(rng.normal(size=3)).astype(np.float64) * rng.uniform(0.2, 0.8) * extent
            r0, r1 = rng.uniform(0.0, 0.3, 2) * extent
            if rng.uniform() < 0.3:
                r1 = 0.0 if rng.uniform() < 0.5 else r0
            sign = -1 if rng.uniform() < 0.2 else 1
            group.cones.add(base, sign * max(r0, 0.02 * extent), base + axis, sign * r1)
    for k in range(n_poly):
        frame = random_rotation(rng) * rng.uniform(0.1, 0.4) * extent
        group.polygons.add(polygon_outline(rng, concave=k % 2 == 1) @ frame.T + center
                           + rng.uniform(-extent, extent, 3))
    for _ in range(n_patch):
        frame = random_rotation(rng) * rng.uniform(0.1, 0.4) * extent
        verts = polygon_outline(rng, False) @ frame.T + center + rng.uniform(-extent, extent, 3)
        normals = frame[:, 2] + 0.3 * rng.normal(size=(len(verts), 3))
        group.patches.add(verts, normals=normals)
    if n_tri:
        # a closed octahedron and a soup of loose triangles
        octa = np.array([(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)], np.float64)
        faces = [(0, 2, 4), (2, 1, 4), (1, 3, 4), (3, 0, 4), (2, 0, 5), (1, 2, 5), (3, 1, 5), (0, 3, 5)]
        octa = octa @ random_rotation(rng).T * 0.4 * extent + center + rng.uniform(-extent, extent, 3) * 0.5
        loose = center + rng.uniform(-extent, extent, (3 * n_tri, 3))
        loose = loose.reshape(n_tri, 3, 3)
        loose = loose.mean(axis=1, keepdims=True) + 0.3 * (loose - loose.mean(axis=1, keepdims=True))
        verts = np.vstack([octa, loose.reshape(-1, 3)])
        faces = np.vstack([faces, 6 + np.arange(3 * n_tri).reshape(-1, 3)])
        group.add(TriangleMesh(verts, faces))
    return group


def random_scene(seed: int, accel=None, n=(30, 12, 14, 8, 30), extent=5.0) -> Scene:
    """A scene whose root (structure `accel`) holds fill_box primitives of every kind."""
    rng = np.random.default_rng(seed)
    scene = Scene()
    scene.root.accel = accel
    fill_box(scene.root, rng, n, extent=extent)
    return scene


def scene_rays(rng, n, center=(0, 0, 0), extent=5.0):
    """(origins, directions, tmin, tmax): a third of the rays start outside the box center +- extent
    and are aimed into it, a third start inside in random directions, a third start inside with
    random tmin and tmax."""
    center = np.asarray(center, np.float64)
    k = n // 3
    far = rng.normal(size=(k, 3))
    o1 = center + 3 * extent * far / np.linalg.norm(far, axis=1)[:, None]
    d1 = center + extent * rng.uniform(-1, 1, (k, 3)) - o1
    o2 = center + extent * rng.uniform(-1, 1, (n - k, 3))
    d2 = rng.normal(size=(n - k, 3)) * rng.uniform(0.2, 3.0, (n - k, 1))
    o, d = np.vstack([o1, o2]), np.vstack([d1, d2])
    tmin = np.zeros(n)
    tmax = np.full(n, np.inf)
    tmin[2 * k:] = rng.uniform(0, 1, n - 2 * k)
    tmax[2 * k:] = tmin[2 * k:] + rng.exponential(2.0, n - 2 * k)
    return o, d, tmin, tmax


def cast_interval(scene, o, d, tmin=0.0, tmax=np.inf, accel="list", any_hit=False):
    """traverse.cast_rays of the scene built with `accel` (list by default) over [tmin, tmax]."""
    geo, _ = flatten(scene, accel)
    return cast_rays(geo, o, d, tmin, tmax, any_hit)


def assert_close_hits(got, want, mask=None, what=""):
    """Same (kind, index, instance) and t within RTOL relative, on the rays in `mask`."""
    t, kind, index, inst = got[:4]
    wt, wkind, windex, winst = want[:4]
    n = len(t)
    mask = np.ones(n, bool) if mask is None else mask
    with np.errstate(invalid="ignore"):
        close = (t == wt) | (np.abs(t - wt) <= RTOL * np.abs(wt))
    ok = close & (kind == wkind) & (index == windex) & (inst == winst)
    bad = np.flatnonzero(mask & ~ok)
    if len(bad):
        r = bad[0]
        pytest.fail(f"{what}: {len(bad)} of {mask.sum()} rays differ; first, ray {r}: got t={t[r]!r} "
                    f"({kind[r]}, {index[r]}, {inst[r]}), want t={wt[r]!r} ({wkind[r]}, {windex[r]}, {winst[r]})")


# ---------------------------------------------------------------- closed solids with their own crossing tests

def box_mesh(lo, hi):
    """The 8 corners of the box lo..hi and its 6 faces as outward quadrilaterals of corner indices."""
    v = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])], float)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    return v, quads


class Sphere:
    """A sphere solid: added as a sphere primitive, crossed where the quadratic says."""

    def __init__(self, c, r):
        self.c, self.r = np.asarray(c, float), float(r)

    def add_to(self, g):
        g.spheres.add(self.c, self.r, 0)

    def crossings(self, o, d):
        f = o - self.c
        a, b, c = d @ d, 2 * f @ d, f @ f - self.r ** 2
        disc = b * b - 4 * a * c
        if disc < 0:
            return []
        s = np.sqrt(disc)
        return [(-b - s) / (2 * a), (-b + s) / (2 * a)]


class MeshBox:
    """A closed triangle mesh: a box split into 12 triangles."""

    def __init__(self, lo, hi):
        self.v, quads = box_mesh(lo, hi)
        self.f = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])

    def add_to(self, g):
        g.add(TriangleMesh(self.v, self.f, 0))

    def crossings(self, o, d):
        out = []
        for a, b, c in self.v[self.f]:
            e1, e2 = b - a, c - a
            p = np.cross(d, e2)
            det = e1 @ p
            if abs(det) < 1e-300:
                continue
            s = o - a
            u = s @ p / det
            q = np.cross(s, e1)
            v = d @ q / det
            if u >= 0 and v >= 0 and u + v <= 1:
                out.append(e2 @ q / det)
        return out


class PolygonBox:
    """A closed polygon set: a box of six quadrilaterals."""

    def __init__(self, lo, hi):
        self.lo, self.hi = np.asarray(lo, float), np.asarray(hi, float)
        v, quads = box_mesh(lo, hi)
        self.quads = [v[list(q)] for q in quads]

    def add_to(self, g):
        for q in self.quads:
            g.polygons.add(q, 0)

    def crossings(self, o, d):
        out = []
        for axis in range(3):
            if d[axis] == 0:
                continue
            for plane in (self.lo[axis], self.hi[axis]):
                t = (plane - o[axis]) / d[axis]
                p = o + t * d
                others = [k for k in range(3) if k != axis]
                if all(self.lo[k] <= p[k] <= self.hi[k] for k in others):
                    out.append(t)
        return out


class Placed:
    """A solid seen through an affine map (an Instance): the line mapped, t unchanged."""

    def __init__(self, solid, matrix):
        self.solid, self.m = solid, matrix
        self.inv = np.linalg.inv(matrix)

    def add_to(self, g):
        inner = Group(name="placed")
        self.solid.add_to(inner)
        g.add(Instance(inner, self.m))

    def crossings(self, o, d):
        return self.solid.crossings(self.inv[:3, :3] @ o + self.inv[:3, 3], self.inv[:3, :3] @ d)


class Node:
    """A CSG node: op over operands (solids or nodes); for difference the first `base` are the base."""

    def __init__(self, op, operands, base=1):
        self.op, self.operands, self.base = op, operands, base

    def group(self, operand_spec=None):
        g = Group(name=self.op, accel=f"difference(base={self.base})" if self.op == "difference" else self.op)
        for x in self.operands:
            if isinstance(x, Node):
                g.add(x.group(operand_spec))
            else:
                child = Group(name="operand", accel=operand_spec)
                x.add_to(child)
                g.add(child)
        return g

    def inside(self, states):
        if self.op == "difference":
            return any(states[:self.base]) and not any(states[self.base:])
        if self.op == "intersection":
            return all(states)
        return any(states)

    def transitions(self, o, d):
        """(t, entering) where the line crosses the result's surface, in order."""
        lists = [x.transitions(o, d) if isinstance(x, Node) else [(t, None) for t in sorted(x.crossings(o, d))]
                 for x in self.operands]
        events = sorted((t, k) for k, lst in enumerate(lists) for t, _ in lst)
        states = [False] * len(self.operands)
        now, out = False, []
        for t, k in events:
            states[k] = not states[k]
            new = self.inside(states)
            if new != now:
                out.append((t, new))
                now = new
        return out


def random_solid(rng, scale=1.0, spread=1.0):
    """A sphere, a mesh box, a polygon box or an ellipsoid (an instanced sphere) at random."""
    c = rng.uniform(-1, 1, 3) * scale * spread
    kind = rng.integers(4)
    if kind == 0:
        return Sphere(c, rng.uniform(0.4, 1.2) * scale)
    half = rng.uniform(0.3, 1.0, 3) * scale
    if kind == 1:
        return MeshBox(c - half, c + half)
    if kind == 2:
        return PolygonBox(c - half, c + half)
    a = np.linalg.qr(rng.normal(size=(3, 3)))[0] @ np.diag(rng.uniform(0.5, 1.5, 3))
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = a, c
    return Placed(Sphere(np.zeros(3), rng.uniform(0.4, 1.0) * scale), m)


def random_tree(rng, depth=2, scale=1.0, spread=1.0):
    """A random CSG Node of 2 or 3 operands: random_solid ones, or (above depth 1) subtrees."""
    op = ("difference", "intersection", "union")[rng.integers(3)]
    n = int(rng.integers(2, 4))
    operands = [random_tree(rng, depth - 1, scale, spread) if depth > 1 and rng.uniform() < 0.35 else
                random_solid(rng, scale, spread) for _ in range(n)]
    return Node(op, operands, base=int(rng.integers(1, n)) if op == "difference" else n)


def rays_at_solids(rng, n, scale=1.0):
    """(origins, directions) of n rays from a sphere of radius 4 scale (the middle third from inside
    the box +-scale) towards points of the box +-0.8 scale."""
    o = rng.normal(size=(n, 3))
    o = 4 * scale * o / np.linalg.norm(o, axis=1)[:, None]
    o[n // 3:2 * n // 3] = rng.uniform(-scale, scale, (2 * n // 3 - n // 3, 3))    # some start inside
    d = rng.uniform(-0.8, 0.8, (n, 3)) * scale - o
    return o, d


# ---------------------------------------------------------------- closed meshes with dyadic vertices

DYADIC = 2.0 ** -20     # the meshes' vertex coordinates are multiples of this


def dyadic(x):
    """x rounded to multiples of DYADIC."""
    return np.round(np.asarray(x, float) / DYADIC) * DYADIC


def icosphere(level: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit icosphere (subdivided icosahedron), outward winding, vertices rounded to dyadic numbers."""
    p = (1 + 5 ** 0.5) / 2
    v = [(-1, p, 0), (1, p, 0), (-1, -p, 0), (1, -p, 0), (0, -1, p), (0, 1, p), (0, -1, -p), (0, 1, -p),
         (p, 0, -1), (p, 0, 1), (-p, 0, -1), (-p, 0, 1)]
    f = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2), (10, 7, 6),
         (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10),
         (8, 6, 7), (9, 8, 1)]
    verts = [np.array(x, float) / np.linalg.norm(x) for x in v]
    faces = f
    for _ in range(level):
        mid = {}

        def middle(a, b):
            key = (min(a, b), max(a, b))
            if key not in mid:
                m = verts[a] + verts[b]
                verts.append(m / np.linalg.norm(m))
                mid[key] = len(verts) - 1
            return mid[key]
        new = []
        for a, b, c in faces:
            ab, bc, ca = middle(a, b), middle(b, c), middle(c, a)
            new += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = new
    return dyadic(np.array(verts)), np.array(faces, np.int64)


def cube() -> tuple[np.ndarray, np.ndarray]:
    """The cube [-1, 1]^3 as 12 outward-wound triangles (each face split along a diagonal)."""
    v = np.array([(x, y, z) for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (-1.0, 1.0)])
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    faces = []
    for a, b, c, d in quads:
        faces += [(a, b, c), (a, c, d)]
    faces = np.array(faces, np.int64)
    n = np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]])
    centroid = v[faces].mean(axis=1)
    flip = np.einsum("ij,ij->i", n, centroid) < 0
    faces[flip] = faces[flip][:, ::-1]
    return v, faces


def lumpy_sphere(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A closed, non-convex, star-shaped mesh: an icosphere with random radii."""
    v, f = icosphere(2)
    r = np.random.default_rng(seed).uniform(0.6, 1.4, len(v))
    return dyadic(v * r[:, None]), f


def targets(v, f, rng, n_edge_points=3):
    """Every vertex, and points on every edge at dyadic fractions (exactly representable)."""
    pts = [v]
    edges = np.unique(np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1), axis=0)
    for _ in range(n_edge_points):
        s = rng.integers(1, 16, len(edges)) / 16.0
        pts.append(v[edges[:, 0]] + s[:, None] * (v[edges[:, 1]] - v[edges[:, 0]]))
    return np.vstack(pts)


def rays_through(points, inside, scale=2.0):
    """Rays through each point towards `inside`, starting `scale` direction-lengths before it."""
    d = inside - points
    o = points - scale * d
    assert np.all(o + scale * d == points), "targets must be exactly on the rays"
    return o, d


# name -> (vertices, faces) of closed meshes: a cube, an icosphere and two lumpy spheres
MESHES = {"cube": cube(), "icosphere": icosphere(3), "lumpy-0": lumpy_sphere(0), "lumpy-1": lumpy_sphere(1)}


# ---------------------------------------------------------------- walking a scene's groups

def child(group: Group, name: str) -> Group:
    """The one child group of `group` named `name` (an assertion error if there is not exactly one)."""
    found = [c for c in group.children if isinstance(c, Group) and c.name == name]
    assert len(found) == 1, f"no single child group {name!r} in {[c.name for c in group.children]}"
    return found[0]


def groups(group: Group, seen=None):
    """The group and every group below it, instanced ones once (the park instances some)."""
    seen = set() if seen is None else seen
    yield group
    for c in group.children:
        g = c.group if isinstance(c, Instance) else c
        if id(g) not in seen:
            seen.add(id(g))
            yield from groups(g, seen)


def points(group: Group) -> np.ndarray:
    """Every vertex, and the extreme points of spheres and cones, of `group` and below."""
    out = [np.zeros((0, 3))]
    for g in groups(group):
        s = g.spheres.freeze()
        for c, r in zip(s.center, np.abs(s.radius)):
            out.append(c + r * np.vstack([np.eye(3), -np.eye(3)]))
        c = g.cones.freeze()
        r = np.maximum(np.abs(c.base_radius), np.abs(c.apex_radius))[:, None]
        for box in (c.base - r, c.base + r, c.apex - r, c.apex + r):
            out.append(box)
        out += [g.polygons.freeze().vertices, g.patches.freeze().vertices]
        out += [m.vertices for m in g.meshes]
    return np.vstack(out)


def world_corners(group: Group, matrix=None, out=None) -> list:
    """Vertices of every polygon, patch and mesh triangle reachable from `group`, in world space,
    as (k, 3) arrays of one polygon or triangle each."""
    out = [] if out is None else out
    m = np.eye(4) if matrix is None else matrix
    for s in group.primitive_sets():
        if isinstance(s, Polygons):
            for i in range(len(s)):
                out.append(s.polygon(i)[0] @ m[:3, :3].T + m[:3, 3])
        elif isinstance(s, TriangleMesh):
            for f in s.faces:
                out.append(s.vertices[f] @ m[:3, :3].T + m[:3, 3])
    for c in group.children:
        if isinstance(c, Instance):
            world_corners(c.group, m @ c.matrix, out)
        else:
            world_corners(c, m, out)
    return out


def stadium_rays(scene: Scene, rng, n: int):
    """(origins, directions, tmin, tmax) of n rays into pathological.stadium: camera rays over the
    view, rays from the stands and the sky aimed at teapot vertices and edge midpoints, and
    axis-parallel rays down onto the teapot and along the field."""
    teapot = next(g for g in scene.root.children if isinstance(g, Group) and g.name == "teapot")
    corners = world_corners(teapot)
    pts = np.array([p[j] for p in corners for j in range(len(p))])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    k = n // 4
    cam = scene.camera
    forward, right, up = cam.basis()
    spread = np.tan(np.radians(cam.angle) / 2)
    u, v = rng.uniform(-spread, spread, (2, k))
    d1 = forward + u[:, None] * right + v[:, None] * up
    o1 = np.tile(cam.eye, (k, 1))
    pick = [corners[j] for j in rng.integers(0, len(corners), k)]
    target = np.array([0.5 * (p[0] + p[j]) if j else p[0] for p in pick for j in [rng.integers(len(p))]])
    o2 = rng.uniform([-150, -210, 0.5], [450, 210, 80], (k, 3))
    d2 = target - o2
    o3 = np.column_stack([rng.uniform(lo[0], hi[0], k), rng.uniform(lo[1], hi[1], k), np.full(k, 200.0)])
    d3 = np.tile([0.0, 0.0, -1.0], (k, 1))
    o4 = np.column_stack([np.full(n - 3 * k, -149.0), rng.uniform(lo[1], hi[1], n - 3 * k),
                          rng.uniform(lo[2], hi[2], n - 3 * k)])
    d4 = np.tile([1.0, 0.0, 0.0], (n - 3 * k, 1))
    return np.vstack([o1, o2, o3, o4]), np.vstack([d1, d2, d3, d4]), 0.0, np.inf


# ---------------------------------------------------------------- small hand-made scenes and their counts

def make_scene(eye=(0.0, -5.0, 0.0), look_at=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0), angle=45.0,
               size=1, background=(0.0, 0.0, 0.0)) -> Scene:
    """An empty scene with a square `size` x `size` camera."""
    return Scene(camera=Camera(eye=eye, look_at=look_at, up=up, angle=angle, hither=0.0,
                               width=size, height=size),
                 background=background)


def add_sphere(scene: Scene, center, radius, **material) -> int:
    """A sphere in the root with a material of its own (Material(**material)); that material's index."""
    m = scene.add_material(Material(**material))
    scene.root.spheres.add(center, radius, m)
    return m


def add_polygon(scene: Scene, vertices, **material) -> int:
    """A polygon in the root with a material of its own (Material(**material)); that material's index."""
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


def entered_masks(scene, accel, resolution, boxes_wanted, frozen=None):
    """The explorer's brute-force check: which samples' walks entered each box, every sample
    traced alone into zeroed box counters; and the visits of a whole TILE x TILE tile traced as
    a render traces it, for the tile sums. (bool masks (boxes, h, w), first tile's visits).
    frozen: the render job of a lazy structure, traced as that render left it."""
    from raykernel.explorer.model import sample_job
    from raykernel.rendering.structure import box_rows, boxes_of
    job, (tiles_x, tiles_y), _ = sample_job(scene, accel, resolution, frozen=frozen)
    n = len(job.tile_x)
    rows = box_rows(boxes_of(job.geo), job.probe)[boxes_wanted]
    masks = np.zeros((len(boxes_wanted), n), bool)
    for k in range(n):
        job.probe.counts[:] = 0
        job.trace(0, k, k + 1, 1)
        masks[:, k] = job.probe.counts[rows, 0] > 0
    # the first tile as a render traces it: its visits are the samples' sums
    job.tile_x, job.tile_y = tiles_x, tiles_y
    job.passes, job.work, job.pass_counts = [(1, 0, 0, len(tiles_x))], [len(tiles_x)], [None]
    job.counts = np.zeros((len(tiles_x), job.counts.shape[1]), np.int64)
    job.probe.counts[:] = 0
    job.trace(0, 0, 1, 1)
    return masks.reshape(len(boxes_wanted), job.sh, job.sw), job.probe.counts[rows, 0]


# ---------------------------------------------------------------- headless Chromium

def headless_chromium(window: str, logs: tuple = ("browser",)):
    """A selenium driver of headless Chromium with a window of `window` ("W,H") that keeps the
    log types `logs`; the test is skipped where chromium, chromium-driver or selenium are missing."""
    import shutil
    chromium = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
    driver = shutil.which("chromedriver")
    if not (chromium and driver):
        pytest.skip("headless Chromium needs the chromium and chromium-driver packages")
    webdriver = pytest.importorskip("selenium.webdriver")
    options = webdriver.ChromeOptions()
    options.binary_location = chromium
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", f"--window-size={window}"):
        options.add_argument(arg)
    options.set_capability("goog:loggingPrefs", {kind: "ALL" for kind in logs})
    return webdriver.Chrome(options=options, service=webdriver.ChromeService(executable_path=driver))

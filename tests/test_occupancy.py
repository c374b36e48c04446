"""contains on closed meshes through the occupancy grid (casting/occupancy.py), against a brute-force
crossing count in numpy and against the ray cast alone."""

from __future__ import annotations

import numpy as np
import pytest

trimesh = pytest.importorskip("trimesh")

from raykernel import RayScene  # noqa: E402
from raykernel.casting.occupancy import occupancy_grid  # noqa: E402
from raykernel.casting.proximity import is_closed, occupancy, parity_directions  # noqa: E402

DIRECTION = np.array([0.5123987, 0.3321741, 0.7917531])


def brute_inside(vertices, faces, points):
    """Odd number of triangles crossed by a ray from each point (Moller-Trumbore over every triangle)."""
    tri = vertices[faces]
    a, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    d = DIRECTION / np.linalg.norm(DIRECTION)
    p = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, p)
    out = np.zeros(len(points), bool)
    for k, o in enumerate(points):
        s = o - a
        u = np.einsum("ij,ij->i", s, p) / det
        q = np.cross(s, e1)
        v = (q @ d) / det
        t = np.einsum("ij,ij->i", e2, q) / det
        out[k] = np.count_nonzero((u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)) % 2 == 1
    return out


def shell():
    """A sphere with a spherical cavity: the cavity is outside the solid, enclosed by it."""
    outer = trimesh.creation.icosphere(subdivisions=3)
    inner = trimesh.creation.icosphere(subdivisions=3)
    inner.vertices *= 0.5
    inner.invert()
    return trimesh.util.concatenate([outer, inner])


MESHES = {
    "icosphere": lambda: trimesh.creation.icosphere(subdivisions=3),
    "torus": lambda: trimesh.creation.torus(major_radius=1.0, minor_radius=0.3, major_sections=48, minor_sections=24),
    "box": lambda: trimesh.creation.box(extents=(2.0, 1.0, 0.5)),
    "two spheres": lambda: trimesh.util.concatenate([trimesh.creation.icosphere(subdivisions=2),
                                                     trimesh.creation.icosphere(subdivisions=2).apply_translation((2.05, 0, 0))]),
    "shell": shell,
}


def points_around(mesh, n, seed):
    lo, hi = mesh.bounds
    rng = np.random.default_rng(seed)
    return rng.uniform(lo - 0.1 * (hi - lo), hi + 0.1 * (hi - lo), (n, 3))


@pytest.mark.parametrize("name", MESHES)
@pytest.mark.parametrize("scale", [1e-6, 1.0, 1e7])
def test_contains_matches_a_brute_force_crossing_count(name, scale):
    mesh = MESHES[name]()
    mesh.vertices *= scale
    p = points_around(mesh, 1500, 7)
    rs = RayScene.from_trimesh(mesh)
    assert is_closed(rs)
    got = rs.contains(p)
    assert rs._grid.lookup(p)[1].any(), "the grid answered no point"
    np.testing.assert_array_equal(got, brute_inside(np.asarray(mesh.vertices), np.asarray(mesh.faces), p))


@pytest.mark.parametrize("name", MESHES)
def test_the_grid_gives_the_ray_cast_s_answer_on_every_point(name):
    mesh = MESHES[name]()
    rs = RayScene.from_trimesh(mesh)
    lo, hi = mesh.bounds
    p = np.concatenate([points_around(mesh, 20000, 3), mesh.vertices, mesh.triangles_center,
                        np.array([lo, hi, (lo + hi) / 2, [lo[0], hi[1], lo[2]]])])
    box = np.concatenate([lo, hi])
    cast = rs.count_hits(p, parity_directions(p, box)) % 2 == 1
    np.testing.assert_array_equal(rs.contains(p), cast)


def test_an_enclosed_cavity_is_outside_and_the_torus_hole_too():
    rs = RayScene.from_trimesh(shell())
    inside, known = occupancy(rs, lambda q: rs.count_hits(q, parity_directions(q, np.array([-1, -1, -1, 1, 1, 1.0]))) % 2 == 1).lookup(
        np.array([[0.0, 0, 0], [0.75, 0, 0], [0, 0, 0.1]]))
    assert known.all()
    assert list(inside) == [False, True, False]
    torus = trimesh.creation.torus(major_radius=1.0, minor_radius=0.3, major_sections=48, minor_sections=24)
    assert list(RayScene.from_trimesh(torus).contains(np.array([[0.0, 0, 0], [1.0, 0, 0], [0, 1.0, 0.29]]))) \
        == [False, True, True]


def test_points_in_touched_cells_are_left_to_their_rays():
    mesh = trimesh.creation.icosphere(subdivisions=3)
    calls = []

    def classify(q):
        calls.append(len(q))
        return np.linalg.norm(q, axis=1) < 0.985       # an unmarked cell's centre is half a cell from the surface
    grid = occupancy_grid(mesh.vertices, mesh.faces, classify)
    assert calls == [len(grid.inside)] and len(grid.inside) == 2          # outside and inside, one ray each
    inside, known = grid.lookup(np.concatenate([mesh.vertices, mesh.triangles_center]))
    assert not known.any()                                                  # every surface point is in a marked cell
    inside, known = grid.lookup(np.array([[0.0, 0, 0], [5.0, 0, 0], [-5.0, 2, 1]]))
    assert known.all() and list(inside) == [True, False, False]


def test_a_grid_with_every_cell_marked_still_answers_by_rays():
    """A slab thinner than a cell: no unmarked cell inside it, every point inside is cast."""
    mesh = trimesh.creation.box(extents=(10.0, 10.0, 1e-4))
    rs = RayScene.from_trimesh(mesh)
    p = np.array([[0.0, 0, 0], [1.0, 2.0, 3e-5], [1.0, 2.0, 1e-3], [20.0, 0, 0]])
    assert list(rs.contains(p)) == [True, True, False, False]


def test_an_open_mesh_does_not_use_the_grid():
    mesh = trimesh.creation.icosphere(subdivisions=2)
    mesh.update_faces(np.arange(len(mesh.faces)) != 0)
    rs = RayScene.from_trimesh(mesh)
    rs.contains(np.zeros((3, 3)), method="parity")
    assert not hasattr(rs, "_grid")

"""Point queries (casting/proximity.py) against brute force: closest points, distances, inside tests."""

from __future__ import annotations

import numpy as np
import pytest

from raykernel import Group, Instance, RayInputError, RayScene, Scene, TriangleMesh

trimesh = pytest.importorskip("trimesh")


def brute_distance_triangles(p, tri):
    """Distance of points p (N, 3) to triangles tri (T, 3, 3): the plane's foot where it falls in
    the triangle (barycentric coordinates by least squares), else the nearest edge point."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1)[:, None]
    h = np.einsum("ptk,tk->pt", p[:, None, :] - a[None], n)
    foot = p[:, None, :] - h[..., None] * n[None]
    # barycentric coordinates of the foot
    v0, v1 = b - a, c - a
    w = foot - a[None]
    d00, d01, d11 = (v0 * v0).sum(1), (v0 * v1).sum(1), (v1 * v1).sum(1)
    d20, d21 = (w * v0[None]).sum(2), (w * v1[None]).sum(2)
    den = d00 * d11 - d01 * d01
    v = (d11 * d20 - d01 * d21) / den
    u = (d00 * d21 - d01 * d20) / den
    inside = (v >= 0) & (u >= 0) & (u + v <= 1)
    best = np.where(inside, np.abs(h), np.inf)
    for s, e in ((a, b), (b, c), (c, a)):
        ex = e - s
        t = np.clip(np.einsum("ptk,tk->pt", p[:, None, :] - s[None], ex) / (ex * ex).sum(1), 0, 1)
        q = s[None] + t[..., None] * ex[None]
        best = np.minimum(best, np.linalg.norm(p[:, None, :] - q, axis=2))
    return best.min(axis=1), best.argmin(axis=1)


def query_points(mesh, rng, n=600):
    """Points near and far, inside, and exactly on faces, edges and vertices of the mesh."""
    lo, hi = mesh.bounds
    c, size = (lo + hi) / 2, (hi - lo).max()
    tri = mesh.triangles
    k = n // 6
    pick = rng.integers(0, len(tri), 3 * k)
    bary = rng.dirichlet([1, 1, 1], k)
    on_face = np.einsum("pk,pkd->pd", bary, tri[pick[:k]])
    s = rng.uniform(0, 1, (k, 1))
    on_edge = (1 - s) * tri[pick[k:2 * k], 0] + s * tri[pick[k:2 * k], 1]
    on_vertex = tri[pick[2 * k:], rng.integers(0, 3, k)]
    near = c + rng.uniform(-0.8, 0.8, (2 * k, 3)) * size
    far = c + rng.normal(size=(n - 5 * k, 3)) * 1e3 * size
    return np.vstack([on_face, on_edge, on_vertex, near, far])


@pytest.mark.parametrize("name", ["icosphere", "box", "torus"])
def test_closest_points_of_a_mesh_match_brute_force(name):
    mesh = {"icosphere": trimesh.creation.icosphere(subdivisions=2), "box": trimesh.creation.box((1, 2, 3)),
            "torus": trimesh.creation.torus(major_radius=1.0, minor_radius=0.3)}[name]
    rng = np.random.default_rng(3)
    p = query_points(mesh, rng)
    rs = RayScene.from_trimesh(mesh)
    near = rs.closest_points(p)
    want, which = brute_distance_triangles(p, mesh.triangles)
    scale = np.abs(p).max(axis=1)
    np.testing.assert_allclose(near.distance, want, rtol=1e-9, atol=1e-12 * scale.max())
    # the point returned is that far, and on the triangle it names
    np.testing.assert_allclose(np.linalg.norm(near.points - p, axis=1), near.distance, rtol=1e-9, atol=1e-12)
    tri = mesh.triangles[near.prim_id]
    for k in range(0, len(p), 37):
        d, _ = brute_distance_triangles(near.points[k:k + 1], tri[k:k + 1])
        assert d[0] <= 1e-9 * max(1.0, scale[k])
    # points on the surface are at distance 0 (faces, edges, vertices: the first half)
    assert np.all(near.distance[:300] <= 1e-12)
    assert near.geom_id.tolist() == [0] * len(p) and near.kind.tolist() == [4] * len(p)
    np.testing.assert_allclose(np.linalg.norm(near.normal, axis=1), 1.0)
    np.testing.assert_array_equal(rs.distance(p), near.distance)
    assert len(which) == len(p)


def test_closest_points_on_spheres_polygons_and_a_concave_polygon():
    s = Scene()
    s.root.spheres.add((0, 0, 0), 1.0, 0)
    s.root.spheres.add((5, 0, 0), 0.5, 0)
    # an L-shaped (concave) polygon in the plane z = 3
    s.root.polygons.add(np.array([[0, 0, 3.0], [2, 0, 3], [2, 1, 3], [1, 1, 3], [1, 2, 3], [0, 2, 3]]), 0)
    rs = RayScene(s)
    p = np.array([[0, 0, 0.0], [3, 0, 0], [0, 0, -4], [5, 0, 2], [1.5, 1.5, 3.5], [0.5, 0.5, 4], [1.5, 0.5, 2.0]])
    near = rs.closest_points(p)
    np.testing.assert_allclose(near.distance, [1.0, 1.5, 3.0, 1.5, np.sqrt(0.5), 1.0, 1.0])
    # (1.5, 1.5, 3.5) lies above the notch: two edges are as near; the first in the polygon's order wins
    np.testing.assert_allclose(near.points[4], [1.5, 1.0, 3.0])
    np.testing.assert_allclose(near.points[5], [0.5, 0.5, 3.0])
    assert near.kind.tolist() == [0, 0, 0, 0, 1, 1, 1]
    np.testing.assert_allclose(near.points[3], [5, 0, 0.5])
    np.testing.assert_allclose(near.normal[3], [0, 0, 1])


def test_contains_and_signed_distance_on_closed_meshes():
    rng = np.random.default_rng(8)
    box = trimesh.creation.box((1, 2, 3))
    torus = trimesh.creation.torus(major_radius=1.0, minor_radius=0.3, major_sections=64, minor_sections=32)
    for mesh, inside_fn in ((box, lambda q: np.all(np.abs(q) < [0.5, 1, 1.5], axis=1)),
                            (torus, lambda q: (np.hypot(q[:, 0], q[:, 1]) - 1) ** 2 + q[:, 2] ** 2 < 0.3 ** 2)):
        rs = RayScene.from_trimesh(mesh)
        p = rng.uniform(mesh.bounds[0] - 0.3, mesh.bounds[1] + 0.3, (3000, 3))
        d = rs.distance(p)
        clear = d > 0.02          # the tessellated torus differs from the analytic one near its surface
        got = rs.contains(p)
        np.testing.assert_array_equal(got[clear], inside_fn(p)[clear])
        assert 0.05 < got.mean() < 0.9
        sd = rs.signed_distance(p)
        np.testing.assert_array_equal(np.abs(sd), d)
        np.testing.assert_array_equal(sd < 0, got & (d > 0))
    # axis-parallel points on a grid: rays in the fixed directions still vote right
    grid = np.stack(np.meshgrid(*[np.linspace(-0.45, 0.45, 7)] * 3), -1).reshape(-1, 3)
    assert RayScene.from_trimesh(box).contains(grid).all()


def test_contains_spheres_and_shapes():
    rs = RayScene.from_spheres([(0, 0, 0), (3, 0, 0)], [1.0, 0.5])
    p = np.array([[[0.5, 0, 0], [3.2, 0, 0]], [[2.0, 0, 0], [0, 0, 1.5]]])
    assert rs.contains(p).tolist() == [[True, True], [False, False]]
    np.testing.assert_allclose(rs.signed_distance(p), [[-0.5, -0.3], [0.5, 0.5]])
    assert rs.closest_points(p).points.shape == (2, 2, 3)


def test_point_queries_refuse_what_they_cannot_answer():
    g = Group(name="g")
    g.add(TriangleMesh(np.eye(3), np.array([[0, 1, 2]])))
    s = Scene()
    s.root.add(Instance(g, np.eye(4)))
    rs = RayScene(s)
    with pytest.raises(RayInputError, match="instances"):
        rs.closest_points([0, 0, 0])
    with pytest.raises(RayInputError, match="instances"):
        rs.contains([0, 0, 0])
    with pytest.raises(RayInputError, match="points must have shape"):
        RayScene.from_spheres([(0, 0, 0)], 1.0).distance(np.zeros((4, 2)))
    empty = RayScene(Scene()).closest_points(np.zeros((2, 3)))
    assert np.isinf(empty.distance).all() and (empty.prim_id == -1).all()

"""Watertight ray/triangle tests: rays aimed exactly at shared vertices and
edges of closed meshes are never missed and never counted twice.

Every mesh has dyadic coordinates and every ray has a dyadic origin and
direction chosen so that the ray passes exactly (in real arithmetic) through
its target vertex or edge point, heading into the solid: a ray entering a
closed surface crosses it an even number of times, exactly twice for a
convex one, and its first crossing is the target itself. The meshes (MESHES, in
support.py) have their vertex coordinates on multiples of 2^-20.
"""

from __future__ import annotations

import numpy as np
import pytest
from reference import all_hits, world_primitives
from support import MESHES, lumpy_sphere, rays_through, targets

from raykernel import RayScene
from raykernel.geometry.primitives import hit_triangle


def assert_closed(faces):
    """Every edge of the faces is met once in each direction: a closed, consistently wound surface."""
    edges = {}
    for a, b, c in faces:
        for e in ((a, b), (b, c), (c, a)):
            edges[e] = edges.get(e, 0) + 1
    assert all(n == 1 and edges.get((b, a)) == 1 for (a, b), n in edges.items())


@pytest.mark.parametrize("accel", ["bvh", "list", "grid", "bvh(split=8)"])
@pytest.mark.parametrize("name", list(MESHES))
def test_rays_through_shared_vertices_and_edges(name, accel):
    v, f = MESHES[name]
    assert_closed(f)
    rng = np.random.default_rng(7)
    pts = targets(v, f, rng)
    inside = np.array([2.0 ** -5, -3 * 2.0 ** -7, 2.0 ** -6])      # off-centre, to avoid symmetric lines
    o, d = rays_through(pts, inside)
    scene = RayScene.from_mesh(v, f, accel=accel)
    hits = scene.intersect(o, d)
    assert np.all(np.isfinite(hits.t)), f"{np.sum(~np.isfinite(hits.t))} rays missed the closed mesh"
    # the target is the first crossing for a star-shaped mesh seen from outside along a ray to its centre
    np.testing.assert_allclose(hits.t, 2.0, rtol=1e-12)
    counts = scene.count_hits(o, d)
    ray, t, prim = scene.intersect_all(o, d)
    assert np.array_equal(np.bincount(ray, minlength=len(o)), counts)
    assert np.all(counts % 2 == 0), "an odd number of crossings of a closed surface"
    if name in ("cube", "icosphere"):
        assert np.all(counts == 2), f"convex mesh: {np.sum(counts > 2)} double hits, {np.sum(counts < 2)} misses"
    else:
        assert np.all(counts >= 2)
    # no primitive twice for one ray
    assert len(np.unique(np.stack([ray, prim]), axis=1)[0]) == len(ray)
    # the first hit of intersect_all is the closest hit
    first = np.r_[0, np.flatnonzero(np.diff(ray)) + 1]
    assert np.array_equal(t[first], hits.t)


def test_axis_aligned_rays_through_a_grid_of_triangles():
    """Rays along -z through every vertex and edge of an 8x8 grid of triangle pairs in z = 0:
    each meets exactly one triangle (the list aggregate: no box test below the root)."""
    n = 8
    xs = np.arange(n + 1) / n
    v = np.array([(x, y, 0.0) for y in xs for x in xs])
    f = []
    for j in range(n):
        for i in range(n):
            a = j * (n + 1) + i
            f += [(a, a + 1, a + n + 2), (a, a + n + 2, a + n + 1)]
    scene = RayScene.from_mesh(v, np.array(f), accel="list")
    g = np.arange(1, 2 * n) / (2 * n)
    pts = np.array([(x, y) for x in g for y in g])
    o = np.column_stack([pts, np.full(len(pts), 1.0)])
    counts = scene.count_hits(o, (0.0, 0.0, -1.0))
    assert np.all(counts == 1)
    # the same with a slanted direction
    d = np.array([2.0 ** -3, -(2.0 ** -4), -1.0])
    counts = scene.count_hits(np.column_stack([pts, np.zeros(len(pts))]) - d, d)
    assert np.all(counts == 1)


def test_shared_edge_and_vertex_of_two_triangles_exactly_one():
    # two triangles sharing the diagonal (0,0)-(1,1); rays through the diagonal and the shared corners
    tri_a = [(0, 0, 0), (1, 0, 0), (1, 1, 0)]
    tri_b = [(0, 0, 0), (1, 1, 0), (0, 1, 0)]
    for d in [(0.0, 0.0, -1.0), (0.25, 0.125, -1.0), (-0.5, 0.25, 1.0)]:
        for p in [(0.5, 0.5), (0.25, 0.25), (0.0, 0.0), (1.0, 1.0), (0.75, 0.75)]:
            o = (p[0] - d[0], p[1] - d[1], -d[2])
            n = sum(np.isfinite(hit_triangle(*np.ravel(np.array(tri, float)), *o, *d, 0.0, np.inf)) for tri in (tri_a, tri_b))
            inside_hull = p not in ((0.0, 0.0), (1.0, 1.0))
            assert n == 1 if inside_hull else n <= 1, (d, p, n)


def test_random_rays_agree_with_the_reference():
    v, f = lumpy_sphere(3)
    scene = RayScene.from_mesh(v, f)
    prims = world_primitives(scene.scene)
    rng = np.random.default_rng(11)
    o = rng.uniform(-2, 2, (300, 3))
    d = rng.normal(size=(300, 3))
    ref = all_hits(prims, o, d).astype(float)
    counts = np.isfinite(ref).sum(axis=0)
    assert np.array_equal(scene.count_hits(o, d), counts)
    np.testing.assert_allclose(scene.intersect(o, d).t, ref.min(axis=0), rtol=1e-9)
    outside = np.linalg.norm(o, axis=1) > 1.5
    assert outside.sum() > 50 and np.all(counts[outside] % 2 == 0)


# ---------------------------------------------------------------- inclusive edges: grazing rays hit, once

@pytest.mark.parametrize("accel", ["bvh", "grid", "octree", "bvh(split=8)"])
def test_inclusive_edges_report_grazing_rays_once(accel):
    import trimesh

    from raykernel import RayInputError, RayScene
    box = trimesh.creation.box()              # [-0.5, 0.5]^3 in 12 triangles
    rs = RayScene.from_trimesh(box, accel=accel, edges="inclusive")
    tight = RayScene.from_trimesh(box, accel=accel)
    o = np.array([[0.5, -3, 0.1],        # in the plane of the side face x = 0.5
                  [0.5, -3, 0.5],        # along the silhouette edge x = z = 0.5
                  [1.5, 0.5, 0.0],       # grazing the vertical edge x = 0.5, y = -0.5 at one point
                  [0.1, 0.1, 3.0]])      # down through the diagonal of the top face (two triangles at once)
    d = np.array([[0, 1.0, 0], [0, 1.0, 0], [-1.0, -1.0, 0], [0.2 - 0.1, 0.2 - 0.1, 0.5 - 3.0]])
    ray, t, prim = rs.intersect_all(o, d)
    got = {r: t[ray == r].tolist() for r in range(4)}
    assert got[0] == [2.5, 3.5] and got[1] == [2.5, 3.5] and got[2] == [1.0]
    assert got[3][0] == pytest.approx(1.0) and len(got[3]) == 2      # the top face once, then the bottom
    np.testing.assert_array_equal(rs.count_hits(o, d), [2, 2, 1, 2])
    h = rs.intersect(o, d)
    assert h.hit.all() and h.t[0] == 2.5 and h.t[2] == 1.0
    # the watertight rule keeps a closed mesh's parity instead: never one crossing on a graze
    assert all(c % 2 == 0 for c in tight.count_hits(o, d))
    # away from edges both rules agree
    rng = np.random.default_rng(1)
    ro = rng.normal(0, 2, (3000, 3))
    rd = rng.uniform(-0.4, 0.4, (3000, 3)) - ro
    np.testing.assert_array_equal(rs.count_hits(ro, rd), tight.count_hits(ro, rd))
    np.testing.assert_array_equal(rs.intersect(ro, rd).t, tight.intersect(ro, rd).t)
    with pytest.raises(RayInputError, match="edges must be one of"):
        RayScene.from_trimesh(box, edges="loose")

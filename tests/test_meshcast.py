"""The mesh fast path of RayScene against the generic kernel, and geometry identities.

The fast kernel (meshcast.py) on the binary tree (bvh(width=2)) must give
exactly what the generic traversal gives on the same BVH: the same t,
identities, surfaces and counters, bit for bit, for every query kind. On the
4-wide tree (the default) the hits, surfaces and ray counts are the same and
only the walk's own counters (nodes, box tests, triangle tests and how many of those hit: the
closest hit so far depends on the order) differ.
"""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest
from numba import njit
from support import MESHES, rays_through, targets

from raykernel import Group, Instance, RayScene, Scene, TriangleMesh
from raykernel.aggregates.widebvh import CHILD, COUNT, _down, _up, box4_entries, collapse, wide_ray
from raykernel.geometry.boxes import box_entry, inverse
from raykernel.geometry.primitives import SPHERE, TRIANGLE

WALK = ("bounds.tests", "cells.visited", "cells.leaves", "tests.triangle", "hits.triangle", "walk.bvh.bounds",
        "walk.bvh.steps")


def generic(scene: RayScene) -> RayScene:
    """The same scene with the fast path switched off."""
    other = copy.copy(scene)
    other._mesh = None
    return other


def binary(scene: RayScene) -> RayScene:
    """The same scene cast through the mesh kernel on the binary tree."""
    return RayScene(scene.scene, "bvh(width=2)", edges=scene.edges)


def _run(scene, query, o, d, tmin, tmax):
    out = getattr(scene, query)(o, d, tmin, tmax)
    return out, {k: v for k, v in scene.last_stats.items() if not k.startswith("time.")}


def _same_output(query, a, b):
    if query == "intersect":
        for field in ("t", "prim_id", "geom_id", "inst_id", "kind", "uv", "normal", "shading_normal"):
            assert np.array_equal(getattr(a, field), getattr(b, field), equal_nan=True), field
    elif query == "intersect_all":
        for x, y in zip(a, b):
            assert np.array_equal(x, y)
    else:
        assert np.array_equal(a, b)


def assert_same_queries(scene: RayScene, o, d, tmin=0.0, tmax=np.inf):
    """The wide kernel, the binary mesh kernel and the generic kernel agree on every query;
    the binary mesh kernel and the generic one on every counter too."""
    assert scene._mesh is not None and len(scene._mesh.wide.nodes), "this scene should take the wide fast path"
    narrow = binary(scene)
    slow = generic(narrow)
    for query in ("intersect", "occluded", "count_hits", "intersect_all"):
        wide_out, wide_stats = _run(scene, query, o, d, tmin, tmax)
        fast_out, fast_stats = _run(narrow, query, o, d, tmin, tmax)
        slow_out, slow_stats = _run(slow, query, o, d, tmin, tmax)
        assert fast_stats == slow_stats, query
        assert {k: v for k, v in wide_stats.items() if k not in WALK} == \
            {k: v for k, v in fast_stats.items() if k not in WALK}, query
        assert wide_stats.get("cells.visited", 0) <= fast_stats.get("cells.visited", 0), query
        _same_output(query, fast_out, slow_out)
        _same_output(query, wide_out, slow_out)
    return scene.intersect(o, d, tmin, tmax)


def test_random_triangle_soup():
    rng = np.random.default_rng(11)
    v = rng.uniform(-1, 1, (600, 3))
    f = np.arange(600).reshape(-1, 3)
    o = rng.uniform(-2, 2, (3000, 3))
    d = rng.uniform(-1, 1, (3000, 3)) - o
    h = assert_same_queries(RayScene.from_mesh(v, f), o, d)
    assert 0.2 < np.mean(np.isfinite(h.t)) < 0.95


def test_intervals_and_axis_parallel_rays():
    rng = np.random.default_rng(12)
    v = rng.uniform(-1, 1, (900, 3))
    f = np.arange(900).reshape(-1, 3)
    o = rng.uniform(-2, 2, (2000, 3))
    d = np.zeros((2000, 3))
    d[np.arange(2000), rng.integers(0, 3, 2000)] = rng.choice([-1.0, 1.0], 2000)
    d[:500] = rng.normal(size=(500, 3))
    tmin = rng.uniform(0, 1, 2000)
    tmax = tmin + rng.uniform(0, 3, 2000)
    tmax[:100] = tmin[:100]            # empty-length intervals
    assert_same_queries(RayScene.from_mesh(v, f), o, d, tmin, tmax)


@pytest.mark.parametrize("name", list(MESHES))
def test_shared_edges_and_vertices_of_closed_meshes(name):
    v, f = MESHES[name]
    pts = targets(v, f, np.random.default_rng(7))
    o, d = rays_through(pts, np.array([2.0 ** -5, -3 * 2.0 ** -7, 2.0 ** -6]))
    h = assert_same_queries(RayScene.from_mesh(v, f), o, d)
    assert np.all(np.isfinite(h.t))


def test_smooth_normals_and_flat_meshes():
    rng = np.random.default_rng(13)
    v, f = MESHES["lumpy-0"]
    n = v / np.linalg.norm(v, axis=1)[:, None]
    o = rng.normal(size=(1500, 3)) * 3
    d = rng.normal(size=(1500, 3)) * 0.1 - 0.1 * o
    assert_same_queries(RayScene.from_mesh(v, f, normals=n), o, d)
    flat = np.c_[rng.uniform(-1, 1, (300, 2)), np.zeros(300)]          # every triangle in z = 0
    assert_same_queries(RayScene.from_mesh(flat, np.arange(300).reshape(-1, 3)), o, d)


def test_huge_and_tiny_scales():
    v, f = MESHES["icosphere"]
    rng = np.random.default_rng(14)
    o = rng.normal(size=(800, 3)) * 4
    d = rng.normal(size=(800, 3)) * 0.5 - o          # towards points near the unit sphere
    for scale, shift in ((1e-6, 0.0), (1e6, 0.0), (1.0, 1e7)):
        h = assert_same_queries(RayScene.from_mesh(v * scale + shift, f), o * scale + shift, d * scale)
        assert np.mean(np.isfinite(h.t)) > 0.3


def test_which_scenes_take_the_fast_path():
    v, f = MESHES["cube"]
    assert RayScene.from_mesh(v, f)._mesh is not None
    assert RayScene.from_mesh(v, f, accel="bvh(build=gs)")._mesh is not None
    assert RayScene.from_mesh(v, f, accel="grid")._mesh is None
    assert RayScene.from_mesh(v, f, accel="list")._mesh is None
    assert RayScene.from_spheres([(0, 0, 0)], 1.0)._mesh is None
    scene = Scene()
    scene.root.add(TriangleMesh(v, f))
    scene.root.spheres.add((3, 0, 0), 1.0)
    assert RayScene.from_scene(scene)._mesh is None
    inst = Scene()
    g = Group(name="g", accel="bvh")
    g.add(TriangleMesh(v, f))
    inst.root.add(Instance(g, np.eye(4)))
    assert RayScene.from_scene(inst)._mesh is None


def test_geometry_ids_count_within_each_geometry():
    """Two meshes and a sphere set in the root, a third mesh in a nested group:
    geom_id numbers them in build order and prim_id counts within each."""
    square = np.array([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], float)
    quads = np.array([(0, 1, 2), (0, 2, 3)])
    scene = Scene()
    scene.root.add(TriangleMesh(square + (0, 0, 0), quads))        # geometry 0: x in [0, 1]
    scene.root.add(TriangleMesh(square + (2, 0, 0), quads))        # geometry 1: x in [2, 3]
    scene.root.spheres.add((5.5, 0.5, 0.0), 0.25)                   # a sphere set
    inner = Group(name="inner", accel="bvh")
    inner.add(TriangleMesh(square + (8, 0, 0), quads))
    scene.root.add(inner)
    rs = RayScene.from_scene(scene)
    kinds = [g["kind"] for g in rs.geometries]
    assert sorted(kinds) == ["sphere", "triangle", "triangle", "triangle"] and len(rs.geometries) == 4
    assert all(g["count"] == (1 if g["kind"] == "sphere" else 2) for g in rs.geometries)
    # aim at the lower-right triangle (face 0) and upper-left (face 1) of each square, and at the sphere
    o = np.array([(0.7, 0.2, 1), (0.2, 0.7, 1), (2.7, 0.2, 1), (2.2, 0.7, 1), (5.5, 0.5, 1), (8.2, 0.7, 1),
                  (20, 20, 1)], float)
    h = rs.intersect(o, (0, 0, -1))
    mesh_ids = [i for i, k in enumerate(kinds) if k == "triangle"]
    sphere_id = kinds.index("sphere")
    assert h.prim_id.tolist() == [0, 1, 0, 1, 0, 1, -1]
    assert h.kind.tolist() == [TRIANGLE] * 4 + [SPHERE, TRIANGLE, -1]
    first, second, nested = mesh_ids
    assert h.geom_id.tolist() == [first, first, second, second, sphere_id, nested, -1]
    assert len({first, second, nested, sphere_id}) == 4
    ray, t, prim, geom, inst = rs.intersect_all(o, (0, 0, -1), ids=True)
    assert ray.tolist() == [0, 1, 2, 3, 4, 5] and prim.tolist() == [0, 1, 0, 1, 0, 1]
    assert geom.tolist() == h.geom_id[:6].tolist() and inst.tolist() == [-1] * 6



def test_collapse_keeps_every_leaf_and_contains_every_box():
    """The 4-wide tree holds each binary leaf exactly once, at most 4 children a node, used
    slots first, and float32 boxes that contain the binary tree's float64 boxes (both taken
    relative to the tree's center)."""
    rng = np.random.default_rng(15)
    v = rng.uniform(-1, 1, (3000, 3)) * rng.choice([1e-6, 1.0, 1e7], (3000, 1))
    rs = RayScene.from_mesh(v, np.arange(3000).reshape(-1, 3), accel="bvh(leaf=2)")
    g = rs.geo
    leaf = g.node_count > 0
    wide, _ = collapse(g.node_bounds, g.node_first, g.node_count, 0)
    count = wide.nodes[:, COUNT:]
    child = wide.nodes[:, CHILD:COUNT]
    used = count >= 0
    assert np.all(used[:, 0]) and np.all(used[:, :-1] | ~used[:, 1:])        # used slots come first
    got = sorted(zip(child[count > 0].tolist(), count[count > 0].tolist()))
    assert got == sorted(zip(g.node_first[leaf].tolist(), g.node_count[leaf].tolist()))
    inner = child[count == 0]
    assert sorted(inner.tolist()) == list(range(1, len(wide.nodes)))           # every node but the root once
    assert np.all(inner > np.nonzero(count == 0)[0])                          # children after their parent
    # each leaf slot's box contains the binary leaf's box
    box = wide.boxes[:, :24].reshape(-1, 6, 4)
    by_first = {int(f): i for i, f in zip(np.flatnonzero(leaf), g.node_first[leaf])}
    for w, s in zip(*np.nonzero(count > 0)):
        b = g.node_bounds[by_first[int(child[w, s])]] - np.tile(wide.center, 2)     # stored relative to center
        assert np.all(box[w, :3, s].astype(float) <= b[:3]) and np.all(box[w, 3:, s].astype(float) >= b[3:])
    assert np.all(box[:, :3][~np.broadcast_to(used[:, None, :], box[:, :3].shape)] == np.inf)


@njit
def _rounded(x, lo, hi):
    for i in range(len(x)):
        lo[i] = _down(x[i])
        hi[i] = _up(x[i])


def test_float32_boxes_round_outwards_by_at_most_one_step():
    """The wide boxes' rounding gives the float32 just at or below (above) each float64 value:
    equal to numpy's nextafter rule at every scale, signed zeros, the tiniest and the largest
    floats, beyond float32's range and infinities."""
    rng = np.random.default_rng(4)
    x = rng.standard_normal(200_000) * 10.0 ** rng.integers(-60, 60, 200_000)
    edge = [0.0, -0.0, 1e-50, -1e-50, 1.4e-45, -1.4e-45, 1e-45, 3.4028234663852886e38, 3.5e38, -3.5e38,
            1e300, -1e300, np.inf, -np.inf, 1.0, -1.0, 1.0 + 2.0 ** -30, -(1.0 + 2.0 ** -30)]
    x = np.concatenate([x, edge])
    lo, hi = np.empty(len(x), np.float32), np.empty(len(x), np.float32)
    _rounded(x, lo, hi)
    with np.errstate(over="ignore"):
        f = x.astype(np.float32)
    with np.errstate(over="ignore"):      # nextafter of the largest float32 is infinite
        want_lo = np.where(f.astype(float) > x, np.nextafter(f, np.float32(-np.inf)), f)
        want_hi = np.where(f.astype(float) < x, np.nextafter(f, np.float32(np.inf)), f)
    assert np.array_equal(lo, want_lo) and np.array_equal(hi, want_hi)
    assert np.all(lo.astype(float) <= x) and np.all(hi.astype(float) >= x)


@njit
def _both_box_tests(nodes, boxes, center, origins, directions, tmin, tmax):
    """For every ray and node: box4_entries' mask and t4, and box_entry on each child box (origins
    relative to center, as the boxes are stored)."""
    n, w = len(origins), len(nodes)
    mask = np.zeros((n, w), np.int64)
    vec_t = np.zeros((n, w, 4))
    ref_t = np.zeros((n, w, 4))
    t4 = np.empty(4)
    box = np.empty((1, 6))
    for r in range(n):
        ox, oy, oz = origins[r]
        ix, iy, iz = inverse(directions[r, 0]), inverse(directions[r, 1]), inverse(directions[r, 2])
        wx, wy, wz, vx, vy, vz, near = wide_ray(center, ox, oy, oz, ix, iy, iz)
        for v in range(w):
            mask[r, v] = box4_entries(nodes, v, wx, wy, wz, vx, vy, vz, near, tmin, tmax, t4)
            vec_t[r, v] = t4
            for s in range(4):
                for a in range(3):
                    box[0, a] = boxes[v, 4 * a + s]
                    box[0, 3 + a] = boxes[v, 12 + 4 * a + s]
                ref_t[r, v, s] = box_entry(box, 0, wx, wy, wz, ix, iy, iz, tmin, tmax)
    return mask, vec_t, ref_t


def test_vector_box_test_equals_the_scalar_one_for_still_rays_on_box_planes():
    """box4_entries against the scalar slab test (box_entry) on every node's boxes, for
    axis-parallel rays (an infinite inverse) whose origins lie exactly on box planes, inside
    and outside boxes, and for oblique rays: the same boxes entered at the same distance."""
    rng = np.random.default_rng(21)
    v = rng.uniform(-1, 1, (600, 3))
    wide = RayScene.from_mesh(v, np.arange(600).reshape(-1, 3), accel="bvh(leaf=2)")._mesh.wide
    planes = wide.boxes[:, :24].astype(float)
    planes = planes[np.isfinite(planes)]
    n = 3000
    o = rng.uniform(-1.2, 1.2, (n, 3))
    on_plane = rng.random((n, 3)) < 0.5
    o[on_plane] = rng.choice(planes, on_plane.sum())          # exactly on some box's plane
    d = np.zeros((n, 3))
    d[np.arange(n), rng.integers(0, 3, n)] = rng.choice([-1.0, 1.0], n)
    two = rng.random(n) < 0.3                                  # some move along a second axis: still along one
    d[two, rng.integers(0, 3, two.sum())] = rng.normal(size=two.sum())
    d[:300] = rng.normal(size=(300, 3))
    d[300:400] *= -0.0                                        # still along every axis but one, with -0.0
    d[300:400, 0] = 1.0
    # origins taken relative to the tree's center (a zero center here), so that they lie on the planes exactly
    mask, vec_t, ref_t = _both_box_tests(wide.nodes, wide.boxes, np.zeros(3), o, d, 0.0, 2.5)
    entered = (mask[:, :, None] >> np.arange(4)) & 1 == 1
    used = (mask[:, :, None] >> (4 + np.arange(4))) & 1 == 1
    assert np.array_equal(used, np.broadcast_to(wide.nodes[:, COUNT:] >= 0, used.shape))
    assert not entered[~used].any()                     # an unused slot's empty box is never entered
    # (the scalar test is not asked about empty boxes: the walks never give it one)
    assert np.array_equal(entered[used], np.isfinite(ref_t[used]))
    assert np.array_equal(vec_t[entered], ref_t[entered])
    assert 0.05 < entered[used].mean() < 0.95


def test_wide_kernel_against_brute_force():
    """Closest hits of the 4-wide kernel against testing every triangle (the list), at
    scales from 1e-6 to 1e7, with axis-parallel rays and rays from inside the mesh."""
    v0, f = MESHES["icosphere"]
    rng = np.random.default_rng(16)
    for scale, shift in ((1e-6, 0.0), (1.0, 0.0), (1e7, 0.0), (1.0, 1e7)):
        v = v0 * scale + shift
        o = np.r_[rng.normal(size=(600, 3)) * 3, rng.uniform(-0.5, 0.5, (200, 3))] * scale + shift
        d = rng.normal(size=(800, 3))
        d[:150] = 0.0
        d[np.arange(150), rng.integers(0, 3, 150)] = rng.choice([-1.0, 1.0], 150)
        wide = RayScene.from_mesh(v, f)
        brute = RayScene.from_mesh(v, f, accel="list")
        a, b = wide.intersect(o, d), brute.intersect(o, d)
        assert np.array_equal(a.t, b.t) and np.array_equal(a.prim_id, b.prim_id), scale
        assert np.array_equal(wide.occluded(o, d), brute.occluded(o, d))
        assert np.array_equal(wide.count_hits(o, d), brute.count_hits(o, d))
        assert 0.2 < np.mean(np.isfinite(a.t)) < 1.0      # rays from inside all hit, many from outside miss


def test_wide_counters_are_per_box_and_per_node():
    """One ray into a single 4-triangle leaf's mesh: one wide node (the root) visited, one box
    test for the root's own box and one per used child slot."""
    v = np.array([(0, 0, 0), (1, 0, 0), (0, 1, 0)], float)
    quads = np.concatenate([v + (2 * i, 0, 0) for i in range(4)])
    rs = RayScene.from_mesh(quads, np.arange(12).reshape(-1, 3), accel="bvh(leaf=1)")
    h = rs.intersect([(0.2, 0.2, 1.0)], [(0, 0, -1.0)])
    s = rs.last_stats
    slots = int((rs._mesh.wide.nodes[0, COUNT:] >= 0).sum())
    assert h.prim_id.tolist() == [0] and len(rs._mesh.wide.nodes) == 1 and slots == 4
    assert s["cells.visited"] == 1 and s["bounds.tests"] == 1 + slots and s["tests.triangle"] == 1


def _frozen(a):
    a = np.array(a)
    a.flags.writeable = False
    return a


def _compiled() -> dict:
    """Every raykernel kernel of the process and the argument types it has been compiled for."""
    import gc
    from numba.core.registry import CPUDispatcher
    return {k: set(k.overloads) for k in gc.get_objects()     # (type, not isinstance: a dead weak proxy raises)
            if type(k) is CPUDispatcher and k.py_func.__module__.startswith("raykernel")}


def _queries(scene, o, d, lo, hi, points):
    hits = scene.intersect(o, d, lo, hi)
    methods = ("winding", "parity") if scene._mesh is not None else ("vote",)
    return (hits.t, hits.prim_id, hits.normal, scene.occluded(o, d, lo, hi), scene.closest_points(points).distance,
            *(scene.contains(points, method=m) for m in methods))


def test_read_only_arrays_take_the_kernels_already_made():
    """numba compiles a kernel once per argument types, and a read-only array is a type of its own:
    read-only rays or points (a broadcast origin, a memory-mapped file), a mesh of read-only arrays,
    and a mesh built from a scene (whose Geometry's center is read-only) would each compile the
    kernels again, seconds each. Every mix of flags is passed as one type (rayinput.read_only and
    writable), with the same answers."""
    rng = np.random.default_rng(5)
    v, f = MESHES["cube"]
    o = rng.uniform(-2, 2, (500, 3))
    d = rng.uniform(-1, 1, (500, 3)) - o
    lo, hi = np.zeros(500), np.full(500, 10.0)
    points = rng.uniform(-2, 2, (300, 3))
    in_scene, other = Scene(), Scene()
    in_scene.root.add(TriangleMesh(v, f))
    other.root.add(TriangleMesh(v, f))
    other.root.spheres.add((3, 0, 0), 1.0)          # the general kernel
    plain = {name: make(v, f) for name, make in (("mesh", RayScene.from_mesh),
                                                 ("single", lambda v, f: RayScene.from_mesh(v, f, precision="single")))}
    plain["other"] = RayScene.from_scene(other)
    expected = {name: _queries(scene, o, d, lo, hi, points) for name, scene in plain.items()}
    made = _compiled()
    from raykernel.casting import meshcast, rayqueries
    assert {meshcast.query, rayqueries._query} <= set(made)
    scenes = [("mesh", RayScene.from_mesh(_frozen(v), _frozen(f))), ("mesh", RayScene.from_scene(in_scene)),
              ("single", RayScene.from_mesh(_frozen(v), f, precision="single")), ("other", plain["other"])]
    assert scenes[1][1]._mesh is not None and plain["other"]._mesh is None
    for name, scene in scenes:
        for args in ((_frozen(o), d, lo, hi, _frozen(points)), (o, _frozen(d), _frozen(lo), hi, points),
                     (o, d, lo, _frozen(hi), np.broadcast_to(points[0], points.shape)),
                     (np.broadcast_to(o[0], o.shape), d, 0.0, 10.0, points)):
            answers = _queries(scene, *args)
            reference = _queries(plain[name], *(np.array(a) for a in args))
            for a, b in zip(answers, reference, strict=True):
                np.testing.assert_array_equal(a, b)         # (NaN normals of misses equal)
        for a, b in zip(_queries(scene, o, d, lo, hi, points), expected[name], strict=True):
            np.testing.assert_array_equal(a, b)
    assert _compiled() == made          # nothing compiled for the flags


def _field_scenes(walk: str) -> list:
    """Scenes for test_each_field_alone...: a smooth and a flat mesh through the walk named; for
    the general kernel also spheres, and a rotated, scaled instance of the smooth mesh."""
    v, f = MESHES["lumpy-0"]
    smooth = RayScene.from_mesh(v, f, normals=v / np.linalg.norm(v, axis=1)[:, None])
    scenes = [smooth, RayScene.from_mesh(v, f)]
    if walk == "binary":
        return [binary(scene) for scene in scenes]
    if walk == "4-wide":
        return scenes
    inst = Scene()
    g = Group(name="g", accel="bvh")
    g.add(TriangleMesh(v, f, normals=v / np.linalg.norm(v, axis=1)[:, None]))
    turn = np.array([[0.0, -1.5, 0, 0.2], [1.5, 0, 0, 0], [0, 0, 1.5, -0.1], [0, 0, 0, 1]])
    inst.root.add(Instance(g, turn))
    rng = np.random.default_rng(3)
    return [generic(scene) for scene in scenes] + [
        RayScene.from_spheres(rng.normal(size=(40, 3)), rng.uniform(0.1, 0.4, 40)), RayScene.from_scene(inst)]


@pytest.mark.parametrize("walk", ["4-wide", "binary", "general"])
def test_each_field_alone_equals_the_same_field_of_every_field(walk):
    """The kernels make surfaces after each chunk's walk, and only when a surface field is
    asked for: any subset of fields, in either dtype, gives exactly those columns of the call
    that asks for every field (misses NaN), on the mesh kernel's walks and the general kernel."""
    rng = np.random.default_rng(29)
    o = rng.normal(size=(700, 3)) * 3
    d = rng.normal(size=(700, 3)) * 0.1 - 0.1 * o
    for scene in _field_scenes(walk):
        assert (scene._mesh is None) == (walk == "general")
        if walk == "binary":
            assert not len(scene._mesh.wide.nodes)
        for dtype in ("float64", "float32"):
            every = scene.intersect(o, d, dtype=dtype)
            assert 0 < np.isfinite(every.t).sum() < len(o)          # hits and misses both
            assert np.isnan(every.normal[~np.isfinite(every.t)]).all()
            for fields in (("t",), ("t", "prim_id"), ("uv",), ("normal",), ("shading_normal",),
                           ("geom_id", "uv", "shading_normal")):
                some = scene.intersect(o, d, fields=fields, dtype=dtype)
                for name in ("t",) + fields:
                    assert np.array_equal(getattr(some, name), getattr(every, name), equal_nan=True), (fields, name)


@pytest.mark.slow
def test_a_query_without_surfaces_compiles_no_surface_code(tmp_path):
    """numba drops the surface pass from the mesh kernel and the general one when no surface
    field is asked for (surface_out None): in a fresh process on an empty cache, a query of t
    and ids compiles no surface kernel, and one of normals then does."""
    import os
    import subprocess
    import sys
    code = """
import json, numpy as np, raykernel
from raykernel.casting import meshcast, rayqueries
o, d = np.zeros((2, 3)), np.array([[1.0, 1, 1], [-1, -1, -1]])
for scene, query, surfaces in (
        (raykernel.RayScene.from_mesh(np.eye(3), [(0, 1, 2)]), meshcast.query, meshcast._surfaces),
        (raykernel.RayScene.from_spheres([(1.0, 1, 1)], 0.5), rayqueries._query, rayqueries._surfaces)):
    scene.intersect(o, d, fields=("t", "prim_id"))
    without = [len(query.signatures), len(surfaces.signatures)]
    h = scene.intersect(o, d, fields="normal")
    print(json.dumps([without, [len(query.signatures), len(surfaces.signatures)], h.normal.tolist()]))
"""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    mesh, spheres = (json.loads(line) for line in out.splitlines())
    for without, with_normals, normal in (mesh, spheres):
        assert without == [1, 0]
        assert with_normals == [2, 1]
        assert np.isnan(normal[1]).all()            # a miss
    assert np.allclose(np.abs(mesh[2][0]), 1 / np.sqrt(3))          # the triangle's normal
    assert np.allclose(spheres[2][0], -1 / np.sqrt(3))              # the sphere's, towards the ray

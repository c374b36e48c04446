"""The fast walk of a scene that is one BVH over primitives (aggregates/widewalk.py).

It must answer every query exactly as the general driver does on the same tree (bvh(width=2)
keeps the general driver), and as the brute-force reference: the same primitive and the same
t, hit for hit, for closest, any, opaque-only and every hit; renders must give the same image
bytes and the same rays.* counters. Only the walk's own counters (nodes, box tests, and the
tests an any-hit query makes before it stops) may differ.
"""

from __future__ import annotations

import numpy as np
import pytest
import reference as ref
from support import assert_close_hits, make_scene, random_scene, ray_counts, scene_rays, work_counts

import raykernel
from raykernel import Group, Instance, RayScene, Scene, TriangleMesh
from raykernel.engine.flatten import flatten
from raykernel.engine.traverse import ANY_OPAQUE, cast_rays, intersect, workspace
from raykernel.geometry import counters as C
from raykernel.geometry.primitives import CONE, INDEX_MASK, KIND_SHIFT, PATCH, POLYGON, SPHERE, TRIANGLE
from raykernel.scene import Material

WALK = ("bounds.tests", "cells.visited", "cells.leaves", "walk.bvh.bounds", "walk.bvh.steps")


# ----------------------------------------------------------------- when the fast walk is taken

def test_one_bvh_over_primitives_takes_the_fast_walk():
    geo, stats = flatten(random_scene(1), "bvh")
    assert len(geo.wide_nodes) > 0 and geo.wide_prims.shape == (len(geo.refs), 10)     # 80 bytes a reference
    assert stats["aggregates"][0]["wide_nodes"] == len(geo.wide_nodes)
    assert stats["build.bytes"] >= geo.wide_nodes.nbytes + geo.wide_prims.nbytes


def test_the_records_hold_each_references_primitive():
    scene = random_scene(7)
    assert not flatten(scene, "bvh")[0].wide_prims[:, 9].any()      # opaque
    scene.add_material(Material(t=0.5))     # every primitive's material 0 now transmits: flagged
    geo, _ = flatten(scene, "bvh")
    kind, idx = geo.refs >> KIND_SHIFT, geo.refs & INDEX_MASK
    rec = geo.wide_prims
    for k in (SPHERE, POLYGON, PATCH, CONE, TRIANGLE):
        assert np.any(kind == k), k
    s = kind == SPHERE
    assert np.array_equal(rec[s, :4], np.column_stack([geo.sph_center[idx[s]], geo.sph_radius[idx[s]]]))
    t = kind == TRIANGLE
    assert np.array_equal(rec[t, :9], geo.tri_verts[geo.tri_faces[idx[t]]].reshape(-1, 9))
    c = kind == CONE
    assert np.array_equal(rec[c, 6], geo.cone_length[idx[c]])
    p = (kind == POLYGON) | (kind == PATCH)
    assert np.array_equal(rec[p, 3:6].astype(np.int64),
                          np.column_stack([geo.poly_start[idx[p]], geo.poly_count[idx[p]], geo.poly_axis[idx[p]]]))
    mats = np.select([kind == SPHERE, p, kind == CONE], [geo.sph_mat[idx * s], geo.poly_mat[idx * p],
                                                         geo.cone_mat[idx * c]], geo.tri_mat[idx * t])
    assert np.array_equal(rec[:, 9] != 0.0, geo.mat_clear[mats]) and rec[:, 9].all()


@pytest.mark.parametrize("accel", ["bvh(width=2)", "list", "grid", "octree", "bvh(build=gs, width=2)"])
def test_other_structures_keep_the_general_walk(accel):
    geo, _ = flatten(random_scene(1), accel)
    assert len(geo.wide_nodes) == 0 and len(geo.wide_prims) == 0


def test_nesting_and_instances_keep_the_general_walk():
    scene = random_scene(2)
    child = Group(accel="bvh")
    child.spheres.add((0, 0, 9), 1.0)
    scene.root.add(child)
    assert len(flatten(scene)[0].wide_nodes) == 0
    inst = random_scene(2)
    inst.root.add(Instance(child, np.eye(4)))
    assert len(flatten(inst)[0].wide_nodes) == 0


def test_kernels_given_a_wide_geometry_compile_no_general_driver():
    # the geometry's type tells numba: a read-only wide_center when the scene is one 4-wide BVH
    from numba import njit, typeof

    from raykernel.engine.flatten import Geometry
    from raykernel.engine.traverse import CLOSEST, CLOSEST_EAGER
    from raykernel.aggregates.widewalk import _walk_wide, wide_only, with_driver

    wide, _ = flatten(random_scene(1), "bvh")
    general, _ = flatten(random_scene(1), "bvh(width=2)")
    assert wide_only(wide) and not wide_only(general)
    driven = with_driver(wide)
    assert not wide_only(driven) and typeof(driven) != typeof(wide) and with_driver(general) is general
    assert np.array_equal(driven.wide_center, wide.wide_center)
    same = [name for name in Geometry._fields if name not in ("wide_center", "root")]
    assert all(getattr(driven, name) is getattr(wide, name) for name in same)     # the same arrays

    @njit
    def first_hit(geo, mode, ws, cnt):
        return intersect(geo, 0.0, 0.0, -50.0, 0.0, 0.0, 1.0, 0.0, np.inf, mode, ws, cnt)

    ws, cnt = workspace(), np.zeros(C.N_COUNTERS, np.int64)
    first_hit(wide, CLOSEST, ws, cnt)
    code = first_hit.inspect_llvm(first_hit.signatures[0])
    assert "_walk_wide" in code and "traverse4walk" not in code
    walks = set(_walk_wide.overloads)
    with pytest.raises(ValueError, match="with_driver"):
        first_hit(wide, CLOSEST_EAGER, ws, cnt)     # eager normals need the driver: given with_driver(geo)
    assert first_hit(driven, CLOSEST_EAGER, ws, cnt) == first_hit(driven, CLOSEST, ws, cnt)
    assert set(_walk_wide.overloads) == walks       # the walk itself, compiled apart, serves both types


def test_a_geometry_keeps_what_its_kernels_compile_through_pickle():
    # Dask sends a scene's Geometry to its workers: they must compile (or load) what the client does
    import pickle

    from numba import typeof

    from raykernel.aggregates.widewalk import wide_only, with_driver

    rays = scene_rays(np.random.default_rng(3), 300)
    for geo in (flatten(random_scene(2), "bvh")[0], flatten(random_scene(2), "grid")[0]):
        for typed in (geo, with_driver(geo)):
            back = pickle.loads(pickle.dumps(typed))
            assert typeof(back) == typeof(typed) and wide_only(back) == wide_only(typed)
            assert all(np.array_equal(a, b) for a, b in zip(back[:-1], typed[:-1])) and back.root == typed.root
            hits = [cast_rays(g, *rays)[:4] for g in (typed, back)]
            assert all(np.array_equal(a, b) for a, b in zip(*hits)) and np.isfinite(hits[0][0]).any()
    assert wide_only(flatten(random_scene(2), "bvh")[0])        # the case pickle used to lose


def test_eager_normals_render_one_bvh_with_the_driver_and_the_same_image():
    # tricks without lazy normals take CLOSEST_EAGER queries, which only the general driver answers:
    # a render with tricks gets the geometry typed with it
    scene = raykernel.load("spd:balls:1")
    eager = raykernel.render(scene, resolution=24, tricks="closest")
    lazy = raykernel.render(scene, resolution=24, tricks="closest,lazynormals")
    binary = raykernel.render(scene, resolution=24, tricks="closest", accel="bvh(width=2)")
    assert np.array_equal(eager.image, lazy.image) and np.array_equal(eager.image, binary.image)
    assert eager.stats["normals.computed"] > lazy.stats["normals.computed"]
    assert eager.stats["normals.computed"] == binary.stats["normals.computed"]


def test_an_empty_scene_has_no_tree():
    geo, _ = flatten(Scene())
    assert len(geo.wide_nodes) == 0
    t, kind, *_ = cast_rays(geo, np.zeros((3, 3)), np.eye(3))
    assert np.all(np.isinf(t)) and np.all(kind == -1)


# ----------------------------------------------------------------- the same answers as the general walk

@pytest.mark.parametrize("seed", [3, 4, 5])
@pytest.mark.parametrize("scale", [1e-6, 1.0, 1e7])
def test_every_query_equals_the_general_walk_and_brute_force(seed, scale):
    scene = random_scene(seed, n=(30, 12, 14, 8, 30), extent=5.0 * scale)
    rng = np.random.default_rng(seed)
    o, d, tmin, tmax = scene_rays(rng, 900, extent=5.0 * scale)
    tmin, tmax = tmin * scale, tmax * scale
    fast, slow = RayScene(scene, "bvh"), RayScene(scene, "bvh(width=2)")
    assert len(fast.geo.wide_nodes) and not len(slow.geo.wide_nodes)
    a, b = fast.intersect(o, d, tmin, tmax), slow.intersect(o, d, tmin, tmax)
    for field in ("t", "prim_id", "geom_id", "kind", "uv", "normal", "shading_normal"):
        assert np.array_equal(getattr(a, field), getattr(b, field), equal_nan=True), field
    assert np.array_equal(fast.occluded(o, d, tmin, tmax), slow.occluded(o, d, tmin, tmax))
    assert np.array_equal(fast.count_hits(o, d, tmin, tmax), slow.count_hits(o, d, tmin, tmax))
    for x, y in zip(fast.intersect_all(o, d, tmin, tmax), slow.intersect_all(o, d, tmin, tmax)):
        assert np.array_equal(x, y)
    # against brute force on the rays whose answer is not sensitive to rounding
    geo, _ = flatten(scene, "bvh")
    got = cast_rays(geo, o, d, tmin, tmax)
    prims = ref.world_primitives(scene)
    want = ref.cast(prims, o, d, tmin, tmax)
    stable = ~ref.unstable(prims, o, d, 1e-6 * scale, tmin, tmax)
    assert stable.mean() > 0.9
    assert_close_hits(got, want, stable, f"fast walk at scale {scale}")
    assert np.isfinite(got[0]).mean() > 0.2


def test_axis_parallel_and_grazing_rays_on_a_closed_mesh():
    # a cube of 12 triangles, rays along the axes through its shared edges and corners
    v = np.array([(x, y, z) for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    f = np.array([(0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5), (0, 4, 5), (0, 5, 1), (2, 3, 7), (2, 7, 6),
                  (0, 2, 6), (0, 6, 4), (1, 5, 7), (1, 7, 3)])
    scene = Scene()
    scene.root.add(TriangleMesh(v, f))
    scene.root.spheres.add((3, 3, 3), 0.5)      # not a mesh alone: the render path's walk, not RayScene's
    grid = np.linspace(0, 1, 5)
    pts = np.array([(x, y) for x in grid for y in grid])
    rays_o, rays_d = [], []
    for axis in range(3):
        o = np.zeros((len(pts), 3))
        others = [a for a in range(3) if a != axis]
        o[:, others] = pts
        o[:, axis] = -2.0
        dvec = np.zeros(3)
        dvec[axis] = 1.0
        rays_o.append(o)
        rays_d.append(np.tile(dvec, (len(pts), 1)))
    o, d = np.vstack(rays_o), np.vstack(rays_d)
    fast, slow = RayScene(scene, "bvh"), RayScene(scene, "list")
    assert len(fast.geo.wide_nodes)
    a, b = fast.intersect(o, d), slow.intersect(o, d)
    assert np.array_equal(a.t, b.t) and np.array_equal(a.prim_id, b.prim_id)
    # watertight: every ray through the inside of a face, across the diagonal edges the face's two
    # triangles share, enters the closed cube exactly once and leaves it once (the rays along its
    # outer edges graze the silhouette: hit or miss by the edge rule, the same for both walks)
    inner = np.all((o > 0.0) & (o < 1.0) | (o == -2.0), axis=1)
    assert inner.sum() == 27
    assert np.all(a.t[inner] == 2.0)
    assert np.array_equal(fast.count_hits(o, d)[inner], np.full(27, 2))
    assert np.array_equal(fast.count_hits(o, d), slow.count_hits(o, d))


def test_opaque_only_queries_pass_over_transparent_primitives():
    scene = make_scene()
    glass = scene.add_material(Material(color=(1, 1, 1), t=0.9, ior=1.5))
    solid = scene.add_material(Material(color=(1, 1, 1)))
    scene.root.spheres.add((0, 0, 0), 1.0, glass)
    scene.root.spheres.add((0, 3, 0), 1.0, solid)
    scene.root.spheres.add((5, 0, 0), 1.0, glass)
    geo, _ = flatten(scene, "bvh")
    slow, _ = flatten(scene, "bvh(width=2)")
    assert len(geo.wide_nodes)
    for g in (geo, slow):
        ws = workspace()
        cnt = np.zeros(C.N_COUNTERS, np.int64)
        # through the glass sphere only: no opaque blocker
        assert not intersect(g, 0.0, -5.0, 0.0, 0.0, 1.0, 0.0, 0.0, 4.5, ANY_OPAQUE, ws, cnt)
        # on to the solid one behind it
        assert intersect(g, 0.0, -5.0, 0.0, 0.0, 1.0, 0.0, 0.0, 20.0, ANY_OPAQUE, ws, cnt)
        assert ws.hit_i[0] == SPHERE and ws.hit_i[1] == 1


# ----------------------------------------------------------------- the walk's counters

def test_counters_of_one_sphere_are_exact():
    scene = Scene()
    scene.root.spheres.add((0, 0, 0), 1.0)
    rs = RayScene(scene, "bvh")
    assert len(rs.geo.wide_nodes) == 1
    rs.intersect(np.array([[0.0, 0.0, -5.0], [3.0, 3.0, -5.0]]), np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]]))
    s = rs.last_stats
    # ray 1: the root box, then the one node's one child box, its leaf, its sphere; ray 2 misses the root box
    assert s["bounds.tests"] == 3 and s["walk.bvh.bounds"] == 3
    assert s["cells.visited"] == 1 and s["walk.bvh.steps"] == 1 and s["walk.bvh.entries"] == 1
    assert s["cells.leaves"] == 1 and s["tests.sphere"] == 1


def test_the_walk_counts_its_steps_and_bounds_as_the_bvh_walk():
    rs = RayScene(random_scene(6), "bvh")
    o, d, tmin, tmax = scene_rays(np.random.default_rng(6), 600)
    rs.intersect(o, d, tmin, tmax)
    s = rs.last_stats
    assert s["walk.bvh.steps"] == s["cells.visited"] > 0
    assert s["walk.bvh.bounds"] == s["bounds.tests"] > s["cells.visited"]
    narrow = RayScene(random_scene(6), "bvh(width=2)")
    narrow.intersect(o, d, tmin, tmax)
    assert s["cells.visited"] < narrow.last_stats["cells.visited"]


# ----------------------------------------------------------------- renders

RENDER_SCENES = ["spd:balls:1", "spd:gears:1", "spd:tree:2", "spd:teapot:2", "spd:rings:1", "spd:mount:2"]


@pytest.mark.parametrize("name", RENDER_SCENES)
def test_renders_equal_the_general_walk_and_the_list(name):
    scene = raykernel.load(name)
    fast = raykernel.render(scene, accel="bvh", resolution=48, spd=True)
    assert fast.stats.aggregates[0].get("wide_nodes", 0) > 0
    for other in ("bvh(width=2)", "list"):
        slow = raykernel.render(scene, accel=other, resolution=48, spd=True)
        assert np.array_equal(fast.to_uint8(), slow.to_uint8()), other
        assert np.array_equal(fast.image, slow.image), other
        assert ray_counts(fast.stats) == ray_counts(slow.stats), other


@pytest.mark.parametrize("options", [dict(shading="hall", shadows="filtered"), dict(tricks="all"),
                                     dict(tricks="none"), dict(shading="heckbert")])
def test_renders_with_other_options_equal_the_general_walk(options):
    scene = raykernel.load("spd:gears:1")
    fast = raykernel.render(scene, accel="bvh", resolution=32, **options)
    slow = raykernel.render(scene, accel="bvh(width=2)", resolution=32, **options)
    assert np.array_equal(fast.image, slow.image)
    assert ray_counts(fast.stats) == ray_counts(slow.stats)


def test_render_counts_do_not_depend_on_threads():
    scene = raykernel.load("spd:balls:1")
    one = raykernel.render(scene, accel="bvh", resolution=48, spd=True, threads=1)
    two = raykernel.render(scene, accel="bvh", resolution=48, spd=True, threads=2)
    assert np.array_equal(one.image, two.image)
    assert work_counts(one.stats) == work_counts(two.stats)

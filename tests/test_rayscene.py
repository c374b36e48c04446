"""RayScene: every query against the brute-force reference, input checks, hand-computed surfaces."""

from __future__ import annotations

import numpy as np
import pytest
from reference import all_hits, world_primitives
from support import rays_into_box

from raykernel import Group, Instance, RayInputError, RayScene, Scene, TriangleMesh
from raykernel.casting.rayinput import check_rays
from raykernel.geometry.primitives import CONE, PATCH, POLYGON, SPHERE, TRIANGLE


def random_mesh(rng, n=150):
    v = rng.uniform(-1, 1, (3 * n, 3))
    return v, np.arange(3 * n).reshape(-1, 3)


def reference_hits(scene: RayScene, o, d, tmin=0.0, tmax=np.inf):
    """(n_prims, n_rays) t of every primitive, and the primitives' (kind, index, instance)."""
    prims = world_primitives(scene.scene)
    t = all_hits(prims, o, d, tmin, tmax).astype(float)
    ident = np.array([(p.kind, p.index, p.instance) for p in prims], np.int64).reshape(-1, 3)
    return t, ident


KIND_CODES = {"sphere": SPHERE, "polygon": POLYGON, "patch": PATCH, "cone": CONE, "triangle": TRIANGLE}


def user_ids(scene: RayScene, kind, index):
    """(geom_id, prim_id) of global (kind, index) pairs, from the sizes scene.geometries lists:
    geometries of one kind family (polygons and patches together) are numbered one after another."""
    family = {PATCH: POLYGON}
    ranges, next_first = [], {}
    for g, info in enumerate(scene.geometries):
        k = family.get(KIND_CODES[info["kind"]], KIND_CODES[info["kind"]])
        first = next_first.get(k, 0)
        ranges.append((k, first, info["count"], g))
        next_first[k] = first + info["count"]
    geom = np.full(len(kind), -1, np.int64)
    local = np.full(len(kind), -1, np.int64)
    for i, (k, idx) in enumerate(zip(kind, index)):
        for fk, first, n, g in ranges:
            if k >= 0 and family.get(k, k) == fk and first <= idx < first + n:
                geom[i], local[i] = g, idx - first
    return geom, local


def check_all_queries(scene, o, d, tmin=0.0, tmax=np.inf):
    t_ref, ident = reference_hits(scene, o, d, tmin, tmax)
    geom_ref, local_ref = user_ids(scene, ident[:, 0], ident[:, 1])
    best = np.argmin(t_ref, axis=0)
    t_best = t_ref[best, np.arange(len(o))]
    hit = np.isfinite(t_best)
    assert hit.sum() > 20 and (~hit).sum() > 5
    h = scene.intersect(o, d, tmin, tmax)
    np.testing.assert_allclose(h.t, t_best, rtol=1e-9)
    assert np.all(h.prim_id[~hit] == -1) and np.all(h.geom_id[~hit] == -1)
    # identities where the closest hit is not a near tie
    t_sorted = np.sort(t_ref, axis=0)
    clear = hit & ((t_sorted[1] - t_sorted[0]) > 1e-9 * np.abs(t_sorted[0]) + 1e-12)
    assert np.array_equal(h.kind[clear], ident[best[clear], 0])
    assert np.array_equal(h.geom_id[clear], geom_ref[best[clear]])
    assert np.array_equal(h.prim_id[clear], local_ref[best[clear]])
    assert np.array_equal(h.inst_id[clear], ident[best[clear], 2])
    np.testing.assert_allclose(np.linalg.norm(h.normal[hit], axis=1), 1.0, rtol=1e-12)
    assert np.all(np.isnan(h.normal[~hit]))
    # occluded equals "the closest hit lies in [tmin, tmax]"
    assert np.array_equal(scene.occluded(o, d, tmin, tmax), hit)
    # count_hits and intersect_all against the per-ray lists of the reference
    counts = np.isfinite(t_ref).sum(axis=0)
    assert np.array_equal(scene.count_hits(o, d, tmin, tmax), counts)
    ray, t, prim, geom, inst = scene.intersect_all(o, d, tmin, tmax, ids=True)
    r_ref, p_ref = np.nonzero(np.isfinite(t_ref.T))
    tt = t_ref.T[r_ref, p_ref]
    order = np.lexsort((ident[p_ref, 2], local_ref[p_ref], geom_ref[p_ref], tt, r_ref))
    assert np.array_equal(ray, r_ref[order])
    np.testing.assert_allclose(t, tt[order], rtol=1e-9)
    assert np.array_equal(prim, local_ref[p_ref[order]])
    assert np.array_equal(geom, geom_ref[p_ref[order]])
    assert np.array_equal(inst, ident[p_ref[order], 2])
    assert np.array_equal(np.bincount(ray, minlength=len(o)), counts)
    assert np.all((np.diff(ray) > 0) | ((np.diff(ray) == 0) & (np.diff(t) >= 0)))
    return h


@pytest.mark.parametrize("accel", ["bvh", "grid", "list"])
def test_random_mesh_all_queries(accel):
    rng = np.random.default_rng(1)
    v, f = random_mesh(rng)
    scene = RayScene.from_mesh(v, f, accel=accel)
    o, d = rays_into_box(rng)
    h = check_all_queries(scene, o, d)
    assert np.all(h.kind[np.isfinite(h.t)] == TRIANGLE) and np.all(h.geom_id[np.isfinite(h.t)] == 0)
    assert scene.last_stats["rays.cast"] == len(o)
    assert scene.last_stats["tests.triangle"] > 0


def test_random_mesh_with_intervals():
    rng = np.random.default_rng(2)
    v, f = random_mesh(rng)
    scene = RayScene.from_mesh(v, f)
    o, d = rays_into_box(rng)
    tmin = rng.uniform(0, 0.5, len(o))
    tmax = tmin + rng.uniform(0, 1.0, len(o))
    check_all_queries(scene, o, d, tmin, tmax)


def test_random_spheres_all_queries():
    rng = np.random.default_rng(3)
    c = rng.uniform(-1, 1, (80, 3))
    r = rng.uniform(0.02, 0.2, 80)
    scene = RayScene.from_spheres(c, r)
    o, d = rays_into_box(rng)
    h = check_all_queries(scene, o, d)
    assert np.all(h.kind[np.isfinite(h.t)] == SPHERE) and np.all(h.geom_id[np.isfinite(h.t)] == 0)


def test_scene_with_instances():
    rng = np.random.default_rng(4)
    v, f = random_mesh(rng, 40)
    g = Group(name="part", accel="bvh")
    g.add(TriangleMesh(v * 0.5, f))
    g.spheres.add((0.2, 0.1, 0.0), 0.3)
    scene = Scene()
    m = np.eye(4)
    m[:3, 3] = (0.6, 0.0, 0.1)
    scene.root.add(Instance(g, m))
    m2 = np.eye(4)
    m2[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    m2[:3, 3] = (-0.5, 0.2, -0.3)
    scene.root.add(Instance(g, m2))
    rs = RayScene.from_scene(scene)
    o, d = rays_into_box(rng)
    h = check_all_queries(rs, o, d)
    assert set(h.inst_id[np.isfinite(h.t)]) == {0, 1}


def test_hand_computed_triangle_surface():
    v = np.array([(0, 0, 0), (2, 0, 0), (0, 2, 0)], float)
    n = np.array([(0, 0, 1), (1, 0, 1), (0, 1, 1)], float)
    scene = RayScene.from_mesh(v, [(0, 1, 2)], normals=n)
    h = scene.intersect([(0.5, 0.25, 1.0), (0.5, 0.25, -3.0)], [(0, 0, -1), (0, 0, 2)])
    np.testing.assert_allclose(h.t, [1.0, 1.5])
    np.testing.assert_allclose(h.uv, [(0.25, 0.125)] * 2)
    np.testing.assert_allclose(h.normal, [(0, 0, 1)] * 2)
    # shading normal: 0.625 n0 + 0.25 n1 + 0.125 n2 = (0.25, 0.125, 1), normalised
    s = np.array([0.25, 0.125, 1.0])
    np.testing.assert_allclose(h.shading_normal, [s / np.linalg.norm(s)] * 2)
    assert h.prim_id.tolist() == [0, 0] and h.geom_id.tolist() == [0, 0] and h.kind.tolist() == [TRIANGLE] * 2
    # flat mesh: shading normal = geometric normal; reversed winding flips it
    flat = RayScene.from_mesh(v, [(0, 2, 1)]).intersect((0.5, 0.25, 1.0), (0, 0, -1))
    np.testing.assert_allclose(flat.normal, [(0, 0, -1)])
    np.testing.assert_allclose(flat.shading_normal, [(0, 0, -1)])


def test_hand_computed_sphere_surface():
    scene = RayScene.from_spheres([(1.0, 0.0, 0.0)], 2.0)
    h = scene.intersect([(1, 0, 5), (6, 0, 0), (1, -7, 0)], [(0, 0, -1), (-2, 0, 0), (0, 1, 0)])
    np.testing.assert_allclose(h.t, [3.0, 1.5, 5.0])
    np.testing.assert_allclose(h.normal, [(0, 0, 1), (1, 0, 0), (0, -1, 0)], atol=1e-15)
    np.testing.assert_allclose(h.uv[:, 1], [0.0, 0.5, 0.5], atol=1e-12)
    np.testing.assert_allclose(h.uv[1:, 0], [0.0, 0.75], atol=1e-12)
    np.testing.assert_allclose(h.shading_normal, h.normal)
    # from inside: the far side, normal still outward
    h = scene.intersect((1, 0, 0), (0, 0, 1))
    np.testing.assert_allclose(h.t, [2.0])
    np.testing.assert_allclose(h.normal, [(0, 0, 1)])


def test_float32_geometry_and_rays():
    rng = np.random.default_rng(5)
    v, f = random_mesh(rng)
    v32 = v.astype(np.float32)
    o, d = rays_into_box(rng)
    a = RayScene.from_mesh(v32, f.astype(np.int32)).intersect(o.astype(np.float32), d.astype(np.float32))
    b = RayScene.from_mesh(v32.astype(np.float64), f).intersect(o.astype(np.float32).astype(float),
                                                                d.astype(np.float32).astype(float))
    assert np.array_equal(a.t, b.t) and np.array_equal(a.prim_id, b.prim_id)


def test_single_ray_and_broadcast_origin():
    scene = RayScene.from_spheres([(0, 0, 0)], 1.0)
    assert scene.intersect((0, 0, 5), (0, 0, -1)).t.tolist() == [4.0]
    h = scene.intersect((0, 0, 5), [(0, 0, -1), (0, 0, 1), (0, 0, -2)])
    assert h.t.tolist() == [4.0, np.inf, 2.0]
    assert scene.count_hits((0, 0, 5), (0, 0, -1)).tolist() == [1]
    assert scene.occluded((0, 0, 5), (0, 0, -1), tmax=3.9).tolist() == [False]
    assert scene.occluded((0, 0, 5), (0, 0, -1), tmax=4.0).tolist() == [True]


def test_empty_batch():
    scene = RayScene.from_spheres([(0, 0, 0)], 1.0)
    h = scene.intersect(np.zeros((0, 3)), np.zeros((0, 3)))
    assert len(h) == 0
    ray, t, prim = scene.intersect_all(np.zeros((0, 3)), np.zeros((0, 3)))
    assert len(ray) == len(t) == len(prim) == 0


@pytest.mark.parametrize("kwargs, match", [
    (dict(origins=np.zeros((4, 2)), directions=np.ones((4, 3))), r"origins must have shape"),
    (dict(origins=np.zeros((4, 3)), directions=np.ones((5, 3))), r"origins and directions differ"),
    (dict(origins=np.zeros((4, 3)), directions=np.ones((4, 3, 1))), r"directions must have shape"),
    (dict(origins=[(0, 0, np.nan)], directions=[(0, 0, 1)]), r"origins\[0\] is not finite"),
    (dict(origins=[(0, 0, 0)], directions=[(0, np.inf, 1)]), r"directions\[0\] is not finite"),
    (dict(origins=np.zeros((2, 3)), directions=[(0, 0, 1), (0, 0, 0)]), r"directions\[1\] has zero length"),
    (dict(origins=[(0, 0, 0)], directions=[(0, 0, 1)], tmin=2.0, tmax=1.0), r"tmin > tmax"),
    (dict(origins=np.zeros((0, 3)), directions=np.zeros((0, 3)), tmin=2.0, tmax=1.0), r"tmin > tmax for ray 0"),
    (dict(origins=np.zeros((2, 3)), directions=np.ones((2, 3)), tmin=[0.0, 3.0], tmax=2.0),
     r"tmin > tmax for ray 1: 3.0 > 2.0"),
    (dict(origins=[(0, 0, 0)], directions=[(0, 0, 1)], tmin=np.nan), r"tmin\[0\] is NaN"),
    (dict(origins=[(0, 0, 0)], directions=[(0, 0, 1)], tmax=[1.0, 2.0]), r"tmax must be a number or have shape"),
    (dict(origins=np.array([["a", "b", "c"]]), directions=[(0, 0, 1)]), r"origins must be an array of real"),
    (dict(origins=[(0, 0, 0)], directions=np.array([(0, 0, 1j)])), r"directions must be an array of real"),
])
@pytest.mark.parametrize("query", ["intersect", "occluded", "count_hits", "intersect_all"])
def test_ray_input_errors(kwargs, match, query):
    scene = RayScene.from_spheres([(0, 0, 0)], 1.0)
    with pytest.raises(ValueError, match=match):
        getattr(scene, query)(**kwargs)
    with pytest.raises(RayInputError):
        getattr(scene, query)(**kwargs)


@pytest.mark.parametrize("tmin, tmax, match", [
    (np.nan, 1.0, r"tmin\[0\] is NaN"),
    (0.0, np.nan, r"tmax\[0\] is NaN"),
    (2.0, 1.0, r"tmin > tmax for ray 0: 2.0 > 1.0"),
])
def test_the_common_call_checks_its_numbers_as_the_general_one(tmin, tmax, match):
    """(N, 3) float64 arrays skip check_rays' broadcasting and float numbers its array conversion:
    the same errors, and the same arrays as the general way (reached here with a list of rays or
    a Fortran-ordered array)."""
    o, d = np.zeros((3, 3)), np.tile([0.0, 0.0, 1.0], (3, 1))
    for origins in (o, o.tolist()):
        with pytest.raises(RayInputError, match=match):
            check_rays(origins, d, tmin, tmax)
    rng = np.random.default_rng(5)
    o, d = rng.normal(size=(7, 3)), rng.normal(size=(7, 3))
    short = check_rays(o, d, 0.25, 4.0)
    assert short[0] is o and short[1] is d       # the caller's arrays, not copies
    for general in (check_rays(o.tolist(), d, 0.25, 4.0), check_rays(np.asfortranarray(o), d, 0.25, 4.0)):
        for a, b in zip(short[:4], general[:4]):
            assert a.dtype == b.dtype and np.array_equal(a, b)
        assert short[4] == general[4] == (7,)


@pytest.mark.parametrize("bad, match", [
    (("origins", 0, np.nan), r"origins\[{i}\] is not finite"),
    (("origins", 2, -np.inf), r"origins\[{i}\] is not finite"),
    (("directions", 1, np.inf), r"directions\[{i}\] is not finite"),
    (("directions", None, 0.0), r"directions\[{i}\] has zero length"),
])
@pytest.mark.parametrize("scene", ["mesh", "spheres", "lazy"])
@pytest.mark.parametrize("query", ["intersect", "occluded", "count_hits", "intersect_all"])
def test_a_bad_ray_deep_in_a_batch_is_named_by_every_kernel(bad, match, scene, query):
    """The kernels check each ray's values as they read it (rayinput.py): a bad ray far past the
    first chunk, among rays that are fine, raises the error naming it, whichever kernel casts."""
    rng = np.random.default_rng(3)
    n, i = 5000, 3777
    o = rng.uniform(-2, 2, (n, 3))
    d = rng.normal(size=(n, 3))
    name, axis, value = bad
    (o if name == "origins" else d)[i, slice(None) if axis is None else axis] = value
    v, f = random_mesh(rng)
    rs = {"mesh": lambda: RayScene.from_mesh(v, f),
          "spheres": lambda: RayScene.from_spheres([(0, 0, 0), (1, 0, 0)], 0.5),
          "lazy": lambda: RayScene.from_mesh(v, f, accel="lazyoctree")}[scene]()
    with pytest.raises(RayInputError, match=match.format(i=i)):
        getattr(rs, query)(o, d)


@pytest.mark.parametrize("o, d, valid", [
    ((0, 0, 0), (0, 0, 1), True),
    ((1e30, -1e30, 0), (1e-30, 0, 0), True),            # the ends of the range raykernel answers
    ((0, 0, 0), (1e30, -1e30, 1e-300), True),
    ((1e308, 0, 0), (0, 0, 1), False),                  # beyond it (geometry/primitives.py, MAX_COORDINATE)
    ((0, 0, 0), (5e-324, 0, 0), False),
    ((0, 0, 0), (0, 2e30, 0), False),
    ((0, 0, 0), (0, 0, 0), False),
    ((0, 0, 0), (-0.0, 0.0, -0.0), False),
    ((np.nan, 0, 0), (0, 0, 1), False),
    ((0, np.inf, 0), (0, 0, 1), False),
    ((0, 0, 0), (0, 0, -np.inf), False),
    ((0, 0, 0), (np.nan, 1, 1), False),
])
def test_valid_ray_agrees_with_the_numpy_checks(o, d, valid):
    from raykernel.casting.rayinput import valid_ray
    from raykernel.casting.rayinput import check_ray_values
    assert valid_ray(*o, *d) == valid
    if valid:
        check_ray_values(np.array([o], float), np.array([d], float))
    else:
        with pytest.raises(RayInputError):
            check_ray_values(np.array([o], float), np.array([d], float))


@pytest.mark.parametrize("build, match", [
    (lambda: RayScene.from_mesh(np.zeros((3, 2)), [(0, 1, 2)]), r"vertices must have shape"),
    (lambda: RayScene.from_mesh(np.zeros((3, 3)), [(0, 1, 3)]), r"faces refer to vertex 3"),
    (lambda: RayScene.from_mesh(np.zeros((3, 3)), [(0.0, 1.0, 2.0)]), r"faces must be integer"),
    (lambda: RayScene.from_mesh(np.full((3, 3), np.nan), [(0, 1, 2)]), r"vertices\[0\] is not finite"),
    (lambda: RayScene.from_mesh(np.zeros((3, 3)), [(0, 1, 2)], normals=np.zeros((2, 3))), r"normals must have"),
    (lambda: RayScene.from_spheres([(0, 0, 0)], [-1.0]), r"radii\[0\] must be finite and positive"),
    (lambda: RayScene.from_spheres([(0, 0, 0), (1, 1, 1)], [1.0]), r"radii must be a number or have shape"),
    (lambda: RayScene.from_scene("not a scene"), r"scene must be a raykernel Scene"),
])
def test_geometry_input_errors(build, match):
    with pytest.raises(ValueError, match=match):
        build()


def test_large_coordinates_stay_exact():
    """A unit mesh 1e7 away from the origin and rays from near it: t as precise as near the origin."""
    rng = np.random.default_rng(6)
    v, f = random_mesh(rng, 60)
    o, d = rays_into_box(rng, 200)
    near = RayScene.from_mesh(v, f).intersect(o, d)
    shift = np.array([1e7, -3e7, 2e7])
    far = RayScene.from_mesh(v + shift, f).intersect(o + shift, d)
    hit = np.isfinite(near.t)
    assert np.array_equal(hit, np.isfinite(far.t))
    np.testing.assert_allclose(far.t[hit], near.t[hit], rtol=1e-6)


# ---------------------------------------------------------------- several Python threads at once

THREAD_SPECS = ("list", "bvh", "grid", "hgrid", "octree", "hybrid", "lazyoctree", "rc", "rc(lazy=off)",
                "octree(walk=parametric)", "bvh(build=gs)")


@pytest.mark.parametrize("spec", THREAD_SPECS)
def test_four_python_threads_on_one_scene_agree_with_list(spec):
    """Four threads query one RayScene at once (closest, any and all hits, counts), three rounds
    each: every answer equals a list's. Lazy kinds refine meanwhile; they used to corrupt the heap."""
    import threading

    import trimesh
    mesh = trimesh.creation.icosphere(subdivisions=3)
    rng = np.random.default_rng(11)
    o = rng.normal(0, 3, (6000, 3))
    d = rng.uniform(-0.7, 0.7, (6000, 3)) - o
    ref = RayScene.from_mesh(mesh.vertices, mesh.faces, accel="list")
    scene = Scene()
    scene.root.accel = spec
    scene.root.add(TriangleMesh(mesh.vertices, mesh.faces))
    rs = RayScene(scene, spec)
    want = (ref.intersect(o, d).t, ref.intersect(o, d).prim_id, ref.occluded(o, d), ref.count_hits(o, d),
            ref.intersect_all(o, d))
    results, errors = [], []

    def work(k):
        try:
            for _ in range(3):
                sel = slice(k * 1000, k * 1000 + 3000)
                h = rs.intersect(o[sel], d[sel])
                stats = rs.last_stats
                assert stats["rays.cast"] == 3000
                results.append((sel, h.t, h.prim_id, rs.occluded(o[sel], d[sel]), rs.count_hits(o[sel], d[sel]),
                                rs.intersect_all(o[sel], d[sel])))
        except Exception as e:      # reported below, in the main thread
            errors.append(e)

    threads = [threading.Thread(target=work, args=(k,)) for k in range(4)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert not errors, errors
    assert len(results) == 12
    all_ray, all_t, all_prim = want[4]
    for sel, t, prim, occ, n, (ray, tt, pp) in results:
        np.testing.assert_array_equal(t, want[0][sel])
        np.testing.assert_array_equal(prim, want[1][sel])
        np.testing.assert_array_equal(occ, want[2][sel])
        np.testing.assert_array_equal(n, want[3][sel])
        keep = (all_ray >= sel.start) & (all_ray < sel.stop)
        np.testing.assert_array_equal(ray + sel.start, all_ray[keep])
        np.testing.assert_array_equal(tt, all_t[keep])
        np.testing.assert_array_equal(pp, all_prim[keep])


def test_a_rayscene_pickles_and_copies():
    import copy
    import pickle
    v, f = random_mesh(np.random.default_rng(2))
    rs = RayScene.from_mesh(v, f, accel="bvh")
    o, d = rays_into_box(np.random.default_rng(3))
    for other in (pickle.loads(pickle.dumps(rs)), copy.deepcopy(rs)):
        np.testing.assert_array_equal(other.intersect(o, d).t, rs.intersect(o, d).t)


# ---------------------------------------------------------------- shaped rays, camera rays, threads per call

def test_image_shaped_rays_give_image_shaped_answers():
    from raykernel import camera_rays
    scene = RayScene.from_spheres([(0, 0, 0)], 1.0)
    o, d = camera_rays(eye=(0, -5, 0), look_at=(0, 0, 0), up=(0, 0, 1), fov=40, width=16, height=12)
    assert o.shape == d.shape == (12, 16, 3)
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0)
    h = scene.intersect(o, d)
    assert h.t.shape == h.prim_id.shape == (12, 16) and h.normal.shape == h.points.shape == (12, 16, 3)
    flat = scene.intersect(o.reshape(-1, 3), d.reshape(-1, 3))
    np.testing.assert_array_equal(h.t.reshape(-1), flat.t)
    np.testing.assert_array_equal(h.normal.reshape(-1, 3), flat.normal)
    assert scene.occluded(o, d).shape == scene.count_hits(o, d).shape == (12, 16)
    hit = h.hit
    assert 0.1 < hit.mean() < 0.9
    # the points lie on the sphere; misses are NaN
    np.testing.assert_allclose(np.linalg.norm(h.points[hit], axis=-1), 1.0)
    assert np.isnan(h.points[~hit]).all()
    # a per-ray interval of the same shape, and one origin for every direction
    tmax = np.full((12, 16), 3.9)        # the sphere is 4 away
    assert not scene.occluded(o, d, tmax=tmax).any() and scene.occluded(o, d, tmax=tmax + 1).any()
    np.testing.assert_array_equal(scene.intersect((0, -5, 0), d).t, h.t)
    ray, t, _ = scene.intersect_all(o, d)
    rows, cols = np.unravel_index(ray, (12, 16))
    np.testing.assert_array_equal(np.isfinite(h.t[rows, cols]), True)


def test_camera_rays_look_where_they_should():
    from raykernel import camera_rays
    o, d = camera_rays(eye=(1, 2, 3), look_at=(1, 12, 3), up=(0, 0, 1), fov=90, width=4, height=2)
    np.testing.assert_allclose(o, np.broadcast_to([1.0, 2.0, 3.0], (2, 4, 3)))
    # fov 90: the outer pixel centres at x = +-0.75 of the half-width tan(45) = 1; the top row looks up
    np.testing.assert_allclose(d[0, 0] / d[0, 0, 1], [-0.75, 1.0, 0.25])
    np.testing.assert_allclose(d[1, 3] / d[1, 3, 1], [0.75, 1.0, -0.25])
    for kwargs, words in ((dict(fov=0), "fov"), (dict(width=0), "width"), (dict(look_at=(1, 2, 3)), "differ"),
                          (dict(up=(0, 1, 0)), "parallel"), (dict(height=2.5), "height")):
        args = dict(eye=(1, 2, 3), look_at=(1, 12, 3), up=(0, 0, 1)) | kwargs
        with pytest.raises(RayInputError, match=words):
            camera_rays(**args)


@pytest.mark.parametrize("accel", ["bvh", "lazyoctree"])
def test_threads_per_call_give_the_same_answers(accel):
    scene = Scene()
    scene.root.accel = accel
    v, f = random_mesh(np.random.default_rng(4))
    scene.root.add(TriangleMesh(v, f))
    o, d = rays_into_box(np.random.default_rng(5), 3000)
    one = RayScene(scene, accel)
    two = RayScene(scene, accel)
    a, b = one.intersect(o, d, threads=1), two.intersect(o, d, threads=2)
    np.testing.assert_array_equal(a.t, b.t)
    np.testing.assert_array_equal(a.prim_id, b.prim_id)
    assert one.last_stats == {**two.last_stats, "time.trace": one.last_stats["time.trace"],
                              "time.compile": one.last_stats["time.compile"], "time.load": one.last_stats["time.load"]}
    np.testing.assert_array_equal(one.count_hits(o, d, threads=1), two.count_hits(o, d, threads=2))


# ----------------------------------------------------------------- what a query computes and where it writes

def _mixed_scene():
    """Spheres, a mesh and an instance under a general structure (the general kernel)."""
    rng = np.random.default_rng(11)
    v, f = random_mesh(rng, 60)
    scene = Scene()
    scene.root.add(TriangleMesh(v, f))
    sph = scene.root.spheres
    sph.center, sph.radius, sph.material = rng.uniform(-1, 1, (20, 3)), rng.uniform(0.05, 0.2, 20), np.zeros(20, np.int32)
    part = Group(name="part")
    part.add(TriangleMesh(v[:30] * 0.5, f[:10]))
    m = np.eye(4)
    m[:3, 3] = (0.3, -0.2, 0.1)
    scene.root.children.append(Instance(part, m))
    return scene


QUERY_SCENES = {
    "mesh kernel": lambda: RayScene.from_mesh(*random_mesh(np.random.default_rng(5))),
    "general": lambda: RayScene.from_scene(_mixed_scene(), "grid"),
    "lazy": lambda: RayScene.from_scene(_mixed_scene(), "lazyoctree"),
}


@pytest.mark.parametrize("which", list(QUERY_SCENES))
@pytest.mark.parametrize("fields", [("t",), ("prim_id",), ("t", "geom_id", "kind"), ("normal",), ("uv", "inst_id"),
                                    ("shading_normal", "prim_id")])
def test_fields_computes_only_what_is_asked_and_the_same(which, fields):
    scene = QUERY_SCENES[which]()
    o, d = rays_into_box(np.random.default_rng(2), 600)
    full = scene.intersect(o, d)
    part = scene.intersect(o, d, fields=fields)
    assert np.isfinite(full.t).sum() > 50
    np.testing.assert_array_equal(part.t, full.t)
    for name in ("prim_id", "geom_id", "inst_id", "kind", "uv", "normal", "shading_normal"):
        if name in fields:
            np.testing.assert_array_equal(getattr(part, name), getattr(full, name))
        else:
            assert getattr(part, name) is None


@pytest.mark.parametrize("which", list(QUERY_SCENES))
def test_float32_outputs_are_the_double_results_rounded(which):
    scene = QUERY_SCENES[which]()
    o, d = rays_into_box(np.random.default_rng(3), 500)
    full = scene.intersect(o, d)
    small = scene.intersect(o, d, dtype="float32")
    for name in ("t", "uv", "normal", "shading_normal"):
        assert getattr(small, name).dtype == np.float32
        np.testing.assert_array_equal(getattr(small, name), getattr(full, name).astype(np.float32))
    for name in ("prim_id", "geom_id", "inst_id", "kind"):
        assert getattr(small, name).dtype == np.int32
        np.testing.assert_array_equal(getattr(small, name), getattr(full, name))


@pytest.mark.parametrize("which", list(QUERY_SCENES))
@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_out_fills_the_given_arrays_in_place(which, dtype):
    scene = QUERY_SCENES[which]()
    rng = np.random.default_rng(4)
    o1, d1 = rays_into_box(rng, 300)
    o2, d2 = rays_into_box(rng, 300)
    hits = scene.intersect(o1, d1, fields=("t", "prim_id", "normal"), dtype=dtype)
    arrays = (hits.t, hits.prim_id, hits.normal)
    again = scene.intersect(o2, d2, fields=("t", "prim_id", "normal"), dtype=dtype, out=hits)
    assert again is hits and all(a is b for a, b in zip(arrays, (hits.t, hits.prim_id, hits.normal)))
    fresh = scene.intersect(o2, d2, fields=("t", "prim_id", "normal"), dtype=dtype)
    for name in ("t", "prim_id", "normal"):
        np.testing.assert_array_equal(getattr(hits, name), getattr(fresh, name))
    assert not np.array_equal(fresh.t, scene.intersect(o1, d1, fields="t", dtype=dtype).t)
    np.testing.assert_array_equal(hits.origins, o2)


def test_out_of_another_shape_dtype_or_fields_is_refused():
    scene = RayScene.from_spheres([(0, 0, 0)], 1.0)
    o, d = np.zeros((4, 3)) - 3, np.ones((4, 3))
    hits = scene.intersect(o, d, fields=("t", "prim_id"))
    with pytest.raises(RayInputError, match=r"out.t must be a writable contiguous float64 array of shape \(5,\)"):
        scene.intersect(np.zeros((5, 3)) - 3, np.ones((5, 3)), fields=("t", "prim_id"), out=hits)
    with pytest.raises(RayInputError, match=r"out.t must be a writable contiguous float32"):
        scene.intersect(o, d, fields=("t", "prim_id"), dtype="float32", out=hits)
    with pytest.raises(RayInputError, match=r"out.normal is None"):
        scene.intersect(o, d, fields=("t", "normal"), out=hits)
    with pytest.raises(RayInputError, match=r"out must be the Hits"):
        scene.intersect(o, d, out=np.zeros(4))
    hits.t = hits.t[::-1]
    with pytest.raises(RayInputError, match=r"out.t must be a writable contiguous"):
        scene.intersect(o, d, fields=("t", "prim_id"), out=hits)
    with pytest.raises(RayInputError, match=r"fields: no Hits field 'distance'"):
        scene.intersect(o, d, fields=("t", "distance"))
    with pytest.raises(RayInputError, match=r"dtype must be one of float64, float32"):
        scene.intersect(o, d, dtype="float16")


@pytest.mark.parametrize("which", list(QUERY_SCENES))
def test_one_bound_for_every_ray_equals_a_bound_per_ray(which):
    scene = QUERY_SCENES[which]()
    o, d = rays_into_box(np.random.default_rng(6), 400)
    n = len(o)
    for lo, hi in ((0.3, 0.9), (0.0, np.inf), (0.5, 0.5)):
        one = scene.intersect(o, d, tmin=lo, tmax=hi)
        each = scene.intersect(o, d, tmin=np.full(n, lo), tmax=np.full(n, hi))
        np.testing.assert_array_equal(one.t, each.t)
        np.testing.assert_array_equal(one.prim_id, each.prim_id)
        assert np.array_equal(scene.occluded(o, d, lo, hi), scene.occluded(o, d, np.full(n, lo), np.full(n, hi)))
        assert np.array_equal(scene.count_hits(o, d, lo, hi), scene.count_hits(o, d, np.full(n, lo), np.full(n, hi)))
    with pytest.raises(RayInputError, match=r"tmin > tmax for ray 2: 1.0 > 0.5"):
        scene.intersect(o[:4], d[:4], tmin=1.0, tmax=[1.0, 2.0, 0.5, 3.0])

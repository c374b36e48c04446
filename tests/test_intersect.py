"""Whole scenes through raykernel.engine.traverse.cast_rays.

Every accelerator against "list" (same primitive, same t), nested aggregates
against the same scene merged into one aggregate, instances against scenes
whose geometry the test transforms itself, everything against the
brute-force reference (tests/reference.py), the counters, and the limits of
flatten (nesting depth, cycles).
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import reference as ref
from support import (
    RTOL,
    affine,
    assert_close_hits,
    cast_interval,
    fill_box,
    random_scene,
    scene_rays,
    similarity,
)

from raykernel import Group, Instance, Scene, SceneError, TriangleMesh
from raykernel.aggregates.walk import MAX_NESTING
from raykernel.engine.flatten import Geometry, flatten
from raykernel.engine.traverse import cast_rays
from raykernel.geometry import counters as C
from raykernel.geometry.primitives import CONE, KIND_SHIFT, PATCH, POLYGON, SPHERE, TRIANGLE

ACCELS = ["bvh", "bvh(leaf=1)", "bvh(leaf=8, bins=4)"]
KINDS = (SPHERE, POLYGON, PATCH, CONE, TRIANGLE)


# ----------------------------------------------------------------- casting and comparing

def assert_sane(result, tmin, tmax):
    t, kind, index, inst = result[:4]
    n = len(t)
    tmin = np.broadcast_to(tmin, (n,))
    tmax = np.broadcast_to(tmax, (n,))
    assert not np.isnan(t).any()
    hit = np.isfinite(t)
    assert np.all(t[~hit] == np.inf) and np.all(kind[~hit] == -1)
    assert np.all((t[hit] >= tmin[hit]) & (t[hit] <= tmax[hit]))
    assert np.all(np.isin(kind[hit], KINDS)) and np.all(index[hit] >= 0)


_REFERENCE_CACHE: dict = {}


def reference_answer(key, scene, o, d, tmin, tmax, delta=1e-6):
    """The reference's world primitives, every t of every ray with every primitive, the closest
    hits and the stable rays; computed once per `key` (tests that share a scene share it)."""
    if key not in _REFERENCE_CACHE:
        prims = ref.world_primitives(scene)
        hits = ref.all_hits(prims, o, d, tmin, tmax)
        which = ref.closest(prims, hits)
        t = np.array([hits[j, r] if j >= 0 else np.inf for r, j in enumerate(which)], np.float64)
        want = (t, *ref.identities(prims, which))
        stable = ~ref.unstable(prims, o, d, delta, tmin, tmax)
        _REFERENCE_CACHE[key] = prims, hits, want, stable
    return _REFERENCE_CACHE[key]


def compare_with_reference(key, scene, o, d, tmin, tmax, accel, min_stable=0.9):
    """Kernel (with `accel`) against the reference on the stable rays; returns the kernel result."""
    got = cast_interval(scene, o, d, tmin, tmax, accel)
    assert_sane(got, tmin, tmax)
    _, _, want, stable = reference_answer(key, scene, o, d, tmin, tmax)
    assert stable.mean() >= min_stable, f"only {stable.sum()} of {len(stable)} rays are stable"
    assert_close_hits(got, want, stable, f"{accel} against the reference")
    return got, stable


def check_any_hit(key, scene, o, d, tmin, tmax, accel, closest_result):
    """any_hit reports a hit exactly when there is a closest hit in [tmin, tmax], and the hit it
    reports is a real one: that primitive is met at that t (within RTOL) according to the reference."""
    t, kind, index, inst, _ = cast_interval(scene, o, d, tmin, tmax, accel, any_hit=True)
    assert_sane((t, kind, index, inst), tmin, tmax)
    assert np.array_equal(np.isfinite(t), np.isfinite(closest_result[0])), f"any_hit with {accel}"
    assert np.all(t[np.isfinite(t)] >= closest_result[0][np.isfinite(t)])
    prims, hits, _, stable = reference_answer(key, scene, o, d, tmin, tmax)
    for r in np.flatnonzero(np.isfinite(t) & stable):
        ts = [hits[i, r] for i, p in enumerate(prims) if (p.kind, p.index, p.instance) == (kind[r], index[r], inst[r])]
        assert any(abs(x - t[r]) <= RTOL * t[r] for x in ts), f"any_hit ray {r}: no such hit"


# ----------------------------------------------------------------- accelerators against "list"

@pytest.fixture(scope="module", params=[0, 1, 2])
def mixed(request):
    """A random scene of every primitive kind, rays, the "list" answer and a cache key."""
    seed = request.param
    scene = random_scene(seed)
    o, d, tmin, tmax = scene_rays(np.random.default_rng(100 + seed), 900)
    return scene, o, d, tmin, tmax, cast_interval(scene, o, d, tmin, tmax, "list"), ("mixed", seed)


@pytest.mark.parametrize("accel", ACCELS)
def test_accels_agree_with_list(mixed, accel):
    scene, o, d, tmin, tmax, listed, _ = mixed
    got = cast_interval(scene, o, d, tmin, tmax, accel)
    assert_close_hits(got, listed, what=f"{accel} against list")
    assert np.isfinite(listed[0]).mean() > 0.3
    assert set(listed[1][np.isfinite(listed[0])]) == set(KINDS)


@pytest.mark.parametrize("accel", ["list"] + ACCELS)
def test_any_hit_agrees_with_closest_hit(mixed, accel):
    scene, o, d, tmin, tmax, listed, key = mixed
    # finite tmax everywhere so that the interval matters
    tmax = np.minimum(tmax, np.random.default_rng(5).uniform(0.5, 12.0, len(o)))
    closest = cast_interval(scene, o, d, tmin, tmax, accel)
    check_any_hit(key + ("finite tmax",), scene, o, d, tmin, tmax, accel, closest)


@pytest.mark.parametrize("accel", ["list", "bvh"])
def test_mixed_scene_against_reference(mixed, accel):
    scene, o, d, tmin, tmax, _, key = mixed
    compare_with_reference(key, scene, o, d, tmin, tmax, accel)


def test_exact_ties_go_to_the_smaller_reference():
    """Duplicated primitives at the same place: every accelerator reports the smaller index,
    and for a duplicated instance the smaller instance id."""
    rng = np.random.default_rng(7)
    scene = Scene()
    g = fill_box(Group(name="g"), rng, (4, 2, 3, 1, 4), extent=1.0)
    for s in (g.spheres, g.cones, g.polygons, g.patches):
        s.freeze()
    # each sphere, cone and polygon twice (the copy later in the arrays)
    g.spheres.add(g.spheres.center[0], g.spheres.radius[0])
    g.cones.add(g.cones.base[0], g.cones.base_radius[0], g.cones.apex[0], g.cones.apex_radius[0])
    g.polygons.add(g.polygons.polygon(0)[0])
    m = similarity(rng)
    scene.root.add(Instance(g, m))
    scene.root.add(Instance(g, m.copy()))
    o, d, tmin, tmax = scene_rays(rng, 600, m[:3, 3], 2.0)
    listed = cast_interval(scene, o, d, tmin, tmax, "list")
    hit = np.isfinite(listed[0])
    assert hit.sum() > 50
    assert np.all(listed[3][hit] == 0), "the first instance wins every tie"
    n_sph, n_cone, n_poly = len(g.spheres) - 1, len(g.cones) - 1, len(g.polygons) - 1
    assert not np.any((listed[1] == SPHERE) & (listed[2] == n_sph))
    assert not np.any((listed[1] == CONE) & (listed[2] == n_cone))
    assert not np.any((listed[1] == POLYGON) & (listed[2] == n_poly))
    for accel in ACCELS:
        assert_close_hits(cast_interval(scene, o, d, tmin, tmax, accel), listed, what=accel)


def test_grid_aligned_rays_on_shared_mesh_edges_tie_like_list():
    n = 8
    xs = np.arange(n + 1) / n
    verts = np.array([(x, y, 0.0) for y in xs for x in xs])
    faces = []
    for j in range(n):
        for i in range(n):
            a = j * (n + 1) + i
            faces += [(a, a + 1, a + n + 2), (a, a + n + 2, a + n + 1)]
    scene = Scene()
    scene.root.add(TriangleMesh(verts, np.array(faces)))
    pts = [(k / n, y) for k in range(1, n) for y in (0.3125, 0.5625, 0.71875)]
    o = np.array([(x, y, 2.0) for x, y in pts] + [(y, x, 2.0) for x, y in pts])
    d = np.tile([0.0, 0.0, -1.0], (len(o), 1))
    listed = cast_interval(scene, o, d)
    assert np.all(listed[0] == 2.0)
    assert_close_hits(cast_interval(scene, o, d, accel="bvh(leaf=1)"), listed, what="bvh(leaf=1)")


# ----------------------------------------------------------------- nested aggregates

def three_level_scene(seed: int, specs) -> Scene:
    """Three levels: the root (specs[0]) holds primitives and three child groups (specs[1]),
    each holding primitives and two grandchildren (specs[2]). None merges a group into its parent."""
    rng = np.random.default_rng(seed)
    scene = Scene()
    scene.root.accel = specs[0]
    fill_box(scene.root, rng, (5, 2, 3, 1, 4), extent=5.0)
    for i in range(3):
        child = fill_box(Group(name=f"c{i}", accel=specs[1]), rng, (4, 2, 2, 1, 4),
                           center=rng.uniform(-3, 3, 3), extent=1.5)
        for j in range(2):
            child.add(fill_box(Group(name=f"c{i}{j}", accel=specs[2]), rng, (3, 1, 2, 1, 3),
                                 center=rng.uniform(-3, 3, 3), extent=0.8))
        scene.root.add(child)
    return scene


NESTINGS = [("list", "bvh", "list"), ("bvh", "list", "bvh"), ("bvh", "bvh", "bvh"), ("list", "list", "list"),
            ("bvh(leaf=1)", "bvh(leaf=8, bins=4)", "list"), ("list", None, "bvh"), ("bvh", "bvh", None)]


@pytest.mark.parametrize("specs", NESTINGS, ids=["/".join(str(s) for s in n) for n in NESTINGS])
def test_nested_aggregates_agree_with_one_flat_aggregate(specs):
    flat = three_level_scene(3, ("list", None, None))
    nested = three_level_scene(3, specs)
    geo, stats = flatten(nested, "bvh")
    assert stats["build.nesting"] == 1 + (specs[1] is not None) + (specs[2] is not None)
    o, d, tmin, tmax = scene_rays(np.random.default_rng(4), 600)
    want = cast_interval(flat, o, d, tmin, tmax)
    got = cast_rays(geo, o, d, tmin, tmax)
    assert_close_hits(got, want, what=f"nested {specs}")
    any_got = cast_rays(geo, o, d, tmin, tmax, True)
    assert np.array_equal(np.isfinite(any_got[0]), np.isfinite(want[0]))


def test_nested_aggregates_against_reference():
    scene = three_level_scene(5, ("list", "bvh", "list"))
    o, d, tmin, tmax = scene_rays(np.random.default_rng(6), 600)
    compare_with_reference(("nested", 5), scene, o, d, tmin, tmax, "bvh")


# ----------------------------------------------------------------- instances

def instanced_scene(seed: int, root_accel="bvh", group_accel=None):
    """G (every kind) placed by four similarity maps, H (flat kinds only) by three general
    affine maps, plus primitives of the root's own."""
    rng = np.random.default_rng(seed)
    scene = Scene()
    scene.root.accel = root_accel
    fill_box(scene.root, rng, (4, 2, 2, 1, 4), extent=5.0)
    g = fill_box(Group(name="G", accel=group_accel), rng, (5, 3, 3, 2, 8), extent=1.0)
    h = fill_box(Group(name="H", accel=group_accel), rng, (0, 0, 4, 2, 10), extent=1.0, curved=False)
    mirror = np.diag([-1.0, 1.0, 1.0, 1.0])
    for k in range(4):
        scene.root.add(Instance(g, similarity(rng) @ (mirror if k == 3 else np.eye(4))))
    for k in range(3):
        scene.root.add(Instance(h, affine(rng) @ (mirror if k == 2 else np.eye(4))))
    return scene


def nested_instance_scene(seed: int):
    """P holds instances of G and H and primitives; the root places P twice and G once more."""
    rng = np.random.default_rng(seed)
    scene = Scene()
    scene.root.accel = "list"
    fill_box(scene.root, rng, (3, 1, 2, 1, 3), extent=5.0)
    g = fill_box(Group(name="G", accel="bvh"), rng, (4, 2, 3, 1, 6), extent=1.0)
    h = fill_box(Group(name="H"), rng, (0, 0, 3, 1, 6), extent=1.0, curved=False)
    p = fill_box(Group(name="P", accel="bvh(leaf=1)"), rng, (3, 1, 2, 1, 3), extent=2.0)
    p.add(Instance(g, similarity(rng, shift=1.5)))
    p.add(Instance(g, similarity(rng, shift=1.5)))
    p.add(Instance(h, affine(rng, shift=1.5)))
    scene.root.add(Instance(p, similarity(rng, (0.7, 1.3))))
    scene.root.add(Instance(p, similarity(rng, (0.7, 1.3))))
    scene.root.add(Instance(g, similarity(rng)))
    return scene


INSTANCE_CASES = [("bvh", None), ("list", None), ("list", "bvh"), ("bvh", "list"), ("bvh(leaf=1)", "bvh")]


@pytest.mark.parametrize("root_accel,group_accel", INSTANCE_CASES)
def test_instances_against_transformed_geometry(root_accel, group_accel):
    scene = instanced_scene(8, root_accel, group_accel)
    o, d, tmin, tmax = scene_rays(np.random.default_rng(9), 600)
    got, stable = compare_with_reference(("instances", 8), scene, o, d, tmin, tmax, root_accel)
    # the same primitives transformed by the test, in one flat aggregate
    flat, identity = ref.flattened_scene(ref.world_primitives(scene))
    ft, fkind, findex, finst, _ = cast_interval(flat, o, d, tmin, tmax, "list")
    mapped = np.array([identity[(k, i)] if k >= 0 else (-1, -1, -1) for k, i in zip(fkind, findex)])
    assert np.all(finst == -1)
    assert_close_hits(got, (ft, mapped[:, 0], mapped[:, 1], mapped[:, 2]), stable, "instances against flattened")
    hit = np.isfinite(got[0])
    assert set(got[3][hit]) == {-1, 0, 1, 2, 3, 4, 5, 6}, "the root and every instance are hit somewhere"


def test_nested_instances():
    scene = nested_instance_scene(12)
    o, d, tmin, tmax = scene_rays(np.random.default_rng(13), 900)
    got, stable = compare_with_reference(("nested instances", 12), scene, o, d, tmin, tmax, "bvh")
    flat, identity = ref.flattened_scene(ref.world_primitives(scene))
    ft, fkind, findex, _, _ = cast_interval(flat, o, d, tmin, tmax, "bvh")
    mapped = np.array([identity[(k, i)] if k >= 0 else (-1, -1, -1) for k, i in zip(fkind, findex)])
    assert_close_hits(got, (ft, mapped[:, 0], mapped[:, 1], mapped[:, 2]), stable, "nested instances")
    for accel in ["list", "bvh(leaf=8, bins=4)"]:
        assert_close_hits(cast_interval(scene, o, d, tmin, tmax, accel), got, what=accel)
        any_hit = cast_interval(scene, o, d, tmin, tmax, accel, any_hit=True)
        assert np.array_equal(np.isfinite(any_hit[0]), np.isfinite(got[0]))
    # the two instances of G inside P (ids 0 and 1), H inside P (2), P twice (3, 4), G at the root (5)
    hit = np.isfinite(got[0])
    assert set(got[3][hit]) == {-1, 0, 1, 2, 3, 4, 5}


def test_instance_maps_the_ray_not_the_t():
    """t is measured along the world ray: a unit sphere scaled by 2 and moved to x = 10."""
    g = Group(name="unit")
    g.spheres.add((0, 0, 0), 1.0)
    scene = Scene()
    m = np.diag([2.0, 2.0, 2.0, 1.0])
    m[:3, 3] = (10, 0, 0)
    scene.root.add(Instance(g, m))
    o = np.array([[0.0, 0, 0], [0.0, 0, 0], [10.0, 0, 0], [10.0, 5, 0]])
    d = np.array([[1.0, 0, 0], [4.0, 0, 0], [0.0, 0, 0.5], [0.0, -1, 0]])
    t, kind, index, inst, _ = cast_interval(scene, o, d)
    assert t.tolist() == [8.0, 2.0, 4.0, 3.0] and inst.tolist() == [0, 0, 0, 0]


# ----------------------------------------------------------------- empty scenes and groups

@pytest.mark.parametrize("accel", ["list"] + ACCELS)
def test_empty_scene(accel):
    scene = Scene()
    o, d, tmin, tmax = scene_rays(np.random.default_rng(14), 300)
    t, kind, index, inst, counts = cast_interval(scene, o, d, tmin, tmax, accel)
    assert np.all(t == np.inf) and np.all(kind == -1) and np.all(index == -1) and np.all(inst == -1)
    assert counts[C.RAYS_CAST] == 300
    assert counts[C.TESTS:C.TESTS + 5].sum() == 0
    t_any = cast_interval(scene, o, d, tmin, tmax, accel, any_hit=True)[0]
    assert np.all(t_any == np.inf)


def _with_empty_children(root_accel, child, seed=15):
    """fill_box primitives in a root of structure `root_accel` with an empty child (`child`: "group",
    a group naming no structure; "instance", an instance of an empty group; else an empty group of
    that spec) and a list group holding a sphere and an empty bvh group. child None: the same
    primitives and sphere without any empty group."""
    rng = np.random.default_rng(seed)
    scene = Scene()
    scene.root.accel = root_accel
    fill_box(scene.root, rng, (6, 2, 3, 1, 6), extent=3.0)
    if child == "group":
        scene.root.add(Group(name="empty"))
    elif child == "instance":
        scene.root.add(Instance(Group(name="empty"), similarity(rng)))
    elif child is not None:
        scene.root.add(Group(name="empty", accel=child))
    holder = Group(name="holder", accel="list")
    holder.spheres.add((0, 0, 0), 0.5)
    if child is not None:
        holder.add(Group(name="inner empty", accel="bvh"))
    scene.root.add(holder)
    return scene


EMPTY_CHILDREN = [(root, child) for root in ("list", "bvh") for child in ("group", "list", "bvh", "instance")]


@pytest.mark.parametrize("root_accel,child", EMPTY_CHILDREN)
def test_empty_child_groups_change_nothing(root_accel, child):
    scene = _with_empty_children(root_accel, child)
    plain = _with_empty_children(root_accel, None)          # no empty group anywhere
    o, d, tmin, tmax = scene_rays(np.random.default_rng(16), 400, extent=3.0)
    want = cast_interval(plain, o, d, tmin, tmax, "list")
    assert np.isfinite(want[0]).sum() > 100
    for accel in ("list", "bvh"):
        got = cast_interval(scene, o, d, tmin, tmax, accel)
        assert_close_hits(got, want, what=f"{root_accel} root with an empty {child}")


# ----------------------------------------------------------------- a scene spanning 1e-3 .. 1e7

def spanning_scene(accel=None) -> Scene:
    """Sizes from 1e-3 to 1e7: a sky sphere of radius 1e7 seen from inside, a ground polygon
    1e7 wide, buildings of size 1..100 up to 1e4 away, and millimetre things near the origin."""
    rng = np.random.default_rng(17)
    scene = Scene()
    scene.root.accel = accel
    root = scene.root
    root.spheres.add((0, 0, 0), -1e7)
    root.polygons.add([(-1e7, -1e7, -2.0), (1e7, -1e7, -2.0), (1e7, 1e7, -2.0), (-1e7, 1e7, -2.0)])
    for _ in range(20):
        c = rng.uniform(-1e4, 1e4, 3) * np.array([1, 1, 0.01])
        s = 10 ** rng.uniform(0, 2)
        if rng.uniform() < 0.5:
            root.spheres.add(c, s)
        else:
            root.cones.add(c, s, c + (0, 0, 3 * s), 0.5 * s)
    city = Group(name="city", accel="bvh")
    fill_box(city, rng, (10, 5, 6, 2, 10), center=(300.0, -200.0, 20.0), extent=200.0)
    root.add(city)
    small = Group(name="small", accel="bvh")
    fill_box(small, rng, (10, 4, 6, 2, 10), center=(0.02, 0.01, 0.0), extent=0.02)
    fill_box(small, rng, (10, 4, 6, 2, 10), center=(0.0, 0.0, 0.0), extent=0.002)
    root.add(small)
    return scene


def spanning_rays(rng, n=600):
    o = rng.normal(size=(n, 3)) * np.array([0.01, 0.01, 0.005])
    d = rng.normal(size=(n, 3))
    k = n // 3
    d[:k] = rng.uniform(-0.02, 0.04, (k, 3)) - o[:k]                # at the millimetre things
    d[k:2 * k, 2] = np.abs(d[k:2 * k, 2]) * 0.02                      # towards the horizon
    return o, d


def test_spanning_scales():
    scene = spanning_scene()
    o, d = spanning_rays(np.random.default_rng(18))
    listed = cast_interval(scene, o, d, accel="list")
    assert np.all(np.isfinite(listed[0])), "the sky sphere catches every ray"
    for accel in ACCELS:
        assert_close_hits(cast_interval(scene, o, d, accel=accel), listed, what=accel)
    prims = ref.world_primitives(scene)
    want = ref.cast(prims, o, d)
    sizes = np.array([p.size() for p in prims])
    # 1e-6 of the smallest size: far above rounding even at 1e7
    stable = ~ref.unstable(prims, o, d, 1e-6 * sizes.min())
    assert stable.mean() > 0.9
    assert_close_hits(listed, want, stable, "spanning scene against the reference")
    t = listed[0][stable]
    assert t.min() < 1e-2 and t.max() > 1e6


# ----------------------------------------------------------------- counters

def test_counters_list_tests_every_primitive_for_every_ray_in_its_bounds():
    scene = random_scene(19, accel="list")
    geo, _ = flatten(scene, "bvh")
    n_by_kind = {SPHERE: len(geo.sph_radius), CONE: len(geo.cone_r0), TRIANGLE: len(geo.tri_faces),
                 POLYGON: int(np.sum(geo.refs >> KIND_SHIFT == POLYGON)),
                 PATCH: int(np.sum(geo.refs >> KIND_SHIFT == PATCH))}
    n_prims = sum(n_by_kind.values())
    lo, hi = geo.agg_bounds[geo.root, :3], geo.agg_bounds[geo.root, 3:]
    rng = np.random.default_rng(20)
    n = 3000
    # every ray starts inside the root's bounds
    o = lo + (hi - lo) * rng.uniform(0.01, 0.99, (n, 3))
    d = rng.normal(size=(n, 3))
    counts = cast_rays(geo, o, d)[4]
    assert counts[C.RAYS_CAST] == n
    assert counts[C.BOUNDS_TESTS] == n
    for k in KINDS:
        assert counts[C.TESTS + k] == n * n_by_kind[k], C.NAMES[C.TESTS + k]
    assert counts[C.TESTS:C.TESTS + 5].sum() == n * n_prims
    # from outside: rays aimed at the middle of the box enter it, rays pointing away do not
    centre = 0.5 * (lo + hi)
    far = centre + 3 * (hi - lo) * ref.unit(rng.normal(size=(n, 3))).astype(np.float64)
    towards = rng.uniform(size=n) < 0.4
    d = np.where(towards[:, None], centre - far, far - centre)
    counts = cast_rays(geo, far, d)[4]
    assert counts[C.RAYS_CAST] == n and counts[C.BOUNDS_TESTS] == n
    assert counts[C.TESTS:C.TESTS + 5].sum() == towards.sum() * n_prims


def _geometry_npz(geo: Geometry, path, **extra):
    np.savez(path, **{f"geo_{k}": np.asarray(v) for k, v in geo._asdict().items()}, **extra)


CAST_IN_SUBPROCESS = textwrap.dedent("""
    import sys
    import numpy as np
    from raykernel.engine.flatten import Geometry
    from raykernel.engine.traverse import cast_rays
    data = np.load(sys.argv[1])
    fields = {k[4:]: data[k] for k in data.files if k.startswith("geo_")}
    fields["root"] = int(fields["root"])
    geo = Geometry(**fields)
    out = {}
    for any_hit in (False, True):
        t, kind, index, inst, counts = cast_rays(geo, data["o"], data["d"], data["tmin"], data["tmax"], any_hit)
        out.update({f"{name}_{int(any_hit)}": v for name, v in
                    (("t", t), ("kind", kind), ("index", index), ("inst", inst), ("counts", counts))})
    import numba
    np.savez(sys.argv[2], threads=numba.get_num_threads(), **out)
""")


def test_counters_identical_between_runs_and_thread_counts(tmp_path):
    scene = nested_instance_scene(21)
    geo, _ = flatten(scene, "bvh")
    o, d, tmin, tmax = scene_rays(np.random.default_rng(22), 5000)
    here = {}
    for any_hit in (False, True):
        first = cast_rays(geo, o, d, tmin, tmax, any_hit)
        again = cast_rays(geo, o, d, tmin, tmax, any_hit)
        for a, b in zip(first, again):
            assert np.array_equal(a, b)
        assert first[4][C.RAYS_CAST] == 5000
        here[any_hit] = first
    _geometry_npz(geo, tmp_path / "in.npz", o=o, d=d, tmin=tmin, tmax=tmax)
    procs = {}
    for threads in (1, 2):
        env = dict(os.environ, NUMBA_NUM_THREADS=str(threads))
        procs[threads] = subprocess.Popen([sys.executable, "-c", CAST_IN_SUBPROCESS, str(tmp_path / "in.npz"),
                                           str(tmp_path / f"out{threads}.npz")], env=env,
                                          stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    for threads, proc in procs.items():
        out, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, err[-2000:]
        res = np.load(tmp_path / f"out{threads}.npz")
        assert int(res["threads"]) == threads
        for any_hit in (False, True):
            for name, mine in zip(("t", "kind", "index", "inst", "counts"), here[any_hit]):
                assert np.array_equal(res[f"{name}_{int(any_hit)}"], mine), (threads, any_hit, name)


# ----------------------------------------------------------------- nesting limit and cycles

def chain(levels: int, instanced: bool = False) -> Scene:
    """`levels` aggregates nested one inside the next (the root counts), alternating list and
    bvh, each holding two spheres; through instances that each move their group by +1 in x."""
    scene = Scene()
    scene.root.accel = "list"
    group = scene.root
    for k in range(levels):
        group.spheres.add((0.0, 0.0, 3.0 * k), 0.5)
        group.spheres.add((0.0, 2.0, 3.0 * k), 0.5)
        if k + 1 < levels:
            child = Group(name=f"level{k + 1}", accel="bvh" if k % 2 == 0 else "list")
            if instanced:
                m = np.eye(4)
                m[0, 3] = 1.0
                group.add(Instance(child, m))
            else:
                group.add(child)
            group = child
    return scene


@pytest.mark.parametrize("instanced", [False, True], ids=["groups", "instances"])
def test_nesting_limit(instanced):
    assert MAX_NESTING == 16
    geo, stats = flatten(chain(16, instanced), "bvh")
    assert stats["build.nesting"] == 16
    # every level's sphere is found, the deepest one included
    levels = np.arange(16)
    x = levels * (1.0 if instanced else 0.0)
    o = np.column_stack([x, np.full(16, -5.0), 3.0 * levels])
    d = np.tile([0.0, 1.0, 0.0], (16, 1))
    t, kind, index, inst, _ = cast_rays(geo, o, d)
    assert np.all(t == 4.5) and np.all(kind == SPHERE)
    # instances are numbered as flatten finishes them: the deepest first
    assert np.all(inst == (np.where(levels == 0, -1, 15 - levels) if instanced else -1))
    with pytest.raises(SceneError, match="nest"):
        flatten(chain(17, instanced), "bvh")


def test_cycles_are_scene_errors():
    g = Group(name="g", accel="list")
    g.spheres.add((0, 0, 0), 1.0)
    g.add(Instance(g, np.eye(4)))
    scene = Scene()
    scene.root.add(Instance(g, np.eye(4)))
    with pytest.raises(SceneError, match="cycle"):
        flatten(scene, "bvh")
    # through a second group, instanced and plain, with and without an accel spec
    for spec in (None, "bvh"):
        a, b = Group(name="a", accel=spec), Group(name="b", accel=spec)
        a.spheres.add((0, 0, 0), 1.0)
        a.add(Instance(b, np.eye(4)))
        b.add(a)
        scene = Scene()
        scene.root.add(a)
        with pytest.raises(SceneError, match="cycle"):
            flatten(scene, "list")
        c = Group(name="c", accel=spec)
        c.spheres.add((0, 0, 0), 1.0)
        c.add(c)
        scene = Scene()
        scene.root.add(c)
        with pytest.raises(SceneError, match="cycle"):
            flatten(scene, "bvh")
    # the root instancing itself
    scene = Scene()
    scene.root.spheres.add((0, 0, 0), 1.0)
    scene.root.add(Instance(scene.root, np.eye(4)))
    with pytest.raises(SceneError, match="cycle"):
        flatten(scene, "list")

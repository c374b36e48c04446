"""The counters the cost model prices besides tests, steps and bounds: the corners a polygon
test walks (polygon.corners) and the tests that found their primitive (hits.KIND), against
brute force on one primitive under every structure kind."""

from __future__ import annotations

import math

import numpy as np
import pytest
import reference as ref

import raykernel
from raykernel import RayScene, Scene
from raykernel.analysis import costmodel
from raykernel.aggregates import rc as rc_module
from raykernel.aggregates.bvh import walked_wide
from raykernel.aggregates.registry import COUNTER_NAMES
from raykernel.geometry import polybands

KINDS = ["list", "bvh", "grid", "octree", "hgrid", "hybrid", "rc", "lazyoctree"]


def _star(n: int, scale: float = 1.0) -> np.ndarray:
    """A concave star of n corners in the plane z = 0 (n even: points and notches alternate)."""
    a = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    r = np.where(np.arange(n) % 2 == 0, 1.0, 0.45) * scale
    return np.stack([r * np.cos(a), r * np.sin(a), np.zeros(n)], axis=1)


def _toward(rng, count: int, scale: float):
    """Rays from above aimed at points of the plane z = 0 in and around the star."""
    origins = np.column_stack([rng.uniform(-2, 2, count) * scale, rng.uniform(-2, 2, count) * scale,
                               np.full(count, 3.0 * scale)])
    aims = np.column_stack([rng.uniform(-1.2, 1.2, count) * scale, rng.uniform(-1.2, 1.2, count) * scale,
                            np.zeros(count)])
    return origins, aims - origins


def _stats(scene, accel, origins, directions):
    """Every counter of one query (last_stats leaves out those that stayed 0)."""
    rs = RayScene(scene, accel)
    rs.intersect(origins, directions)
    return {name: rs.last_stats.get(name, 0) for name in list(COUNTER_NAMES.values()) + ["rays.cast"]}


@pytest.mark.parametrize("n", [12, 38])
@pytest.mark.parametrize("scale", [1e-6, 1.0, 1e6])
@pytest.mark.parametrize("accel", KINDS)
def test_a_polygon_test_walks_its_corners_only_where_the_ray_meets_its_plane(accel, scale, n):
    """12 corners: every test walks them all; 38: the test walks its bins' edges
    (test_polybands.py counts them exactly), fewer than the corners."""
    scene = Scene()
    scene.root.polygons.add(_star(n, scale))
    rng = np.random.default_rng(7)
    origins, directions = _toward(rng, 400, scale)
    s = _stats(scene, accel, origins, directions)
    want_hits = int(np.isfinite(ref.hit_polygon(_star(n, scale), origins, directions)).sum())
    assert 50 < want_hits < 350
    assert s["hits.polygon"] == want_hits
    # every ray aimed at the plane meets it in range wherever it is tested
    assert s["tests.polygon"] >= want_hits
    if n < polybands.MIN_CORNERS:
        assert s["polygon.corners"] == n * s["tests.polygon"]
    else:
        assert 0 < s["polygon.corners"] < n * s["tests.polygon"] / 2
    # rays pointing away from the plane, and grazing rays in it, walk no corner and hit nothing
    away = _stats(scene, accel, origins, -directions)
    flat = np.column_stack([rng.uniform(-2, 2, 100), rng.uniform(-2, 2, 100), np.zeros(100)]) * scale
    grazing = _stats(scene, accel, flat - np.array([3.0 * scale, 0.0, 0.0]), np.tile([1.0, 0.3, 0.0], (100, 1)))
    assert grazing["tests.polygon"] > 0      # tested: their boxes hold the plane
    for other in (away, grazing):
        assert other["polygon.corners"] == 0 and other["hits.polygon"] == 0


@pytest.mark.parametrize("accel", KINDS)
def test_sphere_and_triangle_hits_equal_brute_force(accel):
    scene = Scene()
    scene.root.spheres.add((0.0, 0.0, 0.0), 1.0)
    scene.root.add(raykernel.TriangleMesh([[3, -1, 0], [5, -1, 0], [4, 1, 0]], [[0, 1, 2]]))
    rng = np.random.default_rng(3)
    origins = np.column_stack([rng.uniform(-2, 6, 500), rng.uniform(-2, 2, 500), np.full(500, 4.0)])
    aims = np.column_stack([rng.uniform(-1.5, 5.5, 500), rng.uniform(-1.5, 1.5, 500), np.zeros(500)])
    directions = aims - origins
    s = _stats(scene, accel, origins, directions)
    sphere = np.isfinite(ref.hit_sphere((0.0, 0.0, 0.0), 1.0, origins, directions))
    triangle = np.isfinite(ref.hit_triangle([3, -1, 0], [5, -1, 0], [4, 1, 0], origins, directions))
    assert sphere.sum() > 20 and triangle.sum() > 20
    assert s["hits.sphere"] == sphere.sum() and s["hits.triangle"] == triangle.sum()
    assert s["tests.sphere"] >= s["hits.sphere"] and s["polygon.corners"] == 0


def test_the_cost_model_prices_corners_hits_mailboxes_leaves_and_lazy_rays():
    scene = raykernel.load("spd:gears:1")
    eager = raykernel.render(scene, accel="grid", resolution=24, spd=True).stats
    f = costmodel.features(eager)
    assert f["polygon.corner"] == eager["polygon.corners"] > 2 * eager["tests.polygon"]   # many-cornered faces
    assert f["hit.polygon"] == eager["hits.polygon"] > 0
    assert f["mailbox"] == eager["mailbox.saved"] and f["leaf"] == eager["cells.leaves"] > 0
    assert not any(name.startswith(("ray.lazy", "pass.lazy")) for name in f)
    assert not walked_wide(eager) and "test.polygon.wide" not in f
    # a grid's entries and bound tests: one a ray at most, the rest priced apart
    rays = f["ray.shaded"] + f["ray.shadow"]
    for what, counter in (("entry", "walk.grid.entries"), ("bound", "walk.grid.bounds")):
        assert 0 < f[f"{what}.grid"] <= rays and f[f"{what}.grid.more"] >= 0
        assert f[f"{what}.grid"] + f[f"{what}.grid.more"] == eager[counter]
    nested = costmodel.features(raykernel.render(scene, accel="hgrid", resolution=24, spd=True).stats)
    assert nested["entry.grid.more"] > 0        # an hgrid's inner grids
    rows = {(r[0], r[1]): r for r in eager.rows()}
    assert rows[("tests", "polygon")][3] == f"{eager['hits.polygon']:,} hit"
    assert rows[("tests", "polygon corners")][2] == f"{eager['polygon.corners']:,}"
    lazy = raykernel.render(scene, accel="lazyoctree", resolution=24, spd=True).stats
    g = costmodel.features(lazy)
    assert g["ray.lazy.octree"] == g["ray.shaded"] + g["ray.shadow"] > 0
    assert g["pass.lazy"] == g["refine.pass"] == lazy["build.refine_passes"] > 1 and "ray.lazy.rc" not in g
    rc_stats = raykernel.render(scene, accel="rc", resolution=24, spd=True).stats
    rc = costmodel.features(rc_stats)
    assert rc["ray.lazy.rc"] == rc["ray.shaded"] + rc["ray.shadow"] and rc["ray.lazy.rc_mb"] > 0
    # tests from rc's candidate lists and its refinement's references by size are priced apart
    assert rc["test.rc"] + rc["test.rc.more"] == rc_stats["tests.total"] > 0
    assert 0 < rc["test.rc"] <= rc_module.TESTS_PER_STEP * rc_stats["walk.rc.steps"] and rc["test.rc.more"] >= 0
    assert rc["polygon.corner.rc"] == rc_stats["polygon.corners"]
    (agg,) = rc_stats.aggregates
    assert agg["refs"] > 0 and rc["refine.rc.ref_size"] == pytest.approx(agg["refs"] * agg["bytes"] / 2 ** 20)
    assert not {"test.rc", "test.rc.more"} & (set(f) | set(g)) and "refine.rc.ref_size" not in g
    # a scene that is one BVH takes the 4-wide walk, priced apart; with eager normals it does not
    wide = raykernel.render(scene, accel="bvh", resolution=24, spd=True).stats
    w = costmodel.features(wide)
    assert walked_wide(wide) and costmodel.walks_used(wide) == {"wide"}
    assert w["test.polygon.wide"] == wide["tests.polygon"] > 0 and "test.polygon" not in w
    assert w["step.wide"] == wide["walk.bvh.steps"] > 0 and "step.bvh" not in w
    eager_bvh = raykernel.render(scene, accel="bvh", resolution=24, spd=True, tricks="closest").stats
    assert not walked_wide(eager_bvh) and costmodel.features(eager_bvh)["step.bvh"] > 0
    binary = raykernel.render(scene, accel="bvh(width=2)", resolution=24, spd=True).stats
    assert not walked_wide(binary) and costmodel.walks_used(binary) == {"bvh"}
    model = costmodel.CostModel.load(costmodel.REFERENCE_PATH)
    assert model.costs["polygon.corner"] > 0 and model.predict(eager) > 0


def test_the_cost_model_prices_culled_eye_rays_apart():
    """Eye rays of tiles culled whole (frustum.culled) leave ray.shaded and the wide walk's bound
    tests for ray.culled; a render that culls nothing has none."""
    jacks = raykernel.render(raykernel.load("spd:jacks:1"), accel="bvh", resolution=64, spd=True).stats
    culled = jacks["frustum.culled"]
    assert culled > 0
    f = costmodel.features(jacks)
    assert f["ray.culled"] == culled
    assert f["ray.shaded"] == jacks["rays.eye"] + jacks["rays.reflect"] + jacks["rays.refract"] - culled
    assert f["bound.wide"] == jacks["walk.bvh.bounds"] - culled >= 0
    grid = raykernel.render(raykernel.load("spd:jacks:1"), accel="grid", resolution=64, spd=True).stats
    assert grid["frustum.culled"] == 0 and costmodel.features(grid)["ray.culled"] == 0
    assert costmodel.features(grid)["bound.grid"] == grid["walk.grid.bounds"]

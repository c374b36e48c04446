"""Haines's efficiency tricks: on or off, the same image and ray counts for every kind and nesting;
each trick's counter moves, and scenes built for it show it saving work."""

from pathlib import Path

import numpy as np
import pytest
from support import ray_counts

from raykernel.errors import OptionError
from raykernel.rendering import tricks as T
from raykernel.rendering.render import render
from raykernel.aggregates import registry as accel
from raykernel.scene.loading import load
from raykernel.scene.model import Camera, Light, Material, Scene
from raykernel.scene.spd import NAMES as SPD_NAMES

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
KINDS = [k for k, kind in accel.KINDS.items() if not kind.operands]
ALONE = list(T.NAMES)


def small(name):
    return load(f"spd:{name}:{2 if name == 'teapot' else 1}")      # the SPD's smallest sizes


def same_work_counts(a, b):
    assert np.array_equal(a.image, b.image)
    assert ray_counts(a.stats) == ray_counts(b.stats)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("name", SPD_NAMES)
def test_every_trick_on_or_off_renders_the_same_on_every_spd_scene_and_kind(name, kind):
    scene = small(name)
    base = render(scene, accel=kind, resolution=20, spd=True, tricks="none")
    every = render(scene, accel=kind, resolution=20, spd=True, tricks="all")
    same_work_counts(base, every)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("trick", ALONE)
@pytest.mark.parametrize("name", ["balls", "gears", "teapot", "mount"])
def test_each_trick_alone_renders_the_same(name, trick, kind):
    scene = small(name)
    base = render(scene, accel=kind, resolution=16, tricks="none")
    alone = render(scene, accel=kind, resolution=16, tricks=trick)
    same_work_counts(base, alone)


@pytest.mark.parametrize("path", [str(EXAMPLES / "nested.json"), "example:csg"])
# Hall's shading with filtered shadows over nested structures compiles a variant of its own (minutes)
@pytest.mark.parametrize("options", [dict(),
                                     pytest.param(dict(shading="hall", shadows="filtered"), marks=pytest.mark.slow),
                                     dict(aa="adaptive")])
def test_nesting_instances_and_csg_render_the_same_with_every_trick(path, options):
    scene = load(path)
    base = render(scene, resolution=40, tricks="none", **options)
    for tricks in ("all", "raytree", "shadowcache", "closest,raytree,shadowcache"):
        same_work_counts(base, render(scene, resolution=40, tricks=tricks, **options))


@pytest.mark.slow      # the filtered-shadow kernels with the tricks' memory: compiled for this test alone
@pytest.mark.parametrize("name", ["gears", "mount"])
def test_filtered_shadows_render_the_same_with_every_trick(name):
    scene = small(name)
    base = render(scene, resolution=24, shadows="filtered", tricks="none")
    for tricks in ("all", "transparentlast", "shadowcache"):
        same_work_counts(base, render(scene, resolution=24, shadows="filtered", tricks=tricks))


def blocker_scene():
    """A floor under one big opaque slab lit from above: most floor points' shadow rays meet the slab."""
    scene = Scene(camera=Camera(eye=(0, -9, 7), look_at=(0, 0, 0), angle=45.0), background=(0, 0, 0))
    scene.lights.append(Light((0, 0, 12)))
    floor = scene.add_material(Material(color=(1, 1, 1), kd=1.0))
    slab = scene.add_material(Material(color=(1, 0, 0), kd=1.0))
    scene.root.polygons.add([(-6, -6, 0), (6, -6, 0), (6, 6, 0), (-6, 6, 0)], floor)
    scene.root.polygons.add([(-3, -3, 4), (3, -3, 4), (3, 3, 4), (-3, 3, 4)], slab)
    for k in range(30):         # clutter beside the slab: work for a search the cache avoids
        scene.root.spheres.add((-5 + (k % 6) * 0.3, 4.5 + (k // 6) * 0.3, 1.0), 0.1, floor)
    return scene


def test_the_shadow_cache_settles_the_shadows_of_one_big_blocker():
    scene = blocker_scene()
    off = render(scene, resolution=32, tricks="closest")
    on = render(scene, resolution=32, tricks="closest,shadowcache")
    same_work_counts(off, on)
    blocked = on.stats["rays.shadow_blocked"]
    assert on.stats["shadow_cache.hits"] > 0.9 * blocked
    assert on.stats["shadow_cache.tries"] >= on.stats["shadow_cache.hits"]
    assert off.stats["shadow_cache.hits"] == off.stats["shadow_cache.tries"] == 0
    # each cache hit is one test instead of a search of the scene
    assert on.stats["bounds.tests"] < off.stats["bounds.tests"]


def test_the_previous_ray_tree_bounds_the_search_where_pixels_see_the_same_object():
    scene = blocker_scene()
    off = render(scene, resolution=32, tricks="closest")
    on = render(scene, resolution=32, tricks="closest,raytree")
    same_work_counts(off, on)
    # neighbouring pixels mostly see the same floor or slab: the remembered object bounds the search
    assert on.stats["raytree.hits"] > 0.8 * on.stats["rays.eye"]
    assert on.stats["raytree.tries"] >= on.stats["raytree.hits"]


def test_the_closest_cut_off_saves_tests_on_a_grid():
    scene = small("balls")
    off = render(scene, accel="list", resolution=24, tricks="none")
    on = render(scene, accel="list", resolution=24, tricks="closest")
    same_work_counts(off, on)
    assert off.stats["tricks.full_walks"] > 0 and on.stats["tricks.full_walks"] == 0
    grid_off = render(scene, accel="grid", resolution=24, tricks="none")
    grid_on = render(scene, accel="grid", resolution=24, tricks="closest")
    assert grid_on.stats["tests.total"] < grid_off.stats["tests.total"]
    assert grid_on.stats["cells.visited"] < grid_off.stats["cells.visited"]


def test_lazy_normals_compute_one_normal_per_hit():
    scene = small("balls")
    on = render(scene, accel="list", resolution=24, tricks="closest,lazynormals")
    off = render(scene, accel="list", resolution=24, tricks="closest")
    same_work_counts(on, off)
    hits = sum(on.stats[f"rays.{k}_hit"] for k in ("eye", "reflect", "refract"))
    assert on.stats["normals.computed"] == hits
    # brute force meets closer and closer hits along a ray: a normal for each
    assert off.stats["normals.computed"] > hits


@pytest.mark.slow      # filtered shadows with transparentlast: a kernel variant compiled for this test alone
def test_transparent_last_skips_the_walk_when_an_opaque_blocker_is_behind_glass():
    scene = blocker_scene()
    glass = scene.add_material(Material(color=(1, 1, 1), kd=0.0, t=0.6, ior=1.0))
    for z in (6.0, 7.0, 8.0):       # three panes above the slab
        scene.root.polygons.add([(-4, -4, z), (4, -4, z), (4, 4, z), (-4, 4, z)], glass)
    off = render(scene, resolution=32, shadows="filtered", tricks="closest")
    on = render(scene, resolution=32, shadows="filtered", tricks="closest,transparentlast")
    same_work_counts(off, on)
    assert on.stats["shadow.steps"] < off.stats["shadow.steps"]


@pytest.mark.parametrize("bad", ["fast", "closest,,raytree", "closest, warp", 99, 1.5, -1])
def test_bad_trick_lists_are_clear_errors(bad):
    with pytest.raises(OptionError):
        render(small("balls"), resolution=4, tricks=bad)


def test_trick_names_parse_as_documented():
    assert T.parse("all") == T.ALL and T.parse("none") == 0
    assert T.parse("closest, shadowcache") == T.CLOSEST_CUT | T.SHADOWCACHE
    assert T.names(T.parse("raytree,lazynormals")) == ["raytree", "lazynormals"]


def test_start_lists_hold_each_primitives_leaf_and_bound_secondary_rays():
    from raykernel.engine.flatten import flatten
    from raykernel.geometry.primitives import INDEX_MASK, KIND_SHIFT
    from raykernel.rendering.startlists import prepare
    scene = small("balls")
    geo, _ = flatten(scene, "bvh")
    starts = prepare(geo)
    # brute force: scan every leaf of the BVH for each primitive
    leaf_of = {}
    for node in range(len(geo.node_count)):
        for slot in range(geo.node_first[node], geo.node_first[node] + geo.node_count[node]):
            ref = int(geo.refs[slot])
            leaf_of.setdefault((ref >> KIND_SHIFT, ref & INDEX_MASK), []).append(node)
    for (kind, idx), nodes in leaf_of.items():
        assert starts.prim_leaf[starts.prim_offset[kind] + idx] == (nodes[0] if len(nodes) == 1 else -1)
    off = render(scene, resolution=32, tricks="closest")
    on = render(scene, resolution=32, tricks="closest,startlists")
    same_work_counts(off, on)
    assert on.stats["start_lists.used"] > 0 and on.stats["start_lists.hits"] > 0
    assert 0 < on.stats["start_lists.built"] <= on.stats["start_lists.used"]
    # eye rays leave no object; without a BVH no primitive has a list
    grid = render(scene, accel="grid", resolution=32, tricks="closest,startlists")
    assert grid.stats["start_lists.used"] == 0
    eye_only = render(scene, resolution=32, max_depth=1, tricks="closest,startlists")
    assert eye_only.stats["start_lists.used"] > 0          # shadow rays leave the hit object
    assert eye_only.stats["rays.reflect"] == 0


@pytest.mark.parametrize("kind", KINDS)
def test_the_lean_default_kernel_does_the_same_work_as_the_one_with_the_tricks_memory(kind):
    # the default tricks run without per-tile state (tricks.LEAN); adding a trick that has nothing to
    # do with opaque shadows runs the kernel with it: every counter must agree
    from support import work_counts
    scene = small("gears")
    lean = render(scene, accel=kind, resolution=20)
    full = render(scene, accel=kind, resolution=20, tricks="closest,lazynormals,transparentlast")
    assert lean.stats.info["tricks"] == ["closest", "lazynormals"]
    assert np.array_equal(lean.image, full.image)
    # (the lean kernel alone culls tiles whose eye rays all miss: frustum.py)
    assert work_counts(lean.stats) == dict(work_counts(full.stats), **{"frustum.culled": lean.stats["frustum.culled"]})

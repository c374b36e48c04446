"""Hall shading, filtered shadows and the light at the eye (Haines's trick and puzzle)."""

import math
from pathlib import Path

import numpy as np
import pytest
from support import work_counts

from raykernel.errors import OptionError
from raykernel.rendering.hall import fresnel, weights
from raykernel.rendering.render import render
from raykernel.scene.loading import load
from raykernel.scene.model import Camera, Light, Material, Scene

PUZZLE = Path(__file__).resolve().parents[1] / "examples" / "eye_light_puzzle.json"


def reference_fresnel(n1, n2, cos_i):
    """Fresnel's equations for unpolarised light, from the two indices and Snell's law."""
    sin_t = n1 / n2 * math.sqrt(max(0.0, 1.0 - cos_i * cos_i))
    if sin_t >= 1.0:
        return 1.0
    cos_t = math.sqrt(1.0 - sin_t * sin_t)
    rs = ((n1 * cos_i - n2 * cos_t) / (n1 * cos_i + n2 * cos_t)) ** 2
    rp = ((n1 * cos_t - n2 * cos_i) / (n1 * cos_t + n2 * cos_i)) ** 2
    return 0.5 * (rs + rp)


@pytest.mark.parametrize("n1, n2", [(1.0, 1.5), (1.5, 1.0), (1.0, 1.1), (1.33, 1.0), (1.0, 2.4)])
def test_fresnel_matches_the_equations_and_the_textbook_values(n1, n2):
    for cos_i in np.linspace(0.0, 1.0, 41):
        f, _ = fresnel(cos_i, n1 / n2)
        assert f == pytest.approx(reference_fresnel(n1, n2, cos_i), abs=1e-12)
    # normal incidence ((n1 - n2) / (n1 + n2))^2 either way; Brewster's angle reflects no p light
    assert fresnel(1.0, n1 / n2)[0] == pytest.approx(((n1 - n2) / (n1 + n2)) ** 2)
    brewster = math.atan(n2 / n1)
    f, _ = fresnel(math.cos(brewster), n1 / n2)
    cos_t = math.sqrt(1 - (n1 / n2 * math.sin(brewster)) ** 2)
    rs = ((n1 * math.cos(brewster) - n2 * cos_t) / (n1 * math.cos(brewster) + n2 * cos_t)) ** 2
    assert f == pytest.approx(0.5 * rs)
    if n1 > n2:     # past the critical angle: total internal reflection
        critical = math.asin(n2 / n1)
        assert fresnel(math.cos(critical + 1e-3), n1 / n2) == (1.0, 0.0)


def test_reflected_and_transmitted_weights_never_exceed_one():
    rng = np.random.default_rng(4)
    for ks, kt, f in rng.uniform([0, 0, 0], [2, 2, 1], size=(2000, 3)):
        w_mirror, w_refract = weights(ks, kt, f)
        assert 0.0 <= w_mirror and 0.0 <= w_refract
        assert w_mirror + w_refract <= 1.0 + 1e-12
    # at total internal reflection everything goes to the mirror ray
    assert weights(0.1, 0.7, 1.0) == pytest.approx((0.8, 0.0))


def glowing_room(inside=None):
    """The camera inside a sphere that only glows white; `inside` a list of (centre, radius, material)."""
    scene = Scene(camera=Camera(eye=(0, -3, 0), look_at=(0, 0, 0), angle=30.0), background=(0, 0, 0))
    glow = scene.add_material(Material(color=(1, 1, 1), kd=0.0, kl=1.0))
    scene.root.spheres.add((0, 0, 0), 20.0, glow)
    for center, radius, material in inside or []:
        scene.root.spheres.add(center, radius, scene.add_material(material))
    return scene


def test_hall_never_creates_light_where_whitted_does():
    # a glass ball whose Ks + T exceeds 1 in a white room: Whitted's tree weighs more than the
    # light that came in; Hall's weights sum to at most 1, so no pixel is brighter than the room
    scene = glowing_room([((0, 0, 0), 1.0, Material(kd=0.0, ks=0.5, t=0.8, ior=1.5))])
    hall = render(scene, resolution=32, shading="hall", max_depth=32, cutoff=0.0)
    whitted = render(scene, resolution=32, max_depth=32, cutoff=0.0)
    assert hall.image.max() <= 1.0 + 1e-12
    assert whitted.image.max() > 1.05
    # with Ks + T = 1 no light is lost either, except what the depth limit leaves untraced
    lossless = glowing_room([((0, 0, 0), 1.0, Material(kd=0.0, ks=0.0, t=1.0, ior=1.5))])
    image = render(lossless, resolution=32, shading="hall", max_depth=32, cutoff=0.0).image
    assert image.max() <= 1.0 + 1e-12 and np.median(image) > 0.999


def test_total_internal_reflection_is_counted_and_casts_no_refraction_ray():
    # looking at a corner of a glass cube: rays entering one face meet the next beyond the critical
    # angle (a ball would not do: its symmetry keeps every inner ray below that angle)
    scene = glowing_room()
    glass = scene.add_material(Material(kd=0.0, ks=0.0, t=1.0, ior=1.5))
    for axis in range(3):
        for side in (-1.0, 1.0):
            quad = []
            for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                p = [0.0, 0.0, 0.0]
                p[axis], p[(axis + 1) % 3], p[(axis + 2) % 3] = side, a, b
                quad.append(p)
            scene.root.polygons.add(quad, glass)
    scene.camera = Camera(eye=(3, -4, 2.5), look_at=(0, 0, 0), angle=35.0)
    for shading in ("whitted", "hall"):
        stats = render(scene, resolution=24, shading=shading, max_depth=6, cutoff=0.0).stats
        assert stats["rays.tir"] > 0
        assert stats["rays.refract_spd"] == stats["rays.refract"] + stats["rays.tir"]


def test_a_medium_filters_by_the_distance_travelled():
    # under water (colour c per unit length) a glowing wall 4 units ahead shows c^4 at the centre
    c = np.array([0.9, 0.8, 0.5])
    scene = Scene(camera=Camera(eye=(0, 0, 0), look_at=(0, 1, 0), angle=10.0), background=(0, 0, 0))
    water = scene.add_material(Material(color=tuple(c), kd=0.0, t=1.0, ior=1.33))
    wall = scene.add_material(Material(color=(1, 1, 1), kd=0.0, kl=1.0))
    scene.root.spheres.add((0, 0, 0), 30.0, water)
    scene.root.polygons.add([(-5, 4, -5), (5, 4, -5), (5, 4, 5), (-5, 4, 5)], wall)
    scene.camera.medium = water
    image = render(scene, resolution=5, shading="hall").image
    assert image[2, 2] == pytest.approx(c ** 4, rel=1e-9)
    scene.camera.medium = None
    assert render(scene, resolution=5, shading="hall").image[2, 2] == pytest.approx([1, 1, 1])


def sheet_scene(t=0.5):
    """A floor lit from above, with a transparent sheet (T = t) between the light and part of it."""
    scene = Scene(camera=Camera(eye=(0, -8, 6), look_at=(0, 0, 0), angle=50.0), background=(0, 0, 0))
    scene.lights.append(Light((0, 0, 10)))
    floor = scene.add_material(Material(color=(1, 1, 1), kd=1.0))
    scene.root.polygons.add([(-5, -5, 0), (5, -5, 0), (5, 5, 0), (-5, 5, 0)], floor)
    if t is not None:
        sheet = scene.add_material(Material(color=(1, 1, 1), kd=0.0, t=t, ior=1.0))
        scene.root.polygons.add([(-1, -1, 3), (1, -1, 3), (1, 1, 3), (-1, 1, 3)], sheet)
    return scene


@pytest.mark.parametrize("shading", ["whitted", "hall"])
def test_filtered_shadows_pass_light_times_t(shading):
    # the floor's centre, seen directly, lies under the sheet: lit by T of the light, or not at all
    clear = render(sheet_scene(None), resolution=33, shading=shading, max_depth=1).image[18, 16]
    filtered = render(sheet_scene(0.5), resolution=33, shading=shading, max_depth=1, shadows="filtered")
    opaque = render(sheet_scene(0.5), resolution=33, shading=shading, max_depth=1).image[18, 16]
    assert clear.min() > 0.1
    assert filtered.image[18, 16] == pytest.approx(0.5 * clear, rel=1e-9)
    assert np.all(opaque == 0.0)
    assert filtered.stats["rays.shadow_blocked"] < render(sheet_scene(0.5), resolution=33, shading=shading,
                                                           max_depth=1).stats["rays.shadow_blocked"]


def test_spd_and_heckbert_refuse_what_they_do_not_have():
    with pytest.raises(OptionError, match="SPD mode"):
        render(sheet_scene(), resolution=4, spd=True, shadows="filtered")
    with pytest.raises(OptionError, match="SPD mode"):
        render(sheet_scene(), resolution=4, spd=True, eye_light=1.0)
    with pytest.raises(OptionError, match="heckbert"):
        render(sheet_scene(), resolution=4, shading="heckbert", shadows="filtered")
    with pytest.raises(OptionError):
        render(sheet_scene(), resolution=4, eye_light=-1.0)
    with pytest.raises(OptionError):
        render(sheet_scene(), resolution=4, eye_light=1.0, eye_light_shadows="sometimes")


@pytest.mark.parametrize("name", ["spd:balls:2", "spd:gears:2", "spd:tetra:3", "spd:teapot:4", "spd:mount:3"])
def test_the_eye_light_trick_is_exact_under_whitted(name):
    scene = load(name)
    skip = render(scene, resolution=48, eye_light=0.7)
    cast = render(scene, resolution=48, eye_light=0.7, eye_light_shadows="cast")
    assert np.array_equal(skip.image, cast.image)
    # every ray it skipped, the other render cast, and none of them was blocked
    assert skip.stats["shadow.eye_light_skipped"] > 0
    assert cast.stats["rays.shadow"] - skip.stats["rays.shadow"] == skip.stats["shadow.eye_light_skipped"]
    assert cast.stats["rays.shadow_blocked"] == skip.stats["rays.shadow_blocked"]


def test_no_shadow_ray_is_cast_toward_the_eye_light_from_an_eye_rays_hit():
    scene = load("spd:balls:2")
    without = render(scene, resolution=32, max_depth=1)
    with_light = render(scene, resolution=32, max_depth=1, eye_light=1.0)
    assert with_light.stats["rays.shadow"] == without.stats["rays.shadow"]
    assert with_light.stats["shadow.eye_light_skipped"] > 0
    assert work_counts(with_light.stats)["rays.eye"] == work_counts(without.stats)["rays.eye"]


def test_the_puzzle_scene_shows_the_error_under_hall_and_not_under_whitted():
    scene = load(str(PUZZLE))
    options = dict(resolution=48, eye_light=1.5)
    naive = render(scene, shading="hall", **options).image
    right = render(scene, shading="hall", eye_light_shadows="cast", **options).image
    # the trick leaves out the water between the light and what the eye sees: too bright
    lit = right.sum(axis=2) > 0.01
    assert np.all(right <= naive + 1e-12)
    assert np.median(right.sum(axis=2)[lit] / naive.sum(axis=2)[lit]) < 0.9
    whitted = [render(scene, eye_light_shadows=s, **options).image for s in ("skip", "cast")]
    assert np.array_equal(*whitted)


@pytest.mark.slow
def test_gears_refraction_count_follows_the_spd_table_once_total_internal_reflections_count():
    # the SPD authors' table gives 207,564 refraction rays for gears-sf4 at 512x512; their count
    # includes a refraction ray at every total internal reflection (docs/guide/rendering.md, "Shading")
    stats = render(load("spd:gears"), resolution=512, spd=True).stats
    assert stats["rays.tir"] > 0
    assert stats["rays.refract_spd"] == pytest.approx(207_564, rel=2e-3)
    assert stats["rays.refract"] < 207_564 * (1 - 2e-3)

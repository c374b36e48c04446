"""The Whitted renderer against values worked out by hand or with a small numpy reference."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import textwrap

import numba
import numpy as np
import pytest
from support import add_sphere, add_square, make_scene, ray_counts, work_counts

from raykernel import OptionError, load, render
from raykernel.scene import Polygons

BG = (0.1, 0.2, 0.3)

# Every size-factor-1 NFF file of the SPD programs (tests/data/spd); each renders in
# well under a second at 64x64 with either accelerator, so all of them are in the fast set.
SF1_NAMES = ["balls", "gears", "jacks", "lattice", "mount", "nurbtst", "rings", "sample", "shells",
             "sombrero", "teapot", "tetra", "tree"]


def unit(v):
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


def counts_of(result, *names):
    return {n: result.stats[n] for n in names}


# ---------------------------------------------------------------- direct lighting


def diffuse_scene(lights):
    """A unit sphere at the origin seen along +y from (0, -5, 0): the centre ray hits
    (0, -1, 0) where the normal is (0, -1, 0)."""
    scene = make_scene(size=3, background=BG)
    add_sphere(scene, (0, 0, 0), 1.0, color=(1.0, 0.5, 0.25), kd=0.7)
    for position, color in lights:
        scene.add_light(position, color)
    return scene


def test_diffuse_one_light():
    # light at (3, -5, 0): from the hit point (0, -1, 0) it lies along (3, -4, 0)/5, cos = 4/5
    result = render(diffuse_scene([((3, -5, 0), None)]))
    expected = 0.7 * np.array([1.0, 0.5, 0.25]) * 0.8
    np.testing.assert_allclose(result.image[1, 1], expected, rtol=0, atol=1e-9)
    # the sphere spans +-11.5 degrees, the neighbouring pixels look 22.5 degrees off axis
    assert counts_of(result, "rays.eye", "rays.eye_hit", "rays.shadow", "rays.shadow_blocked",
                     "rays.reflect", "rays.refract") == {
        "rays.eye": 9, "rays.eye_hit": 1, "rays.shadow": 1, "rays.shadow_blocked": 0,
        "rays.reflect": 0, "rays.refract": 0}


def test_diffuse_two_coloured_lights_scaled_by_sqrt_n():
    # the second light is behind the sphere: it adds nothing, but halves the power of both
    color = np.array([0.5, 1.0, 2.0])
    result = render(diffuse_scene([((3, -5, 0), color), ((0, 5, 0), None)]))
    expected = 0.7 * np.array([1.0, 0.5, 0.25]) * 0.8 * color / math.sqrt(2.0)
    np.testing.assert_allclose(result.image[1, 1], expected, rtol=0, atol=1e-9)
    assert result.stats["rays.shadow"] == 1


def test_background_where_nothing_is_hit():
    result = render(diffuse_scene([((3, -5, 0), None)]))
    mask = np.ones((3, 3), bool)
    mask[1, 1] = False
    assert np.array_equal(result.image[mask], np.tile(BG, (8, 1)))
    assert not np.allclose(result.image[1, 1], BG)


def test_empty_scene_is_background():
    scene = make_scene(size=4, background=BG)
    result = render(scene)
    assert np.array_equal(result.image, np.broadcast_to(BG, (4, 4, 3)))
    assert result.stats["rays.eye"] == 16 and result.stats["rays.eye_hit"] == 0


# ---------------------------------------------------------------- shadows


def shadow_scene(with_blocker=True):
    """A floor z = 0 seen from (0, -5, 5) towards the origin; a small sphere at (0, 0, 1)
    between the origin and the light (0, 0, 5); a second light (4, 0, 3) the sphere
    does not hide (the segment passes 0.8 from the sphere's centre, radius 0.5). The
    eye ray passes 0.707 from the sphere's centre, so it reaches the floor."""
    scene = make_scene(eye=(0, -5, 5), background=BG)
    add_square(scene, (0, 0, 0), (10, 0, 0), (0, 10, 0), color=(0.9, 0.6, 0.3), kd=0.8)
    if with_blocker:
        add_sphere(scene, (0, 0, 1), 0.5, color=(1, 1, 1), kd=1.0)
    scene.add_light((0, 0, 5))
    scene.add_light((4, 0, 3))
    return scene


def test_shadow_darkens_floor_behind_sphere():
    c = np.array([0.9, 0.6, 0.3])
    result = render(shadow_scene())
    # only the light at (4, 0, 3) reaches the origin: cos = 3/5, intensity 1/sqrt(2)
    np.testing.assert_allclose(result.image[0, 0], 0.8 * c * 0.6 / math.sqrt(2), rtol=0, atol=1e-9)
    assert counts_of(result, "rays.eye_hit", "rays.shadow", "rays.shadow_blocked") == {
        "rays.eye_hit": 1, "rays.shadow": 2, "rays.shadow_blocked": 1}
    open_sky = render(shadow_scene(with_blocker=False))
    np.testing.assert_allclose(open_sky.image[0, 0], 0.8 * c * 1.6 / math.sqrt(2), rtol=0, atol=1e-9)
    assert open_sky.stats["rays.shadow_blocked"] == 0


def floor_scene_3x3(lights):
    """A 3x3 view from (0, -5, 5) towards the origin in which every pixel sees the floor
    (the farthest corner ray lands at (+-5, 7.07, 0), inside the 20 x 20 square)."""
    scene = make_scene(eye=(0, -5, 5), size=3, background=BG)
    add_square(scene, (0, 0, 0), (10, 0, 0), (0, 10, 0), color=(0.9, 0.6, 0.3), kd=0.8)
    for light in lights:
        scene.add_light(light)
    return scene


def test_light_behind_surface_casts_no_shadow_ray():
    result = render(floor_scene_3x3([(0, 0, -3)]))
    assert result.stats["rays.eye_hit"] == 9
    assert result.stats["rays.shadow"] == 0
    assert np.array_equal(result.image, np.zeros((3, 3, 3)))


def test_shadow_rays_only_towards_lights_in_front():
    result = render(floor_scene_3x3([(0, 0, -3), (0, 0, 20)]))
    assert result.stats["rays.shadow"] == 9
    assert result.stats["rays.shadow_blocked"] == 0


# ---------------------------------------------------------------- Phong highlight and mirrors


@pytest.mark.parametrize("light, cos", [((0, -3, 0), 1.0), ((3, -5, 0), 0.8)])
def test_phong_highlight(light, cos):
    """Eye ray along +y hits (0, -1, 0); its mirror direction is -y. With the light on
    that direction r.l = 1; from (3, -5, 0) both n.l and r.l are 4/5."""
    kd, ks, shine = 0.5, 0.3, 20.0
    c = np.array([1.0, 0.2, 0.4])
    light_color = np.array([0.6, 0.6, 0.6])
    scene = make_scene(background=BG)
    add_sphere(scene, (0, 0, 0), 1.0, color=c, kd=kd, ks=ks, shine=shine)
    scene.add_light(light, light_color)
    result = render(scene)
    # diffuse + highlight + the mirror ray going back along -y into the background
    expected = kd * c * cos * light_color + ks * cos ** shine * light_color + ks * np.array(BG)
    np.testing.assert_allclose(result.image[0, 0], expected, rtol=0, atol=1e-9)
    assert counts_of(result, "rays.reflect", "rays.reflect_hit", "rays.shadow") == {
        "rays.reflect": 1, "rays.reflect_hit": 0, "rays.shadow": 1}


def test_mirror_reflects_coloured_sphere():
    """A mirror square in the plane y = 0 faces the eye at (0, -5, 0); the eye ray
    comes back along -y and hits a red sphere behind the eye at (0, -9, 0), whose
    normal there is +y; the light (0, -6, 4) lies along (0, 3, 4)/5 from it: cos 0.6.
    At the mirror, r = -y and l = (0, -6, 4)/sqrt(52): highlight (6/sqrt(52))^10."""
    scene = make_scene(background=(0, 0, 0))
    add_square(scene, (0, 0, 0), (2, 0, 0), (0, 0, 2), color=(1, 1, 1), kd=0.0, ks=1.0, shine=10.0)
    add_sphere(scene, (0, -10, 0), 1.0, color=(1, 0, 0), kd=1.0)
    scene.add_light((0, -6, 4))
    result = render(scene)
    h = (6.0 / math.sqrt(52.0)) ** 10
    np.testing.assert_allclose(result.image[0, 0], [0.6 + h, h, h], rtol=0, atol=1e-9)
    assert counts_of(result, "rays.eye", "rays.eye_hit", "rays.reflect", "rays.reflect_hit",
                     "rays.refract", "rays.shadow", "rays.shadow_blocked") == {
        "rays.eye": 1, "rays.eye_hit": 1, "rays.reflect": 1, "rays.reflect_hit": 1,
        "rays.refract": 0, "rays.shadow": 2, "rays.shadow_blocked": 0}


def facing_mirrors(size=1):
    scene = make_scene(eye=(0, 0, 0), look_at=(0, 1, 0), size=size, background=BG)
    for y in (-1.0, 1.0):
        add_square(scene, (0, y, 0), (100, 0, 0), (0, 0, 100), kd=0.0, ks=1.0)
    return scene


@pytest.mark.parametrize("depth", [1, 2, 3, 4, 5])
def test_max_depth_between_facing_mirrors(depth):
    result = render(facing_mirrors(), max_depth=depth)
    assert result.stats["rays.eye"] == 1
    assert result.stats["rays.reflect"] == depth - 1
    assert result.stats["rays.reflect_hit"] == depth - 1
    # the ray never escapes and nothing is lit
    assert np.array_equal(result.image, np.zeros((1, 1, 3)))


@pytest.mark.parametrize("depth", [1, 3, 5])
def test_max_depth_spd_mode_four_corner_rays(depth):
    # a 1x1 SPD image has four corner rays; they tilt by tan(22.5 deg) and stay on the mirrors
    result = render(facing_mirrors(), max_depth=depth, spd=True)
    assert result.stats["rays.eye"] == 4
    assert result.stats["rays.reflect"] == 4 * (depth - 1)


# ---------------------------------------------------------------- refraction


def refract(d, n, eta):
    """Snell's law: d unit incident direction, n unit normal against d, eta = n1/n2."""
    cos_i = -np.dot(d, n)
    k = 1.0 - eta * eta * (1.0 - cos_i * cos_i)
    assert k >= 0.0
    return unit(eta * d + (eta * cos_i - math.sqrt(k)) * n)


def glass_scene(x, backdrops, background=BG):
    """A glass unit sphere (T 1, ior 1.5) at the origin, seen along +y from (x, -5, 0);
    coloured squares in the plane y = 5 lit from (0, 3, 0)."""
    scene = make_scene(eye=(x, -5, 0), look_at=(x, 0, 0), background=background)
    add_sphere(scene, (0, 0, 0), 1.0, color=(1, 1, 1), kd=0.0, ks=0.0, t=1.0, ior=1.5)
    for center, half_width, color in backdrops:
        add_square(scene, (center, 5, 0), (half_width, 0, 0), (0, 0, 10), color=color, kd=0.9)
    scene.add_light((0, 3, 0))
    return scene


def test_refraction_through_centre_goes_straight():
    c = np.array([0.2, 0.4, 0.8])
    result = render(glass_scene(0.0, [(0.0, 10.0, c)]))
    # straight through to (0, 5, 0), which faces the light at (0, 3, 0): cos 1
    np.testing.assert_allclose(result.image[0, 0], 0.9 * c, rtol=0, atol=1e-9)
    # enter and exit; neither glass surface faces the light; the backdrop casts one shadow ray
    assert counts_of(result, "rays.eye", "rays.eye_hit", "rays.refract", "rays.refract_hit",
                     "rays.reflect", "rays.shadow") == {
        "rays.eye": 1, "rays.eye_hit": 1, "rays.refract": 2, "rays.refract_hit": 2,
        "rays.reflect": 0, "rays.shadow": 1}


def snell_landing(x):
    """Where the eye ray at height x lands on the plane y = 5 after the glass sphere."""
    d = np.array([0.0, 1.0, 0.0])
    p1 = np.array([x, -math.sqrt(1 - x * x), 0.0])
    t1 = refract(d, p1, 1 / 1.5)
    sin_i = np.linalg.norm(np.cross(d, p1))
    sin_t = np.linalg.norm(np.cross(t1, p1))
    assert sin_t == pytest.approx(sin_i / 1.5, abs=1e-12)
    p2 = p1 - 2.0 * np.dot(p1, t1) * t1          # the chord's far end on the unit sphere
    assert np.linalg.norm(p2) == pytest.approx(1.0, abs=1e-12)
    t2 = refract(t1, -p2, 1.5)
    s = (5.0 - p2[1]) / t2[1]
    return p2[0] + s * t2[0]


def test_refraction_off_centre_bends_by_snell():
    x = 0.5
    landing = snell_landing(x)
    assert abs(landing - x) > 1.5                 # clearly not where a straight ray lands
    split = 0.5 * (landing + x)
    red, green = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)
    # red covers the Snell landing point, green the straight-line one; 10 units of each
    if landing < x:
        backdrops = [(split - 10.0, 10.0, red), (split + 10.0, 10.0, green)]
    else:
        backdrops = [(split + 10.0, 10.0, red), (split - 10.0, 10.0, green)]
    result = render(glass_scene(x, backdrops))
    pixel = result.image[0, 0]
    assert pixel[0] > 0.05 and pixel[1] == 0.0 and pixel[2] == 0.0
    assert result.stats["rays.refract"] == 2 and result.stats["rays.refract_hit"] == 2


def test_refraction_counts_two_per_ray_in_centred_pixel():
    # a 3x3 image: only the centre ray meets the sphere (the others look 22.5 degrees away)
    scene = glass_scene(0.0, [(0.0, 100.0, (0.2, 0.4, 0.8))])
    scene.camera.width = scene.camera.height = 3
    result = render(scene)
    assert result.stats["rays.eye_hit"] == 9
    assert result.stats["rays.refract"] == 2


def inside_glass(height, ks=0.0, t=1.0):
    """The eye inside a glass unit sphere at (0, 0, height), looking along +y: the ray
    meets the boundary at sin(incidence) = height, from the dense side (eta = 1.5)."""
    scene = make_scene(eye=(0, 0, height), look_at=(0, 1, height), background=BG)
    add_sphere(scene, (0, 0, 0), 1.0, kd=0.0, ks=ks, t=t, ior=1.5)
    return scene


def test_total_internal_reflection():
    # 1.5 * 0.9 = 1.35 > 1: total internal reflection; a chord keeps its angle, so every
    # bounce reflects again until the depth limit: 4 reflections, no refraction, no light out
    result = render(inside_glass(0.9), max_depth=5)
    assert counts_of(result, "rays.eye", "rays.eye_hit", "rays.reflect", "rays.reflect_hit", "rays.refract") == {
        "rays.eye": 1, "rays.eye_hit": 1, "rays.reflect": 4, "rays.reflect_hit": 4, "rays.refract": 0}
    assert np.array_equal(result.image[0, 0], np.zeros(3))


def test_below_critical_angle_refracts_out():
    # 1.5 * 0.5 = 0.75 < 1: the ray leaves into the background; Ks 0 makes no mirror ray
    result = render(inside_glass(0.5), max_depth=5)
    assert counts_of(result, "rays.reflect", "rays.refract", "rays.refract_hit") == {
        "rays.reflect": 0, "rays.refract": 1, "rays.refract_hit": 0}
    np.testing.assert_allclose(result.image[0, 0], BG, rtol=0, atol=1e-12)


def test_total_internal_reflection_adds_t_to_reflection_weight():
    # Ks 0.1 + T 0.1 reflect with weight 0.2 per bounce: 0.2, 0.04, 0.008 reach the
    # 1/512 cut-off, 0.0016 does not: 3 reflections (Ks alone would give 2)
    result = render(inside_glass(0.9, ks=0.1, t=0.1), max_depth=5)
    assert counts_of(result, "rays.reflect", "rays.refract") == {"rays.reflect": 3, "rays.refract": 0}
    assert np.array_equal(result.image[0, 0], np.zeros(3))


def test_partial_transmission_weights():
    # below the critical angle every hit splits into refraction (T 0.1) and reflection
    # (Ks 0.1); the chord keeps its angle. Weights: 0.1 + 0.1, then 0.01 + 0.01, then
    # 0.001 < 1/512 stops. Both refracted rays leave into the background.
    result = render(inside_glass(0.5, ks=0.1, t=0.1), max_depth=10)
    assert counts_of(result, "rays.reflect", "rays.refract", "rays.refract_hit") == {
        "rays.reflect": 2, "rays.refract": 2, "rays.refract_hit": 0}
    np.testing.assert_allclose(result.image[0, 0], (0.1 + 0.01) * np.array(BG), rtol=0, atol=1e-15)


# ---------------------------------------------------------------- two-sidedness and inside-only spheres


@pytest.mark.parametrize("flip", [False, True])
def test_polygon_is_two_sided(flip):
    """The same square in y = 0 with either vertex order: one of the two is seen from its
    back. Light (1, -4, 0) on the viewer's side: cos = 4/sqrt(17) at the origin."""
    scene = make_scene(background=BG)
    u, v = (2, 0, 0), (0, 0, 2)
    if flip:
        u, v = v, u
    c = np.array([0.3, 0.6, 0.9])
    add_square(scene, (0, 0, 0), u, v, color=c, kd=0.8)
    scene.add_light((1, -4, 0))
    result = render(scene)
    np.testing.assert_allclose(result.image[0, 0], 0.8 * c * 4 / math.sqrt(17), rtol=0, atol=1e-9)
    assert result.stats["rays.shadow"] == 1


def test_teapot_body_has_no_holes():
    scene = load("spd:teapot:2")
    scene.root.polygons = Polygons()          # no floor: a hole would show the background
    result = render(scene, resolution=32)
    background = np.all(result.image == scene.background, axis=2)
    body = background[9:16, 11:22]            # well inside the body's silhouette at 32x32
    assert not body.any()
    assert np.all(result.image[9:16, 11:22].sum(axis=2) > 0)
    assert background[:4].all()               # the sky above the teapot is background


def test_negative_radius_sphere_shows_inside_back_wall():
    """Radius -1 at the origin, eye at (0, -5, 0): the visible point is (0, 1, 0), whose
    inward normal is -y; the light (0.6, 0, 0) is inside: cos = 1/sqrt(1.36). At the
    front point (0, -1, 0) the same light would be behind the surface (black)."""
    scene = make_scene(background=BG)
    add_sphere(scene, (0, 0, 0), -1.0, color=(1.0, 0.8, 0.6), kd=1.0)
    scene.add_light((0.6, 0, 0))
    result = render(scene)
    np.testing.assert_allclose(result.image[0, 0], np.array([1.0, 0.8, 0.6]) / math.sqrt(1.36),
                               rtol=0, atol=1e-9)
    assert result.stats["rays.shadow"] == 1 and result.stats["rays.shadow_blocked"] == 0


# ---------------------------------------------------------------- no shadow acne at any scale

ACNE_N = 24
ACNE_EYE, ACNE_AT, ACNE_ANGLE = np.array([0.0, -8.0, 4.0]), np.array([0.0, 0.0, 0.5]), 40.0
ACNE_SPHERE, ACNE_LIGHT, ACNE_HALF = np.array([0.0, 0.0, 1.0]), np.array([3.0, -2.0, 6.0]), 4.0
FLOOR_C, SPHERE_C = 0.8 * np.array([0.9, 0.9, 0.9]), 0.7 * np.array([1.0, 0.5, 0.5])


def acne_scene(scale, shift=0.0):
    """A unit sphere resting on a floor square, all coordinates times `scale` plus `shift`."""
    p = lambda x: np.asarray(x, np.float64) * scale + shift   # noqa: E731
    scene = make_scene(eye=p(ACNE_EYE), look_at=p(ACNE_AT), angle=ACNE_ANGLE, size=ACNE_N, background=BG)
    add_square(scene, p((0, 0, 0)), (ACNE_HALF * scale, 0, 0), (0, ACNE_HALF * scale, 0),
               color=(0.9, 0.9, 0.9), kd=0.8)
    add_sphere(scene, p(ACNE_SPHERE), scale, color=(1.0, 0.5, 0.5), kd=0.7)
    scene.add_light(p(ACNE_LIGHT))
    return scene


def _segment_distance(a, b, c):
    """Distance from point c to the segments a[k] -> b (a: (n, 3))."""
    ab = b - a
    s = np.clip(np.einsum("ij,ij->i", c - a, ab) / np.einsum("ij,ij->i", ab, ab), 0.0, 1.0)
    return np.linalg.norm(a + s[:, None] * ab - c, axis=1)


def acne_reference():
    """Expected image (scale 1) from NFF's camera, ray-sphere and ray-plane tests, and a
    mask of the pixels well away from silhouettes, shadow edges and the floor's edge."""
    forward = unit(ACNE_AT - ACNE_EYE)
    right = unit(np.cross(forward, [0.0, 0.0, 1.0]))
    up = np.cross(right, forward)
    spacing = 2.0 * math.tan(math.radians(ACNE_ANGLE) / 2.0) / (ACNE_N - 1)
    k = np.arange(ACNE_N) - (ACNE_N - 1) / 2.0
    d = forward + spacing * (k[None, :, None] * right - k[:, None, None] * up)
    d = (d / np.linalg.norm(d, axis=2, keepdims=True)).reshape(-1, 3)
    n_rays = len(d)
    image = np.tile(np.array(BG), (n_rays, 1))
    ok = np.ones(n_rays, bool)
    kind = np.zeros(n_rays, int)                 # 0 nothing, 1 floor, 2 sphere

    oc = ACNE_EYE - ACNE_SPHERE
    b = d @ oc
    miss_dist = np.linalg.norm(oc - b[:, None] * d, axis=1)    # ray line to sphere centre
    ok &= np.abs(miss_dist - 1.0) > 0.02
    disc = b * b - (oc @ oc - 1.0)
    t_sphere = np.where(disc > 0, -b - np.sqrt(np.maximum(disc, 0.0)), np.inf)
    t_floor = np.where(d[:, 2] < 0, -ACNE_EYE[2] / np.where(d[:, 2] < 0, d[:, 2], -1.0), np.inf)
    pf = ACNE_EYE + t_floor[:, None] * d
    on_floor = np.isfinite(t_floor) & (np.abs(pf[:, 0]) <= ACNE_HALF) & (np.abs(pf[:, 1]) <= ACNE_HALF)
    ok &= ~np.isfinite(t_floor) | (np.abs(np.abs(pf[:, :2]) - ACNE_HALF) > 0.02).all(axis=1)
    t_floor = np.where(on_floor, t_floor, np.inf)

    sphere = t_sphere < t_floor
    floor = ~sphere & np.isfinite(t_floor)
    kind[sphere], kind[floor] = 2, 1

    ps = ACNE_EYE + t_sphere[sphere, None] * d[sphere]
    n = ps - ACNE_SPHERE
    cos = np.einsum("ij,ij->i", n, unit_rows(ACNE_LIGHT - ps))
    image[sphere] = np.maximum(cos, 0.0)[:, None] * SPHERE_C
    ok[np.flatnonzero(sphere)[np.abs(cos) < 0.02]] = False     # terminator

    pf = pf[floor]
    cos = unit_rows(ACNE_LIGHT - pf)[:, 2]
    dist = _segment_distance(pf, ACNE_LIGHT, ACNE_SPHERE)
    lit = dist > 1.0
    image[floor] = np.where(lit, cos, 0.0)[:, None] * FLOOR_C
    ok[np.flatnonzero(floor)[np.abs(dist - 1.0) < 0.02]] = False   # shadow edge
    lit_floor = np.zeros(n_rays, bool)
    lit_floor[np.flatnonzero(floor)[lit]] = True
    shape = (ACNE_N, ACNE_N)
    return image.reshape(ACNE_N, ACNE_N, 3), ok.reshape(shape), kind.reshape(shape), lit_floor.reshape(shape)


def unit_rows(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def test_acne_reference_is_meaningful():
    _, ok, kind, lit_floor = acne_reference()
    assert (ok & (kind == 2)).sum() > 20
    assert (ok & lit_floor).sum() > 50
    assert (ok & (kind == 1) & ~lit_floor).sum() > 5        # some floor is in shadow
    assert (ok & (kind == 0)).sum() > 5


def test_no_acne_at_any_scale():
    expected, ok, kind, lit_floor = acne_reference()
    results = {s: render(acne_scene(s)) for s in (1.0, 1e-6, 1e6)}
    for scale, result in results.items():
        image = result.image
        np.testing.assert_allclose(image[ok], expected[ok], rtol=0, atol=1e-6, err_msg=f"scale {scale}")
        assert np.all(image[ok & lit_floor] >= expected[ok & lit_floor] - 1e-6), f"scale {scale}"
        np.testing.assert_allclose(image, results[1.0].image, rtol=0, atol=1e-6, err_msg=f"scale {scale}")
        assert ray_counts(result.stats) == ray_counts(results[1.0].stats), f"scale {scale}"


def test_no_acne_far_from_origin():
    """Translated by 1e7: offsets grow to 2^-32 * 1e7 = 2.3e-3 along the normal, which moves a
    shading value by at most about 2.3e-3 / 7 (the distance to the light); acne would be 0."""
    expected, ok, kind, lit_floor = acne_reference()
    image = render(acne_scene(1.0, shift=np.array([1e7, -1e7, 1e7]))).image
    np.testing.assert_allclose(image[ok], expected[ok], rtol=0, atol=1e-3)
    assert np.all(image[ok & lit_floor] >= expected[ok & lit_floor] - 1e-3)
    assert np.all(image[ok & (kind == 2)].sum(axis=1) >= expected[ok & (kind == 2)].sum(axis=1) - 3e-3)


# ---------------------------------------------------------------- SPD mode


def spd_test_scene(angle, size):
    scene = make_scene(eye=(0.3, -6, 3), look_at=(0, 0, 0.5), angle=angle, size=size, background=BG)
    add_square(scene, (0, 0, 0), (5, 0, 0), (0, 5, 0), color=(0.9, 0.8, 0.7), kd=0.8)
    add_sphere(scene, (-0.8, 0.3, 0.9), 0.9, color=(1.0, 0.3, 0.3), kd=0.5, ks=0.5, shine=10.0)
    add_sphere(scene, (1.1, -0.2, 0.6), 0.6, color=(0.3, 1.0, 0.3), kd=0.9)
    scene.add_light((4, -3, 6))
    scene.add_light((-3, -4, 5), (0.5, 0.5, 1.0))
    return scene


def test_spd_mode_averages_corner_rays():
    """A w-pixel SPD image takes w+1 corner rays per row, one pixel spacing apart, the
    outermost half a pixel beyond the outermost pixel centres: a plain (w+1)-pixel image
    whose angle spans w spacings (NFF's angle spans the outermost centres) has its pixel
    centres exactly on those corners."""
    w, angle = 8, 40.0
    wide = 2.0 * math.degrees(math.atan(w / (w - 1) * math.tan(math.radians(angle) / 2.0)))
    spd = render(spd_test_scene(angle, w), spd=True, max_depth=3)
    corners = render(spd_test_scene(wide, w + 1), spd=False, max_depth=3)
    c = corners.image
    averaged = (c[:-1, :-1] + c[1:, :-1] + c[:-1, 1:] + c[1:, 1:]) / 4.0
    assert spd.image.shape == (w, w, 3)
    np.testing.assert_allclose(spd.image, averaged, rtol=0, atol=1e-12)
    assert spd.stats["rays.eye"] == (w + 1) * (w + 1)
    assert spd.stats["rays.eye_hit"] > 0 and spd.stats["rays.reflect"] > 0
    # weights stay at or above 1/4 here, so the cut-off changes nothing either
    assert ray_counts(spd.stats) == ray_counts(corners.stats)


@pytest.mark.parametrize("w, h", [(5, 5), (16, 16), (17, 17)])
def test_spd_eye_ray_count(w, h):
    result = render(spd_test_scene(40.0, 1), resolution=w, spd=True)
    assert result.image.shape == (h, w, 3)
    assert result.stats["rays.eye"] == (w + 1) * (h + 1)


# ---------------------------------------------------------------- determinism


def test_same_render_twice_is_identical():
    scene = load("spd:balls:1")
    a = render(scene, resolution=24)
    b = render(scene, resolution=24)
    assert a.image.tobytes() == b.image.tobytes()
    assert work_counts(a.stats) == work_counts(b.stats)


def test_threads_argument_does_not_change_result():
    scene = load("spd:balls:1")
    try:
        one = render(scene, resolution=40, spd=True, threads=1)
        two = render(scene, resolution=40, spd=True, threads=2)
    finally:
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
    assert one.image.tobytes() == two.image.tobytes()
    assert work_counts(one.stats) == work_counts(two.stats)


SUBPROCESS_RENDER = textwrap.dedent("""
    import sys
    import numpy as np
    from raykernel import load, render
    r = render(load("spd:balls:1"), resolution=40, spd=True)
    keys = sorted(k for k, v in r.stats.items() if isinstance(v, int) and not k.startswith("time."))
    np.savez(sys.argv[1], image=r.image, keys=np.array(keys), values=np.array([r.stats[k] for k in keys]),
             threads=r.stats.info["threads"])
""")


def test_thread_count_does_not_change_result(tmp_path):
    out = {}
    for n in (1, 2):
        path = tmp_path / f"t{n}.npz"
        env = dict(os.environ, NUMBA_NUM_THREADS=str(n))
        proc = subprocess.run([sys.executable, "-c", SUBPROCESS_RENDER, str(path)], env=env,
                              capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr
        out[n] = np.load(path)
        assert int(out[n]["threads"]) == n
    assert out[1]["image"].tobytes() == out[2]["image"].tobytes()
    assert list(out[1]["keys"]) == list(out[2]["keys"])
    assert np.array_equal(out[1]["values"], out[2]["values"])


def assert_bvh_matches_list(scene, **options):
    bvh = render(scene, accel="bvh", **options)
    brute = render(scene, accel="list", **options)
    assert np.array_equal(bvh.image, brute.image)
    assert ray_counts(bvh.stats) == ray_counts(brute.stats)
    assert bvh.stats["rays.eye_hit"] > 0
    return bvh


@pytest.mark.parametrize("name", ["spd:balls:1", "spd:gears:1"])
def test_bvh_and_list_agree_on_generated_scenes(name):
    assert_bvh_matches_list(load(name), resolution=48)


@pytest.mark.parametrize("name", SF1_NAMES)
def test_bvh_and_list_agree_on_sf1_files(spd_dir, name):
    scene = load(str(spd_dir / f"{name}-sf1.nff"))
    assert_bvh_matches_list(scene, resolution=64, spd=True)


def test_sf1_list_is_complete(spd_dir):
    assert sorted(p.name for p in spd_dir.glob("*-sf1.nff")) == sorted(f"{n}-sf1.nff" for n in SF1_NAMES)


# ---------------------------------------------------------------- options and examples


@pytest.mark.parametrize("options", [
    {"max_depth": 0}, {"max_depth": 33}, {"max_depth": 2.0}, {"resolution": 0}, {"resolution": -3},
    {"threads": 0}, {"accel": "bsptree"}, {"accel": "bvh(leaf=0)"}, {"accel": "bvh(depth=3)"},
    {"accel": "bvh(leaf=4"},
], ids=repr)
def test_bad_options_raise_option_error(options):
    scene = make_scene()
    add_sphere(scene, (0, 0, 0), 1.0)
    with pytest.raises(OptionError):
        render(scene, **options)


def test_heckbert_example_renders():
    scene = load("example:heckbert")
    result = render(scene, resolution=32, max_depth=3)
    assert result.image.shape == (32, 32, 3)
    assert np.all(np.isfinite(result.image))
    not_bg = ~np.all(result.image == scene.background, axis=2)
    assert not_bg.sum() > 32
    assert result.stats["rays.refract"] > 0
    assert result.stats["rays.refract_hit"] > 0

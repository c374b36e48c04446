"""Anti-aliasing (jittered and adaptive supersampling) and the weight cut-off of the ray tree."""

import numpy as np
import pytest
from support import work_counts

from raykernel.errors import OptionError
from raykernel.rendering.render import render
from raykernel.scene.loading import load
from raykernel.scene.model import Camera, Light, Material, Scene
from raykernel.scene.spd import NAMES as SPD_NAMES


def two_spheres(background=(0.0, 0.0, 0.0)):
    scene = Scene(camera=Camera(eye=(0, -6, 0), look_at=(0, 0, 0), angle=40.0), background=background)
    scene.lights.append(Light((3, -5, 4)))
    red = scene.add_material(Material(color=(1, 0.2, 0.2), kd=0.8, ks=0.3, shine=30))
    glass = scene.add_material(Material(color=(1, 1, 1), kd=0.1, ks=0.2, t=0.7, ior=1.5))
    scene.root.spheres.add((-0.8, 0, 0), 1.0, red)
    scene.root.spheres.add((0.9, -0.5, 0.3), 0.7, glass)
    return scene


def glowing_room(color):
    """The camera inside a sphere that only glows: every ray sees exactly `color`."""
    scene = Scene(camera=Camera(eye=(0, 0, 0), look_at=(0, 1, 0)), background=(0.3, 0.6, 0.9))
    glow = scene.add_material(Material(color=color, kd=0.0, kl=1.0))
    scene.root.spheres.add((0, 0, 0), 5.0, glow)
    return scene


CONSTANT = [dict(), dict(aa="jitter", samples=9, seed=3), dict(aa="jitter", samples=16),
            dict(aa="adaptive", aa_threshold=0.0, aa_depth=3)]


@pytest.mark.parametrize("options", CONSTANT)
def test_a_constant_scene_gives_exactly_its_colour(options):
    for scene, color in ((glowing_room((0.5, 0.25, 0.125)), (0.5, 0.25, 0.125)),
                         (Scene(camera=Camera(), background=(0.75, 0.5, 0.0625)), (0.75, 0.5, 0.0625))):
        image = render(scene, resolution=8, **options).image
        assert np.array_equal(image, np.broadcast_to(color, image.shape))


@pytest.mark.parametrize("options", [dict(aa="jitter", samples=4, seed=7),
                                     dict(aa="adaptive", aa_threshold=0.05, aa_depth=3)])
def test_images_and_counts_do_not_depend_on_the_threads(options):
    scene = two_spheres()
    one = render(scene, resolution=40, threads=1, **options)
    two = render(scene, resolution=40, threads=2, **options)
    assert np.array_equal(one.image, two.image)
    assert work_counts(one.stats) == work_counts(two.stats)


def test_jitter_traces_samples_per_pixel_and_the_seed_moves_them():
    scene = two_spheres()
    a = render(scene, resolution=20, aa="jitter", samples=9, seed=1)
    b = render(scene, resolution=20, aa="jitter", samples=9, seed=1)
    c = render(scene, resolution=20, aa="jitter", samples=9, seed=2)
    assert a.stats["rays.eye"] == 20 * 20 * 9
    assert a.stats.info["eye_rays_per_pixel"] == 9
    assert np.array_equal(a.image, b.image)
    assert not np.array_equal(a.image, c.image)
    # two seeds differ only where a pixel straddles an edge, and then by part of the contrast
    assert np.abs(a.image - c.image).max() < 0.5
    assert np.mean(np.any(a.image != c.image, axis=2)) < 0.5


def test_jitter_with_one_sample_per_pixel_stays_within_the_pixel():
    # one jittered ray per pixel sees what an unjittered ray at most half a pixel away sees:
    # on a smooth sphere far from its edge the colours agree closely
    scene = two_spheres()
    plain = render(scene, resolution=64).image
    jitter = render(scene, resolution=64, aa="jitter", samples=1, seed=5).image
    assert np.abs(plain[28:36, 8:16] - jitter[28:36, 8:16]).max() < 0.05
    assert not np.array_equal(plain, jitter)


def test_adaptive_without_cuts_is_the_mean_of_the_pixel_corners_as_in_spd_mode():
    scene = two_spheres()
    corners = render(scene, resolution=24, spd=True)
    adaptive = render(scene, resolution=24, aa="adaptive", aa_depth=0, cutoff=0.0)
    assert np.allclose(adaptive.image, corners.image, rtol=0, atol=1e-9)
    # corners shared by the pixels of each 16 x 16 tile: (17 x 17 per full tile, less at the border)
    tiles = [(min(16, 24 - x) + 1) * (min(16, 24 - y) + 1) for x in (0, 16) for y in (0, 16)]
    assert adaptive.stats["rays.eye"] == sum(tiles)


def test_adaptive_cuts_where_corners_differ():
    scene = two_spheres()
    n = 24
    corners = sum((min(16, n - x) + 1) * (min(16, n - y) + 1) for x in (0, 16) for y in (0, 16))
    some = render(scene, resolution=n, aa="adaptive", aa_threshold=0.1, aa_depth=2)
    every = render(scene, resolution=n, aa="adaptive", aa_threshold=0.0, aa_depth=2)
    # points are shared within a tile: never more than the tile's full lattice, 4 x 4 per pixel
    full = sum((4 * min(16, n - x) + 1) * (4 * min(16, n - y) + 1) for x in (0, 16) for y in (0, 16))
    assert corners < some.stats["rays.eye"] < every.stats["rays.eye"] <= full
    never = render(scene, resolution=n, aa="adaptive", aa_threshold=1e9, aa_depth=2)
    assert never.stats["rays.eye"] == corners
    # where it did not cut, a pixel is the mean of its corners, as without cuts
    none = render(scene, resolution=n, aa="adaptive", aa_depth=0)
    uncut = np.isclose(some.image, none.image, rtol=0, atol=1e-12).all(axis=2)
    assert 0 < uncut.sum() < n * n
    # a scene without edges is never cut
    flat = render(glowing_room((0.5, 0.5, 0.5)), resolution=n, aa="adaptive", aa_threshold=0.0, aa_depth=2)
    assert flat.stats["rays.eye"] == corners


@pytest.mark.parametrize("name", SPD_NAMES)
def test_adaptive_traces_fewer_rays_than_full_supersampling_on_the_spd_scenes(name):
    # full supersampling at 2 cuts per pixel: every corner of a 4n x 4n grid, (4n + 1)^2 rays
    n = 16
    scene = load(f"spd:{name}")
    adaptive = render(scene, resolution=n, max_depth=2, aa="adaptive", aa_depth=2, aa_threshold=0.1)
    assert adaptive.stats["rays.eye"] < (4 * n + 1) ** 2


@pytest.mark.parametrize("bad", [dict(aa="box"), dict(aa="jitter", samples=10), dict(aa="jitter", samples=0),
                                 dict(aa="adaptive", aa_depth=5), dict(aa="adaptive", aa_threshold=-1.0),
                                 dict(aa="jitter", seed=-1), dict(cutoff=2.0), dict(shading="phong"),
                                 dict(spd=True, aa="jitter"), dict(spd=True, cutoff=0.01)])
def test_bad_sampling_options_are_clear_errors(bad):
    with pytest.raises(OptionError):
        render(two_spheres(), resolution=4, **bad)


def test_the_cut_off_counts_the_rays_it_saves():
    # at depth 2 every secondary ray is a leaf: cast + cut off is the same whatever the cut-off
    scene = two_spheres()
    totals = []
    for cutoff in (0.0, 1 / 512, 0.15, 0.5, 1.0):
        s = render(scene, resolution=32, max_depth=2, cutoff=cutoff).stats
        totals.append(s["rays.reflect"] + s["rays.refract"] + s["rays.cut_off"])
        if cutoff == 0.0:
            assert s["rays.cut_off"] == 0
        if cutoff >= 0.5:
            assert s["rays.reflect"] == 0       # every Ks here is below 0.5
    assert len(set(totals)) == 1
    deep_all = render(scene, resolution=32, max_depth=8, cutoff=0.0)
    deep_cut = render(scene, resolution=32, max_depth=8, cutoff=0.01)
    assert deep_cut.stats["rays.cut_off"] > 0
    assert deep_cut.stats["rays.total"] < deep_all.stats["rays.total"]
    # what it cut weighed less than 0.01 a ray: the image moves by less than that many of them
    assert np.abs(deep_cut.image - deep_all.image).max() < 0.01 * 8

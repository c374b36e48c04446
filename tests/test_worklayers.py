"""Work layers (render(..., work=True)): every layer sums to its counter in the statistics, for
every kind, nested scenes, tricks, antialiasing, the other shading models, lazy kinds and SPD
mode; the splits by ray type and by nesting level add up to their figures; the same bytes at
any thread count; the memory budget holds them; the files and pictures they are written to."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from raykernel.aggregates import registry
from raykernel.aggregates.memory import MemoryBudgetError
from raykernel.geometry.work import FIGURES, RAY_TYPES
from raykernel.errors import OptionError
from raykernel.rendering import worklayers
from raykernel.rendering.render import render
from raykernel.scene import Group
from raykernel.scene.loading import load

STRUCTURES = tuple(name for name, kind in registry.KINDS.items() if not kind.operands)


@pytest.fixture(scope="module")
def balls():
    return load("spd:balls:1")


@pytest.fixture(scope="module")
def stadium():
    return load("scene:stadium:stadium_prims=600,teapot_prims=200")


def assert_layers_sum(result):
    """Every layer equals its counter summed; the splits add up to their figures; a counter
    the render counted has its layer."""
    layers, stats = result.work, result.stats
    assert layers is not None
    shape = next(iter(layers.values())).shape
    compared = 0
    for name, layer in layers.items():
        assert layer.shape == shape, name
        assert (np.asarray(layer) >= 0).all(), name
        if name in stats:
            assert int(np.asarray(layer, np.int64).sum()) == stats[name], name
            compared += 1
    for name in registry.COUNTER_NAMES.values():
        if name in stats and stats[name] and not name.startswith("lazy."):
            assert name in layers, f"{name} was counted ({stats[name]}) but has no layer"
    for figure in FIGURES:
        by_type = sum(np.asarray(layers[f"{figure}.{t}"], np.int64) for t in RAY_TYPES)
        assert np.array_equal(by_type, layers[figure]), figure
        levels = [k for k in layers if k.startswith(f"{figure}.level")]
        if levels:
            assert np.array_equal(sum(np.asarray(layers[k], np.int64) for k in levels), layers[figure]), figure
    assert compared >= 8
    return layers


@pytest.mark.parametrize("accel", STRUCTURES)
def test_every_kind_s_layers_sum_to_its_counters(balls, accel):
    result = render(balls, accel=accel, resolution=24, work=True)
    layers = assert_layers_sum(result)
    assert layers["rays.eye"].shape == (24, 24)
    assert (layers["rays.eye"] == 1).all()          # one eye ray a pixel
    assert layers["rays.shadow"].sum() > 0 and layers["tests.total.shadow"].sum() > 0


def test_spd_layers_are_the_pixel_corners(balls):
    result = render(balls, accel="bvh", resolution=20, spd=True, work=True)
    layers = assert_layers_sum(result)
    assert layers["tests.total"].shape == (21, 21)
    assert (layers["rays.eye"] == 1).all()


def nested(scene, outer, inner):
    """`scene` with `outer` at the root and `inner` over each of its groups (the teapot's, ...)."""
    scene = copy.deepcopy(scene)
    scene.root.accel = outer
    for child in scene.root.children:
        if isinstance(child, Group):
            child.accel = inner
    return scene


@pytest.mark.parametrize("outer, inner", [("grid", "bvh"), ("octree", "grid"), ("bvh", "octree"), ("hybrid", "bvh"),
                                          ("list", "hgrid"), ("rc", "list")])
def test_nested_layers_split_by_level(stadium, outer, inner):
    result = render(nested(stadium, outer, inner), accel=outer, resolution=24, work=True)
    layers = assert_layers_sum(result)
    assert result.stats["build.nesting"] >= 2
    deeper = [k for k in layers if k.startswith("tests.total.level") and not k.endswith("level0")]
    assert deeper and sum(int(layers[k].sum()) for k in deeper) > 0      # the teapot's group did work


@pytest.mark.parametrize("options", [
    {"tricks": "all"},
    {"tricks": "none"},
    {"aa": "adaptive"},
    {"aa": "jitter", "samples": 4},
    {"shading": "hall", "shadows": "filtered"},
    {"shading": "heckbert"},
    {"eye_light": 0.5},
])
def test_render_options_keep_the_sums(balls, options):
    layers = assert_layers_sum(render(balls, accel="grid", resolution=16, work=True, **options))
    if options.get("aa"):
        assert (layers["rays.eye"] >= 1).all() and layers["rays.eye"].max() > 1     # a pixel's samples
    elif options.get("shading") != "heckbert":
        assert (layers["rays.eye"] == 1).all()


def test_lazy_kinds_keep_the_sums(balls, stadium):
    for name, kind in registry.KINDS.items():
        if kind.lazy is not None:
            assert_layers_sum(render(balls, accel=name, resolution=32, work=True))
            assert_layers_sum(render(stadium, accel=name, resolution=32, work=True))
    assert_layers_sum(render(balls, accel="rc(lazy=on)", resolution=32, work=True))


def test_same_bytes_at_any_thread_count(stadium):
    one = render(stadium, accel="grid", resolution=40, threads=1, work=True)
    two = render(stadium, accel="grid", resolution=40, threads=2, work=True)
    assert one.work.keys() == two.work.keys()
    for name in one.work:
        assert np.array_equal(one.work[name], two.work[name]), name
    assert np.array_equal(one.image, two.image)


def test_layers_change_nothing_else(balls):
    plain = render(balls, accel="octree", resolution=24)
    worked = render(balls, accel="octree", resolution=24, work=True)
    assert plain.work is None
    assert np.array_equal(plain.image, worked.image)
    def work(stats):
        return {k: v for k, v in stats.items() if not k.startswith("time.") and not k.endswith("seconds")}
    assert work(plain.stats) == work(worked.stats)


def test_an_empty_scene_has_layers_of_misses():
    from raykernel.scene import Scene
    scene = Scene()
    result = render(scene, resolution=8, work=True)
    assert (result.work["rays.eye"] == 1).all()
    assert result.work["tests.total"].sum() == 0


def test_the_budget_holds_the_layers(balls):
    with pytest.raises(MemoryBudgetError, match="work layers"):
        render(balls, accel="list", resolution=400, work=True, max_memory="20M")


def test_files(balls, tmp_path):
    result = render(balls, accel="grid", resolution=16, work=True)
    worklayers.save_layers(result.work, tmp_path / "w.npz")
    saved = np.load(tmp_path / "w.npz")
    for name in ("tests.total", "bounds.tests", "cells.visited", "rays.shadow", "tests.total.shadow"):
        assert np.array_equal(saved[name], result.work[name])
    with pytest.raises(OptionError, match=r"\.npz or \.exr"):
        worklayers.save_layers(result.work, tmp_path / "w.txt")
    assert not (tmp_path / "w.txt").exists()


def test_picture(balls, tmp_path):
    from PIL import Image
    result = render(balls, accel="grid", resolution=16, work=True)
    worklayers.picture(result.work, "tests.total", tmp_path / "t.png", title="balls, grid", scale="log")
    image = Image.open(tmp_path / "t.png")
    assert image.size[0] > 300 and image.size[1] > 300
    with pytest.raises(OptionError, match="no work layer 'tests.bogus'"):
        worklayers.picture(result.work, "tests.bogus", tmp_path / "x.png")
    with pytest.raises(OptionError, match="scale"):
        worklayers.picture(result.work, "tests.total", tmp_path / "x.png", scale="cubic")
    assert not (tmp_path / "x.png").exists()


def test_command_line(tmp_path, capsys):
    from raykernel.cli import main
    out = tmp_path / "balls.png"
    assert main(["render", "spd:balls:1", "--resolution", "16", "--accel", "grid", "-o", str(out),
                 "--work", str(tmp_path / "w.npz"), "--work-image", "tests.total", "--work-image",
                 f"cells.visited.shadow={tmp_path / 'v.png'}", "--work-scale", "log"]) == 0
    saved = np.load(tmp_path / "w.npz")
    assert saved["tests.total"].shape == (16, 16)
    direct = render(load("spd:balls:1"), accel="grid", resolution=16, work=True)
    for name in ("tests.total", "cells.visited", "rays.shadow", "walk.grid.steps"):
        assert np.array_equal(saved[name], direct.work[name]), name
    assert (tmp_path / "balls.tests.total.png").stat().st_size > 1000
    assert (tmp_path / "v.png").stat().st_size > 1000


@pytest.mark.parametrize("argv, message", [
    (["--work", "w.txt"], ".npz or .exr"),
    (["--work-image", "tests.bogus"], "no work layer 'tests.bogus'"),
    (["--work-image", "tests.total=w.jpg"], "written as .png"),
    (["--work-image", "=w.png"], "expected COUNTER"),
])
def test_command_line_refuses_bad_work_options_before_rendering(tmp_path, capsys, monkeypatch, argv, message):
    from raykernel.cli import main
    monkeypatch.chdir(tmp_path)
    assert main(["render", "spd:balls:1", "--resolution", "16", "-o", "b.png"] + argv) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert not (tmp_path / "b.png").exists()

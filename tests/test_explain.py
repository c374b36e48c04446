"""raykernel explain: one sample's ray tree, logged by the kernels, against the work layers of
the same render (every kind, nested, SPD, AA, tricks) and against itself (its steps and tests
add up to what its searches counted)."""

from __future__ import annotations

import copy
import json

import pytest

from raykernel.aggregates import registry
from raykernel.errors import OptionError
from raykernel.rendering.explain import explain, text
from raykernel.rendering.render import render
from raykernel.scene import Group
from raykernel.scene.loading import load

STRUCTURES = tuple(name for name, kind in registry.KINDS.items() if not kind.operands)
PIXELS = ((3, 4), (12, 12), (20, 7), (0, 23))


@pytest.fixture(scope="module")
def balls():
    return load("spd:balls:1")


def assert_explains(ex, layers, x, y):
    """The explanation's totals are the layers at (x, y); its searches' steps and tests add up
    to what each search counted, and the searches to the totals (no trick counts outside them)."""
    assert ex["totals"] == {name: int(layer[y, x]) for name, layer in layers.items()}
    assert ex["outside"] == {}
    for ray in ex["rays"]:
        tests = sum(len(s["tests"]) for s in ray["steps"]) + len(ray.get("tests", []))
        assert tests == ray["counted"]["tests.total"], ray
        assert sum(s["visited"] for s in ray["steps"]) == ray["counted"]["cells.visited"], ray
        entered = len(ray["entered"]) if not ray.get("culled") else 1
        assert sum(s["bounds"] for s in ray["steps"]) + entered == ray["counted"]["bounds.tests"], ray
        assert ray["type"] in ("eye", "reflect", "refract", "shadow")
    for figure in ("tests.total", "bounds.tests", "cells.visited"):
        assert sum(r["counted"][figure] for r in ex["rays"]) == ex["totals"][figure]
    eye = [r for r in ex["rays"] if r["type"] == "eye"]
    assert len(eye) == ex["totals"]["rays.eye"]


@pytest.mark.parametrize("accel", STRUCTURES)
def test_every_kind_explained_as_its_layers(balls, accel):
    layers = render(balls, accel=accel, resolution=24, work=True).work
    for x, y in PIXELS:
        assert_explains(explain(balls, x, y, accel=accel, resolution=24), layers, x, y)


def test_nested_spd_and_hits(balls):
    stadium = load("scene:stadium:stadium_prims=600,teapot_prims=200")
    scene = copy.deepcopy(stadium)
    scene.root.accel = "grid"
    for child in scene.root.children:
        if isinstance(child, Group):
            child.accel = "octree"
    layers = render(scene, accel="grid", resolution=24, spd=True, work=True).work
    levels = set()
    for x, y in ((12, 12), (24, 24), (5, 18)):
        ex = explain(scene, x, y, accel="grid", resolution=24, spd=True)
        assert_explains(ex, layers, x, y)
        levels |= {s["level"] for r in ex["rays"] for s in r["steps"]}
    assert levels >= {0, 1}
    ex = explain(balls, 12, 12, resolution=24)
    hit = ex["rays"][0]["hit"]
    assert ex["rays"][0]["type"] == "eye" and hit is not None
    assert any(t["t"] == hit["t"] and t["index"] == hit["index"] for s in ex["rays"][0]["steps"] for t in s["tests"])


@pytest.mark.parametrize("options", [{"aa": "jitter", "samples": 4}, {"shading": "hall"}, {"accel": "lazyoctree"}])
def test_options_explained_as_their_layers(balls, options):
    layers = render(balls, resolution=16, work=True, **options).work
    for x, y in ((3, 4), (8, 8)):
        assert_explains(explain(balls, x, y, resolution=16, **options), layers, x, y)


def test_tricks_outside_the_searches(balls):
    layers = render(balls, accel="grid", resolution=16, tricks="all", work=True).work
    ex = explain(balls, 8, 8, accel="grid", resolution=16, tricks="all")
    assert ex["totals"] == {name: int(layer[8, 8]) for name, layer in layers.items()}
    for figure in ("tests.total", "bounds.tests", "cells.visited"):
        assert sum(r["counted"][figure] for r in ex["rays"]) + ex["outside"].get(figure, 0) == ex["totals"][figure]


def test_a_pixel_outside_the_image_is_refused(balls):
    with pytest.raises(OptionError, match=r"pixel \(24, 0\) is outside the 24x24"):
        explain(balls, 24, 0, resolution=24)
    with pytest.raises(OptionError, match="whole number"):
        explain(balls, 1.5, 0, resolution=24)


def test_a_long_log_grows(balls):
    small = explain(balls, 12, 12, accel="list", resolution=24, capacity=4)
    big = explain(balls, 12, 12, accel="list", resolution=24)
    assert small == big and sum(len(s["tests"]) for r in big["rays"] for s in r["steps"]) > 4


def test_command_line(tmp_path, capsys):
    from raykernel.cli import main
    assert main(["explain", "spd:balls:1", "--pixel", "12", "12", "--resolution", "24", "--accel", "octree",
                 "--json", str(tmp_path / "p.json")]) == 0
    out = capsys.readouterr().out
    assert "pixel (12, 12)" in out and "eye ray" in out and "totals" in out
    saved = json.loads((tmp_path / "p.json").read_text())
    layers = render(load("spd:balls:1"), accel="octree", resolution=24, work=True).work
    assert saved["totals"]["tests.total"] == int(layers["tests.total"][12, 12])
    assert text(saved).splitlines()[0] == out.splitlines()[0]
    assert main(["explain", "spd:balls:1", "--pixel", "99", "0", "--resolution", "24"]) == 2
    assert "outside" in capsys.readouterr().err

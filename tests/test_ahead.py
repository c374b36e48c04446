"""A first render's renderer compiled against a stand-in while a helper process builds (rendering/ahead.py)."""

import json
import os
import pickle
import subprocess
import sys

import numba
import numpy as np
import pytest
from numba.core.typing.typeof import Purpose

import raykernel
from raykernel.rendering import ahead
from raykernel.rendering.render import RenderJob
from raykernel.scene.model import Group, TriangleMesh

from support import icosphere, nested_scene, random_scene


def argument_types(job) -> tuple:
    """The numba types of the job's kernel arguments: what its compiled kernel is specialised to."""
    first = job.passes[0][2]
    return tuple(numba.typeof(a, Purpose.argument) for a in job.arguments(0, np.array([first, 0], np.int64), first))


def mesh_scene():
    scene = raykernel.load("spd:balls:1")
    v, f = icosphere(2)
    scene.root.add(TriangleMesh(v, f, 0))
    return scene


SCENES = {
    "balls": lambda: raykernel.load("spd:balls:1"),
    "gears": lambda: raykernel.load("spd:gears:1"),
    "rings": lambda: raykernel.load("spd:rings:1"),
    "teapot": lambda: raykernel.load("spd:teapot:2"),
    "jacks": lambda: raykernel.load("spd:jacks:1"),
    "csg": lambda: raykernel.load("example:csg"),
    "mesh": mesh_scene,
    "nested": lambda: nested_scene(np.random.default_rng(3), "bvh", "grid"),
    "instanced": lambda: nested_scene(np.random.default_rng(4), "bvh", "bvh", instanced=True),
    "random": lambda: random_scene(5),
}
OPTIONS = [dict(), dict(spd=True), dict(accel="grid"), dict(accel="bvh(width=2)"), dict(accel="octree"),
           dict(accel="kdtree"), dict(accel="rc"), dict(accel="hybrid"), dict(tricks="all"), dict(tricks="none"),
           dict(shading="hall"), dict(aa="jitter", samples=4), dict(shadows="filtered"), dict(work=True)]


@pytest.mark.parametrize("name", SCENES)
@pytest.mark.parametrize("options", OPTIONS, ids=lambda o: ",".join(f"{k}={v}" for k, v in o.items()) or "default")
def test_the_stand_in_is_typed_as_the_real_build(name, options):
    """The kernel compiled against the stand-in is the one the real render calls: every argument
    of the same numba type (the scene walk's mark included), so the real render compiles nothing."""
    if name == "csg" and options.get("accel", "bvh") != "bvh":
        pytest.skip("the CSG example names its own structures")
    scene = SCENES[name]()
    options = dict(dict(resolution=24), **options)
    assert argument_types(ahead.stand_in_job(scene, options)) == argument_types(RenderJob(scene, **options))


def test_the_stand_in_marks_a_scene_of_one_wide_bvh_and_no_other():
    def marked(scene, accel="bvh"):
        return not ahead.stand_in_job(scene, dict(accel=accel)).geo.wide_center.flags.writeable
    balls = raykernel.load("spd:balls:1")
    assert marked(balls)
    assert not any(marked(balls, accel) for accel in ("grid", "bvh(width=2)", "list"))
    assert not marked(raykernel.Scene())
    assert not marked(nested_scene(np.random.default_rng(4), "bvh", "bvh", instanced=True))


class Recorder:
    """Stands in for what compile_ahead starts and compiles: the helper's command (run for real,
    or replaced by `command`) and the stand-in job it compiles against."""

    def __init__(self, monkeypatch, command=None):
        self.helpers, self.jobs = [], []
        real_popen = subprocess.Popen

        def popen(args, **kw):
            self.helpers.append(list(args))
            return real_popen(command or args, **kw)
        monkeypatch.setattr(ahead.subprocess, "Popen", popen)
        monkeypatch.setattr(RenderJob, "compile_kernel", lambda job: self.jobs.append(job))
        monkeypatch.setattr(ahead, "cached", lambda kernel: False)
        monkeypatch.setattr(ahead, "compiled", lambda kernel: False)
        monkeypatch.setattr(ahead, "enabled", lambda: True)


def test_a_first_render_compiles_against_the_stand_in_while_a_helper_builds(monkeypatch):
    rec = Recorder(monkeypatch)
    scene = raykernel.load("spd:balls:1")
    options = dict(accel="bvh", resolution=8, max_memory=None)
    assert ahead.compile_ahead(scene, options, raykernel.rendering.render._render_tiles)
    (helper,) = rec.helpers
    assert helper[:3] == [sys.executable, "-m", "raykernel.rendering.ahead"]
    assert not os.path.exists(helper[3])        # its task file went with its folder
    (job,) = rec.jobs
    assert job.build["build.aggregates"] == 1 and not job.geo.wide_center.flags.writeable


def test_a_helper_that_fails_costs_the_render_nothing(monkeypatch):
    """The helper dies at once: compile_ahead still compiles against the stand-in, and the render
    (which builds for itself) gives the image a render without any helper gives."""
    rec = Recorder(monkeypatch, command=[sys.executable, "-c", "raise SystemExit(3)"])
    scene = raykernel.load("spd:balls:1")
    assert ahead.compile_ahead(scene, dict(accel="bvh", resolution=8), raykernel.rendering.render._render_tiles)
    assert len(rec.helpers) == 1 and len(rec.jobs) == 1
    monkeypatch.undo()
    assert np.array_equal(raykernel.render(scene, resolution=8).image, raykernel.render(scene, resolution=8).image)


def test_ctrl_c_while_compiling_ahead_stops_the_helper(monkeypatch):
    """Interrupted while it compiles against the stand-in, compile_ahead ends its helper (a
    process that would otherwise sleep on) and leaves no task file behind."""
    rec = Recorder(monkeypatch, command=[sys.executable, "-c", "import time; time.sleep(60)"])
    started = []
    real_popen = ahead.subprocess.Popen

    def popen(args, **kw):
        started.append(real_popen(args, **kw))
        return started[-1]
    monkeypatch.setattr(ahead.subprocess, "Popen", popen)

    def interrupted(job):
        raise KeyboardInterrupt
    monkeypatch.setattr(RenderJob, "compile_kernel", interrupted)
    with pytest.raises(KeyboardInterrupt):
        ahead.compile_ahead(raykernel.load("spd:balls:1"), dict(accel="bvh"), raykernel.rendering.render._render_tiles)
    (helper,) = started
    assert helper.returncode is not None and helper.returncode != 0       # killed, not left to sleep
    assert not os.path.exists(rec.helpers[0][3])


def test_no_helper_where_the_kernel_is_ready_or_the_scene_too_big_or_it_is_off(monkeypatch):
    scene = raykernel.load("spd:balls:1")
    kernel = raykernel.rendering.render._render_tiles
    options = dict(accel="bvh", resolution=8)
    rec = Recorder(monkeypatch)
    monkeypatch.setattr(ahead, "compiled", lambda k: True)
    assert not ahead.compile_ahead(scene, options, kernel)
    monkeypatch.setattr(ahead, "compiled", lambda k: False)
    monkeypatch.setattr(ahead, "cached", lambda k: True)
    assert not ahead.compile_ahead(scene, options, kernel)
    monkeypatch.setattr(ahead, "cached", lambda k: False)
    assert not ahead.compile_ahead(scene, dict(options, accel="auto"), kernel)
    monkeypatch.setattr(ahead, "MAX_HELPER_PRIMITIVES", scene.count_primitives() - 1)
    assert not ahead.compile_ahead(scene, options, kernel)
    assert rec.helpers == [] and rec.jobs == []


def test_it_is_off_on_one_core_or_when_asked(monkeypatch):
    monkeypatch.setenv("RAYKERNEL_COMPILE_AHEAD", "0")
    assert not ahead.enabled()
    monkeypatch.delenv("RAYKERNEL_COMPILE_AHEAD")
    monkeypatch.setattr(ahead.os, "sched_getaffinity", lambda pid: {0}, raising=False)
    assert not ahead.enabled()
    monkeypatch.setattr(ahead.os, "sched_getaffinity", lambda pid: {0, 1}, raising=False)
    assert ahead.enabled()


def test_a_scene_that_cannot_be_pickled_is_compiled_as_before(monkeypatch):
    rec = Recorder(monkeypatch)
    scene = raykernel.load("spd:balls:1")
    scene.root.add(Group(name="odd"))
    scene.root.children[-1].unpicklable = lambda: None      # a lambda does not pickle
    assert not ahead.compile_ahead(scene, dict(accel="bvh", resolution=8), raykernel.rendering.render._render_tiles)
    assert rec.helpers == [] and rec.jobs == []


def test_the_helper_builds_the_scene_it_is_given(tmp_path, monkeypatch):
    """The helper's own entry point builds the pickled scene with the given structure (and fails
    loudly on a structure that cannot be built, as flatten would)."""
    calls = []
    monkeypatch.setattr(ahead, "flatten", lambda *a: calls.append(a))
    task = tmp_path / "build.pickle"
    scene = raykernel.load("spd:balls:1")
    task.write_bytes(pickle.dumps((scene, "grid", "1G")))
    ahead._main([str(task)])
    ((built, accel, budget),) = calls
    assert accel == "grid" and budget == "1G" and built.count_primitives() == scene.count_primitives()


@pytest.mark.slow
def test_on_an_empty_cache_the_builder_compiles_in_the_helper(tmp_path):
    """In a fresh process on an empty cache, a first render compiles the renderer's kernel once,
    against the stand-in, and not the builder's (the helper's, loaded from the cache); its image
    and counts are those of a process that compiled both itself."""
    code = """
import json, sys, numpy as np, raykernel
from numba.core import event
from raykernel.rendering import render as R
compiled = []
class Listen(event.Listener):
    def on_start(self, ev):
        compiled.append(ev.data["dispatcher"].py_func.__qualname__)
    def on_end(self, ev):
        pass
scene = raykernel.load("spd:balls:1")
with event.install_listener("numba:compile", Listen()):
    r = raykernel.render(scene, resolution=16)
np.save(sys.argv[1], r.image)
print(json.dumps([compiled, len(R._render_tiles.signatures), r.stats["rays.total"], r.stats["time.compile"]]))
"""
    results = []
    for on in ("1", "0"):
        env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / f"cache{on}"), RAYKERNEL_COMPILE_AHEAD=on)
        out = subprocess.run([sys.executable, "-c", code, str(tmp_path / f"image{on}.npy")], env=env,
                             capture_output=True, text=True, check=True).stdout
        results.append(json.loads(out.strip().splitlines()[-1]))
    (names, signatures, rays, compile_s), (names_alone, _, rays_alone, _) = results
    assert "_build_loop" in names_alone and "_build_loop" not in names
    assert names.count("_render_tiles") == 1 and signatures == 1 and compile_s > 0.0
    assert rays == rays_alone
    assert np.array_equal(np.load(tmp_path / "image1.npy"), np.load(tmp_path / "image0.npy"))

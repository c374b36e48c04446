"""First compiles side by side: a helper process builds (geometry/ahead.py) while a first render's
renderer (rendering/ahead.py) or a first mesh query's kernel (casting/meshahead.py) compiles here."""

import json
import os
import pickle
import subprocess
import sys
from types import SimpleNamespace

import numba
import numpy as np
import pytest
from numba.core.typing.typeof import Purpose

import raykernel
from raykernel.aggregates.registry import KINDS
from raykernel.casting import meshahead, meshcast, rayqueries
from raykernel.geometry import ahead as helpers
from raykernel.rendering import ahead
from raykernel.rendering.render import RenderJob, tile_kernel
from raykernel.scene.model import Group, TriangleMesh

from support import icosphere, nested_scene, random_scene

QUERY = meshcast.query
TILES = tile_kernel("whitted", None)


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
# every scene with the options that change the kernel's types most; every structure that takes no
# operands, by name (auto anneals first: it compiles nothing ahead), on a flat and a nested scene;
# the other options on spheres and on a mesh
STRUCTURES = ["bvh(width=2)", *(name for name, kind in KINDS.items() if not kind.operands and name != "auto")]
CASES = [*((name, options) for name in SCENES for options in (dict(), dict(tricks="all"), dict(work=True))),
         *((name, dict(accel=accel)) for name in ("balls", "nested") for accel in STRUCTURES),
         *((name, options) for name in ("balls", "mesh")
           for options in (dict(spd=True), dict(tricks="none"), dict(shading="hall"), dict(aa="jitter", samples=4),
                           dict(shadows="filtered")))]


@pytest.mark.parametrize("name,options", CASES,
                         ids=[f"{n}-" + (",".join(f"{k}={v}" for k, v in o.items()) or "default") for n, o in CASES])
def test_the_stand_in_is_typed_as_the_real_build(name, options):
    """The kernel compiled against the stand-in is the one the real render calls: every argument
    of the same numba type (the scene walk's mark included), so the real render compiles nothing."""
    scene = SCENES[name]()
    options = dict(dict(resolution=24), **options)
    assert argument_types(ahead.stand_in_job(RenderJob, scene, options)) == argument_types(RenderJob(scene, **options))


def test_the_stand_in_marks_a_scene_of_one_wide_bvh_and_no_other():
    def marked(scene, accel="bvh"):
        return not ahead.stand_in_job(RenderJob, scene, dict(accel=accel)).geo.wide_center.flags.writeable
    balls = raykernel.load("spd:balls:1")
    assert marked(balls)
    assert not any(marked(balls, accel) for accel in ("grid", "bvh(width=2)", "list"))
    assert not marked(raykernel.Scene())
    assert not marked(nested_scene(np.random.default_rng(4), "bvh", "bvh", instanced=True))


class Recorder:
    """Stands in for what compile_ahead starts and compiles: the helper (run for real, or
    `command` instead), what it was asked to call, and the stand-in job compiled here."""

    def __init__(self, monkeypatch, command=None):
        self.helpers, self.calls, self.jobs, self.started = [], [], [], []
        real_popen = subprocess.Popen

        def popen(args, **kw):
            self.helpers.append(list(args))
            self.calls.append(pickle.loads(open(args[3], "rb").read()))
            self.started.append(real_popen(command or args, **kw))
            return self.started[-1]
        monkeypatch.setattr(helpers.subprocess, "Popen", popen)
        monkeypatch.setattr(RenderJob, "compile_kernel", lambda job: self.jobs.append(job))
        monkeypatch.setattr(ahead, "cached", lambda kernel: False)
        monkeypatch.setattr(ahead, "compiled", lambda kernel: False)
        monkeypatch.setattr(ahead, "enabled", lambda: True)


def test_a_first_render_compiles_against_the_stand_in_while_a_helper_builds(monkeypatch):
    rec = Recorder(monkeypatch)
    scene = raykernel.load("spd:balls:1")
    options = dict(accel="bvh", resolution=8, max_memory=None)
    assert ahead.compile_ahead(RenderJob, scene, options, TILES)
    (helper,) = rec.helpers
    assert helper[:3] == [sys.executable, "-m", "raykernel.geometry.ahead"]
    assert not os.path.exists(helper[3])        # its task file went with its folder
    ((module, function, (built, accel, budget)),) = rec.calls
    assert (module, function, accel, budget) == ("raykernel.engine.flatten", "flatten", "bvh", None)
    assert built.count_primitives() == scene.count_primitives()
    assert rec.started[0].returncode == 0       # the helper built it
    (job,) = rec.jobs
    assert job.build["build.aggregates"] == 1 and not job.geo.wide_center.flags.writeable


def test_a_helper_that_fails_costs_the_render_nothing(monkeypatch):
    """The helper dies at once: compile_ahead still compiles against the stand-in, and the render
    (which builds for itself) gives the image a render without any helper gives."""
    rec = Recorder(monkeypatch, command=[sys.executable, "-c", "raise SystemExit(3)"])
    scene = raykernel.load("spd:balls:1")
    assert ahead.compile_ahead(RenderJob, scene, dict(accel="bvh", resolution=8), TILES)
    assert len(rec.helpers) == 1 and len(rec.jobs) == 1
    monkeypatch.undo()
    assert np.array_equal(raykernel.render(scene, resolution=8).image, raykernel.render(scene, resolution=8).image)


def test_ctrl_c_while_compiling_ahead_stops_the_helper(monkeypatch):
    """Interrupted while it compiles against the stand-in, compile_ahead ends its helper (a
    process that would otherwise sleep on) and leaves no task file behind."""
    rec = Recorder(monkeypatch, command=[sys.executable, "-c", "import time; time.sleep(60)"])

    def interrupted(job):
        raise KeyboardInterrupt
    monkeypatch.setattr(RenderJob, "compile_kernel", interrupted)
    with pytest.raises(KeyboardInterrupt):
        ahead.compile_ahead(RenderJob, raykernel.load("spd:balls:1"), dict(accel="bvh"), TILES)
    (helper,) = rec.started
    assert helper.returncode is not None and helper.returncode != 0       # killed, not left to sleep
    assert not os.path.exists(rec.helpers[0][3])


def test_no_helper_where_the_kernel_is_ready_or_the_scene_too_big_or_it_is_off(monkeypatch):
    scene = raykernel.load("spd:balls:1")
    kernel = TILES
    options = dict(accel="bvh", resolution=8)
    rec = Recorder(monkeypatch)
    monkeypatch.setattr(ahead, "compiled", lambda k: True)
    assert not ahead.compile_ahead(RenderJob, scene, options, kernel)
    monkeypatch.setattr(ahead, "compiled", lambda k: False)
    monkeypatch.setattr(ahead, "cached", lambda k: True)
    assert not ahead.compile_ahead(RenderJob, scene, options, kernel)
    monkeypatch.setattr(ahead, "cached", lambda k: False)
    assert not ahead.compile_ahead(RenderJob, scene, dict(options, accel="auto"), kernel)
    monkeypatch.setattr(ahead, "MAX_HELPER_PRIMITIVES", scene.count_primitives() - 1)
    assert not ahead.compile_ahead(RenderJob, scene, options, kernel)
    assert rec.helpers == [] and rec.jobs == []


def test_it_is_off_on_one_core_or_when_asked(monkeypatch):
    monkeypatch.setenv("RAYKERNEL_COMPILE_AHEAD", "0")
    assert not helpers.enabled()
    monkeypatch.delenv("RAYKERNEL_COMPILE_AHEAD")
    monkeypatch.setattr(helpers.os, "sched_getaffinity", lambda pid: {0}, raising=False)
    assert not helpers.enabled()
    monkeypatch.setattr(helpers.os, "sched_getaffinity", lambda pid: {0, 1}, raising=False)
    assert helpers.enabled()


def test_a_scene_that_cannot_be_pickled_is_compiled_as_before(monkeypatch):
    rec = Recorder(monkeypatch)
    scene = raykernel.load("spd:balls:1")
    scene.root.add(Group(name="odd"))
    scene.root.children[-1].unpicklable = lambda: None      # a lambda does not pickle
    assert not ahead.compile_ahead(RenderJob, scene, dict(accel="bvh", resolution=8), TILES)
    assert rec.helpers == [] and rec.jobs == []


def test_the_helper_makes_the_call_it_is_given(tmp_path, monkeypatch):
    """The helper's own entry point calls the pickled function with its arguments (and fails
    loudly where that call fails, as it would here)."""
    from raykernel.engine import flatten as flatten_module
    calls = []
    monkeypatch.setattr(flatten_module, "flatten", lambda *a: calls.append(a))
    task = tmp_path / "call.pickle"
    scene = raykernel.load("spd:balls:1")
    task.write_bytes(pickle.dumps(("raykernel.engine.flatten", "flatten", (scene, "grid", "1G"))))
    helpers._main([str(task)])
    ((built, accel, budget),) = calls
    assert accel == "grid" and budget == "1G" and built.count_primitives() == scene.count_primitives()
    task.write_bytes(pickle.dumps(("raykernel.engine.flatten", "no_such_function", ())))
    with pytest.raises(AttributeError):
        helpers._main([str(task)])


# a child process's first lines: `compiled` lists the kernels it compiles, by name, in order
COMPILES = """
import json, sys, numpy as np, raykernel
from numba.core import event
compiled = []
class Listen(event.Listener):
    def on_start(self, ev):
        compiled.append(ev.data["dispatcher"].py_func.__qualname__)
    def on_end(self, ev):
        pass
"""


@pytest.mark.slow
def test_on_an_empty_cache_the_builder_compiles_in_the_helper(tmp_path):
    """In a fresh process on an empty cache, a first render compiles the renderer's kernel once,
    against the stand-in, and not the builder's (the helper's, loaded from the cache); its image
    and counts are those of a process that compiled both itself."""
    code = COMPILES + """
from raykernel.rendering import render as R
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


# a first mesh query (casting/meshahead.py)

def mesh_kernel_types(monkeypatch, call) -> tuple:
    """The numba types of the mesh kernel's arguments in `call`'s first call of it."""
    seen = []

    def recorded(*args):
        seen.append(tuple(numba.typeof(a, Purpose.argument) for a in args))
        return QUERY(*args)
    monkeypatch.setattr(meshcast, "query", recorded)
    call()
    monkeypatch.setattr(meshcast, "query", QUERY)
    return seen[0]


@pytest.mark.parametrize("single", [False, True], ids=["double", "single"])
@pytest.mark.parametrize("smooth", [False, True], ids=["flat", "smooth"])
@pytest.mark.parametrize("edges", ["watertight", "inclusive"])
@pytest.mark.parametrize("quality", ["fast", "high"])
def test_the_mesh_stand_in_is_typed_as_the_real_build(monkeypatch, single, smooth, edges, quality):
    """The kernel compiled against the stand-in is the one a query without surface fields
    calls on the real build, closest hits and occluded alike (read-only inputs included)."""
    monkeypatch.setenv("RAYKERNEL_COMPILE_AHEAD", "0")
    v, f = icosphere(2)
    v.flags.writeable = False
    normals = v / np.linalg.norm(v, axis=1)[:, None] if smooth else None
    rs = raykernel.RayScene.from_mesh(v, f, normals, edges=edges, quality=quality,
                                      precision="single" if single else "double")
    mesh = rs._mesh
    stand_in = SimpleNamespace(_mesh=meshahead.stand_in(mesh.geo.tri_verts, mesh.geo.tri_faces,
                                                        None if not smooth else mesh.geo.tri_vnormals,
                                                        int(mesh.geo.tri_edges[0]), single), _lazy=None)
    o, d = np.array([[0.1, 0.2, -3.0]]), np.array([[0.0, 0.0, 1.0]])
    want = mesh_kernel_types(monkeypatch, lambda: rayqueries.compile_query(stand_in))
    assert mesh_kernel_types(monkeypatch, lambda: rs.intersect(o, d, fields=("t", "prim_id"))) == want
    assert mesh_kernel_types(monkeypatch, lambda: rs.occluded(o, d)) == want
    # a query of surface fields is another kernel (it compiles its surface pass)
    assert mesh_kernel_types(monkeypatch, lambda: rs.intersect(o, d)) != want


def test_a_first_mesh_query_compiles_ahead_while_a_helper_builds_a_small_mesh(monkeypatch):
    rec = Recorder(monkeypatch)
    compiled_for = []
    monkeypatch.setattr(meshahead, "cached", lambda kernel: False)
    monkeypatch.setattr(meshahead, "compiled", lambda kernel: False)
    monkeypatch.setattr(meshahead, "enabled", lambda: True)
    monkeypatch.setattr(rayqueries, "compile_query", lambda rs: compiled_for.append(rs._mesh))
    v, f = icosphere(1)
    rs = raykernel.RayScene.from_mesh(v, f, quality="fast", edges="inclusive", precision="single")
    ((module, function, args),) = rec.calls
    assert (module, function) == ("raykernel.casting.meshbuild", "build_mesh")
    small_v, small_f, normals, quality, edges, threads, single = args
    assert (quality, single, normals) == ("fast", True, None) and edges == int(rs._mesh.geo.tri_edges[0])
    assert rec.started[0].returncode == 0       # the helper built the small mesh
    (stand_in,) = compiled_for
    assert len(stand_in.wide.nodes) == 1 and stand_in.blocks.dtype == np.float32
    assert stand_in.geo.tri_faces is rs._mesh.geo.tri_faces      # the mesh's own arrays, not copied
    assert rs.build_stats["query_compile_seconds"] >= 0.0
    hits = rs.intersect(np.array([[0.1, 0.2, -3.0]]), np.array([[0.0, 0.0, 1.0]]))
    assert np.isfinite(hits.t[0])


def test_no_mesh_query_is_compiled_ahead_where_it_is_ready_or_off(monkeypatch):
    rec = Recorder(monkeypatch)
    v, f = icosphere(1)
    monkeypatch.setattr(meshahead, "enabled", lambda: True)
    for ready in ("compiled", "cached"):
        monkeypatch.setattr(meshahead, "compiled", lambda kernel: ready == "compiled")
        monkeypatch.setattr(meshahead, "cached", lambda kernel: ready == "cached")
        assert meshahead.compile_query_ahead(v, f, None, "medium", 0, None, False) == 0.0
    monkeypatch.setattr(meshahead, "cached", lambda kernel: False)
    monkeypatch.setattr(meshahead, "enabled", lambda: False)
    assert meshahead.compile_query_ahead(v, f, None, "medium", 0, None, False) == 0.0
    assert rec.helpers == []


@pytest.mark.slow
def test_on_an_empty_cache_a_first_mesh_query_compiles_beside_the_builder(tmp_path):
    """In a fresh process on an empty cache, from_mesh compiles the query kernel and not the
    builder's (the helper's, loaded from the cache); the query's answers are those of a process
    that compiled both itself, and a later query of every field compiles no walk again."""
    code = COMPILES + """
sys.path.insert(0, sys.argv[2])
from support import icosphere
v, f = icosphere(3)
rng = np.random.default_rng(1)
o = rng.normal(0, 3, (500, 3)); d = -o + rng.normal(0, 0.3, (500, 3))
with event.install_listener("numba:compile", Listen()):
    rs = raykernel.RayScene.from_mesh(v, f)
    ids = rs.intersect(o, d, fields=("t", "prim_id"))
    built = list(compiled)
    every = rs.intersect(o, d)
np.save(sys.argv[1], np.c_[ids.t, ids.prim_id, every.t, every.normal])
print(json.dumps([built, compiled[len(built):]]))
"""
    results = []
    for on in ("1", "0"):
        env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / f"cache{on}"), RAYKERNEL_COMPILE_AHEAD=on)
        out = subprocess.run([sys.executable, "-c", code, str(tmp_path / f"hits{on}.npy"), os.path.dirname(__file__)],
                             env=env, capture_output=True, text=True, check=True).stdout
        results.append(json.loads(out.strip().splitlines()[-1]))
    (built, later), (built_alone, _) = results
    assert "_build_loop" in built_alone and "_build_loop" not in built
    assert built.count("query") == 1 and "_chunk4" in built
    assert "_chunk4" not in later and "_surfaces" in later
    assert np.array_equal(np.load(tmp_path / "hits1.npy"), np.load(tmp_path / "hits0.npy"), equal_nan=True)

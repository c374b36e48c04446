"""Compile the kernels a user will need before the first real call (or load them from the cache).

    report = warm_up("render")      # "render", "cast" or "all"; progress(done, total, label) if given
    report["seconds"], report["compile"], report["load"], report["steps"], report["processes"]
    warm_up("all", processes=2)     # the steps shared out among 2 processes, one a core (the default)

Rendering's steps render a tiny scene once with every structure kind, each shading model,
antialiasing, filtered shadows and work layers: each of those compiles its own kernels. Casting's
steps make every RayScene query on a small mesh, on spheres and on a scene walked by the general
driver. Kernels are cached on disk (geometry/config.py), so later processes, and other users of
the same cache folder (NUMBA_CACHE_DIR), load them instead of compiling. numba compiles on one
thread, so the steps are shared out among processes, one a core, each compiling its own share
into the cache (`python -m raykernel.analysis.warmup TARGET STEP ...` runs a share and says, a
line of JSON a step, what it took); compile and load seconds are summed over the processes.
"""

from __future__ import annotations

import contextlib
import functools
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from types import SimpleNamespace

import numpy as np

from ..aggregates.registry import KINDS
from ..errors import OptionError
from ..geometry.compiletime import CompileClock

TARGETS = ("render", "cast", "all")


@functools.cache
def _balls():
    from ..scene.loading import load
    return load("spd:balls:1")


def _render_steps() -> list:
    from ..rendering.render import render
    from ..scene.loading import load

    def step(**options):
        return lambda: render(_balls(), resolution=4, threads=None, **options)
    steps = [(f"render with {name}", step(accel=name)) for name, kind in KINDS.items() if not kind.operands]
    steps.append(("render a CSG scene", lambda: render(load("example:csg"), resolution=4)))
    steps += [("render with Hall's shading", step(shading="hall")),
              ("render with Heckbert's shading", step(shading="heckbert")),
              ("render antialiased", step(aa="jitter", samples=4)),
              ("render with filtered shadows", step(shadows="filtered")),
              ("render with work layers", step(work=True))]
    return steps


@functools.cache
def _cast_scenes() -> SimpleNamespace:
    """A closed octahedron (in both precisions), spheres and a scene walked by the general driver,
    with rays from around them inwards and points: built by the first cast step that runs (in the
    process that runs it)."""
    from ..casting.rayscene import RayScene
    from ..scene.model import Scene, Spheres
    vertices = np.array([[1.0, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]])
    faces = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    origins = np.array([[3.0, 0.2, 0.1], [0.1, -3.0, 0.3], [0.2, 0.1, 3.0]])
    points = origins / 4.0
    general = Scene()
    general.root.spheres = Spheres()
    general.root.spheres.add([0.0, 0.0, 0.0], 1.0, 0)
    return SimpleNamespace(mesh=RayScene.from_mesh(vertices, faces), o=origins, d=-origins, points=points,
                           single=RayScene.from_mesh(vertices, faces, precision="single"),
                           spheres=RayScene.from_spheres(points, np.full(len(points), 0.5)),
                           driven=RayScene.from_scene(general, accel="bvh"))


def _cast_steps() -> list:
    def step(query):
        return lambda: query(_cast_scenes())
    return [("cast: intersect", step(lambda c: c.mesh.intersect(c.o, c.d))),
            ("cast: intersect in float32", step(lambda c: c.mesh.intersect(c.o, c.d, fields=("t", "prim_id"),
                                                                           dtype="float32"))),
            ("cast: intersect, single precision", step(lambda c: c.single.intersect(c.o, c.d))),
            ("cast: occluded", step(lambda c: c.mesh.occluded(c.o, c.d))),
            ("cast: intersect_all", step(lambda c: c.mesh.intersect_all(c.o, c.d))),
            ("cast: count_hits", step(lambda c: c.mesh.count_hits(c.o, c.d))),
            ("cast: closest_points", step(lambda c: c.mesh.closest_points(c.points))),
            ("cast: contains", step(lambda c: c.mesh.contains(c.points))),
            ("cast: spheres", step(lambda c: c.spheres.intersect(c.o, c.d))),
            ("cast: a scene's driver", step(lambda c: c.driven.intersect(c.o, c.d)))]


def plan(target: str) -> list:
    """The (label, call) steps of a warm-up of `target` (render, cast or all)."""
    if target not in TARGETS:
        raise OptionError(f"warm up what? {target!r}: one of {', '.join(TARGETS)}")
    steps = []
    if target in ("render", "all"):
        steps += _render_steps()
    if target in ("cast", "all"):
        steps += _cast_steps()
    return steps


def _timed(call) -> tuple[float, float]:
    """Run call(); its compile and load seconds."""
    with CompileClock() as clock:
        call()
    return clock.seconds, clock.loading


def _run(steps, progress) -> tuple[float, float]:
    """Run (label, call) steps here; their compile and load seconds."""
    compile_s = load_s = 0.0
    for done, (label, call) in enumerate(steps):
        if progress is not None:
            progress(done, len(steps), label)
        c, s = _timed(call)
        compile_s, load_s = compile_s + c, load_s + s
    return compile_s, load_s


def _shares(count: int, processes: int) -> list[list[int]]:
    """Step indices dealt out round-robin: neighbouring steps (one kind's render, then the next) apart."""
    return [list(range(k, count, processes)) for k in range(processes) if k < count]


def _in_processes(target: str, steps, processes: int, progress) -> tuple[float, float]:
    """Each share of the steps in a process of its own; progress as their steps finish. A child's
    stderr goes to a file of its own, so that nothing it says can fill a pipe and stop it."""
    done, totals, errors, lock = [0], [0.0, 0.0], [], threading.Lock()

    def follow(child, said):
        for line in child.stdout:
            step = json.loads(line)
            with lock:
                done[0] += 1
                totals[0] += step["compile"]
                totals[1] += step["load"]
                if progress is not None and done[0] < len(steps):      # the last: warm_up's "done"
                    progress(done[0], len(steps), step["label"])
        if child.wait():
            said.seek(0)
            errors.append(said.read().decode(errors="replace").strip().splitlines()[-1:]
                          or [f"exit status {child.returncode}"])

    with contextlib.ExitStack() as stack:
        children = []
        for share in _shares(len(steps), processes):
            said = stack.enter_context(tempfile.TemporaryFile())
            # the processes fill the cores already: no render of theirs starts a helper of its own (rendering/ahead.py)
            child = stack.enter_context(subprocess.Popen([sys.executable, "-m", __name__, target, *map(str, share)],
                                                         stdout=subprocess.PIPE, stderr=said, text=True,
                                                         env=dict(os.environ, RAYKERNEL_COMPILE_AHEAD="0")))
            stack.callback(lambda c=child: c.poll() is None and c.kill())      # runs before the Popen's exit
            children.append((child, said))
        readers = [threading.Thread(target=follow, args=pair, daemon=True) for pair in children]
        for r in readers:
            r.start()
        for r in readers:
            while r.is_alive():
                r.join(0.2)         # a short wait, so Ctrl-C is answered at once
    if errors:
        raise RuntimeError(f"warm-up: a process failed: {errors[0][0]}")
    return totals[0], totals[1]


def warm_up(target: str = "all", progress=None, processes: int | None = None) -> dict:
    """Run the steps of `target`, shared out among `processes` processes (default: one a core;
    1: all in this process); the seconds taken, of them compiling and loading (summed over the
    processes), the step count and the processes used."""
    steps = plan(target)
    if processes is None:
        processes = os.cpu_count() or 1
    processes = max(1, min(int(processes), len(steps)))
    t0 = time.perf_counter()
    if processes == 1:
        compile_s, load_s = _run(steps, progress)
    else:
        if progress is not None:
            progress(0, len(steps), f"in {processes} processes")
        compile_s, load_s = _in_processes(target, steps, processes, progress)
    if progress is not None:
        progress(len(steps), len(steps), "done")
    return {"target": target, "steps": len(steps), "seconds": time.perf_counter() - t0, "compile": compile_s,
            "load": load_s, "processes": processes}


def _main(argv) -> None:
    """python -m raykernel.analysis.warmup TARGET STEP ...: run those steps of the target's plan,
    a line of JSON for each when it is done."""
    steps = plan(argv[0])
    for index in map(int, argv[1:]):
        label, call = steps[index]
        compile_s, load_s = _timed(call)
        print(json.dumps({"label": label, "compile": compile_s, "load": load_s}), flush=True)


if __name__ == "__main__":
    _main(sys.argv[1:])

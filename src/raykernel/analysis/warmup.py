"""Compile the kernels a user will need before the first real call (or load them from the cache).

    report = warm_up("render")      # "render", "cast" or "all"; progress(done, total, label) if given
    report["seconds"], report["compile"], report["load"], report["steps"]

Rendering's steps render a tiny scene once with every structure kind, each shading model,
antialiasing, filtered shadows and work layers: each of those compiles its own kernels. Casting's
steps make every RayScene query on a small mesh, on spheres and on a scene walked by the general
driver. Kernels are cached on disk (geometry/config.py), so later processes, and other users of
the same cache folder (NUMBA_CACHE_DIR), load them instead of compiling.
"""

from __future__ import annotations

import time

import numpy as np

from ..aggregates.registry import KINDS
from ..errors import OptionError
from ..geometry.compiletime import CompileClock

TARGETS = ("render", "cast", "all")


def _render_steps() -> list:
    from ..rendering.render import render
    from ..scene.loading import load
    scene = load("spd:balls:1")

    def step(**options):
        return lambda: render(scene, resolution=4, threads=None, **options)
    steps = [(f"render with {name}", step(accel=name)) for name, kind in KINDS.items() if not kind.operands]
    steps.append(("render a CSG scene", lambda: render(load("example:csg"), resolution=4)))
    steps += [("render with Hall's shading", step(shading="hall")),
              ("render with Heckbert's shading", step(shading="heckbert")),
              ("render antialiased", step(aa="jitter", samples=4)),
              ("render with filtered shadows", step(shadows="filtered")),
              ("render with work layers", step(work=True))]
    return steps


def _cast_steps() -> list:
    from ..casting.rayscene import RayScene
    from ..scene.model import Scene, Spheres
    # a closed octahedron, and rays from around it inwards
    vertices = np.array([[1.0, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]])
    faces = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    origins = np.array([[3.0, 0.2, 0.1], [0.1, -3.0, 0.3], [0.2, 0.1, 3.0]])
    directions = -origins
    points = origins / 4.0
    mesh = RayScene.from_mesh(vertices, faces)
    spheres = RayScene.from_spheres(points, np.full(len(points), 0.5))
    general = Scene()
    general.root.spheres = Spheres()
    general.root.spheres.add([0.0, 0.0, 0.0], 1.0, 0)
    driven = RayScene.from_scene(general, accel="bvh")
    return [("cast: intersect", lambda: mesh.intersect(origins, directions)),
            ("cast: intersect in float32", lambda: mesh.intersect(origins, directions, fields=("t", "prim_id"),
                                                                  dtype="float32")),
            ("cast: occluded", lambda: mesh.occluded(origins, directions)),
            ("cast: intersect_all", lambda: mesh.intersect_all(origins, directions)),
            ("cast: count_hits", lambda: mesh.count_hits(origins, directions)),
            ("cast: closest_points", lambda: mesh.closest_points(points)),
            ("cast: contains", lambda: mesh.contains(points)),
            ("cast: spheres", lambda: spheres.intersect(origins, directions)),
            ("cast: a scene's driver", lambda: driven.intersect(origins, directions))]


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


def warm_up(target: str = "all", progress=None) -> dict:
    """Run the steps of `target`; the seconds taken, of them compiling and loading, and the step count."""
    steps = plan(target)
    t0 = time.perf_counter()
    compile_s = load_s = 0.0
    for done, (label, call) in enumerate(steps):
        if progress is not None:
            progress(done, len(steps), label)
        with CompileClock() as clock:
            call()
        compile_s += clock.seconds
        load_s += clock.loading
    if progress is not None:
        progress(len(steps), len(steps), "done")
    return {"target": target, "steps": len(steps), "seconds": time.perf_counter() - t0, "compile": compile_s,
            "load": load_s}

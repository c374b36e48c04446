"""Renders whose structures are `auto`: the hierarchy annealed first (anneal.py), then rendered.

    result = render(scene, accel="auto(seconds=10)", resolution=256)     # raykernel.render
    scene, options, annealed = tune(scene, {"accel": "auto", ...})         # the search alone

A spec `auto` (the render's accel, or a group's) is not a structure but a search
for one: this layer anneals it into a hierarchy of the registered kinds, then
hands the render to rendering.render with what it found recorded in the
statistics (time.anneal, info["anneal"]). A render without auto specs is
rendering.render's as it is.
"""

from __future__ import annotations

import time

from ..rendering import render as rendering
from ..scene.model import Scene
from .anneal import resolve_auto


def tune(scene: Scene, kw: dict):
    """Resolve `auto` specs (the render's accel or a group's) by annealing: (the scene with the
    hierarchies found, the options with a concrete accel, what was found: {"seconds",
    "groups"}, or None where nothing was auto)."""
    t0 = time.perf_counter()
    options = {k: v for k, v in kw.items() if k != "accel"}
    found = resolve_auto(scene, kw.get("accel", "bvh"), options)
    if found is None:
        return scene, kw, None
    tuned, default, groups = found
    tuned.source = scene.source
    return tuned, {**kw, "accel": default}, {"seconds": time.perf_counter() - t0, "groups": groups}


def render(scene: Scene, accel: str = "bvh", **options) -> rendering.RenderResult:
    """rendering.render (see its arguments), `auto` specs annealed first."""
    scene, options, annealed = tune(scene, dict(options, accel=accel))
    return rendering.render(scene, annealed=annealed, **options)


render.__doc__ = rendering.render.__doc__.replace("Render `scene`;", "Render `scene` (auto specs annealed first);", 1)

"""A first render's two compiles side by side: the renderer here, the builder in a helper process.

    with CompileClock(notice=say) as clock:
        went = compile_ahead(RenderJob, scene, options, tile_kernel(shading, aa))   # render() does this first
    job = RenderJob(scene, **options)       # its build and its trace load what compiled

When the renderer's kernel is in neither this process nor the kernel cache, a helper process
builds the scene (geometry/ahead.py), its builder's kernels compiling into the cache, while this
process compiles the renderer against a stand-in: the scene laid out as a plain list (which no
kernel builds), typed as the real build will be (`StandIn`). The stand-in's type is a forecast:
where it misses, the real render compiles its own kernel too (time lost, not a wrong image);
tests hold it on the usual scenes and options.
"""

from __future__ import annotations

import numpy as np

from ..aggregates.registry import parse_spec
from ..aggregates.spec import is_auto
from ..engine.flatten import flatten
from ..geometry.ahead import beside, enabled
from ..geometry.config import cached, compiled

MAX_HELPER_PRIMITIVES = 1_000_000    # above, the helper's copy of the build costs more than it saves


class StandIn:
    """A RenderJob builder that builds nothing: the scene as one plain list, typed as `accel`'s
    build will be. The one type that differs between structures is the scene walk's mark
    (aggregates/widewalk.py, wide_only): a scene that is one BVH of width 4 over primitives
    gets its read-only center."""

    @staticmethod
    def flatten(scene, accel, max_memory):
        geo, build = flatten(scene, "list", max_memory)
        if _wide_alone(scene, accel, geo):
            center = np.zeros(3)
            center.flags.writeable = False
            geo = geo._replace(wide_center=center)
        return geo, build


def _wide_alone(scene, accel, geo) -> bool:
    """The real build of `scene` will be one BVH of width 4 over primitives (widewalk.prepare):
    one aggregate, no instance, the root's spec a BVH of width 4, and something in it."""
    if len(geo.agg_kind) != 1 or len(geo.inst_agg) or not len(geo.refs):
        return False
    name, params = parse_spec(scene.root.accel or accel)
    return name == "bvh" and params.get("width", 4) == 4


def stand_in_job(job_class, scene, options: dict):
    """A job (render.RenderJob, given: it imports this module) of `scene` with `options` (its
    keywords) on the stand-in, one pixel in size: its kernel's arguments have the real job's
    types (sizes are not part of a type)."""
    return job_class(scene, builder=StandIn, **dict(options, resolution=1))


def compile_ahead(job_class, scene, options: dict, kernel) -> bool:
    """Compile `kernel`, the renderer's, for a render of `scene` with `options` (the keywords
    of job_class, render.RenderJob) against a stand-in, while a helper process builds the scene
    with the same structures. Does nothing, and returns False, unless the kernel is neither
    compiled in this process nor cached, compiling ahead is enabled and the scene is small
    enough and picklable for the helper to take a copy."""
    if compiled(kernel) or cached(kernel) or not enabled() or is_auto(options["accel"]):
        return False
    if scene.count_primitives() > MAX_HELPER_PRIMITIVES:
        return False
    return beside(("raykernel.engine.flatten", "flatten", (scene, options["accel"], options.get("max_memory"))),
                  lambda: stand_in_job(job_class, scene, options).compile_kernel())

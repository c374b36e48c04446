"""A first render's two compiles side by side: the renderer here, the builder in a helper process.

    with CompileClock(notice=say) as clock:
        went = compile_ahead(scene, options, tile_kernel(shading, aa))   # render() does this first
    job = RenderJob(scene, **options)       # its build and its trace load what compiled

A render's first run compiles two sets of kernels that do not depend on each other: the
builder of its structures (a few seconds) and the renderer (most of the wait). numba compiles
on one thread, one kernel after another, and the renderer needs only the numba *type* of the
built geometry, not the geometry. So when the renderer's kernel is in neither this process nor
the kernel cache, and a second core is free, a helper process (`python -m
raykernel.rendering.ahead FILE`) builds the scene, compiling the builder's kernels into the
shared cache, while this process compiles the renderer against a stand-in: the scene laid out
as a plain list (which no kernel builds), typed as the real build will be (`StandIn`). The
real build then loads the builder's kernels the helper left; if the helper failed, it compiles
them as it would have. The stand-in's type is a forecast: where it misses, the real render
compiles its own kernel too (time lost, not a wrong image); tests hold it on the usual scenes.
RAYKERNEL_COMPILE_AHEAD=0 turns it off.
"""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ..aggregates.registry import parse_spec
from ..aggregates.spec import is_auto
from ..engine.flatten import flatten
from ..geometry.config import cached, compiled

MAX_HELPER_PRIMITIVES = 1_000_000    # above, the helper's copy of the build costs more than it saves
WAIT_POLL = 0.1                      # seconds between looks at the helper: Ctrl-C is answered at once


def enabled() -> bool:
    """Compiling ahead is on (RAYKERNEL_COMPILE_AHEAD is not 0) and a second core is free."""
    if os.environ.get("RAYKERNEL_COMPILE_AHEAD", "1") == "0":
        return False
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return cores > 1


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


def stand_in_job(scene, options: dict):
    """A RenderJob of `scene` with `options` (its keywords) on the stand-in, one pixel in size:
    its kernel's arguments have the real job's types (sizes are not part of a type)."""
    from .render import RenderJob
    return RenderJob(scene, builder=StandIn, **dict(options, resolution=1))


def compile_ahead(scene, options: dict, kernel) -> bool:
    """Compile `kernel`, the renderer's, for a render of `scene` with `options` (RenderJob's
    keywords) against a stand-in, while a helper process builds the scene with the same
    structures; wait for the helper. Does nothing, and returns False, unless the kernel is
    neither compiled in this process nor cached, compiling ahead is enabled and the scene is
    small enough for the helper to copy."""
    if compiled(kernel) or cached(kernel) or not enabled() or is_auto(options["accel"]):
        return False
    if scene.count_primitives() > MAX_HELPER_PRIMITIVES:
        return False
    with tempfile.TemporaryDirectory(prefix="raykernel-ahead-") as folder:
        task = Path(folder) / "build.pickle"
        try:
            task.write_bytes(pickle.dumps((scene, options["accel"], options.get("max_memory"))))
        except (pickle.PicklingError, TypeError, AttributeError):
            return False        # a scene that cannot travel: compiled one after the other, as before
        helper = subprocess.Popen([sys.executable, "-m", __name__, str(task)], stdin=subprocess.DEVNULL,
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=_helper_env())
        try:
            stand_in_job(scene, options).compile_kernel()
            while helper.poll() is None:
                time.sleep(WAIT_POLL)
        finally:
            if helper.poll() is None:
                helper.kill()
                helper.wait()
    return True


def _helper_env() -> dict:
    """This process's environment (the same kernel cache), with this raykernel importable."""
    env = dict(os.environ)
    package_parent = str(Path(__file__).resolve().parents[2])
    env["PYTHONPATH"] = os.pathsep.join(p for p in (package_parent, env.get("PYTHONPATH")) if p)
    return env


def _main(argv) -> None:
    """python -m raykernel.rendering.ahead FILE: build the pickled (scene, accel, max_memory)."""
    scene, accel, max_memory = pickle.loads(Path(argv[0]).read_bytes())
    flatten(scene, accel, max_memory)


if __name__ == "__main__":
    _main(sys.argv[1:])

"""Compile time measured apart from the work, and the first-run check the CLI uses."""

import math
import threading
import time

import numba
import numpy as np
import pytest

import raykernel
from raykernel.geometry.compiletime import CompileClock
from raykernel.rendering.render import first_run


def fresh_kernel():
    @numba.njit
    def f(x):
        return x * 2 + 1
    return f


def test_the_clock_counts_compiles_of_its_own_thread_only():
    mine, theirs = fresh_kernel(), fresh_kernel()
    with CompileClock() as clock:
        other = threading.Thread(target=theirs, args=(1.0,))
        other.start()
        other.join()
        assert clock.seconds == 0.0          # another thread's compile is not ours
        assert mine(2.0) == 5.0
    assert clock.seconds > 0.0
    with CompileClock() as again:
        assert mine(3.0) == 7.0              # compiled already: nothing to count
    assert again.seconds == 0.0


def test_the_clocks_notice_fires_once_for_a_compile_that_lasts():
    said = []
    with CompileClock(notice=lambda: said.append(1), after=0.0) as clock:      # 0: at a compile's start
        fresh_kernel()(1.0)
        fresh_kernel()(2.0)
    assert said == [1] and clock.seconds > 0.0                                  # once per clock
    with CompileClock(notice=lambda: said.append(2), after=3600.0):
        fresh_kernel()(1.0)                  # over long before an hour: nothing said
    compiled = fresh_kernel()
    compiled(1.0)
    with CompileClock(notice=lambda: said.append(3), after=0.0):
        compiled(2.0)                        # no compile at all
    assert said == [1]

    @numba.njit
    def slow(a):                             # a compile that takes well over 10 ms
        return np.sort(a).cumsum().argmax() + np.unique(a).size + np.median(a)
    with CompileClock(notice=lambda: said.append(4), after=0.01):
        slow(np.arange(5.0))
    time.sleep(0.05)
    assert said == [1, 4]                    # the timer, on its own thread


def test_a_compile_notice_is_said_again_for_each_later_compile(capsys):
    from raykernel.geometry.compiletime import compile_notice
    from raykernel.geometry.config import tell_once
    tell_once("test-notice", None)           # the caller said the first one its own way
    for _ in range(3):
        compile_notice("test-notice", "compiling test kernels")()
    assert capsys.readouterr().err.count("compiling test kernels") == 2


LOAD_CHILD = """
import sys, numba
from raykernel.geometry.compiletime import CompileClock
@numba.njit(cache=True)
def f(x):
    return x * 2 + 1
with CompileClock() as clock:
    assert f(2.0) == 5.0
print(clock.seconds, clock.loading)
"""


def test_the_clock_tells_loading_from_the_cache_apart_from_compiling(tmp_path):
    """A cached kernel compiles in the first process and loads in the next: the clock counts
    the first as compile time and the second as loading, never both."""
    import os
    import subprocess
    import sys
    script = tmp_path / "kernel.py"
    script.write_text(LOAD_CHILD)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    runs = [subprocess.run([sys.executable, str(script)], env=env, capture_output=True, text=True, check=True)
            for _ in range(2)]
    (compiled_s, _), (again_s, loaded_s) = (map(float, r.stdout.split()) for r in runs)
    assert compiled_s > 0.0
    assert again_s == 0.0 and loaded_s > 0.0


def test_numbas_typing_set_up_is_timed_once_per_process():
    """typing_setup: numba's first typeof in a fresh process takes time, every later call none."""
    import subprocess
    import sys
    code = ("from raykernel.geometry.compiletime import typing_setup as t\n"
            "print(t(), t())")
    first, again = map(float, subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                                             check=True).stdout.split())
    assert first > 0.0 and again == 0.0


def test_render_reports_parse_and_load_apart_from_the_work():
    """time.parse is the loading of the scene; a scene built in Python has none. Loading kernels
    from the cache is start-up (time.load), in neither time.parse, time.preprocess nor time.trace:
    the reader's own kernel is loaded when a process reads its first NFF text."""
    import subprocess
    import sys
    code = ("import time, raykernel; t0 = time.perf_counter()\n"
            "s = raykernel.load('spd:balls:1'); assert s.parse_seconds > 0\n"
            "assert s.load_seconds > 0 and s.compile_seconds == 0 and raykernel.load('spd:balls:1').load_seconds == 0\n"
            "r = raykernel.render(s, resolution=8); wall = time.perf_counter() - t0\n"
            "print(r.stats['time.parse'], r.stats['time.load'], r.stats['time.compile'], r.stats['time.trace'],"
            " r.stats['time.preprocess'], wall)")
    raykernel.render(raykernel.load("spd:balls:1"), resolution=8)       # compiled and cached, if it was not
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    parse, load, compile_s, trace, preprocess, wall = map(float, out.stdout.split())
    assert parse > 0.0 and load > 0.0 and compile_s == 0.0 and trace > 0.0 and preprocess >= 0.0
    # apart: the parts add up to no more than the whole, measured around the load and the render
    assert parse + load + trace + preprocess <= wall
    scene = raykernel.load("spd:balls:1")
    scene.parse_seconds = 0.0
    built = raykernel.render(scene, resolution=8)
    assert built.stats["time.parse"] == 0.0 and built.stats["time.load"] == 0.0    # loaded in this process already


def test_render_reports_compile_apart_and_first_run_turns_false():
    t0 = time.perf_counter()
    r = raykernel.render(raykernel.load("spd:balls:1"), resolution=8)
    wall = time.perf_counter() - t0
    parts = [r.stats[f"time.{k}"] for k in ("parse", "preprocess", "trace", "compile", "load")]
    assert all(math.isfinite(x) for x in parts) and r.stats["time.trace"] > 0.0
    # compiling and loading kernels are left out of parse, preprocess and trace: together within the whole
    assert min(parts) >= 0.0 and sum(parts) <= wall
    assert not first_run()                   # this checkout's render kernel is in the cache now


def test_a_first_query_that_compiles_says_so_once(tmp_path):
    """On an empty kernel cache a first RayScene query that compiles prints one line on stderr
    for each compile: from_mesh compiles the kernel of a query without surfaces (beside a helper
    that compiles the builder: casting/meshahead.py), the query of every field then its surface
    part. A later process, starting from the cache, prints nothing. Without the helper, the
    query compiles once and the builder's compile says so too."""
    import os
    import subprocess
    import sys
    code = ("import numpy as np; from raykernel import RayScene; s = RayScene.from_mesh(np.eye(3), [(0, 1, 2)]); "
            "s.intersect(np.zeros(3), np.ones(3)); s.intersect(np.zeros(3), np.ones(3))")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    first = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert first.stderr.count("raykernel: compiling the ray-casting kernels") == 2
    assert "building the BVH" not in first.stderr
    again = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert "compiling" not in again.stderr
    alone = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "alone"), RAYKERNEL_COMPILE_AHEAD="0")
    first = subprocess.run([sys.executable, "-c", code], env=alone, capture_output=True, text=True, check=True)
    assert first.stderr.count("raykernel: compiling the ray-casting kernels") == 1
    assert "compiling the mesh builder" in first.stderr


@pytest.mark.slow
def test_each_kind_of_render_that_compiles_says_so(tmp_path):
    """On an empty cache: a render of a one-BVH scene and then one of a nested structure compile
    different specialisations, and each says so; a later process loads both and says nothing."""
    import os
    import subprocess
    import sys
    code = ("import raykernel; s = raykernel.load('spd:balls:1'); raykernel.render(s, resolution=8); "
            "raykernel.render(s, resolution=8, accel='grid')")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))
    first = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert first.stderr.count("raykernel: compiling the renderer's kernels") == 2
    again = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert "compiling" not in again.stderr


@pytest.mark.slow
def test_no_kernel_is_compiled_for_a_literal_argument(tmp_path):
    """numba compiles a kernel once per argument types, and a literal argument (a constant, or
    a counter that starts at a constant) is a type of its own: a call made with `0` where the
    same call elsewhere passes an int64 compiles the callee twice (trace was, for the literal
    0 its counter of eye rays started at: 8 s of a first render). In a fresh process on an
    empty cache (kernels loaded from a cache bring their callees inside them), a render or
    query of each kind compiles no kernel for a literal (every kernel here: no helper compiles the
    builder, rendering/ahead.py)."""
    import os
    import subprocess
    import sys
    code = """
import gc, numpy as np, raykernel
from numba.core import types
from numba.core.registry import CPUDispatcher
scene = raykernel.load("spd:balls:1")
raykernel.render(scene, resolution=24)
raykernel.render(scene, resolution=24, aa="jitter", samples=4)
raykernel.render(scene, resolution=24, accel="grid")
raykernel.RayScene(scene).intersect(np.zeros((1, 3)), np.ones((1, 3)))
raykernel.RayScene.from_mesh(np.eye(3), [(0, 1, 2)]).intersect(np.zeros((1, 3)), np.ones((1, 3)))
kernels = [f for f in gc.get_objects() if isinstance(f, CPUDispatcher) and f.py_func.__module__.startswith("raykernel")]
for f in kernels:
    for sig in f.overloads:
        literal = [str(a) for a in sig if isinstance(a, types.Literal)]
        if literal:
            print(f.py_func.__module__, f.py_func.__name__, literal)
print("checked", sum(len(f.overloads) for f in kernels))
"""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path), RAYKERNEL_COMPILE_AHEAD="0")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    *literal, checked = out.strip().splitlines()
    assert int(checked.split()[1]) > 30          # the kernels of all four calls, callees included
    assert literal == []

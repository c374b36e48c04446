"""Ctrl-C: a render, a ray query or a mesh build stops within about a second of SIGINT, from Python and from the
command line, leaves no file behind, and the next call in the same process works."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="SIGINT to a child process is POSIX")

# the child: warm up (compile or load the kernels), then the long call with SIGINT sent to
# itself one second in, then a small call again; it prints how long the interrupt took to answer
CHILD = textwrap.dedent("""
    import os, signal, sys, threading, time
    import numpy as np
    import raykernel
    from raykernel.scene.loading import load
    threads = int(sys.argv[2])
    if sys.argv[1] == "render":
        scene = load("spd:balls:3")
        small = lambda: raykernel.render(scene, resolution=8, threads=threads).stats["rays.eye"]
        long = lambda: raykernel.render(scene, resolution=4096, threads=threads)
    elif sys.argv[1] == "build":
        # a height field of 1.28M triangles, built again and again: SIGINT meets some phase of a build
        k = 801
        x, y = np.meshgrid(np.linspace(0, 1, k), np.linspace(0, 1, k))
        v = np.c_[x.ravel(), y.ravel(), 0.1 * np.sin(9 * x.ravel()) * np.cos(7 * y.ravel())]
        q = (np.arange(k - 1)[:, None] * k + np.arange(k - 1)[None]).ravel()
        f = np.concatenate([np.c_[q, q + 1, q + k], np.c_[q + 1, q + k + 1, q + k]])
        ray = np.array([[0.5, 0.5, 1.0]]), np.array([[0.0, 0.0, -1.0]])
        small = lambda: int(raykernel.RayScene.from_mesh(v[:4 * k], f[:100]).intersect(*ray).prim_id[0] >= -1)
        long = lambda: [raykernel.RayScene.from_mesh(v, f, threads=threads) for _ in range(100)]
    else:
        rays = raykernel.RayScene(load("spd:balls:4"), accel="list")
        rng = np.random.default_rng(1)
        o, d = rng.normal(size=(4_000_000, 3)) * 0.3, rng.normal(size=(4_000_000, 3))
        small = lambda: int(np.isfinite(rays.intersect(o[:64], d[:64], threads=threads).t).sum())
        long = lambda: rays.intersect(o, d, threads=threads)
    first = small()
    sent = []
    def interrupt():
        sent.append(time.perf_counter())
        os.kill(os.getpid(), signal.SIGINT)
    threading.Timer(1.0, interrupt).start()
    try:
        long()
        print("finished")
    except KeyboardInterrupt:
        print(f"interrupted {time.perf_counter() - sent[0]:.3f}")
    print("again", small() == first, flush=True)
""")


@pytest.mark.parametrize("what,threads", [("render", 1), ("render", 2), ("query", 1), ("query", 2), ("build", 1),
                                          ("build", 2)])
def test_python_call_stops_within_a_second_and_the_next_call_works(what, threads):
    out = subprocess.run([sys.executable, "-c", CHILD, what, str(threads)], capture_output=True, text=True,
                         timeout=900)
    lines = out.stdout.split()
    assert "interrupted" in lines, out.stdout + out.stderr
    waited = float(lines[lines.index("interrupted") + 1])
    assert waited < 2.0
    assert lines[-2:] == ["again", "True"], out.stdout + out.stderr
    assert "Traceback" not in out.stderr


def test_command_line_render_exits_130_and_leaves_no_file(tmp_path):
    cli = [sys.executable, "-m", "raykernel"]
    warm = subprocess.run(cli + ["render", "spd:balls:3", "--resolution", "8", "-o", str(tmp_path / "warm.png")],
                          capture_output=True, text=True, timeout=900)
    assert warm.returncode == 0, warm.stderr
    out = tmp_path / "big.png"
    child = subprocess.Popen(cli + ["render", "spd:balls:3", "--resolution", "4096", "-o", str(out)],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(4.0)
    assert child.poll() is None, "the render ended before it could be interrupted"
    sent = time.perf_counter()
    child.send_signal(signal.SIGINT)
    stdout, stderr = child.communicate(timeout=60)
    waited = time.perf_counter() - sent
    assert child.returncode == 130, stderr
    assert waited < 2.0
    assert "interrupted" in stderr and "Traceback" not in stderr
    assert sorted(p.name for p in Path(tmp_path).iterdir()) == ["warm.png"]


def test_main_module_runs():
    # `python -m raykernel` is what the test above runs
    out = subprocess.run([sys.executable, "-m", "raykernel", "--help"], capture_output=True, text=True, timeout=300,
                         env=dict(os.environ))
    assert out.returncode == 0 and "render" in out.stdout

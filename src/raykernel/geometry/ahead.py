"""Two first compiles side by side: one here, the builder's in a helper process.

    if enabled():
        went = beside(("raykernel.engine.flatten", "flatten", (scene, accel, max_memory)), compile_here)

numba compiles on one thread, one kernel after another. A first render or ray cast needs two
sets of kernels that do not depend on each other: a builder's (a few seconds) and the
renderer's or the query's (most of the wait), which needs only the numba *types* of what the
build makes. So a helper process runs the build, its kernels compiling into the shared kernel
cache, while this process compiles the other set against a stand-in typed as the build's
result will be (rendering/ahead.py, casting/meshahead.py); the real build here then loads
what the helper compiled, or, if the helper failed, compiles it as it would have. The helper
is `python -m raykernel.geometry.ahead FILE`, FILE the pickled (module, function, arguments)
it calls. RAYKERNEL_COMPILE_AHEAD=0 turns it off, as does a single core.
"""

from __future__ import annotations

import importlib
import os
import pickle
import subprocess
import sys
import tempfile
import time
from pathlib import Path

WAIT_POLL = 0.1         # seconds between looks at the helper: Ctrl-C is answered at once


def enabled() -> bool:
    """Compiling ahead is on (RAYKERNEL_COMPILE_AHEAD is not 0) and a second core is free."""
    if os.environ.get("RAYKERNEL_COMPILE_AHEAD", "1") == "0":
        return False
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return cores > 1


def beside(call: tuple, compile_here) -> bool:
    """Run compile_here() in this process while a helper process calls `call` (module name,
    function name, arguments); then wait for the helper. False, and nothing run, where the
    arguments cannot be pickled. The helper is ended if compile_here raises (Ctrl-C too)."""
    with tempfile.TemporaryDirectory(prefix="raykernel-ahead-") as folder:
        task = Path(folder) / "call.pickle"
        try:
            task.write_bytes(pickle.dumps(call))
        except (pickle.PicklingError, TypeError, AttributeError):
            return False
        helper = subprocess.Popen([sys.executable, "-m", __name__, str(task)], stdin=subprocess.DEVNULL,
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=_helper_env())
        try:
            compile_here()
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
    """python -m raykernel.geometry.ahead FILE: call the pickled (module, function, arguments)."""
    module, function, args = pickle.loads(Path(argv[0]).read_bytes())
    getattr(importlib.import_module(module), function)(*args)


if __name__ == "__main__":
    _main(sys.argv[1:])

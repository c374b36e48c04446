"""A docstring edit recompiles nothing: every kernel module edited in turn, the next run's compile time.

    .venv/bin/python bench/cache_edits.py [--no-write]

Copies the package into a temporary folder with a kernel cache of its own, warms the cache with
a probe (renders with every kind of structure, a CSG scene, Hall shading with antialiasing, ray
casting against a mesh), then, for every module that defines a kernel, one at a time: changes
every docstring of the module, adds a comment after every `def` and blank lines, runs the probe
again in a fresh process, and puts the module back. Each row gives the probe's time.compile
(seconds compiling kernels: 0 when every kernel loads from the cache) and time.load. A last
row changes a constant the kernels freeze (a counter column) to show the cache is not blind:
that run compiles. Writes the `cache_edits` section of BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import ast
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from datetime import date
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _report import DETAILS, ROOT, machine, replace_section  # noqa: E402

PROBE = r"""
import json
import numpy as np
import raykernel
total = {"compile": 0.0, "load": 0.0}
def add(stats):
    total["compile"] += stats["time.compile"]
    total["load"] += stats["time.load"]
from raykernel.aggregates.registry import KINDS
scene = raykernel.load("spd:balls:1")
for accel in ["bvh(width=2)"] + [name for name, kind in KINDS.items() if not kind.operands]:
    add(raykernel.render(scene, accel=accel, resolution=8).stats)
add(raykernel.render(raykernel.load(CSG), resolution=8).stats)
add(raykernel.render(scene, resolution=8, shading="hall", aa="jitter", samples=4, tricks="all").stats)
mesh = raykernel.load("spd:tetra:2")
rs = raykernel.RayScene(mesh)
rs.intersect(np.zeros((4, 3)), np.ones((4, 3)))
add({"time.compile": rs.last_stats.get("time.compile", 0.0), "time.load": rs.last_stats.get("time.load", 0.0)})
print(json.dumps(total))
"""


def retext(source: str) -> str:
    """The same code as other text: every docstring changed, a comment after every def, blank
    lines before it."""
    lines = source.splitlines(keepends=True)
    for node in ast.walk(ast.parse(source)):
        body = getattr(node, "body", None)
        if (isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef)) and body and isinstance(body[0], ast.Expr)
                and isinstance(body[0].value, ast.Constant) and isinstance(body[0].value.value, str)):
            doc = body[0].value
            line = lines[doc.lineno - 1]
            quote = doc.col_offset + (3 if line[doc.col_offset:doc.col_offset + 3] in ('"""', "'''") else 1)
            lines[doc.lineno - 1] = line[:quote] + "Edited. " + line[quote:]
    return re.sub(r"^(\s*def [^\n]*\):)$", r"\n\1  # a comment", "".join(lines), flags=re.M) + "\n# the end\n"


def probe(src: Path, cache: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(src), NUMBA_CACHE_DIR=str(cache))
    code = f"CSG = {str(ROOT / 'examples' / 'csg.json')!r}\n" + PROBE       # a scene of CSG nodes
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    if out.returncode:
        sys.exit(out.stderr[-3000:])
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / "src"
        shutil.copytree(ROOT / "src" / "raykernel", src / "raykernel",
                        ignore=shutil.ignore_patterns("__pycache__"))
        cache = Path(tmp) / "cache"
        t0 = time.perf_counter()
        warm = probe(src, cache)
        print(f"warm-up: compile {warm['compile']:.1f} s ({time.perf_counter() - t0:.0f} s)", flush=True)
        package = src / "raykernel"
        modules = sorted(p for p in package.rglob("*.py") if "@njit" in p.read_text())
        rows = []
        for path in modules:
            text = path.read_text()
            path.write_text(retext(text))
            got = probe(src, cache)
            path.write_text(text)
            rows.append((path.relative_to(package).as_posix(), got))
            print(f"{rows[-1][0]}: compile {got['compile']:.2f} s, load {got['load']:.2f} s", flush=True)
        counters = package / "geometry" / "counters.py"
        text = counters.read_text()
        counters.write_text(text.replace("RAYS_EYE, RAYS_EYE_HIT = 0, 1", "RAYS_EYE, RAYS_EYE_HIT = 1, 0", 1))
        changed = probe(src, cache)
        counters.write_text(text)
        print(f"a counter column swapped: compile {changed['compile']:.1f} s", flush=True)
    lines = ["## A docstring edit recompiles nothing",
             "",
             f"`python bench/cache_edits.py` ({date.today().isoformat()}): the package copied with a kernel cache "
             "of its own, warmed by a "
             "probe (renders with every kind of structure, a CSG scene, Hall shading with antialiasing and "
             "tricks, ray casting on a mesh); then every module that defines a kernel, one at a time, gets "
             "every docstring changed, a comment after every `def` and blank lines, and the probe runs again "
             "in a fresh process. `time.compile` is what that run spent compiling (0: every kernel loaded "
             "from the cache).",
             "", f"Machine: {machine()}.", "",
             *summary([f"{got['compile']:.2f}" for _, got in rows], f"{warm['compile']:.1f}",
                      f"{changed['compile']:.1f}"),
             "", DETAILS, "",
             f"Warm-up (an empty cache): {warm['compile']:.1f} s compiling.", "",
             "| module edited | time.compile s | time.load s |", "|---|---:|---:|"]
    lines += [f"| `{name}` | {got['compile']:.2f} | {got['load']:.2f} |" for name, got in rows]
    lines += ["", f"Two counter columns swapped in geometry/counters.py (a constant every kernel freezes): the "
                  f"next run compiled for {changed['compile']:.1f} s, as it must."]
    if not args.no_write:
        replace_section("cache_edits", "\n".join(lines))
    return 0


def summary(compiles: list[str], warm: str, changed: str) -> list[str]:
    """The summary's table, from the full table's time.compile cells as printed and the warm-up's and the
    last run's compile seconds as printed (so a migration of an old section gets the same)."""
    return ["| modules edited | runs after an edit that compiled | most seconds compiling after an edit | "
            "warm-up compile s | a frozen constant changed: compile s |", "|---:|---:|---:|---:|---:|",
            f"| {len(compiles)} | {sum(c != '0.00' for c in compiles)} | "
            f"{max(compiles, key=float, default='-')} | {warm} | {changed} |"]


if __name__ == "__main__":
    sys.exit(main())

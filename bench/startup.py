"""Start-up: how long each entry point takes on an empty kernel cache (cold) and from the cache (warm).

    .venv/bin/python bench/startup.py [--label after] [--only render-balls] [--against 01dc804]

Each entry point runs in a fresh process twice: first with an empty
NUMBA_CACHE_DIR (everything compiles), then again with the cache the first
run left (everything loads). numba's compile events (`numba:compile`) give
the seconds spent compiling, per top-level function. Writes the `startup`
section of BENCHMARKS.md (the latest run's rows) and its page,
docs/benchmarks/startup.md, with the rows of every label kept in
bench/startup.json, so a table measured before a change and one after sit
side by side. With --against REV each entry point runs for REV (checked out
into a temporary git worktree) and then for this tree, back to back, so that
both rows meet the same machine load: a machine's speed drifts within minutes.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shlex
import subprocess
import sys
import tempfile
from datetime import date
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _report import BENCHMARKS, DETAILS, ROOT, machine, replace_section, subtable  # noqa: E402

ENTRY_POINTS = {
    "import": "import raykernel",
    "cli-render-tetra": "import tempfile, os; from raykernel.cli import main\n"
                        "with tempfile.TemporaryDirectory() as d:\n"
                        "    assert main(['render', 'spd:tetra', '--resolution', '64', '-o', os.path.join(d, 't.png')]) == 0",
    "render-balls": "from raykernel.scene.loading import load; from raykernel.rendering.render import render\n"
                    "render(load('spd:balls'), resolution=32)",
    "render-heckbert": "from raykernel.scene.loading import load; from raykernel.rendering.render import render\n"
                       "render(load('example:heckbert'), resolution=32)",
    "render-heckbert-shading": "from raykernel.scene.loading import load; from raykernel.rendering.render import render\n"
                               "render(load('example:heckbert'), resolution=32, shading='heckbert')",
    "rayscene-mesh": "import numpy as np, raykernel\n"
                     "v = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0]]); f = np.array([[0, 1, 2]])\n"
                     "s = raykernel.RayScene.from_mesh(v, f)\n"
                     "s.intersect(np.array([[0.2, 0.2, -1.]]), np.array([[0., 0, 1]]))",
    "rayscene-mesh-ids": "import numpy as np, raykernel\n"
                         "v = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0]]); f = np.array([[0, 1, 2]])\n"
                         "s = raykernel.RayScene.from_mesh(v, f)\n"
                         "s.intersect(np.array([[0.2, 0.2, -1.]]), np.array([[0., 0, 1]]), fields=('t', 'prim_id'))",
    "rayscene-scene": "import numpy as np, raykernel\nfrom raykernel.scene.loading import load\n"
                      "s = raykernel.RayScene(load('spd:balls'))\n"
                      "s.intersect(np.array([[0., 0, 5]]), np.array([[0., 0, -1]]))",
}

# entry points whose process must not import numba before their code does
PLAIN = {"import"}
PLAIN_CHILD = """
import time, json
t0 = time.perf_counter()
{code}
print(json.dumps({{"total": time.perf_counter() - t0, "compile": {{}}, "inclusive": {{}}}}))
"""

CHILD = """
import time, json, sys
t0 = time.perf_counter()
from numba.core import event
rec = event.RecordingListener()
event.register("numba:compile", rec)
{code}
total = time.perf_counter() - t0
compile_s = {{}}
inclusive = {{}}
stack = []
for ts, ev in rec.buffer:
    name = ev.data["dispatcher"].py_func.__qualname__ if ev.data and "dispatcher" in ev.data else "?"
    mod = ev.data["dispatcher"].py_func.__module__ if ev.data and "dispatcher" in ev.data else "?"
    if ev.is_start:
        stack.append((ts, mod + "." + name))
    else:
        start, key = stack.pop()
        inclusive[key] = inclusive.get(key, 0.0) + ts - start
        if not stack:                       # top-level compiles only: nested ones are inside them
            compile_s[key] = compile_s.get(key, 0.0) + ts - start
print(json.dumps({{"total": total, "compile": compile_s, "inclusive": inclusive}}))
"""


def run_child(name: str, cache: str, src: str | None = None) -> dict:
    env = dict(os.environ, NUMBA_CACHE_DIR=cache)
    if src:
        env["PYTHONPATH"] = src + os.pathsep + env.get("PYTHONPATH", "")
    child = PLAIN_CHILD if name in PLAIN else CHILD
    out = subprocess.run([sys.executable, "-c", child.format(code=ENTRY_POINTS[name])], env=env, capture_output=True,
                         text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


COLUMNS = ["label", "entry point", "cold total s", "cold compile s", "warm total s"]    # of the summary's table


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--label", default="now", help="row label, e.g. before or after")
    ap.add_argument("--only", action="append", help="entry points to run (default: all)")
    ap.add_argument("--no-write", action="store_true", help="print, do not write BENCHMARKS.md")
    ap.add_argument("--table-only", action="store_true", help="rewrite the section from bench/startup.json, run nothing")
    ap.add_argument("--against", metavar="REV", help="also run revision REV, entry point by entry point")
    args = ap.parse_args()
    rows = []
    sides = [(args.label, None)]
    with contextlib.ExitStack() as stack:
        if args.against:
            tree = stack.enter_context(tempfile.TemporaryDirectory())
            subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", tree, args.against], check=True,
                           capture_output=True)
            stack.callback(subprocess.run, ["git", "-C", str(ROOT), "worktree", "remove", "--force", tree],
                           capture_output=True)
            sides.insert(0, (f"{args.against} (same run as {args.label})", str(Path(tree) / "src")))
        for name in [] if args.table_only else (args.only or ENTRY_POINTS):
            for label, src in sides:
                with tempfile.TemporaryDirectory() as cache:
                    cold = run_child(name, cache, src)
                    warm = run_child(name, cache, src)
                top = sorted(cold["inclusive"].items(), key=lambda kv: -kv[1])[:4]
                row = dict(label=label, entry=name, cold=cold["total"], cold_compile=sum(cold["compile"].values()),
                           warm=warm["total"], warm_compile=sum(warm["compile"].values()),
                           top=", ".join(f"{k.split('.')[-1]} {v:.1f}" for k, v in top))
                rows.append(row)
                print(json.dumps(row), flush=True)
    if args.no_write:
        return 0
    store = BENCHMARKS.with_name("bench") / "startup.json"
    old = json.loads(store.read_text()) if store.exists() else {}
    old.setdefault("rows", [])
    fresh = {(r["label"], r["entry"]) for r in rows}
    old["rows"] = [r for r in old["rows"] if (r["label"], r["entry"]) not in fresh] + rows
    for label in {r["label"] for r in rows}:
        old.setdefault("machines", {})[label] = machine()
    if rows:        # the latest run: its labels (REV's first), command and date, the summary's rows
        old["latest"] = dict(labels=[label for label, _ in sides], date=date.today().isoformat(),
                             command=shlex.join([".venv/bin/python", "bench/startup.py"] + sys.argv[1:]))
    store.write_text(json.dumps(old, indent=1) + "\n")
    latest = old.get("latest") or dict(labels=[], date="", command=".venv/bin/python bench/startup.py --label LABEL")
    here = old.get("machines", {}).get(latest["labels"][-1] if latest["labels"] else "", "not recorded")
    table = ["| label | entry point | cold total s | cold compile s | warm total s | warm compile s | "
             "largest compiles (s) |",
             "|---|---|---|---|---|---|---|"]
    for r in old["rows"]:
        table.append(f"| {r['label']} | {r['entry']} | {r['cold']:.2f} | {r['cold_compile']:.1f} | {r['warm']:.2f} | "
                     f"{r['warm_compile']:.2f} | {r['top']} |")
    lines = ["## Start-up: compile time, cold and warm",
             "",
             f"`{latest['command']}` ({latest['date']}). Each entry point runs in a fresh process on an "
             "empty numba cache (cold), then again on the cache it left (warm). Seconds of the whole process "
             "after interpreter start; `compile` is the time inside numba's compile events in that process (the "
             "full table also names the functions whose compiles took longest, callees included); where a first "
             "render or mesh query compiles its builder in a helper process beside it (geometry/ahead.py), that "
             "compile shows in the total only. Targets: "
             "`import raykernel` at most 0.3 s; the command `raykernel render spd:tetra --resolution 64` "
             "(cli-render-tetra) at most 1.0 s warm; render-balls cold compile at most 10 s, a mesh query's "
             "(rayscene-mesh) at most 4 s.",
             "",
             f"Machine: {here}.",
             "",
             "The latest run, both sides entry point by entry point (every run kept in bench/startup.json is in "
             "the full table):",
             "",
             *subtable(table, COLUMNS, {"label": latest["labels"]}),
             "",
             DETAILS,
             "",
             "Every run kept, by label (each label's machine below the table):",
             "",
             *table]
    lines += [""] + [f"- {label}: {m}" for label, m in old["machines"].items()]
    replace_section("startup", "\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

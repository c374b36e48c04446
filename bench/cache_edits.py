"""What an edit recompiles: for an edit in each module, how many kernels get a new cache stamp.

    .venv/bin/python bench/cache_edits.py [--no-write]

Copies the package into a temporary folder and lists the stamp of every cached kernel
(geometry/cachekey.py: a kernel recompiles exactly when its stamp changes, since numba's own
key, the signature, the CPU and the function's bytecode, does not change with an edit
elsewhere). Then, for every module, one at a time, in a fresh process each:

* a text edit: every docstring changed, a comment after every `def` and blank lines (retext);
  no kernel may restamp;
* a code edit: a statement added to every function of the module (code_edit); the kernels that
  restamp are those that call or inline one of its functions, or are its own.

Named edits follow, each the kind of change a developer makes: an error message, a builder,
a counter column that every counting kernel freezes. Writes the `cache_edits` section of
BENCHMARKS.md.
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
from datetime import date
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _report import DETAILS, ROOT, machine, replace_section  # noqa: E402

PROBE = "import json; from raykernel.geometry import cachekey; print(json.dumps(cachekey.all_stamps()))"
# the walks: each kind's step and the drivers that run them (what every ray and query compiles in)
WALK_MODULES = ("raykernel.engine.traverse.", "raykernel.aggregates.widewalk.")

# (what a developer changes, module, text before, text after)
NAMED_EDITS = [
    ("an error message", "errors.py", "class SceneError(RayKernelError):",
     "class SceneError(RayKernelError):\n    EDITED = 'a message'"),
    ("the BVH's builder (its SAH sweep)", "aggregates/bvhbuild.py", None, "_best_split"),
    ("the NFF reader", "scene/nff.py", None, "parse_nff"),
    ("a counter column every counting kernel freezes", "geometry/counters.py",
     "RAYS_EYE, RAYS_EYE_HIT = 0, 1", "RAYS_EYE, RAYS_EYE_HIT = 1, 0"),
]


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


def code_edit(source: str, only: str | None = None) -> str:
    """The source with `_edited = 0` as the first statement (after the docstring) of every function,
    or only of the function named `only`."""
    lines = source.splitlines(keepends=True)
    spots = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and (only is None or node.name == only):
            body = node.body
            first = body[1] if (len(body) > 1 and isinstance(body[0], ast.Expr)
                                and isinstance(body[0].value, ast.Constant)) else body[0]
            if first.lineno > node.lineno:          # not a one-line def
                spots.append((first.lineno, first.col_offset))
    for lineno, col in sorted(spots, reverse=True):
        lines.insert(lineno - 1, " " * col + "_edited = 0\n")
    return "".join(lines)


def stamps(src: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(src))
    out = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, cwd=src)
    if out.returncode:
        sys.exit(out.stderr[-3000:])
    return json.loads(out.stdout.strip().splitlines()[-1])


def restamped(src: Path, path: Path, new_text: str, before: dict) -> list[str]:
    """The kernels whose stamp changes when `path` reads `new_text` (put back after)."""
    text = path.read_text()
    path.write_text(new_text)
    try:
        after = stamps(src)
    finally:
        path.write_text(text)
    if set(after) != set(before):
        sys.exit(f"{path}: the edit changed which kernels exist")
    return sorted(k for k in before if after[k] != before[k])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / "src"
        shutil.copytree(ROOT / "src" / "raykernel", src / "raykernel", ignore=shutil.ignore_patterns("__pycache__"))
        package = src / "raykernel"
        before = stamps(src)
        total = len(before)
        walks = {k for k in before if k.endswith(".walk_step") or k.startswith(WALK_MODULES)}
        print(f"{total} cached kernels", flush=True)
        rows = []
        for path in sorted(package.rglob("*.py")):
            text = path.read_text()
            name = path.relative_to(package).as_posix()
            if not any(isinstance(n, ast.FunctionDef) for n in ast.walk(ast.parse(text))):
                continue
            by_text = restamped(src, path, retext(text), before)
            by_code = restamped(src, path, code_edit(text), before)
            own = sum(k.startswith("raykernel." + name[:-3].replace("/", ".") + ".") for k in before)
            rows.append((name, own, len(by_code), len(by_text)))
            print(f"{name}: {own} own kernels; a code edit restamps {len(by_code)}, a text edit {len(by_text)}",
                  flush=True)
        named = []
        for what, name, old, new in NAMED_EDITS:
            path = package / name
            text = path.read_text()
            edited = code_edit(text, only=new) if old is None else text.replace(old, new, 1)
            if edited == text:
                sys.exit(f"{name}: the edit for {what!r} found nothing to change")
            got = restamped(src, path, edited, before)
            named.append((what, name, len(got), len(set(got) & walks)))
            print(f"{what}: {len(got)} kernels restamped, {named[-1][3]} of them walks", flush=True)
    lines = ["## What an edit recompiles",
             "",
             f"`python bench/cache_edits.py` ({date.today().isoformat()}): the package copied, the cache stamp of "
             f"every one of its {total} cached kernels listed, then each module edited in turn, in a fresh "
             "process each. A kernel recompiles exactly when its stamp changes (geometry/cachekey.py: its own "
             "code and the code and constants it calls). A text edit changes every docstring and adds comments "
             "and blank lines; a code edit adds a statement to every function of the module.",
             "", f"Machine: {machine()}.", "",
             "| edit | module | kernels recompiled | of them walks |", "|---|---|---:|---:|"]
    lines += [f"| {what} | `{name}` | {n} of {total} | {w} of {len(walks)} |" for what, name, n, w in named]
    lines += ["", f"Text edits in {len(rows)} modules: {sum(r[3] for r in rows)} kernels recompiled in all.",
              "", DETAILS, "",
              "| module | its own kernels | a code edit to every function: kernels recompiled | a text edit |",
              "|---|---:|---:|---:|"]
    lines += [f"| `{name}` | {own} | {code} | {text} |" for name, own, code, text in rows]
    if not args.no_write:
        replace_section("cache_edits", "\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())

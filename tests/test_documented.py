"""Every command and Python block the README and the documentation show runs, on a small input.

Collected from README.md and docs/ (getting started, the guide, the newsletter page, every page
but the generated benchmark pages and the code fragments of adding-a-kind.md): each line of a
code block that starts with `raykernel ` (continued over `\\` line ends), and each ```python
block. A command runs through the command line's main() in a folder holding the files the docs
name (model.obj, scene.nff, bunny.ply, rays.npz, examples/orbit.json), made smaller by the rules of SMALL
(size factors, resolutions, frame counts, annealing seconds); a Python block runs with the names
it leaves to the reader (vertices, faces, origins, directions, points, batches, placements)
bound to a small mesh and rays; rays.npz holds rays for the cast commands. Each fails on an exception, a
non-zero status, or a warning that is not raykernel's own. A command that serves until stopped
(SERVERS: `raykernel explore`) runs as a process on a free port: it passes when it prints its
address on a line of its own and that page answers.
"""

from __future__ import annotations

import re
import shlex
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

from raykernel.cli import main

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
SKIPPED_PAGES = {"docs/adding-a-kind.md"}       # fragments of a kind's module, with `...` for the rest
SKIPPED_FOLDERS = ("docs/benchmarks/", "docs/_build/", "docs/auto_examples/")

# (pattern, replacement): what makes a documented command or block small, in this order
SMALL = [
    (r"\bspd:(\w+)\b(?::\d+)?(?!:)", r"spd:\1:1"),
    (r"(raykernel spd \w+ --size )\d+", r"\g<1>1"),
    (r"(--resolution |resolution=)\d+", r"\g<1>12"),
    (r"(--frames |frames=)\d+", r"\g<1>6"),
    (r"--fps \d+", "--fps 2"),
    (r"seconds=\d+", "seconds=1"),
    (r"(--param \w+)=([^ ,]+),([^ ,]+)\S*", r"\1=\2,\3"),
    (r"--dask (local:\d+|tcp://\S+)", "--dask local:1"),
    (r" \.\.\. ", " "),
    (r"--pixel \d+ \d+", "--pixel 5 5"),
    (r"--time 0 5400", "--time 0 60"),
    (r"(raykernel calibrate)", r"\1 --resolutions 8 16 --repeats 1"),
]
RENDERING = {"render", "compare", "explain", "animate", "anneal", "sweep", "structure", "explore"}
SERVERS = {"explore"}       # serve until stopped: started as a process, its address read and fetched, then stopped


def _pages():
    for page in PAGES:
        name = page.relative_to(ROOT).as_posix()
        if name not in SKIPPED_PAGES and not name.startswith(SKIPPED_FOLDERS):
            yield name, page.read_text(encoding="utf-8")


def _blocks(text: str):
    """(language, body) of every fenced block, and ("", body) of every indented one."""
    for m in re.finditer(r"^```(\w*)[^\n]*\n(.*?)^```", text, re.S | re.M):
        yield m.group(1), m.group(2)
    for m in re.finditer(r"(?:^\n)((?:(?:    |\t)[^\n]*\n)+)", text, re.M):
        yield "", "\n".join(line[4:] for line in m.group(1).splitlines()) + "\n"


def documented_commands() -> list[tuple[str, str]]:
    found = {}
    for name, text in _pages():
        for lang, body in _blocks(text):
            if lang not in ("", "bash", "sh", "shell", "console", "text"):
                continue
            for line in body.replace("\\\n", " ").splitlines():
                line = re.sub(r"^\$ ", "", line.strip())
                if line.startswith("raykernel "):
                    found.setdefault(re.sub(r"\s+#.*$", "", line).strip(), name)
    return sorted((page, command) for command, page in found.items())


def documented_blocks() -> list[tuple[str, list[str]]]:
    """(page, its Python blocks in order): a page's blocks build on each other."""
    pages = [(name, [body for lang, body in _blocks(text) if lang in ("python", "py")]) for name, text in _pages()]
    return [(name, blocks) for name, blocks in pages if blocks]


def small(text: str) -> str:
    for pattern, replacement in SMALL:
        text = re.sub(pattern, replacement, text)
    return text


def _argv(command: str) -> list[str]:
    argv = shlex.split(small(command))[1:]
    if argv[0] in RENDERING and "--resolution" not in argv and (argv[0] != "structure" or "--use" in argv):
        argv += ["--resolution", "12"]
    return argv


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """A folder with the files the documentation names."""
    import trimesh
    here = tmp_path_factory.mktemp("documented")
    shutil.copytree(ROOT / "examples", here / "examples", ignore=shutil.ignore_patterns("gallery"))
    mesh = trimesh.creation.icosphere(subdivisions=2)
    for name in ("bunny.ply", "bunny.obj", "model.obj"):
        mesh.export(here / name)
    assert main(["spd", "tetra", "--size", "1", "-o", str(here / "scene.nff")]) == 0
    rng = np.random.default_rng(5)      # the rays the cast commands read (a Python block shows writing them)
    origins = rng.uniform(-3, 3, (300, 3))
    np.savez(here / "rays.npz", origins=origins, directions=-origins)
    return here


def _strict(run):
    """run() with every warning recorded: those not of raykernel's own categories fail."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = run()
    foreign = [f"{w.category.__name__}: {w.message} ({w.filename}:{w.lineno})" for w in caught
               if not w.category.__module__.startswith("raykernel")]
    assert not foreign, foreign
    return result


def test_the_docs_show_commands_and_blocks_to_run():
    commands, blocks = documented_commands(), documented_blocks()
    assert len(commands) >= 30 and sum(len(b) for _, b in blocks) >= 10
    shown = {command.split()[1] for _, command in commands}
    assert {"render", "compare", "accels", "animate", "explain", "structure", "sweep", "anneal", "spd"} <= shown
    assert small("raykernel render spd:teapot:12 --resolution 512") == "raykernel render spd:teapot:1 --resolution 12"


def _serves(argv: list[str], folder) -> None:
    """Run a server command as a process on a free port, fetch the address it prints, stop it."""
    import subprocess
    import sys
    import urllib.request
    if "--port" in argv:
        argv[argv.index("--port") + 1] = "0"
    else:
        argv += ["--port", "0"]
    proc = subprocess.Popen([sys.executable, "-m", "raykernel", *argv], cwd=folder, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        address = None
        for line in proc.stdout:
            if re.fullmatch(r"https?://\S+", line.strip()):
                address = line.strip()
                break
        assert address, f"{argv}: no address printed; {proc.stderr.read()[-2000:] if proc.poll() is not None else ''}"
        with urllib.request.urlopen(address) as page:
            assert page.status == 200
    finally:
        proc.terminate()
        proc.communicate()


@pytest.mark.parametrize("page, command", documented_commands())
def test_documented_command_runs(folder, monkeypatch, capsys, page, command):
    monkeypatch.chdir(folder)
    if command.split()[1] in SERVERS:
        _serves(_argv(command), folder)
        return
    status = _strict(lambda: main(_argv(command)))
    out = capsys.readouterr()
    assert status == 0, f"{page}: {command}\n{out.err[-2000:]}"


@pytest.mark.parametrize("page, blocks", documented_blocks())
def test_documented_python_blocks_run(folder, monkeypatch, page, blocks):
    import trimesh
    monkeypatch.chdir(folder)
    mesh = trimesh.creation.icosphere(subdivisions=2)
    rng = np.random.default_rng(3)
    origins = rng.uniform(-3, 3, (64, 3))
    directions = -origins + rng.normal(0, 0.2, (64, 3))
    names = dict(vertices=np.asarray(mesh.vertices), faces=np.asarray(mesh.faces), origins=origins,
                 directions=directions, points=rng.uniform(-1.5, 1.5, (32, 3)),
                 batches=[(origins + k, directions) for k in range(3)],
                 placements=[np.eye(4), np.diag([2.0, 2.0, 2.0, 1.0])])
    for block in blocks:
        _strict(lambda: exec(compile(small(block), f"<{page}>", "exec"), names))


def documented_accels() -> list[str]:
    """Every `--accel` value the pages show (placeholders such as SPEC left out), and auto."""
    found = {"auto"}
    for _, text in _pages():
        for m in re.finditer(r"--accel[ =](\"[^\"]+\"|'[^']+'|[^\s`]+)", text):
            value = m.group(1).strip("\"'")
            if not value.isupper():
                found.add(value)
    return sorted(found)


@pytest.mark.parametrize("accel", documented_accels())
def test_render_takes_every_documented_accel_form(tmp_path, capsys, accel):
    assert {"auto", "bvh", "grid", "octree"} <= set(documented_accels())
    out = tmp_path / "a.png"
    status = _strict(lambda: main(["render", "spd:tetra:1", "--accel", small(accel), "--resolution", "8",
                                   "-o", str(out)]))
    assert status == 0, capsys.readouterr().err[-2000:]
    assert out.stat().st_size > 0


@pytest.mark.parametrize("target", [[], ["all"], ["render"], ["cast"]])
def test_warmup_runs_every_target(capsys, target):
    # no target: the default (all); each loads a scene the package holds (example:csg included)
    assert _strict(lambda: main(["warmup", *target])) == 0, capsys.readouterr().err[-2000:]

"""The `raykernel` command: rendering with statistics, error messages, atomic outputs, listings."""

from __future__ import annotations

import importlib
import json
import os
import math
import subprocess
import sys
import time
from pathlib import Path

import numba
import numpy as np
import pytest
from PIL import Image

from raykernel.cli import main
from raykernel.aggregates import registry as accel

RAYKERNEL = Path(sys.executable).parent / "raykernel"
render_module = importlib.import_module("raykernel.rendering.render")   # the package re-exports the function under the same name

COUNTER_KEYS = [
    "rays.eye", "rays.eye_hit", "rays.reflect", "rays.reflect_hit", "rays.refract", "rays.refract_hit",
    "rays.shadow", "rays.shadow_blocked", "tests.total", "tests.sphere", "tests.polygon", "tests.patch",
    "tests.cone", "tests.triangle", "bounds.tests", "cells.visited", "build.nodes", "build.bytes",
    "time.parse", "time.preprocess", "time.trace", "time.compile", "time.load", "transforms.affine",
]

# lines 1-7
VIEW = "v\nfrom 0 -5 0\nat 0 0 0\nup 0 0 1\nangle 40\nhither 1\nresolution 8 8\n"
GOOD_NFF = VIEW + "l 2 -4 3\nf 1 0.5 0.2 0.8 0 0 0 1\ns 0 0 0 1\n"


def write(path: Path, data) -> Path:
    if isinstance(data, bytes):
        path.write_bytes(data)
    else:
        path.write_text(data)
    return path


def error_line(capsys) -> str:
    """The one line main() wrote to stderr; stdout must stay empty."""
    out, err = capsys.readouterr()
    assert out == ""
    assert "Traceback" not in err
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("raykernel: error: ")
    return lines[0]


def leftovers(directory: Path, keep=()) -> list[str]:
    return sorted(p.name for p in directory.iterdir() if p.name not in keep)


# ---------------------------------------------------------------- rendering


@pytest.mark.parametrize("spd, eye_rays", [(False, 16 * 16), (True, 17 * 17)])
def test_render_sf1_with_stats_json(spd_dir, tmp_path, capsys, spd, eye_rays):
    out, stats = tmp_path / "balls.png", tmp_path / "stats.json"
    argv = ["render", str(spd_dir / "balls-sf1.nff"), "-o", str(out), "--resolution", "16",
            "--stats-json", str(stats)] + (["--spd"] if spd else [])
    t0 = time.perf_counter()
    assert main(argv) == 0
    wall = time.perf_counter() - t0
    printed = capsys.readouterr().out
    assert "balls-sf1.nff" in printed
    with Image.open(out) as img:
        assert img.format == "PNG" and img.size == (16, 16) and img.mode == "RGB"
        assert len(set(map(tuple, np.asarray(img).reshape(-1, 3)))) > 2
    data = json.loads(stats.read_text())
    counters = data["counters"]
    missing = [k for k in COUNTER_KEYS if k not in counters]
    assert not missing
    assert counters["rays.eye"] == eye_rays
    assert 0 < counters["rays.eye_hit"] <= eye_rays
    assert counters["tests.total"] == sum(counters[f"tests.{k}"]
                                          for k in ("sphere", "polygon", "patch", "cone", "triangle"))
    assert counters["tests.sphere"] > 0 and counters["tests.polygon"] > 0
    assert counters["build.nodes"] > 0 and counters["build.bytes"] > 0
    # the command's times: each a clock difference less the compiling and loading inside it, so finite
    # and not below zero; reading, building, tracing, compiling and loading kernels are kept apart,
    # so together they fit in the time the command took
    times = [counters[f"time.{k}"] for k in ("parse", "preprocess", "trace", "compile", "load")]
    assert all(math.isfinite(x) and x >= 0.0 for x in times) and counters["time.trace"] > 0.0
    assert counters["time.parse"] > 0.0 and sum(times) <= wall
    assert leftovers(tmp_path) == ["balls.png", "stats.json"]


def test_render_max_depth_and_threads_reach_the_renderer(spd_dir, tmp_path, capsys):
    stats = tmp_path / "s.json"
    argv = ["render", str(spd_dir / "balls-sf1.nff"), "-o", str(tmp_path / "b.png"), "--resolution", "8",
            "--max-depth", "1", "--threads", "1", "--stats-json", str(stats)]
    try:
        assert main(argv) == 0
    finally:
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
    data = json.loads(stats.read_text())
    assert data["counters"]["rays.reflect"] == 0           # depth 1: eye rays only
    assert data["info"]["max_depth"] == 1 and data["info"]["threads"] == 1


def test_render_subprocess_exit_zero(spd_dir, tmp_path):
    out = tmp_path / "t.png"
    proc = subprocess.run([str(RAYKERNEL), "render", str(spd_dir / "tetra-sf1.nff"), "-o", str(out),
                           "--resolution", "12"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    with Image.open(out) as img:
        assert img.size == (12, 12)


def test_console_script_exits_with_mains_status_and_freezes_the_heap(monkeypatch, capsys):
    """run() (the `raykernel` script) returns main's status as the exit code, and leaves the
    objects made so far out of the exit's garbage collections (gc.freeze)."""
    import gc

    from raykernel import cli
    monkeypatch.setattr(sys, "argv", ["raykernel", "accels"])
    try:
        with pytest.raises(SystemExit) as done:
            cli.run()
        assert done.value.code == 0 and gc.get_freeze_count() > 0
        monkeypatch.setattr(sys, "argv", ["raykernel", "render", "no-such-scene.nff"])
        with pytest.raises(SystemExit) as failed:
            cli.run()
        assert failed.value.code == 2 and "no such file" in capsys.readouterr().err
    finally:
        gc.unfreeze()


# ---------------------------------------------------------------- bad inputs

BAD_FILES = {
    # name: (content, line the message must name, or None when only the file is named)
    "keyword": (VIEW + "foo 1 2 3\n", 8),
    "binary": (b"\x89PNG\r\n\x1a\n\0\0\0\rIHDR", None),
    "empty": ("", None),
    "truncated": (VIEW + "f 1 0 0 1 0 0 0 1\ns 0 0 0\n", 9),
    "cut-view": ("v\nfrom 0 -5 0\nat 0 0", 3),
}


@pytest.mark.parametrize("name", list(BAD_FILES))
def test_bad_scene_file(tmp_path, capsys, name):
    content, line = BAD_FILES[name]
    path = write(tmp_path / f"{name}.nff", content)
    out = tmp_path / "out.png"
    assert main(["render", str(path), "-o", str(out)]) == 2
    message = error_line(capsys)
    assert str(path) in message
    if line is not None:
        assert f"{path}:{line}:" in message
    assert not out.exists()
    assert leftovers(tmp_path) == [path.name]


def test_error_stays_on_one_line_on_a_narrow_terminal(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "40")
    deep = tmp_path / ("a-rather-long-directory-name-" * 3)
    deep.mkdir()
    path = write(deep / "keyword.nff", VIEW + "foo 1 2 3\n")
    assert main(["render", str(path), "-o", str(tmp_path / "o.png")]) == 2
    assert f"{path}:8:" in error_line(capsys)


def test_missing_file(tmp_path, capsys):
    path = tmp_path / "nowhere.nff"
    assert main(["render", str(path), "-o", str(tmp_path / "o.png")]) == 2
    assert str(path) in error_line(capsys)
    assert leftovers(tmp_path) == []


@pytest.mark.parametrize("argv, what", [
    (["render", "MISSING.nff"], "MISSING.nff"),
    (["render", "GOOD", "--accel", "nosuchtree"], "nosuchtree"),
    (["render", "BAD"], ":8:"),
])
def test_subprocess_errors_without_traceback(tmp_path, argv, what):
    good = write(tmp_path / "good.nff", GOOD_NFF)
    bad = write(tmp_path / "bad.nff", VIEW + "foo 1 2 3\n")
    names = {"MISSING.nff": str(tmp_path / "MISSING.nff"), "GOOD": str(good), "BAD": str(bad)}
    argv = [names.get(a, a) for a in argv] + ["-o", str(tmp_path / "o.png")]
    proc = subprocess.run([str(RAYKERNEL), *argv], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    lines = proc.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("raykernel: error: ") and what in lines[0]
    assert not (tmp_path / "o.png").exists()


def test_bad_accel_lists_the_kinds(tmp_path, capsys):
    nff = write(tmp_path / "good.nff", GOOD_NFF)
    out = tmp_path / "o.png"
    assert main(["render", str(nff), "--accel", "nosuchtree", "-o", str(out)]) == 2
    message = error_line(capsys)
    assert "nosuchtree" in message
    for kind in ("bvh", "list"):
        assert kind in message.split("nosuchtree", 1)[1]
    assert not out.exists()


def test_bad_accel_parameter(tmp_path, capsys):
    nff = write(tmp_path / "good.nff", GOOD_NFF)
    assert main(["render", str(nff), "--accel", "bvh(leaf=0)", "-o", str(tmp_path / "o.png")]) == 2
    assert "leaf" in error_line(capsys)


@pytest.mark.parametrize("value", ["0", "-4", "abc", "2.5"])
def test_bad_resolution(tmp_path, capsys, value):
    nff = write(tmp_path / "good.nff", GOOD_NFF)
    with pytest.raises(SystemExit) as exc:
        main(["render", str(nff), "--resolution", value, "-o", str(tmp_path / "o.png")])
    assert exc.value.code == 2
    out, err = capsys.readouterr()
    assert "Traceback" not in err
    assert "--resolution" in err.splitlines()[-1]
    assert not (tmp_path / "o.png").exists()


def test_output_into_missing_directory(tmp_path, capsys):
    nff = write(tmp_path / "good.nff", GOOD_NFF)
    target = tmp_path / "no" / "such" / "dir" / "o.png"
    assert main(["render", str(nff), "--resolution", "4", "-o", str(target)]) == 2
    message = error_line(capsys)
    assert str(target.parent) in message
    assert leftovers(tmp_path) == ["good.nff"]


def test_stats_json_into_missing_directory(tmp_path, capsys):
    nff = write(tmp_path / "good.nff", GOOD_NFF)
    target = tmp_path / "missing" / "s.json"
    code = main(["render", str(nff), "--resolution", "4", "-o", str(tmp_path / "o.png"),
                 "--stats-json", str(target)])
    assert code == 2
    assert str(target.parent) in error_line(capsys)
    assert not target.parent.exists()


# ---------------------------------------------------------------- atomic outputs


def interrupt_after_start(monkeypatch):
    """Make raykernel.rendering.render.render raise KeyboardInterrupt from its first progress report,
    i.e. after the scene was built and the first tiles were traced."""
    real = render_module.render
    started = []

    def boom(done, total):
        started.append(done)
        raise KeyboardInterrupt

    def failing(scene, **options):
        options["progress"] = boom
        return real(scene, **options)

    monkeypatch.setattr(render_module, "render", failing)
    return started


def interrupt_mid_write(monkeypatch):
    """Make every binary file opened through os.fdopen take half its first write, then
    raise KeyboardInterrupt, as a Ctrl-C in the middle of writing the PNG would."""
    real = os.fdopen
    written = []

    class HalfWriter:
        def __init__(self, f):
            self._f = f

        def write(self, data):
            self._f.write(data[:len(data) // 2])
            self._f.flush()
            written.append(len(data) // 2)
            raise KeyboardInterrupt

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self._f.close()
            return False

        def __getattr__(self, name):
            return getattr(self._f, name)

    def fdopen(fd, mode="r", *args, **kwargs):
        f = real(fd, mode, *args, **kwargs)
        return HalfWriter(f) if "b" in mode else f

    monkeypatch.setattr(os, "fdopen", fdopen)
    return written


@pytest.mark.parametrize("failure", [interrupt_after_start, interrupt_mid_write])
def test_interrupted_render_leaves_no_file(tmp_path, capsys, monkeypatch, failure):
    nff = write(tmp_path / "good.nff", GOOD_NFF)
    out, stats = tmp_path / "o.png", tmp_path / "s.json"
    happened = failure(monkeypatch)
    code = main(["render", str(nff), "--resolution", "40", "-o", str(out), "--stats-json", str(stats)])
    assert happened, "the failure was not triggered"
    assert code == 130
    assert "Traceback" not in capsys.readouterr().err
    assert leftovers(tmp_path) == ["good.nff"]


@pytest.mark.parametrize("failure", [interrupt_after_start, interrupt_mid_write])
def test_interrupted_render_keeps_existing_output(tmp_path, capsys, monkeypatch, failure):
    nff = write(tmp_path / "good.nff", GOOD_NFF)
    out = tmp_path / "o.png"
    assert main(["render", str(nff), "--resolution", "8", "-o", str(out)]) == 0
    before = out.read_bytes()
    happened = failure(monkeypatch)
    assert main(["render", str(nff), "--resolution", "40", "-o", str(out)]) == 130
    assert happened
    assert out.read_bytes() == before
    assert leftovers(tmp_path) == ["good.nff", "o.png"]


def test_failed_render_keeps_existing_output(tmp_path, capsys):
    nff = write(tmp_path / "good.nff", GOOD_NFF)
    out = tmp_path / "o.png"
    write(out, b"an earlier picture")
    assert main(["render", str(nff), "--accel", "nosuchtree", "-o", str(out)]) == 2
    assert out.read_bytes() == b"an earlier picture"
    assert leftovers(tmp_path) == ["good.nff", "o.png"]


# ---------------------------------------------------------------- accels and spd


def test_accels_lists_kinds_and_parameters(capsys):
    assert main(["accels"]) == 0
    out = capsys.readouterr().out
    text = " ".join(out.split())
    heads = [line.split(":")[0] for line in out.splitlines() if line and not line[0].isspace()]
    assert "bvh" in heads and "list" in heads
    assert "leaf=" in text and "bins=" in text
    for kind in accel.KINDS.values():
        assert kind.name in heads
        for p in kind.params:
            default = ("on" if p.default else "off") if isinstance(p.default, bool) else str(p.default)
            assert f"{p.name}={default}" in text


def _tokens(text: str) -> list[str]:
    return [t for line in text.splitlines() for t in line.split("#", 1)[0].split()]


def assert_same_nff(a: str, b: str):
    ta, tb = _tokens(a), _tokens(b)
    assert len(ta) == len(tb)
    for k, (x, y) in enumerate(zip(ta, tb)):
        try:
            fx, fy = float(x), float(y)
        except ValueError:
            assert x == y, f"token {k}: {x!r} != {y!r}"
        else:
            assert abs(fx - fy) <= 1e-4, f"token {k}: {x} != {y}"


def test_spd_balls_size_one_matches_reference(spd_dir, capsys):
    assert main(["spd", "balls", "--size", "1"]) == 0
    out = capsys.readouterr().out
    assert_same_nff(out, (spd_dir / "balls-sf1.nff").read_text())


def test_spd_to_file(spd_dir, tmp_path, capsys):
    target = tmp_path / "tetra.nff"
    assert main(["spd", "tetra", "--size", "1", "-o", str(target)]) == 0
    assert capsys.readouterr().out == ""
    assert_same_nff(target.read_text(), (spd_dir / "tetra-sf1.nff").read_text())
    assert leftovers(tmp_path) == ["tetra.nff"]


def test_spd_unknown_name(capsys):
    assert main(["spd", "nosuch"]) == 2
    message = error_line(capsys)
    assert "nosuch" in message and "balls" in message


@pytest.mark.parametrize("argv, expected", [
    (["--accel", "nosuchtree"], "nosuchtree"),
    (["--accel", "bvh(leaf=0)"], "leaf"),
    (["-o", "{tmp}/no/such/dir/o.png"], "does not exist"),
    (["--stats-json", "{tmp}/missing/s.json"], "does not exist"),
    (["-o", "{tmp}/o.bmpx"], "bmpx"),
])
def test_bad_render_options_fail_before_the_compile_notice(tmp_path, capsys, monkeypatch, argv, expected):
    # on a first run the CLI says it will compile; options that cannot work are refused before that
    import raykernel.rendering.render as render
    monkeypatch.setattr(render, "first_run", lambda: True)
    nff = write(tmp_path / "good.nff", GOOD_NFF)
    argv = [a.format(tmp=tmp_path) for a in argv]
    if "-o" not in argv:
        argv += ["-o", str(tmp_path / "o.png")]
    assert main(["render", str(nff), "--resolution", "4", *argv]) == 2
    assert expected in error_line(capsys)
    assert leftovers(tmp_path) == ["good.nff"]

"""The kernel cache is keyed on the kernels' code (geometry/cachekey.py): no stale kernel runs, and
no docstring, comment or blank line recompiles one."""

import re
import shutil
import sys
from pathlib import Path

import numba
import numpy as np
import pytest
from numba.core.caching import FunctionCache

from raykernel.geometry import cachekey, config

KERNEL_FILES = sorted(p.relative_to(config.PACKAGE).as_posix() for p in config.PACKAGE.rglob("*.py")
                      if b"@njit" in p.read_bytes())


def _copy_package(tmp_path):
    dest = tmp_path / "pkg"
    shutil.copytree(config.PACKAGE, dest, ignore=shutil.ignore_patterns("__pycache__"))
    return dest


def _stamps(pkg):
    return {name: cachekey.code_stamp(pkg / name, pkg) for name in KERNEL_FILES}


def _retext(source: str) -> str:
    """The same code as other text: bench/cache_edits.py's edit (every docstring changed, a
    comment after every def, blank lines before it, a comment at the end)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
    try:
        from cache_edits import retext
    finally:
        sys.path.pop(0)
    return retext(source)


def test_every_kernel_file_is_stamped_by_its_code_alone(tmp_path):
    pkg = _copy_package(tmp_path)
    before = _stamps(pkg)
    assert before == {name: cachekey.code_stamp(config.PACKAGE / name) for name in KERNEL_FILES}
    assert len(KERNEL_FILES) > 20
    for name in KERNEL_FILES:
        path = pkg / name
        text = path.read_text()
        path.write_text(_retext(text))
        assert path.read_text() != text
        assert _stamps(pkg) == before, name
        path.write_text(text)


def test_a_code_change_restamps_its_file_and_every_file_importing_it(tmp_path):
    pkg = _copy_package(tmp_path)
    before = _stamps(pkg)
    prims = pkg / "geometry" / "primitives.py"
    prims.write_text(prims.read_text() + "\nCHANGED = 1\n")
    after = _stamps(pkg)
    assert after["geometry/primitives.py"] != before["geometry/primitives.py"]
    assert after["engine/traverse.py"] != before["engine/traverse.py"]       # inlines the primitive tests
    assert after["geometry/boxes.py"] == before["geometry/boxes.py"]         # imports nothing of it


@pytest.mark.parametrize("feeder", ["geometry/counters.py", "aggregates/walk.py"])
def test_a_constant_that_kernels_freeze_restamps_them(tmp_path, feeder):
    # no kernel of their own, but counter columns and stack sizes are frozen into kernels
    pkg = _copy_package(tmp_path)
    before = _stamps(pkg)
    path = pkg / feeder
    text = path.read_text()
    number = re.search(r"^([A-Z_]+) = (\d+)", text, re.M)
    path.write_text(text.replace(number.group(0), f"{number.group(1)} = {int(number.group(2)) + 1}", 1))
    after = _stamps(pkg)
    assert after["engine/traverse.py"] != before["engine/traverse.py"]


def test_imports_are_found_in_every_form(tmp_path):
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    for name in ("a.py", "b.py", "c.py", "g.py", "sub/__init__.py", "sub/d.py", "sub/e.py", "sub/f.py"):
        (pkg / name).write_text("")
    (pkg / "sub" / "k.py").write_text("from ..a import x  # a comment, d\nfrom . import d, e as g\n"
                                      "from .f import (\n    y,  # z\n    w,\n)\nfrom .. import b\nimport c\n"
                                      "def later():\n    from ..g import h\n")
    found = {p.relative_to(pkg).as_posix() for p in cachekey.dependencies(pkg / "sub" / "k.py", pkg)}
    assert found == {"sub/k.py", "a.py", "sub/d.py", "sub/e.py", "sub/f.py", "sub/__init__.py", "b.py", "g.py"}


def test_kernels_cache_in_raykernels_folder_and_other_numba_code_in_numbas():
    saved = numba.config.CACHE_DIR

    @config.njit
    def twice(x):
        return 2 * x

    @numba.njit(cache=True)
    def thrice(x):
        return 3 * x

    assert twice(21) == 42 and thrice(2) == 6
    assert numba.config.CACHE_DIR == saved
    assert isinstance(twice._cache, cachekey.KernelCache)
    assert twice._cache.cache_path.startswith(config.CACHE_DIR)
    assert type(thrice._cache) is FunctionCache and not thrice._cache.cache_path.startswith(config.CACHE_DIR)


def test_the_entry_name_does_not_move_with_the_lines_above(tmp_path):
    import importlib.util

    def load(name, source):
        (tmp_path / f"{name}.py").write_text(source)
        spec = importlib.util.spec_from_file_location(name, tmp_path / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module

    plain = load("plain", "def first(x):\n    return x + 1\n")
    moved = load("moved", "\n\n# moved down\n\ndef first(x):\n    \"\"\"Now documented.\"\"\"\n    return x + 1  # same\n")
    changed = load("changed", "def first(x):\n    return x + 2\n")
    assert cachekey.function_key(plain.first) == cachekey.function_key(moved.first)
    assert cachekey.function_key(plain.first) != cachekey.function_key(changed.first)


def test_factory_form_takes_options():
    @config.njit(parallel=False, cache=False)
    def add(a, b):
        return a + b

    assert add(1, 2) == 3


@pytest.mark.parametrize("option", ["private", "borrows"])
def test_borrowing_kernels_count_no_references(option):
    # a private or borrowing kernel does no reference counting: many calls leave the
    # array's count as it was and see the caller's data; only `borrows` keeps a Python wrapper
    @config.njit(cache=False, **{option: True})
    def _total(a, i):
        return a[i] + a[0]

    @config.njit(cache=False)
    def caller(a, n):
        s = 0.0
        for i in range(n):
            s += _total(a, i % a.shape[0])
        return s

    a = np.arange(5.0)
    count = sys.getrefcount(a)
    assert caller(a, 1000) == sum(a[i % 5] + a[0] for i in range(1000))
    assert sys.getrefcount(a) == count
    options = _total.targetoptions
    assert options["_nrt"] is False
    assert options.get("no_cpython_wrapper", False) is (option == "private")
    if option == "borrows":
        assert _total(a, 3) == 3.0          # callable from Python
        assert "NRT_incref" not in next(iter(_total.inspect_llvm().values()))


def test_a_private_kernel_may_not_allocate():
    @config.njit(private=True, cache=False)
    def _fresh(n):
        return np.zeros(n).sum()

    @config.njit(cache=False)
    def caller(n):
        return _fresh(n)

    with pytest.raises(numba.core.errors.TypingError):
        caller(3)


def test_the_kernels_inner_loops_count_no_references():
    # what kernels call per ray, per candidate or per pixel with arrays borrows them (or is inlined):
    # reference counts there are atomics the threads fight over (they took half the time of a query)
    from raykernel.aggregates import bvh, collect, csg, grid, octree, rc
    from raykernel.casting import meshcast, proximity, rayscene
    from raykernel.engine import transforms, traverse, widewalk
    from raykernel.geometry import primitives
    from raykernel.rendering import hall, heckbert, render, sampling, startlists, tricks, whitted

    per_item = [primitives.hit_polygon, primitives.point_in_polygon, primitives.point_in_triangle, rc.meets_beam,
                proximity._closest_on_polygon,
                traverse.walk, widewalk._walk_wide, whitted.trace, heckbert.trace, hall.trace, tricks.test_ref, tricks.list_hint,
                startlists.start_list,
                sampling._render_tile, render._render_tile, render._missed_tile,
                rayscene._cast, meshcast._chunk, meshcast._chunk4, bvh.descend, grid.dda, rc.classify,
                csg.start, collect.record, csg.resolve, octree._parametric, octree._point_walk, transforms.map_ray]
    for kernel in per_item:
        assert kernel.targetoptions.get("_nrt") is False, kernel.py_func.__qualname__
    assert traverse.intersect.targetoptions.get("inline") == "always"     # a dispatcher, inlined where called


def test_a_geometry_is_typed_once_per_layout_as_numba_would():
    from numba.core import types
    from numba.core.typing.typeof import Purpose, typeof

    import raykernel
    from raykernel.engine.flatten import flatten

    geo, _ = flatten(raykernel.load("spd:tetra:1"), "bvh")
    field_by_field = types.NamedTuple([typeof(x, Purpose.argument) for x in geo], type(geo))
    assert typeof(geo, Purpose.argument) == field_by_field
    # another layout is another type: a strided view, a read-only array, another dtype
    strided = geo._replace(node_bounds=np.zeros((4, 12))[:, ::2])
    frozen = geo.node_bounds.copy()
    frozen.flags.writeable = False
    for other in (strided, geo._replace(node_bounds=frozen), geo._replace(refs=geo.refs.astype(np.int32))):
        ty = typeof(other, Purpose.argument)
        assert ty != field_by_field
        assert ty == types.NamedTuple([typeof(x, Purpose.argument) for x in other], type(other))


def test_cache_command_shows_and_clears_only_when_asked(tmp_path, monkeypatch, capsys):
    from raykernel.cli import main
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    old = tmp_path / "raykernel" / "numba-0123456789abcdef"     # an earlier version's folder
    (old / "rendering_x").mkdir(parents=True)
    (old / "rendering_x" / "k.nbc").write_bytes(b"x" * 2048)
    assert main(["cache"]) == 0
    assert str(old) in capsys.readouterr().out and old.is_dir()     # shown, kept
    assert main(["cache", "--clear"]) == 0
    assert "Removed 1" in capsys.readouterr().out and not old.exists()


def test_importing_raykernel_deletes_no_folder(tmp_path):
    import os
    import subprocess
    old = tmp_path / "raykernel" / "numba-0123456789abcdef"
    old.mkdir(parents=True)
    os.utime(old, (0, 0))           # unused for decades
    env = dict(os.environ, XDG_CACHE_HOME=str(tmp_path))
    env.pop("NUMBA_CACHE_DIR", None)
    subprocess.run([sys.executable, "-c", "import raykernel"], env=env, check=True)
    assert old.is_dir()

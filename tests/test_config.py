"""The kernel cache is keyed on the kernel sources, so no stale kernel runs."""

import shutil
import sys

import numba
import numpy as np
import pytest

from raykernel.geometry import config


def _copy_package(tmp_path):
    dest = tmp_path / "pkg"
    shutil.copytree(config.PACKAGE, dest, ignore=shutil.ignore_patterns("__pycache__"))
    return dest


def test_hash_changes_with_a_kernel_source(tmp_path):
    pkg = _copy_package(tmp_path)
    before = config.kernel_source_hash(pkg)
    assert before == config.kernel_source_hash(config.PACKAGE)
    prims = pkg / "geometry" / "primitives.py"
    prims.write_text(prims.read_text() + "\n# changed\n")
    assert config.kernel_source_hash(pkg) != before


@pytest.mark.parametrize("feeder", ["geometry/counters.py", "scene/model.py", "engine/flatten.py"])
def test_hash_changes_with_a_module_whose_constants_kernels_use(tmp_path, feeder):
    # no kernel of their own, but counter columns, MAX_NESTING and the stack size are frozen into kernels
    pkg = _copy_package(tmp_path)
    before = config.kernel_source_hash(pkg)
    path = pkg / feeder
    assert b"njit" not in path.read_bytes()
    path.write_text(path.read_text() + "\n# changed\n")
    assert config.kernel_source_hash(pkg) != before


def test_imports_are_found_in_every_form(tmp_path):
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    for name in ("a.py", "b.py", "c.py", "sub/__init__.py", "sub/d.py", "sub/e.py", "sub/f.py"):
        (pkg / name).write_text("")
    (pkg / "sub" / "k.py").write_text("from ..a import x  # a comment, d\nfrom . import d, e as g\n"
                                      "from .f import (\n    y,  # z\n    w,\n)\nfrom .. import b\nimport c\n")
    found = {p.relative_to(pkg).as_posix() for p in config._imported(pkg / "sub" / "k.py", pkg)}
    assert found == {"a.py", "sub/d.py", "sub/e.py", "sub/f.py", "sub/__init__.py", "b.py"}


def test_hash_ignores_files_without_kernels(tmp_path):
    pkg = _copy_package(tmp_path)
    before = config.kernel_source_hash(pkg)
    cli = pkg / "cli.py"
    assert b"njit" not in cli.read_bytes()
    cli.write_text(cli.read_text() + "\n# changed\n")
    assert config.kernel_source_hash(pkg) == before


def test_cache_dir_is_keyed_and_restored():
    assert config.kernel_source_hash() in config.CACHE_DIR
    saved = numba.config.CACHE_DIR

    @config.njit
    def twice(x):
        return 2 * x

    assert twice(21) == 42
    assert numba.config.CACHE_DIR == saved
    assert twice._cache._cache_path.startswith(config.CACHE_DIR)


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
                rayscene._cast, meshcast._chunk, meshcast._chunk4, bvh.step, grid.step, rc.step,
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

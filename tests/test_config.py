"""The kernel cache is keyed on the kernels' code (geometry/cachekey.py): no stale kernel runs, and
no docstring, comment or blank line recompiles one."""

import json
import os
import pickle
import shutil
import subprocess
import sys
from pathlib import Path

import numba
import numpy as np
import pytest
from numba.core.caching import FunctionCache

from raykernel.geometry import cachekey, config

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
from cache_edits import code_edit, retext  # noqa: E402  (the edits bench/cache_edits.py counts)

sys.path.pop(0)
PROBE = "import json; from raykernel.geometry import cachekey; print(json.dumps(cachekey.all_stamps()))"


def _copy_package(tmp_path):
    dest = tmp_path / "src" / "raykernel"
    shutil.copytree(config.PACKAGE, dest, ignore=shutil.ignore_patterns("__pycache__"))
    return dest


def _stamps(pkg) -> dict:
    """Every cached kernel's stamp, as a fresh process importing the package at `pkg` makes them."""
    env = dict(os.environ, PYTHONPATH=str(pkg.parent))
    out = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, cwd=pkg.parent,
                         check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _changed(before, after):
    assert set(before) == set(after)
    return {k for k in before if before[k] != after[k]}


@pytest.fixture(scope="module")
def package(tmp_path_factory):
    """A copy of the package and its kernels' stamps."""
    pkg = _copy_package(tmp_path_factory.mktemp("stamps"))
    return pkg, _stamps(pkg)


def test_stamps_are_made_at_first_use_and_the_same_in_every_process(package):
    pkg, before = package
    assert len(before) > 200
    assert before == cachekey.all_stamps()              # this process, the checkout itself
    assert _stamps(pkg) == before


def test_no_text_edit_restamps_a_kernel(package):
    pkg, before = package
    edited = {path: path.read_text() for path in pkg.rglob("*.py")}
    for path, text in edited.items():
        path.write_text(retext(text))
    try:
        assert _stamps(pkg) == before
    finally:
        for path, text in edited.items():
            path.write_text(text)


def _edit(pkg, name, new_text):
    path = pkg / name
    text = path.read_text()
    assert new_text != text
    path.write_text(new_text)
    try:
        return _stamps(pkg)
    finally:
        path.write_text(text)


def test_a_code_change_restamps_its_callers_and_no_other_kernel(package):
    pkg, before = package
    prims = pkg / "geometry" / "primitives.py"
    changed = _changed(before, _edit(pkg, "geometry/primitives.py", code_edit(prims.read_text(), only="sphere_roots")))
    assert "raykernel.geometry.primitives.sphere_roots" in changed
    assert "raykernel.engine.traverse.walk" in changed            # inlines the sphere test
    assert not any(k.startswith("raykernel.geometry.boxes.") for k in changed)      # calls nothing of it
    assert not any(k.startswith("raykernel.casting.meshbuild.") for k in changed)   # nor the mesh builds
    # and a builder edit restamps no walk
    builder = pkg / "aggregates" / "bvhbuild.py"
    changed = _changed(before, _edit(pkg, "aggregates/bvhbuild.py", code_edit(builder.read_text(), only="_best_split")))
    assert "raykernel.aggregates.bvhbuild._best_split" in changed
    assert not any(k.endswith(".walk_step") or ".traverse." in k or ".widewalk." in k for k in changed)


@pytest.mark.parametrize("feeder, old, new", [
    ("geometry/counters.py", "RAYS_EYE, RAYS_EYE_HIT = 0, 1", "RAYS_EYE, RAYS_EYE_HIT = 1, 0"),
    ("aggregates/walk.py", "MAX_TREE_DEPTH = 96", "MAX_TREE_DEPTH = 97"),
    ("errors.py", "class SceneError(RayKernelError):", "class SceneError(RayKernelError):\n    EDITED = 1"),
])
def test_a_constant_that_kernels_freeze_restamps_them(package, feeder, old, new):
    # no kernel of their own, but counter columns and stack sizes are frozen into kernels; an error
    # message is frozen into none
    pkg, before = package
    text = (pkg / feeder).read_text()
    assert old in text
    changed = _changed(before, _edit(pkg, feeder, text.replace(old, new, 1)))
    if feeder == "errors.py":
        assert not changed
    elif feeder == "geometry/counters.py":
        assert any(k.startswith("raykernel.rendering.") for k in changed)
    else:
        assert "raykernel.engine.traverse.workspace" in changed     # sizes the stack


CACHED_PAIR = """
from raykernel.geometry.config import njit


@njit
def inner(x):
    return x + 1


@njit
def outer(x):
    return 2 * inner(x)


@njit
def other(x):
    return x - 1
"""
RUN_PAIR = ("import json, probe; a, b = probe.outer(20), probe.other(5); "
            "print(json.dumps([a, b, sum(probe.outer.stats.cache_hits.values()), "
            "sum(probe.other.stats.cache_hits.values())]))")


def _run_pair(folder, cache):
    env = dict(os.environ, PYTHONPATH=f"{folder}{os.pathsep}{config.PACKAGE.parent}", NUMBA_CACHE_DIR=str(cache))
    out = subprocess.run([sys.executable, "-c", RUN_PAIR], env=env, capture_output=True, text=True, check=True)
    return tuple(json.loads(out.stdout.strip().splitlines()[-1]))


def test_an_edit_recompiles_the_kernels_that_use_it_and_only_those(tmp_path):
    # end to end, through numba's cache: a fresh process loads what an earlier one compiled
    probe = tmp_path / "probe.py"
    probe.write_text(CACHED_PAIR)
    cache = tmp_path / "cache"
    assert _run_pair(tmp_path, cache) == (42, 4, 0, 0)          # compiled
    assert _run_pair(tmp_path, cache) == (42, 4, 1, 1)          # loaded
    probe.write_text(retext(CACHED_PAIR))
    assert _run_pair(tmp_path, cache) == (42, 4, 1, 1)          # a text edit: loaded
    probe.write_text(CACHED_PAIR.replace("x + 1", "x + 2"))
    assert _run_pair(tmp_path, cache) == (44, 4, 0, 1)          # inner changed: outer recompiled, other loaded


CACHED_ALLOCATING = """
import numpy as np
from numba import prange
from raykernel.geometry.config import njit


@njit
def squares(n):                     # allocates (numba's runtime) and returns an array (boxing)
    out = np.empty(n)
    for i in range(n):
        out[i] = i * i
    return out


@njit(parallel=True)
def total(a):                       # the threading layer's symbols
    s = 0.0
    for i in prange(a.shape[0]):
        s += a[i]
    return s


@njit
def words():                        # hashes strings: the hash secret's symbols
    d = {"one": 1, "two": 2}
    return d["one"] + d["two"]
"""
RUN_ALLOCATING = """
import json, sys, numba, probe
import llvmlite.binding as ll
parsed = []
parse_bitcode = ll.parse_bitcode
ll.parse_bitcode = lambda code, *a: parsed.append(len(code)) or parse_bitcode(code, *a)
a = probe.squares(5)
result = [a.tolist(), probe.total(a), probe.words()]
hits = [sum(k.stats.cache_hits.values()) for k in (probe.squares, probe.total, probe.words)]
refreshed = "numba.np.linalg" in sys.modules          # imported only by the target context's refresh
loads_parsed = len(parsed)
later = numba.njit(lambda x: x + 1)(1)                  # a compile after the loads (numba refreshes then)
linked = numba.njit(lambda n: probe.squares(n).sum() + probe.words())(4)    # links loaded kernels' code
print(json.dumps([result, hits, refreshed, later, loads_parsed, linked, len(parsed) > loads_parsed]))
"""


def test_a_warm_process_loads_kernels_without_numbas_typing_set_up(tmp_path):
    # loading machine code needs numba's runtime and the symbols it links against, not the typing and
    # lowering registries a compile needs: a process that only loads never imports them
    (tmp_path / "probe.py").write_text(CACHED_ALLOCATING)
    env = dict(os.environ, PYTHONPATH=f"{tmp_path}{os.pathsep}{config.PACKAGE.parent}",
               NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    runs = [json.loads(subprocess.run([sys.executable, "-c", RUN_ALLOCATING], env=env, capture_output=True,
                                      text=True, check=True).stdout.strip().splitlines()[-1]) for _ in range(2)]
    expected = [[0.0, 1.0, 4.0, 9.0, 16.0], 30.0, 3]
    (first, first_hits, *_), (again, hits, refreshed, later, loads_parsed, linked, parsed_to_link) = runs
    assert first == again == expected
    assert first_hits == [0, 0, 0] and hits == [1, 1, 1]
    assert not refreshed and later == 2
    # the loaded kernels' LLVM modules are parsed only when a later compile links them (_LinkedOnDemand)
    assert loads_parsed == 0
    assert linked == 14 + 3 and parsed_to_link


def test_an_entry_in_numbas_own_form_loads_as_numba_loads_it():
    # entries written before the symbols' names were stored beside the bitcode: parsed at once, as numba does
    @numba.njit
    def plus_one(x):
        return x + 1

    assert plus_one(1) == 2
    cres = plus_one.overloads[plus_one.signatures[0]]
    state = cres.library.serialize_using_object_code()
    assert len(state[2]) == 2           # (machine code, bitcode): no names
    assert cachekey._linked_on_demand(cres.target_context)
    library = cachekey._LinkedOnDemand._unserialize(cres.target_context.codegen(), state)
    assert "_linking_module" in vars(library) and "_bitcode" not in vars(library)
    assert library.get_pointer_to_function(cres.fndesc.llvm_cpython_wrapper_name) != 0


def test_a_cache_entry_naming_a_module_that_moved_is_a_miss(tmp_path):
    # a kernel whose code is unchanged keeps its stamp, but its cached signature may name a type
    # whose module has since moved (engine/work.py became geometry/work.py): that entry is
    # compiled again and written over, where numba's own index raises
    from numba.core.caching import IndexDataCacheFile

    def index(kind):
        return kind(cache_path=str(tmp_path), filename_base="kernel-1.py311", source_stamp=("stamp", 1))

    def write_entry_naming(module):
        with open(index(IndexDataCacheFile)._index_path, "wb") as f:
            pickle.dump(index(IndexDataCacheFile)._version, f, protocol=-1)
            f.write(f"c{module}\nThing\n.".encode())        # a pickle of a class in that module

    write_entry_naming("raykernel_moved_away")
    with pytest.raises(ModuleNotFoundError):
        index(IndexDataCacheFile).load("key")
    tolerant = index(cachekey._TolerantIndex)
    assert tolerant.load("key") is None
    tolerant.save("key", {"compiled": 1})
    assert index(cachekey._TolerantIndex).load("key") == {"compiled": 1}
    assert index(IndexDataCacheFile).load("key") == {"compiled": 1}       # written over: numba reads it again
    data = tmp_path / next(p.name for p in tmp_path.iterdir() if p.suffix == ".nbc")
    data.write_bytes(b"craykernel_moved_away\nThing\n.")
    assert index(cachekey._TolerantIndex).load("key") is None               # a data file naming it: a miss too


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


def _module(folder, name, source):
    """A module of `source`, imported from folder/name.py."""
    import importlib.util
    (folder / f"{name}.py").write_text(source)
    spec = importlib.util.spec_from_file_location(name, folder / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_entry_name_does_not_move_with_the_lines_above(tmp_path):
    plain = _module(tmp_path, "plain", "def first(x):\n    return x + 1\n")
    moved = _module(tmp_path, "moved", "\n\n# moved down\n\ndef first(x):\n    \"\"\"Now documented.\"\"\"\n    return x + 1  # same\n")
    changed = _module(tmp_path, "changed", "def first(x):\n    return x + 2\n")
    assert cachekey.function_key(plain.first) == cachekey.function_key(moved.first)
    assert cachekey.function_key(plain.first) != cachekey.function_key(changed.first)
    assert cachekey.kernel_stamp(plain.first) == cachekey.kernel_stamp(moved.first)


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
    from raykernel.aggregates import bvhwalk, collect, csg, grid, octpoint, octwalk, rcbuild, rcwalk, widewalk
    from raykernel.casting import meshcast, proximity, rayqueries
    from raykernel.engine import transforms, traverse
    from raykernel.geometry import primitives
    from raykernel.rendering import hall, heckbert, render, sampling, startlists, tricks, whitted

    per_item = [primitives.hit_polygon, primitives.point_in_polygon, primitives.point_in_triangle, rcbuild.meets_beam,
                proximity._closest_on_polygon,
                traverse.walk, widewalk._walk_wide, whitted.trace, heckbert.trace, hall.trace, tricks.test_ref, tricks.list_hint,
                startlists.start_list,
                sampling._render_tile, render._render_tile, render._missed_tile,
                rayqueries._cast, meshcast._chunk, meshcast._chunk4, bvhwalk.descend, grid.dda, rcwalk.classify,
                csg.start, collect.record, csg.resolve, octwalk.parametric, octpoint.point_walk, transforms.map_ray]
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


def test_importing_makes_no_stamp_and_the_scene_model_needs_no_numba():
    code = ("import sys, raykernel; assert 'numba' not in sys.modules; raykernel.Scene, raykernel.Spheres; "
            "import raykernel.scene.model; assert 'numba' not in sys.modules, 'model'; "
            "raykernel.render; import raykernel.cli, raykernel.casting.rayscene; "
            "from raykernel.geometry import cachekey; print(len(cachekey._stamps))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["0"]


def test_a_default_argument_is_part_of_the_stamp(tmp_path):
    one = _module(tmp_path, "one", "K = 3\ndef f(x, k=2):\n    return x * k + K\n")
    two = _module(tmp_path, "two", "K = 3\ndef f(x, k=5):\n    return x * k + K\n")
    three = _module(tmp_path, "three", "K = 4\ndef f(x, k=2):\n    return x * k + K\n")
    stamps = {cachekey.kernel_stamp(m.f) for m in (one, two, three)}
    assert len(stamps) == 3


def test_a_kernel_numba_cannot_cache_warns_and_runs(tmp_path):
    """numba refuses to cache a kernel that holds dynamic globals (with NUMBA_OPT=0 the NFF
    scanner's constant tables stay globals) and says so in a warning that points at the
    kernel's file; raykernel's cache locator gives it that file, so the kernel warns and
    runs instead of failing on numba's warning."""
    code = ("from raykernel.scene.tokens import scan\n"
            "values, kinds = scan(b'v 1 -2.5e1 x')\n"
            "print(values.tolist(), kinds.tolist())")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path), NUMBA_OPT="0")
    run = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert "Cannot cache" in run.stderr and "tokens.py" in run.stderr
    values, kinds = run.stdout.split("] [")
    assert "-25.0" in values and "1.0" in values

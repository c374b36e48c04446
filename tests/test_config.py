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


def test_private_kernels_borrow_their_arguments():
    # a private kernel does no reference counting: many calls leave the array's
    # count as it was and see the caller's data
    @config.njit(private=True, cache=False)
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
    assert caller(a, 1000) == sum(a[i % 5] for i in range(1000))
    assert sys.getrefcount(a) == count
    options = _total.targetoptions
    assert options["_nrt"] is False and options["no_cpython_wrapper"] is True


def test_a_private_kernel_may_not_allocate():
    @config.njit(private=True, cache=False)
    def _fresh(n):
        return np.zeros(n).sum()

    @config.njit(cache=False)
    def caller(n):
        return _fresh(n)

    with pytest.raises(numba.core.errors.TypingError):
        caller(3)

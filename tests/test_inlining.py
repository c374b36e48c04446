"""numba's inliner without its defensive copies (geometry/inlining.py): same results, and only
where numba has the shape it was written against."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import types

import numba
import numpy as np
from numba.core import inline_closurecall

from raykernel.geometry import inlining


@numba.njit(inline="always")
def _scaled(x, k):
    if x < 0:
        return -x * k
    return x * k


@numba.njit(inline="always")
def _twice(x):
    return _scaled(x, 2) + _scaled(-x, 1)       # an inlined function that inlines another twice


@numba.njit
def _uses_inlined(values):
    total = 0.0
    count = 0
    for v in values:
        total += _twice(v) + _scaled(v, 3.5)        # the same callees at several sites, other types
        count += _scaled(np.int64(v > 0), 4)
    return total, count


def _reference(values):
    scaled = lambda x, k: -x * k if x < 0 else x * k      # noqa: E731
    total = sum(scaled(v, 2) + scaled(-v, 1) + scaled(v, 3.5) for v in values)
    return total, sum(scaled(int(v > 0), 4) for v in values)


def test_inlined_callees_at_many_sites_give_python_results():
    values = np.array([-2.5, 0.0, 1.25, 7.0, -0.5])
    assert inlining.skip_inline_copies()        # this numba has the shape: the change is in effect
    assert inline_closurecall.InlineWorker.inline_function.__module__ == inlining.__name__
    assert _uses_inlined(values) == _reference(values)
    assert inline_closurecall.copy is inlining.copy      # the stand-in is gone after each inlining


def test_the_same_kernel_compiles_alike_with_numba_as_shipped(tmp_path):
    # a raykernel kernel on an empty cache: the short inliner is set up by its compile, not by the import
    code = ("import json, sys, numpy as np, raykernel.geometry.config as config; "
            "at_import = 'numba.core.inline_closurecall' in sys.modules; "
            "sys.path.insert(0, sys.argv[1]); import test_inlining as t; "
            "from numba.core import inline_closurecall as m; "
            "kernel = config.njit(t._uses_inlined.py_func); "
            "print(json.dumps([kernel(np.linspace(-3, 3, 13)), m.InlineWorker.inline_function.__module__, at_import]))")
    results = []
    for shipped in ("", "1"):
        env = dict(os.environ, RAYKERNEL_NUMBA_AS_SHIPPED=shipped, NUMBA_CACHE_DIR=str(tmp_path / f"cache{shipped}"))
        out = subprocess.run([sys.executable, "-c", code, os.path.dirname(__file__)], env=env, capture_output=True,
                             text=True, check=True).stdout
        results.append(json.loads(out.splitlines()[-1]))
    (changed, where_changed, imported), (shipped, where_shipped, imported_shipped) = results
    assert changed == shipped == list(_reference(np.linspace(-3, 3, 13)))
    assert where_changed == "raykernel.geometry.inlining" and where_shipped == "numba.core.inline_closurecall"
    assert not imported and not imported_shipped        # importing raykernel leaves numba's inliner unloaded


def test_the_short_inliner_is_set_up_by_a_cache_miss_only(monkeypatch, tmp_path):
    from raykernel.geometry import cachekey, config
    calls = []
    monkeypatch.setattr(cachekey, "skip_inline_copies", lambda: calls.append(1))
    monkeypatch.setattr(config, "CACHE_DIR", str(tmp_path))

    def twice_plus_one(x):
        return 2.0 * x + 1.0

    assert config.njit(twice_plus_one)(3.0) == 7.0          # a miss: compiled, the inliner set up first
    assert len(calls) == 1
    assert config.njit(twice_plus_one)(4.0) == 9.0          # the same code from the cache: nothing to set up
    assert len(calls) == 1
    unwritable = config.njit(twice_plus_one)
    monkeypatch.setattr(unwritable._cache, "_open", lambda: False)     # no cache folder: compiled every time
    assert unwritable(5.0) == 11.0
    assert len(calls) == 2


def test_an_inliner_of_another_shape_is_left_alone():
    class Worker:
        def inline_ir(self, caller_ir, block, i, callee_ir, freevars, arg_typs=None):
            return callee_ir.copy()

        def inline_function(self, caller_ir, block, i, function, arg_typs=None):
            return self.inline_ir(caller_ir, block, i, function, ())

    other = types.SimpleNamespace(InlineWorker=Worker, copy=inlining.copy)
    assert not inlining._expected_shape(other)
    assert not inlining._expected_shape(types.SimpleNamespace(copy=inlining.copy))    # no InlineWorker at all
    assert inlining._expected_shape(inline_closurecall)


def test_only_raykernels_callees_skip_the_copies(monkeypatch):
    # other numba code in the process is inlined by numba's own method, copies and all
    from raykernel.geometry.boxes import inverse
    real = inline_closurecall.InlineWorker.inline_ir
    copied = {}

    def spy(self, caller_ir, block, i, callee_ir, freevars, arg_typs=None):
        copied[callee_ir.func_id.func.__module__] = inline_closurecall.copy is inlining.copy
        return real(self, caller_ir, block, i, callee_ir, freevars, arg_typs=arg_typs)

    monkeypatch.setattr(inline_closurecall.InlineWorker, "inline_ir", spy)

    @numba.njit(cache=False)
    def both(x):
        return _scaled(x, 2.0) + inverse(x)

    assert both(4.0) == 8.25
    assert copied == {__name__: True, "raykernel.geometry.boxes": False}

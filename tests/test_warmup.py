"""raykernel warmup: what it compiles, what it reports, and that a later process compiles nothing."""

from __future__ import annotations

import subprocess
import sys

import pytest

from raykernel.aggregates.registry import KINDS
from raykernel.analysis.warmup import plan, warm_up
from raykernel.errors import OptionError


def test_plans_cover_every_kind_and_query():
    labels = [label for label, _ in plan("render")]
    for name, kind in KINDS.items():
        assert (f"render with {name}" in labels) == (not kind.operands), name
    cast = [label for label, _ in plan("cast")]
    for query in ("intersect", "intersect, single precision", "occluded", "intersect_all", "count_hits",
                  "closest_points", "contains"):
        assert f"cast: {query}" in cast
    assert [label for label, _ in plan("all")] == labels + cast
    with pytest.raises(OptionError, match="one of render, cast, all"):
        plan("everything")


def test_cast_warm_up_reports_and_leaves_nothing_to_compile():
    seen = []
    report = warm_up("cast", processes=1, progress=lambda done, total, label: seen.append((done, total, label)))
    assert report["steps"] == len(plan("cast")) == seen[-1][0] == seen[-1][1]
    assert [d for d, _, _ in seen] == list(range(report["steps"] + 1))
    assert 0.0 <= report["compile"] + report["load"] <= report["seconds"]
    out = subprocess.run([sys.executable, "-m", "raykernel.cli", "warmup", "cast"], capture_output=True, text=True,
                         timeout=600)
    assert out.returncode == 0, out.stderr
    assert f"warm-up of cast: {len(plan('cast'))} steps" in out.stdout and "compiling 0.0 s" in out.stdout, out.stdout


def test_warm_up_shares_the_steps_among_processes():
    from raykernel.analysis.warmup import _shares
    assert _shares(5, 2) == [[0, 2, 4], [1, 3]]
    assert _shares(2, 4) == [[0], [1]]
    assert sorted(i for share in _shares(17, 3) for i in share) == list(range(17))
    seen = []
    report = warm_up("cast", processes=2, progress=lambda done, total, label: seen.append((done, total, label)))
    assert report["processes"] == 2 and report["steps"] == len(plan("cast"))
    assert [d for d, _, _ in seen] == list(range(report["steps"] + 1))       # every step reported once, in order
    assert {label for _, _, label in seen[1:-1]} <= {label for label, _ in plan("cast")}
    # the processes compiled into the shared cache: a later process loads everything
    out = subprocess.run([sys.executable, "-m", "raykernel.cli", "warmup", "cast", "--processes", "1"],
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0 and "in 1 process(es) (compiling 0.0 s" in out.stdout, out.stdout + out.stderr


def test_the_warm_up_processes_start_no_render_helpers(monkeypatch):
    """warm_up's processes fill the cores already: their first renders start no helper process
    each (rendering/ahead.py)."""
    import raykernel.analysis.warmup as warmup
    envs = []
    real_popen = subprocess.Popen

    def popen(args, **kw):
        envs.append(kw["env"])
        return real_popen([sys.executable, "-c", ""], stdout=kw["stdout"], stderr=kw["stderr"], text=True)
    monkeypatch.setattr(warmup.subprocess, "Popen", popen)
    assert warmup._in_processes("render", plan("render"), 2, None) == (0.0, 0.0)
    assert len(envs) == 2 and all(env["RAYKERNEL_COMPILE_AHEAD"] == "0" for env in envs)

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
    for query in ("intersect", "occluded", "intersect_all", "count_hits", "closest_points", "contains"):
        assert f"cast: {query}" in cast
    assert [label for label, _ in plan("all")] == labels + cast
    with pytest.raises(OptionError, match="one of render, cast, all"):
        plan("everything")


def test_cast_warm_up_reports_and_leaves_nothing_to_compile():
    seen = []
    report = warm_up("cast", progress=lambda done, total, label: seen.append((done, total, label)))
    assert report["steps"] == len(plan("cast")) == seen[-1][0] == seen[-1][1]
    assert [d for d, _, _ in seen] == list(range(report["steps"] + 1))
    assert 0.0 <= report["compile"] + report["load"] <= report["seconds"]
    out = subprocess.run([sys.executable, "-m", "raykernel.cli", "warmup", "cast"], capture_output=True, text=True,
                         timeout=600)
    assert out.returncode == 0, out.stderr
    assert f"warm-up of cast: {len(plan('cast'))} steps" in out.stdout and "compiling 0.0 s" in out.stdout, out.stdout

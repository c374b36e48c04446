"""The fuzzer (fuzzing.py): a short campaign answers or refuses every input, the saved reproducers
stay fixed, and the harness itself tells failures apart (it can fail)."""

from __future__ import annotations

import warnings
from pathlib import Path

import pytest

import fuzzing
from raykernel.errors import RayKernelWarning, SceneError

REPRODUCERS = sorted((Path(__file__).parent / "data" / "fuzz").glob("*.json"))


def test_a_short_campaign_has_no_failures(tmp_path):
    report = fuzzing.campaign(seed=20261206, n=150, save=tmp_path / "found", workdir=tmp_path)
    assert [outcome for _, outcome in report["failures"]] == []
    counts = report["counts"]
    for target in fuzzing.TARGETS:
        assert counts[target, "answered"] + counts[target, "refused"] == 30
    # the inputs reach both sides: some are answered and some refused, overall and for the readers
    assert counts["nff", "answered"] and counts["nff", "refused"] and counts["spec", "refused"]
    assert sum(counts[t, "answered"] for t in fuzzing.TARGETS) > 20


@pytest.mark.parametrize("path", REPRODUCERS, ids=[p.stem for p in REPRODUCERS])
def test_reproducers_stay_fixed(path, tmp_path):
    assert fuzzing.run(fuzzing.load_case(path), tmp_path) in ("answered", "refused")


def test_cases_come_back_from_the_seed():
    first = [c.key() for c in fuzzing.cases(7, 40)]
    assert first == [c.key() for c in fuzzing.cases(7, 40)] and len(set(first)) > 30


def test_the_harness_tells_failures_apart(monkeypatch, tmp_path):
    def raises(error):
        def runner(payload, workdir):
            raise error
        return runner

    def warns(payload, workdir):
        warnings.warn("overflow encountered in multiply", RuntimeWarning)

    def warns_on_purpose(payload, workdir):
        warnings.warn("a size of 1 is not supported by the SPD; writing it anyway", RayKernelWarning)
    case = fuzzing.Case("nff", "v\n")
    for runner, expected in ((raises(SceneError("one line")), "refused"), (lambda p, w: None, "answered"),
                             (raises(SceneError("two\nlines")), "a refusal of several lines"),
                             (raises(ValueError("deep")), "ValueError: deep"), (warns, "RuntimeWarning: overflow"),
                             (warns_on_purpose, "answered")):
        monkeypatch.setitem(fuzzing.RUNNERS, "nff", runner)
        assert fuzzing.run(case).startswith(expected)
    saved = fuzzing.save_case(case, "ValueError", tmp_path)
    assert fuzzing.load_case(saved) == case and not list(tmp_path.glob("*.tmp"))

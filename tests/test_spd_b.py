"""SPD generators teapot, jacks, lattice, sombrero, sample and nurbtst against
the reference NFF files, and their primitive counts at other size factors."""

from __future__ import annotations

from collections import Counter

import pytest

from raykernel.errors import OptionError
from raykernel.scene import spd
from raykernel.scene.spd import jacks, lattice, nurbtst, sample, sombrero, teapot

from support import SPD_DIR
TOLERANCE = 1.0e-4

REFERENCES = [("teapot", 1), ("teapot", 2), ("teapot", 6), ("teapot", 12),
              ("jacks", 1), ("jacks", 4), ("lattice", 1), ("lattice", 12),
              ("sombrero", 1), ("sample", 1), ("nurbtst", 1)]



def _teapot_one():
    with pytest.warns(RuntimeWarning):
        return teapot.generate(1)


def _tokens(text: str) -> list[tuple[str, int]]:
    return [(tok, line_no) for line_no, line in enumerate(text.splitlines(), 1) for tok in line.split()]


def _number(tok: str):
    try:
        return float(tok)
    except ValueError:
        return None


def first_mismatch(generated: str, reference: str, tol: float = TOLERANCE) -> str | None:
    """None if both texts have the same tokens, numbers agreeing within `tol`
    (absolute, or relative for magnitudes above 1); otherwise a description
    of the first difference."""
    ours, theirs = _tokens(generated), _tokens(reference)
    for index, ((a, line_a), (b, line_b)) in enumerate(zip(ours, theirs)):
        x, y = _number(a), _number(b)
        if x is None or y is None:
            same = a == b
        else:
            same = abs(x - y) <= tol * max(1.0, abs(x), abs(y))
        if not same:
            return (f"token {index}: generated {a!r} (line {line_a}) "
                    f"vs reference {b!r} (line {line_b})")
    if len(ours) != len(theirs):
        return f"token count differs: generated {len(ours)}, reference {len(theirs)}"
    return None


def entity_counts(text: str) -> Counter:
    """How many lines start with each NFF keyword (s, p, pp, c, l, f, ...)."""
    return Counter(line.split(None, 1)[0] for line in text.splitlines()
                   if line and line[0].isalpha())


def _generate(name: str, size: int) -> str:
    if name == "teapot" and size == 1:
        return _teapot_one()
    return spd.generate(name, size)


def test_first_mismatch_reports_token_line_and_values():
    assert first_mismatch("p 3\n1 2 3\n", "p 3\n1 2.00001 3\n") is None
    message = first_mismatch("s 0 0 0 1\ns 1 1 1 2\n", "s 0 0 0 1\ns 1 1.5 1 2\n")
    assert message is not None and "token 7" in message and "'1'" in message and "'1.5'" in message
    assert "line 2" in message
    assert "token 0" in first_mismatch("pp 3\n", "p 3\n")
    assert "count" in first_mismatch("s 0 0 0 1\n", "s 0 0 0 1\ns 1 1 1 1\n")


@pytest.mark.parametrize("name,size", REFERENCES, ids=[f"{n}-sf{s}" for n, s in REFERENCES])
def test_matches_reference_file(name, size):
    path = SPD_DIR / f"{name}-sf{size}.nff"
    mismatch = first_mismatch(_generate(name, size), path.read_text())
    assert mismatch is None, f"{name} -s {size}: {mismatch}"


@pytest.mark.parametrize("n", [2, 3, 4])
def test_teapot_counts(n):
    counts = entity_counts(teapot.generate(n))
    assert counts["pp"] == 64 * n * n - 8 * n
    assert counts["p"] == n * n
    assert counts["l"] == 2 and counts["f"] == 3


def test_teapot_size_one_warns_and_writes_the_scene():
    with pytest.warns(RuntimeWarning, match="a size of 1 is not supported"):
        counts = entity_counts(spd.generate("teapot", 1))
    assert counts["pp"] == 56 and counts["p"] == 1


@pytest.mark.parametrize("size", [1, 2, 3])
def test_jacks_counts(size):
    counts = entity_counts(jacks.generate(size))
    jack_count = (8 ** size - 1) // 7
    assert counts["c"] == 3 * jack_count
    assert counts["s"] == 6 * jack_count
    assert counts["c"] + counts["s"] == 9 * (8 ** size - 1) // 7


@pytest.mark.parametrize("size", [1, 2, 3])
def test_lattice_counts(size):
    counts = entity_counts(lattice.generate(size))
    assert counts["s"] == (size + 1) ** 3
    assert counts["c"] == 3 * size * (size + 1) ** 2
    assert counts["f"] == counts["s"] + counts["c"]
    assert counts["l"] == 6


@pytest.mark.parametrize("size", [1, 2])
def test_sombrero_counts(size):
    width = 32 * 2 ** (size - 1)
    counts = entity_counts(sombrero.generate(size))
    assert counts["p"] == 2 * (width - 1) ** 2


def test_sample_and_nurbtst_ignore_size():
    assert sample.generate(3) == sample.generate(1)
    assert nurbtst.generate(2) == nurbtst.generate(1)
    counts = entity_counts(sample.generate())
    assert (counts["pp"], counts["p"], counts["c"], counts["f"]) == (864, 16, 1, 5)
    assert entity_counts(nurbtst.generate())["pp"] == 1500


@pytest.mark.parametrize("module", [teapot, jacks, lattice, sombrero, sample, nurbtst])
def test_module_contract(module):
    assert isinstance(module.DEFAULT_SIZE, int) and module.DEFAULT_SIZE >= 1
    assert isinstance(module.SIZE_RULE, str) and "\n" not in module.SIZE_RULE
    assert module.__doc__ and "generate" in module.__doc__


@pytest.mark.parametrize("name", ["teapot", "jacks", "lattice", "sombrero"])
def test_size_limit(name):
    limit = spd.module(name).MAX_SIZE
    with pytest.raises(OptionError):
        spd.generate(name, limit + 1)



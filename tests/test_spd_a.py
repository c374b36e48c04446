"""The Python SPD generators balls, gears, mount, rings, tetra, tree and shells
against the NFF files made by the original C programs (shared/scenes/spd)."""

from __future__ import annotations

import math
from collections import Counter

import pytest

from raykernel.errors import OptionError
from raykernel.scene import spd

from support import SPD_DIR
TOLERANCE = 1e-4

REFERENCES = [
    ("balls", 1), ("balls", 4),
    ("gears", 1), ("gears", 4),
    ("mount", 1), ("mount", 6),
    ("rings", 1), ("rings", 7),
    ("tetra", 1), ("tetra", 6),
    ("tree", 1), ("tree", 11),
    ("shells", 1), ("shells", 5),
]
NAMES = sorted({name for name, _ in REFERENCES})


def _tokens(text: str):
    """(token, line number) for every whitespace-separated token."""
    for line_no, line in enumerate(text.splitlines(), start=1):
        for token in line.split():
            yield token, line_no


def _number(token: str):
    try:
        return float(token)
    except ValueError:
        return None


def nff_mismatch(got: str, want: str, tol: float = TOLERANCE) -> str | None:
    """None if the two NFF texts have the same tokens, numbers agreeing within
    `tol` absolute or relative (whichever allows more); else a description of
    the first difference."""
    got_tokens, want_tokens = list(_tokens(got)), list(_tokens(want))
    for index, ((g, g_line), (r, r_line)) in enumerate(zip(got_tokens, want_tokens)):
        gv, rv = _number(g), _number(r)
        if gv is None or rv is None:
            same = g == r
        else:
            same = abs(gv - rv) <= tol * max(1.0, abs(rv))
        if not same:
            return (f"token {index}: generated {g!r} (line {g_line}: {got.splitlines()[g_line - 1]!r}) "
                    f"!= reference {r!r} (line {r_line}: {want.splitlines()[r_line - 1]!r})")
    if len(got_tokens) != len(want_tokens):
        return f"generated {len(got_tokens)} tokens, reference {len(want_tokens)}"
    return None


def entity_counts(text: str) -> Counter:
    """How many lines start with each NFF keyword (s, p, c, f, l, ...)."""
    counts = Counter()
    for line in text.splitlines():
        head = line.split(maxsplit=1)[0] if line.strip() else ""
        if head and _number(head) is None:
            counts[head] += 1
    return counts


def polygon_sizes(text: str) -> Counter:
    return Counter(int(line.split()[1]) for line in text.splitlines() if line.startswith("p "))


def expected_counts(name: str, sf: int) -> dict:
    """Entity counts of scene `name` at size factor `sf`, from the SPD README rules."""
    if name == "balls":
        return {"s": sum(9 ** k for k in range(sf + 1)), "p": 1, "c": 0, "l": 3, "f": 2}
    if name == "gears":
        return {"s": 0, "p": sf ** 3 * (2 + 144) + 1, "c": 0, "l": 5, "f": sf ** 3 + 1}
    if name == "mount":
        return {"s": 4, "p": 2 * 4 ** sf, "c": 0, "l": 1, "f": 2}
    if name == "rings":
        n = 5 * sf * (sf + 1) * (2 * sf + 1)
        return {"s": n, "p": 1, "c": n, "l": 3, "f": 1 + n // 5}
    if name == "tetra":
        return {"s": 0, "p": 4 ** sf, "c": 0, "l": 1, "f": 1}
    if name == "tree":
        n = 2 ** (sf + 1) - 1
        return {"s": n, "p": 1, "c": n, "l": 7, "f": 2}
    if name == "shells":
        return {"s": 180 * 2 ** sf + 1, "p": 0, "c": 0, "l": 1, "f": 1}
    raise KeyError(name)


def _reference(name: str, sf: int) -> str:
    return (SPD_DIR / f"{name}-sf{sf}.nff").read_text()


# ---------------------------------------------------------------- the comparison helper itself

def test_mismatch_helper_accepts_tolerance_and_reports_position():
    assert nff_mismatch("s 1 2 3 0.5\n", "s 1.00001 2 3 0.5\n") is None
    assert nff_mismatch("s 1e-17 0 0 1\n", "s -2e-16 0 0 1\n") is None
    assert nff_mismatch("s 1000 0 0 1\n", "s 1000.09 0 0 1\n") is None
    message = nff_mismatch("f 1 1 1\ns 1 2 3 0.5\n", "f 1 1 1\ns 1 2.01 3 0.5\n")
    assert message is not None and "token 6" in message and "line 2" in message
    assert "2.01" in message
    assert nff_mismatch("s 1 2 3 0.5\n", "c 1 2 3 0.5\n") is not None
    assert "tokens" in nff_mismatch("s 1 2 3 0.5\n", "s 1 2 3 0.5\ns 1 2 3 0.5\n")


# ---------------------------------------------------------------- exact agreement with the C output

@pytest.mark.parametrize("name,sf", REFERENCES, ids=[f"{n}-sf{s}" for n, s in REFERENCES])
def test_matches_reference_file(name, sf):
    want = _reference(name, sf)
    got = spd.generate(name, sf)
    problem = nff_mismatch(got, want)
    assert problem is None, f"{name} -s {sf}: {problem}"


# ---------------------------------------------------------------- primitive counts at other sizes

COUNT_CASES = [("balls", 2), ("balls", 3), ("gears", 2), ("gears", 3), ("mount", 2), ("mount", 3),
               ("rings", 2), ("rings", 3), ("tetra", 2), ("tetra", 3), ("tree", 2), ("tree", 5),
               ("shells", 2), ("shells", 3)]


@pytest.mark.parametrize("name,sf", COUNT_CASES, ids=[f"{n}-sf{s}" for n, s in COUNT_CASES])
def test_primitive_counts_follow_size_rule(name, sf):
    text = spd.generate(name, sf)
    counts = entity_counts(text)
    for keyword, n in expected_counts(name, sf).items():
        assert counts[keyword] == n, f"{name} -s {sf}: {counts[keyword]} '{keyword}' lines, rule says {n}"
    assert counts["v"] == 1 and counts["b"] == 1


@pytest.mark.parametrize("name,sf", REFERENCES, ids=[f"{n}-sf{s}" for n, s in REFERENCES])
def test_count_rule_agrees_with_reference_files(name, sf):
    counts = entity_counts(_reference(name, sf))
    for keyword, n in expected_counts(name, sf).items():
        assert counts[keyword] == n


@pytest.mark.parametrize("sf", [1, 2])
def test_gear_faces_have_144_vertices(sf):
    sizes = polygon_sizes(spd.generate("gears", sf))
    assert sizes == Counter({144: 2 * sf ** 3, 4: 144 * sf ** 3 + 1})


def test_mount_and_tetra_are_triangles():
    assert set(polygon_sizes(spd.generate("mount", 3))) == {3}
    assert set(polygon_sizes(spd.generate("tetra", 3))) == {3}


# ---------------------------------------------------------------- module interface

@pytest.mark.parametrize("name", NAMES)
def test_module_interface(name):
    mod = spd.module(name)
    assert f'spd.generate("{name}", {mod.DEFAULT_SIZE})' in mod.__doc__
    assert f"(default {mod.DEFAULT_SIZE})" in mod.__doc__
    assert isinstance(mod.DEFAULT_SIZE, int) and mod.DEFAULT_SIZE >= 1
    assert isinstance(mod.SIZE_RULE, str) and mod.SIZE_RULE and "\n" not in mod.SIZE_RULE
    assert mod.MAX_SIZE >= mod.DEFAULT_SIZE
    assert spd.default_size(name) == mod.DEFAULT_SIZE


@pytest.mark.parametrize("name", NAMES)
def test_max_size_keeps_primitive_count_bounded(name):
    mod = spd.module(name)
    def total(sf):
        c = expected_counts(name, sf)
        return c["s"] + c["p"] + c["c"]
    assert total(mod.MAX_SIZE) <= 10_000_000 < total(mod.MAX_SIZE + 1)


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("bad", [0, -1, 2.0, 1.5, "3", True])
def test_bad_sizes_raise_option_error(name, bad):
    with pytest.raises(OptionError):
        spd.generate(name, bad)


@pytest.mark.parametrize("name", NAMES)
def test_size_above_max_raises_option_error(name):
    with pytest.raises(OptionError):
        spd.generate(name, spd.module(name).MAX_SIZE + 1)


def test_balls_size_zero_raises():
    with pytest.raises(OptionError):
        spd.generate("balls", 0)


def test_default_size_generates_the_default_file():
    assert spd.generate("tetra") == spd.generate("tetra", 6)




# ---------------------------------------------------------------- shared helpers

def test_shine_from_highlight_angle():
    from raykernel.scene.spd._common import shine
    assert shine(0.0) == 100000.0
    assert shine(90.0) == 1.0
    assert math.isclose(shine(37.0), 3.0827, rel_tol=1e-4)
    assert math.isclose(shine(10.0), 45.2776, rel_tol=1e-5)
    assert math.isclose(shine(6.7), 101.148, rel_tol=1e-5)


def test_clean_polygon_merges_repeated_vertices():
    from raykernel.scene.spd._common import clean_polygon
    square = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]
    assert clean_polygon(square) == [tuple(map(float, v)) for v in square]
    expected = [tuple(map(float, v)) for v in square]
    assert clean_polygon(square + [(0, 0, 1e-9)]) == expected
    assert clean_polygon([(0, 0, 0), (1, 0, 0), (1, 0, 1e-9), (1, 1, 0)]) == [
        (0.0, 0.0, 0.0), (1.0, 0.0, 1e-9), (1.0, 1.0, 0.0)]
    assert clean_polygon([(0, 0, 0), (0, 0, 0), (1, 0, 0)]) is None


def test_mount_hash_uses_64_bit_shifts():
    from raykernel.scene.spd.mount import hash_rand
    assert hash_rand(1, 0, 6) == 2
    assert hash_rand(0, 1, 6) == 1 << 9
    assert hash_rand(3, 0, 8) == 0x8000
    assert all(0 <= hash_rand(a, b, sf) <= 0xFFFF for a in range(0, 64, 7) for b in range(0, 64, 5)
               for sf in range(1, 12))


def test_gauss_rand_is_a_deterministic_normal_deviate():
    from raykernel.scene.spd._common import gauss_rand
    values = [gauss_rand(seed) for seed in range(21, 21 + 4000)]
    assert gauss_rand(21) == values[0]
    mean = sum(values) / len(values)
    var = sum((v - mean) ** 2 for v in values) / len(values)
    assert abs(mean) < 0.1 and 0.8 < var < 1.2

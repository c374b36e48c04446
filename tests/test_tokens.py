"""The compiled token scan against Python: str.split() for the tokens, float() for the numbers."""

from __future__ import annotations

import random
import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from raykernel.scene import tokens


def python_reading(token: str):
    """float(token), or None where Python refuses it."""
    try:
        return float(token)
    except ValueError:
        return None


def check(text: str) -> tuple[int, int]:
    """The scan of `text` agrees with Python; returns how many tokens it read as numbers and as OTHER."""
    values, kinds = tokens.scan(text.encode("ascii"))
    words = text.split()
    assert len(kinds) == len(words)
    counted = [0, 0]
    for value, kind, word in zip(values.tolist(), kinds.tolist(), words):
        if word[0].isalpha():
            assert kind == tokens.WORD, word
        elif kind == tokens.NUMBER:
            expected = python_reading(word)
            assert expected is not None, word
            # bit for bit: the sign of a zero included
            assert struct.pack("<d", value) == struct.pack("<d", expected), (word, value, expected)
            counted[0] += 1
        else:
            assert kind == tokens.OTHER, word
            counted[1] += 1
    return counted[0], counted[1]


def test_edge_tokens():
    read = {"1": 1.0, "-2.5": -2.5, "+.5": 0.5, "5.": 5.0, "1e3": 1000.0, "1E+3": 1000.0, "-0": -0.0,
            "0.000": 0.0, "-0e5": -0.0, "7e22": 7e22, "1e-22": 1e-22, "9007199254740992": 2.0 ** 53,
            "000000000000000000000000001": 1.0, "0.408248": 0.408248, "-0.9375": -0.9375}
    left = ["1e", "1e+", ".", "-", "+-1", "1..2", "1.2.3", "1e2.5", "0x10", "1-2", "3.14159265358979323846",
            "9007199254740993", "1e23", "1e-23", "1.5e-30", "2e400", "1e99999", "1,5", "1/2", "--1"]
    n, other = check(" ".join(list(read) + left))
    assert (n, other) == (len(read), len(left))
    values, kinds = tokens.scan(" ".join(read).encode())
    assert values.tolist() == list(read.values())


def test_separators_as_str_split():
    text = "p\t3\n1 2\x0b3\x0c\r4\x1c5\x1d6\x1e7\x1f8   9\n\n"
    assert check(text) == (10, 0)
    assert check("") == (0, 0)
    assert check(" \n\t ") == (0, 0)
    assert check("x") == (0, 0)


def test_printed_doubles():
    """Numbers as programs print them: %g, %f, %e and repr of doubles across magnitudes."""
    rng = random.Random(5)
    words = []
    for _ in range(20000):
        x = rng.choice([-1, 1]) * rng.random() * 10.0 ** rng.randint(-30, 30)
        fmt = rng.choice(["%g", "%.6f", "%.3e", "%.10g", "%.15g", "%.17g", "repr"])
        words.append(repr(x) if fmt == "repr" else fmt % x)
    n, other = check(" ".join(words))
    assert n > 10000        # most take the compiled path; the rest (17 digits, 1e-30) are still Python's
    # what NFF files hold, %g of numbers near 1, all of it
    assert check(" ".join("%g" % (rng.random() * 100 - 50) for _ in range(5000))) == (5000, 0)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.text(alphabet="0123456789.eE+-", min_size=1, max_size=24), min_size=1, max_size=40))
def test_any_digit_strings(words):
    check(" ".join(words))


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 2 ** 60), st.integers(-30, 30), st.booleans())
def test_mantissa_and_exponent(mantissa, exponent, negative):
    word = f"{'-' if negative else ''}{mantissa}e{exponent}"
    n, other = check(word)
    if mantissa <= 2 ** 53 and (mantissa == 0 or -22 <= exponent <= 22):
        assert n == 1
    else:
        assert other == 1


def test_nonfinite_words():
    values, kinds = tokens.scan(b"nan inf -inf Infinity")
    # words to the reader (its keyword lookup refuses them), OTHER when signed: never a number
    assert kinds.tolist() == [tokens.WORD, tokens.WORD, tokens.OTHER, tokens.WORD]


@pytest.mark.parametrize("size", [1, 2, 3, 1000])
def test_buffer_bounds(size):
    """Texts of one-character tokens fill the scan's arrays to the last entry."""
    text = " ".join(["7"] * size)
    values, kinds = tokens.scan(text.encode())
    assert len(kinds) == size and np.all(values == 7.0) and np.all(kinds == tokens.NUMBER)

"""The tokens of an ASCII text and their numbers, read by one compiled pass.

    values, kinds = scan(text.encode("ascii"))
    # one entry per token of text.split(): kinds[i] is NUMBER (values[i] is float(token)),
    # WORD (it begins with a letter) or OTHER (ask Python's float(), which may refuse it)

A number is read here only when the answer is certainly Python's: an optional sign,
digits with at most one point, an optional exponent, and at most 2**53 as an integer
once the point is dropped, with a power of ten within 1e-22..1e22. Both factors are
then exact doubles, so one multiply or divide rounds the exact decimal value once,
correctly, as float() does (Clinger's fast path). Anything else is OTHER.
"""

from __future__ import annotations

import numpy as np

from ..geometry.config import njit

NUMBER, WORD, OTHER = 0, 1, 2

# the separators of Python's str.split() among ASCII characters
SPACE = np.zeros(256, np.bool_)
SPACE[[9, 10, 11, 12, 13, 28, 29, 30, 31, 32]] = True

_POWERS = np.array([10.0 ** k for k in range(23)])     # each exact in a double
_EXACT = 2 ** 53


def scan(data: bytes) -> tuple[np.ndarray, np.ndarray]:
    """The value and the kind of every token of `data` (ASCII bytes, split as str.split()
    splits), as described above."""
    chars = np.frombuffer(data, np.uint8)
    most = len(chars) // 2 + 1
    values, kinds = np.empty(most), np.empty(most, np.int8)
    n = _scan(chars, SPACE, _POWERS, values, kinds)
    return values[:n], kinds[:n]


@njit
def _scan(chars, space, powers, values, kinds):
    n = 0
    i = 0
    size = chars.shape[0]
    while i < size:
        if space[chars[i]]:
            i += 1
            continue
        start = i
        while i < size and not space[chars[i]]:
            i += 1
        kinds[n], values[n] = _token(chars, start, i, powers)
        n += 1
    return n


@njit(inline="always")
def _token(chars, i, end, powers):
    """(kind, value) of the token chars[i:end]."""
    c = chars[i]
    if (c >= 97 and c <= 122) or (c >= 65 and c <= 90):
        return WORD, 0.0
    negative = c == 45      # '-'
    if c == 43 or c == 45:
        i += 1
    mantissa = 0
    digits = 0
    scale = 0               # the power of ten the point moves the digits by
    point = False
    while i < end:
        c = chars[i]
        if c >= 48 and c <= 57:
            mantissa = mantissa * 10 + (c - 48)
            if mantissa > _EXACT:
                return OTHER, 0.0
            digits += 1
            if point:
                scale -= 1
        elif c == 46 and not point:     # '.'
            point = True
        else:
            break
        i += 1
    if digits == 0:
        return OTHER, 0.0
    if i < end:
        if chars[i] != 101 and chars[i] != 69:      # 'e', 'E'
            return OTHER, 0.0
        i += 1
        exp_negative = False
        if i < end and (chars[i] == 43 or chars[i] == 45):
            exp_negative = chars[i] == 45
            i += 1
        if i == end:
            return OTHER, 0.0
        exponent = 0
        while i < end:
            c = chars[i]
            if c < 48 or c > 57 or exponent > 1000:
                return OTHER, 0.0
            exponent = exponent * 10 + (c - 48)
            i += 1
        scale += -exponent if exp_negative else exponent
    if mantissa == 0:
        value = 0.0
    elif scale < -22 or scale > 22:
        return OTHER, 0.0
    elif scale < 0:
        value = mantissa / powers[-scale]
    else:
        value = mantissa * powers[scale]
    return NUMBER, -value if negative else value

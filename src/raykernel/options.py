"""Checks of the options a user gives, worded the same everywhere.

    leaf = number(leaf, "octree leaf", 1, 1 << 30, integer=True)     # OptionError naming it otherwise
    shading = choice(shading, "shading", ("whitted", "hall", "heckbert"))
"""

from __future__ import annotations

import math

import numpy as np

from .errors import OptionError


def number(value, name: str, lo, hi, integer: bool = False, above: bool = False):
    """value if it is a finite number (an integer if asked) in [lo, hi] ((lo, hi] if `above`),
    else an OptionError naming `name`; booleans are not numbers here."""
    kinds = (int, np.integer) if integer else (int, float, np.integer, np.floating)
    what = "an integer" if integer else "a number"
    ok = not isinstance(value, (bool, np.bool_)) and isinstance(value, kinds) and math.isfinite(value) and \
        (lo < value if above else lo <= value) and value <= hi
    if not ok:
        raise OptionError(f"{name} must be {what} in {'(' if above else '['}{lo}, {hi}], got {value!r}")
    return value


def choice(value, name: str, choices):
    """value if it is one of `choices`, else an OptionError listing them."""
    if value not in choices:
        raise OptionError(f"unknown {name} {value!r}; choose from {', '.join(map(str, choices))}")
    return value

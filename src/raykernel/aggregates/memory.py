"""One memory budget for every build and every lazy refinement.

    limit = memory_limit()                  # bytes: the default, a safe share of this machine
    limit = parse_size("8G")                # --max-memory / max_memory= in bytes, K, M, G or T (1024s)
    check(nbytes, limit, "octree of group root", "lower depth or set budget")
    a = grown(a, rows, used)                # a builder's growing array, doubled (kernels and Python alike)

A build whose arrays would pass the limit stops with one MemoryBudgetError
that names the structure, the memory it needed and the parameter to change,
before it asks the system for that memory: without a limit a deep octree
with no reference budget or an eager ray classification with a huge
budget_mb would take the machine's memory, or end in a MemoryError raised
deep inside a builder.
"""

from __future__ import annotations

import functools
import os
import re

try:
    import resource
except ImportError:     # not on Windows
    resource = None

import numpy as np

from ..errors import OptionError, RayKernelError
from ..geometry.config import njit

SAFE_SHARE = 0.5            # of physical memory (or of the address-space limit, if lower)


class MemoryBudgetError(RayKernelError):
    """A build or refinement would need more memory than the budget allows."""


@functools.cache
def physical_memory() -> int:
    """This machine's memory in bytes, or the address-space limit if lower."""
    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        total = 8 << 30
    if resource is not None:
        try:
            soft, _ = resource.getrlimit(resource.RLIMIT_AS)
            if soft != resource.RLIM_INFINITY and soft > 0:
                total = min(total, soft)
        except (ValueError, OSError):
            pass
    return int(total)


def memory_limit(max_memory=None) -> int:
    """The budget in bytes: max_memory (bytes, or a size such as "8G") or SAFE_SHARE of the machine."""
    if max_memory is None:
        return int(SAFE_SHARE * physical_memory())
    if isinstance(max_memory, str):
        return parse_size(max_memory)
    if isinstance(max_memory, bool) or not isinstance(max_memory, (int, float)) or not max_memory > 0:
        raise OptionError(f"max_memory must be a positive number of bytes or a size such as '8G', got {max_memory!r}")
    return int(max_memory)


_SIZE = re.compile(r"^\s*(\d+(?:\.\d*)?|\.\d+)\s*([kmgt]?)i?b?\s*$", re.I)


def parse_size(text: str) -> int:
    """'512M', '8G', '1.5g', '123456' (bytes) -> bytes; units are powers of 1024."""
    m = _SIZE.match(text)
    if not m or float(m.group(1)) <= 0:
        raise OptionError(f"--max-memory: expected a size such as 512M, 8G or a number of bytes, got {text!r}")
    scale = 1024 ** " kmgt".index(m.group(2).lower() or " ")
    return int(float(m.group(1)) * scale)


def describe_bytes(n: float) -> str:
    for unit, scale in (("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if n >= scale:
            return f"{n / scale:.1f} {unit}"
    return f"{int(n)} bytes"


def check(nbytes: float, limit: int, what: str, hint: str) -> None:
    """MemoryBudgetError unless nbytes fit in limit."""
    if nbytes > limit:
        over_budget(limit, what, hint, nbytes)


def over_budget(limit: int, what: str, hint: str, nbytes: float | None = None):
    """Raise the MemoryBudgetError for `what`, which needs nbytes (None: more than limit)."""
    need = f"at least {describe_bytes(nbytes)}, more than" if nbytes is not None else "more than"
    raise MemoryBudgetError(f"{what} needs {need} the memory budget of {describe_bytes(limit)}; {hint}, or "
                            f"raise the budget with --max-memory (max_memory=)")


@njit
def grown(a, rows, used):
    """a if it has `rows` rows, else a new array of twice its rows (or `rows`, if more), its first
    `used` rows a's: how every builder grows its arrays."""
    if rows <= a.shape[0]:
        return a
    out = np.empty((max(rows, 2 * a.shape[0]),) + a.shape[1:], a.dtype)
    out[:used] = a[:used]
    return out

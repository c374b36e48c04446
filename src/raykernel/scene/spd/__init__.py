"""Eric Haines's Standard Procedural Databases, generated in Python.

    from raykernel.scene import spd
    text = spd.generate("balls", size=4)     # NFF text, as `balls -s 4` prints it
    spd.NAMES                                # the 13 generators

Each generator lives in its own module `raykernel.scene.spd.<name>` with
`DEFAULT_SIZE`, `SIZE_RULE` (how the size factor sets the primitive count)
and `generate(size) -> str`.
"""

from __future__ import annotations

import importlib

from ...errors import OptionError

NAMES = ("balls", "gears", "mount", "rings", "teapot", "tetra", "tree",
         "jacks", "lattice", "shells", "sombrero", "sample", "nurbtst")


def module(name: str):
    if name not in NAMES:
        raise OptionError(f"unknown SPD generator {name!r}; choose one of: {', '.join(NAMES)}")
    return importlib.import_module(f"{__name__}.{name}")


def default_size(name: str) -> int:
    return module(name).DEFAULT_SIZE


def generate(name: str, size: int | None = None) -> str:
    """NFF text of SPD scene `name` at size factor `size` (None: its default)."""
    mod = module(name)
    if size is None:
        size = mod.DEFAULT_SIZE
    if isinstance(size, bool) or not isinstance(size, int) or size < 1:
        raise OptionError(f"SPD size factor for {name} must be a positive integer, got {size!r}")
    limit = getattr(mod, "MAX_SIZE", None)
    if limit is not None and size > limit:
        raise OptionError(f"SPD size factor for {name} must be at most {limit} "
                          f"(larger sizes make too many primitives), got {size}")
    return mod.generate(size)

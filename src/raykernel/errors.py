"""Errors a user can act on: each says where (file, line, parameter) and what.

    raise SceneError("expected 3 numbers after 'from'", path="a.nff", line=4)
    # -> a.nff:4: expected 3 numbers after 'from'
"""

from __future__ import annotations


class RayKernelError(Exception):
    """Base of the errors raykernel raises on purpose; the CLI prints them
    as one line instead of a traceback."""


class SceneError(RayKernelError):
    """A scene (file, JSON or Python model) is not valid."""

    def __init__(self, message: str, path: str | None = None, line: int | None = None):
        self.message = message
        self.path = str(path) if path is not None else None
        self.line = line
        where = ""
        if self.path is not None:
            where = f"{self.path}:{line}: " if line is not None else f"{self.path}: "
        elif line is not None:
            where = f"line {line}: "
        super().__init__(where + message)


class OptionError(RayKernelError):
    """A render option or accelerator spec is not valid."""


class RayKernelWarning(RuntimeWarning):
    """A warning raykernel gives on purpose, saying what it did anyway and why (numpy's own
    RuntimeWarnings are bugs of ours: tests/fuzzing.py tells the two apart)."""

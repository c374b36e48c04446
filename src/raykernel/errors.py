"""Errors a user can act on: each says where (file, line, parameter) and what.

    raise SceneError("expected 3 numbers after 'from'", path="a.nff", line=4)
    # -> a.nff:4: expected 3 numbers after 'from'
"""

from __future__ import annotations


class RayKernelError(Exception):
    """Base of the errors raykernel raises on purpose.

    The command line prints them as one line instead of a traceback.
    """


class SceneError(RayKernelError):
    """A scene (file, JSON or Python model) is not valid.

    The message starts with where: ``path:line: message``, ``path: message`` or
    ``line N: message``.

    Parameters
    ----------
    message : str
        What is wrong.
    path : str or path-like, optional
        The file (or other source) of the scene.
    line : int, optional
        The line in it.

    Attributes
    ----------
    message : str
        What is wrong, without where.
    path : str or None
        The file, as a string.
    line : int or None
        The line.

    Examples
    --------
    >>> str(SceneError("expected 3 numbers after 'from'", path="a.nff", line=4))
    "a.nff:4: expected 3 numbers after 'from'"
    """

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

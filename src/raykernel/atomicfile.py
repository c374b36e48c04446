"""Writing files atomically: a reader never sees half a file, and a failed or
interrupted write leaves the old file (if any) untouched.

    write_text("scene.nff", text)
    with atomic_write("image.png", "wb") as f: f.write(data)

Problems (missing directory, no permission, disk full) are SceneErrors
naming the path. A new file gets the usual permissions (0666 less the
umask); a replaced file keeps its own.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

from .errors import SceneError


def check_output_directory(path) -> Path:
    """`path` as a Path whose directory exists; otherwise a SceneError naming it."""
    path = Path(path)
    directory = path.parent if str(path.parent) else Path(".")
    if not directory.exists():
        raise SceneError(f"cannot write: directory {directory} does not exist", path=str(path))
    if not directory.is_dir():
        raise SceneError(f"cannot write: {directory} is not a directory", path=str(path))
    if path.is_dir():
        raise SceneError("cannot write: it is a directory", path=str(path))
    return path


def _new_file_mode(path: Path) -> int:
    if path.exists():
        return path.stat().st_mode & 0o7777
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


@contextlib.contextmanager
def atomic_write(path, mode: str = "w"):
    """Yield a file object for a temporary file beside `path`; on success it
    is flushed to disk and renamed to `path`, on any error it is removed."""
    path = check_output_directory(path)
    try:
        file_mode = _new_file_mode(path)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as e:
        raise SceneError(f"cannot write: {e.strerror or e}", path=str(path)) from None
    try:
        with os.fdopen(fd, mode, **({} if "b" in mode else {"encoding": "utf-8"})) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, file_mode)
        os.replace(tmp, path)
    except BaseException as e:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(e, OSError):
            raise SceneError(f"cannot write: {e.strerror or e}", path=str(path)) from None
        raise


def write_text(path, text: str) -> Path:
    with atomic_write(path) as f:
        f.write(text)
    return Path(path)


def write_bytes(path, data: bytes) -> Path:
    with atomic_write(path, "wb") as f:
        f.write(data)
    return Path(path)

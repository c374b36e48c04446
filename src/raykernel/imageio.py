"""Writing images and other outputs atomically: a reader never sees half a file.

    save_png(image, "out.png")          # float RGB in [0, 1], clamped
    with atomic_write("stats.json") as f: f.write(text)
"""

from __future__ import annotations

import base64
import contextlib
import io
import os
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image

from .errors import RayKernelError


@contextlib.contextmanager
def atomic_write(path, mode: str = "w"):
    """Write to a temporary file beside `path`, then rename it into place;
    on any error (or Ctrl-C) the temporary file is removed and `path` is untouched."""
    path = Path(path)
    directory = path.parent if str(path.parent) else Path(".")
    if not directory.is_dir():
        raise RayKernelError(f"{path}: directory {directory} does not exist")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=directory)
    try:
        with os.fdopen(fd, mode) as f:
            yield f
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def to_uint8(image: np.ndarray) -> np.ndarray:
    return (np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def _png_bytes(image: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(to_uint8(image), "RGB").save(buf, format="PNG")
    return buf.getvalue()


def save_png(image: np.ndarray, path) -> None:
    data = _png_bytes(image)
    with atomic_write(path, "wb") as f:
        f.write(data)


def png_data_uri(image: np.ndarray) -> str:
    return "data:image/png;base64," + base64.b64encode(_png_bytes(image)).decode("ascii")

"""Images out: PNG files (written atomically) and data URIs for HTML.

    save_png(image, "out.png")          # float RGB in [0, 1], clamped
    png_data_uri(image)                 # "data:image/png;base64,..."
"""

from __future__ import annotations

import base64
import io

import numpy as np
from PIL import Image

from .atomicfile import write_bytes



def to_uint8(image: np.ndarray) -> np.ndarray:
    return (np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def _png_bytes(image: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(to_uint8(image), "RGB").save(buf, format="PNG")
    return buf.getvalue()


def save_png(image: np.ndarray, path) -> None:
    write_bytes(path, _png_bytes(image))


def png_data_uri(image: np.ndarray) -> str:
    return "data:image/png;base64," + base64.b64encode(_png_bytes(image)).decode("ascii")

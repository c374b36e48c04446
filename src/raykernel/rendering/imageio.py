"""Images out, in the format the file name asks for, written atomically; data URIs for HTML.

    save_image(image, "out.png")        # .png .jpg .jpeg .tif .tiff .webp: 8-bit RGB, clamped to [0, 1]
    save_image(image, "out.exr")        # .npy .pfm .exr: the float image as rendered (HDR)
    png_data_uri(image)                 # "data:image/png;base64,..."

An unknown suffix is an OptionError that lists the formats; .exr needs the
OpenEXR package (`pip install raykernel[exr]`).
"""

from __future__ import annotations

import base64
import io
from pathlib import Path

import numpy as np
from PIL import Image

from ..atomicfile import write_bytes
from ..errors import OptionError

PILLOW_FORMATS = {".png": "PNG", ".jpg": "JPEG", ".jpeg": "JPEG", ".tif": "TIFF", ".tiff": "TIFF", ".webp": "WEBP"}
FLOAT_FORMATS = (".npy", ".pfm", ".exr")
FORMATS = tuple(PILLOW_FORMATS) + FLOAT_FORMATS


def to_uint8(image: np.ndarray) -> np.ndarray:
    if image.dtype == np.uint8:
        return image
    return (np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def image_format(path) -> str:
    """The suffix of `path` if it names a format we write, else an OptionError listing them."""
    suffix = Path(path).suffix.lower()
    if suffix not in FORMATS:
        raise OptionError(f"{path}: cannot write images as {suffix or '(no suffix)'!r}; use one of "
                          f"{', '.join(FORMATS)}")
    return suffix


def _pillow_bytes(image: np.ndarray, fmt: str) -> bytes:
    buf = io.BytesIO()
    options = {"quality": 95} if fmt in ("JPEG", "WEBP") else {}
    Image.fromarray(to_uint8(image), "RGB").save(buf, format=fmt, **options)
    return buf.getvalue()


def _pfm_bytes(image: np.ndarray) -> bytes:
    # Portable Float Map: colour, little-endian (negative scale), rows bottom to top
    h, w = image.shape[:2]
    rows = np.ascontiguousarray(image[::-1], dtype="<f4")
    return f"PF\n{w} {h}\n-1.0\n".encode("ascii") + rows.tobytes()


def _npy_bytes(image: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.ascontiguousarray(image))
    return buf.getvalue()


def _exr_bytes(image: np.ndarray, path) -> bytes:
    try:
        import OpenEXR
    except ImportError:
        raise OptionError(f"{path}: writing .exr needs the OpenEXR package: pip install 'raykernel[exr]'") from None
    import tempfile
    rgb = np.ascontiguousarray(image, dtype=np.float32)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with tempfile.TemporaryDirectory() as tmp:
        name = str(Path(tmp) / "image.exr")
        with OpenEXR.File(header, {"RGB": rgb}) as f:
            f.write(name)
        return Path(name).read_bytes()


def save_image(image: np.ndarray, path) -> None:
    """Write `image` ((h, w, 3) float RGB) to `path` in the format its suffix names."""
    suffix = image_format(path)
    if suffix in PILLOW_FORMATS:
        data = _pillow_bytes(image, PILLOW_FORMATS[suffix])
    elif suffix == ".pfm":
        data = _pfm_bytes(image)
    elif suffix == ".npy":
        data = _npy_bytes(image)
    else:
        data = _exr_bytes(image, path)
    write_bytes(path, data)


def save_png(image: np.ndarray, path) -> None:
    write_bytes(path, _pillow_bytes(image, "PNG"))


def png_data_uri(image: np.ndarray) -> str:
    return "data:image/png;base64," + base64.b64encode(_pillow_bytes(image, "PNG")).decode("ascii")

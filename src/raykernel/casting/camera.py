"""Rays of a pinhole camera, shaped as an image, for RayScene queries.

    origins, directions = camera_rays(eye=(0, -5, 2), look_at=(0, 0, 0), fov=60, width=320, height=240)
    depth = scene.intersect(origins, directions).t          # (240, 320)

Pixel (row i from the top, column j from the left) looks through its
centre; `fov` is the horizontal field of view in degrees, the vertical one
follows from the aspect ratio (square pixels), as in Open3D's
`create_rays_pinhole`. Directions are unit vectors, so t is the distance.
"""

from __future__ import annotations

import math

import numpy as np

from .rayinput import RayInputError


def camera_rays(eye, look_at, up=(0.0, 0.0, 1.0), fov: float = 60.0, width: int = 640, height: int = 480):
    """Origins and unit directions of a pinhole camera's rays, shaped as an image.

    Pixel (row i from the top, column j from the left) looks through its centre. The
    directions are unit vectors, so a query's t is the distance.

    Parameters
    ----------
    eye : (3,) array_like
        The camera's position.
    look_at : (3,) array_like
        The point it looks at, different from `eye`.
    up : (3,) array_like, default (0, 0, 1)
        The up direction, not parallel to the viewing direction.
    fov : float, default 60
        The horizontal field of view in degrees, in (0, 180); the vertical one follows from the
        aspect ratio (square pixels), as in Open3D's ``create_rays_pinhole``.
    width : int, default 640
        The image's width in pixels.
    height : int, default 480
        The image's height in pixels.

    Returns
    -------
    origins : (height, width, 3) float64 array
        Every ray's origin: `eye`.
    directions : (height, width, 3) float64 array
        Unit directions through the pixels' centres.

    Raises
    ------
    RayInputError
        An argument is not valid (the message names it).

    Examples
    --------
    >>> origins, directions = camera_rays(eye=(0, -5, 2), look_at=(0, 0, 0), fov=60, width=320, height=240)
    >>> depth = scene.intersect(origins, directions).t          # (240, 320)
    """
    eye = np.asarray(eye, np.float64).reshape(3)
    look_at = np.asarray(look_at, np.float64).reshape(3)
    up = np.asarray(up, np.float64).reshape(3)
    for name, value in (("width", width), ("height", height)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise RayInputError(f"{name} must be a positive integer, got {value!r}")
    if not 0.0 < fov < 180.0:
        raise RayInputError(f"fov must be in (0, 180) degrees, got {fov!r}")
    if not (np.all(np.isfinite(eye)) and np.all(np.isfinite(look_at)) and np.all(np.isfinite(up))):
        raise RayInputError("eye, look_at and up must be finite")
    forward = look_at - eye
    if not np.any(forward):
        raise RayInputError("look_at must differ from eye")
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, up)
    if np.linalg.norm(right) <= 1e-12 * np.linalg.norm(up):
        raise RayInputError("up must not be parallel to the viewing direction")
    right /= np.linalg.norm(right)
    true_up = np.cross(right, forward)
    half = math.tan(math.radians(fov) / 2.0)
    x = (np.arange(width) + 0.5) / width * 2.0 - 1.0             # -1 .. 1 across the image
    y = 1.0 - (np.arange(height) + 0.5) / height * 2.0           # top row first
    d = (forward + half * x[None, :, None] * right + half * (height / width) * y[:, None, None] * true_up)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return np.broadcast_to(eye, d.shape).copy(), d

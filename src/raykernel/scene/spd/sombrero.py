"""SPD "sombrero": a height field of the damped ripple cos(2 pi r) e^-r,
written to NFF as matte red triangles; one light.

    from raykernel.scene import spd
    text = spd.generate("sombrero", 1)      # NFF text, same as `sombrero -s 1`

Size factor SF (default 1): a w x w grid of heights, w = 32 * 2^(SF-1)
(32, 64, 128, ...), sampled at x, z = -4, -4 + 8/w, ..., 4 - 8/w and stretched
over the square -4..4; every cell becomes two triangles, 2 (w-1)^2 in all
(sf1: 1922). Heights are rounded to single precision, as the SPD stores them.
"""

from __future__ import annotations

import numpy as np

from ..nffwriter import NffWriter
from ._common import SKY_BLUE, material

DEFAULT_SIZE = 1
SIZE_RULE = "2*(w-1)^2 triangles for a w x w height field, w = 32*2^(SF-1)"
MAX_SIZE = 7

#: The SPD's value of 2 pi for the ripple (a truncated pi).
TWO_PI = 2.0 * 3.14159265358
#: Extent of the field: x and z from -4 to 4, heights offset to y = -3.
LOW, HIGH, BASE = -4.0, 4.0, -3.0


def heights(width: int) -> np.ndarray:
    """Single-precision heights on a width x width grid; rows run along z, columns along x."""
    step = (HIGH - LOW) / width
    coord = LOW + step * np.arange(width)
    r = np.sqrt(coord[None, :] ** 2 + coord[:, None] ** 2)
    return (3.0 * np.cos(TWO_PI * r) * np.exp(-1.0 * r) / 3.0).astype(np.float32)


def row_triangles(width: int):
    """Per row of cells (along z), the triangles of the height field in SPD
    order, shape (2 (w-1), 3, 3): for each cell (i, j) the triangles
    (i,j) (i+1,j+1) (i,j+1) and (i,j) (i+1,j) (i+1,j+1), i along z, j along x."""
    h = heights(width).astype(float)
    delta = (HIGH - LOW) / (width - 1)
    k = np.arange(width)
    x = LOW + k * delta
    z = LOW + k * delta
    for i in range(width - 1):
        near = np.stack([x, BASE + h[i], np.full(width, z[i])], axis=-1)
        far = np.stack([x, BASE + h[i + 1], np.full(width, z[i + 1])], axis=-1)
        tris = np.stack([np.stack([near[:-1], far[1:], near[1:]], axis=1),
                         np.stack([near[:-1], far[:-1], far[1:]], axis=1)], axis=1)
        yield tris.reshape(-1, 3, 3)


def generate(size: int = DEFAULT_SIZE) -> str:
    """NFF text of the sombrero scene at size factor `size`."""
    width = 32 * 2 ** (size - 1)
    w = NffWriter()
    w.background(SKY_BLUE)
    w.view((0.0, 5.0, -8.0), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 40.0, 0.01, 512)
    w.light((10.0, 10.0, -10.0))
    material(w, (1.0, 0.1, 0.1), kd=0.8, ks=0.0, highlight=40.0, ior=1.0)
    for tris in row_triangles(width):
        for tri in tris.tolist():
            w.polygon(tri)
    return w.text()

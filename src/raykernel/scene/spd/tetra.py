"""SPD "tetra": a Sierpinski tetrahedral pyramid, the scene of Glassner's and
Kay & Kajiya's space-subdivision papers. One light.

    from raykernel.scene import spd
    text = spd.generate("tetra", 6)      # NFF text, same as `tetra -s 6`

Size factor SF (default 6): 4^(SF-1) tetrahedra of 4 triangles each, i.e.
4^SF triangles (sf 6: 4096).
"""

from __future__ import annotations

import numpy as np

from ..nffwriter import NffWriter
from ._common import SKY_BLUE, material

DEFAULT_SIZE = 6
SIZE_RULE = "4^SF triangles (4^(SF-1) tetrahedra)"
MAX_SIZE = 11

#: The four cube corners (x, y, z in {-1, 1} with x*y*z = 1) that make a
#: tetrahedron, in the order the SPD visits them.
CORNERS = np.array([(x, y, z) for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (-1.0, 1.0)
                    if x * y * z == 1.0])
#: Corner indices of the four faces, counter-clockwise from outside.
FACES = np.array([(0, 1, 2), (3, 2, 1), (2, 3, 0), (1, 0, 3)])


def triangles(size: int) -> np.ndarray:
    """All triangles, shape (4^size, 3, 3), in the SPD's depth-first order."""
    centers = np.zeros((1, 3))
    half = 1.0
    for _ in range(size - 1):
        half /= 2.0
        centers = (centers[:, None, :] + CORNERS[None, :, :] * half).reshape(-1, 3)
    corners = centers[:, None, :] + CORNERS[None, :, :] * half
    return corners[:, FACES].reshape(-1, 3, 3)


def generate(size: int) -> str:
    w = NffWriter()
    w.background(SKY_BLUE)
    w.view((1.022846, -3.177154, -2.174512), (-0.004103, -0.004103, 0.216539),
           (-0.816497, -0.816497, 0.816497), 45.0, 1.0, 512)
    w.light((2.0, -18.0, -5.0))
    material(w, (1.0, 0.2, 0.2), kd=1.0, ks=0.0)
    for triangle in triangles(size).tolist():
        w.polygon(triangle)
    return w.text()

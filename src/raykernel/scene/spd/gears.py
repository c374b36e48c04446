"""SPD "gears": an SF x SF x SF stack of intermeshing 36-tooth gears over a
reflective floor; each gear face is one concave 144-vertex polygon, some gears
are transmissive. Five lights.

    from raykernel.scene import spd
    text = spd.generate("gears", 4)      # NFF text, same as `gears -s 4`

Size factor SF (default 4): SF^3 gears, each 2 face polygons of 144 vertices
and 144 side quads, plus 1 floor quad (sf 4: 9345 polygons).
"""

from __future__ import annotations

import numpy as np

from ..nffwriter import NffWriter
from ._common import PI, SKY_BLUE, material, polygon

DEFAULT_SIZE = 4
SIZE_RULE = "SF^3 gears, each 2 faces of 144 vertices and 144 side quads, plus 1 floor quad"
MAX_SIZE = 40

TEETH = 36
OUTER_EDGE_RATIO = 0.995
INNER_EDGE_RATIO = 0.9
EDGE_DIFF = 1.0 - INNER_EDGE_RATIO
DEPTH_RATIO = 0.1

#: Where the four corners of a tooth sit, in fractions of the tooth angle,
#: and whether each lies on the outer (True) or inner radius.
_TOOTH_CORNERS = ((-0.19, True), (0.19, True), (0.3, False), (0.7, False))


def _face(center, offset_angle: float, outer: float, inner: float, z: float, sign: float) -> np.ndarray:
    """The 144 vertices of one gear face at height `z` (relative to the
    centre), going around counter-clockwise (sign 1) or clockwise (sign -1)."""
    tooth = sign * 2.0 * PI / TEETH
    teeth = np.arange(TEETH, dtype=float)
    gear_angles = offset_angle + sign * (2.0 * PI * teeth / TEETH)
    fractions = np.array([f for f, _ in _TOOTH_CORNERS])
    radii = np.array([outer if on_rim else inner for _, on_rim in _TOOTH_CORNERS])
    angles = (gear_angles[:, None] + fractions[None, :] * tooth).ravel()
    r = np.tile(radii, TEETH)
    return np.column_stack([r * np.cos(angles) + center[0],
                            r * np.sin(angles) + center[1],
                            np.full(angles.shape, z + center[2])])


def _gear(w: NffWriter, center, offset_angle: float, outer: float, inner: float, thickness: float):
    top = _face(center, offset_angle, outer, inner, 0.0, 1.0)
    polygon(w, top)
    below = top.copy()
    below[:, 2] -= thickness
    nxt = np.roll(np.arange(len(top)), -1)
    sides = np.stack([top, below, below[nxt], top[nxt]], axis=1)
    for quad in sides:
        polygon(w, quad)
    polygon(w, _face(center, offset_angle, outer, inner, -thickness, -1.0))


def _fraction(x: float) -> float:
    return x - int(x)


def _gear_color(ix: int, iy: int, iz: int):
    color = (0.01 + _fraction((ix * 3 + iy * 2 + iz + 1) * 5.0 / 7.0),
             0.01 + _fraction((iy * 3 + iz * 2 + ix + 1) * 3.0 / 7.0),
             0.01 + _fraction((iz * 3 + ix * 2 + iy + 1) * 2.0 / 7.0))
    brightest = max(color)
    return tuple(c / brightest for c in color)


def generate(size: int) -> str:
    w = NffWriter()
    w.background(SKY_BLUE)
    w.view((-1.1, -2.1, 2.6), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 45.0, 1.0, 512)
    for light in ((2.0, 4.0, 4.0), (-2.0, 4.0, 3.0), (2.0, -2.5, 2.5), (-1.0, -4.0, 2.0),
                  (-1.111, -2.121, 2.626)):
        w.light(light)

    material(w, (1.0, 0.85, 0.7), kd=0.3, ks=0.6, highlight=37.0)
    polygon(w, [(2.0, 2.0, 0.0), (-2.0, 2.0, 0.0), (-2.0, -2.0, 0.0), (2.0, -2.0, 0.0)])

    outer_radius = 1.0 / (size - (size - 1) * EDGE_DIFF / 2.0)
    corner = -1.0 + outer_radius
    step = outer_radius * (2.0 - EDGE_DIFF)
    thickness = min(DEPTH_RATIO, 1.0 / (2.0 * size))
    for iz in range(size):
        z = 1.0 + iz * (-1.0 / size)
        for iy in range(size):
            y = corner + iy * step
            for ix in range(size):
                x = corner + ix * step
                color = _gear_color(ix, iy, iz)
                if (ix * 4 + iy * 2 + iz) % 5 == 0:
                    material(w, color, kd=0.2, ks=0.0, t=0.8, ior=1.1)
                else:
                    material(w, color, kd=1.0, ks=0.0)
                angle = PI * ((ix + iy + iz) % 2) / TEETH
                _gear(w, (x, y, z), angle, OUTER_EDGE_RATIO * outer_radius,
                      (1.0 - EDGE_DIFF) * outer_radius, thickness)
    return w.text()

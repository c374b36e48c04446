"""SPD "rings": objects made of six pentagonal rings (spheres joined by
cylinders) through the edge midpoints of a dodecahedron, stacked in a pyramid
seen from its tip, with a backdrop quad behind. Three lights.

    from raykernel.scene import spd
    text = spd.generate("rings", 7)      # NFF text, same as `rings -s 7`

Size factor SF (default 7): 1 + 4 + ... + SF^2 objects of 30 spheres and 30
cylinders each, i.e. 5*SF*(SF+1)*(2SF+1) spheres and as many cylinders, plus
1 backdrop quad (sf 7: 4200 of each).
"""

from __future__ import annotations

import math

import numpy as np

from ..nffwriter import NffWriter
from ._common import PI, SKY_BLUE, X_AXIS, Z_AXIS, material, polygon, rotation, transform_points

DEFAULT_SIZE = 7
SIZE_RULE = "5*SF*(SF+1)*(2SF+1) spheres and as many cylinders, plus 1 backdrop quad"
MAX_SIZE = 78

#: Radius of the spheres and cylinders.
RADIUS = 0.07412
#: Above 1, deeper layers of the pyramid spread out more.
SPREAD_OUT = 1.0
RING_COLORS = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0),
               (0.0, 1.0, 1.0), (1.0, 0.0, 1.0), (1.0, 1.0, 0.0))


def _ring_points(minor_radius: float) -> np.ndarray:
    """30 points, five per ring: a pentagon in the XY plane and five copies
    tipped over by the dodecahedron's dihedral angle and turned about Z; the
    whole object, tubes included, fits a unit sphere."""
    scale = 1.0 / (1.0 + minor_radius)
    k = np.arange(5) * 2.0 * PI / 5.0
    pentagon = np.column_stack([scale * np.cos(k), scale * np.sin(k), np.zeros(5)])
    tip = rotation(X_AXIS, 2.0 * math.acos(math.cos(PI / 3.0) / math.sin(PI / 5.0)))
    rings = [pentagon]
    for n in range(1, 6):
        turn = rotation(Z_AXIS, PI * (2.0 * (n - 1) + 1.0) / 5.0)
        rings.append(transform_points(transform_points(pentagon, tip), turn))
    return np.concatenate(rings)


def generate(size: int) -> str:
    spread = 1.0 / math.sin(PI / 8.0)
    if SPREAD_OUT <= spread:
        y_step, xz_step = spread / SPREAD_OUT, 1.0
    else:
        y_step, xz_step = 1.0, SPREAD_OUT / spread

    w = NffWriter()
    w.background(SKY_BLUE)
    eye = (-1.0, -spread, 0.5)
    w.view(eye, (eye[0], eye[1] + 1.0, eye[2]), (0.0, 0.0, 1.0), 45.0, 1.0, 512)
    for light in ((3.0, -spread, 3.0), (-4.0, -spread, 1.0), (2.0, -spread, -4.0)):
        w.light(light)

    material(w, (1.0, 1.0, 1.0), kd=1.0, ks=0.0)
    wall_y = y_step * (size + 1)
    half = 1.01 * (wall_y - eye[1]) * math.tan(PI / 8.0)
    polygon(w, [(sx * half + eye[0], wall_y, sz * half + eye[2])
                for sx, sz in ((1, 1), (-1, 1), (-1, -1), (1, -1))])

    points = _ring_points(RADIUS)
    previous = np.array([e + 4 if e % 5 == 0 else e - 1 for e in range(30)])
    for depth in range(size):
        y = y_step * (depth + 1)
        for iz in range(depth + 1):
            z = xz_step * (2 * iz - depth)
            for ix in range(depth + 1):
                x = xz_step * (2 * ix - depth)
                placed = points + np.array([x, y, z])
                bases = placed.tolist()
                apexes = placed[previous].tolist()
                for e in range(30):
                    if e % 5 == 0:
                        material(w, RING_COLORS[e // 5], kd=0.5, ks=0.2, highlight=37.0)
                    w.cone(bases[e], RADIUS, apexes[e], RADIUS)
                    w.sphere(bases[e], RADIUS)
    return w.text()

"""SPD "lattice": a cubic lattice of shiny spheres in the unit cube, each
joined to its neighbours by matte red (x), green (y) and blue (z) cylinders;
six lights.

    from raykernel.scene import spd
    text = spd.generate("lattice", 12)      # NFF text, same as `lattice -s 12`

Size factor SF (default 12): (SF+1)^3 spheres of radius 1/(4 SF) and
3 SF (SF+1)^2 cylinders of radius 1/(16 SF), each with its own `f` line
before it (sf1: 8 + 12, sf12: 2197 + 6084). Points are visited x, then y,
then z, each sphere followed by its +x, +y and +z cylinders.
"""

from __future__ import annotations

import math

from ..nffwriter import NffWriter
from ._common import SKY_BLUE, material

DEFAULT_SIZE = 12
SIZE_RULE = "(SF+1)^3 spheres and 3*SF*(SF+1)^2 cylinders, an f line before each"
MAX_SIZE = 134

SPHERE_COLOR = (0.9, 0.9, 0.9)
ARM_COLORS = ((0.9, 0.1, 0.1), (0.1, 0.9, 0.1), (0.1, 0.1, 0.9))
SPHERE_RADIUS = 1.0 / 4.0
ARM_RADIUS = 1.0 / 16.0
LIGHTS = ((2.0, 0.5, 0.5), (-1.0, 0.5, 0.5), (0.5, 2.0, 0.5),
          (0.5, -1.0, 0.5), (0.5, 0.5, 2.0), (0.5, 0.5, -1.0))


def generate(size: int = DEFAULT_SIZE) -> str:
    """NFF text of the lattice scene at size factor `size`."""
    n = size
    inv = 1.0 / n
    r_sphere = SPHERE_RADIUS / n
    r_arm = ARM_RADIUS / n
    # Each arm starts just inside the sphere surface where it meets the arm's rim.
    inset = (r_sphere * (1.0 - math.sqrt(ARM_RADIUS / SPHERE_RADIUS))) * 0.99
    mid = ((n >> 1) + 0.5) * inv
    w = NffWriter()
    w.background(SKY_BLUE)
    w.view((mid, 1.0, 1.0 - 1.0 / (n << 1)), (mid, -1.0, -1.0 - 1.0 / (n << 1)), (0.2, 1.0, 0.0), 60.0, 0.0, 512)
    for light in LIGHTS:
        w.light(light)
    for x in range(n + 1):
        x0 = x / n
        for y in range(n + 1):
            y0 = y / n
            for z in range(n + 1):
                z0 = z / n
                center = (x0, y0, z0)
                material(w, SPHERE_COLOR, kd=0.5, ks=0.5, highlight=37.0, ior=0.0)
                w.sphere(center, r_sphere)
                for axis, (k, color) in enumerate(zip((x, y, z), ARM_COLORS)):
                    if k == n:
                        continue
                    material(w, color, kd=0.99, ks=0.0, highlight=0.0, ior=0.0)
                    base, apex = list(center), list(center)
                    base[axis] += inset
                    apex[axis] = center[axis] + inv - inset
                    w.cone(base, r_arm, apex, r_arm)
    return w.text()

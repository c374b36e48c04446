"""SPD "balls" (the sphereflake): a shiny sphere sprouting nine spheres of a
third its radius, each sprouting nine more, over a matte floor; three lights.

    from raykernel.scene import spd
    text = spd.generate("balls", 4)      # NFF text, same as `balls -s 4`

Size factor SF (default 4): 1 + 9 + ... + 9^SF spheres plus 1 floor quad
(sf 1/2/3/4: 10/91/820/7381 spheres).
"""

from __future__ import annotations

import math

import numpy as np

from ..nffwriter import NffWriter
from ._common import (
    PI,
    SKY_BLUE,
    Y_AXIS,
    Z_AXIS,
    axis_rotation,
    identity,
    material,
    normalize,
    rotation,
    transform_vectors,
)

DEFAULT_SIZE = 4
SIZE_RULE = "1 + 9 + ... + 9^SF spheres and 1 floor quad"
MAX_SIZE = 7

#: Child radius over parent radius.
CHILD_RATIO = 1.0 / 3.0


def _child_directions() -> np.ndarray:
    """Unit directions of the nine children of a sphere whose axis is +Z:
    three trios 120 degrees apart, each with two children on the equator
    and one above it."""
    d = 1.0 / math.sqrt(2.0)
    trio = np.array([[d, d, 0.0], [d, 0.0, -d], [0.0, d, -d]])
    tilt = axis_rotation(normalize([1.0, -1.0, 0.0]), math.asin(2.0 / math.sqrt(6.0)))
    trio = transform_vectors(trio, tilt)
    return np.concatenate([transform_vectors(trio, rotation(Z_AXIS, k * 2.0 * PI / 3.0)) for k in range(3)])


def _align_z(direction) -> np.ndarray:
    """Rotation taking +Z to the unit vector `direction`."""
    x, y, z = direction
    if z >= 0.9999:
        return identity()
    if z <= -0.9999:
        return rotation(Y_AXIS, PI)
    axis = normalize([-y, x, 0.0])
    return axis_rotation(axis, math.acos(z))


def _flake(w: NffWriter, children: np.ndarray, depth: int, center, radius: float, direction):
    w.sphere(center, radius)
    if depth <= 0:
        return
    spread = radius * (1.0 + CHILD_RATIO)
    center = np.asarray(center)
    child_centers = transform_vectors(children, _align_z(direction)) * spread + center
    child_dirs = ((child_centers - center) / spread).tolist()
    child_centers = child_centers.tolist()
    child_radius = radius * CHILD_RATIO
    for c, d in zip(child_centers, child_dirs):
        _flake(w, children, depth - 1, c, child_radius, d)


def generate(size: int) -> str:
    w = NffWriter()
    w.background(SKY_BLUE)
    w.view((2.1, 1.3, 1.7), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 45.0, 0.01, 512)
    for light in ((4.0, 3.0, 2.0), (1.0, -4.0, 4.0), (-3.0, 1.0, 5.0)):
        w.light(light)

    radius = 1.0
    material(w, (1.0, 0.75, 0.33), kd=0.8, ks=0.0, ior=1.0)
    x, y, z = 12.0 * radius, 12.0 * radius, -radius / 2.0
    w.polygon([(x, y, z), (-x, y, z), (-x, -y, z), (x, -y, z)])

    material(w, (1.0, 0.9, 0.7), kd=0.5, ks=0.5, highlight=37.0, ior=1.0)
    _flake(w, _child_directions(), size, (0.0, 0.0, 0.0), radius / 2.0, (0.0, 0.0, 1.0))
    return w.text()

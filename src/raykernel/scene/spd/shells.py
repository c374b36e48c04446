"""SPD "shells": a seashell after Pickover, a logarithmic spiral of ever
larger, heavily overlapping spheres; a pathological test. One light.

    from raykernel.scene import spd
    text = spd.generate("shells", 5)     # NFF text, same as `shells -s 5`

Size factor SF (default 5): 180*2^SF + 1 spheres (sf 5: 5761). The SPD source
header says 180*2^SF spheres plus a square; the program writes one more
sphere and no square, and so does this module.
"""

from __future__ import annotations

import numpy as np

from ..nffwriter import NffWriter
from ._common import PI, SKY_BLUE, material

DEFAULT_SIZE = 5
SIZE_RULE = "180*2^SF + 1 spheres"
MAX_SIZE = 15

#: Pickover's shell parameters: radius scale, z = ALPHA*angle if ALPHA > 0
#: else z = BETA*r, growth exponent and relative size.
GAMMA = 1.0
ALPHA = 0.0
BETA = -2.0
EXPONENT = 0.15
RELATIVE_SIZE = 1.0
TURNS = 3.0


def spheres(size: int) -> np.ndarray:
    """(n, 4) array of sphere centres and radii, in output order."""
    steps = int(180.0 * 2.0 ** size)
    first = -((steps * 2) // 3)
    last = steps // 3
    i = np.arange(first, last + 1, dtype=float)
    angle = TURNS * 6.0 * PI * i / steps
    r = RELATIVE_SIZE * np.exp(EXPONENT * angle)
    z = ALPHA * angle if ALPHA > 0.0 else BETA * r
    return np.column_stack([r * np.sin(angle), r * np.cos(angle), z, r / GAMMA])


def generate(size: int) -> str:
    w = NffWriter()
    w.background(SKY_BLUE)
    w.view((-6.0, -60.0, 35.0), (0.0, 8.0, -15.0), (0.0, 0.0, 1.0), 45.0, 0.5, 512)
    w.light((-100.0, -100.0, 100.0))
    material(w, (1.0, 0.8, 0.4), kd=0.8, ks=0.2, highlight=10.0, ior=1.0)
    for x, y, z, r in spheres(size).tolist():
        w.sphere((x, y, z), r)
    return w.text()

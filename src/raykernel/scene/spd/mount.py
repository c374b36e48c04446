"""SPD "mount": a fractal mountain made by midpoint subdivision of a square
(Carpenter's method on a grid), with a pyramid of four glass spheres in front
of it. One light.

    from raykernel.scene import spd
    text = spd.generate("mount", 6)      # NFF text, same as `mount -s 6`

Size factor SF (default 6): a 2^SF x 2^SF grid written as 2*4^SF triangles,
plus 4 spheres (sf 6: 8192 triangles).

The random heights come from the original SPD hash of the grid position (the
one behind the published images, with its known repetitions), fed to the SPD
library's Gaussian deviate, so the terrain is the published one. The hash
shifts by 7 - SF bits; above SF 7 that count is negative and is taken modulo
64, as the compiled C program does on x86-64.
"""

from __future__ import annotations

import math

from ..nffwriter import NffWriter
from ._common import PI, SKY_BLUE, Z_AXIS, axis_rotation, gauss_rand, material, normalize, rotation, transform_vectors

DEFAULT_SIZE = 6
SIZE_RULE = "2*4^SF terrain triangles plus 4 spheres"
MAX_SIZE = 11

FRACTAL_DIMENSION = 2.2
MOUNTAIN_NO = 21
X_CORNER = -1.0
Y_CORNER = -1.0
WIDTH = 2.0

_MASK64 = (1 << 64) - 1


def _shift_left(value: int, count: int) -> int:
    """`value << count` on a 64-bit unsigned long, the count taken modulo 64."""
    return (value << (count & 63)) & _MASK64


def hash_rand(a: int, b: int, size: int) -> int:
    """The original mount hash of grid point (a, b): 16 bits."""
    return (_shift_left(a, 23 - size) + _shift_left(b, 15 - size) + _shift_left(a, 7 - size)) & 0xFFFF


def _spheres(w: NffWriter, center, radius: float):
    """Four spheres of `radius` touching each other: one on top of three."""
    top = (0.0, 0.0, radius * math.sqrt(3.0 / 2.0))
    w.sphere([c + t for c, t in zip(center, top)], radius)
    tilted = axis_rotation(normalize([1.0, 1.0, 0.0]), math.acos(-1.0 / 3.0))
    base = transform_vectors(top, tilted)
    for i in range(3):
        p = transform_vectors(base, rotation(Z_AXIS, i * 2.0 * PI / 3.0))
        w.sphere((p + center).tolist(), radius)


class _Mountain:
    def __init__(self, w: NffWriter, size: int):
        self.w = w
        self.size = size
        self.cells = float(1 << size)
        ratio = 2.0 / math.exp(math.log(2.0) / (FRACTAL_DIMENSION - 1.0))
        self.roughness = math.sqrt(ratio * ratio - 1.0)

    def _noise(self, a: int, b: int) -> float:
        return gauss_rand(MOUNTAIN_NO + hash_rand(a, b, self.size))

    def grow(self, width: int, x: int, y: int, ll: float, lr: float, ur: float, ul: float):
        """Heights ll, lr, ur, ul at the corners of the width x width cell block
        whose lower-left grid point is (x, y): subdivide, or write two triangles."""
        if width == 1:
            n = self.cells
            x0 = X_CORNER + x * WIDTH / n
            x1 = X_CORNER + (x + 1) * WIDTH / n
            y0 = Y_CORNER + y * WIDTH / n
            y1 = Y_CORNER + (y + 1) * WIDTH / n
            self.w.polygon([(x0, y0, ll), (x1, y0, lr), (x1, y1, ur)])
            self.w.polygon([(x1, y1, ur), (x0, y1, ul), (x0, y0, ll)])
            return
        half = width >> 1
        rise = half * WIDTH / self.cells * self.roughness
        lower = (ll + lr) / 2.0 + rise * self._noise(x + half, y)
        right = (lr + ur) / 2.0 + rise * self._noise(x + width, y + half)
        upper = (ur + ul) / 2.0 + rise * self._noise(x + half, y + width)
        left = (ul + ll) / 2.0 + rise * self._noise(x, y + half)
        middle = (ll + lr + ur + ul) / 4.0 + 1.4142136 * rise * self._noise(x + half, y + half)
        self.grow(half, x, y, ll, lower, middle, left)
        self.grow(half, x + half, y, lower, lr, right, middle)
        self.grow(half, x + half, y + half, middle, right, ur, upper)
        self.grow(half, x, y + half, left, middle, upper, ul)


def generate(size: int) -> str:
    w = NffWriter()
    w.background(SKY_BLUE)
    w.view((-1.6, 1.6, 1.7), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 45.0, 0.01, 512)
    w.light((-100.0, -100.0, 100.0))

    material(w, (1.0, 1.0, 1.0), kd=0.1, ks=0.1, highlight=6.7, t=0.9, ior=1.5)
    _spheres(w, (-0.8, 0.8, 1.0), 0.17)

    material(w, (0.5, 0.45, 0.35), kd=1.0, ks=0.0)
    _Mountain(w, size).grow(1 << size, 0, 0, 0.0, 0.0, 0.0, 0.0)
    return w.text()

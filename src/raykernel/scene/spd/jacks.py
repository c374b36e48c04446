"""SPD "jacks": a recursive jack (three crossed cylinders with a sphere on
every end), with a half-size copy in each of its eight octants, and so on;
shiny pink on dark purple, one light.

    from raykernel.scene import spd
    text = spd.generate("jacks", 4)      # NFF text, same as `jacks -s 4`

Size factor SF (default 1) is the recursion depth: 1 + 8 + ... + 8^(SF-1)
jacks of 3 cylinders and 6 spheres, 9 (8^SF - 1) / 7 primitives in all
(sf1: 9, sf4: 5265). The whole assembly is turned -20 degrees about y,
then -30 degrees about x.
"""

from __future__ import annotations

from ..nffwriter import NffWriter
from ._common import PI, X_AXIS, Y_AXIS, material
from ._tessellate import TransformStack

DEFAULT_SIZE = 1
SIZE_RULE = "9*(8^SF-1)/7 primitives: each jack is 3 cylinders and 6 spheres, each level adds 8 children per jack"
MAX_SIZE = 7

PINK = (0.737, 0.561, 0.561)
DARK_PURPLE = (0.2, 0.05, 0.2)
ARM_RADIUS = 0.1
BALL_RADIUS = 0.2
#: A jack is shrunk by this much so that neighbours do not touch.
JACK_SCALE = 0.75
AXES = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


def _jack(w: NffWriter, tx: TransformStack):
    tx.push()
    tx.scale((JACK_SCALE,) * 3)
    arm = tx.radius(ARM_RADIUS)
    for axis in AXES:
        base = tx.point([-a for a in axis])
        apex = tx.point(axis)
        w.cone(base, arm, apex, arm)
    ball = tx.radius(BALL_RADIUS)
    for sign in (1.0, -1.0):
        for axis in AXES:
            w.sphere(tx.point([sign * a for a in axis]), ball)
    tx.pop()


def _recursive_jack(w: NffWriter, tx: TransformStack, depth: int, max_depth: int):
    _jack(w, tx)
    if depth >= max_depth:
        return
    for i in (-0.5, 0.5):
        for j in (-0.5, 0.5):
            for k in (-0.5, 0.5):
                tx.push()
                tx.translate((i, j, k))
                tx.scale((0.5, 0.5, 0.5))
                _recursive_jack(w, tx, depth + 1, max_depth)
                tx.pop()


def generate(size: int = DEFAULT_SIZE) -> str:
    """NFF text of the jacks scene at size factor `size`."""
    w = NffWriter()
    w.background(DARK_PURPLE)
    w.view((0.0, 0.0, -8.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 25.0, 0.001, 256)
    w.light((-10.0, 3.0, -20.0))
    tx = TransformStack()
    tx.rotate(X_AXIS, -30.0 * PI / 180.0)
    tx.rotate(Y_AXIS, -20.0 * PI / 180.0)
    material(w, PINK, kd=0.7, ks=0.7, highlight=20.0, ior=1.0)
    _recursive_jack(w, tx, 1, size)
    return w.text()

"""SPD "nurbtst": one bicubic B-spline patch (6 x 5 control points, open
uniform knots) tessellated into 1500 smooth-shaded triangles; red on black,
one light.

    from raykernel.scene import spd
    text = spd.generate("nurbtst")      # NFF text, same as `nurbtst`

The size factor is ignored (DEFAULT_SIZE 1; every size gives the same
scene). The parameter ranges are cut into 6 x 5 = 30 by 5 x 5 = 25 steps,
two triangles per cell. The control weights are listed but, as in the SPD,
not used. The patch is moved by (-2, -2.5, 0), turned -90 degrees about x,
then 30 degrees about y.
"""

from __future__ import annotations

import numpy as np

from ..nffwriter import NffWriter
from ._common import PI, X_AXIS, Y_AXIS, material
from ._tessellate import TransformStack, nurbs_patches

DEFAULT_SIZE = 1
SIZE_RULE = "size ignored: always 1500 triangle patches (a 30 x 25 grid on one NURBS patch)"

ORDER = 4
RESOLUTION = 5
#: Control points (x, y, z, weight), six rows of five.
CONTROL = np.array([
    [(0, 0, 0, 1), (1, 0, 3, 1), (2, 0, -3, 1), (3, 0, 3, 1), (4, 0, 0, 1)],
    [(0, 1, 0, 1), (1, 1, 0, 1), (2, 1, 0, 1), (3, 1, 0, 1), (4, 1, 0, 1)],
    [(0, 2, 0, 1), (1, 2, 0, 2), (2, 2, 5, 0.5), (3, 2, 0, 1), (4, 2, 0, 1)],
    [(0, 3, 0, 1), (1, 3, 0, 2), (2, 3, 5, 0.5), (3, 3, 0, 1), (4, 3, 0, 1)],
    [(0, 4, 0, 1), (1, 4, 0, 1), (2, 4, 0, 20), (3, 4, 0, 1), (4, 4, 0, 1)],
    [(0, 5, 0, 1), (1, 5, -3, 1), (2, 5, 3, 1), (3, 5, -3, 1), (4, 5, 0, 1)],
], dtype=float)
RED = (1.0, 0.0, 0.0)


def generate(size: int = DEFAULT_SIZE) -> str:
    """NFF text of the nurbtst scene (`size` is ignored)."""
    w = NffWriter()
    w.background((0.0, 0.0, 0.0))
    w.view((0.0, 5.0, -10.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 30.0, 0.001, 256)
    w.light((0.0, 50.0, -10.0))
    material(w, RED, kd=0.7, ks=0.0, highlight=10.0, ior=1.0)
    tx = TransformStack()
    tx.rotate(Y_AXIS, PI * 30.0 / 180.0)
    tx.rotate(X_AXIS, PI * -90.0 / 180.0)
    tx.translate((-2.0, -2.5, 0.0))
    verts, norms = nurbs_patches(ORDER, ORDER, CONTROL, RESOLUTION, RESOLUTION)
    verts = tx.point(verts.reshape(-1, 3)).reshape(-1, 3, 3)
    norms = tx.normal(norms.reshape(-1, 3)).reshape(-1, 3, 3)
    for v, n in zip(verts.tolist(), norms.tolist()):
        w.patch(v, n)
    return w.text()

"""SPD "sample": the SPD library's demonstration scene: three interlocking
tori (tessellated into smooth-shaded triangles), a cone and a disc beneath
them (tessellated into flat triangles); matte colours on light grey, one light.

    from raykernel.scene import spd
    text = spd.generate("sample")      # NFF text, same as `sample`

The size factor is ignored (DEFAULT_SIZE 1; every size gives the same
scene). Each torus is a 12 x 12 grid of cells, two triangle patches per cell
(3 x 288 = 864 pp); the cone is one `c`; the disc is 16 sectors, each a
triangle once its two centre corners are merged (16 p).
"""

from __future__ import annotations

from ..nffwriter import NffWriter
from ._common import material, polygon
from ._tessellate import disc_polygons, torus_patches

DEFAULT_SIZE = 1
SIZE_RULE = "size ignored: always 3 tori of 288 triangle patches, 1 cone and a disc of 16 triangles"

LIGHT_GREY = (0.8, 0.8, 0.8)
CYAN = (0.0, 1.0, 1.0)
YELLOW = (1.0, 1.0, 0.0)
MAGENTA = (1.0, 0.0, 1.0)
RED = (1.0, 0.0, 0.0)
#: Tessellation of the tori (grid cells per quarter turn in each direction).
TORUS_RESOLUTION = 3
#: Sectors per quarter turn of the disc.
DISC_RESOLUTION = 4
#: (colour, centre, axis) of the three tori; major radius 2, minor 0.5.
TORI = ((CYAN, (-1.0, 0.0, 0.0), (1.0, 1.0, -0.5)),
        (YELLOW, (0.0, 0.0, 0.0), (0.0, 1.0, -0.5)),
        (MAGENTA, (1.0, 0.0, 0.0), (-1.0, 1.0, -0.5)))


def _paint(w: NffWriter, color):
    material(w, color, kd=0.7, ks=0.0, highlight=10.0, ior=1.0)


def generate(size: int = DEFAULT_SIZE) -> str:
    """NFF text of the sample scene (`size` is ignored)."""
    w = NffWriter()
    w.background(LIGHT_GREY)
    w.view((0.0, 5.0, -5.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 45.0, 0.001, 512)
    w.light((-10.0, 20.0, -20.0))
    for color, center, axis in TORI:
        _paint(w, color)
        verts, norms = torus_patches(center, axis, 2.0, 0.5, TORUS_RESOLUTION, TORUS_RESOLUTION)
        for v, n in zip(verts.tolist(), norms.tolist()):
            w.patch(v, n)
    _paint(w, RED)
    w.cone((0.0, -2.0, 0.0), 2.0, (0.0, 2.0, 0.0), 0.1)
    _paint(w, RED)
    for quad in disc_polygons((0.0, -2.0, 0.0), (0.0, 1.0, 0.0), 0.0, 4.0, DISC_RESOLUTION):
        polygon(w, quad)
    return w.text()

"""SPD "teapot": the Newell teapot (with Crow's bottom) as smooth-shaded
triangles, sitting on a reflective checkerboard; two lights.

    from raykernel.scene import spd
    text = spd.generate("teapot", 6)          # NFF text, same as `teapot -s 6`
    from raykernel.scene.spd import teapot
    text = teapot.generate(1)                 # what `teapot -s 1` writes (with the SPD's warning)

Size factor n (default 6, the SPD statistics use 12): each of the 32 bicubic
Bezier patches is cut into an n x n grid, every cell split into two triangle
patches (pp, with the surface normal at each vertex). Triangles that collapse
onto the lid or bottom cusp are dropped, leaving 64 n^2 - 8 n of them, plus an
n x n checkerboard of quads (white squares first, then grey). The SPD warns
that "a size of 1 is not supported" and writes the scene anyway; so do we
(a RuntimeWarning), since teapot-sf1.nff is such a file.
"""

from __future__ import annotations

import warnings

import numpy as np

from ...errors import OptionError, RayKernelWarning
from ..nffwriter import NffWriter
from ._common import SKY_BLUE, material

DEFAULT_SIZE = 6
SIZE_RULE = "64*n^2 - 8*n triangle patches (cusp-degenerate ones dropped) plus an n x n checkerboard of quads"
MAX_SIZE = 390

#: Vertices within this distance of the z axis (in x and in y) are on a cusp.
CUSP_TOLERANCE = 1.0e-4

# Control point indices of the 32 patches (rim 4, body 8, handle 4, spout 4,
# lid 8, bottom 4), each a 4 x 4 grid, rows along s and columns along t.
PATCHES = np.array([
    0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15,
    3, 16, 17, 18, 7, 19, 20, 21, 11, 22, 23, 24, 15, 25, 26, 27,
    18, 28, 29, 30, 21, 31, 32, 33, 24, 34, 35, 36, 27, 37, 38, 39,
    30, 40, 41, 0, 33, 42, 43, 4, 36, 44, 45, 8, 39, 46, 47, 12,
    12, 13, 14, 15, 48, 49, 50, 51, 52, 53, 54, 55, 56, 57, 58, 59,
    15, 25, 26, 27, 51, 60, 61, 62, 55, 63, 64, 65, 59, 66, 67, 68,
    27, 37, 38, 39, 62, 69, 70, 71, 65, 72, 73, 74, 68, 75, 76, 77,
    39, 46, 47, 12, 71, 78, 79, 48, 74, 80, 81, 52, 77, 82, 83, 56,
    56, 57, 58, 59, 84, 85, 86, 87, 88, 89, 90, 91, 92, 93, 94, 95,
    59, 66, 67, 68, 87, 96, 97, 98, 91, 99, 100, 101, 95, 102, 103, 104,
    68, 75, 76, 77, 98, 105, 106, 107, 101, 108, 109, 110, 104, 111, 112, 113,
    77, 82, 83, 56, 107, 114, 115, 84, 110, 116, 117, 88, 113, 118, 119, 92,
    120, 121, 122, 123, 124, 125, 126, 127, 128, 129, 130, 131, 132, 133, 134, 135,
    123, 136, 137, 120, 127, 138, 139, 124, 131, 140, 141, 128, 135, 142, 143, 132,
    132, 133, 134, 135, 144, 145, 146, 147, 148, 149, 150, 151, 68, 152, 153, 154,
    135, 142, 143, 132, 147, 155, 156, 144, 151, 157, 158, 148, 154, 159, 160, 68,
    161, 162, 163, 164, 165, 166, 167, 168, 169, 170, 171, 172, 173, 174, 175, 176,
    164, 177, 178, 161, 168, 179, 180, 165, 172, 181, 182, 169, 176, 183, 184, 173,
    173, 174, 175, 176, 185, 186, 187, 188, 189, 190, 191, 192, 193, 194, 195, 196,
    176, 183, 184, 173, 188, 197, 198, 185, 192, 199, 200, 189, 196, 201, 202, 193,
    203, 203, 203, 203, 204, 205, 206, 207, 208, 208, 208, 208, 209, 210, 211, 212,
    203, 203, 203, 203, 207, 213, 214, 215, 208, 208, 208, 208, 212, 216, 217, 218,
    203, 203, 203, 203, 215, 219, 220, 221, 208, 208, 208, 208, 218, 222, 223, 224,
    203, 203, 203, 203, 221, 225, 226, 204, 208, 208, 208, 208, 224, 227, 228, 209,
    209, 210, 211, 212, 229, 230, 231, 232, 233, 234, 235, 236, 237, 238, 239, 240,
    212, 216, 217, 218, 232, 241, 242, 243, 236, 244, 245, 246, 240, 247, 248, 249,
    218, 222, 223, 224, 243, 250, 251, 252, 246, 253, 254, 255, 249, 256, 257, 258,
    224, 227, 228, 209, 252, 259, 260, 229, 255, 261, 262, 233, 258, 263, 264, 237,
    265, 265, 265, 265, 266, 267, 268, 269, 270, 271, 272, 273, 92, 119, 118, 113,
    265, 265, 265, 265, 269, 274, 275, 276, 273, 277, 278, 279, 113, 112, 111, 104,
    265, 265, 265, 265, 276, 280, 281, 282, 279, 283, 284, 285, 104, 103, 102, 95,
    265, 265, 265, 265, 282, 286, 287, 266, 285, 288, 289, 270, 95, 94, 93, 92,
]).reshape(32, 4, 4)

CONTROL_POINTS = np.array([
    1.4, 0, 2.4, 1.4, -0.784, 2.4, 0.784, -1.4, 2.4, 0, -1.4, 2.4,
    1.3375, 0, 2.53125, 1.3375, -0.749, 2.53125, 0.749, -1.3375, 2.53125, 0, -1.3375, 2.53125,
    1.4375, 0, 2.53125, 1.4375, -0.805, 2.53125, 0.805, -1.4375, 2.53125, 0, -1.4375, 2.53125,
    1.5, 0, 2.4, 1.5, -0.84, 2.4, 0.84, -1.5, 2.4, 0, -1.5, 2.4,
    -0.784, -1.4, 2.4, -1.4, -0.784, 2.4, -1.4, 0, 2.4,
    -0.749, -1.3375, 2.53125, -1.3375, -0.749, 2.53125, -1.3375, 0, 2.53125,
    -0.805, -1.4375, 2.53125, -1.4375, -0.805, 2.53125, -1.4375, 0, 2.53125,
    -0.84, -1.5, 2.4, -1.5, -0.84, 2.4, -1.5, 0, 2.4,
    -1.4, 0.784, 2.4, -0.784, 1.4, 2.4, 0, 1.4, 2.4,
    -1.3375, 0.749, 2.53125, -0.749, 1.3375, 2.53125, 0, 1.3375, 2.53125,
    -1.4375, 0.805, 2.53125, -0.805, 1.4375, 2.53125, 0, 1.4375, 2.53125,
    -1.5, 0.84, 2.4, -0.84, 1.5, 2.4, 0, 1.5, 2.4,
    0.784, 1.4, 2.4, 1.4, 0.784, 2.4,
    0.749, 1.3375, 2.53125, 1.3375, 0.749, 2.53125,
    0.805, 1.4375, 2.53125, 1.4375, 0.805, 2.53125,
    0.84, 1.5, 2.4, 1.5, 0.84, 2.4,
    1.75, 0, 1.875, 1.75, -0.98, 1.875, 0.98, -1.75, 1.875, 0, -1.75, 1.875,
    2, 0, 1.35, 2, -1.12, 1.35, 1.12, -2, 1.35, 0, -2, 1.35,
    2, 0, 0.9, 2, -1.12, 0.9, 1.12, -2, 0.9, 0, -2, 0.9,
    -0.98, -1.75, 1.875, -1.75, -0.98, 1.875, -1.75, 0, 1.875,
    -1.12, -2, 1.35, -2, -1.12, 1.35, -2, 0, 1.35,
    -1.12, -2, 0.9, -2, -1.12, 0.9, -2, 0, 0.9,
    -1.75, 0.98, 1.875, -0.98, 1.75, 1.875, 0, 1.75, 1.875,
    -2, 1.12, 1.35, -1.12, 2, 1.35, 0, 2, 1.35,
    -2, 1.12, 0.9, -1.12, 2, 0.9, 0, 2, 0.9,
    0.98, 1.75, 1.875, 1.75, 0.98, 1.875,
    1.12, 2, 1.35, 2, 1.12, 1.35,
    1.12, 2, 0.9, 2, 1.12, 0.9,
    2, 0, 0.45, 2, -1.12, 0.45, 1.12, -2, 0.45, 0, -2, 0.45,
    1.5, 0, 0.225, 1.5, -0.84, 0.225, 0.84, -1.5, 0.225, 0, -1.5, 0.225,
    1.5, 0, 0.15, 1.5, -0.84, 0.15, 0.84, -1.5, 0.15, 0, -1.5, 0.15,
    -1.12, -2, 0.45, -2, -1.12, 0.45, -2, 0, 0.45,
    -0.84, -1.5, 0.225, -1.5, -0.84, 0.225, -1.5, 0, 0.225,
    -0.84, -1.5, 0.15, -1.5, -0.84, 0.15, -1.5, 0, 0.15,
    -2, 1.12, 0.45, -1.12, 2, 0.45, 0, 2, 0.45,
    -1.5, 0.84, 0.225, -0.84, 1.5, 0.225, 0, 1.5, 0.225,
    -1.5, 0.84, 0.15, -0.84, 1.5, 0.15, 0, 1.5, 0.15,
    1.12, 2, 0.45, 2, 1.12, 0.45,
    0.84, 1.5, 0.225, 1.5, 0.84, 0.225,
    0.84, 1.5, 0.15, 1.5, 0.84, 0.15,
    -1.6, 0, 2.025, -1.6, -0.3, 2.025, -1.5, -0.3, 2.25, -1.5, 0, 2.25,
    -2.3, 0, 2.025, -2.3, -0.3, 2.025, -2.5, -0.3, 2.25, -2.5, 0, 2.25,
    -2.7, 0, 2.025, -2.7, -0.3, 2.025, -3, -0.3, 2.25, -3, 0, 2.25,
    -2.7, 0, 1.8, -2.7, -0.3, 1.8, -3, -0.3, 1.8, -3, 0, 1.8,
    -1.5, 0.3, 2.25, -1.6, 0.3, 2.025,
    -2.5, 0.3, 2.25, -2.3, 0.3, 2.025,
    -3, 0.3, 2.25, -2.7, 0.3, 2.025,
    -3, 0.3, 1.8, -2.7, 0.3, 1.8,
    -2.7, 0, 1.575, -2.7, -0.3, 1.575, -3, -0.3, 1.35, -3, 0, 1.35,
    -2.5, 0, 1.125, -2.5, -0.3, 1.125, -2.65, -0.3, 0.9375, -2.65, 0, 0.9375,
    -2, -0.3, 0.9, -1.9, -0.3, 0.6, -1.9, 0, 0.6,
    -3, 0.3, 1.35, -2.7, 0.3, 1.575,
    -2.65, 0.3, 0.9375, -2.5, 0.3, 1.125,
    -1.9, 0.3, 0.6, -2, 0.3, 0.9,
    1.7, 0, 1.425, 1.7, -0.66, 1.425, 1.7, -0.66, 0.6, 1.7, 0, 0.6,
    2.6, 0, 1.425, 2.6, -0.66, 1.425, 3.1, -0.66, 0.825, 3.1, 0, 0.825,
    2.3, 0, 2.1, 2.3, -0.25, 2.1, 2.4, -0.25, 2.025, 2.4, 0, 2.025,
    2.7, 0, 2.4, 2.7, -0.25, 2.4, 3.3, -0.25, 2.4, 3.3, 0, 2.4,
    1.7, 0.66, 0.6, 1.7, 0.66, 1.425,
    3.1, 0.66, 0.825, 2.6, 0.66, 1.425,
    2.4, 0.25, 2.025, 2.3, 0.25, 2.1,
    3.3, 0.25, 2.4, 2.7, 0.25, 2.4,
    2.8, 0, 2.475, 2.8, -0.25, 2.475, 3.525, -0.25, 2.49375, 3.525, 0, 2.49375,
    2.9, 0, 2.475, 2.9, -0.15, 2.475, 3.45, -0.15, 2.5125, 3.45, 0, 2.5125,
    2.8, 0, 2.4, 2.8, -0.15, 2.4, 3.2, -0.15, 2.4, 3.2, 0, 2.4,
    3.525, 0.25, 2.49375, 2.8, 0.25, 2.475,
    3.45, 0.15, 2.5125, 2.9, 0.15, 2.475,
    3.2, 0.15, 2.4, 2.8, 0.15, 2.4,
    0, 0, 3.15, 0.8, 0, 3.15, 0.8, -0.45, 3.15, 0.45, -0.8, 3.15, 0, -0.8, 3.15,
    0, 0, 2.85, 0.2, 0, 2.7, 0.2, -0.112, 2.7, 0.112, -0.2, 2.7, 0, -0.2, 2.7,
    -0.45, -0.8, 3.15, -0.8, -0.45, 3.15, -0.8, 0, 3.15,
    -0.112, -0.2, 2.7, -0.2, -0.112, 2.7, -0.2, 0, 2.7,
    -0.8, 0.45, 3.15, -0.45, 0.8, 3.15, 0, 0.8, 3.15,
    -0.2, 0.112, 2.7, -0.112, 0.2, 2.7, 0, 0.2, 2.7,
    0.45, 0.8, 3.15, 0.8, 0.45, 3.15,
    0.112, 0.2, 2.7, 0.2, 0.112, 2.7,
    0.4, 0, 2.55, 0.4, -0.224, 2.55, 0.224, -0.4, 2.55, 0, -0.4, 2.55,
    1.3, 0, 2.55, 1.3, -0.728, 2.55, 0.728, -1.3, 2.55, 0, -1.3, 2.55,
    1.3, 0, 2.4, 1.3, -0.728, 2.4, 0.728, -1.3, 2.4, 0, -1.3, 2.4,
    -0.224, -0.4, 2.55, -0.4, -0.224, 2.55, -0.4, 0, 2.55,
    -0.728, -1.3, 2.55, -1.3, -0.728, 2.55, -1.3, 0, 2.55,
    -0.728, -1.3, 2.4, -1.3, -0.728, 2.4, -1.3, 0, 2.4,
    -0.4, 0.224, 2.55, -0.224, 0.4, 2.55, 0, 0.4, 2.55,
    -1.3, 0.728, 2.55, -0.728, 1.3, 2.55, 0, 1.3, 2.55,
    -1.3, 0.728, 2.4, -0.728, 1.3, 2.4, 0, 1.3, 2.4,
    0.224, 0.4, 2.55, 0.4, 0.224, 2.55,
    0.728, 1.3, 2.55, 1.3, 0.728, 2.55,
    0.728, 1.3, 2.4, 1.3, 0.728, 2.4,
    0, 0, 0, 1.425, 0, 0, 1.425, 0.798, 0, 0.798, 1.425, 0, 0, 1.425, 0,
    1.5, 0, 0.075, 1.5, 0.84, 0.075, 0.84, 1.5, 0.075, 0, 1.5, 0.075,
    -0.798, 1.425, 0, -1.425, 0.798, 0, -1.425, 0, 0,
    -0.84, 1.5, 0.075, -1.5, 0.84, 0.075, -1.5, 0, 0.075,
    -1.425, -0.798, 0, -0.798, -1.425, 0, 0, -1.425, 0,
    -1.5, -0.84, 0.075, -0.84, -1.5, 0.075, 0, -1.5, 0.075,
    0.798, -1.425, 0, 1.425, -0.798, 0,
    0.84, -1.5, 0.075, 1.5, -0.84, 0.075,
], dtype=float).reshape(290, 3)

#: Bezier basis matrix: the point at (s, t) is [s^3 s^2 s 1] B G B^T [t^3 t^2 t 1]^T.
BEZIER = np.array([[-1.0, 3.0, -3.0, 1.0],
                   [3.0, -6.0, 3.0, 0.0],
                   [-3.0, 3.0, 0.0, 0.0],
                   [1.0, 0.0, 0.0, 0.0]])

TEAPOT_COLOR = (1.0, 0.5, 0.1)
WHITE = (1.0, 1.0, 1.0)
GREY = (0.5, 0.5, 0.5)


def _powers(n: int):
    """[u^3, u^2, u, 1] and its derivative at u = k/n, k = 0..n (shape (n + 1, 4) each)."""
    u = np.arange(n + 1) / float(n)
    one, zero = np.ones_like(u), np.zeros_like(u)
    value = np.stack([u * u * u, u * u, u, one], axis=1)
    slope = np.stack([u * u * 3.0, u * 2.0, one, zero], axis=1)
    return value, slope


def _surface_grid(patch: int, n: int):
    """Points and unit normals (cross of the t and s tangents) of one patch on
    its (n + 1) x (n + 1) grid of s, t = k/n: arrays of shape (n + 1, n + 1, 3)."""
    geometry = CONTROL_POINTS[PATCHES[patch]]                          # (4, 4, 3)
    coeff = np.einsum("rk,kjc,sj->rsc", BEZIER, geometry, BEZIER)     # B G B^T per coordinate
    value, slope = _powers(n)
    point = np.einsum("ar,rsc,bs->abc", value, coeff, value)
    s_dir = np.einsum("ar,rsc,bs->abc", slope, coeff, value)
    t_dir = np.einsum("ar,rsc,bs->abc", value, coeff, slope)
    normal = np.cross(t_dir, s_dir)
    length = np.linalg.norm(normal, axis=-1, keepdims=True)
    normal = np.divide(normal, length, out=normal.copy(), where=length > 0.0)
    return point, normal


def _cell_corners(n: int):
    """Grid indices (s, t) of the triangle corners in SPD order: per cell
    (s step, then t step) the triangles (0,0) (0,1) (1,1) and (1,1) (1,0) (0,0).
    Two arrays of shape (2 n^2, 3)."""
    a, b = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    ds = np.array([[0, 0, 1], [1, 1, 0]])
    dt = np.array([[0, 1, 1], [1, 0, 0]])
    return (a[:, :, None, None] + ds).reshape(-1, 3), (b[:, :, None, None] + dt).reshape(-1, 3)


def patch_triangles(n: int):
    """Per Bezier patch, in SPD order, the triangle vertices and normals
    (shape (m, 3, 3) each) after the cusp rule: a triangle with two or more
    corners on the z axis is dropped; a single corner there gets the normal
    (0, 0, 1) above z = 1.5 (the lid knob) or (0, 0, -1) below (the bottom)."""
    si, ti = _cell_corners(n)
    for patch in range(len(PATCHES)):
        point, normal = _surface_grid(patch, n)
        verts, norms = point[si, ti], normal[si, ti]
        on_axis = (np.abs(verts[..., 0]) <= CUSP_TOLERANCE) & (np.abs(verts[..., 1]) <= CUSP_TOLERANCE)
        keep = on_axis.sum(axis=1) <= 1
        verts, norms, on_axis = verts[keep], norms[keep], on_axis[keep]
        norms[on_axis] = 0.0
        norms[..., 2][on_axis] = np.where(verts[..., 2] > 1.5, 1.0, -1.0)[on_axis]
        yield verts, norms


def _checkerboard(w: NffWriter, n: int):
    """The n x n floor squares spanning -4..4 in x and y: the white ones
    ((s + t) odd) first, then the grey ones."""
    def coord(k):
        return 4.0 * (2.0 * k / n - 1.0)

    for color, parity in ((WHITE, 1), (GREY, 0)):
        material(w, color, kd=0.5, ks=0.5, highlight=30.0, ior=0.0)
        for s in range(n):
            for t in range(n):
                if (s + t) % 2 == parity:
                    x0, x1, y0, y1 = coord(s), coord(s + 1), coord(t), coord(t + 1)
                    w.polygon([(x0, y0, 0.0), (x1, y0, 0.0), (x1, y1, 0.0), (x0, y1, 0.0)])


def generate(size: int = DEFAULT_SIZE) -> str:
    """NFF text of the teapot scene at size factor `size` (n = 1 warns, as the SPD does)."""
    if size == 1:
        warnings.warn("teapot: a size of 1 is not supported by the SPD; writing it anyway", RayKernelWarning,
                      stacklevel=2)
    if size < 1:
        raise OptionError(f"teapot size factor must be a positive integer, got {size!r}")
    w = NffWriter()
    w.background(SKY_BLUE)
    w.view((4.86, 7.2, 5.4), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 45.0, 1.0, 512)
    w.light((-3.1, 9.8, 12.1))
    w.light((11.3, 5.1, 8.8))
    _checkerboard(w, size)
    material(w, TEAPOT_COLOR, kd=0.75, ks=0.25, highlight=37.0, ior=0.0)
    for verts, norms in patch_triangles(size):
        for v, nrm in zip(verts.tolist(), norms.tolist()):
            w.patch(v, nrm)
    return w.text()

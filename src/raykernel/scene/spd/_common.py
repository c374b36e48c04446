"""Pieces the SPD generators share: the Shine of a highlight angle, materials,
4x4 matrices in the SPD convention, polygon clean-up and the SPD random deviate.

    from raykernel.scene.nffwriter import NffWriter
    from raykernel.scene.spd._common import SKY_BLUE, material, rotation, transform_points

    w = NffWriter()
    w.background(SKY_BLUE)
    material(w, (1.0, 0.9, 0.7), kd=0.5, ks=0.5, highlight=37.0, ior=1.0)   # Shine 3.0827
    m = rotation(Z_AXIS, PI / 2)
    transform_points([1.0, 0.0, 0.0], m)                                   # -> [0, 1, 0]

Matrices follow the SPD library: row vectors multiply from the left
(p' = p @ M), the translation sits in the last row, and `a @ b` applies
`a` first, then `b`.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

PI = 3.141592653589793
SKY_BLUE = (0.078, 0.361, 0.753)
X_AXIS, Y_AXIS, Z_AXIS = 0, 1, 2
#: Adjacent polygon vertices closer than this are merged into one.
DEGENERATE_EDGE = 1.0e-6
#: The Shine written where no highlight is wanted.
NO_HIGHLIGHT_SHINE = 100000.0


def shine(highlight: float) -> float:
    """Phong exponent whose highlight falls to half strength at `highlight` degrees
    from the mirror direction: ln(0.5) / ln(cos a); 100000 for a <= 0, 1 for a >= 90."""
    a = PI * highlight / 180.0
    if a <= 0.0:
        return NO_HIGHLIGHT_SHINE
    if a >= PI / 2.0:
        return 1.0
    return math.log(0.5) / math.log(math.cos(a))


def material(w, color, kd: float, ks: float, highlight: float = 0.0, t: float = 0.0, ior: float = 0.0):
    """Write an `f` line: colour, diffuse and specular weights, the Shine of
    `highlight` (degrees), transmission and index of refraction."""
    w.fill(color, kd=kd, ks=ks, shine=shine(highlight), t=t, ior=ior)


# ---------------------------------------------------------------- vectors

def normalize(v) -> np.ndarray:
    """`v` scaled to unit length (returned unchanged if it has zero length)."""
    v = np.asarray(v, dtype=float)
    length = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    return v / length if length > 0.0 else v


# ---------------------------------------------------------------- matrices

def identity() -> np.ndarray:
    return np.eye(4)


def rotation(axis: int, angle: float) -> np.ndarray:
    """Rotation by `angle` radians about coordinate axis X_AXIS, Y_AXIS or Z_AXIS."""
    if axis not in (X_AXIS, Y_AXIS, Z_AXIS):
        raise ValueError(f"axis must be 0, 1 or 2, got {axis!r}")
    c, s = math.cos(angle), math.sin(angle)
    m = np.eye(4)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    m[i, i] = c
    m[j, j] = c
    m[i, j] = s
    m[j, i] = -s
    return m


def axis_rotation(axis, angle: float) -> np.ndarray:
    """Rotation by `angle` radians about the unit vector `axis`."""
    x, y, z = (float(a) for a in axis[:3])
    c, s = math.cos(angle), math.sin(angle)
    k = 1.0 - c
    return np.array([
        [x * x + (1.0 - x * x) * c, x * y * k + z * s, x * z * k - y * s, 0.0],
        [x * y * k - z * s, y * y + (1.0 - y * y) * c, y * z * k + x * s, 0.0],
        [x * z * k + y * s, y * z * k - x * s, z * z + (1.0 - z * z) * c, 0.0],
        [0.0, 0.0, 0.0, 1.0],
    ])


def scale_translate(scale: float, offset) -> np.ndarray:
    """Uniform scaling by `scale`, then translation by `offset`."""
    m = np.diag([scale, scale, scale, 1.0])
    m[3, :3] = offset
    return m


def transform_vectors(vectors, m: np.ndarray) -> np.ndarray:
    """Directions (shape (3,) or (n, 3)) moved by the linear part of `m`.
    The sums run x, y, z in turn, unfused, so results round as in the SPD."""
    v = np.asarray(vectors, dtype=float)
    return v[..., 0:1] * m[0, :3] + v[..., 1:2] * m[1, :3] + v[..., 2:3] * m[2, :3]


def transform_points(points, m: np.ndarray) -> np.ndarray:
    """Points (shape (3,) or (n, 3)) moved by `m`, translation included."""
    return transform_vectors(points, m) + m[3, :3]


# ---------------------------------------------------------------- polygons

def clean_polygon(vertices, eps: float = DEGENERATE_EDGE):
    """Merge runs of adjacent (cyclically) vertices closer than `eps`, keeping the
    later vertex of each close pair. Returns the vertex list, or None when fewer
    than three vertices remain."""
    verts = [tuple(map(float, v[:3])) for v in vertices]
    i = 0
    while i < len(verts):
        a, b = verts[i], verts[(i + 1) % len(verts)]
        if math.dist(a, b) < eps:
            del verts[i]
        else:
            i += 1
    return verts if len(verts) >= 3 else None


def polygon(w, vertices, eps: float = DEGENERATE_EDGE) -> bool:
    """Write polygon `vertices` after `clean_polygon`; False if it degenerated."""
    verts = np.asarray(vertices, dtype=float)[:, :3]
    edges = verts - np.roll(verts, -1, axis=0)
    if len(verts) >= 3 and np.einsum("ij,ij->i", edges, edges).min() >= eps * eps:
        w.polygon(verts.tolist())
        return True
    cleaned = clean_polygon(verts, eps)
    if cleaned is None:
        return False
    w.polygon(cleaned)
    return True


# ---------------------------------------------------------------- random numbers

_GAUSS_M = 134456
_GAUSS_A = 8121
_GAUSS_C = 28411


@lru_cache(maxsize=None)
def gauss_rand(seed: int) -> float:
    """The SPD library's portable normal deviate for integer `seed`: a linear
    congruential pair (x -> (28411 + 8121 x) mod 134456) fed to the polar
    Box-Muller method; the same seed always gives the same number."""
    x2 = seed
    while True:
        x1 = (_GAUSS_C + x2 * _GAUSS_A) % _GAUSS_M
        x2 = (_GAUSS_C + x1 * _GAUSS_A) % _GAUSS_M
        v1 = x1 * 2.0 / _GAUSS_M - 1.0
        v2 = x2 * 2.0 / _GAUSS_M - 1.0
        r = v1 * v1 + v2 * v2
        if r < 1.0:
            break
    return v1 * math.sqrt(-2.0 * math.log(r) / r)

"""Transform stacks and surface tessellators shared by teapot, jacks, sample and nurbtst.

    from raykernel.scene.spd._tessellate import TransformStack, torus_patches, nurbs_patches

    tx = TransformStack()
    tx.rotate(X_AXIS, -PI / 6)              # later calls act first on the object
    tx.push(); tx.scale(0.75)
    tx.point((1, 0, 0)), tx.radius(0.2)     # where a unit-x point and a 0.2 radius end up
    tx.pop()

    verts, norms = torus_patches((0, 0, 0), (0, 0, 1), 2.0, 0.5, 3, 3)   # (N, 3, 3) each

Matrices follow the SPD library (row vectors, p' = p @ M, translation in the
last row). Each tessellator returns triangles in the order the SPD library
emits them, with the vertex order and the per-vertex normals it writes.
"""

from __future__ import annotations

import math

import numpy as np

from ._common import PI, axis_rotation, rotation

#: Vectors shorter than this are treated as zero (the SPD's EPSILON2).
TINY = 1.0e-6


def _unit(v: np.ndarray) -> np.ndarray:
    """Rows of `v` scaled to unit length; zero rows stay zero."""
    length = np.sqrt(np.einsum("...i,...i->...", v, v))[..., None]
    return np.divide(v, length, out=np.array(v, dtype=float), where=length > 0.0)


class TransformStack:
    """The SPD library's current-transform stack. `rotate`, `scale` and
    `translate` put the new transform in front of the current one, so the
    last call made is the first applied to an object's own coordinates."""

    def __init__(self):
        self.matrix = np.eye(4)
        self._saved: list[np.ndarray] = []

    def push(self):
        self._saved.append(self.matrix.copy())

    def pop(self):
        self.matrix = self._saved.pop()

    def _prepend(self, m: np.ndarray):
        self.matrix = m @ self.matrix

    def rotate(self, axis: int, angle: float):
        self._prepend(rotation(axis, angle))

    def scale(self, factors):
        self._prepend(np.diag([*map(float, factors), 1.0]))

    def translate(self, offset):
        m = np.eye(4)
        m[3, :3] = offset
        self._prepend(m)

    def point(self, p) -> np.ndarray:
        """Point(s) `p` (shape (3,) or (n, 3)) in world coordinates."""
        return np.asarray(p, dtype=float) @ self.matrix[:3, :3] + self.matrix[3, :3]

    def normal(self, n) -> np.ndarray:
        """Normal(s) `n` carried by the inverse transpose (not re-normalised,
        as the SPD writes them)."""
        inverse = np.linalg.inv(self.matrix)
        return np.asarray(n, dtype=float) @ inverse[:3, :3].T

    def radius(self, r: float) -> float:
        """Radius `r` scaled by the length of the first matrix row (the SPD
        assumes uniform scaling)."""
        return r * float(np.linalg.norm(self.matrix[0, :3]))


def canonical_to_world(origin, up) -> np.ndarray:
    """Matrix taking the canonical frame (origin at 0, axis +Z) to the frame
    at `origin` with unit axis `up`: a rotation about (-up.y, up.x, 0) by
    acos(up.z), then the translation."""
    up = np.asarray(up, dtype=float)
    if abs(up[2]) == 1.0:
        pivot = np.array([1.0, 0.0, 0.0])
    else:
        pivot = np.array([-up[1], up[0], 0.0])
    pivot = _unit(pivot)
    m = axis_rotation(pivot, math.acos(up[2]))
    m[3, :3] = origin
    return m


def _steps(count: int, delta: float) -> np.ndarray:
    """0, delta, 2 delta, ... as a C loop accumulates them (count + 1 values)."""
    out = np.empty(count + 1)
    a = 0.0
    for i in range(count + 1):
        out[i] = a
        a += delta
    return out


def torus_patches(center, normal, major: float, minor: float, u_res: int, v_res: int):
    """Triangle patches of a torus of radii `major`/`minor` about axis `normal`
    at `center`: a (4 u_res) x (4 v_res) grid, two triangles per cell.
    Returns (vertices, normals), each of shape (32 u_res v_res, 3, 3)."""
    axis = np.asarray(normal, dtype=float)
    length = math.sqrt(float(axis @ axis))
    if length < TINY:
        raise ValueError("torus normal has zero length")
    to_world = canonical_to_world(center, axis / length)
    nu, nv = 4 * u_res, 4 * v_res
    theta_d, phi_d = 2.0 * PI / nu, 2.0 * PI / nv
    th0 = _steps(nu - 1, theta_d)[:, None]
    th1 = th0 + theta_d
    phi = _steps(nv - 1, phi_d)[None, :]

    def evaluate(th, ph):
        ring = major + minor * np.sin(th)
        p = np.stack(np.broadcast_arrays(ring * np.cos(ph), ring * np.sin(ph), minor * np.cos(th)), axis=-1)
        d_theta = np.stack(np.broadcast_arrays(minor * np.cos(th) * np.cos(ph), minor * np.cos(th) * np.sin(ph),
                                               -minor * np.sin(th)), axis=-1)
        d_phi = np.stack(np.broadcast_arrays(-ring * np.sin(ph), ring * np.cos(ph), 0.0 * ph), axis=-1)
        n = _unit(np.cross(d_theta, d_phi))
        return p @ to_world[:3, :3] + to_world[3, :3], n @ to_world[:3, :3]

    p00, n00 = evaluate(th0, phi)
    p01, n01 = evaluate(th0, phi + phi_d)
    p11, n11 = evaluate(th1, phi + phi_d)
    p10, n10 = evaluate(th1, phi)
    verts = np.stack([np.stack([p11, p01, p00], axis=-2), np.stack([p10, p11, p00], axis=-2)], axis=-3)
    norms = np.stack([np.stack([n11, n01, n00], axis=-2), np.stack([n10, n11, n00], axis=-2)], axis=-3)
    return verts.reshape(-1, 3, 3), norms.reshape(-1, 3, 3)


def disc_polygons(center, normal, inner: float, outer: float, u_res: int) -> list[np.ndarray]:
    """Quads of a flat ring (a disc when `inner` is 0) about axis `normal`:
    4 u_res sectors, each outer(u), outer(u + du), inner(u + du), inner(u).
    The caller drops coincident neighbours (a disc's sectors become triangles)."""
    axis = np.asarray(normal, dtype=float)
    length = math.sqrt(float(axis @ axis))
    if length < TINY:
        raise ValueError("disc normal has zero length")
    to_world = canonical_to_world(center, axis / length)
    n = 4 * u_res
    du = 2.0 * PI / n
    u = _steps(n - 1, du)
    width = outer - inner

    def ring(angle, r):
        p = np.stack([r * np.cos(angle), r * np.sin(angle), np.zeros_like(angle)], axis=-1)
        return p @ to_world[:3, :3] + to_world[3, :3]

    quads = np.stack([ring(u, inner + width), ring(u + du, inner + width), ring(u + du, inner), ring(u, inner)],
                     axis=1)
    return list(quads)


# ---------------------------------------------------------------- NURBS

def _open_uniform_knots(order: int, count: int) -> np.ndarray:
    """Open uniform knot vector: `order` zeros, then steps of one, then `order`
    copies of the last value (count + order knots)."""
    knots = [0.0]
    for i in range(1, count + order):
        knots.append(knots[-1] + 1.0 if order <= i < count + 1 else knots[-1])
    return np.array(knots, dtype=np.float32)


def _bspline_basis(order: int, count: int, knots: np.ndarray, t: np.ndarray):
    """B-spline basis values and first derivatives at parameters `t`
    (float32, evaluated in single precision like the SPD library).
    Returns two arrays of shape (len(t), count + order)."""
    f32 = np.float32
    size = count + order
    t = t.astype(f32)[:, None]
    x = knots.astype(f32)
    basis = ((t >= x[:-1]) & (t < x[1:])).astype(f32)
    basis = np.concatenate([basis, np.zeros((len(t), 1), f32)], axis=1)
    basis[t[:, 0] >= x[size - 1], count - 1] = 1.0
    dbasis = np.zeros_like(basis)
    zero = f32(0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        for k in range(2, order + 1):
            for i in range(size - k):
                lo = x[i + k - 1] - x[i]
                hi = x[i + k] - x[i + 1]
                bi, bj = basis[:, i], basis[:, i + 1]
                di, dj = dbasis[:, i], dbasis[:, i + 1]
                ti = (t[:, 0] - x[i]).astype(f32)
                tj = (x[i + k] - t[:, 0]).astype(f32)
                b1 = np.where(bi != 0, (ti * bi) / lo, zero)
                b2 = np.where(bj != 0, (tj * bj) / hi, zero)
                f1 = np.where(bi != 0, bi / lo, zero)
                f2 = np.where(bj != 0, -bj / hi, zero)
                f3 = np.where(di != 0, (ti * di) / lo, zero)
                f4 = np.where(dj != 0, (tj * dj) / hi, zero)
                basis[:, i] = b1 + b2
                dbasis[:, i] = ((f1 + f2) + f3) + f4
    return basis[:, :count], dbasis[:, :count]


def _float_steps(count: int, upper: float) -> np.ndarray:
    """0, d, 2d, ... (count + 1 values) accumulated in single precision, d = upper / count."""
    delta = np.float32(upper) / np.float32(count)
    out = np.empty(count + 1, dtype=np.float32)
    a = np.float32(0.0)
    for i in range(count + 1):
        out[i] = a
        a = np.float32(a + delta)
    return out


def nurbs_patches(u_order: int, v_order: int, control, u_res: int, v_res: int):
    """Triangle patches of a non-rational B-spline surface with open uniform
    knots; `control` has shape (nu, nv, 3 or 4) (a fourth, weight, column is
    ignored, as the SPD tessellator ignores it). The parameter ranges are cut
    into nu u_res by nv v_res steps, two triangles per cell.
    Returns (vertices, normals), each of shape (2 nu u_res nv v_res, 3, 3)."""
    control = np.asarray(control, dtype=float)[..., :3]
    nu, nv = control.shape[:2]
    us = _float_steps(nu * u_res, nu - u_order + 1)
    vs = _float_steps(nv * v_res, nv - v_order + 1)
    bu, dbu = _bspline_basis(u_order, nu, _open_uniform_knots(u_order, nu), us)
    bv, dbv = _bspline_basis(v_order, nv, _open_uniform_knots(v_order, nv), vs)

    def weights(a, b):
        return (a[:, None, :, None] * b[None, :, None, :]).astype(np.float32).astype(float)

    p = np.einsum("abij,ijk->abk", weights(bu, bv), control)
    du = np.einsum("abij,ijk->abk", weights(dbu, bv), control)
    dv = np.einsum("abij,ijk->abk", weights(bu, dbv), control)
    n = _unit(np.cross(dv, du))
    a0, a1 = slice(0, -1), slice(1, None)
    b0, b1 = slice(0, -1), slice(1, None)
    verts = np.stack([np.stack([p[a0, b0], p[a1, b0], p[a1, b1]], axis=-2),
                      np.stack([p[a0, b0], p[a1, b1], p[a0, b1]], axis=-2)], axis=-3)
    norms = np.stack([np.stack([n[a0, b0], n[a1, b0], n[a1, b1]], axis=-2),
                      np.stack([n[a0, b0], n[a1, b1], n[a0, b1]], axis=-2)], axis=-3)
    return verts.reshape(-1, 3, 3), norms.reshape(-1, 3, 3)

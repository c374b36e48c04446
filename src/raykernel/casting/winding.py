"""Generalized winding numbers of a triangle mesh at query points, over the mesh kernel's 4-wide tree.

    w = winding_numbers(mesh, points, threads=2)    # (N,) float64; about 1 inside a closed mesh, 0 outside
    inside = w > 0.5                                # RayScene.contains(points, method="winding")

The winding number of a closed, consistently oriented mesh at a point is 1
inside and 0 outside; for a mesh with holes it varies smoothly near them, so
`w > 0.5` decides inside-ness in a way that depends on no ray's direction
(Jacobson, Kavan and Sorkine-Hornung 2013). Each triangle adds its signed
solid angle over 4 pi (Van Oosterom and Strackee 1983). Far from a subtree it
is summed as one dipole (Barill et al. 2018, order 1): the subtree's
area-weighted normal N at its area-weighted centre p adds (p - q) . N /
(4 pi |p - q|^3) when |p - q| exceeds BETA times the subtree's radius around
p (the farthest corner of its box); nearer subtrees are opened, and leaves
near q are summed exactly. The far field errs by a few hundredths at most
(tests/test_meshbuild.py checks 0.05 against the exact sum), far less than
the half that separates inside from outside.
"""

from __future__ import annotations

import math

import numpy as np

from ..aggregates.widebvh import CHILD, COUNT
from ..geometry.parallel import for_ranges
from ..geometry.config import njit
from .meshcast import MeshKernel
from .rayinput import read_only
from .triangles4 import corner

BETA = 2.0          # open a subtree nearer than this many of its radii (Barill et al.'s accuracy parameter)
STACK = 512


@njit
def _dipoles(nodes, boxes, center, blocks):
    """(W, 4, 7): each child slot's area-weighted normal sum, area-weighted centre and radius,
    children before parents (the tree stores children after their parent)."""
    w_count = nodes.shape[0]
    out = np.zeros((w_count, 4, 7))
    area = np.zeros((w_count, 4))
    for w in range(w_count - 1, -1, -1):
        for s in range(4):
            cnt = nodes[w, COUNT + s]
            if cnt < 0:
                continue
            nx = ny = nz = px = py = pz = a_sum = 0.0
            if cnt > 0:
                first = nodes[w, CHILD + s]
                for lane in range(first, first + cnt):
                    ax, ay, az = corner(blocks, lane, 0), corner(blocks, lane, 1), corner(blocks, lane, 2)
                    ex, ey, ez = (corner(blocks, lane, 3) - ax, corner(blocks, lane, 4) - ay,
                                  corner(blocks, lane, 5) - az)
                    fx, fy, fz = (corner(blocks, lane, 6) - ax, corner(blocks, lane, 7) - ay,
                                  corner(blocks, lane, 8) - az)
                    cx, cy, cz = 0.5 * (ey * fz - ez * fy), 0.5 * (ez * fx - ex * fz), 0.5 * (ex * fy - ey * fx)
                    a = math.sqrt(cx * cx + cy * cy + cz * cz)
                    nx += cx
                    ny += cy
                    nz += cz
                    px += a * (ax + (ex + fx) / 3.0)
                    py += a * (ay + (ey + fy) / 3.0)
                    pz += a * (az + (ez + fz) / 3.0)
                    a_sum += a
            else:
                c = nodes[w, CHILD + s]
                for t in range(4):
                    if nodes[c, COUNT + t] < 0:
                        continue
                    nx += out[c, t, 0]
                    ny += out[c, t, 1]
                    nz += out[c, t, 2]
                    px += area[c, t] * out[c, t, 3]
                    py += area[c, t] * out[c, t, 4]
                    pz += area[c, t] * out[c, t, 5]
                    a_sum += area[c, t]
            lo_x, lo_y, lo_z = boxes[w, s] + center[0], boxes[w, 4 + s] + center[1], boxes[w, 8 + s] + center[2]
            hi_x, hi_y, hi_z = boxes[w, 12 + s] + center[0], boxes[w, 16 + s] + center[1], boxes[w, 20 + s] + center[2]
            if a_sum > 0.0:
                px, py, pz = px / a_sum, py / a_sum, pz / a_sum
            else:
                px, py, pz = 0.5 * (lo_x + hi_x), 0.5 * (lo_y + hi_y), 0.5 * (lo_z + hi_z)
            rx = max(px - lo_x, hi_x - px)
            ry = max(py - lo_y, hi_y - py)
            rz = max(pz - lo_z, hi_z - pz)
            out[w, s, 0], out[w, s, 1], out[w, s, 2] = nx, ny, nz
            out[w, s, 3], out[w, s, 4], out[w, s, 5] = px, py, pz
            out[w, s, 6] = math.sqrt(rx * rx + ry * ry + rz * rz)
            area[w, s] = a_sum
    return out


@njit(inline="always")
def solid_angle(ax, ay, az, bx, by, bz, cx, cy, cz):
    """The signed solid angle of triangle a, b, c (corners relative to the point) over 4 pi."""
    la = math.sqrt(ax * ax + ay * ay + az * az)
    lb = math.sqrt(bx * bx + by * by + bz * bz)
    lc = math.sqrt(cx * cx + cy * cy + cz * cz)
    det = ax * (by * cz - bz * cy) - ay * (bx * cz - bz * cx) + az * (bx * cy - by * cx)
    den = la * lb * lc + (ax * bx + ay * by + az * bz) * lc + (bx * cx + by * cy + bz * cz) * la \
        + (cx * ax + cy * ay + cz * az) * lb
    return math.atan2(det, den) / (2.0 * math.pi)


@njit
def _winding(nodes, dipoles, blocks, points, out, i0, i1):
    """out[i] for points i0..i1-1."""
    stack = np.empty(STACK, np.int64)
    for i in range(i0, i1):
        qx, qy, qz = points[i, 0], points[i, 1], points[i, 2]
        w = 0.0
        stack[0] = 0
        sp = 1
        while sp > 0:
            sp -= 1
            node = stack[sp]
            for s in range(4):
                cnt = nodes[node, COUNT + s]
                if cnt < 0:
                    continue
                dx, dy, dz = dipoles[node, s, 3] - qx, dipoles[node, s, 4] - qy, dipoles[node, s, 5] - qz
                d2 = dx * dx + dy * dy + dz * dz
                r = BETA * dipoles[node, s, 6]
                if d2 > r * r:
                    w += (dx * dipoles[node, s, 0] + dy * dipoles[node, s, 1] + dz * dipoles[node, s, 2]) \
                        / (4.0 * math.pi * d2 * math.sqrt(d2))
                elif cnt > 0:
                    first = nodes[node, CHILD + s]
                    for lane in range(first, first + cnt):
                        w += solid_angle(corner(blocks, lane, 0) - qx, corner(blocks, lane, 1) - qy,
                                         corner(blocks, lane, 2) - qz, corner(blocks, lane, 3) - qx,
                                         corner(blocks, lane, 4) - qy, corner(blocks, lane, 5) - qz,
                                         corner(blocks, lane, 6) - qx, corner(blocks, lane, 7) - qy,
                                         corner(blocks, lane, 8) - qz)
                else:
                    stack[sp] = nodes[node, CHILD + s]
                    sp += 1
        out[i] = w


def dipoles(mesh: MeshKernel) -> np.ndarray:
    """The far-field data winding_numbers needs of a 4-wide mesh kernel (W * 224 bytes)."""
    return _dipoles(mesh.wide.nodes, mesh.wide.boxes, mesh.wide.center, mesh.blocks)


def winding_numbers(mesh: MeshKernel, points: np.ndarray, far: np.ndarray, threads=None) -> np.ndarray:
    """The winding number of the mesh at each of points ((N, 3) float64); far: dipoles(mesh)."""
    out = np.empty(len(points))
    points = read_only(points)      # one compiled kernel whatever the caller's flags
    for_ranges(lambda i0, i1: _winding(mesh.wide.nodes, far, mesh.blocks, points, out, np.int64(i0), np.int64(i1)),
               len(points), threads, kernel=_winding, min_size=256)
    return out

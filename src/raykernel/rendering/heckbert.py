"""Heckbert's shading: the model of the minimal ray tracer printed in "Ray Tracing News" 2(1).

    r, g, b = trace(geo, mats, lights, ambient, ox, oy, oz, dx, dy, dz, max_depth, rays, ws, cnt)
    cam = camera_vectors(camera, width, height)      # the program's eye rays

`raykernel render SCENE --shading heckbert` (the default for example:heckbert). The model, as
the program computes it:

* the nearest hit with t > 1e-7, measured from the hit point itself (no offset); a miss returns
  the ambient colour (the scene's background); past the last level, black;
* at a hit, N = unit(centre - P) and d = -D.N; when d < 0 the normal flips, d = -d and
  eta = 1/ior, otherwise eta = ior. The program's `vcomb(-1., P, s->cen)` is centre - P, the
  inward normal, so a ray from outside flips it outward and refracts with 1/ior: Snell's law
  as it should be, read from the printed code (a reading of N as the outward normal would make
  "eta = ior" on entry a slip of the program's; it is not one);
* colour = ambient + the sum over lights of e x light colour, where e = kl (N.L) toward a
  luminous sphere's centre (N.L toward a point light) when e > 0 and the first thing the shadow
  ray meets is the light itself; then colour times the surface colour;
* the result is kt x (the refracted ray eta D + (eta d - sqrt(1 - eta^2 (1 - d^2))) N, black
  when the root is imaginary) + ks x (the reflected ray D + 2 d N) + kd x colour
  + kl x surface colour, max_depth levels deep (3 in the program);
* pixel (i, j) of a w x h image looks along (i - w/2, (h/2) / tan(angle/2), h/2 - j) in the
  camera's (right, forward, up) frame, integer halves, no half-pixel offset.

Rays of zero weight are not traced: they add nothing. Luminous spheres (kl > 0) are spheres
the rays see, and lights (render.light_table).
"""

import math

import numpy as np

from ..engine.traverse import ANY_HIT, CLOSEST, intersect
from ..geometry.work import SHADOW, charge_type, work_figures
from ..geometry import counters as C
from ..geometry.config import njit
from ..geometry.surface import dot, hit_normals
from .whitted import pop, spawn

T_MIN = 1e-7      # the program's hit threshold, in units of the ray's (unit) direction


def camera_vectors(camera, width: int, height: int) -> np.ndarray:
    """eye, direction of pixel (0, 0), step right, step down, as render.camera_vectors lays them out."""
    forward, right, up = camera.basis()
    depth = (height // 2) / math.tan(math.radians(camera.angle) / 2.0)
    first = depth * forward - (width // 2) * right + (height // 2) * up
    return np.concatenate([camera.eye, first, right, -up])


@njit(inline="always")
def _light_distance(lights, li, distance):
    """How far a shadow ray toward light li looks for anything in front of the light: to a point
    light, or to where the ray meets a luminous sphere (leaves it, from inside)."""
    radius = lights[li, 6]
    if distance > radius:
        return (distance - radius) * (1.0 - 1e-9)
    return (distance + radius) * (1.0 - 1e-9)


@njit(private=True)
def trace(geo, mats, lights, ambient, ox, oy, oz, dx, dy, dz, max_depth, rays, ws, cnt):
    """Colour of one eye ray under Heckbert's model; rays as whitted.trace lays them out."""
    r_out, g_out, b_out = 0.0, 0.0, 0.0
    spawn(rays, 0, 0.0, ox, oy, oz, dx, dy, dz, 1.0, 1.0, 1.0, 1, 0, -1, 1, None, cnt)
    top = 1
    while top > 0:
        top, ox, oy, oz, dx, dy, dz, wr, wg, wb, depth, ray_kind, _, _ = pop(rays, top, cnt)
        before = work_figures(ws.work, cnt)
        found = intersect(geo, ox, oy, oz, dx, dy, dz, T_MIN, np.inf, CLOSEST, ws, cnt)
        charge_type(ws.work, ray_kind, before, cnt)
        if not found:
            r_out += wr * ambient[0]
            g_out += wg * ambient[1]
            b_out += wb * ambient[2]
            continue
        cnt[C.RAYS_EYE_HIT + 2 * ray_kind] += 1
        hit_f, hit_i = ws.hit_f, ws.hit_i
        t = hit_f[0]
        px, py, pz = ox + t * dx, oy + t * dy, oz + t * dz
        _, _, _, nx, ny, nz, mat = hit_normals(geo, hit_f, hit_i, px, py, pz)
        nx, ny, nz = -nx, -ny, -nz          # the program's N: centre - P
        d = -dot(dx, dy, dz, nx, ny, nz)
        ior = mats[mat, 7]
        eta = ior
        if d < 0.0:
            nx, ny, nz = -nx, -ny, -nz
            eta = 1.0 / ior
            d = -d
        cr, cg, cb = ambient[0], ambient[1], ambient[2]
        before = work_figures(ws.work, cnt)
        for li in range(lights.shape[0]):
            lx, ly, lz = lights[li, 0] - px, lights[li, 1] - py, lights[li, 2] - pz
            distance = math.sqrt(dot(lx, ly, lz, lx, ly, lz))
            if distance == 0.0:
                continue
            lx, ly, lz = lx / distance, ly / distance, lz / distance
            e = dot(nx, ny, nz, lx, ly, lz)
            if e <= 0.0:
                continue
            cnt[C.RAYS_SHADOW] += 1
            if intersect(geo, px, py, pz, lx, ly, lz, T_MIN, _light_distance(lights, li, distance), ANY_HIT,
                         ws, cnt):
                cnt[C.RAYS_SHADOW_BLOCKED] += 1
                continue
            cr += e * lights[li, 3]
            cg += e * lights[li, 4]
            cb += e * lights[li, 5]
        charge_type(ws.work, SHADOW, before, cnt)
        sr, sg, sb = mats[mat, 0], mats[mat, 1], mats[mat, 2]
        kd, ks, kt, kl = mats[mat, 3], mats[mat, 4], mats[mat, 6], mats[mat, 8]
        r_out += wr * (kd * cr * sr + kl * sr)
        g_out += wg * (kd * cg * sg + kl * sg)
        b_out += wb * (kd * cb * sb + kl * sb)
        if depth >= max_depth:
            continue
        root = 1.0 - eta * eta * (1.0 - d * d)
        if kt > 0.0 and root > 0.0:
            c = eta * d - math.sqrt(root)
            top = spawn(rays, top, 0.0, px, py, pz, eta * dx + c * nx, eta * dy + c * ny, eta * dz + c * nz,
                        wr * kt, wg * kt, wb * kt, depth + 1, 2, -1, 0, None, cnt)
        if ks > 0.0:
            top = spawn(rays, top, 0.0, px, py, pz, dx + 2.0 * d * nx, dy + 2.0 * d * ny, dz + 2.0 * d * nz,
                        wr * ks, wg * ks, wb * ks, depth + 1, 1, -1, 0, None, cnt)
    return r_out, g_out, b_out

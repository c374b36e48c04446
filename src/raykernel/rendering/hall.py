"""Hall and Greenberg's shading (1983), with NFF's parameters: Fresnel-weighted reflection and
transmission, transmitted highlights and filtering by distance inside transparent media.

    r, g, b = trace(geo, mats, lights, background, ox, oy, oz, dx, dy, dz, max_depth, cutoff, medium,
                    filtered, tricks, state, rays, ws, cnt)

`raykernel render SCENE --shading hall`. How NFF's `f r g b Kd Ks Shine T ior` maps (our
choices, docs/guide/rendering.md, "Shading"):

* Ks and T are clamped to [0, 1] and, if Ks + T > 1, scaled to sum to 1. At a transparent
  surface (T > 0) the Fresnel reflectance F of the boundary (unpolarised, from ior and the
  angle; 1 at total internal reflection) splits T: the mirror ray weighs Ks + T F and the
  refracted ray T (1 - F), so the two never weigh more than 1. Opaque surfaces reflect Ks.
* Lights on the side the ray sees: Kd x colour x N.L and a highlight of the mirror weight x
  (R.L)^Shine, R the mirror direction (Phong's lobe, so that NFF's Shine means what it means
  under Whitted shading; Hall wrote it with the halfway vector). Lights on the far side of a
  transparent surface: a transmitted highlight of the refracted weight x (T'.L)^Shine, T' the
  refracted view direction: the light seen through the surface.
* A ray travelling inside a transparent object (entered by refraction, or from a camera with a
  `medium`) is filtered by the object's colour to the power of the distance it travels there,
  as is light on its way to a point there. Media do not nest: leaving one is leaving into air.
* Shadow rays: `filtered` False, any surface blocks the light; True (`--shadows filtered`),
  transparent surfaces pass it, times T at each crossing and filtered by distance inside.

The rays array has one more column than Whitted's: the medium (material, -1 for air).
"""

import math

import numpy as np

from ..geometry import counters as C
from ..geometry.config import njit
from ..geometry.primitives import normalize
from ..geometry.surface import dot, hit_normals
from ..geometry.work import SHADOW, charge_type, work_figures
from .shadows import filter_by_distance, light_through
from .tricks import ORIGIN, closest, hold_origin, shadow_slot
from .whitted import pop, seen_side, shadow_reach, spawn


@njit(inline="always")
def fresnel(cos_i, eta):
    """Unpolarised Fresnel reflectance of a dielectric boundary for light arriving at cos_i > 0
    with eta = n_incident / n_transmitted, and the cosine of the refracted ray (F = 1, cos 0 at
    total internal reflection)."""
    sin2_t = eta * eta * (1.0 - cos_i * cos_i)
    if sin2_t >= 1.0:
        return 1.0, 0.0
    cos_t = math.sqrt(1.0 - sin2_t)
    rs = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    rp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    return 0.5 * (rs * rs + rp * rp), cos_t


@njit(inline="always")
def weights(ks, kt, f):
    """(mirror weight, refracted weight) of a surface with Ks ks, T kt and Fresnel reflectance f."""
    ks, kt = min(max(ks, 0.0), 1.0), min(max(kt, 0.0), 1.0)
    if ks + kt > 1.0:
        ks, kt = ks / (ks + kt), kt / (ks + kt)
    return ks + kt * f, kt * (1.0 - f)


@njit(private=True)
def trace(geo, mats, lights, background, ox, oy, oz, dx, dy, dz, max_depth, cutoff, medium, filtered, tricks,
          state, rays, ws, cnt):
    """Colour of one eye ray under Hall's model; rays[k] = whitted.trace's columns, then the medium.
    medium: the camera's (-1: air)."""
    r_out, g_out, b_out = 0.0, 0.0, 0.0
    spawn(rays, 0, 0.0, ox, oy, oz, dx, dy, dz, 1.0, 1.0, 1.0, 1, 0, medium, 1, None, cnt)
    rays[0, ORIGIN] = -1.0      # leaves no object
    top = 1
    while top > 0:
        top, ox, oy, oz, dx, dy, dz, wr, wg, wb, depth, ray_kind, inside, node = pop(rays, top, cnt)
        before = work_figures(ws.work, cnt)
        found = closest(geo, ox, oy, oz, dx, dy, dz, 0.0, np.inf, node, tricks, state, rays, top, ws, cnt)
        charge_type(ws.work, ray_kind, before, cnt)
        hit_f, hit_i = ws.hit_f, ws.hit_i
        t = hit_f[0] if found else np.inf
        wr, wg, wb = filter_by_distance(mats, inside, t * math.sqrt(dot(dx, dy, dz, dx, dy, dz)), wr, wg, wb)
        if not found:
            r_out += wr * background[0]
            g_out += wg * background[1]
            b_out += wb * background[2]
            continue
        cnt[C.RAYS_EYE_HIT + 2 * ray_kind] += 1
        px, py, pz = ox + t * dx, oy + t * dy, oz + t * dz
        gx, gy, gz, sx, sy, sz, mat = hit_normals(geo, hit_f, hit_i, px, py, pz)
        cnt[C.NORMALS_COMPUTED] += 1
        hold_origin(state, ws)      # the object the shadow and secondary rays below leave
        entering, gx, gy, gz, sx, sy, sz, eps = seen_side(gx, gy, gz, sx, sy, sz, ox, oy, oz, dx, dy, dz, px, py, pz)
        ax, ay, az = px + eps * gx, py + eps * gy, pz + eps * gz     # on the side the ray came from
        bx, by, bz = px - eps * gx, py - eps * gy, pz - eps * gz     # the far side
        cr, cg, cb = mats[mat, 0], mats[mat, 1], mats[mat, 2]
        kd, ks, shine, tr, ior, kl = mats[mat, 3], mats[mat, 4], mats[mat, 5], mats[mat, 6], mats[mat, 7], mats[mat, 8]
        vx, vy, vz = normalize(-dx, -dy, -dz)
        cos_i = dot(vx, vy, vz, sx, sy, sz)
        # the boundary: refraction, Fresnel, the weights; the medium beyond it
        f, cos_t, eta = 1.0, 0.0, 1.0
        far = inside
        if tr > 0.0:
            eta = 1.0 / ior if entering else ior
            if ior <= 0.0:
                eta = 1.0
            f, cos_t = fresnel(max(cos_i, 0.0), eta)
            far = mat if entering else np.int64(-1)
        w_mirror, w_refract = weights(ks, tr, f)
        if f >= 1.0 and tr > 0.0:
            cnt[C.RAYS_TIR] += 1
        # refracted direction T' = -eta V + (eta cos_i - cos_t) N, none at total internal reflection
        qx = -eta * vx + (eta * cos_i - cos_t) * sx
        qy = -eta * vy + (eta * cos_i - cos_t) * sy
        qz = -eta * vz + (eta * cos_i - cos_t) * sz
        mx, my, mz = -vx + 2.0 * cos_i * sx, -vy + 2.0 * cos_i * sy, -vz + 2.0 * cos_i * sz     # the mirror direction
        dr, dg, db = 0.0, 0.0, 0.0
        hr, hg, hb = 0.0, 0.0, 0.0
        n_lights = lights.shape[0]
        before = work_figures(ws.work, cnt)
        for li in range(n_lights):
            near_side = True
            lx, ly, lz = lights[li, 0] - ax, lights[li, 1] - ay, lights[li, 2] - az
            ulx, uly, ulz = normalize(lx, ly, lz)
            n_dot_l = dot(sx, sy, sz, ulx, uly, ulz)
            if n_dot_l <= 0.0 or dot(gx, gy, gz, ulx, uly, ulz) <= 0.0:
                if tr <= 0.0 or w_refract <= 0.0:
                    continue        # faces away, and nothing comes through: no shadow ray
                near_side = False
                lx, ly, lz = lights[li, 0] - bx, lights[li, 1] - by, lights[li, 2] - bz
                ulx, uly, ulz = normalize(lx, ly, lz)
                if dot(gx, gy, gz, ulx, uly, ulz) >= 0.0:
                    continue
            if near_side and lights[li, 7] != 0.0 and ray_kind == 0:
                # Haines's light at the eye: an eye ray's hit is seen from it, so it is lit
                cnt[C.EYE_LIGHT_SKIPPED] += 1
                lr, lg, lb = 1.0, 1.0, 1.0
            elif near_side:
                cnt[C.RAYS_SHADOW] += 1
                lr, lg, lb = light_through(geo, mats, ax, ay, az, lx, ly, lz, shadow_reach(lights, li, lx, ly, lz),
                                           inside, filtered, shadow_slot(node, n_lights, li), tricks, state, ws, cnt)
            else:
                cnt[C.RAYS_SHADOW] += 1
                lr, lg, lb = light_through(geo, mats, bx, by, bz, lx, ly, lz, shadow_reach(lights, li, lx, ly, lz),
                                           far, filtered, np.int64(-1), tricks, state, ws, cnt)
            if lr == 0.0 and lg == 0.0 and lb == 0.0:
                cnt[C.RAYS_SHADOW_BLOCKED] += 1
                continue
            lr, lg, lb = lr * lights[li, 3], lg * lights[li, 4], lb * lights[li, 5]
            if near_side:
                dr += n_dot_l * lr
                dg += n_dot_l * lg
                db += n_dot_l * lb
                r_dot_l = dot(mx, my, mz, ulx, uly, ulz)
                if w_mirror > 0.0 and r_dot_l > 0.0:
                    spec = w_mirror * r_dot_l ** shine
                    hr += spec * lr
                    hg += spec * lg
                    hb += spec * lb
            else:
                t_dot_l = dot(qx, qy, qz, ulx, uly, ulz)
                if t_dot_l > 0.0:
                    spec = w_refract * t_dot_l ** shine
                    hr += spec * lr
                    hg += spec * lg
                    hb += spec * lb
        charge_type(ws.work, SHADOW, before, cnt)
        r_out += wr * (kd * cr * dr + hr + kl * cr)
        g_out += wg * (kd * cg * dg + hg + kl * cg)
        b_out += wb * (kd * cb * db + hb + kl * cb)
        if depth >= max_depth or (ks <= 0.0 and tr <= 0.0):
            continue
        if w_refract > 0.0:
            tx, ty, tz = normalize(qx, qy, qz)
            top = spawn(rays, top, cutoff, bx, by, bz, tx, ty, tz, wr * w_refract, wg * w_refract, wb * w_refract,
                        depth + 1, 2, far, 2 * node + 1, state, cnt)
        rx, ry, rz = normalize(mx, my, mz)
        top = spawn(rays, top, cutoff, ax, ay, az, rx, ry, rz, wr * w_mirror, wg * w_mirror, wb * w_mirror,
                    depth + 1, 1, inside, 2 * node, state, cnt)
    return r_out, g_out, b_out

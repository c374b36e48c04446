"""Whitted shading with NFF's parameters: the ray tree of one eye ray, on an explicit stack.

    trace(geo, mats, lights, background, ex, ey, ez, eyes, n, colors, max_depth, cutoff, filtered, tricks,
          state, rays, ws, cnt)         # colors[e] = the colour seen along eyes[e], for e < n

Kd diffuse and Ks Phong highlight (exponent Shine) from point lights, Ks mirror reflection,
T transmission by Snell's law with total internal reflection; a luminous surface (Kl, Heckbert's
luminance) adds Kl times its colour. filtered: True or False: shadow rays pass transparent
surfaces, times T, or not (shadows.py); None: not, without compiling that code. tricks, state: Haines's efficiency tricks and their per-tile memory (tricks.py).
rays: a (RAY_STACK, RAY_COLUMNS) scratch array; ws: traverse.workspace().
One call traces a batch of eye rays (a tile's), since a call that takes the scene's Geometry
passes every one of its arrays' pointers and sizes, about as long as a ray that misses takes to trace.
"""

import math

import numpy as np

from ..engine.traverse import ANY_HIT, CLOSEST, intersect
from ..geometry.work import SHADOW, charge_type, record_sample, start_samples, work_figures
from ..geometry import counters as C
from ..geometry.config import njit
from ..geometry.primitives import normalize
from ..geometry.surface import dot, hit_normals
from .shadows import light_through
from .tricks import ORIGIN, blocked, closest, hold_origin, pass_origin, shadow_slot

# Secondary rays start this far off the surface, relative to the magnitude of
# the coordinates involved: far above the rounding error of a double-precision
# hit point (about 1e-16 relative), far below any feature a scene can show.
OFFSET = 2.0 ** -32
RAY_STACK = 80           # a ray tree of depth 32 keeps at most 2 rays per level waiting
RAY_COLUMNS = 28         # origin, direction, weight, depth, kind, (hall.py's medium), ray-tree node, and from
                         # tricks.ORIGIN the object the ray leaves (kind, index, _, map: tricks.py)


@njit(inline="always")
def shadow_reach(lights, li, tx, ty, tz):
    """How far along (tx, ty, tz), the vector from a point to light li's position, a shadow ray
    looks for blockers: to the light itself (1), or for a luminous sphere (radius > 0) to just
    before its surface, where the ray meets it (from outside; from inside, where it leaves)."""
    radius = lights[li, 6]
    if radius == 0.0:
        return 1.0
    length = math.sqrt(tx * tx + ty * ty + tz * tz)
    if length > radius:
        return (1.0 - radius / length) * (1.0 - 1e-9)
    return (1.0 + radius / length) * (1.0 - 1e-9)


@njit(inline="always")
def spawn(rays, top, cutoff, ox, oy, oz, dx, dy, dz, wr, wg, wb, depth, kind, medium, node, state, cnt):
    """Push a ray of weight (wr, wg, wb) on the ray stack at `top`, as a ray of the ray tree's node
    `node` leaving the object tricks.hold_origin held, unless its largest weight falls below
    `cutoff` (0: none), which rays.cut_off counts. Returns the new top."""
    if cutoff > 0.0 and max(wr, max(wg, wb)) < cutoff:
        cnt[C.RAYS_CUT_OFF] += 1
        return top
    rays[top, 0], rays[top, 1], rays[top, 2] = ox, oy, oz
    rays[top, 3], rays[top, 4], rays[top, 5] = dx, dy, dz
    rays[top, 6], rays[top, 7], rays[top, 8] = wr, wg, wb
    rays[top, 9] = depth
    rays[top, 10] = kind
    rays[top, 11] = medium
    rays[top, 12] = node
    pass_origin(state, rays, top)
    return top + 1


@njit(inline="always")
def seen_side(gx, gy, gz, sx, sy, sz, ox, oy, oz, dx, dy, dz, px, py, pz):
    """The geometric and shading normals of the hit p of ray o + t d turned to the side the ray
    sees (two-sided shading; vertex normals may disagree with the winding), whether the ray enters
    the surface, and how far off it secondary rays start (OFFSET of the coordinates' magnitude):
    (entering, g, s, eps)."""
    entering = dot(gx, gy, gz, dx, dy, dz) < 0.0
    if not entering:
        gx, gy, gz = -gx, -gy, -gz
    if dot(sx, sy, sz, gx, gy, gz) < 0.0:
        sx, sy, sz = -sx, -sy, -sz
    eps = OFFSET * max(max(abs(px), abs(py)), max(abs(pz), max(max(abs(ox), abs(oy)), abs(oz))))
    return entering, gx, gy, gz, sx, sy, sz, eps


@njit(inline="always")
def pop(rays, top, cnt):
    """Take the ray on top of the ray stack (spawn's columns) and count it by its kind: (new top,
    origin, direction, weight, depth, kind, medium, node). Every shading model's loop starts so."""
    top -= 1
    cnt[C.RAYS_EYE + 2 * int(rays[top, 10])] += 1
    return (top, rays[top, 0], rays[top, 1], rays[top, 2], rays[top, 3], rays[top, 4], rays[top, 5],
            rays[top, 6], rays[top, 7], rays[top, 8], int(rays[top, 9]), int(rays[top, 10]),
            np.int64(rays[top, 11]), np.int64(rays[top, 12]))


@njit(private=True)
def trace(geo, mats, lights, background, ex, ey, ez, eyes, n, colors, max_depth, cutoff, filtered, tricks, state,
          rays, ws, cnt):
    """Colours of n eye rays from the eye (ex, ey, ez) along the unit directions eyes[:n, :3], in order, into
    colors[:n]: each ray's whole ray tree, depth first, on an explicit stack.
    rays[k] = origin(3), direction(3), weight(3), depth, kind (0 eye, 1 reflect, 2 refract)."""
    n_lights = lights.shape[0]
    r_out, g_out, b_out = 0.0, 0.0, 0.0
    e = 0
    top = 0
    samples = eyes.shape[1] > 3         # eyes[:, 3:5] the sample each eye ray is: its work is recorded there
    if samples:
        start_samples(ws.work, cnt)
    while True:     # one loop over the eye rays and their trees (a loop nest compiles slower)
        if top == 0:
            if e > 0:
                colors[e - 1, 0], colors[e - 1, 1], colors[e - 1, 2] = r_out, g_out, b_out
                if samples:
                    record_sample(ws.work, int(eyes[e - 1, 3]), int(eyes[e - 1, 4]), cnt)
            if e == n:
                break
            r_out, g_out, b_out = 0.0, 0.0, 0.0
            spawn(rays, 0, 0.0, ex, ey, ez, eyes[e, 0], eyes[e, 1], eyes[e, 2], 1.0, 1.0, 1.0, 1, 0, -1, 1, None, cnt)
            rays[0, ORIGIN] = -1.0      # leaves no object
            top = 1
            e += 1
        top, ox, oy, oz, dx, dy, dz, wr, wg, wb, depth, ray_kind, _, node = pop(rays, top, cnt)
        # `state is None` tested here, on trace's own argument: numba then prunes the tricks'
        # calls before it would inline them (it inlines before it prunes the callees' tests)
        before = work_figures(ws.work, cnt)
        if state is None:
            found = intersect(geo, ox, oy, oz, dx, dy, dz, 0.0, np.inf, CLOSEST, ws, cnt)
        else:
            found = closest(geo, ox, oy, oz, dx, dy, dz, 0.0, np.inf, node, tricks, state, rays, top, ws, cnt)
        charge_type(ws.work, ray_kind, before, cnt)
        if not found:
            r_out += wr * background[0]
            g_out += wg * background[1]
            b_out += wb * background[2]
            continue
        cnt[C.RAYS_EYE_HIT + 2 * ray_kind] += 1
        hit_f, hit_i = ws.hit_f, ws.hit_i
        t = hit_f[0]
        px, py, pz = ox + t * dx, oy + t * dy, oz + t * dz
        gx, gy, gz, sx, sy, sz, mat = hit_normals(geo, hit_f, hit_i, px, py, pz)
        cnt[C.NORMALS_COMPUTED] += 1
        if state is not None:
            hold_origin(state, ws)      # the object the shadow and secondary rays below leave
        entering, gx, gy, gz, sx, sy, sz, eps = seen_side(gx, gy, gz, sx, sy, sz, ox, oy, oz, dx, dy, dz, px, py, pz)
        ax, ay, az = px + eps * gx, py + eps * gy, pz + eps * gz     # on the side the ray came from
        cr, cg, cb = mats[mat, 0], mats[mat, 1], mats[mat, 2]
        kd, ks, shine, tr, ior = mats[mat, 3], mats[mat, 4], mats[mat, 5], mats[mat, 6], mats[mat, 7]
        ndx, ndy, ndz = normalize(dx, dy, dz)
        cos_i = -dot(ndx, ndy, ndz, sx, sy, sz)
        # mirror direction, also used for the Phong highlight
        rx, ry, rz = ndx + 2.0 * cos_i * sx, ndy + 2.0 * cos_i * sy, ndz + 2.0 * cos_i * sz
        dr, dg, db = 0.0, 0.0, 0.0
        hr, hg, hb = 0.0, 0.0, 0.0
        before = work_figures(ws.work, cnt)
        for li in range(n_lights):
            tlx, tly, tlz = lights[li, 0] - ax, lights[li, 1] - ay, lights[li, 2] - az
            ulx, uly, ulz = normalize(tlx, tly, tlz)
            n_dot_l = dot(sx, sy, sz, ulx, uly, ulz)
            if n_dot_l <= 0.0 or dot(gx, gy, gz, ulx, uly, ulz) <= 0.0:
                continue        # the surface faces away from this light: no shadow ray
            lr, lg, lb = lights[li, 3], lights[li, 4], lights[li, 5]
            if lights[li, 7] != 0.0 and ray_kind == 0:
                # Haines's light at the eye: an eye ray's hit is seen from it, so it is lit
                cnt[C.EYE_LIGHT_SKIPPED] += 1
            elif filtered is not None:      # None: opaque shadows, and numba compiles no walk through glass
                cnt[C.RAYS_SHADOW] += 1
                fr, fg, fb = light_through(geo, mats, ax, ay, az, tlx, tly, tlz,
                                           shadow_reach(lights, li, tlx, tly, tlz), np.int64(-1), filtered,
                                           shadow_slot(node, n_lights, li), tricks, state, ws, cnt)
                if fr == 0.0 and fg == 0.0 and fb == 0.0:
                    cnt[C.RAYS_SHADOW_BLOCKED] += 1
                    continue
                lr, lg, lb = lr * fr, lg * fg, lb * fb
            else:
                cnt[C.RAYS_SHADOW] += 1
                reach = shadow_reach(lights, li, tlx, tly, tlz)
                if state is None:
                    shadowed = intersect(geo, ax, ay, az, tlx, tly, tlz, 0.0, reach, ANY_HIT, ws, cnt)
                else:
                    shadowed = blocked(geo, ax, ay, az, tlx, tly, tlz, reach, ANY_HIT, shadow_slot(node, n_lights, li),
                                       tricks, state, ws, cnt)
                if shadowed:
                    cnt[C.RAYS_SHADOW_BLOCKED] += 1
                    continue
            dr += n_dot_l * lr
            dg += n_dot_l * lg
            db += n_dot_l * lb
            if ks > 0.0:
                r_dot_l = dot(rx, ry, rz, ulx, uly, ulz)
                if r_dot_l > 0.0:
                    spec = ks * r_dot_l ** shine
                    hr += spec * lr
                    hg += spec * lg
                    hb += spec * lb
        charge_type(ws.work, SHADOW, before, cnt)
        kl = mats[mat, 8]
        r_out += wr * (kd * cr * dr + hr + kl * cr)
        g_out += wg * (kd * cg * dg + hg + kl * cg)
        b_out += wb * (kd * cb * db + hb + kl * cb)
        if depth >= max_depth or (ks <= 0.0 and tr <= 0.0):
            continue
        reflect_weight = ks
        if tr > 0.0:
            eta = 1.0 / ior if entering else ior
            if ior <= 0.0:
                eta = 1.0
            k = 1.0 - eta * eta * (1.0 - cos_i * cos_i)
            if k < 0.0:
                reflect_weight += tr        # total internal reflection
                cnt[C.RAYS_TIR] += 1
            else:
                c2 = eta * cos_i - math.sqrt(k)
                tx, ty, tz = normalize(eta * ndx + c2 * sx, eta * ndy + c2 * sy, eta * ndz + c2 * sz)
                # from the far side
                top = spawn(rays, top, cutoff, px - eps * gx, py - eps * gy, pz - eps * gz, tx, ty, tz, wr * tr,
                            wg * tr, wb * tr, depth + 1, 2, -1, 2 * node + 1, state, cnt)
        rx, ry, rz = normalize(rx, ry, rz)
        top = spawn(rays, top, cutoff, ax, ay, az, rx, ry, rz, wr * reflect_weight, wg * reflect_weight,
                    wb * reflect_weight, depth + 1, 1, -1, 2 * node, state, cnt)

"""Whitted-style rendering of a scene, with exact counts of the work done.

    result = render(scene, accel="bvh", spd=True)
    result.image          # (height, width, 3) float RGB, not clamped
    result.stats          # counters, build statistics, times
    result.save("out.png")

Shading follows NFF: Kd diffuse and Ks Phong highlight (exponent Shine)
from point lights of intensity 1/sqrt(number of lights), Ks mirror
reflection, T transmission by Snell's law with total internal reflection.
`spd=True` follows the SPD test procedure (README, "Shading"): one eye ray per pixel
corner averaged into pixels, no adaptive cut-off; otherwise one ray per
pixel centre and rays whose weight falls below 1/512 are not cast.

The image is traced in tiles of TILE x TILE samples, in parallel; each
tile owns one row of counters, so counts and image bytes do not depend on
the number of threads. The tiles are traced in batches of n_tiles // 32 (at
least one), in a fixed order. With lazy structures (aggregates/lazyoctree.py,
rc.py) the image is traced coarse to fine (lazy_passes): one sample per tile
first, in passes that start with one tile, then the samples between them
level by level, so that the trees, refined after each pass from its counts,
are deepened wherever the image looks before most of its rays are cast.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numba
import numpy as np

from ..aggregates.lazyoctree import pass_ranges
from ..engine.compiletime import FIRST_RUN_SECONDS, CompileClock, first_run
from ..engine.flatten import flatten
from ..engine.parallel import default_threads, for_ranges
from ..engine.traverse import ANY_HIT, CLOSEST, intersect, workspace
from ..errors import OptionError
from ..geometry import counters as C
from ..geometry.config import compiled, njit, tell_once
from ..geometry.primitives import CONE, PATCH, POLYGON, SPHERE, cone_normal, normalize
from ..scene.model import Scene
from .stats import Stats

TILE = 16
RANGE_SAMPLES = 512          # samples a thread is handed at least: fewer cost more to hand over than to trace
CUTOFF = 1.0 / 512.0       # outside SPD mode: rays weighing less cannot change an 8-bit pixel
# Secondary rays start this far off the surface, relative to the magnitude of
# the coordinates involved: far above the rounding error of a double-precision
# hit point (about 1e-16 relative), far below any feature a scene can show.
OFFSET = 2.0 ** -32
RAY_STACK = 80           # a ray tree of depth 32 keeps at most 2 rays per level waiting


@njit(inline="always")
def _dot(ax, ay, az, bx, by, bz):
    return ax * bx + ay * by + az * bz


@njit(inline="always")
def _patch_normal(geo, idx, px, py, pz):
    """Interpolated vertex normal of patch idx at local point p: barycentric
    in the fan triangle (v0, vk, vk+1) that contains p."""
    s = geo.poly_start[idx]
    n = geo.poly_count[idx]
    v = geo.poly_verts
    vn = geo.poly_vnormals
    gx, gy, gz = geo.poly_normal[idx, 0], geo.poly_normal[idx, 1], geo.poly_normal[idx, 2]
    best_x, best_y, best_z = gx, gy, gz
    best_score = -1e300
    for k in range(1, n - 1):
        a, b, c = s, s + k, s + k + 1
        # barycentric coordinates from signed areas along the plane normal
        e1x, e1y, e1z = v[b, 0] - v[a, 0], v[b, 1] - v[a, 1], v[b, 2] - v[a, 2]
        e2x, e2y, e2z = v[c, 0] - v[a, 0], v[c, 1] - v[a, 1], v[c, 2] - v[a, 2]
        wx, wy, wz = px - v[a, 0], py - v[a, 1], pz - v[a, 2]
        area = _dot(e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x, gx, gy, gz)
        if area == 0.0:
            continue
        beta = _dot(wy * e2z - wz * e2y, wz * e2x - wx * e2z, wx * e2y - wy * e2x, gx, gy, gz) / area
        gamma = _dot(e1y * wz - e1z * wy, e1z * wx - e1x * wz, e1x * wy - e1y * wx, gx, gy, gz) / area
        alpha = 1.0 - beta - gamma
        score = min(alpha, min(beta, gamma))
        if score > best_score:
            best_score = score
            best_x = alpha * vn[a, 0] + beta * vn[b, 0] + gamma * vn[c, 0]
            best_y = alpha * vn[a, 1] + beta * vn[b, 1] + gamma * vn[c, 1]
            best_z = alpha * vn[a, 2] + beta * vn[b, 2] + gamma * vn[c, 2]
            if score >= 0.0:
                break
    return best_x, best_y, best_z



@njit(inline="always")
def surface(geo, kind, idx, px, py, pz):
    """Local geometric normal, local shading normal (both unnormalised) and
    material of primitive (kind, idx) at local point p."""
    if kind == SPHERE:
        nx = px - geo.sph_center[idx, 0]
        ny = py - geo.sph_center[idx, 1]
        nz = pz - geo.sph_center[idx, 2]
        return nx, ny, nz, nx, ny, nz, geo.sph_mat[idx]
    if kind == POLYGON or kind == PATCH:
        gx, gy, gz = geo.poly_normal[idx, 0], geo.poly_normal[idx, 1], geo.poly_normal[idx, 2]
        if kind == PATCH:
            sx, sy, sz = _patch_normal(geo, idx, px, py, pz)
            return gx, gy, gz, sx, sy, sz, geo.poly_mat[idx]
        return gx, gy, gz, gx, gy, gz, geo.poly_mat[idx]
    if kind == CONE:
        r0 = abs(geo.cone_r0[idx])
        slope = (abs(geo.cone_r1[idx]) - r0) / geo.cone_length[idx]
        nx, ny, nz = cone_normal(geo.cone_base[idx, 0], geo.cone_base[idx, 1], geo.cone_base[idx, 2],
                                 geo.cone_axis[idx, 0], geo.cone_axis[idx, 1], geo.cone_axis[idx, 2],
                                 r0, slope, px, py, pz)
        return nx, ny, nz, nx, ny, nz, geo.cone_mat[idx]
    # triangle
    f = geo.tri_faces
    v = geo.tri_verts
    a, b, c = f[idx, 0], f[idx, 1], f[idx, 2]
    e1x, e1y, e1z = v[b, 0] - v[a, 0], v[b, 1] - v[a, 1], v[b, 2] - v[a, 2]
    e2x, e2y, e2z = v[c, 0] - v[a, 0], v[c, 1] - v[a, 1], v[c, 2] - v[a, 2]
    gx, gy, gz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
    if not geo.tri_smooth[idx]:
        return gx, gy, gz, gx, gy, gz, geo.tri_mat[idx]
    area = _dot(gx, gy, gz, gx, gy, gz)
    wx, wy, wz = px - v[a, 0], py - v[a, 1], pz - v[a, 2]
    beta = _dot(wy * e2z - wz * e2y, wz * e2x - wx * e2z, wx * e2y - wy * e2x, gx, gy, gz) / area
    gamma = _dot(e1y * wz - e1z * wy, e1z * wx - e1x * wz, e1x * wy - e1y * wx, gx, gy, gz) / area
    alpha = 1.0 - beta - gamma
    vn = geo.tri_vnormals
    sx = alpha * vn[a, 0] + beta * vn[b, 0] + gamma * vn[c, 0]
    sy = alpha * vn[a, 1] + beta * vn[b, 1] + gamma * vn[c, 1]
    sz = alpha * vn[a, 2] + beta * vn[b, 2] + gamma * vn[c, 2]
    return gx, gy, gz, sx, sy, sz, geo.tri_mat[idx]


@njit(private=True)
def _trace(geo, mats, lights, background, ox, oy, oz, dx, dy, dz, max_depth, cutoff,
           rays, ws, cnt):
    """Colour of one eye ray: the whole ray tree, depth first, on an explicit stack.
    rays[k] = origin(3), direction(3), weight(3), depth, kind (0 eye, 1 reflect, 2 refract)."""
    r_out, g_out, b_out = 0.0, 0.0, 0.0
    n_lights = lights.shape[0]
    rays[0, 0], rays[0, 1], rays[0, 2], rays[0, 3], rays[0, 4], rays[0, 5] = ox, oy, oz, dx, dy, dz
    rays[0, 6] = rays[0, 7] = rays[0, 8] = 1.0
    rays[0, 9] = 1.0
    rays[0, 10] = 0.0
    top = 1
    while top > 0:
        top -= 1
        ox, oy, oz = rays[top, 0], rays[top, 1], rays[top, 2]
        dx, dy, dz = rays[top, 3], rays[top, 4], rays[top, 5]
        wr, wg, wb = rays[top, 6], rays[top, 7], rays[top, 8]
        depth = int(rays[top, 9])
        ray_kind = int(rays[top, 10])
        cnt[C.RAYS_EYE + 2 * ray_kind] += 1
        if not intersect(geo, ox, oy, oz, dx, dy, dz, 0.0, np.inf, CLOSEST,
                         ws, cnt):
            r_out += wr * background[0]
            g_out += wg * background[1]
            b_out += wb * background[2]
            continue
        cnt[C.RAYS_EYE_HIT + 2 * ray_kind] += 1
        hit_f, hit_i = ws[5], ws[6]
        t = hit_f[0]
        kind = hit_i[0]
        idx = hit_i[1]
        px, py, pz = ox + t * dx, oy + t * dy, oz + t * dz
        m = hit_f[1:13]
        lx = m[0] * px + m[1] * py + m[2] * pz + m[3]
        ly = m[4] * px + m[5] * py + m[6] * pz + m[7]
        lz = m[8] * px + m[9] * py + m[10] * pz + m[11]
        gx, gy, gz, sx, sy, sz, mat = surface(geo, kind, idx, lx, ly, lz)
        # normals to world space by the transpose of the world-to-local map
        gx, gy, gz = normalize(m[0] * gx + m[4] * gy + m[8] * gz, m[1] * gx + m[5] * gy + m[9] * gz,
                                m[2] * gx + m[6] * gy + m[10] * gz)
        sx, sy, sz = normalize(m[0] * sx + m[4] * sy + m[8] * sz, m[1] * sx + m[5] * sy + m[9] * sz,
                                m[2] * sx + m[6] * sy + m[10] * sz)
        if hit_i[3] != 0:
            # a surface a CSG difference cut: its outside is the operand's inside
            gx, gy, gz, sx, sy, sz = -gx, -gy, -gz, -sx, -sy, -sz
        entering = _dot(gx, gy, gz, dx, dy, dz) < 0.0
        if not entering:
            # two-sided: shade the side the ray sees
            gx, gy, gz = -gx, -gy, -gz
        if _dot(sx, sy, sz, gx, gy, gz) < 0.0:
            # vertex normals may disagree with the winding; keep them on the seen side
            sx, sy, sz = -sx, -sy, -sz
        eps = OFFSET * max(max(abs(px), abs(py)), max(abs(pz), max(max(abs(ox), abs(oy)), abs(oz))))
        ax, ay, az = px + eps * gx, py + eps * gy, pz + eps * gz     # on the side the ray came from
        cr, cg, cb = mats[mat, 0], mats[mat, 1], mats[mat, 2]
        kd, ks, shine, tr, ior = mats[mat, 3], mats[mat, 4], mats[mat, 5], mats[mat, 6], mats[mat, 7]
        ndx, ndy, ndz = normalize(dx, dy, dz)
        cos_i = -_dot(ndx, ndy, ndz, sx, sy, sz)
        # mirror direction, also used for the Phong highlight
        rx, ry, rz = ndx + 2.0 * cos_i * sx, ndy + 2.0 * cos_i * sy, ndz + 2.0 * cos_i * sz
        dr, dg, db = 0.0, 0.0, 0.0
        hr, hg, hb = 0.0, 0.0, 0.0
        for li in range(n_lights):
            tlx, tly, tlz = lights[li, 0] - ax, lights[li, 1] - ay, lights[li, 2] - az
            ulx, uly, ulz = normalize(tlx, tly, tlz)
            n_dot_l = _dot(sx, sy, sz, ulx, uly, ulz)
            if n_dot_l <= 0.0 or _dot(gx, gy, gz, ulx, uly, ulz) <= 0.0:
                continue        # the surface faces away from this light: no shadow ray
            cnt[C.RAYS_SHADOW] += 1
            if intersect(geo, ax, ay, az, tlx, tly, tlz, 0.0, 1.0, ANY_HIT,
                         ws, cnt):
                cnt[C.RAYS_SHADOW_BLOCKED] += 1
                continue
            dr += n_dot_l * lights[li, 3]
            dg += n_dot_l * lights[li, 4]
            db += n_dot_l * lights[li, 5]
            if ks > 0.0:
                r_dot_l = _dot(rx, ry, rz, ulx, uly, ulz)
                if r_dot_l > 0.0:
                    spec = ks * r_dot_l ** shine
                    hr += spec * lights[li, 3]
                    hg += spec * lights[li, 4]
                    hb += spec * lights[li, 5]
        r_out += wr * (kd * cr * dr + hr)
        g_out += wg * (kd * cg * dg + hg)
        b_out += wb * (kd * cb * db + hb)
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
            else:
                tw = tr
                if cutoff == 0.0 or max(wr, max(wg, wb)) * tw >= cutoff:
                    c2 = eta * cos_i - math.sqrt(k)
                    bx, by, bz = px - eps * gx, py - eps * gy, pz - eps * gz   # the far side
                    rays[top, 0], rays[top, 1], rays[top, 2] = bx, by, bz
                    tx, ty, tz = normalize(eta * ndx + c2 * sx, eta * ndy + c2 * sy, eta * ndz + c2 * sz)
                    rays[top, 3], rays[top, 4], rays[top, 5] = tx, ty, tz
                    rays[top, 6], rays[top, 7], rays[top, 8] = wr * tw, wg * tw, wb * tw
                    rays[top, 9] = depth + 1
                    rays[top, 10] = 2.0
                    top += 1
        if cutoff == 0.0 or max(wr, max(wg, wb)) * reflect_weight >= cutoff:
            rays[top, 0], rays[top, 1], rays[top, 2] = ax, ay, az
            rx, ry, rz = normalize(rx, ry, rz)
            rays[top, 3], rays[top, 4], rays[top, 5] = rx, ry, rz
            rays[top, 6], rays[top, 7], rays[top, 8] = wr * reflect_weight, wg * reflect_weight, wb * reflect_weight
            rays[top, 9] = depth + 1
            rays[top, 10] = 1.0
            top += 1
    return r_out, g_out, b_out


@njit
def _render_tiles(geo, mats, lights, background, cam, samples_w, samples_h, tile_x, tile_y, first, last, row0,
                  max_depth, cutoff, out, counters, passes, step, coarse):
    """Trace tiles first..last-1 of the sample grid into `out`, adding into one counter row per tile.
    cam = eye(3), direction to sample (0, 0) (3), step right (3), step down (3).
    Within each tile only the samples on the lattice of `step` (every step-th row and column),
    less those on the coarser lattice of `coarse` (0: none) traced before.
    passes[tile - row0]: the tile's pass counts of lazy structures (aggregates/lazyoctree.py)."""
    for tile in range(first, last):
        ws = workspace()
        rays = np.zeros((RAY_STACK, 11))
        cnt = np.zeros(C.N_COUNTERS + passes.shape[1], np.int64)
        _render_tile(geo, mats, lights, background, cam, samples_w, samples_h, tile_x[tile], tile_y[tile], max_depth,
                     cutoff, out, step, coarse, rays, ws, cnt)
        for k in range(C.N_COUNTERS):
            counters[tile, k] += cnt[k]
        for k in range(passes.shape[1]):
            passes[tile - row0, k] = cnt[C.N_COUNTERS + k]


@njit(private=True)     # one call per tile: the pixels' calls into _trace count no references
def _render_tile(geo, mats, lights, background, cam, samples_w, samples_h, x0, y0, max_depth, cutoff, out, step,
                 coarse, rays, ws, cnt):
    """The samples of the tile at (x0, y0) for _render_tiles, with the tile's workspace and counters."""
    for j in range(y0, min(y0 + TILE, samples_h), step):
        for i in range(x0, min(x0 + TILE, samples_w), step):
            if coarse > 0 and (i - x0) % coarse == 0 and (j - y0) % coarse == 0:
                continue
            dx = cam[3] + i * cam[6] + j * cam[9]
            dy = cam[4] + i * cam[7] + j * cam[10]
            dz = cam[5] + i * cam[8] + j * cam[11]
            dx, dy, dz = normalize(dx, dy, dz)
            r, g, b = _trace(geo, mats, lights, background, cam[0], cam[1], cam[2], dx, dy, dz,
                             max_depth, cutoff, rays, ws, cnt)
            out[j, i, 0] = r
            out[j, i, 1] = g
            out[j, i, 2] = b


def lazy_passes(n_tiles: int, batch: int) -> list[tuple[int, int, int, int]]:
    """The passes of a render with lazy structures, as (step, coarse, first tile, last tile):
    the image's samples on a lattice of every TILE-th row and column first (one per tile), in
    runs of 1, 1, 2, 4, ... tiles up to `batch`; then the lattice halved (the samples not yet
    traced) level by level down to every sample, in runs of `batch` tiles."""
    out = [(TILE, 0, a, b) for a, b in pass_ranges(n_tiles, 1, batch)]
    step = TILE // 2
    while step >= 1:
        out += [(step, 2 * step, a, min(n_tiles, a + batch)) for a in range(0, n_tiles, batch)]
        step //= 2
    return out


def camera_vectors(camera, width: int, height: int, corners: bool) -> np.ndarray:
    """eye, direction to the first sample, step to the right, step down.
    NFF's angle spans the centres of the outermost pixels (height, and width
    with square pixels); corner samples lie half a pixel further out."""
    forward, right, up = camera.basis()
    spacing = 2.0 * math.tan(math.radians(camera.angle) / 2.0) / max(height - 1, 1)
    shift = 0.5 if corners else 0.0
    first = forward + (-(width - 1) / 2.0 - shift) * spacing * right + ((height - 1) / 2.0 + shift) * spacing * up
    return np.concatenate([camera.eye, first, spacing * right, -spacing * up])


def material_table(scene: Scene) -> np.ndarray:
    mats = scene.materials or []
    table = np.zeros((max(1, len(mats)), 8))
    table[0] = [1, 1, 1, 1, 0, 0, 0, 1]
    for i, m in enumerate(mats):
        table[i] = [*m.color, m.kd, m.ks, m.shine, m.t, m.ior]
    return table


def light_table(scene: Scene) -> np.ndarray:
    """Position and colour times the SPD's suggested intensity 1/sqrt(n)."""
    n = len(scene.lights)
    table = np.zeros((n, 6))
    for i, light in enumerate(scene.lights):
        color = np.ones(3) if light.color is None else light.color
        table[i, :3] = light.position
        table[i, 3:] = color / math.sqrt(n)
    return table


@dataclass
class RenderResult:
    image: np.ndarray       # (height, width, 3) float RGB
    stats: Stats

    def to_uint8(self) -> np.ndarray:
        from .imageio import to_uint8
        return to_uint8(self.image)

    def save(self, path) -> None:
        """Write the image in the format the suffix names (imageio.save_image)."""
        from .imageio import save_image
        save_image(self.image, path)

    def _repr_html_(self) -> str:
        from .imageio import png_data_uri
        return (f'<div><img src="{png_data_uri(self.image)}" style="image-rendering:pixelated"/>'
                f"{self.stats._repr_html_()}</div>")


def render(scene: Scene, accel: str = "bvh", resolution: int | None = None, spd: bool = False,
           max_depth: int = 5, threads: int | None = None, progress=None, max_memory=None) -> RenderResult:
    """Render `scene`; returns the float image and the statistics.

    accel: the default accelerator spec for groups that name none.
    resolution: square image size (default: the scene camera's).
    spd: follow the SPD test procedure (corner rays, no cut-off).
    threads: worker threads (default: all cores).
    progress: callable(done, total) called after each pass, in samples (of full tiles).
    max_memory: the memory budget of every build, in bytes or as "8G" (default: half of this
    machine's memory); a structure that would need more is a MemoryBudgetError.
    """
    if isinstance(max_depth, bool) or not isinstance(max_depth, (int, np.integer)) or not 1 <= max_depth <= 32:
        raise OptionError(f"max_depth must be an integer in [1, 32], got {max_depth!r}")
    if resolution is not None and (isinstance(resolution, bool) or not isinstance(resolution, (int, np.integer))
                                   or not 1 <= resolution <= 16384):
        raise OptionError(f"resolution must be an integer in [1, 16384], got {resolution!r}")
    if threads is not None:
        if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 1:
            raise OptionError(f"threads must be a positive integer, got {threads!r}")
        numba.set_num_threads(min(int(threads), numba.config.NUMBA_NUM_THREADS))
    n_threads = int(threads) if threads is not None else default_threads()
    width = height = resolution
    if resolution is None:
        width, height = scene.camera.width, scene.camera.height

    t0 = time.perf_counter()
    with CompileClock() as build_clock:     # the builders' kernels compile on first use too
        geo, build = flatten(scene, accel, max_memory)
    preprocess = time.perf_counter() - t0 - build_clock.seconds

    sw, sh = (width + 1, height + 1) if spd else (width, height)
    tiles_x = np.arange(0, sw, TILE)
    tiles_y = np.arange(0, sh, TILE)
    tile_x = np.tile(tiles_x, len(tiles_y)).astype(np.int64)
    tile_y = np.repeat(tiles_y, len(tiles_x)).astype(np.int64)
    n_tiles = len(tile_x)
    samples = np.zeros((sh, sw, 3))
    counts = np.zeros((n_tiles, C.N_COUNTERS), np.int64)
    cam = camera_vectors(scene.camera, width, height, corners=spd)
    mats, lights = material_table(scene), light_table(scene)
    cutoff = 0.0 if spd else CUTOFF

    t1 = time.perf_counter()
    lazy = build.get("lazy")     # lazy structures: refined after each pass
    batch = max(1, n_tiles // 32)     # lazy: the pass schedule, which must not depend on the threads
    if lazy is None:
        # passes of about 1/32 of the image (the progress bar's steps), with enough tiles for every thread
        size = max(batch, 4 * n_threads)
        passes = [(1, 0, a, min(n_tiles, a + size)) for a in range(0, n_tiles, size)]
    else:
        passes = lazy_passes(n_tiles, batch)
    # samples of full tiles each pass traces, for the progress report
    work = [(last - first) * ((TILE // step) ** 2 - (TILE // coarse) ** 2 if coarse else (TILE // step) ** 2)
            for step, coarse, first, last in passes]
    done, total = 0, sum(work)
    if not compiled(_render_tiles) and first_run():
        tell_once("render", f"raykernel: compiling the renderer's kernels (first render after install, about "
                            f"{FIRST_RUN_SECONDS} s; cached for later processes)")
    with CompileClock() as clock:
        for (step, coarse, first, last), part in zip(passes, work):
            pass_counts = np.zeros((last - first, 0 if lazy is None else lazy.columns), np.int64)

            def tiles(lo, hi, first=first, step=step, coarse=coarse, geo=geo, pass_counts=pass_counts):
                _render_tiles(geo, mats, lights, scene.background, cam, sw, sh, tile_x, tile_y, first + lo, first + hi,
                              first, max_depth, cutoff, samples, counts, pass_counts, step, coarse)
            for_ranges(tiles, last - first, n_threads, kernel=_render_tiles,
                       min_size=-(-RANGE_SAMPLES * (last - first) // max(1, part)))
            if lazy is not None:
                geo = lazy.refine(geo, pass_counts)
            done += part
            if progress is not None:
                progress(done, total)
    trace = time.perf_counter() - t1 - clock.seconds
    if lazy is not None:
        lazy.update_stats(build, geo)

    if spd:
        image = 0.25 * (samples[:-1, :-1] + samples[1:, :-1] + samples[:-1, 1:] + samples[1:, 1:])
    else:
        image = samples
    stats = Stats.from_counters(counts.sum(axis=0), build, preprocess=preprocess, trace=trace, compile=build_clock.seconds + clock.seconds,
                                info={"scene": scene.source, "accel": accel, "resolution": [width, height],
                                      "spd": spd, "max_depth": max_depth,
                                      "threads": n_threads,
                                      "primitives": scene.count_primitives()})
    return RenderResult(image=image, stats=stats)

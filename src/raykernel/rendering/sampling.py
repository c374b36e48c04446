"""Pixels from samples: one ray per pixel, jittered supersampling (Cook 1984) or Whitted's
adaptive supersampling, under any shading model (whitted.py, hall.py, heckbert.py).

    render(scene, aa="jitter", samples=16, seed=1)          # 4 x 4 strata, one random ray in each
    render(scene, aa="adaptive", aa_threshold=0.1, aa_depth=2)

The render driver (render.py) calls `render_pixels` in place of its plain kernel whenever the
shading is not Whitted's or a sampler is asked for; it keeps the same tiles, passes and
counter rows, over pixels rather than samples.

* jitter: a k x k grid of strata over the pixel (samples = k^2), one ray through a random point
  of each; the pixel is their mean.
* adaptive: the pixel's four corners first; where they differ by more than the threshold (in
  any channel, max - min), the square is cut in four and its new corners traced, down to
  aa_depth cuts; the pixel is the area-weighted mean of the squares' corner means. Every point
  is traced once for all the pixels of a tile (one call of the kernel) that share it, as
  Whitted shared them, so it never traces more than full supersampling of the tile would.

Random numbers come from a hash of (seed, pixel, sample): an image is the same at any thread
count and in any tile order.
"""

import numpy as np

from ..geometry.parallel import claim, finished
from ..engine.traverse import workspace
from ..geometry.work import record_sample, sample_work, start_samples
from ..geometry import counters as C
from ..geometry.config import njit
from ..geometry.primitives import normalize
from . import hall, heckbert, whitted
from .tricks import memo as tricks_memo

SINGLE, JITTER, ADAPTIVE = np.int64(0), np.int64(1), np.int64(2)
SAMPLERS = {"none": SINGLE, "jitter": JITTER, "adaptive": ADAPTIVE}
SHADINGS = ("whitted", "heckbert", "hall")
MAX_AA_DEPTH = 4                 # 17 x 17 points per pixel at most
_SQUARES = 3 * MAX_AA_DEPTH + 1  # adaptive: squares waiting at most (each cut pops one, pushes four)


def model_arguments(shading: str, medium):
    """The shading model as the kernel's (whitted, heckbert, medium) arguments: each None unless
    its model is chosen (whitted, heckbert: True; medium: the camera's medium, -1 for air), so
    that numba prunes the other models' branches (it prunes a branch on `argument is not None`
    only where the argument is None) and a render compiles only its own model's trace."""
    return (True if shading == "whitted" else None), (True if shading == "heckbert" else None), \
        (medium if shading == "hall" else None)


@njit(inline="always")
def _uniform(seed, pixel, k):
    """A uniform number in [0, 1) from (seed, pixel, k): splitmix64's finaliser over their mix."""
    z = (np.uint64(seed) * np.uint64(0x9E3779B97F4A7C15)) ^ (np.uint64(pixel) * np.uint64(0xD1B54A32D192ED03))
    z = z + np.uint64(k) * np.uint64(0x8CB92BA72F3D8DD7)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    z = z ^ (z >> np.uint64(31))
    return (z >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@njit(inline="always")
def _sample(geo, mats, lights, background, cam, u, v, whitted_on, heckbert_on, max_depth, cutoff, filtered, tricks,
            medium, state, rays, eye, color, ws, cnt):
    """Colour seen through point (u, v) of the image plane, in pixels from pixel (0, 0), under
    the model whose argument is not None (model_arguments).
    eye, color: (1, 3) scratch for whitted.trace, which traces batches of eye rays."""
    dx = cam[3] + u * cam[6] + v * cam[9]
    dy = cam[4] + u * cam[7] + v * cam[10]
    dz = cam[5] + u * cam[8] + v * cam[11]
    dx, dy, dz = normalize(dx, dy, dz)
    r = g = b = 0.0
    if heckbert_on is not None:
        r, g, b = heckbert.trace(geo, mats, lights, background, cam[0], cam[1], cam[2], dx, dy, dz, max_depth,
                                 rays, ws, cnt)
    if medium is not None:
        r, g, b = hall.trace(geo, mats, lights, background, cam[0], cam[1], cam[2], dx, dy, dz, max_depth, cutoff,
                             medium, filtered, tricks, state, rays, ws, cnt)
    if whitted_on is not None:
        eye[0, 0], eye[0, 1], eye[0, 2] = dx, dy, dz
        # n as an int64, the type the tiles' batches give it: a literal 1 had numba compile trace again
        whitted.trace(geo, mats, lights, background, cam[0], cam[1], cam[2], eye, np.int64(1), color, max_depth,
                      cutoff, filtered, tricks, state, rays, ws, cnt)
        r, g, b = color[0, 0], color[0, 1], color[0, 2]
    return r, g, b


@njit
def render_pixels(geo, mats, lights, background, cam, width, height, tile_x, tile_y, counter, last, row0, max_depth,
                   cutoff, out, counters, passes, step, coarse, tile_size, whitted_on, heckbert_on, filtered, tricks,
                   starts, medium, sampler, samples, seed, threshold, aa_depth, layer, levels, probe):
    """render._render_tiles over pixels (tiles of tile_size), each from `sampler`'s samples
    under the model whose argument (whitted_on, heckbert_on or medium) is not None
    (model_arguments); filtered shadows or not. layer: None, or each pixel's record of the work
    of all its samples (geometry/work.py), `levels` nesting levels split; probe: None, or the
    event log of one pixel (rendering/explain.py)."""
    cells = tile_size << aa_depth if sampler == ADAPTIVE else 0
    eye = np.zeros((1, 3))      # whitted.trace's batch of one ray
    color = np.zeros((1, 3))
    while True:
        tile = claim(counter)
        if tile >= last:
            break
        ws = workspace(np.int64(0), sample_work(layer, levels, probe, tile_x[tile], tile_y[tile], tile_size))
        rays = np.zeros((whitted.RAY_STACK, whitted.RAY_COLUMNS))
        state = tricks_memo(lights.shape[0], starts)
        cnt = np.zeros(C.N_COUNTERS + passes.shape[1], np.int64)
        lattice = np.zeros((cells + 1, cells + 1, 3))
        known = np.zeros((cells + 1, cells + 1), np.bool_)
        squares = np.zeros((_SQUARES, 4), np.int64)
        _render_tile(geo, mats, lights, background, cam, width, height, tile_x[tile], tile_y[tile], tile_size,
                     max_depth, cutoff, out, step, coarse, whitted_on, heckbert_on, filtered, tricks, medium, sampler,
                     samples, seed, threshold, aa_depth, state, rays, eye, color, ws, cnt, lattice, known, squares)
        for k in range(C.N_COUNTERS):
            counters[tile, k] += cnt[k]
        for k in range(passes.shape[1]):
            passes[tile - row0, k] = cnt[C.N_COUNTERS + k]
        finished(counter)


@njit(private=True)     # one call per tile: the samples' calls count no references
def _render_tile(geo, mats, lights, background, cam, width, height, x0, y0, tile_size, max_depth, cutoff, out,
                 step, coarse, whitted_on, heckbert_on, filtered, tricks, medium, sampler, samples, seed, threshold,
                 aa_depth, state, rays, eye, color, ws, cnt, lattice, known, squares):
    """The pixels of the tile at (x0, y0) for render_pixels. lattice, known: the adaptive
    sampler's points of the tile, 2^aa_depth per pixel side, traced on first use; squares: its
    stack of squares, rows of (column, row, size) on that lattice and the cuts made."""
    k = 1
    while k * k < samples:
        k += 1
    start_samples(ws.work, cnt)
    for j in range(y0, min(y0 + tile_size, height), step):
        for i in range(x0, min(x0 + tile_size, width), step):
            if coarse > 0 and (i - x0) % coarse == 0 and (j - y0) % coarse == 0:
                continue
            r, g, b = 0.0, 0.0, 0.0
            if sampler == SINGLE:
                r, g, b = _sample(geo, mats, lights, background, cam, float(i), float(j), whitted_on, heckbert_on,
                                  max_depth, cutoff, filtered, tricks, medium, state, rays, eye, color, ws, cnt)
            elif sampler == JITTER:
                pixel = j * width + i
                for s in range(k * k):
                    u = i - 0.5 + (s % k + _uniform(seed, pixel, 2 * s)) / k
                    v = j - 0.5 + (s // k + _uniform(seed, pixel, 2 * s + 1)) / k
                    sr, sg, sb = _sample(geo, mats, lights, background, cam, u, v, whitted_on, heckbert_on, max_depth,
                                         cutoff, filtered, tricks, medium, state, rays, eye, color, ws, cnt)
                    r += sr
                    g += sg
                    b += sb
                r, g, b = r / (k * k), g / (k * k), b / (k * k)
            else:
                r, g, b = _adaptive(geo, mats, lights, background, cam, whitted_on, heckbert_on, max_depth, cutoff,
                                    filtered, tricks, medium, threshold, aa_depth, x0, y0, i, j, lattice, known,
                                    squares, state, rays, eye, color, ws, cnt)
            out[j, i, 0] = r
            out[j, i, 1] = g
            out[j, i, 2] = b
            record_sample(ws.work, j, i, cnt)


@njit(inline="always")
def _point(geo, mats, lights, background, cam, whitted_on, heckbert_on, max_depth, cutoff, filtered, tricks, medium,
           aa_depth, x0, y0, a, e, lattice, known, state, rays, eye, color, ws, cnt):
    """Trace lattice point (a, e) of the tile at (x0, y0) unless it is known."""
    if not known[e, a]:
        scale = 1.0 / (1 << aa_depth)
        r, g, b = _sample(geo, mats, lights, background, cam, x0 - 0.5 + a * scale, y0 - 0.5 + e * scale, whitted_on,
                          heckbert_on, max_depth, cutoff, filtered, tricks, medium, state, rays, eye, color, ws, cnt)
        lattice[e, a, 0], lattice[e, a, 1], lattice[e, a, 2] = r, g, b
        known[e, a] = True


@njit(inline="always")
def _adaptive(geo, mats, lights, background, cam, whitted_on, heckbert_on, max_depth, cutoff, filtered, tricks, medium,
              threshold, aa_depth, x0, y0, i, j, lattice, known, squares, state, rays, eye, color, ws, cnt):
    """Whitted's subdivision of pixel (i, j): the area-weighted mean of its squares' corner means."""
    full = 1 << aa_depth
    r, g, b = 0.0, 0.0, 0.0
    squares[0, 0], squares[0, 1], squares[0, 2], squares[0, 3] = (i - x0) * full, (j - y0) * full, full, 0
    top = 1
    while top > 0:
        top -= 1
        a, e, size, cut = squares[top, 0], squares[top, 1], squares[top, 2], squares[top, 3]
        for corner in range(4):
            _point(geo, mats, lights, background, cam, whitted_on, heckbert_on, max_depth, cutoff, filtered, tricks,
                   medium, aa_depth, x0, y0, a + size * (corner % 2), e + size * (corner // 2), lattice, known, state,
                   rays, eye, color, ws, cnt)
        spread = 0.0
        for q in range(3):
            c0, c1 = lattice[e, a, q], lattice[e, a + size, q]
            c2, c3 = lattice[e + size, a, q], lattice[e + size, a + size, q]
            spread = max(spread, max(max(c0, c1), max(c2, c3)) - min(min(c0, c1), min(c2, c3)))
        if cut >= aa_depth or spread <= threshold:
            weight = 0.25 * (size / full) * (size / full)
            r += weight * (lattice[e, a, 0] + lattice[e, a + size, 0] + lattice[e + size, a, 0]
                           + lattice[e + size, a + size, 0])
            g += weight * (lattice[e, a, 1] + lattice[e, a + size, 1] + lattice[e + size, a, 1]
                           + lattice[e + size, a + size, 1])
            b += weight * (lattice[e, a, 2] + lattice[e, a + size, 2] + lattice[e + size, a, 2]
                           + lattice[e + size, a + size, 2])
            continue
        half = size // 2
        for piece in range(4):
            squares[top, 0], squares[top, 1] = a + half * (piece % 2), e + half * (piece // 2)
            squares[top, 2], squares[top, 3] = half, cut + 1
            top += 1
    return r, g, b

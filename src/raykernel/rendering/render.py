"""Whitted-style rendering of a scene, with exact counts of the work done.

    result = render(scene, accel="bvh", spd=True)
    result.image          # (height, width, 3) float RGB, not clamped
    result.stats          # counters, build statistics, times
    result.save("out.png")

    render(scene, shading="hall", shadows="filtered", aa="adaptive", tricks="all")

The shading models are whitted.py (NFF's, the default), hall.py and heckbert.py; the samplers
sampling.py; shadow rays through transparent surfaces shadows.py; Haines's efficiency tricks
tricks.py and startlists.py. `spd=True` follows the SPD test procedure (docs/guide/rendering.md, "Shading"): one
eye ray per pixel corner averaged into pixels, no adaptive cut-off, Whitted shading; otherwise
one ray per pixel centre and rays whose weight falls below the cut-off (1/512) are not cast.
Whitted shading without a sampler runs this module's own tile kernel; everything else runs
sampling.py's, which tiles, passes and counts the same way.

The image is traced in tiles of TILE x TILE samples, in parallel; each
tile owns one row of counters, so counts and image bytes do not depend on
the number of threads. Each thread makes one call of the tile kernel and
claims tiles from a shared counter (geometry/parallel.py) until none are
left, and a tile's eye rays go to the shading kernel in one call; a tile
none of whose eye rays can enter the scene's box (frustum.py) gets the
background and the counts of those misses without tracing them. With lazy structures (aggregates/lazyoctree.py,
rc.py) the image is traced coarse to fine (lazy_passes): one sample per tile
first, in passes that start with one tile, then the samples between them
level by level, so that the trees, refined after each pass from its counts,
are deepened wherever the image looks before most of its rays are cast.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass

import numba
import numpy as np

from ..aggregates.lazyset import pass_ranges
from ..geometry.compiletime import OTHER_RENDERS, CompileClock, compile_notice, typing_setup
from ..engine.flatten import flatten
from ..geometry.parallel import claim, default_threads, finished, on_threads
from ..engine.traverse import workspace
from ..aggregates.widewalk import count_misses, with_driver
from ..aggregates.memory import check, describe_bytes, memory_limit
from ..geometry.work import CULLED, charge_type, note, record_sample, sample_work, start_samples, work_figures
from ..geometry.work import columns as work_columns
from ..errors import OptionError
from ..options import choice, number
from ..geometry import counters as C
from ..geometry.config import cached, compiled, njit
from ..geometry.primitives import normalize
from ..scene.model import Scene
from . import heckbert
from .ahead import compile_ahead
from .frustum import tile_misses_box
from .sampling import MAX_AA_DEPTH, SAMPLERS, SHADINGS, render_pixels, model_arguments
from .startlists import prepare as prepare_starts
from .stats import Stats
from .tricks import DEFAULT as TRICKS_DEFAULT
from .tricks import LEAN, STARTLISTS, memo
from .tricks import names as tricks_names
from .tricks import parse as parse_tricks
from .whitted import RAY_COLUMNS, RAY_STACK, trace
from .worklayers import work_layers

TILE = 16
THREAD_SAMPLES = 512        # samples a thread must have at least: fewer cost more to hand over than to trace
CUTOFF = 1.0 / 512.0       # outside SPD mode: rays weighing less cannot change an 8-bit pixel


@njit
def _render_tiles(geo, mats, lights, background, cam, samples_w, samples_h, tile_x, tile_y, counter, last, row0,
                  max_depth, cutoff, filtered, tricks, starts, out, counters, passes, step, coarse, cull, layer,
                  levels, probe):
    """Trace tiles of the sample grid into `out`, adding into one counter row per tile: those
    claimed from `counter` (parallel.claim: every thread of a pass calls this once) below `last`.
    cam = eye(3), direction to sample (0, 0) (3), step right (3), step down (3).
    Within each tile only the samples on the lattice of `step` (every step-th row and column),
    less those on the coarser lattice of `coarse` (0: none) traced before.
    passes[tile - row0]: the tile's pass counts of lazy structures (aggregates/lazyoctree.py).
    cull: a tile none of whose eye rays can enter the scene's box is not traced (_culled).
    layer: None, or each sample's record of its work (geometry/work.py), `levels` nesting levels split;
    probe: None, or the event log of one sample (rendering/explain.py)."""
    eyes = np.zeros((TILE * TILE, 5))      # direction, then the sample's row and column
    colors = np.zeros((TILE * TILE, 3))
    while True:
        tile = claim(counter)
        if tile >= last:
            break
        cnt = np.zeros(C.N_COUNTERS + passes.shape[1], np.int64)
        x0, y0 = tile_x[tile], tile_y[tile]
        work = sample_work(layer, levels, probe, x0, y0, TILE)
        if starts is None and cull and _culled(geo, cam, samples_w, samples_h, x0, y0):
            _missed_tile(background, samples_w, samples_h, x0, y0, step, coarse, out, work, cnt)
        else:
            ws = workspace(np.int64(0), work)   # each tile starts from the same state, whichever thread claims it
            rays = np.zeros((RAY_STACK, RAY_COLUMNS))
            if starts is None:      # tricks.LEAN: no trick needs a memory, and numba compiles none of their code
                _render_tile(geo, mats, lights, background, cam, samples_w, samples_h, x0, y0, max_depth, cutoff,
                             filtered, tricks, None, out, step, coarse, rays, eyes, colors, ws, cnt)
            else:
                _render_tile(geo, mats, lights, background, cam, samples_w, samples_h, x0, y0, max_depth, cutoff,
                             filtered, tricks, memo(lights.shape[0], starts), out, step, coarse, rays, eyes, colors,
                             ws, cnt)
        for k in range(C.N_COUNTERS):
            counters[tile, k] += cnt[k]
        for k in range(passes.shape[1]):
            passes[tile - row0, k] = cnt[C.N_COUNTERS + k]
        finished(counter)



def tile_kernel(shading: str, aa: str | None):
    """The kernel that traces a render's tiles: this module's own for Whitted shading without a
    sampler (the fastest), sampling.py's for everything else."""
    return _render_tiles if shading == "whitted" and aa in (None, "none") else render_pixels


def first_run() -> bool:
    """True when the kernel cache holds no render kernel for this checkout's code yet."""
    return not cached(_render_tiles)

@njit(inline="always")
def _skipped(i, j, x0, y0, coarse):
    """Sample (i, j) of the tile at (x0, y0) was traced by the pass of the coarser lattice."""
    return coarse > 0 and (i - x0) % coarse == 0 and (j - y0) % coarse == 0


@njit(inline="always")
def _culled(geo, cam, samples_w, samples_h, x0, y0):
    """No eye ray of the tile at (x0, y0) can enter the scene's box, and the scene is one 4-wide
    BVH, whose walk of a ray that misses its box is that box test alone (aggregates/widewalk.py)."""
    return geo.wide_nodes.shape[0] > 0 and tile_misses_box(
        cam, x0, min(x0 + TILE, samples_w) - 1, y0, min(y0 + TILE, samples_h) - 1, geo.agg_bounds, geo.root)


@njit(private=True)
def _missed_tile(background, samples_w, samples_h, x0, y0, step, coarse, out, work, cnt):
    """What tracing a culled tile's eye rays would have given: each sample the background as
    trace adds it for a missed eye ray (0.0 + 1.0 * background), and each ray the counts of an
    eye ray that missed the scene's box; frustum.culled counts them too (they cost less).
    work: the samples' records (geometry/work.py), None without work layers."""
    one = np.int64(1)
    start_samples(work, cnt)
    for j in range(y0, min(y0 + TILE, samples_h), step):
        for i in range(x0, min(x0 + TILE, samples_w), step):
            if not _skipped(i, j, x0, y0, coarse):
                out[j, i, 0], out[j, i, 1], out[j, i, 2] = 0.0 + background[0], 0.0 + background[1], \
                    0.0 + background[2]
                before = work_figures(work, cnt)
                note(work, CULLED, 0, 0, 0, 0, 0, 0, 0, 0, 0)
                cnt[C.RAYS_EYE] += 1
                cnt[C.FRUSTUM_CULLED] += 1
                count_misses(cnt, one)
                charge_type(work, 0, before, cnt)
                record_sample(work, j, i, cnt)


@njit(private=True)     # one call per tile: the call into trace counts no references
def _render_tile(geo, mats, lights, background, cam, samples_w, samples_h, x0, y0, max_depth, cutoff, filtered,
                 tricks, state, out, step, coarse, rays, eyes, colors, ws, cnt):
    """The samples of the tile at (x0, y0) for _render_tiles, with the tile's workspace and counters:
    their eye rays traced in one call, in the order of the tile's rows."""
    n = np.int64(0)     # typed int64 from the start: a literal 0 had numba compile trace for n = 0 first
    for j in range(y0, min(y0 + TILE, samples_h), step):
        for i in range(x0, min(x0 + TILE, samples_w), step):
            if _skipped(i, j, x0, y0, coarse):
                continue
            dx = cam[3] + i * cam[6] + j * cam[9]
            dy = cam[4] + i * cam[7] + j * cam[10]
            dz = cam[5] + i * cam[8] + j * cam[11]
            eyes[n, 0], eyes[n, 1], eyes[n, 2] = normalize(dx, dy, dz)
            eyes[n, 3], eyes[n, 4] = j, i       # where its colour goes
            n += 1
    trace(geo, mats, lights, background, cam[0], cam[1], cam[2], eyes, n, colors, max_depth, cutoff, filtered,
          tricks, state, rays, ws, cnt)
    for k in range(n):
        j, i = int(eyes[k, 3]), int(eyes[k, 4])
        out[j, i, 0], out[j, i, 1], out[j, i, 2] = colors[k, 0], colors[k, 1], colors[k, 2]


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
    """One row per material: colour (3), kd, ks, shine, t, ior, kl."""
    mats = scene.materials or []
    table = np.zeros((max(1, len(mats)), 9))
    table[0] = [1, 1, 1, 1, 0, 0, 0, 1, 0]
    for i, m in enumerate(mats):
        table[i] = [*m.color, m.kd, m.ks, m.shine, m.t, m.ior, m.kl]
    return table


def luminous_spheres(scene: Scene):
    """(centre, radius, colour x kl) of every sphere with a luminous material, in the scene's
    groups outside instances (whose spheres have one position each)."""
    out = []
    groups = [scene.root]
    while groups:
        group = groups.pop()
        group.spheres.freeze()
        for c, r, m in zip(group.spheres.center, group.spheres.radius, group.spheres.material):
            mat = scene.materials[m] if m < len(scene.materials) else None
            if mat is not None and mat.kl > 0.0:
                out.append((c, abs(float(r)), np.asarray(mat.color) * mat.kl))
        groups += [g for g in group.children if isinstance(g, type(scene.root))]
    return out


def light_table(scene: Scene, eye_light: float | None = None, eye_light_shadows: str = "skip") -> np.ndarray:
    """One row per light: position (3), colour (3), radius (0 for a point light), 1 for a light at
    the eye whose shadow rays from eye rays' hits are skipped (Haines's trick), else 0.
    Point lights have the SPD's suggested intensity 1/sqrt(n) times their colour; a luminous
    sphere is a light at its centre with colour x kl, seen from a point when nothing lies
    between the point and the sphere's surface; the eye light is white of its intensity."""
    n = len(scene.lights)
    emitters = luminous_spheres(scene)
    table = np.zeros((n + len(emitters) + (eye_light is not None), 8))
    for i, light in enumerate(scene.lights):
        color = np.ones(3) if light.color is None else light.color
        table[i, :3] = light.position
        table[i, 3:6] = color / math.sqrt(n)
    for i, (center, radius, color) in enumerate(emitters, start=n):
        table[i, :3] = center
        table[i, 3:6] = color
        table[i, 6] = radius
    if eye_light is not None:
        table[-1, :3] = scene.camera.eye
        table[-1, 3:6] = eye_light
        table[-1, 7] = eye_light_shadows == "skip"
    return table


@dataclass
class RenderResult:
    """What a render gives: the image, its statistics and, on request, its work layers.

    Attributes
    ----------
    image : (height, width, 3) float64 array
        The RGB image, not clamped.
    stats : Stats
        A dict of counters, build statistics and times (``time.trace``, ...), with the built
        aggregates in ``stats.aggregates`` and the render's settings in ``stats.info``.
    work : dict or None
        With ``render(work=True)``: counter name -> its work layer, an integer array with one
        value a sample (worklayers.py); else None.
    """

    image: np.ndarray       # (height, width, 3) float RGB
    stats: Stats
    work: dict | None = None    # render(work=True): counter name -> its layer (worklayers.py)

    def to_uint8(self) -> np.ndarray:
        """The image as 8-bit RGB, clamped to [0, 1].

        Returns
        -------
        (height, width, 3) uint8 array
            The image itself where it is already uint8.
        """
        from .imageio import to_uint8
        return to_uint8(self.image)

    def save(self, path) -> None:
        """Write the image in the format the suffix of `path` names (imageio.save_image).

        Parameters
        ----------
        path : str or path-like
            ``.png``, ``.jpg``, ``.jpeg``, ``.tif``, ``.tiff`` or ``.webp`` write 8-bit RGB,
            clamped to [0, 1]; ``.npy``, ``.pfm`` or ``.exr`` the float image as rendered. The
            file is written atomically.

        Raises
        ------
        OptionError
            The suffix names no format raykernel writes.
        """
        from .imageio import save_image
        save_image(self.image, path)

    def _repr_html_(self) -> str:
        from .imageio import png_data_uri
        return (f'<div><img src="{png_data_uri(self.image)}" style="image-rendering:pixelated"/>'
                f"{self.stats._repr_html_()}</div>")


def render_options(scene: Scene, accel="bvh", resolution=None, spd=False, max_depth=5, threads=None, max_memory=None,
             shading="whitted", aa=None, samples=4, seed=0, aa_threshold=0.1, aa_depth=2, cutoff=None,
             shadows="opaque", eye_light=None, eye_light_shadows="skip", tricks="default", work=False) -> dict:
    """render()'s arguments checked (OptionError names the bad one), with the defaults resolved."""
    max_depth = number(max_depth, "max_depth", 1, 32, integer=True)
    if resolution is not None:
        resolution = number(resolution, "resolution", 1, 16384, integer=True)
    if threads is not None:
        threads = number(threads, "threads", 1, 1 << 20, integer=True)
    shading = choice(shading, "shading", SHADINGS)
    aa = choice("none" if aa is None else aa, "anti-aliasing (aa)", SAMPLERS)
    samples = number(samples, "samples", 1, 4096, integer=True)
    if aa == "jitter" and math.isqrt(samples) ** 2 != samples:
        raise OptionError(f"samples for jittered anti-aliasing must be a square number (1, 4, 9, 16, ...), "
                          f"got {samples}")
    seed = number(seed, "seed", 0, 2 ** 63 - 1, integer=True)
    aa_threshold = number(aa_threshold, "aa_threshold", 0.0, math.inf)
    aa_depth = number(aa_depth, "aa_depth", 0, MAX_AA_DEPTH, integer=True)
    if cutoff is not None:
        cutoff = number(cutoff, "cutoff", 0.0, 1.0)
    shadows = choice(shadows, "shadows", ("opaque", "filtered"))
    default = isinstance(tricks, str) and tricks.strip().lower() == "default"
    trick_bits = int(TRICKS_DEFAULT if default else parse_tricks(tricks))
    if eye_light is not None:
        eye_light = number(eye_light, "eye_light", 0.0, math.inf)
    eye_light_shadows = choice(eye_light_shadows, "eye_light_shadows", ("skip", "cast"))
    if shading == "heckbert" and shadows != "opaque":
        raise OptionError("heckbert shading follows the printed program, whose shadows are opaque; "
                          f"shadows {shadows!r} is not allowed with it")
    if spd:
        if eye_light is not None:
            raise OptionError("SPD mode lights a scene with its own lights only; eye_light is not allowed with it")
        for name, value, default in (("shading", shading, "whitted"), ("aa", aa, "none"),
                                     ("shadows", shadows, "opaque")):
            if value != default:
                raise OptionError(f"SPD mode traces Whitted shading with one ray per pixel corner; {name} "
                                  f"{value!r} is not allowed with it")
        if cutoff not in (None, 0.0):
            raise OptionError(f"SPD mode casts every ray (rule 8, no adaptive cut-off); cutoff {cutoff!r} is "
                              "not allowed with it")
    if scene.camera.medium is not None and not 0 <= scene.camera.medium < len(scene.materials):
        raise OptionError(f"the camera's medium is material {scene.camera.medium}, which the scene does not have")
    if cutoff is None:
        cutoff = 0.0 if spd else CUTOFF
    if not isinstance(work, (bool, np.bool_)):
        raise OptionError(f"work must be True or False, got {work!r}")
    return dict(accel=accel, resolution=resolution, spd=bool(spd), max_depth=max_depth, threads=threads,
                max_memory=max_memory, shading=shading, aa=aa, samples=samples, seed=seed, aa_threshold=aa_threshold,
                aa_depth=aa_depth, cutoff=cutoff, shadows=shadows, eye_light=eye_light,
                eye_light_shadows=eye_light_shadows, tricks=tricks, trick_bits=trick_bits, work=bool(work))


def _faulted_zeros(shape, dtype) -> np.ndarray:
    """Zeros whose pages are already mapped. np.zeros of a large array gets pages from the
    system that are mapped on first write, which would then happen inside the timed trace,
    costing more or less (a noticeable share of a small trace) as the process's allocator
    has memory to reuse or not; written here, that cost is the same in every process and
    counts as preprocessing."""
    out = np.empty(shape, dtype)
    out.fill(0)
    return out


class RenderJob:
    """One render in its parts, so that its tiles can be traced anywhere (cluster.py):

        job = RenderJob(scene, accel="bvh", spd=True)       # checks the options, builds the structures
        for p in range(len(job.passes)):
            job.trace(p, 0, job.pass_tiles(p), threads=2)   # any split of a pass's tiles, in any order
            job.end_pass(p)                                 # lazy structures refine here
        result = job.result(trace_seconds, compile_seconds)

    Each tile writes only its own samples and its own counter row, so tiles traced in other
    processes and copied in (tile_block / put_block) give the same image bytes and counts.
    builder: what builds the structures, flatten.flatten by default; an incremental.Hierarchy
    refits the previous frame's instead. remote: a job whose structures were built elsewhere
    (plan() of that job): this one only gathers its tiles (put_block) and gives the result."""

    frustum_culling = True      # tiles whose eye rays all miss the scene are not traced (frustum.py); same result

    def __init__(self, scene: Scene, builder=None, remote: dict | None = None, annealed: dict | None = None, **kw):
        self.annealed = annealed        # what annealing found for the scene's auto specs (analysis/auto.py)
        o = self.options = render_options(scene, **kw)
        if o["threads"] is not None:
            numba.set_num_threads(min(o["threads"], numba.config.NUMBA_NUM_THREADS))
        self.scene = scene
        self.kernel = tile_kernel(o["shading"], o["aa"])
        self.plain = self.kernel is _render_tiles
        self.width = self.height = o["resolution"]
        if o["resolution"] is None:
            self.width, self.height = scene.camera.width, scene.camera.height
        if remote is None:
            setup = typing_setup()      # numba's, on a process's first kernel call: start-up, not preprocess
            t0 = time.perf_counter()
            with CompileClock() as build_clock:     # the builders' kernels compile on first use too
                build_fn = flatten if builder is None else builder.flatten
                self.geo, self.build = build_fn(scene, o["accel"], o["max_memory"])
                self.starts = prepare_starts(self.geo, bool(o["trick_bits"] & STARTLISTS))    # trick 6's view of the BVHs
            if o["trick_bits"] != LEAN:
                # the tricks' kernels take the general driver (eager normals need it) on any scene:
                # one compile of them for every scene, not one per geometry type
                self.geo = with_driver(self.geo)
            self.preprocess = time.perf_counter() - t0 - build_clock.seconds - build_clock.loading
            self.build_compile = build_clock.seconds
            self.build_load = setup + build_clock.loading
            self.lazy = self.build.get("lazy")     # lazy structures: refined after each pass
            self.lazy_columns = None if self.lazy is None else self.lazy.columns
        else:
            self.geo = self.starts = self.lazy = None
            self.build, self.preprocess, self.build_compile = remote["build"], remote["preprocess"], remote["compile"]
            self.build_load = remote["load"]
            self.lazy_columns = remote["lazy_columns"]

        spd = o["spd"]
        self.sw, self.sh = (self.width + 1, self.height + 1) if spd else (self.width, self.height)
        tiles_x = np.arange(0, self.sw, TILE)
        tiles_y = np.arange(0, self.sh, TILE)
        self.tile_x = np.tile(tiles_x, len(tiles_y)).astype(np.int64)
        self.tile_y = np.repeat(tiles_y, len(tiles_x)).astype(np.int64)
        self.n_tiles = n_tiles = len(self.tile_x)
        t0 = time.perf_counter()
        # the samples' records of their work (geometry/work.py), by nesting level where aggregates nest
        self.levels = int(self.build.get("build.nesting", 1))
        layer_shape = (self.sh, self.sw, work_columns(self.levels)) if o["work"] else (0, 0, 0)
        self._check_memory(layer_shape, n_tiles)
        self.values = _faulted_zeros((self.sh, self.sw, 3), np.float64)      # the samples' colours
        self.counts = _faulted_zeros((n_tiles, C.N_COUNTERS), np.int64)
        self.layer = None
        self.probe = None       # the event log of one sample (rendering/explain.py)
        if o["work"]:
            self.layer = _faulted_zeros(layer_shape, np.int32)
        self.preprocess += time.perf_counter() - t0
        if o["shading"] == "heckbert":
            self.cam = heckbert.camera_vectors(scene.camera, self.width, self.height)
        else:
            self.cam = camera_vectors(scene.camera, self.width, self.height, corners=spd)
        self.mats = material_table(scene)
        self.lights = light_table(scene, o["eye_light"], o["eye_light_shadows"])
        self.filtered = o["shadows"] == "filtered"
        self.medium = np.int64(-1 if scene.camera.medium is None else scene.camera.medium)
        self.background = np.asarray(scene.background, np.float64)
        self.trick_bits = np.int64(o["trick_bits"])

        if self.lazy_columns is None:
            self.passes = [(1, 0, 0, n_tiles)]      # one pass: the threads claim its tiles one at a time
        else:
            # lazy: the pass schedule, which must not depend on the threads
            self.passes = lazy_passes(n_tiles, max(1, n_tiles // 32))
        # samples of full tiles each pass traces, for the progress report
        self.work = [(last - first) * ((TILE // step) ** 2 - (TILE // coarse) ** 2 if coarse else (TILE // step) ** 2)
                     for step, coarse, first, last in self.passes]
        self.pass_counts = [None] * len(self.passes)
        self.refined = 0        # passes whose counts the lazy structures have refined from
        self._lock = threading.Lock()

    def _check_memory(self, layer_shape, n_tiles) -> None:
        """MemoryBudgetError, before anything is allocated, unless the structures and every buffer
        of the render fit in the memory budget: the samples' colours, the image made from them with
        two temporaries of its size (its 8-bit copy too), the tiles' counters and the work layers."""
        if self.geo is None:
            return      # a remote job's buffers: its own process checked the same
        pixels = self.width * self.height
        buffers = {"image": self.sh * self.sw * 24 + pixels * (3 * 24 + 3) + n_tiles * C.N_COUNTERS * 8,
                   "work layers": int(np.prod(layer_shape)) * 4}
        held = sum(a.nbytes for a in self.geo if isinstance(a, np.ndarray))
        limit = memory_limit(self.options["max_memory"])
        what = f"a {self.width}x{self.height} render ({', '.join(f'{k} {describe_bytes(v)}' for k, v in buffers.items() if v)}"
        check(held + sum(buffers.values()), limit, what + f", beside {describe_bytes(held)} of structures)",
              "lower the resolution" + (", or render without work layers" if buffers["work layers"] else ""))

    def plan(self) -> dict:
        """What a remote job (RenderJob(..., remote=plan)) needs from this one."""
        build = {k: v for k, v in self.build.items() if k != "lazy"}
        if self.lazy is not None:
            self.lazy.update_stats(build, self.geo)
        return {"build": build, "preprocess": self.preprocess, "compile": self.build_compile,
                "load": self.build_load, "lazy_columns": self.lazy_columns}

    @property
    def threads(self) -> int:
        return int(self.options["threads"]) if self.options["threads"] is not None else default_threads()

    def pass_tiles(self, p: int) -> int:
        step, coarse, first, last = self.passes[p]
        return last - first

    def arguments(self, p: int, counter, limit) -> tuple:
        """The arguments of this job's kernel for the tiles of pass p that a call claims from
        counter (next tile, tiles finished) below `limit`."""
        o = self.options
        step, coarse, first, last = self.passes[p]
        if self.pass_counts[p] is None:
            with self._lock:        # callers tracing parts of one pass share its counts
                if self.pass_counts[p] is None:
                    columns = 0 if self.lazy is None else self.lazy.columns     # (lazy structures change them)
                    self.pass_counts[p] = np.zeros((last - first, columns), np.int64)
        if self.plain:
            return (self.geo, self.mats, self.lights, self.background, self.cam, self.sw, self.sh, self.tile_x,
                    self.tile_y, counter, limit, first, o["max_depth"], o["cutoff"], True if self.filtered else None,
                    self.trick_bits, None if self.trick_bits == LEAN else self.starts, self.values, self.counts,
                    self.pass_counts[p], step, coarse, self.frustum_culling, self.layer, self.levels, self.probe)
        whitted_on, heckbert_on, medium = model_arguments(o["shading"], self.medium)
        return (self.geo, self.mats, self.lights, self.background, self.cam, self.sw, self.sh, self.tile_x,
                self.tile_y, counter, limit, first, o["max_depth"], o["cutoff"], self.values, self.counts,
                self.pass_counts[p], step, coarse, TILE, whitted_on, heckbert_on, self.filtered, self.trick_bits,
                self.starts, medium, SAMPLERS[o["aa"]], o["samples"], o["seed"], o["aa_threshold"], o["aa_depth"],
                self.layer, self.levels, self.probe)

    def _runner(self, p: int):
        """run(counter, limit): this job's kernel over the tiles of pass p it claims (arguments)."""
        return lambda counter, limit: self.kernel(*self.arguments(p, counter, limit))

    def compile_kernel(self) -> None:
        """Compile (or load) the kernel this job traces with, for its arguments' types, tracing
        nothing: a call that finds no tile to claim."""
        first = self.passes[0][2]
        self._runner(0)(np.array([first, 0], np.int64), first)

    def trace(self, p: int, lo: int, hi: int, threads: int = 1, report=None) -> None:
        """Trace tiles lo..hi-1 of pass p (counted from the pass's first tile) on `threads` threads,
        which claim them one at a time; report(k), if given, is called every tenth of a second
        or so with the number of tiles finished."""
        step, coarse, first, last = self.passes[p]
        run = self._runner(p)
        start = first + lo
        samples = self.work[p] * (hi - lo) // max(1, last - first)
        threads = max(1, min(threads, hi - lo, -(-samples // THREAD_SAMPLES)))
        if not compiled(self.kernel):
            # the first tile alone, on this thread, while the kernel compiles (or loads): threads
            # calling an uncompiled kernel at once would each compile it, and Ctrl-C stops a compile here
            run(np.array([start, 0], np.int64), start + 1)
            start += 1
        counter = np.array([start, start - first - lo], np.int64)      # next tile, tiles finished
        # the counter given, Ctrl-C stops the tiles; a small pass (a lazy render's first) runs here
        on_threads(lambda: run(counter, first + hi), threads,
                   poll=None if report is None else lambda: report(int(counter[1])),
                   counter=counter if samples > THREAD_SAMPLES else None)

    def trace_pass(self, p: int, threads: int, report=None) -> None:
        """Trace all of pass p over `threads` threads (report: as for trace)."""
        self.trace(p, 0, self.pass_tiles(p), threads, report)

    def end_pass(self, p: int, pass_counts=None) -> None:
        """After every tile of pass p: lazy structures refine from the pass's counts (this
        job's own, or those gathered from wherever its tiles were traced)."""
        counts = self.pass_counts[p] if pass_counts is None else pass_counts
        self.pass_counts[p] = counts
        if self.lazy is None or p < self.refined:
            return
        assert p == self.refined, "passes refine in order"
        self.geo = self.lazy.refine(self.geo, counts)
        self.starts = prepare_starts(self.geo, bool(self.trick_bits & STARTLISTS))
        self.refined += 1

    def tile_block(self, p: int, lo: int, hi: int):
        """What tiles lo..hi-1 of pass p traced: their samples (zero where the pass traced none),
        counter rows, lazy pass counts and the samples' work records (None without work
        layers), for put_block in another process."""
        step, coarse, first, last = self.passes[p]
        block = np.zeros((hi - lo, TILE, TILE, 3))
        work = None if self.layer is None else np.zeros((hi - lo, TILE, TILE, self.layer.shape[2]), np.int32)
        for k, tile in enumerate(range(first + lo, first + hi)):
            y, x = self.tile_y[tile], self.tile_x[tile]
            part = self.values[y:y + TILE, x:x + TILE]
            mask = _lattice(part.shape[0], part.shape[1], step, coarse)
            block[k, :part.shape[0], :part.shape[1]][mask] = part[mask]
            if work is not None:
                work[k, :part.shape[0], :part.shape[1]][mask] = self.layer[y:y + TILE, x:x + TILE][mask]
        rows = self.pass_counts[p][lo:hi]
        return block, self.counts[first + lo:first + hi].copy(), rows.copy(), work

    def put_block(self, p: int, lo: int, block, counts, rows, work=None) -> None:
        step, coarse, first, last = self.passes[p]
        hi = lo + len(block)
        if self.pass_counts[p] is None:
            self.pass_counts[p] = np.zeros((last - first, rows.shape[1]), np.int64)
        for k, tile in enumerate(range(first + lo, first + hi)):
            y, x = self.tile_y[tile], self.tile_x[tile]
            part = self.values[y:y + TILE, x:x + TILE]
            mask = _lattice(part.shape[0], part.shape[1], step, coarse)
            part[mask] = block[k, :part.shape[0], :part.shape[1]][mask]
            if work is not None:
                self.layer[y:y + TILE, x:x + TILE][mask] = work[k, :part.shape[0], :part.shape[1]][mask]
        self.counts[first + lo:first + hi] += counts
        self.pass_counts[p][lo:hi] = rows

    def result(self, trace: float, compile: float, threads: int | None = None, build: dict | None = None,
               preprocess: float | None = None, load: float = 0.0) -> RenderResult:
        """The image and the statistics of the traced job (build and preprocess: another
        process's, where the structures were built there); compile and load: the seconds the
        trace spent compiling kernels and loading them from the cache, left out of `trace`."""
        o = self.options
        build = self.build if build is None else build
        if self.lazy is not None:
            self.lazy.update_stats(build, self.geo)
        v = self.values
        image = 0.25 * (v[:-1, :-1] + v[1:, :-1] + v[:-1, 1:] + v[1:, 1:]) if o["spd"] else v
        width, height, aa = self.width, self.height, o["aa"]
        stats = Stats.from_counters(
            self.counts.sum(axis=0), build, preprocess=self.preprocess if preprocess is None else preprocess,
            trace=trace, compile=self.scene.compile_seconds + self.build_compile + compile,
            load=self.scene.load_seconds + self.build_load + load, parse=self.scene.parse_seconds,
            anneal=self.annealed["seconds"] if self.annealed else 0.0,
            info={"scene": self.scene.source, "accel": o["accel"], "resolution": [width, height],
                  "spd": o["spd"], "max_depth": o["max_depth"], "shading": o["shading"],
                  "aa": None if aa == "none" else aa, "cutoff": o["cutoff"], "shadows": o["shadows"],
                  "tricks": tricks_names(int(self.trick_bits)),
                  **({"eye_light": o["eye_light"], "eye_light_shadows": o["eye_light_shadows"]}
                     if o["eye_light"] is not None else {}),
                  **({"samples": o["samples"], "seed": o["seed"]} if aa == "jitter" else {}),
                  **({"aa_threshold": o["aa_threshold"], "aa_depth": o["aa_depth"]} if aa == "adaptive" else {}),
                  "eye_rays_per_pixel": int(self.counts[:, C.RAYS_EYE].sum()) / (width * height),
                  "threads": self.threads if threads is None else threads,
                  "primitives": self.scene.count_primitives(),
                  **({"anneal": self.annealed["groups"]} if self.annealed else {})})
        return RenderResult(image=image, stats=stats,
                            work=None if self.layer is None else work_layers(self.layer, self.levels))


def _lattice(h: int, w: int, step: int, coarse: int) -> np.ndarray:
    """The samples of an h x w tile a pass of (step, coarse) traces (_render_tile's rule)."""
    j, i = np.mgrid[0:h, 0:w]
    mask = (i % step == 0) & (j % step == 0)
    if coarse > 0:
        mask &= ~((i % coarse == 0) & (j % coarse == 0))
    return mask


# CompileClock's notice for a render's kernels, whichever specialisation compiles
tell_compiling = compile_notice(
    "render", f"raykernel: compiling the renderer's kernels for this kind of render (once after install: tens "
              f"of seconds; {OTHER_RENDERS}; cached for later processes)")


def render(scene: Scene, accel: str = "bvh", resolution: int | None = None, spd: bool = False,
           max_depth: int = 5, threads: int | None = None, progress=None, max_memory=None,
           shading: str = "whitted", aa: str | None = None, samples: int = 4, seed: int = 0,
           aa_threshold: float = 0.1, aa_depth: int = 2, cutoff: float | None = None, shadows: str = "opaque",
           eye_light: float | None = None, eye_light_shadows: str = "skip", tricks="default",
           builder=None, annealed: dict | None = None, work: bool = False) -> RenderResult:
    """Render `scene`; returns the float image and the statistics.

    Parameters
    ----------
    scene : Scene
        The scene to render.
    accel : str, default "bvh"
        The default accelerator spec for groups that name none.
    resolution : int, optional
        Square image size in pixels (default: the scene camera's width and height).
    spd : bool, default False
        Follow the SPD test procedure (rays through pixel corners, no cut-off, Whitted shading,
        no anti-aliasing).
    max_depth : int, default 5
        The deepest level of the ray tree (eye ray = 1), from 1 to 32.
    threads : int, optional
        Worker threads (default: all cores).
    progress : callable, optional
        ``progress(done, total)``, called after each pass, in samples (of full tiles).
    max_memory : int or str, optional
        The memory budget of every build, in bytes or as ``"8G"`` (default: half of this
        machine's memory); a structure that would need more is a MemoryBudgetError.
    shading : {"whitted", "hall", "heckbert"}
        ``"whitted"`` (NFF's parameters, whitted.py), ``"hall"`` (Hall and Greenberg's model,
        hall.py) or ``"heckbert"`` (the minimal ray tracer's model and camera, heckbert.py).
    aa : {None, "jitter", "adaptive"}
        None: one ray per pixel; ``"jitter"``: `samples` rays per pixel in jittered strata,
        `seed` picking the random numbers; ``"adaptive"``: Whitted's, rays through the corners,
        a pixel cut where they differ by more than `aa_threshold` in a channel, at most
        `aa_depth` cuts.
    samples : int, default 4
        Rays per pixel of ``aa="jitter"``: a square number (1, 4, 9, 16, ...).
    seed : int, default 0
        The random numbers of ``aa="jitter"``.
    aa_threshold : float, default 0.1
        The channel difference above which ``aa="adaptive"`` cuts a pixel.
    aa_depth : int, default 2
        The most cuts of ``aa="adaptive"``.
    cutoff : float, optional
        Rays whose weight (the product of the Ks and T factors on their way) falls below it are
        not cast (``rays.cut_off`` counts them); default 1/512 (they cannot change an 8-bit
        pixel), 0 in SPD mode (which allows no other).
    shadows : {"opaque", "filtered"}
        ``"opaque"``: any surface blocks a light; ``"filtered"``: transparent surfaces pass it,
        times T (shadows.py). Heckbert shading has opaque shadows only.
    eye_light : float, optional
        The intensity of a white point light at the eye (Haines's trick); None: no such light.
    eye_light_shadows : {"skip", "cast"}
        ``"skip"`` (the trick: eye rays' hits are lit by it without a shadow ray, counted in
        ``shadow.eye_light_skipped``) or ``"cast"`` (shadow rays as for any light).
    tricks : str, default "default"
        Haines's efficiency tricks (tricks.py): ``"all"``, ``"none"``, ``"default"`` (closest,
        lazynormals) or a comma-separated list of closest, raytree, shadowcache,
        transparentlast, lazynormals, startlists. They change the work, not the image or the
        ray counts; heckbert shading runs the printed program's searches and takes none.
    builder : optional
        What builds the structures (default: flatten.flatten, from scratch); an
        ``engine.incremental.Hierarchy`` keeps them between the frames of an animation.
    annealed : dict, optional
        What annealing found for the scene's auto specs, for the statistics (a render with
        auto specs is raykernel.render's, analysis/auto.py, which anneals first).
    work : bool, default False
        True records ``result.work``: the work of every sample's whole ray tree, counter by
        counter, ray type by ray type and nesting level by level (worklayers.py); False records
        nothing.

    Returns
    -------
    RenderResult
        ``image``, the (height, width, 3) float64 RGB image, not clamped; ``stats``, the
        counters, build statistics and times; ``work``, the work layers where `work` is True.

    Raises
    ------
    OptionError
        An option or accelerator spec is not valid (the message names it), or two options do
        not go together.
    MemoryBudgetError
        The structures or the render's buffers would need more than `max_memory`.
    SceneError
        The scene cannot be built (a group cycle, aggregates nested too deep, coordinates
        beyond the range raykernel answers exactly).
    """
    options = dict(accel=accel, resolution=resolution, spd=spd, max_depth=max_depth, threads=threads,
                   max_memory=max_memory, shading=shading, aa=aa, samples=samples, seed=seed,
                   aa_threshold=aa_threshold, aa_depth=aa_depth, cutoff=cutoff, shadows=shadows,
                   eye_light=eye_light, eye_light_shadows=eye_light_shadows, tricks=tricks, work=work)
    with CompileClock(notice=tell_compiling) as ahead:
        if builder is None:     # a first render: the renderer compiles here while a helper builds (ahead.py)
            compile_ahead(RenderJob, scene, options, tile_kernel(shading, aa))
    job = RenderJob(scene, builder=builder, annealed=annealed, **options)
    n_threads = job.threads
    t1 = time.perf_counter()
    done, total = 0, sum(job.work)
    with CompileClock(notice=tell_compiling) as clock:
        for p, part in enumerate(job.work):
            report = None
            if progress is not None:
                per_tile = part / max(1, job.pass_tiles(p))
                report = lambda tiles, base=done, per_tile=per_tile: progress(base + round(tiles * per_tile), total)
            job.trace_pass(p, n_threads, report)
            job.end_pass(p)
            done += part
    trace = time.perf_counter() - t1 - clock.seconds - clock.loading
    return job.result(trace, ahead.seconds + clock.seconds, load=ahead.loading + clock.loading)

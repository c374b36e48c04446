"""What the explorer shows, as numbers: each structure's render, work layers, boxes and their use,
per sample, and the maps that link one view to another. No framework here: tests read it directly.

    s = settings(["octree", "bvh"], resolution=48)          # OptionError names a bad value
    ex = explore_scene(load("scene:stadium"), s)            # Exploration: one Run per structure
    ex.counts_at(10, 20)                    # every structure's every layer at column 10, row 20
    ex.scale("tests.total")                 # (low, high, "log" or "linear"): one scale for all
    ex.hottest("tests.total", 10)           # the samples with the most work, every structure's count
    ex.in_range("octree", "tests.total", 100, 1e9)     # bool (h, w): a histogram's range selection
    run = ex.runs["octree"]
    run.node_mask(box)                      # bool (h, w): the samples whose rays entered box `box`
    run.pixel_boxes(10, 20)                 # (boxes entered, boxes whose items were tested)

A Run holds the render's image, statistics and work layers (render(..., work=True): the same
numbers `compare --work` shows), the structure's boxes with how the render's rays used them
(structure --use), and each sample's use of each box. The last comes from tracing the image one
sample at a time with the box counters on (rendering/structure.py's Use, on one thread): each
sample's trace is the only one between two reads of the counters, so the rows that changed are
the boxes its rays entered and the tests made in them, exactly. A lazy structure (lazyoctree, rc)
refines between the passes of its render, so its samples cannot trace alone in it as it grew;
they trace alone in it as the render left it, frozen (its pass counts are kept, never refined
from): its boxes, their use, its node masks and its tile times are of that structure, while its
work layers and image are those of the refining render (Run.note says so). A Run also holds the
seconds each tile took (tile_seconds): time, never mixed with the counts; and the flattened
arrays it traced (geo), whose primitives the 3D view draws (primitive_box, primitive_shape).
"""

from __future__ import annotations

import copy
import dataclasses
import json
import time
from dataclasses import dataclass

import numpy as np

from ..aggregates.memory import check, memory_limit
from ..aggregates.registry import parse_spec
from ..aggregates.spec import is_auto
from ..analysis.workimages import WorkImages
from ..aggregates.widewalk import with_driver
from ..geometry.work import TESTS, VISITS
from ..errors import OptionError
from ..options import number
from ..rendering.render import TILE, RenderJob
from ..rendering.structure import Boxes, box_rows, boxes_of, use_of, use_values
from ..rendering.worklayers import check_layer_name

DEFAULT_RESOLUTION = 48
COARSE = 4              # the coarse pass renders at 1/COARSE of the resolution
TIME_REPEATS = 3        # each tile timed this often, the fastest kept (the others met interrupts)
CHUNK = 8               # tiles traced between looks at whether a newer request came
SAMPLE_CHUNK = 64       # samples traced alone between such looks (each is a call of its own)
MAX_STRUCTURES = 8
DECADES = 2.0           # a layer whose values span more than this many decades opens on a log scale


class Cancelled(Exception):
    """A newer request came: the render in progress stops."""


@dataclass(frozen=True)
class Settings:
    accels: tuple = ("bvh",)
    resolution: int = DEFAULT_RESOLUTION
    eye: tuple | None = None        # the camera's, where changed
    look_at: tuple | None = None
    up: tuple | None = None
    angle: float | None = None
    counter: str = "tests.total"    # the layer the views open on

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), indent=1)

    def replace(self, **changes) -> "Settings":
        return settings(**(dataclasses.asdict(self) | changes))


def settings(accels=("bvh",), resolution=DEFAULT_RESOLUTION, eye=None, look_at=None, up=None, angle=None,
             counter="tests.total") -> Settings:
    """Settings, each value checked: an OptionError names the bad one."""
    if isinstance(accels, str):
        accels = [accels]
    accels = tuple(str(a).strip() for a in accels if str(a).strip())
    if not accels:
        raise OptionError("accels: name at least one structure")
    if len(accels) > MAX_STRUCTURES:
        raise OptionError(f"accels: at most {MAX_STRUCTURES} structures at once, got {len(accels)}")
    if len(set(accels)) != len(accels):
        raise OptionError(f"accels: each structure once, got {', '.join(accels)}")
    for a in accels:
        parse_spec(a)
        if is_auto(a):
            raise OptionError(f"accels: {a!r} is a search, not a structure (raykernel anneal finds one)")
    resolution = number(resolution, "resolution", 2, 1024, integer=True)
    vectors = {}
    for name, value in (("eye", eye), ("look_at", look_at), ("up", up)):
        if value is not None:
            v = [float(number(x, name, -np.inf, np.inf)) for x in value] if len(value) == 3 else None
            if v is None:
                raise OptionError(f"{name} must be three numbers, got {value!r}")
            vectors[name] = tuple(v)
    if angle is not None:
        angle = float(number(angle, "angle", 0.0, 180.0, above=True))
    check_layer_name(counter)
    return Settings(accels, int(resolution), vectors.get("eye"), vectors.get("look_at"), vectors.get("up"),
                    angle, counter)


def read_settings(text: str) -> Settings:
    """Settings from their JSON (Settings.to_json)."""
    try:
        data = json.loads(text)
    except ValueError as e:
        raise OptionError(f"settings: not JSON ({e})") from None
    if not isinstance(data, dict) or set(data) - {f.name for f in dataclasses.fields(Settings)}:
        raise OptionError(f"settings: a JSON object with the fields {', '.join(f.name for f in dataclasses.fields(Settings))}")
    return settings(**data)


def viewed(scene, s: Settings):
    """A copy of `scene` whose camera has the settings' changes (the camera checks them)."""
    changes = {k: np.asarray(v) for k, v in (("eye", s.eye), ("look_at", s.look_at), ("up", s.up)) if v is not None}
    if s.angle is not None:
        changes["angle"] = s.angle
    if not changes:
        return scene
    if scene.camera is None:
        raise OptionError("camera: this scene has none to change")
    out = copy.copy(scene)
    out.camera = dataclasses.replace(scene.camera, **changes)
    return out


@dataclass
class SampleUse:
    """Each sample's use of each box's counter row (compressed rows: sample k's entries are
    indptr[k]:indptr[k + 1])."""
    indptr: np.ndarray      # (samples + 1,)
    rows: np.ndarray        # the Use row (rendering/structure.box_rows)
    visits: np.ndarray      # the times the sample's rays entered it
    tests: np.ndarray       # the primitive tests they made in it

    def of_sample(self, k: int):
        a, b = self.indptr[k], self.indptr[k + 1]
        return self.rows[a:b], self.visits[a:b], self.tests[a:b]


@dataclass
class Run:
    accel: str
    image: np.ndarray           # (h, w, 3) float RGB
    layers: dict                # name -> (h, w) work layer (rendering/worklayers.py)
    stats: dict                 # the render's statistics (rendering/stats.Stats)
    boxes: Boxes
    use: dict                   # USE's values, one a box (structure_use)
    rows: np.ndarray            # each box's Use row
    samples: SampleUse | None   # None: not traced sample by sample
    tile_seconds: np.ndarray | None     # (tiles down, tiles across), None: not timed
    note: str = ""              # what is missing, or of another structure (a lazy one's, frozen)
    geo: object = None          # the flattened arrays traced (engine/flatten.py): the primitives drawn

    @property
    def shape(self) -> tuple:
        return self.image.shape[:2]

    def node_mask(self, box: int, what: str = "visits") -> np.ndarray:
        """The samples whose rays entered box `box` (what="tests": made tests in it), as (h, w) counts."""
        if self.samples is None:
            raise OptionError(f"{self.accel}: {self.note}")
        if not 0 <= box < len(self.boxes):
            raise OptionError(f"box must be in 0..{len(self.boxes) - 1}, got {box}")
        s = self.samples
        owner = np.repeat(np.arange(len(s.indptr) - 1), np.diff(s.indptr))
        pick = s.rows == self.rows[box]
        out = np.zeros(len(s.indptr) - 1, np.int64)
        np.add.at(out, owner[pick], (s.visits if what == "visits" else s.tests)[pick])
        return out.reshape(self.shape)

    def pixel_boxes(self, x: int, y: int):
        """(boxes the rays of sample (x, y) entered, boxes in which they tested items)."""
        if self.samples is None:
            raise OptionError(f"{self.accel}: {self.note}")
        rows, visits, tests = self.samples.of_sample(y * self.shape[1] + x)
        return (np.flatnonzero(np.isin(self.rows, rows[visits > 0])),
                np.flatnonzero(np.isin(self.rows, rows[tests > 0])))


@dataclass
class Exploration:
    scene: str
    settings: Settings
    runs: dict                  # accel -> Run, in the settings' order
    stage: str = "full"         # "coarse" while the full resolution renders
    seconds: float = 0.0

    @property
    def accels(self) -> list:
        return list(self.runs)

    @property
    def shape(self) -> tuple:
        return next(iter(self.runs.values())).shape

    def layer_names(self) -> list:
        names = set.intersection(*(set(r.layers) for r in self.runs.values()))
        return sorted(names)

    def layer(self, accel: str, name: str) -> np.ndarray:
        if accel not in self.runs:
            raise OptionError(f"no structure {accel!r}; this exploration has: {', '.join(self.runs)}")
        layers = self.runs[accel].layers
        if name not in layers:
            raise OptionError(f"no work layer {name!r}; layers: {', '.join(sorted(layers))}")
        return np.asarray(layers[name])

    def scale(self, name: str) -> tuple:
        """(low, high, "log" or "linear"): every structure's layer on one scale, log where its
        values (those above zero) span more than DECADES decades."""
        values = [self.layer(a, name) for a in self.runs]
        low = float(min(v.min() for v in values))
        high = float(max(v.max() for v in values))
        positive = [v[v > 0] for v in values]
        smallest = min((float(p.min()) for p in positive if p.size), default=0.0)
        log = smallest > 0 and high / smallest > 10 ** DECADES
        return low, high, "log" if log else "linear"

    def work_images(self, name: str) -> WorkImages:
        return WorkImages(scene=self.scene, counter=name, layers={a: self.layer(a, name) for a in self.runs},
                          baseline=self.accels[0])

    def counts_at(self, x: int, y: int) -> dict:
        """accel -> {layer: value} at column x, row y (rows from the top)."""
        h, w = self.shape
        if not (0 <= x < w and 0 <= y < h):
            raise OptionError(f"pixel ({x}, {y}) is outside the {w}x{h} samples (columns 0..{w - 1}, rows 0..{h - 1})")
        return {a: {k: int(v[y, x]) for k, v in r.layers.items()} for a, r in self.runs.items()}

    def hottest(self, name: str, n: int = 10, accel: str | None = None) -> list:
        """The n samples with the most `name` (of `accel`, or the most of any structure), hottest
        first: (x, y, {accel: value})."""
        stack = np.stack([self.layer(a, name) for a in self.runs])
        key = stack[self.accels.index(accel)] if accel else stack.max(axis=0)
        order = np.argsort(-key.ravel(), kind="stable")[:n]
        h, w = self.shape
        return [(int(k % w), int(k // w), {a: int(stack[i].ravel()[k]) for i, a in enumerate(self.runs)})
                for k in order]

    def in_range(self, accel: str, name: str, low: float, high: float) -> np.ndarray:
        """The samples whose `name` of `accel` is in [low, high]: a histogram's selection."""
        v = self.layer(accel, name)
        return (v >= low) & (v <= high)

    def comparison(self, name: str):
        """The exploration as a comparison of work layer `name` (analysis/compare.py), for the
        self-contained HTML report (analysis/report.py)."""
        from ..analysis.compare import Comparison
        from ..analysis.compare import Run as Compared
        runs = [Compared(self.scene, a, r.stats, r.image, int(r.stats.info.get("primitives", 0))
                         if hasattr(r.stats, "info") else 0, work=self.layer(a, name)) for a, r in self.runs.items()]
        h, w = self.shape
        s = self.settings
        command = " ".join(["raykernel explore", self.scene, *(f"--accel '{a}'" for a in s.accels),
                            f"--resolution {s.resolution}"])
        return Comparison(runs, {"resolution": f"{w}x{h}", **{k: v for k, v in (("eye", s.eye), ("look_at", s.look_at),
                                 ("up", s.up), ("angle", s.angle)) if v is not None}}, {}, command, work=name)


def explore_scene(scene, s: Settings, label: str = "", resolution: int | None = None, cancelled=None,
                  max_memory=None, timed: bool = True) -> Exploration:
    """Every structure of the settings rendered at `resolution` (default the settings'), with
    its layers, boxes, per-sample use and tile times. cancelled(): True once a newer request
    came (the render stops with Cancelled between chunks of tiles or samples)."""
    t0 = time.perf_counter()
    cancelled = cancelled or (lambda: False)
    shown = viewed(scene, s)
    res = resolution or s.resolution
    runs = {a: run_structure(shown, a, res, cancelled, max_memory, timed) for a in s.accels}
    return Exploration(label or getattr(scene, "source", "scene"), s, runs, seconds=time.perf_counter() - t0)


def run_structure(scene, accel: str, resolution: int, cancelled=None, max_memory=None, timed=True) -> Run:
    cancelled = cancelled or (lambda: False)
    result, job = _render(scene, accel, resolution, cancelled, max_memory)
    # a lazy structure is traced sample by sample and timed as its render left it (job: frozen)
    frozen = job if job.lazy is not None else None
    boxes, use, rows, samples = _sample_use(scene, accel, resolution, cancelled, max_memory, frozen)
    seconds = _tile_seconds(scene, accel, resolution, cancelled, max_memory, frozen) if timed else None
    notes = ["a lazy structure: its boxes, their use, node masks and tile times are of the structure as its "
             "render left it, refined no further; its work layers are the refining render's"] if frozen else []
    if len(job.geo.wide_nodes):     # the render walked the BVH 4-wide; the boxes are walked as drawn
        notes.append("a 4-wide BVH: its boxes and their use are its binary tree's, walked box by box as drawn "
                     "(bvh(width=2)'s visits); its work layers are the 4-wide walk's, which visits about half "
                     "as many nodes")
    notes += [] if timed else ["tile times not measured"]
    return Run(accel, result.image, result.work, result.stats, boxes, use, rows, samples, seconds,
               "; ".join(notes), job.geo)


def _check(cancelled) -> None:
    if cancelled():
        raise Cancelled()


def _render(scene, accel, resolution, cancelled, max_memory):
    """render(scene, accel, resolution=..., work=True), tile chunk by tile chunk; and its job
    (a lazy structure refined as the render left it)."""
    job = RenderJob(scene, accel=accel, resolution=resolution, work=True, max_memory=max_memory)
    t0 = time.perf_counter()
    for p in range(len(job.passes)):
        n = job.pass_tiles(p)
        for lo in range(0, n, CHUNK):
            _check(cancelled)
            job.trace(p, lo, min(n, lo + CHUNK), job.threads)
        job.end_pass(p)
    return job.result(time.perf_counter() - t0, 0.0), job


def sample_job(scene, accel, resolution, max_memory=None, frozen=None):
    """A render of `accel` that traces one sample a "tile": a tile placed at each sample, traced on the
    lattice of every TILE-th sample so that it holds that sample alone, walked node by node with
    structure_use's box counters on (job.probe); with the render's own tiles (tile_x, tile_y) and
    the octree cells there were before any refinement (for use_values). frozen: a render job of a
    lazy structure, whose structure as that render left it is traced, refined no further."""
    job = RenderJob(scene, accel=accel, resolution=resolution, work=True, threads=1, max_memory=max_memory)
    built = len(job.geo.oct_count)
    _freeze(job, frozen)
    job.geo = with_driver(job.geo)._replace(wide_nodes=job.geo.wide_nodes[:0])     # walked node by node, as drawn
    tiles = job.tile_x.copy(), job.tile_y.copy()
    ys, xs = np.mgrid[0:job.sh, 0:job.sw]
    job.tile_x, job.tile_y = xs.ravel().astype(np.int64), ys.ravel().astype(np.int64)
    n = len(job.tile_x)
    job.counts = np.zeros((n, job.counts.shape[1]), np.int64)
    job.passes, job.work, job.pass_counts = [(TILE, 0, 0, n)], [n], [None]
    job.probe = use_of(job.geo)
    return job, tiles, built


def _freeze(job, frozen) -> None:
    """Job traces the lazy structures of render job `frozen` as they stand: their arrays and their
    pass counters (the columns the refined arrays number), in one pass that nothing refines from
    (end_pass is never called)."""
    if frozen is None:
        return
    job.geo, job.lazy, job.starts = frozen.geo, frozen.lazy, frozen.starts
    job.passes, job.work, job.pass_counts = [(1, 0, 0, job.n_tiles)], [job.n_tiles * TILE * TILE], [None]


def _sample_use(scene, accel, resolution, cancelled, max_memory, frozen=None):
    """The boxes, their use (as structure_use gives it), each box's Use row and each sample's
    use (SampleUse): the image traced one sample at a time (sample_job)."""
    job, _, built = sample_job(scene, accel, resolution, max_memory, frozen)
    n = len(job.tile_x)
    counts = job.probe.counts
    budget = memory_limit(max_memory)
    before = counts[:, [VISITS, TESTS]].copy()
    parts, indptr, stored = [], [0], 0
    for k in range(n):
        if k % SAMPLE_CHUNK == 0:
            _check(cancelled)
            check(stored * 24, budget, "the explorer's per-sample use", "lower the resolution")
        job.trace(0, k, k + 1, 1)
        now = counts[:, [VISITS, TESTS]]
        changed = np.flatnonzero((now != before).any(axis=1))
        diff = now[changed] - before[changed]
        parts.append((changed, diff[:, 0], diff[:, 1]))
        before[changed] = now[changed]
        stored += len(changed)
        indptr.append(stored)
    boxes = boxes_of(job.geo)
    rows = box_rows(boxes, job.probe)
    use = use_values(boxes, job.probe, built if frozen is not None else None)
    cat = [np.concatenate([p[i] for p in parts]) if parts else np.zeros(0, np.int64) for i in range(3)]
    return boxes, use, rows, SampleUse(np.asarray(indptr, np.int64), cat[0].astype(np.int64), cat[1], cat[2])


def _tile_seconds(scene, accel, resolution, cancelled, max_memory, frozen=None) -> np.ndarray:
    """Seconds each tile of the render (without work layers: the kernel a render runs) took on
    one thread, by time.perf_counter_ns around the kernel's call (the finest clock Python reads;
    numba reads none finer), fastest of TIME_REPEATS, the tiles in order each time. frozen: as
    for sample_job."""
    job = RenderJob(scene, accel=accel, resolution=resolution, threads=1, max_memory=max_memory)
    _freeze(job, frozen)
    n = job.pass_tiles(0)
    job.trace(0, 0, 1, 1)           # compiles or loads the kernel, untimed
    best = np.full(n, np.inf)
    for _ in range(TIME_REPEATS):
        for k in range(n):
            if k % CHUNK == 0:
                _check(cancelled)
            t = time.perf_counter_ns()
            job.trace(0, k, k + 1, 1)
            best[k] = min(best[k], (time.perf_counter_ns() - t) * 1e-9)
    across = -(-job.sw // TILE)
    return best.reshape(-1, across)


def tested_items(ray: dict) -> tuple:
    """The items explain's `ray` tested, each once in the order first tested, as (kind, index,
    level); and how many it tested inside an instance (in the instance's own space, not drawn)."""
    instanced = [e["level"] for e in ray.get("entered", []) if e.get("instance", -1) >= 0]
    below = min(instanced) if instanced else None       # an instance's items: from its level down
    tests = [t for step in ray.get("steps", []) for t in step["tests"]] + ray.get("tests", [])
    seen, out, hidden = set(), [], set()
    for t in tests:
        key = (t["primitive"], int(t["index"]), int(t["level"]))
        if key in seen or key in hidden:
            continue
        if below is not None and key[2] >= below:
            hidden.add(key)
            continue
        seen.add(key)
        out.append(key)
    return out, len(hidden)


def primitive_box(geo, kind: str, index: int) -> np.ndarray:
    """(2, 3): the low and high corners of primitive `index` of `kind` (explain's names) in the
    flattened arrays' space, as the builders bound it (engine/flatten.py)."""
    if kind == "sphere":
        c, r = geo.sph_center[index], abs(float(geo.sph_radius[index]))
        return np.stack([c - r, c + r])
    if kind == "cone":
        base, axis, length = geo.cone_base[index], geo.cone_axis[index], float(geo.cone_length[index])
        spread = np.sqrt(np.clip(1.0 - axis ** 2, 0.0, 1.0))      # a disc's extent along each axis
        apex = base + axis * length
        e0, e1 = abs(float(geo.cone_r0[index])) * spread, abs(float(geo.cone_r1[index])) * spread
        return np.stack([np.minimum(base - e0, apex - e1), np.maximum(base + e0, apex + e1)])
    points = primitive_shape(geo, kind, index)[0]
    return np.stack([points.min(axis=0), points.max(axis=0)])


def primitive_shape(geo, kind: str, index: int):
    """(corners (n, 3), triangles (m, 3)) of a polygon, patch or triangle (a polygon fanned from
    its first corner); None for a sphere or a cone."""
    if kind in ("polygon", "patch"):
        a, n = int(geo.poly_start[index]), int(geo.poly_count[index])
        fan = np.stack([np.zeros(n - 2, np.int64), np.arange(1, n - 1), np.arange(2, n)], axis=1)
        return geo.poly_verts[a:a + n], fan
    if kind == "triangle":
        return geo.tri_verts[geo.tri_faces[index]], np.array([[0, 1, 2]])
    return None

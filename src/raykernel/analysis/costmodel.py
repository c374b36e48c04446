"""A linear cost model of trace time: seconds per counted operation, fitted on this machine.

::

    model = costmodel.calibrate()                   # renders the calibration set with every structure kind
    model.save(costmodel.default_path())
    model.predict(result.stats)                     # predicted trace seconds
    costmodel.current()                             # this machine's model, else the reference one
    costmodel.SpeedProbe(model)                     # the machine's speed now against the calibration's

Trace time is modelled as ``sum(count * cost)`` over these features::

  render         one per render: fixed overhead (tile dispatch, allocation)
  ray.shaded     eye + reflection + refraction rays (camera, shading, spawning)
  ray.culled     eye rays of tiles culled whole (frustum.culled): each costs a background sample,
                 and neither ray.shaded nor its walk's bound test counts it
  ray.shadow     shadow rays (no shading)
  ray.lazy.W     rays of a render with lazy structures of walk W (the walk of the lazy kind:
                 octree for lazyoctree, rc for rc), traced coarse to fine: the sparse early
                 passes find little in the caches
  pass.lazy      passes of such a render: each hands its tiles to the threads again
  test.KIND      ray/primitive tests, one cost per primitive kind
  hit.KIND       and those that found the primitive in range (a hit computes its root and
                 takes the closest hit: dearer than a miss)
  polygon.corner corners walked by polygon and patch tests (a polygon's test costs more
                 the more corners it has)
  mailbox        references passed over because their mailbox had the ray already
  leaf           non-empty leaves and cells visited (each starts a loop over references)
  entry.W        rays entering an aggregate of walk W (its set-up: a grid's first cell, an
                 octree's entry point, a ray classification's face and key)
  step.W         traversal steps (cells.visited, N_TS) of walk W
  bound.W        ray/bounding-volume tests charged to walk W
  transform      rays mapped into an instance
  (a walk's own) its counters with a feature name (Walk.counters: the boolean operators'
                 csg.crossing and csg.resolve), and whatever its Walk.features prices apart
                 (the BVH's 4-wide walk as `wide`, a grid's entries beyond one a ray, ray
                 classification's tests and lazy memory: their modules say why)
  refine.pass    lazy structures' refinement between passes of rays: one per pass
  refine.W.*     and per lazy walk W: each subdivision, each candidate reference, and each
                 reference weighted by log2(1 + MiB of its structure) (a reference costs more
                 to filter and copy in a larger structure)

W is one of the kernel's walks (registry.WALK_NAMES); every structure kind runs one of them
(hgrid runs grids, hybrid and lazyoctree octrees with BVHs inside), and the kernel counts
each walk's share apart (walk.W.*), so one model prices any nesting of any kinds. Costs
are wall-clock seconds at the thread count of the calibration, so a model only predicts
renders made with that many threads on that machine; REFERENCE_PATH holds one fitted on a
2-core machine, used where this machine has none (analysis.anneal ranks candidates with it:
rankings move less between machines than seconds do).

Calibration set (CALIBRATION_SCENES): small SPD scenes, a triangle scene and nested scenes
(a small park among them), rendered in SPD mode at two resolutions (128 and 256 pixels: at
256 ray classification grows to the sizes it reaches on full scenes) with every structure
kind, the nested ones both with their own structures inside and wholly under the kind (a
kind offered only to small groups, the brute-force list, only on scenes of at most
SMALL_SCENE_PRIMS primitives); each render is repeated REPEATS times and its shortest trace
time kept, since other work on the machine only ever adds time.
The fit is least squares on relative error (each render weighs the same, whatever its
length), with costs held non-negative and a small ridge term so that features that always
move together (a grid's one root bound test per ray and the ray count) split their cost
evenly instead of wildly. Refinement is timed apart (build.refine_seconds), so its features
are fitted to that time and the others to the rest of the trace time: two smaller fits whose
costs cannot trade against each other.
"""

from __future__ import annotations

import json
import math
import os
import platform
import socket
import statistics
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..aggregates.registry import KINDS, SMALL_ONLY, WALK_COUNTERS, WALK_NAMES, WALKS
from ..geometry.primitives import PRIMITIVE_KINDS
from ..errors import OptionError, RayKernelWarning

VERSION = 10                # calibration files of another version priced other features
REFERENCE_PATH = Path(__file__).with_name("reference_costs.json")

CALIBRATION_SCENES = (
    "spd:balls:1", "spd:balls:2", "spd:gears:1", "spd:gears:2", "spd:tetra:3", "spd:tetra:4",
    "spd:tree:4", "spd:tree:6", "spd:teapot:2", "spd:teapot:3", "spd:mount:2", "spd:mount:3",
    "spd:rings:1", "spd:rings:2", "spd:shells:2", "spd:lattice:2", "spd:jacks:1",
    "scene:diamond:facets=300", "scene:stadium:stadium_prims=800,teapot_prims=400,teapot_bvh=1",
    "scene:satellite:prims=600", "scene:park:rides=2,horses=6,trees=60,mountain_level=3",
)
CALIBRATION_RESOLUTIONS = (128, 256)
SMALL_SCENE_PRIMS = 1500   # a kind offered only to small groups (registry.SMALL_ONLY) is calibrated on scenes this small
REPEATS = 3
RIDGE = 1e-4
ANCHOR_SECONDS = 0.1        # SpeedProbe: anchors long enough to time, short enough to repeat
ANCHORS_PER_KIND = 2
ONE_KIND = " (one kind)"    # a calibration scene rendered wholly under the kind (scene.specs.without_specs)
GROUPS = {"ray": "rays", "render": "rays", "test": "tests", "hit": "tests", "polygon": "tests"}   # breakdown()


def features(stats) -> dict:
    """The counted operations of one render, named as the model's features (the walks' own
    counters say which structures did the work); each walk adds what it prices apart
    (Walk.features)."""
    culled = float(stats.get("frustum.culled", 0))
    f = {
        "render": 1.0,
        "ray.shaded": float(stats["rays.eye"] + stats["rays.reflect"] + stats["rays.refract"]
                            + stats.get("rays.cast", 0)) - culled,
        "ray.shadow": float(stats["rays.shadow"]),
        "ray.culled": culled,
    }
    for k in PRIMITIVE_KINDS:
        f[f"test.{k}"] = float(stats.get(f"tests.{k}", 0))
        f[f"hit.{k}"] = float(stats.get(f"hits.{k}", 0))
    f["polygon.corner"] = float(stats.get("polygon.corners", 0))
    f["mailbox"] = float(stats.get("mailbox.saved", 0))
    f["leaf"] = float(stats.get("cells.leaves", 0))
    for walk in WALK_NAMES:
        f[f"entry.{walk}"] = float(stats.get(f"walk.{walk}.entries", 0))
        f[f"step.{walk}"] = float(stats.get(f"walk.{walk}.steps", 0))
        f[f"bound.{walk}"] = float(stats.get(f"walk.{walk}.bounds", 0))
    f["transform"] = float(sum(stats.get(f"transforms.{k}", 0) for k in ("identity", "translation", "scale",
                                                                          "affine")))
    for counter, feature in WALK_COUNTERS:
        if feature:
            f[feature] = float(stats.get(counter, 0))
    # lazy structures refine between passes of rays, inside the trace time
    rays = f["ray.shaded"] + f["ray.shadow"]
    lazy = [a for a in getattr(stats, "aggregates", []) if "subdivisions" in a]
    if lazy:
        passes = float(stats.get("build.refine_passes", 0))
        f["refine.pass"] = f["pass.lazy"] = passes
        for a in lazy:
            walk = KINDS[a.get("kind", "").split("(")[0]].walk.name      # the walk it refines
            refs = float(a.get("refs", 0))
            megabytes = math.log2(1.0 + a.get("bytes", 0) / 2 ** 20)
            for name, count in (("subdivision", float(a.get("subdivisions", 0))), ("ref", refs),
                                ("ref_mb", refs * megabytes)):
                f[f"refine.{walk}.{name}"] = f.get(f"refine.{walk}.{name}", 0.0) + count
            f[f"ray.lazy.{walk}"] = rays
    used = {w for w in WALK_NAMES if stats.get(f"walk.{w}.entries", 0) or stats.get(f"walk.{w}.steps", 0)}
    for walk in WALKS:
        if walk.features is not None:
            walk.features(stats, f, used)
    return f


def refining(name: str) -> bool:
    """Whether a feature prices refinement (fitted to the refinement time)."""
    return name.startswith("refine.")


def unscaled(name: str) -> bool:
    """Whether a feature is not proportional to the rays: the render's own, the passes, refinement."""
    return name in ("render", "pass.lazy") or refining(name)


def walks_used(stats) -> set:
    """The walks whose work a render's features price (a walk's own pricing may name it apart:
    wide for a BVH walked 4-wide)."""
    return {name.split(".", 1)[1] for name, count in features(stats).items()
            if count and name.split(".")[0] in ("entry", "step") and name.count(".") == 1}


def fit_split(rows: list[dict], times, refine_times, ridge: float = RIDGE) -> dict:
    """fit() twice: the refinement features to `refine_times` (the renders that refined), the
    others to `times` less `refine_times`. A render whose refinement took longer than its
    trace is left out (a refinement kernel compiled inside it)."""
    refine_rows, refine_y, rest_rows, rest_y = [], [], [], []
    for row, t, r in zip(rows, times, refine_times):
        if r >= t:
            continue
        refine = {k: v for k, v in row.items() if refining(k)}
        if r > 0 and any(refine.values()):
            refine_rows.append(refine)
            refine_y.append(r)
        rest_rows.append({k: v for k, v in row.items() if not refining(k)})
        rest_y.append(t - r)
    costs = fit(rest_rows, rest_y, ridge)
    if refine_rows:
        costs.update(fit(refine_rows, refine_y, ridge))
    return costs


def fit(rows: list[dict], times, ridge: float = RIDGE) -> dict:
    """Non-negative costs (seconds per operation) minimising the relative error of
    sum(count * cost) against `times`; features never counted get no cost."""
    names = sorted({k for r in rows for k, v in r.items() if v})
    if not names:
        raise OptionError("cannot fit a cost model: no counted operations")
    y = np.asarray(times, float)
    if len(y) != len(rows) or np.any(y <= 0):
        raise OptionError("cannot fit a cost model: need one positive time per row")
    X = np.array([[r.get(n, 0.0) for n in names] for r in rows], float)
    X = X / y[:, None]                       # relative error: each row's target becomes 1
    target = np.ones(len(y))
    scale = np.abs(X).max(axis=0)
    scale[scale == 0] = 1.0
    Xs = X / scale
    active = list(range(len(names)))
    coef = np.zeros(len(names))
    lam = np.sqrt(ridge)
    while active:
        A = np.vstack([Xs[:, active], lam * np.eye(len(active))])
        b = np.concatenate([target, np.zeros(len(active))])
        sol, *_ = np.linalg.lstsq(A, b, rcond=None)
        if np.all(sol >= 0):
            coef[:] = 0.0
            coef[active] = sol
            break
        # drop the most negative feature and refit (an active-set step towards NNLS)
        worst = active[int(np.argmin(sol))]
        active.remove(worst)
    return {n: float(c / s) for n, c, s in zip(names, coef, scale)}


@dataclass
class CostModel:
    """Seconds per counted operation, fitted by `calibrate` on one machine at one thread count.

    Attributes
    ----------
    costs : dict
        Feature name (see the module docstring) -> seconds per operation.
    threads : int
        The thread count of the calibration: the model predicts renders made with as many.
    machine : dict
        The machine it was fitted on: CPU, cores, threads, host, system and versions.
    calibration : list of dict
        The renders it was fitted on: scene, accel, resolution, trace and predicted seconds.
    """

    costs: dict                       # feature name -> seconds per operation
    threads: int
    machine: dict = field(default_factory=dict)
    calibration: list = field(default_factory=list)   # the renders it was fitted on

    def walks(self) -> set:
        """The walks calibrated (registry.WALK_NAMES), as a set of names."""
        return {n.split(".", 1)[1] for n in self.costs if n.startswith(("step.", "bound.", "entry."))}

    def covers(self, stats) -> bool:
        """Whether every walk that did work in the render of `stats` was calibrated.

        Parameters
        ----------
        stats : Stats
            A render's statistics (``RenderResult.stats``).

        Returns
        -------
        bool
        """
        return walks_used(stats) <= self.walks()

    def predict(self, stats, scale: float = 1.0, partial: bool = False) -> float | None:
        """Predicted trace seconds of a render, from its counts.

        Parameters
        ----------
        stats : Stats
            The render's statistics (``RenderResult.stats``).
        scale : float, default 1
            Multiplies every count but the render's own (a sample of rays standing for `scale`
            times as many).
        partial : bool, default False
            Where a walk the render used was not calibrated, price what was, leaving the rest
            out (else None).

        Returns
        -------
        float or None
            The seconds; None when a walk the render used was not calibrated and `partial` is
            False.
        """
        if not partial and not self.covers(stats):
            return None
        return sum(count * (1.0 if unscaled(name) else scale) * self.costs.get(name, 0.0)
                   for name, count in features(stats).items())

    def breakdown(self, stats) -> dict:
        """Predicted seconds per feature group.

        Parameters
        ----------
        stats : Stats
            The render's statistics (``RenderResult.stats``).

        Returns
        -------
        dict
            ``{"rays": seconds, "tests": seconds, "traversal": seconds}``.
        """
        out = {"rays": 0.0, "tests": 0.0, "traversal": 0.0}
        for name, count in features(stats).items():
            group = GROUPS.get(name.split(".")[0], "traversal")
            out[group] += count * self.costs.get(name, 0.0)
        return out

    def to_dict(self) -> dict:
        """The model as the JSON-ready dict a calibration file holds (with its format's version)."""
        return {"version": VERSION, "costs": self.costs, "threads": self.threads, "machine": self.machine,
                "calibration": self.calibration}

    def save(self, path) -> None:
        """Write the model to a calibration file, atomically, making its directory if needed.

        Parameters
        ----------
        path : str or path-like
            The file, e.g. ``default_path()``.
        """
        from ..atomicfile import atomic_write
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_write(path) as f:
            json.dump(self.to_dict(), f, indent=2)
            f.write("\n")

    @classmethod
    def load(cls, path) -> CostModel:
        """Read a model from a calibration file.

        Parameters
        ----------
        path : str or path-like
            A file written by `save`.

        Returns
        -------
        CostModel

        Raises
        ------
        OptionError
            The file cannot be read, is not a calibration file, or was written by a raykernel
            whose features differ (run ``raykernel calibrate`` again).
        """
        try:
            data = json.loads(Path(path).read_text())
            if data.get("version") != VERSION:
                raise OptionError(f"{path}: a calibration of an older raykernel (its features differ); "
                                  "run `raykernel calibrate` again")
            return cls(costs={k: float(v) for k, v in data["costs"].items()}, threads=int(data["threads"]),
                       machine=data.get("machine", {}), calibration=data.get("calibration", []))
        except (OSError, ValueError, KeyError, TypeError) as err:
            raise OptionError(f"{path}: not a cost-model calibration file ({err})") from None


def default_path() -> Path:
    """Per-machine calibration file: $XDG_CACHE_HOME/raykernel/calibration-HOST.json."""
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "raykernel" / f"calibration-{socket.gethostname() or 'machine'}.json"


def load_default() -> CostModel | None:
    """This machine's calibration (raykernel calibrate), None where there is none."""
    path = default_path()
    return CostModel.load(path) if path.exists() else None


def current() -> CostModel:
    """This machine's calibration, else the reference costs shipped with raykernel.

    The reference costs are used also when this machine's calibration was made by a raykernel
    that priced other features: a RayKernelWarning says so.

    Returns
    -------
    CostModel
    """
    try:
        model = load_default()
    except OptionError as err:
        import warnings
        warnings.warn(f"{err}; using the reference costs meanwhile", RayKernelWarning, stacklevel=2)
        model = None
    return model or CostModel.load(REFERENCE_PATH)


def machine_info() -> dict:
    """CPU model, cores, threads and versions."""
    import sys

    from importlib.metadata import PackageNotFoundError, version

    import numba
    import numpy
    try:
        ours = version("raykernel")
    except PackageNotFoundError:      # a source tree that is not installed
        ours = "unknown"
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return {"cpu": cpu, "cores": os.cpu_count(), "threads": numba.get_num_threads(),
            "host": socket.gethostname(), "system": f"{platform.system()} {platform.release()}",
            "python": sys.version.split()[0], "numpy": numpy.__version__, "numba": numba.__version__,
            "raykernel": ours}


class SpeedProbe:
    """The machine's speed now against its speed during the calibration.

    A few of the calibration's own renders (per kind, the `per_kind` whose trace took nearest
    ANCHOR_SECONDS) are timed again. A shared machine's speed drifts after the costs were
    fitted, which adds to the model's own error.

    Parameters
    ----------
    model : CostModel
        The model whose calibration renders are the anchors.
    per_kind : int, optional
        Anchors per structure kind (default ANCHORS_PER_KIND).
    threads : int, optional
        The threads of the anchors' renders (default: all cores).

    Examples
    --------
    >>> probe = costmodel.SpeedProbe(model)
    >>> probe.measure()                     # each anchor rendered once; again between other work
    >>> model.predict(stats) * probe.factor()   # seconds at the speed of the last measurements
    """

    def __init__(self, model: CostModel, per_kind: int | None = None, threads: int | None = None):
        per_kind = ANCHORS_PER_KIND if per_kind is None else per_kind
        by_kind = {}
        for run in model.calibration:
            if run.get("trace", 0) > 0 and {"scene", "accel", "resolution"} <= set(run):
                by_kind.setdefault(run["accel"], []).append(run)
        self.anchors = [run for runs in by_kind.values()
                        for run in sorted(runs, key=lambda r: abs(math.log(r["trace"] / ANCHOR_SECONDS)))[:per_kind]]
        self.threads = threads
        self._scenes = {}
        self.reset()

    def reset(self) -> None:
        """Forget the times measured (the best of each anchor's renders since)."""
        self.best = [math.inf] * len(self.anchors)

    def _scene(self, name):
        from ..scene.loading import load
        from ..scene.specs import without_specs
        if name not in self._scenes:
            base = name.removesuffix(ONE_KIND)
            scene = load(base)
            self._scenes[name] = without_specs(scene) if name != base else scene
        return self._scenes[name]

    def measure(self) -> None:
        """Render every anchor once, keeping each one's best trace time."""
        from ..rendering.render import render
        for i, run in enumerate(self.anchors):
            stats = render(self._scene(run["scene"]), accel=run["accel"], resolution=run["resolution"], spd=True,
                           threads=self.threads).stats
            self.best[i] = min(self.best[i], stats["time.trace"])

    def ratios(self) -> list[float]:
        """Per anchor measured: its best trace time now over its time in the calibration.

        Returns
        -------
        list of float
        """
        return [best / run["trace"] for best, run in zip(self.best, self.anchors) if math.isfinite(best)]

    def factor(self) -> float:
        """The geometric mean of the ratios (1.0 before any measurement).

        Returns
        -------
        float
            Above 1 when the machine runs slower than during the calibration: 1.1 for 10%
            slower.
        """
        ratios = self.ratios()
        return statistics.geometric_mean(ratios) if ratios else 1.0


def _names_structures(group, seen=None) -> bool:
    """Whether `group` or a group below it names a structure of its own."""
    seen = set() if seen is None else seen
    if id(group) in seen:
        return False
    seen.add(id(group))
    return group.accel is not None or any(_names_structures(getattr(c, "group", c), seen) for c in group.children)


def calibrate(kinds=None, scenes=CALIBRATION_SCENES, resolutions=CALIBRATION_RESOLUTIONS,
              threads: int | None = None, log=None, repeats: int = REPEATS) -> CostModel:
    """Render the calibration set with every structure kind and fit the costs.

    Each render is made in SPD mode, repeated `repeats` times, its shortest trace time kept
    (see the module docstring for the set and the fit).

    Parameters
    ----------
    kinds : sequence of str, optional
        The structure kinds to calibrate (default: every registered kind that takes no
        operands).
    scenes : sequence of str, default CALIBRATION_SCENES
        Scene names, as for `raykernel.load`.
    resolutions : sequence of int, default CALIBRATION_RESOLUTIONS
        The image sizes each scene is rendered at.
    threads : int, optional
        The renders' threads (default: all cores); the model predicts renders made with as
        many.
    log : callable, optional
        ``log(str)``, called after each render with its trace time.
    repeats : int, default REPEATS
        Renders of each scene, kind and resolution.

    Returns
    -------
    CostModel
        The fitted model, with the machine's description and the renders it was fitted on.

    Raises
    ------
    OptionError
        No render counted any operation to fit.
    """
    import numba

    from ..rendering.render import render
    from ..scene.loading import load
    from ..scene.specs import without_specs
    kinds = list(kinds or (name for name, kind in KINDS.items() if not kind.operands))
    loaded = []
    for name in scenes:
        scene = load(name)
        loaded.append((name, scene))
        # a scene whose groups name structures of their own is rendered nested and, to price
        # each kind over instances and many small objects, wholly under the kind as well
        if _names_structures(scene.root):
            loaded.append((name + ONE_KIND, without_specs(scene)))
    rows, times, refine_times, runs = [], [], [], []
    for kind in kinds:
        # compile (or load from the cache) before anything is timed
        render(loaded[0][1], accel=kind, resolution=4, spd=True, threads=threads)
        for name, scene in loaded:
            if kind in SMALL_ONLY and scene.count_primitives() > SMALL_SCENE_PRIMS:
                continue
            for res in resolutions:
                t0 = time.perf_counter()
                stats = min((render(scene, accel=kind, resolution=res, spd=True, threads=threads).stats
                             for _ in range(max(1, repeats))), key=lambda s: s["time.trace"])
                if log:
                    log(f"{kind:8s} {name:28s} {res:4d}  trace {stats['time.trace']:.4f} s "
                        f"({time.perf_counter() - t0:.2f} s)")
                if stats["time.trace"] <= 0:
                    continue
                rows.append(features(stats))
                times.append(stats["time.trace"])
                refine_times.append(stats.get("build.refine_seconds", 0.0))
                runs.append({"scene": name, "accel": kind, "resolution": res, "trace": stats["time.trace"]})
    costs = fit_split(rows, times, refine_times)
    model = CostModel(costs=costs, threads=numba.get_num_threads(), machine=machine_info(), calibration=runs)
    for run, row in zip(runs, rows):
        run["predicted"] = sum(c * costs.get(n, 0.0) for n, c in row.items())
    return model

"""Compare acceleration structures by the work they do (Glassner, RTNews 2(1)).

    cmp = compare(["spd:balls", "spd:gears"], ["list", "grid", "bvh"], spd=True, resolution=128)
    cmp.disagreements          # [] when every structure cast the same rays
    cmp = compare(["scene:stadium"], ["grid", "bvh"], work="tests.total")   # + each run's work layer
    for part in tables(cmp, width=console.width): console.print(part)     # split to fit, never cut
    write_json(cmp, "cmp.json"); write_csv(cmp, "cmp.csv")

    sw = sweep("scene:stadium:ratio={ratio}", {"ratio": ["1", "100", "10000"]}, ["grid", "bvh"])
    plot_sweep(sw, "stadium.png")

Every scene is loaded once and rendered with every structure. The ray
counts (`rays.*`) depend only on the scene and the options, never on the
structure, so any difference between structures is a correctness failure.
"""

from __future__ import annotations

import csv
import io
import itertools
import json
import re
import sys
from dataclasses import dataclass, field

import numpy as np

from ..errors import OptionError
from ..rendering.stats import jsonable
from .auto import render

TIMING_KEYS = ("time.parse", "time.preprocess", "time.trace", "time.compile", "time.load", "time.rays_per_second",
               "build.seconds")

# (header, stats key or callable, format)
COLUMNS = (
    ("N_IT", "tests.per_ray", "{:.2f}"),
    ("N_TS", "cells.visited_per_ray", "{:.2f}"),
    ("N_ETS", "cells.leaves_per_ray", "{:.2f}"),
    ("N_EETS", "cells.empty_per_ray", "{:.2f}"),
    ("bounds/ray", "bounds.per_ray", "{:.2f}"),
    ("mailbox saved", "mailbox.saved", "{:,}"),
    ("nodes", "build.nodes", "{:,}"),
    ("bytes", "build.bytes", "{:,}"),
    ("build s", "build.seconds", "{:.3f}"),
    ("trace s", "time.trace", "{:.3f}"),
    ("predicted s", "predicted.trace", "{:.3f}"),
    ("Mrays/s", "mrays", "{:.2f}"),
)


def ray_keys(stats) -> list:
    """The ray counts that must not depend on the structure."""
    return sorted(k for k in stats if k.startswith("rays."))


@dataclass
class Run:
    scene: str
    accel: str
    stats: object
    image: np.ndarray
    primitives: int
    params: dict = field(default_factory=dict)      # sweep parameters, if any
    predicted: float | None = None
    work: np.ndarray | None = None                  # compare(work=COUNTER): that counter's work layer

    def value(self, key):
        if key == "predicted.trace":
            return self.predicted
        if key == "mrays":
            return self.stats.get("time.rays_per_second", 0.0) / 1e6
        return self.stats.get(key)


@dataclass
class Disagreement:
    scene: str
    reference: str
    accel: str
    counters: dict        # key -> (reference value, this structure's value)

    def text(self) -> str:
        diffs = ", ".join(f"{k}: {a} vs {b}" for k, (a, b) in self.counters.items())
        return f"scene {self.scene}: structures {self.reference} and {self.accel} disagree on {diffs}"


@dataclass
class Comparison:
    runs: list
    options: dict
    machine: dict
    command: str
    disagreements: list = field(default_factory=list)
    model: object = None
    params: dict = field(default_factory=dict)     # sweep: name -> values
    work: str | None = None                         # the counter whose work layers the runs hold

    def scenes(self) -> list:
        return list(dict.fromkeys(r.scene for r in self.runs))

    def accels(self) -> list:
        return list(dict.fromkeys(r.accel for r in self.runs))


def command_line(argv=None) -> str:
    import shlex
    argv = sys.argv if argv is None else argv
    return " ".join(shlex.quote(str(a)) for a in ["raykernel", *argv[1:]])


def check_rays(runs: list) -> list:
    """Disagreements of the ray counts between structures, per scene."""
    out = []
    by_scene = {}
    for run in runs:
        by_scene.setdefault(run.scene, []).append(run)
    for scene, group in by_scene.items():
        ref = group[0]
        for other in group[1:]:
            keys = sorted(set(ray_keys(ref.stats)) | set(ray_keys(other.stats)))
            diff = {k: (ref.stats.get(k), other.stats.get(k)) for k in keys
                    if ref.stats.get(k) != other.stats.get(k)}
            if diff:
                out.append(Disagreement(scene, ref.accel, other.accel, diff))
    return out


def _warm_up(accels, spd, threads):
    """Compile (or load from numba's cache) every kernel before anything is timed."""
    from ..scene.loading import load
    scene = load("spd:balls:1")
    for accel in accels:
        render(scene, accel=accel, resolution=4, spd=spd, threads=threads)


def _check_accels(accels):
    from ..aggregates.registry import parse_spec
    if not accels:
        raise OptionError("name at least one structure with --accel SPEC")
    for a in accels:
        parse_spec(a)


def _model(model):
    if model is None or model is False:
        return None
    if model == "default":
        from .costmodel import load_default
        return load_default()
    if isinstance(model, str):
        from .costmodel import CostModel
        return CostModel.load(model)
    return model


def _cell(scene, label, params, accel, options, work=None) -> Run:
    """One scene x structure cell of a comparison (scene: a Scene or a name to load); work: a
    counter whose work layer the run keeps."""
    if not hasattr(scene, "root"):
        scene = _load_scene(scene)
    result = render(scene, accel=accel, work=work is not None, **options)
    if work is not None and work not in result.work:
        raise OptionError(f"{label} with {accel} has no work layer {work!r}; it has: {', '.join(sorted(result.work))}")
    return Run(scene=label, accel=accel, stats=result.stats, image=result.image,
               primitives=scene.count_primitives(), params=dict(params),
               work=None if work is None else np.array(result.work[work]))


def compare(scenes, accels, spd=False, resolution=None, threads=None, max_depth=5, model="default",
            log=None, command=None, warm_up=True, cluster=None, work=None) -> Comparison:
    """Render every scene with every structure.

    The ray counts (``rays.*``) depend only on the scene and the options, never on the
    structure, so any difference between structures is a correctness failure, listed in the
    result's ``disagreements``.

    Parameters
    ----------
    scenes : sequence
        Scene names (as for `raykernel.load`) or ``(label, Scene, params)`` triples.
    accels : sequence of str
        The accelerator specs to compare, at least one.
    spd, resolution, threads, max_depth
        As for `raykernel.render`.
    model : CostModel, str, None or "default"
        The cost model that predicts each run's trace time: ``"default"``, this machine's
        calibration (none where it has none); a path to a calibration file; a CostModel; or
        None or False for no prediction.
    log : callable, optional
        ``log(str)``, called after each run with its trace time (not on a cluster).
    command : str, optional
        The command line recorded in the result (default: this process's).
    warm_up : bool, default True
        Compile (or load from the cache) every kernel before anything is timed.
    cluster : Cluster, optional
        A ``cluster.Cluster`` to run the cells on, one task each (the same counts; the times
        are each worker's).
    work : str, optional
        A counter name (e.g. ``"tests.total"``): every run keeps that counter's work layer
        (analysis/workimages.py draws them).

    Returns
    -------
    Comparison
        ``runs`` (one Run per scene and structure: its stats, image and predicted time),
        ``disagreements`` (empty when every structure cast the same rays), the options, the
        machine and the command.

    Raises
    ------
    OptionError
        No structure is named, a spec or the work counter is not valid, or a run has no work
        layer of that name.

    Examples
    --------
    >>> cmp = compare(["spd:balls", "spd:gears"], ["list", "grid", "bvh"], spd=True, resolution=128)
    >>> cmp.disagreements          # [] when every structure cast the same rays
    """
    from .costmodel import machine_info
    _check_accels(accels)
    if work is not None:
        from ..rendering.worklayers import check_layer_name
        check_layer_name(work)
    model = _model(model)
    options = dict(resolution=resolution, spd=spd, max_depth=max_depth, threads=threads)
    if cluster is not None:
        if warm_up:
            cluster.warm_up({"threads": threads} if threads else {})
        cells = []
        for item in scenes:
            label, scene, params = item if isinstance(item, tuple) else (item, item, {})
            shipped = cluster.share(scene)[0] if hasattr(scene, "root") else scene
            cells += [(shipped, label, params, accel, cluster.task_options(options), work) for accel in accels]
        runs = cluster.map(_cell, cells, doing="comparing")
    else:
        if warm_up:
            _warm_up(accels, spd, threads)
        runs = []
        for item in scenes:
            label, scene, params = item if isinstance(item, tuple) else (item, _load_scene(item), {})
            for accel in accels:
                runs.append(_cell(scene, label, params, accel, options, work))
                if log:
                    log(f"{label} {accel}: trace {runs[-1].stats['time.trace']:.3f} s")
    for run in runs:
        if model is not None:
            run.predicted = model.predict(run.stats)
    return Comparison(runs=runs, options={"spd": spd, "resolution": resolution, "threads": threads,
                                          "max_depth": max_depth},
                      machine=machine_info(), command=command or command_line(),
                      disagreements=check_rays(runs), model=model, work=work)


# --- sweeps ---------------------------------------------------------------------------------

_PLACEHOLDER = re.compile(r"\{(\w+)\}")


def parse_params(items) -> dict:
    """['sf=1,2,3'] -> {'sf': ['1', '2', '3']} (order kept)."""
    params = {}
    for item in items:
        name, eq, values = item.partition("=")
        name = name.strip()
        vals = [v.strip() for v in values.split(",") if v.strip()]
        if not eq or not name or not vals:
            raise OptionError(f"--param expects NAME=V1,V2,..., got {item!r}")
        if name in params:
            raise OptionError(f"--param {name} is given twice")
        params[name] = vals
    return params


def expand(template: str, params: dict) -> list:
    """(scene string, {name: value}) for every combination of the parameter values."""
    used = set(_PLACEHOLDER.findall(template))
    missing = used - set(params)
    if missing:
        raise OptionError(f"the template {template!r} uses {{{sorted(missing)[0]}}} but no --param gives it")
    unused = set(params) - used
    if unused:
        raise OptionError(f"--param {sorted(unused)[0]} does not appear in the template {template!r} "
                          f"(write it as {{{sorted(unused)[0]}}})")
    names = list(params)
    out = []
    for combo in itertools.product(*(params[n] for n in names)):
        values = dict(zip(names, combo))
        out.append((_PLACEHOLDER.sub(lambda m: values[m.group(1)], template), values))
    return out


def _load_scene(text: str):
    from ..scene.loading import load
    prefix, _, rest = text.partition(":")
    if prefix == "scene" and rest:
        from ..scene import pathological
        return pathological.load(rest)
    return load(text)


def sweep(template, params: dict, accels, spd=False, resolution=None, threads=None, max_depth=5,
          model="default", log=None, command=None, cluster=None) -> Comparison:
    """Compare structures over a family of scenes: `compare` of every value of the parameters.

    Parameters
    ----------
    template : str
        A scene name with ``{NAME}`` placeholders, e.g. ``"scene:stadium:ratio={ratio}"``.
    params : dict
        NAME -> list of values (strings), each NAME a placeholder of `template`; every
        combination of values is one scene.
    accels, spd, resolution, threads, max_depth, model, log, command, cluster
        As for `compare`.

    Returns
    -------
    Comparison
        As `compare`'s, with ``params`` and ``options["template"]`` set; each run's ``params``
        holds its values.

    Raises
    ------
    OptionError
        A placeholder has no parameter, or a parameter no placeholder; or as for `compare`.

    Examples
    --------
    >>> sw = sweep("scene:stadium:ratio={ratio}", {"ratio": ["1", "100", "10000"]}, ["grid", "bvh"])
    >>> plot_sweep(sw, "stadium.png")
    """
    # on a cluster the workers load each scene themselves: only its name travels
    items = [(scene, scene if cluster is not None else _load_scene(scene), values)
             for scene, values in expand(template, params)]
    cmp = compare(items, accels, spd=spd, resolution=resolution, threads=threads, max_depth=max_depth,
                  model=model, log=log, command=command, cluster=cluster)
    cmp.params = dict(params)
    cmp.options["template"] = template
    return cmp


def _number(text):
    try:
        return float(text)
    except (TypeError, ValueError):
        return None


def spans_decades(values, decades=2.0) -> bool:
    """Whether the values above zero span more than `decades` decades: drawn on a log scale."""
    v = [x for x in values if x is not None and x > 0]
    return len(v) >= 2 and max(v) / min(v) > 10 ** decades


SWEEP_PANELS = (
    ("tests per ray (N_IT)", "tests.per_ray"),
    ("traversal steps per ray (N_TS)", "cells.visited_per_ray"),
    ("build seconds", "build.seconds"),
    ("trace seconds", "time.trace"),
)


def _png(make, cmp: Comparison) -> bytes:
    """The figure make(cmp) as PNG bytes, drawn without a display."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig = make(cmp)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    plt.close(fig)
    return buf.getvalue()


def sweep_figure_png(cmp: Comparison) -> bytes:
    """sweep_figure(cmp) as PNG bytes."""
    return _png(sweep_figure, cmp)


def sweep_figure(cmp: Comparison):
    """The four sweep panels against the first parameter, one line per structure (and other values)."""
    import matplotlib.pyplot as plt
    names = list(cmp.params)
    xname = names[0]
    xs_text = cmp.params[xname]
    numeric = all(_number(x) is not None for x in xs_text)
    fig, axes = plt.subplots(2, 2, figsize=(11, 8))
    for ax, (title, key) in zip(axes.flat, SWEEP_PANELS):
        all_y = []
        series = {}
        for run in cmp.runs:
            others = ", ".join(f"{n}={run.params[n]}" for n in names[1:])
            label = run.accel + (f" ({others})" if others else "")
            series.setdefault(label, []).append(run)
        for label, runs in series.items():
            xs = [_number(r.params[xname]) if numeric else xs_text.index(r.params[xname]) for r in runs]
            ys = [float(r.value(key) or 0.0) for r in runs]
            all_y += ys
            ax.plot(xs, ys, marker="o", label=label)
        if numeric and spans_decades([_number(x) for x in xs_text]):
            ax.set_xscale("log")
        if not numeric:
            ax.set_xticks(range(len(xs_text)), xs_text)
        if spans_decades(all_y):
            ax.set_yscale("log")
        ax.set_title(title)
        ax.set_xlabel(xname)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(cmp.options.get("template", ""))
    fig.tight_layout()
    return fig


def compare_figure_png(cmp: Comparison) -> bytes:
    """compare_figure(cmp) as PNG bytes."""
    return _png(compare_figure, cmp)


def compare_figure(cmp: Comparison):
    """Grouped bars per scene: N_IT, N_TS, trace seconds, and predicted against measured time
    (that panel only where a calibration predicted times: no empty frame without one)."""
    import matplotlib.pyplot as plt
    scenes, accels = cmp.scenes(), cmp.accels()
    pts = [(r.stats["time.trace"], r.predicted, r.accel) for r in cmp.runs if r.predicted]
    fig, axes = plt.subplots(2, 2, figsize=(12, 8)) if pts else plt.subplots(1, 3, figsize=(15, 4.6))
    width = 0.8 / max(1, len(accels))
    x = np.arange(len(scenes))
    for ax, (title, key) in zip(axes.flat[:3], (("tests per ray (N_IT)", "tests.per_ray"),
                                                ("traversal steps per ray (N_TS)", "cells.visited_per_ray"),
                                                ("trace seconds", "time.trace"))):
        all_y = []
        for i, accel in enumerate(accels):
            ys = []
            for s in scenes:
                run = next((r for r in cmp.runs if r.scene == s and r.accel == accel), None)
                ys.append(float(run.value(key) or 0.0) if run else 0.0)
            all_y += ys
            ax.bar(x + i * width - 0.4 + width / 2, ys, width, label=accel)
        if spans_decades(all_y):
            ax.set_yscale("log")
        ax.set_xticks(x, [s.split(":", 1)[-1] for s in scenes], rotation=60, ha="right", fontsize=7)
        ax.set_title(title)
        ax.legend(fontsize=8)
    if pts:
        ax = axes.flat[3]
        for accel in accels:
            p = [(m, q) for m, q, a in pts if a == accel]
            if p:
                ax.scatter([m for m, _ in p], [q for _, q in p], label=accel, s=14)
        lo = min(min(m, q) for m, q, _ in pts)
        hi = max(max(m, q) for m, q, _ in pts)
        ax.plot([lo, hi], [lo, hi], color="gray", lw=1)
        ax.plot([lo, hi], [1.25 * lo, 1.25 * hi], color="gray", lw=0.5, ls="--")
        ax.plot([lo, hi], [0.75 * lo, 0.75 * hi], color="gray", lw=0.5, ls="--")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.legend(fontsize=8)
        ax.set_xlabel("measured trace s")
        ax.set_ylabel("predicted trace s")
        ax.set_title("cost model: predicted against measured (dashed: ±25%)")
    fig.tight_layout()
    return fig


def plot_sweep(cmp: Comparison, path) -> None:
    from ..atomicfile import atomic_write
    data = sweep_figure_png(cmp)
    with atomic_write(path, "wb") as f:
        f.write(data)


# --- output ---------------------------------------------------------------------------------

def table_rows(cmp: Comparison):
    """(scene, accel, [cell texts]) for every run."""
    for run in cmp.runs:
        cells = []
        for _, key, fmt in COLUMNS:
            v = run.value(key)
            cells.append("-" if v is None else fmt.format(v))
        yield run.scene, run.accel, cells


def table(cmp: Comparison, title=None, columns=COLUMNS):
    """A rich Table of every run (scene, structure and `columns`); no cell is ever cut short."""
    from rich.table import Table
    from rich.text import Text          # names as written: "scene:stadium:" is no emoji, "[x]" no markup
    t = Table(title=title, header_style="bold", show_edge=False)
    t.add_column("scene", overflow="fold")
    t.add_column("structure", overflow="fold")
    for header, _, _ in columns:
        t.add_column(header, justify="right", no_wrap=True)
    keep = [k for k, c in enumerate(COLUMNS) if c in columns]
    last = None
    for scene, accel, cells in table_rows(cmp):
        if last is not None and scene != last:
            t.add_section()
        t.add_row(Text(scene if scene != last else ""), Text(accel), *(cells[k] for k in keep))
        last = scene
    return t


def tables(cmp: Comparison, title=None, width: int = 80) -> list:
    """table() split by columns into as many tables as it takes for each to fit `width`
    characters (each keeps the scene and structure), so that no number is cut or wrapped."""
    rows = list(table_rows(cmp))
    names = max([len("scene") + len("structure")] + [len(s) + len(a) for s, a, _ in rows])
    widths = [max([len(h)] + [len(cells[k]) for _, _, cells in rows]) + 3 for k, (h, _, _) in enumerate(COLUMNS)]
    groups, group, used = [], [], min(names + 6, width // 2)
    for column, w in zip(COLUMNS, widths):
        if group and used + w > width:
            groups.append(group)
            group, used = [], min(names + 6, width // 2)
        group.append(column)
        used += w
    groups.append(group)
    return [table(cmp, title=title if k == 0 else None, columns=tuple(g)) for k, g in enumerate(groups)]


def _run_dict(run: Run) -> dict:
    return {"scene": run.scene, "accel": run.accel, "params": run.params, "primitives": run.primitives,
            "counters": {k: jsonable(v) for k, v in run.stats.items()},
            "predicted_trace": run.predicted, "aggregates": run.stats.aggregates,
            "info": run.stats.info}


def to_dict(cmp: Comparison) -> dict:
    return {"command": cmp.command, "machine": cmp.machine, "options": cmp.options, "params": cmp.params,
            "cost_model": cmp.model.to_dict()["costs"] if cmp.model is not None else None,
            "disagreements": [{"scene": d.scene, "reference": d.reference, "accel": d.accel,
                               "counters": {k: list(v) for k, v in d.counters.items()}}
                              for d in cmp.disagreements],
            "runs": [_run_dict(r) for r in cmp.runs]}


def write_json(cmp: Comparison, path) -> None:
    from ..atomicfile import atomic_write
    with atomic_write(path) as f:
        json.dump(to_dict(cmp), f, indent=2, default=jsonable)
        f.write("\n")


def write_csv(cmp: Comparison, path) -> None:
    from ..atomicfile import atomic_write
    keys = list(dict.fromkeys(k for r in cmp.runs for k in r.stats))
    pnames = list(cmp.params)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["scene", "accel", *pnames, "primitives", *keys, "predicted.trace"])
    for r in cmp.runs:
        w.writerow([r.scene, r.accel, *(r.params.get(n, "") for n in pnames), r.primitives,
                    *(r.stats.get(k, "") for k in keys), "" if r.predicted is None else r.predicted])
    with atomic_write(path) as f:
        f.write(buf.getvalue())


def print_disagreements(cmp: Comparison, console) -> None:
    from rich.panel import Panel
    lines = "\n".join(d.text() for d in cmp.disagreements)
    console.print(Panel(lines, title="CORRECTNESS FAILURE: ray counts differ between structures",
                        style="bold red"), markup=False)
    for d in cmp.disagreements:
        sys.stderr.write(f"raykernel: CORRECTNESS FAILURE: {d.text()}\n")


def prediction_summary(cmp: Comparison) -> list:
    """(accel, worst relative error, mean relative error, runs) of the cost model per structure."""
    out = []
    for accel in cmp.accels():
        errs = [(r.predicted - r.stats["time.trace"]) / r.stats["time.trace"]
                for r in cmp.runs if r.accel == accel and r.predicted and r.stats["time.trace"] > 0]
        if errs:
            worst = max(errs, key=abs)
            out.append((accel, worst, float(np.mean(np.abs(errs))), len(errs)))
    return out


def command_from_args(name: str, args) -> str:
    """The command line that reproduces a parsed `raykernel compare` or `raykernel sweep`."""
    import shlex
    words = ["raykernel", name]
    words += list(getattr(args, "scene", None) or [getattr(args, "template", "")])
    for p in getattr(args, "param", None) or []:
        words += ["--param", p]
    for a in args.accel:
        words += ["--accel", a]
    if args.spd:
        words.append("--spd")
    for opt in ("resolution", "threads", "json", "csv", "report", "plot", "calibration"):
        value = getattr(args, opt, None)
        if value is not None:
            words += [f"--{opt}", str(value)]
    return " ".join(shlex.quote(w) for w in words)

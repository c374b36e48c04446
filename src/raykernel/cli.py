"""The `raykernel` command.

    raykernel render spd:balls -o balls.png --accel bvh --spd
    raykernel render scene.nff --stats-json stats.json --threads 2
    raykernel accels
    raykernel spd teapot --size 12 -o teapot.nff
    raykernel cast model.obj --rays rays.npz --out hits.zarr --fields t,prim_id

Errors a user can fix are printed as one line (no traceback) with exit status 2.
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import sys
import time
from pathlib import Path

from .errors import OptionError, RayKernelError

SCENE_HELP = ("a .nff, .json or model file (.obj with its .mtl, .ply, .stl, .off, .gltf, .glb: the mesh extra), "
              "spd:NAME[:SIZE], scene:NAME[:k=v,...] or example:NAME")


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def _default_output(scene_arg: str) -> str:
    if ":" in scene_arg and not Path(scene_arg).exists():
        return scene_arg.split(":")[1] + ".png"
    return Path(scene_arg).stem + ".png"


class _Progress:
    """A rich progress bar that appears only once a render has run for a second; with `unit` (say
    "rays"), it shows the rate of what was done since its first report (a resumed cast's earlier
    chunks are not counted in the rate)."""

    def __init__(self, console, label: str, compiling: bool = False, unit: str | None = None):
        self.console = console
        self.label = label
        self.start = time.perf_counter()
        self.bar = None
        self.task = None
        self.status = None
        self.unit = unit
        self.first = None       # (time, done) of the first report
        if compiling:
            # the first call compiles before any pass ends: a spinner until the bar can take over
            self.status = console.status(f"{label}: compiling kernels", spinner="dots")
            self.status.start()

    def __call__(self, done: int, total: int):
        if self.status is not None:
            self.status.stop()
            self.status = None
        now = time.perf_counter()
        if self.first is None:
            self.first = (now, done)
        if self.bar is None:
            if now - self.start < 1.0 or done >= total:
                return
            from rich.progress import BarColumn, Progress, TimeElapsedColumn, TimeRemainingColumn
            rate = ("{task.fields[rate]}",) if self.unit else ()
            self.bar = Progress("[progress.description]{task.description}", BarColumn(),
                                "{task.percentage:>3.0f}%", *rate, TimeElapsedColumn(), TimeRemainingColumn(),
                                console=self.console, transient=True)
            self.bar.start()
            self.task = self.bar.add_task(self.label, total=total, rate="")
        seconds = now - self.first[0]
        rate = f"{(done - self.first[1]) / seconds / 1e6:.2f} M{self.unit}/s" if self.unit and seconds > 0 else ""
        self.bar.update(self.task, completed=done, rate=rate)

    def close(self):
        if self.status is not None:
            self.status.stop()
        if self.bar is not None:
            self.bar.stop()


def cmd_render(args, console) -> int:
    from .atomicfile import check_output_directory
    from .geometry.compiletime import OTHER_RENDERS
    from .geometry.config import tell_once
    from .rendering.imageio import image_format
    from .analysis.auto import render
    from .rendering.render import first_run
    from .scene import examples
    from .aggregates.registry import parse_spec
    from .aggregates.spec import is_auto
    from .scene.loading import load
    from .rendering.worklayers import picture, save_layers, work_file_format

    scene = _viewed(load(args.scene), args)
    options = {}
    if args.scene.startswith("example:"):
        options.update(examples.render_defaults(args.scene.split(":", 1)[1]))
    options.update(_trace_options(args))
    out = args.output or _default_output(args.scene)
    # refuse what would fail after the work before it (and before saying it will compile)
    image_format(out)
    check_output_directory(out)
    if args.stats_json:
        check_output_directory(args.stats_json)
    work_images = _work_images(args.work_image, out)
    if args.work:
        work_file_format(args.work)
        check_output_directory(args.work)
    for path in work_images.values():
        check_output_directory(path)
    if args.work or work_images:
        options["work"] = True
    _, auto = parse_spec(args.accel)
    if args.draw is not None and (is_auto(args.accel) or not (args.draw == "all" or args.draw.isdigit())):
        raise OptionError(f"--draw {args.draw}: give a depth (0, 1, ...) or all, with a structure spec (not auto)")
    if is_auto(args.accel):
        console.print(f"Annealing a hierarchy for this render first (auto: up to {auto['seconds']:g} s; "
                      "raykernel anneal writes one to reuse).", markup=False, highlight=False)
        tell_once("anneal", None)
    compiling = first_run()
    if compiling:
        tell_once("render", None)       # the line below says it, and the spinner covers the wait
        console.print(f"Compiling raykernel's kernels: first run after install only, tens of seconds "
                      f"on 2 cores ({OTHER_RENDERS}); later runs start from the cache.", markup=False,
                      highlight=False)
    progress = _Progress(console, f"rendering {args.scene}", compiling)
    try:
        with _cluster(args, console) as cluster:
            run = render if cluster is None else cluster.render
            result = run(scene, accel=args.accel, resolution=args.resolution, spd=args.spd,
                         threads=args.threads, progress=progress, max_memory=args.max_memory, **options)
    finally:
        progress.close()
    if args.draw is None:
        result.save(out)
    else:
        from .rendering.imageio import save_image
        from .rendering.overlay import draw_structure
        save_image(draw_structure(result.image, scene, args.accel, None if args.draw == "all" else int(args.draw),
                                  max_memory=args.max_memory), out)
    if args.stats_json:
        result.stats.to_json(args.stats_json)
    if args.work:
        save_layers(result.work, args.work)
    title = f"{args.scene}, {args.accel}{', SPD' if args.spd else ''}"
    for counter, path in work_images.items():
        picture(result.work, counter, path, title=title, scale=args.work_scale)
    w, h = result.image.shape[1], result.image.shape[0]
    console.print(result.stats.table(title=f"{args.scene}: {scene.count_primitives():,} primitives, "
                                           f"{w}x{h}, accel {args.accel}{', SPD' if args.spd else ''} -> {out}"))
    return 0


def _work_images(items, out: str) -> dict:
    """--work-image COUNTER[=PATH] arguments as {counter: path}; the path defaults to the
    image's name with the counter added (balls.png -> balls.tests.total.png)."""
    from .rendering.worklayers import check_layer_name
    images = {}
    for item in items or ():
        counter, _, path = item.partition("=")
        if not counter:
            raise OptionError(f"--work-image {item!r}: expected COUNTER or COUNTER=PATH, e.g. tests.total=work.png")
        check_layer_name(counter)
        path = path or str(Path(out).with_suffix(f".{counter}.png"))
        if not path.lower().endswith(".png"):
            raise OptionError(f"--work-image {item!r}: work images are written as .png")
        images[counter] = path
    return images


def cmd_explain(args, console) -> int:
    from .atomicfile import check_output_directory
    from .rendering.explain import explain, text, write_json
    from .scene import examples
    from .scene.loading import load
    if args.json:
        check_output_directory(args.json)
    scene = _viewed(load(args.scene), args)
    options = {}
    if args.scene.startswith("example:"):
        options.update(examples.render_defaults(args.scene.split(":", 1)[1]))
    options.update(_trace_options(args))
    x, y = args.pixel
    ex = explain(scene, x, y, accel=args.accel, resolution=args.resolution, spd=args.spd, threads=args.threads,
                 max_memory=args.max_memory, **options)
    console.print(text(ex), markup=False, highlight=False)
    if args.json:
        write_json(ex, args.json)
    return 0


def _vector(text: str):
    """X,Y,Z on the command line."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 3:
        raise argparse.ArgumentTypeError(f"expected three numbers X,Y,Z, got {text!r}")
    return values


def _viewed(scene, args):
    """The scene with --eye, --look-at, --up and --angle put in its camera (checked as the camera checks)."""
    import dataclasses
    changes = {name: getattr(args, name) for name in ("eye", "look_at", "up", "angle") if getattr(args, name) is not None}
    if changes:
        if scene.camera is None:
            raise OptionError("--eye, --look-at, --up and --angle change a camera; this scene has none")
        scene.camera = dataclasses.replace(scene.camera, **changes)
    return scene


def _trace_options(args) -> dict:
    """The shading and sampling options given on the command line (render_options' names)."""
    return {name: getattr(args, name) for name in ("max_depth", "shading", "aa", "samples", "seed", "aa_threshold",
                                                   "aa_depth", "cutoff", "shadows", "eye_light", "eye_light_shadows",
                                                   "tricks") if getattr(args, name) is not None}


@contextlib.contextmanager
def _cluster(args, console, warm: bool = True):
    """The Dask cluster of --dask (its workers' render kernels compiled or loaded first, if `warm`), else None."""
    if getattr(args, "dask", None) is None:
        yield None
        return
    from .cluster import Cluster
    from .rendering.render import first_run
    with Cluster(args.dask) as cluster:
        console.print(f"Dask: {cluster.workers} worker(s) at {cluster.client.scheduler.address}", markup=False,
                      highlight=False)
        if not warm:
            yield cluster
            return
        if first_run():
            console.print("Compiling raykernel's kernels on the workers: first run after install only, tens "
                          "of seconds or more; later runs start from the cache.", markup=False,
                          highlight=False)
        cluster.warm_up({"threads": args.threads} if getattr(args, "threads", None) else {})
        yield cluster


def cmd_cast(args, console) -> int:
    from .casting.castfile import cast_file
    from .casting.rayfiles import open_rays, result_format
    from .casting.rayqueries import field_names
    from .casting.rayscene import RayScene
    from .scene.loading import load
    from .scene.meshfile import SUFFIXES
    # refuse what would fail after the build before it
    open_rays(args.rays)
    result_format(args.out)
    fields = field_names([f.strip() for f in args.fields.split(",") if f.strip()])
    if Path(args.scene).suffix.lower() in SUFFIXES:
        scene = RayScene.from_file(args.scene, accel=args.accel, max_memory=args.max_memory)
    else:
        scene = RayScene(load(args.scene), accel=args.accel or "bvh", max_memory=args.max_memory)
    progress = _Progress(console, f"casting {args.rays}", unit="rays")
    try:
        with _cluster(args, console, warm=False) as cluster:
            report = cast_file(scene, args.rays, args.out, fields=fields, dtype=args.dtype, threads=args.threads,
                               max_memory=args.max_memory, cluster=cluster, progress=progress, chunk=args.chunk)
    except KeyboardInterrupt:
        progress.close()
        sys.stderr.write(f"raykernel: interrupted; the chunks written to {args.out} are whole and kept, and the "
                         f"same command goes on from them\n")
        return 130
    finally:
        progress.close()
    log = lambda line: console.print(line, markup=False, highlight=False, soft_wrap=True)     # noqa: E731
    log(f"{args.rays}: {report.rays:,} rays in {report.chunks:,} chunk(s) of {report.chunk:,}; cast {report.cast:,} "
        f"now ({report.skipped:,} chunk(s) written before) in {report.seconds:.2f} s, "
        f"{report.rays_per_second / 1e6:.2f} Mrays/s -> {args.out}")
    for name, w in sorted(report.workers.items()):
        log(f"  {name}: kernels compiled {w['compile']:.2f} s, loaded {w['load']:.2f} s; cast {w['rays']:,} rays "
            f"({w['chunks']} chunk(s)) in {w['cast']:.2f} s")
    return 0


def cmd_animate(args, console) -> int:
    from .geometry.compiletime import OTHER_RENDERS
    from .geometry.config import tell_once
    from .rendering.animate import animate
    from .rendering.render import first_run
    from .aggregates.registry import parse_spec
    parse_spec(args.accel)
    options = {k: getattr(args, k) for k in ("max_depth", "shading", "shadows", "tricks") if getattr(args, k) is not None}
    if first_run() and not args.dask:
        tell_once("render", None)
        console.print(f"Compiling raykernel's kernels: first run after install only, tens of seconds "
                      f"on 2 cores ({OTHER_RENDERS}); later runs start from the cache.", markup=False,
                      highlight=False)
    progress = _Progress(console, f"animating {args.scene} (frames)")
    log = lambda line: console.print(line, markup=False, highlight=False)     # noqa: E731
    try:
        with _cluster(args, console) as cluster:
            result = animate(args.scene, frames=args.frames, time=args.time, fps=args.fps, output=args.output,
                             incremental=not args.from_scratch, rebuild_threshold=args.rebuild_threshold,
                             segment=args.segment,
                             stats_json=args.stats_json, progress=progress, cluster=cluster, log=log,
                             accel=args.accel, resolution=args.resolution, spd=args.spd, threads=args.threads,
                             max_memory=args.max_memory, **options)
    finally:
        progress.close()
    t = result.totals
    rendered = len(result.frames) - result.skipped
    log(f"{len(result.frames)} frames ({rendered} rendered, {result.skipped} already written) -> {result.output}")
    log(f"rays {t.get('rays.total', 0):,}  trace {t.get('time.trace', 0):.2f} s  build {t.get('build.seconds', 0):.2f} s"
        f"  refit nodes {t.get('build.refit_nodes', 0):,}  rebuilt nodes {t.get('build.rebuilt_nodes', 0):,}")
    return 0


def cmd_accels(args, console) -> int:
    from .aggregates.registry import describe
    console.print(describe(), markup=False, highlight=False)
    return 0


def cmd_cache(args, console) -> int:
    import shutil

    from .geometry.config import cache_folders, cache_root
    folders = cache_folders()
    sizes = [sum(f.stat().st_size for f in folder.rglob("*") if f.is_file()) / 2 ** 20 for folder in folders]
    if args.clear:
        for folder in folders:
            shutil.rmtree(folder, ignore_errors=True)
        print(f"Removed {len(folders)} kernel cache folder(s), {sum(sizes):.1f} MiB; the next run compiles its "
              "kernels again.")
        return 0
    print(f"raykernel's kernel cache: {cache_root()}")       # paths whole, never wrapped
    for folder, mib in zip(folders, sizes):
        print(f"  {folder}  {mib:.1f} MiB")
    if not folders:
        print("  (empty: the next run compiles its kernels)")
    return 0


def cmd_structure(args, console) -> int:
    import numpy as np

    from .aggregates.registry import parse_spec
    from .aggregates.spec import is_auto
    from .rendering.structure import USE, select, structure_boxes, structure_use, write_ply
    from .scene import examples
    from .scene.loading import load
    if Path(args.output).suffix.lower() != ".ply":
        raise OptionError(f"--output {args.output}: the structure is written as PLY; name a .ply file")
    parse_spec(args.accel)
    if is_auto(args.accel):
        raise OptionError("--accel auto is a search, not a structure: `raykernel anneal SCENE -o found.json` writes "
                          "the hierarchy it finds, and `raykernel structure found.json` draws it")
    scene = _viewed(load(args.scene), args)
    use = None
    if args.use:
        options = examples.render_defaults(args.scene.split(":", 1)[1]) if args.scene.startswith("example:") else {}
        options.update(_trace_options(args))
        with console.status("rendering on one thread, counting each box's use"):
            boxes, use, _ = structure_use(scene, args.accel, resolution=args.resolution, spd=args.spd,
                                          max_memory=args.max_memory, **options)
    else:
        boxes = structure_boxes(scene, args.accel, max_memory=args.max_memory)
    keep = np.ones(len(boxes), bool)
    if args.leaves:
        keep &= boxes.leaf == 1
    if args.no_empty:
        keep &= boxes.items != 0
    boxes = select(boxes, keep)
    use = None if use is None else {name: value[keep] for name, value in use.items()}
    write_ply(boxes, args.output, use)
    levels = int(boxes.level.max()) + 1 if len(boxes) else 0
    values = "level, depth, leaf, items, aggregate, walk" + (", " + ", ".join(USE) if use else "")
    print(f"{args.scene} with {args.accel}: {len(boxes):,} boxes over {levels} nesting level(s) -> {args.output} "
          f"(per face: {values})")
    if use:
        print(f"  {int(use['visits'].sum()):,} visits, {int(use['tests'].sum()):,} tests, "
              f"{int(use['futile'][use['futile'] >= 0].sum()):,} futile visits, {int(use['refined'].sum()):,} "
              f"cells refined by the render")
    return 0


def cmd_warmup(args, console) -> int:
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from .analysis.warmup import warm_up
    from .geometry.config import cache_root
    with Progress(TextColumn("warming up {task.fields[step]:<36}"), BarColumn(), "{task.completed}/{task.total}",
                  TimeElapsedColumn(), console=console, transient=True) as bar:
        task = bar.add_task("warmup", total=None, step="")

        def progress(done, total, label):
            bar.update(task, completed=done, total=total, step=label)
        report = warm_up(args.what, progress=progress, processes=args.processes)
    print(f"warm-up of {args.what}: {report['steps']} steps in {report['seconds']:.1f} s in {report['processes']} "
          f"process(es) (compiling {report['compile']:.1f} s, loading cached kernels {report['load']:.1f} s, summed "
          f"over the processes); cached in {cache_root()}")
    return 0


def cmd_spd(args, console) -> int:
    from .atomicfile import atomic_write
    from .scene import spd
    text = spd.generate(args.name, args.size)
    if args.output:
        with atomic_write(args.output) as f:
            f.write(text)
    else:
        sys.stdout.write(text)
    return 0


def cmd_scene(args, console) -> int:
    from .scene import pathological
    if args.list or args.name == "list":
        console.print(pathological.describe(), markup=False, highlight=False, soft_wrap=True)
        return 0
    if args.name is None:
        raise OptionError("name a scene (" + ", ".join(pathological.NAMES) + ") or use --list")
    if not args.output:
        raise OptionError("give the output file with -o FILE.json (groups kept) or -o FILE.nff (flattened)")
    suffix = Path(args.output).suffix.lower()
    if suffix not in (".json", ".nff"):
        raise OptionError(f"{args.output}: unknown output format {suffix or '(no suffix)'!r}; "
                          "use .json (groups kept) or .nff (flattened)")
    from .atomicfile import check_output_directory
    from .scene.convert import convert
    check_output_directory(args.output)
    params = {}
    for item in args.param:
        key, eq, value = item.partition("=")
        key = key.strip()
        if not eq or not key:
            raise OptionError(f"--param expects KEY=VALUE, got {item!r}")
        if key in params:
            raise OptionError(f"--param {key} is given twice")
        params[key] = value.strip()
    scene = pathological.load(args.name, **params)
    convert(scene, args.output)
    console.print(f"{scene.source}: {scene.count_primitives():,} primitives -> {args.output}",
                  markup=False, highlight=False, emoji=False)
    return 0


def cmd_convert(args, console) -> int:
    from .scene.convert import convert
    written = convert(args.scene, args.output, segments=args.segments)
    console.print(f"{args.scene} -> " + ", ".join(str(p) for p in written), markup=False, highlight=False,
                  emoji=False)
    return 0


def _finish_comparison(cmp, args, console, title, plots) -> int:
    from .analysis import compare as cm
    for part in cm.tables(cmp, title=title, width=console.width):
        console.print(part)
    for accel, worst, mean, n in cm.prediction_summary(cmp):
        console.print(f"cost model, {accel}: mean |error| {mean:.0%}, worst {worst:+.0%} over {n} run(s)",
                      markup=False, highlight=False)
    if args.json:
        cm.write_json(cmp, args.json)
    if args.csv:
        cm.write_csv(cmp, args.csv)
    if args.report:
        from .analysis.report import write_report
        write_report(cmp, args.report, title=title, plots=[(name, make()) for name, make in plots])
    if cmp.disagreements:
        cm.print_disagreements(cmp, console)
        return 3
    return 0


def _write_work_images(cmp, folder, console) -> None:
    """One figure per scene (FOLDER/SCENE.COUNTER.png): every structure's work layer on one scale,
    ratios, winners."""
    import re
    from pathlib import Path

    from .analysis.workimages import work_images, write_figure
    folder = Path(folder)
    for scene in cmp.scenes():
        path = folder / (re.sub(r"[^A-Za-z0-9_.=-]+", "_", scene).strip("_") + f".{cmp.work}.png")
        write_figure(work_images(cmp, scene), path)
        console.print(f"work images of {scene}: {path}", markup=False, highlight=False, soft_wrap=True)


def cmd_compare(args, console) -> int:
    from .analysis import compare as cm
    work = args.work or ("tests.total" if args.work_images else None)
    if args.work_images and not Path(args.work_images).is_dir():
        raise OptionError(f"--work-images: {args.work_images} is not a folder")
    with _cluster(args, console) as cluster:
        cmp = cm.compare(args.scene, args.accel, spd=args.spd, resolution=args.resolution, threads=args.threads,
                         model=args.calibration or "default", command=cm.command_from_args("compare", args),
                         cluster=cluster, work=work)
    if args.work_images:
        _write_work_images(cmp, args.work_images, console)
    return _finish_comparison(cmp, args, console, "raykernel compare",
                              [("Counts and times per scene", lambda: cm.compare_figure_png(cmp))])


def cmd_sweep(args, console) -> int:
    from .analysis import compare as cm
    params = cm.parse_params(args.param)
    if not params:
        raise OptionError("give at least one --param NAME=V1,V2,...")
    with _cluster(args, console) as cluster:
        cmp = cm.sweep(args.template, params, args.accel, spd=args.spd, resolution=args.resolution,
                       threads=args.threads, model=args.calibration or "default",
                       command=cm.command_from_args("sweep", args), cluster=cluster)
    if args.plot:
        cm.plot_sweep(cmp, args.plot)
    return _finish_comparison(cmp, args, console, f"raykernel sweep {args.template}",
                              [("Sweep", lambda: cm.sweep_figure_png(cmp))])


def cmd_calibrate(args, console) -> int:
    from .analysis import costmodel
    out = args.output or costmodel.default_path()
    model = costmodel.calibrate(threads=args.threads,
                                resolutions=tuple(args.resolutions or costmodel.CALIBRATION_RESOLUTIONS),
                                repeats=args.repeats or costmodel.REPEATS,
                                log=lambda line: console.print(line, markup=False, highlight=False))
    model.save(out)
    for name, cost in sorted(model.costs.items()):
        console.print(f"{name:18s} {cost * 1e9:10.2f} ns", markup=False, highlight=False)
    console.print(f"calibration of {len(model.calibration)} renders -> {out}", markup=False, highlight=False)
    return 0


def cmd_anneal(args, console) -> int:
    from .analysis import anneal
    from .rendering.render import render, render_options
    from .scene.jsonscene import write_json
    from .scene.loading import load
    if not args.output.lower().endswith(".json"):
        raise OptionError(f"--output {args.output}: the hierarchy is written as a JSON scene; name a .json file")
    scene = load(args.scene)
    options = dict(resolution=args.resolution, spd=args.spd, max_depth=args.max_depth, threads=args.threads)
    render_options(scene, **options)      # bad options fail here, before any search

    def say(line):
        console.print(line, markup=False, highlight=False, soft_wrap=True)

    found = anneal.anneal(scene, seconds=args.seconds, seed=args.seed, memory=args.memory,
                          evaluations=args.evaluations, sample=args.sample, margin=args.margin, options=options,
                          log=say)
    write_json(found.scene, args.output)
    single, single_e = found.best_single
    say("hierarchy before (the best start):")
    say(found.before)
    say("hierarchy found:")
    say(found.after)
    say(f"predicted trace: {found.energy:.4f} s found, {single_e:.4f} s with {single} (the best single kind), "
        f"{found.start_energy:.4f} s at the start")
    say(f"annealing: {found.seconds:.1f} s, {found.evaluations} candidates priced, stopped by {found.stopped}; "
        f"saves a predicted {max(0.0, single_e - found.energy):.4f} s per render")
    if found.kept:
        say(f"kept {found.kept}: the best hierarchy searched ({found.searched:.4f} s predicted) was not "
            f"{args.margin:.0%} faster (--margin)")
    if args.plot:
        anneal.plot(found, args.plot)
        say(f"energy and temperature over the run -> {args.plot}")
    if args.verify:
        got = render(found.scene, **options).stats
        ref = render(scene, accel=single, **options).stats
        say(f"measured trace: {got['time.trace']:.4f} s found, {ref['time.trace']:.4f} s with {single} "
            f"({ref['time.trace'] / max(got['time.trace'], 1e-12):.2f}x); rays {got['rays.total']:,} and "
            f"{ref['rays.total']:,}")
    say(f"wrote {args.output} (render it with: raykernel render {args.output})")
    return 0


def cmd_explore(args, console) -> int:
    from .explorer.server import initial_settings, start
    from .scene.loading import load
    s = initial_settings(args.accel, args.resolution, args.settings)    # bad settings fail before the load
    scene = load(args.scene)
    server = start(scene, args.scene, s, port=args.port, host=args.host, max_memory=args.max_memory)
    print(f"raykernel explore: {args.scene} with {', '.join(s.accels)}; open this address (Ctrl-C stops):",
          flush=True)
    print(server.url, flush=True)
    try:
        server.thread.join()
    except KeyboardInterrupt:
        print("raykernel explore: stopped", flush=True)
    finally:
        server.stop()
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="raykernel", description="Ray tracing with nestable acceleration "
                                     "structures and exact statistics.")
    sub = parser.add_subparsers(dest="command", required=True)
    _add_render(sub)
    _add_explain(sub)
    _add_cast(sub)
    _add_others(sub)
    _add_explore(sub)
    return parser


def _add_explore(sub) -> None:
    ex = sub.add_parser("explore", help="a local web app: every view of where each structure's work goes, linked "
                        "(work layers, ratios, histograms, hottest samples, rays, the structure in 3D, tile times)")
    ex.add_argument("scene", help=SCENE_HELP)
    ex.add_argument("--accel", action="append", default=[], metavar="SPEC",
                    help="a structure to explore (repeatable; default bvh)")
    ex.add_argument("--resolution", type=_positive_int, help="square image size (default: the explorer's)")
    ex.add_argument("--port", type=int, default=8050, help="the port to serve on (default 8050; 0: any free one)")
    ex.add_argument("--host", default="127.0.0.1", help="the address to bind (default 127.0.0.1: this machine only)")
    ex.add_argument("--settings", metavar="FILE", help="open with the settings the page's export wrote")
    ex.add_argument("--max-memory", help="memory budget of every build and render, e.g. 8G")
    ex.set_defaults(func=cmd_explore)


def _add_cast(sub) -> None:
    c = sub.add_parser("cast", help="cast the rays of a file at a scene and write their hits to a file, a chunk at "
                       "a time (any number of rays in bounded memory; the same command resumes a stopped cast)")
    c.add_argument("scene", help=SCENE_HELP)
    c.add_argument("--rays", required=True, help="the rays: .npz (origins, directions, optionally tmin, tmax; "
                   "np.savez), .npy (N, 6), a .zarr group with the .npz's arrays, or .parquet (columns ox, oy, oz, "
                   "dx, dy, dz, optionally tmin, tmax)")
    c.add_argument("--out", required=True, help="the hits: a .zarr group (one array a field) or a .parquet folder "
                   "(one file a chunk)")
    c.add_argument("--fields", default="t,prim_id", help="the Hits fields to write, comma-separated (default "
                   "t,prim_id; also geom_id, inst_id, kind, uv, normal, shading_normal)")
    c.add_argument("--dtype", choices=["float64", "float32"], default="float64", help="float32: float32 t, uv and "
                   "normals and int32 ids (default float64)")
    c.add_argument("--accel", help="accelerator spec (default: a model file's own mesh build, bvh for a scene)")
    c.add_argument("--chunk", type=_positive_int, help="rays a chunk (default: castfile.DEFAULT_CHUNK, fewer if the "
                   "memory budget needs it; a resumed cast keeps its own)")
    c.add_argument("--threads", type=_positive_int, help="threads a chunk (default: all cores; on local:N a "
                   "worker's share)")
    c.add_argument("--max-memory", help="memory budget of the build and of the chunks at work, e.g. 2G")
    c.add_argument("--dask", metavar="ADDRESS", help="cast the chunks on Dask: local[:N] starts N worker processes "
                   "on this machine, tcp://HOST:PORT joins a running scheduler whose workers reach the files at the "
                   "same paths (pip install 'raykernel[cast]')")
    c.set_defaults(func=cmd_cast)


def _add_trace_options(r) -> None:
    """The options that say how a scene is traced: render's and explain's."""
    r.add_argument("--resolution", type=_positive_int, help="square image size (default: the scene's)")
    r.add_argument("--accel", default="bvh", help="accelerator spec for groups that name none (default bvh); "
                   "see `raykernel accels`")
    r.add_argument("--spd", action="store_true", help="follow the SPD test procedure (corner rays, no cut-off)")
    r.add_argument("--max-depth", type=_positive_int, help="maximum ray-tree depth, eye ray = 1 (default 5)")
    r.add_argument("--eye", type=_vector, metavar="X,Y,Z", help="put the camera here (default: the scene's, or for "
                   "a model file one framed around it)")
    r.add_argument("--look-at", type=_vector, metavar="X,Y,Z", help="point the camera at this point")
    r.add_argument("--up", type=_vector, metavar="X,Y,Z", help="the camera's up direction")
    r.add_argument("--angle", type=float, help="the camera's field of view in degrees (NFF's angle)")
    r.add_argument("--threads", type=_positive_int, help="worker threads (default: all cores)")
    r.add_argument("--shading", choices=["whitted", "hall", "heckbert"],
                   help="whitted: NFF's parameters (the default); hall: Hall and Greenberg's model (Fresnel, "
                   "transmitted highlights, filtering in media); heckbert: the model of Heckbert's minimal ray "
                   "tracer (the default for example:heckbert)")
    r.add_argument("--shadows", choices=["opaque", "filtered"], help="filtered: transparent surfaces let light "
                   "through, times T (default opaque; --spd allows no other)")
    r.add_argument("--eye-light", type=float, nargs="?", const=1.0, metavar="INTENSITY",
                   help="add a white point light at the eye (default intensity 1)")
    r.add_argument("--eye-light-shadows", choices=["skip", "cast"], help="skip (the default: Haines's trick, no "
                   "shadow rays toward the eye light from eye rays' hits) or cast")
    r.add_argument("--aa", choices=["jitter", "adaptive"], help="anti-aliasing: jittered strata (--samples, "
                   "--seed) or Whitted's adaptive subdivision (--aa-threshold, --aa-depth); default: one ray "
                   "per pixel")
    r.add_argument("--samples", type=_positive_int, help="rays per pixel for --aa jitter, a square number "
                   "(default 4)")
    r.add_argument("--seed", type=int, help="random seed for --aa jitter (default 0)")
    r.add_argument("--aa-threshold", type=float, help="--aa adaptive: cut a square whose corners differ by "
                   "more than this in a channel (default 0.1)")
    r.add_argument("--aa-depth", type=int, help="--aa adaptive: most cuts of a pixel, 0-4 (default 2)")
    r.add_argument("--cutoff", type=float, help="rays weighing less are not cast (Hall's adaptive tree "
                   "depth; default 1/512, 0 in --spd)")
    r.add_argument("--tricks", metavar="LIST", help="Haines's efficiency tricks: all, none or a comma-separated "
                   "list of closest, raytree, shadowcache, transparentlast, lazynormals, startlists (default: "
                   "closest,lazynormals); they change the work, not the image")
    r.add_argument("--max-memory", help="memory budget of every build, e.g. 8G or 512M (default: half of this "
                   "machine's memory); a structure that needs more stops with an error")


def _add_render(sub) -> None:
    r = sub.add_parser("render", help="render a scene to PNG and print its statistics")
    r.add_argument("scene", help=SCENE_HELP)
    r.add_argument("-o", "--output", help="output image: .png, .jpg, .tif, .webp (8-bit) or .npy, .pfm, .exr "
                   "(float); default: the scene's name + .png")
    _add_trace_options(r)
    r.add_argument("--stats-json", help="write every counter to this JSON file")
    r.add_argument("--work", metavar="OUT", help="write the work layers (each sample's work, counter by counter, "
                   "by ray type and nesting level) to OUT.npz (np.load(OUT)[\"tests.total\"]) or OUT.exr "
                   "(pip install 'raykernel[exr]')")
    r.add_argument("--work-image", action="append", metavar="COUNTER[=PATH]", help="a false-colour PNG of one "
                   "work layer with its legend, e.g. tests.total or cells.visited.shadow (default PATH: the "
                   "image's name + .COUNTER.png); may be given more than once")
    r.add_argument("--work-scale", choices=["linear", "log"], default="linear", help="--work-image's colour "
                   "scale (default linear)")
    r.add_argument("--draw", metavar="DEPTH|all", help="draw the structure's boxes over the image, those DEPTH or "
                   "fewer deep in their structure (0: the roots, and a grid's cells) or all, hidden where the "
                   "scene's surfaces cover them; nesting levels in their own colours")
    r.add_argument("--dask", metavar="ADDRESS", help="run on Dask: local[:N] starts N worker processes on this machine, "
                   "tcp://HOST:PORT joins a running scheduler (pip install 'raykernel[distributed]')")
    r.set_defaults(func=cmd_render)


def _add_explain(sub) -> None:
    e = sub.add_parser("explain", help="re-trace one pixel and print its ray tree: every ray, the cells or nodes "
                       "it visited and the objects it tested, level by level, with the pixel's work layers")
    e.add_argument("scene", help=SCENE_HELP)
    e.add_argument("--pixel", nargs=2, type=int, metavar=("X", "Y"), required=True,
                   help="the pixel: X the column, Y the row from the top (in --spd, the corner sample X, Y)")
    e.add_argument("--json", metavar="FILE", help="also write the explanation as JSON (its `totals`: each counter's "
                   "value at this pixel)")
    _add_trace_options(e)
    e.set_defaults(func=cmd_explain)


def _add_others(sub) -> None:
    an = sub.add_parser("animate", help="render the frames of a moving scene (keyframes, or scene:satellite's time)")
    an.add_argument("scene", help="a .json scene with an animation, or scene:NAME[:k=v,...] with a time parameter")
    an.add_argument("-o", "--output", help="a directory of PNG frames (OUT/frame-0000.png, ...), OUT.png (animated "
                    "PNG) or OUT.mp4 (pip install 'raykernel[video]'); default: the scene's name as a directory")
    an.add_argument("--frames", type=_positive_int, help="number of frames, spread evenly over the time range with both ends "
                    "(default 24)")
    an.add_argument("--time", type=float, nargs=2, metavar=("T0", "T1"), help="time range in seconds (default: "
                    "the animation's)")
    an.add_argument("--fps", type=float, help="frames per second of the movie (default: the scene's, 24)")
    an.add_argument("--resolution", type=_positive_int, help="square image size (default: the scene's)")
    an.add_argument("--accel", default="bvh", help="accelerator spec for groups that name none (default bvh)")
    an.add_argument("--spd", action="store_true", help="follow the SPD test procedure (corner rays, no cut-off)")
    an.add_argument("--max-depth", type=_positive_int, help="maximum ray-tree depth (default 5)")
    an.add_argument("--shading", choices=["whitted", "hall", "heckbert"], help="shading model (default whitted)")
    an.add_argument("--shadows", choices=["opaque", "filtered"], help="shadows (default opaque)")
    an.add_argument("--tricks", metavar="LIST", help="Haines's efficiency tricks (see render --help)")
    an.add_argument("--threads", type=_positive_int, help="worker threads (default: all cores)")
    an.add_argument("--from-scratch", action="store_true", help="build every frame's structures from scratch "
                    "(default: refit or rebuild only what moved)")
    an.add_argument("--rebuild-threshold", type=float, default=1.5, help="rebuild a refit BVH whose SAH cost "
                    "grew past this factor (default 1.5)")
    an.add_argument("--segment", type=_positive_int, default=8, help="frames built from one from-scratch build, "
                    "and the unit of work on --dask (default 8)")
    an.add_argument("--stats-json", help="write each frame's counters and their sums to this JSON file")
    an.add_argument("--max-memory", help="memory budget of every build, e.g. 8G")
    an.add_argument("--dask", metavar="ADDRESS", help="run on Dask: local[:N] starts N worker processes on this machine, "
                   "tcp://HOST:PORT joins a running scheduler (pip install 'raykernel[distributed]')")
    an.set_defaults(func=cmd_animate)

    a = sub.add_parser("accels", help="list the accelerator kinds with their parameters and defaults")
    a.set_defaults(func=cmd_accels)

    ca = sub.add_parser("cache", help="show where the compiled kernels are cached and how much they take")
    ca.add_argument("--clear", action="store_true", help="remove every raykernel kernel cache folder (this "
                    "version's and earlier ones'); the next run compiles again")
    ca.set_defaults(func=cmd_cache)

    st = sub.add_parser("structure", help="write a built structure's cells and nodes as boxes in a PLY file "
                        "(nested structures level by level; per face: level, depth, leaf, items)")
    st.add_argument("scene", help=SCENE_HELP)
    st.add_argument("-o", "--output", required=True, help="the PLY file")
    st.add_argument("--leaves", action="store_true", help="leaves and cells only, no inner nodes")
    st.add_argument("--no-empty", action="store_true", help="leave out empty leaves and cells")
    st.add_argument("--use", action="store_true", help="render the scene (on one thread, with the options below) "
                    "and give each box how its rays used it: visits, tests, futile (visits where nothing was hit) "
                    "and refined (a lazy octree's cells this render made)")
    _add_trace_options(st)
    st.set_defaults(func=cmd_structure)

    w = sub.add_parser("warmup", help="compile the kernels a first render or ray cast would compile (or load them "
                       "from the cache), and say how long it took")
    w.add_argument("what", nargs="?", default="all", choices=["render", "cast", "all"],
                   help="render: every structure, shading model, antialiasing, filtered shadows, work layers; "
                   "cast: every RayScene query; all: both (the default)")
    w.add_argument("--processes", type=_positive_int, help="processes compiling side by side (default: one a core)")
    w.set_defaults(func=cmd_warmup)

    s = sub.add_parser("spd", help="write one of Haines's Standard Procedural Databases as NFF")
    s.add_argument("name", help="balls, gears, mount, rings, teapot, tetra, tree, jacks, lattice, shells, "
                   "sombrero, sample or nurbtst")
    s.add_argument("--size", type=_positive_int, help="size factor (default: the generator's)")
    s.add_argument("-o", "--output", help="output file (default: standard output)")
    s.set_defaults(func=cmd_spd)

    sc = sub.add_parser("scene", help="write a pathological scene of Ray Tracing News 2(1) as JSON or NFF")
    sc.add_argument("name", nargs="?", help="stadium, satellite, sun, teapot-room or diamond; `list` lists them")
    sc.add_argument("--list", action="store_true", help="list the scenes with their parameters and defaults")
    sc.add_argument("-p", "--param", action="append", default=[], metavar="KEY=VALUE",
                    help="set a scene parameter (repeatable), e.g. --param ratio=1e6")
    sc.add_argument("-o", "--output", help="output file: .json (groups kept) or .nff (flattened)")
    sc.set_defaults(func=cmd_scene)

    cv = sub.add_parser("convert", help="convert a scene to NFF, JSON, Wavefront OBJ (+ .mtl) or POV-Ray 3.7")
    cv.add_argument("scene", help=SCENE_HELP)
    cv.add_argument("-o", "--output", required=True, help="output file; its suffix picks the format: "
                    ".nff, .json, .obj or .pov")
    cv.add_argument("--segments", type=_positive_int, default=16,
                    help="OBJ only: slices around spheres and cones (default 16; spheres get half as many rings)")
    cv.set_defaults(func=cmd_convert)

    for name, help_text in (("compare", "render scenes with several structures and compare the work they do"),
                            ("sweep", "scaling study: render a scene template over parameter values")):
        c = sub.add_parser(name, help=help_text)
        if name == "compare":
            c.add_argument("scene", nargs="+", help="scenes: " + SCENE_HELP)
            c.add_argument("--work", metavar="COUNTER", help="keep each render's work layer of COUNTER (e.g. "
                           "tests.total, bounds.tests, cells.visited, tests.total.shadow): the report gets work "
                           "images of every structure on one scale, ratios against the first and a winner map")
            c.add_argument("--work-images", metavar="FOLDER", help="write each scene's work figure (every "
                           "structure on one scale, log2 ratios against the first, the winner map) into FOLDER "
                           "(counter: --work, default tests.total)")
            c.set_defaults(func=cmd_compare)
        else:
            c.add_argument("template", help="scene with {NAME} placeholders, e.g. spd:balls:{sf} or "
                           "scene:stadium:ratio={ratio}")
            c.add_argument("--param", action="append", default=[], metavar="NAME=V1,V2,...",
                           help="values of a placeholder (repeatable; several give every combination)")
            c.add_argument("--plot", help="write the sweep plot to this PNG")
            c.set_defaults(func=cmd_sweep)
        c.add_argument("--accel", action="append", required=True, metavar="SPEC",
                       help="a structure to compare (repeatable); see `raykernel accels`")
        c.add_argument("--spd", action="store_true", help="follow the SPD test procedure")
        c.add_argument("--resolution", type=_positive_int, help="square image size (default: the scene's)")
        c.add_argument("--threads", type=_positive_int, help="worker threads (default: all cores)")
        c.add_argument("--json", help="write every counter of every run, the machine and the command here")
        c.add_argument("--csv", help="write one row per run here")
        c.add_argument("--report", help="write a self-contained HTML report here")
        c.add_argument("--calibration", help="cost-model calibration JSON (default: this machine's, "
                       "from `raykernel calibrate`, if any)")
        c.add_argument("--dask", metavar="ADDRESS", help="run on Dask: local[:N] starts N worker processes on this machine, "
                   "tcp://HOST:PORT joins a running scheduler (pip install 'raykernel[distributed]')")

    an = sub.add_parser("anneal", help="find a hierarchy of structures for a scene by simulated annealing and "
                        "write it as a JSON scene (what --accel auto does inside a render)")
    an.add_argument("scene", help=SCENE_HELP)
    an.add_argument("-o", "--output", required=True, help="the scene with the hierarchy found, as JSON")
    an.add_argument("--seconds", type=float, default=30.0, help="time budget of the search (default 30)")
    an.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    an.add_argument("--memory", type=float, default=0.0, help="seconds of predicted time one MiB is worth (default 0)")
    an.add_argument("--evaluations", type=int, default=0, help="most candidates priced (default 0: no limit)")
    an.add_argument("--sample", type=_positive_int, default=24, help="candidates are traced at SAMPLE pixels along "
                    "the image's longer side (default 24)")
    an.add_argument("--margin", type=float, default=0.05, help="keep the hierarchy found only where it is predicted "
                    "at least this fraction faster than the best single kind (default 0.05)")
    an.add_argument("--resolution", type=_positive_int, help="the render it tunes for (default: the scene's)")
    an.add_argument("--spd", action="store_true", help="tune for an SPD render")
    an.add_argument("--max-depth", type=_positive_int, default=5, help="ray depth of that render (default 5)")
    an.add_argument("--threads", type=_positive_int, help="worker threads (default: all cores)")
    an.add_argument("--plot", help="write energy and temperature over the run to this PNG")
    an.add_argument("--verify", action="store_true", help="render the result and the best single kind and print "
                    "the measured trace times")
    an.set_defaults(func=cmd_anneal)

    cal = sub.add_parser("calibrate", help="fit the cost model (seconds per test, step, bound test) on this machine")
    cal.add_argument("-o", "--output", help="calibration JSON (default: ~/.cache/raykernel/calibration-HOST.json)")
    cal.add_argument("--threads", type=_positive_int, help="worker threads (default: all cores)")
    cal.add_argument("--resolutions", type=_positive_int, nargs="+", metavar="N",
                     help="image sizes each calibration scene is rendered at (default: the calibration set's)")
    cal.add_argument("--repeats", type=_positive_int,
                     help="renders of each scene, kind and size, the fastest kept (default: the calibration set's)")
    cal.set_defaults(func=cmd_calibrate)


def main(argv=None) -> int:
    from rich.console import Console
    args = build_parser().parse_args(argv)
    console = Console(emoji=False)     # "scene:stadium:" is a name, not an emoji code
    try:
        return args.func(args, console)
    except RayKernelError as err:
        sys.stderr.write(f"raykernel: error: {err}\n")     # one line, never wrapped
        return 2
    except KeyboardInterrupt:
        sys.stderr.write("raykernel: interrupted; unfinished output files were removed\n")
        return 130
    except MemoryError as err:      # the machine had less to give than the budget (--max-memory) allowed
        sys.stderr.write(f"raykernel: error: out of memory ({err or 'the system refused an allocation'}); lower "
                         f"--resolution, the samples or --max-memory (the budget: default half of this machine's "
                         f"memory)\n")
        return 2


def run() -> None:
    """The console script: main(), then the objects it made frozen out of the garbage collector
    (gc.freeze), so that the full collections of the interpreter's exit do not walk the
    hundreds of thousands of objects numba's compiler keeps: a noticeable part of a second of every
    command."""
    status = main()
    gc.freeze()
    sys.exit(status)


if __name__ == "__main__":
    run()

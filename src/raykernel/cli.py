"""The `raykernel` command.

    raykernel render spd:balls -o balls.png --accel bvh --spd
    raykernel render scene.nff --stats-json stats.json --threads 2
    raykernel accels
    raykernel spd teapot --size 12 -o teapot.nff

Errors a user can fix are printed as one line (no traceback) with exit status 2.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from .errors import RayKernelError


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
    """A rich progress bar that appears only once a render has run for a second."""

    def __init__(self, console, label: str):
        self.console = console
        self.label = label
        self.start = time.perf_counter()
        self.bar = None
        self.task = None

    def __call__(self, done: int, total: int):
        if self.bar is None:
            if time.perf_counter() - self.start < 1.0 or done >= total:
                return
            from rich.progress import BarColumn, Progress, TimeElapsedColumn, TimeRemainingColumn
            self.bar = Progress("[progress.description]{task.description}", BarColumn(),
                                "{task.percentage:>3.0f}%", TimeElapsedColumn(), TimeRemainingColumn(),
                                console=self.console, transient=True)
            self.bar.start()
            self.task = self.bar.add_task(self.label, total=total)
        self.bar.update(self.task, completed=done)

    def close(self):
        if self.bar is not None:
            self.bar.stop()


def cmd_render(args, console) -> int:
    from . import examples
    from .loading import load
    from .render import render

    scene = load(args.scene)
    options = {}
    if args.scene.startswith("example:"):
        options.update(examples.render_defaults(args.scene.split(":", 1)[1]))
    if args.max_depth is not None:
        options["max_depth"] = args.max_depth
    out = args.output or _default_output(args.scene)
    progress = _Progress(console, f"rendering {args.scene}")
    try:
        result = render(scene, accel=args.accel, resolution=args.resolution, spd=args.spd,
                        threads=args.threads, progress=progress, **options)
    finally:
        progress.close()
    result.save(out)
    if args.stats_json:
        result.stats.to_json(args.stats_json)
    w, h = result.image.shape[1], result.image.shape[0]
    console.print(result.stats.table(title=f"{args.scene}: {scene.count_primitives():,} primitives, "
                                           f"{w}x{h}, accel {args.accel}{', SPD' if args.spd else ''} -> {out}"))
    return 0


def cmd_accels(args, console) -> int:
    from .accel import describe
    console.print(describe(), markup=False, highlight=False)
    return 0


def cmd_spd(args, console) -> int:
    from . import spd
    from .imageio import atomic_write
    text = spd.generate(args.name, args.size)
    if args.output:
        with atomic_write(args.output) as f:
            f.write(text)
    else:
        sys.stdout.write(text)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="raykernel", description="Ray tracing with nestable acceleration "
                                     "structures and exact statistics.")
    sub = parser.add_subparsers(dest="command", required=True)

    r = sub.add_parser("render", help="render a scene to PNG and print its statistics")
    r.add_argument("scene", help="a .nff or .json file, spd:NAME[:SIZE], scene:NAME or example:NAME")
    r.add_argument("-o", "--output", help="output PNG (default: the scene's name + .png)")
    r.add_argument("--resolution", type=_positive_int, help="square image size (default: the scene's)")
    r.add_argument("--accel", default="bvh", help="accelerator spec for groups that name none (default bvh); "
                   "see `raykernel accels`")
    r.add_argument("--spd", action="store_true", help="follow the SPD test procedure (corner rays, no cut-off)")
    r.add_argument("--max-depth", type=_positive_int, help="maximum ray-tree depth, eye ray = 1 (default 5)")
    r.add_argument("--threads", type=_positive_int, help="worker threads (default: all cores)")
    r.add_argument("--stats-json", help="write every counter to this JSON file")
    r.set_defaults(func=cmd_render)

    a = sub.add_parser("accels", help="list the accelerator kinds with their parameters and defaults")
    a.set_defaults(func=cmd_accels)

    s = sub.add_parser("spd", help="write one of Haines's Standard Procedural Databases as NFF")
    s.add_argument("name", help="balls, gears, mount, rings, teapot, tetra, tree, jacks, lattice, shells, "
                   "sombrero, sample or nurbtst")
    s.add_argument("--size", type=_positive_int, help="size factor (default: the generator's)")
    s.add_argument("-o", "--output", help="output file (default: standard output)")
    s.set_defaults(func=cmd_spd)
    return parser


def main(argv=None) -> int:
    from rich.console import Console
    args = build_parser().parse_args(argv)
    console = Console()
    try:
        return args.func(args, console)
    except RayKernelError as err:
        Console(stderr=True).print(f"raykernel: error: {err}", markup=False, highlight=False)
        return 2
    except KeyboardInterrupt:
        Console(stderr=True).print("raykernel: interrupted; no output was written", markup=False)
        return 130


if __name__ == "__main__":
    sys.exit(main())

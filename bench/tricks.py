"""What each of Haines's efficiency tricks buys, per SPD default scene and per kind.

    .venv/bin/python bench/tricks.py [--resolution 96] [--scenes balls,gears] [--kinds bvh,grid] [--repeat 3]

For each scene and kind it renders (SPD mode, depth 5) with no trick, with the closest-hit
cut-off (trick 1), with trick 1 and one other (tricks 2 and 6 bound the closest search, so
every other trick is measured on top of trick 1), and with all of them, and records tests per
ray (N_IT), bound tests per ray and the trace time (best of --repeat). Images and ray counts
must be the same in every column: a difference aborts the run. Writes the `tricks` section of
BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import sys
from datetime import date

import numpy as np
from _report import DETAILS, machine, replace_section, subtable

import raykernel
from raykernel.aggregates.registry import KINDS
from raykernel.scene import spd

SETTINGS = [("none", "none"), ("closest", "closest"), ("+raytree", "closest,raytree"),
            ("+shadowcache", "closest,shadowcache"), ("+transparentlast", "closest,transparentlast"),
            ("+lazynormals", "closest,lazynormals"), ("+startlists", "closest,startlists"), ("all", "all")]
SUMMARY = ("Tests per ray against `closest` / trace time against `none`, averaged over every scene and kind "
           "(the full table has each one's tests per ray / bound tests per ray / trace ms).")
COLUMNS = ["scene", "kind"] + [label for label, _ in SETTINGS]      # of the summary's table: the mean row
RAYS = ("rays.eye", "rays.reflect", "rays.refract", "rays.shadow", "rays.shadow_blocked")


def run(scene, kind, resolution, repeat):
    cells, reference = [], None
    for label, tricks in SETTINGS:
        best = None
        for _ in range(repeat):
            result = raykernel.render(scene, accel=kind, resolution=resolution, spd=True, tricks=tricks)
            if best is None or result.stats["time.trace"] < best.stats["time.trace"]:
                best = result
        rays = tuple(best.stats[k] for k in RAYS)
        if reference is None:
            reference = (best.image, rays)
        elif not np.array_equal(best.image, reference[0]) or rays != reference[1]:
            sys.exit(f"{scene.source} {kind} tricks={tricks}: the image or the ray counts changed")
        cells.append(best.stats)
    return cells


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--resolution", type=int, default=96)
    parser.add_argument("--scenes", default=",".join(spd.NAMES))
    parser.add_argument("--kinds", default=",".join(k for k, kind in KINDS.items()
                                                    if k != "list" and not kind.operands))   # list: brute force, slow
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    kinds = args.kinds.split(",")
    head = " | ".join(label for label, _ in SETTINGS)
    lines = [f"| scene | kind | rays | {head} |", "|---|---|---:|" + "---:|" * len(SETTINGS)]
    totals = np.zeros((len(SETTINGS), 2))
    for name in args.scenes.split(","):
        scene = raykernel.load(f"spd:{name}")
        for kind in kinds:
            cells = run(scene, kind, args.resolution, args.repeat)
            base = cells[0]["time.trace"]
            for k, s in enumerate(cells):
                totals[k] += (s["tests.per_ray"] / max(cells[1]["tests.per_ray"], 1e-12), s["time.trace"] / base)
            text = " | ".join(f"{s['tests.per_ray']:.2f} / {s['bounds.per_ray']:.1f} / {1e3 * s['time.trace']:.0f}"
                              for s in cells)
            lines.append(f"| {name} | {kind} | {cells[0]['rays.total']:,} | {text} |")
            print(lines[-1], flush=True)
    n = len(lines) - 2
    summary = " | ".join(f"{t / n:.2f} / {r / n:.2f}" for t, r in totals)
    lines.append(f"| **mean** | tests vs closest / time vs none | | {summary} |")
    command = " ".join(["python bench/tricks.py"] + sys.argv[1:])
    text = "\n".join([
        "## Haines's efficiency tricks",
        "",
        f"`{command}` ({date.today().isoformat()}): SPD mode at {args.resolution}x{args.resolution}, depth 5, "
        f"each kind at its defaults; trace time best of {args.repeat}.",
        "",
        f"Machine: {machine()}.",
        "",
        SUMMARY,
        "",
        *subtable(lines, COLUMNS, {"scene": ["**mean**"]}),
        "",
        DETAILS,
        "",
        "rays: every ray of the render (eye, reflect, refract, shadow), the same in every column. "
        "Each cell: tests per ray (N_IT) / bound tests per ray / trace ms. `none`: no trick; `closest`: trick 1, "
        "the closest-hit cut-off; `+name`: trick 1 and that one (tricks 2 and 6 bound the closest search, so each "
        "is measured on top of trick 1); `all`: all six. Images and ray counts are the same in every column (the "
        "script checks). The mean row: tests per ray against `closest` / trace time against `none`, averaged "
        "over the rows.",
        "",
        *lines,
    ])
    replace_section("tricks", text)


if __name__ == "__main__":
    main()

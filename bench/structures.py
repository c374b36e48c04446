"""Compare the acceleration structures on the SPD default scenes and the stadium.

    .venv/bin/python bench/structures.py [--resolution 128] [--scenes balls,gears] [--kinds bvh,grid]

For each scene and each kind (default parameters) it renders in SPD mode and
records N_IT (tests per ray), N_TS (traversal steps per ray), N_ETS, N_EETS,
build nodes, bytes, build and trace seconds; a second table compares the
octree's subdivision criteria and traversals on a few scenes, and a third
the lazy structures against the octree as the image grows (their trees are
built by the rays, so the early rays' cost is shared by more rays). Writes
the `structures` section of BENCHMARKS.md. Ray counts must agree across kinds;
a disagreement aborts the run.
"""

from __future__ import annotations

import argparse
import sys
from datetime import date

from _report import DETAILS, machine, pivot, replace_section

import raykernel
from raykernel.aggregates.registry import KINDS
from raykernel.scene import spd

RAY_KEYS = ("rays.eye", "rays.eye_hit", "rays.reflect", "rays.reflect_hit", "rays.refract", "rays.refract_hit",
            "rays.shadow", "rays.shadow_blocked")
# the defaults first, then one change each: walks, criteria off or on (whichever is not the default),
# limits up and down, and the old defaults (depth 8, no budget)
OCTREE_VARIANTS = ("octree", "octree(walk=point)", "octree(walk=parametric)", "octree(walk=wall)", "octree(rule60=on)",
                   "octree(density=0.3)", "octree(vertexcount=on)", "octree(collapse=off)", "octree(mailbox=off)",
                   "octree(leaf=1)", "octree(leaf=8)", "octree(depth=8)", "octree(depth=24)", "octree(budget=8)",
                   "octree(budget=32)", "octree(depth=8, budget=0)")
# the four octree walks over the same tree (the wall walk builds without collapse: so does the last)
OCTREE_WALKS = ("octree(walk=point, collapse=off)", "octree(walk=neighbor, collapse=off)",
                "octree(walk=parametric, collapse=off)", "octree(walk=wall)")
# the lazy structures beside the eager octree, at several image sizes
LAZY_SPECS = ("octree", "lazyoctree", "rc")
SUMMARY = "Tests per ray (N_IT), each kind at its defaults (the full tables: every count, memory and time):"


def run(scenes, specs, resolution):
    rows = []
    for name, scene in scenes:
        reference = None
        for spec in specs:
            s = raykernel.render(scene, accel=spec, resolution=resolution, spd=True).stats
            counts = tuple(s[k] for k in RAY_KEYS)
            if reference is None:
                reference = (spec, counts)
            elif counts != reference[1]:
                sys.exit(f"{name}: ray counts of {spec} differ from {reference[0]}: {counts} vs {reference[1]}")
            rows.append((name, spec, s))
            print(f"{name:10s} {spec:28s} N_IT {s['tests.per_ray']:7.2f} N_TS {s['cells.visited_per_ray']:7.2f} "
                  f"trace {s['time.trace']:6.2f}s", file=sys.stderr)
    return rows


def table(rows):
    lines = ["| scene | structure | N_IT | N_TS | N_ETS | N_EETS | mailbox saved | nodes | bytes | build s | trace s |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for name, spec, s in rows:
        lines.append(f"| {name} | `{spec}` | {s['tests.per_ray']:.2f} | {s['cells.visited_per_ray']:.2f} | "
                     f"{s['cells.leaves_per_ray']:.2f} | {s['cells.empty_per_ray']:.2f} | {s['mailbox.saved']:,} | "
                     f"{s['build.nodes']:,} | {s['build.bytes']:,} | {s['time.preprocess']:.3f} | "
                     f"{s['time.trace']:.2f} |")
    return lines


def walk_table(rows):
    lines = ["| scene | walk | N_TS | N_ETS | wall steps | bound tests | N_IT | trace s |",
             "|---|---|---:|---:|---:|---:|---:|---:|"]
    for name, spec, s in rows:
        rays = max(1, s["rays.total"])
        lines.append(f"| {name} | `{spec}` | {s['cells.visited_per_ray']:.2f} | {s['cells.leaves_per_ray']:.2f} | "
                     f"{s.get('octree.wall_steps', 0) / rays:.2f} | {s['bounds.tests'] / rays:.2f} | "
                     f"{s['tests.per_ray']:.2f} | {s['time.trace']:.2f} |")
    return lines


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--scenes", default=",".join(spd.NAMES) + ",stadium")
    parser.add_argument("--kinds", default=",".join(k for k, kind in KINDS.items()
                                                    if k != "list" and not kind.operands))   # (operators: per group)
    parser.add_argument("--octree-scenes", default="balls,teapot,stadium")
    parser.add_argument("--lazy-scenes", default="balls,teapot,stadium")
    parser.add_argument("--lazy-sizes", default="96,256,512")
    args = parser.parse_args()

    def load(name):
        return raykernel.load("scene:stadium" if name == "stadium" else f"spd:{name}")

    scenes = [(n, load(n)) for n in args.scenes.split(",")]
    kinds = args.kinds.split(",")
    warm = raykernel.load("spd:balls:1")
    for spec in dict.fromkeys(kinds + list(OCTREE_VARIANTS) + list(OCTREE_WALKS) + list(LAZY_SPECS)):
        raykernel.render(warm, accel=spec, resolution=8, spd=True)   # compile or load the cache first
    main_table = table(run(scenes, kinds, args.resolution))
    lines = ["## Acceleration structures side by side", "",
             f"`{('python bench/structures.py ' + ' '.join(sys.argv[1:])).strip()}` ({date.today().isoformat()}): "
             f"SPD mode at {args.resolution}x{args.resolution}, each kind with its default parameters; "
             "per-ray figures divide by all rays (eye, reflect, refract, shadow). Ray counts agree across kinds "
             "(checked by the script).", "", f"Machine: {machine()}.", "", SUMMARY, "",
             *pivot(main_table, "scene", "structure", "N_IT"), "", DETAILS, "",
             "Each kind at its defaults, every count and time:", ""] + main_table
    if "octree" in KINDS:
        oct_scenes = [(n, s) for n, s in scenes if n in args.octree_scenes.split(",")] or \
            [(n, load(n)) for n in args.octree_scenes.split(",")]
        lines += ["", "### Octree criteria and traversals", ""] + table(run(oct_scenes, OCTREE_VARIANTS,
                                                                          args.resolution))
        lines += ["", "### The four octree walks over one tree", "",
                  "The same octree (no collapse: the wall walk's quadtrees index the octants) walked by point "
                  "location from the root (Lathrop), neighbour pointers then descent (Glassner), the parametric "
                  "walk (Revelles et al.) and Glassner's wall quadtrees. N_TS counts the octree nodes visited; "
                  "wall steps, the wall quadtrees' levels gone down instead; all meet the same leaves (N_ETS) "
                  "but the parametric walk, which tests node boxes as it goes."]
        lines += [""] + walk_table(run(oct_scenes, OCTREE_WALKS, args.resolution))
    lazy_scenes = [(n, s) for n, s in scenes if n in args.lazy_scenes.split(",")] or \
        [(n, load(n)) for n in args.lazy_scenes.split(",")]
    lines += ["", "### Lazy structures and image size", "",
              "The same in SPD mode at each size; build s is the build before the first ray, and the lazy "
              "structures' refinement between passes is part of their trace s."]
    for size in (int(x) for x in args.lazy_sizes.split(",")):
        lines += ["", f"{size}x{size}:", ""] + table(run(lazy_scenes, LAZY_SPECS, size))
    replace_section("structures", "\n".join(lines))


if __name__ == "__main__":
    main()

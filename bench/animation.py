"""Animation: per-frame build time with incremental structures against from scratch, and a
render on a Dask LocalCluster against one process.

    .venv/bin/python bench/animation.py [--frames 24] [--resolution 64] [--satellite-prims 100000]
                                        [--stadium-prims 100000] [--render-resolution 512]

Builds: each scene's frames are rendered twice in the same run, with an incremental.Hierarchy
and with every frame built from scratch; every frame's image and ray counts must agree (a
difference aborts the run). The satellite moves as a whole (its primitives' BVH is refit);
in the stadium the teapot, an instance of its own BVH, moves along the goal line and turns
(its BVH is reused, the stadium's BVH refit over the moved instance). Frame 0 is a
from-scratch build in both columns and is left out of the means.

Dask: spd:balls in SPD mode, best of 3, one process on every core against `local:N` with N
worker processes of one thread each (the same cores), rays printed on both sides.
Writes the `animation` section of BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from datetime import date

import numpy as np
from _report import DETAILS, machine, replace_section

import raykernel
from raykernel.engine.incremental import Hierarchy
from raykernel.scene import pathological
from raykernel.scene.animation import Animation, Keyframe, Motion, axis_angle_quaternion, parameter_animation
from raykernel.scene.model import Instance

RAYS = ("rays.eye", "rays.reflect", "rays.refract", "rays.shadow", "rays.shadow_blocked")


def moving_teapot(stadium_prims: int):
    scene = pathological.load("stadium", stadium_prims=stadium_prims, teapot_bvh=1)
    k = [i for i, c in enumerate(scene.root.children) if getattr(c, "name", "") == "teapot"][0]
    inst = Instance(scene.root.children[k])
    scene.root.children[k] = inst
    motion = Motion([Keyframe(0.0), Keyframe(1.0, translate=np.array([0.6, 0.0, 0.0]),
                                             rotate=axis_angle_quaternion([0, 0, 1], 90.0))])
    scene.animation = Animation(time=(0.0, 1.0), motions=[(inst, np.eye(4), motion)])
    return scene


def frames(subject, times):
    for t in times:
        yield subject.at(None, t) if isinstance(subject, Animation) else subject.animation.at(subject, t)


def build_rows(label, subject, times, resolution):
    inc, scratch = Hierarchy(), Hierarchy(incremental=False)
    rows = []
    for scene in frames(subject, times):
        a = raykernel.render(scene, resolution=resolution, builder=inc)
        b = raykernel.render(scene, resolution=resolution, builder=scratch)
        if not np.array_equal(a.image, b.image) or any(a.stats[k] != b.stats[k] for k in RAYS):
            sys.exit(f"{label}: a frame differs between the incremental and the from-scratch build")
        rows.append((a.stats, b.stats))
    later = rows[1:]
    mean = lambda key, side: float(np.mean([r[side][key] for r in later]))    # noqa: E731
    total = lambda key, side: int(sum(r[side][key] for r in later))            # noqa: E731
    prims = rows[0][0].info["primitives"]
    inc_s, scr_s = mean("build.seconds", 0), mean("build.seconds", 1)
    return (f"| {label} | {prims:,} | {len(times)} | {1e3 * inc_s:.1f} | {1e3 * scr_s:.1f} | {scr_s / inc_s:.1f}x "
            f"| {total('build.refit_nodes', 0):,} | {total('build.rebuilt_nodes', 0):,} "
            f"| {total('build.rebuilt_nodes', 1):,} | {mean('bounds.per_ray', 0):.2f} | {mean('bounds.per_ray', 1):.2f} "
            f"| {total('rays.total', 0):,} / {total('rays.total', 1):,} |")


def dask_rows(resolution, repeat):
    from raykernel.cluster import Cluster
    cores = os.cpu_count() or 1
    scene = raykernel.load("spd:balls")
    raykernel.render(scene, resolution=8, spd=True)

    def best(fn):
        out = None
        for _ in range(repeat):
            t0 = time.perf_counter()
            r = fn()
            wall = time.perf_counter() - t0
            if out is None or wall < out[0]:
                out = (wall, r)
        return out
    alone_wall, alone = best(lambda: raykernel.render(scene, resolution=resolution, spd=True, threads=cores))
    with Cluster(f"local:{cores}") as cluster:
        cluster.warm_up()
        spread_wall, spread = best(lambda: cluster.render(scene, resolution=resolution, spd=True))
    if not np.array_equal(alone.image, spread.image) or any(alone.stats[k] != spread.stats[k] for k in RAYS):
        sys.exit("the LocalCluster render differs from the single-process render")
    rays = lambda s: f"{s['rays.total']:,}"     # noqa: E731
    return [f"| one process, {cores} threads | {alone_wall:.3f} | {rays(alone.stats)} | 1.00x |",
            f"| LocalCluster, {cores} workers x 1 thread | {spread_wall:.3f} | {rays(spread.stats)} "
            f"| {alone_wall / spread_wall:.2f}x |"]


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--frames", type=int, default=24)
    parser.add_argument("--resolution", type=int, default=64)
    parser.add_argument("--satellite-prims", type=int, default=100000)
    parser.add_argument("--stadium-prims", type=int, default=100000)
    parser.add_argument("--render-resolution", type=int, default=512)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    sat = parameter_animation(f"scene:satellite:prims={args.satellite_prims}")
    stadium = moving_teapot(args.stadium_prims)
    raykernel.render(raykernel.load("spd:balls:1"), resolution=8, builder=Hierarchy())    # compile first
    head = ("| scene | primitives | frames | build ms/frame, incremental | from scratch | speed-up | refit nodes "
            "| rebuilt nodes | nodes built from scratch | bounds/ray, incremental | from scratch "
            "| rays, incremental / from scratch |")
    lines = [head, "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
             build_rows("satellite (time 0-600 s)", sat, sat.times(args.frames), args.resolution),
             build_rows("stadium, moving teapot", stadium, stadium.animation.times(args.frames), args.resolution)]
    dask = dask_rows(args.render_resolution, args.repeat)
    text = "\n".join([
        "## Animation: incremental structures and Dask",
        "",
        f"Command: `.venv/bin/python bench/animation.py --frames {args.frames} --resolution {args.resolution} "
        f"--satellite-prims {args.satellite_prims} --stadium-prims {args.stadium_prims} "
        f"--render-resolution {args.render_resolution}` ({date.today().isoformat()}). Machine: {machine()}.",
        "",
        "Per-frame build time (`build.seconds`, mean over frames 1 onwards; frame 0 is built from scratch in "
        "both columns), both columns in the same run; every frame's image and ray counts are the same in both.",
        "",
        *lines,
        "",
        DETAILS,
        "",
        f"A render of spd:balls at {args.render_resolution}x{args.render_resolution}, SPD mode, wall clock "
        f"(best of {args.repeat}), the same cores on both sides; the images and every ray count are the same:",
        "",
        "| run | seconds | rays | speed |",
        "|---|---:|---:|---:|",
        *dask,
    ])
    replace_section("animation", text)
    print(text)


if __name__ == "__main__":
    main()

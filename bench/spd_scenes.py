"""Render all 13 default SPD scenes in SPD mode and record times and counts.

    .venv/bin/python bench/spd_scenes.py [--resolution 512] [--accel bvh] [--threads N]

Writes the `spd_scenes` section of BENCHMARKS.md. Scenes come from our own
generators at their default size factors (identical to the SPD's files).
The kernels are compiled (or loaded from the cache) before timing starts.
"""

from __future__ import annotations

import argparse
import sys
import time
from datetime import date

from _report import machine, replace_section

import raykernel
from raykernel.scene import spd


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--resolution", type=int, default=512)
    parser.add_argument("--accel", default="bvh")
    parser.add_argument("--threads", type=int, default=None)
    args = parser.parse_args()

    raykernel.render(raykernel.load("spd:balls:1"), resolution=8, spd=True)   # compile / load the cache
    rows = []
    for name in spd.NAMES:
        scene = raykernel.load(f"spd:{name}")
        t0 = time.perf_counter()
        result = raykernel.render(scene, accel=args.accel, resolution=args.resolution, spd=True,
                                  threads=args.threads)
        wall = time.perf_counter() - t0
        s = result.stats
        rows.append((name, spd.default_size(name), scene.count_primitives(), s, wall))
        print(f"{name:9s} prims {scene.count_primitives():6d}  pre {s['time.preprocess']:6.2f}s  "
              f"trace {s['time.trace']:6.2f}s  rays {s['rays.total']:,}", file=sys.stderr)

    cmd = "python bench/spd_scenes.py " + " ".join(sys.argv[1:])
    lines = [
        "## SPD default scenes, SPD test procedure",
        "",
        f"`{cmd.strip()}` ({date.today().isoformat()}) at {args.resolution}x{args.resolution}, accelerator `{args.accel}`, "
        f"corner rays (513x513 eye rays at 512), depth 5, no cut-off.",
        "",
        f"Machine: {machine()}.",
        "",
        "| scene | sf | prims | preprocess s | trace s | eye | reflect | refract | shadow | shadow blocked "
        "| tests/ray | bound tests/ray | nodes/ray | Mrays/s |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for name, sf, prims, s, wall in rows:
        lines.append(
            f"| {name} | {sf} | {prims:,} | {s['time.preprocess']:.3f} | {s['time.trace']:.2f} | "
            f"{s['rays.eye']:,} | {s['rays.reflect']:,} | {s['rays.refract']:,} | {s['rays.shadow']:,} | "
            f"{s['rays.shadow_blocked']:,} | {s['tests.per_ray']:.2f} | {s['bounds.per_ray']:.2f} | "
            f"{s['cells.visited_per_ray']:.2f} | {s['time.rays_per_second'] / 1e6:.2f} |")
    total = sum(r[3]['time.trace'] for r in rows)
    lines += ["", f"Total trace time {total:.1f} s. Per-ray figures divide by all rays (eye, reflect, refract, "
              "shadow)."]
    replace_section("spd_scenes", "\n".join(lines))


if __name__ == "__main__":
    main()

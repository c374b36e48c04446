"""Early split clipping (`bvh(split=N)`) against the plain SAH BVH: renders and mesh casting.

    .venv/bin/python bench/presplit.py [--resolution 256] [--rays 500000] [--rounds 5]

Renders: SPD mode at --resolution on 2 threads, the scenes below under one BVH each
(anneal.without_specs), plain and split into up to 4 and 16 pieces; the same image bytes and
ray counts are checked; trace seconds the best of --rounds rounds, the structures alternating.
Mesh casting: RayScene.from_mesh (the mesh kernel, bvh(block=4)) plain and split on the meshes
of bench/raycast.py, the same coherent and incoherent rays; the same hits are checked (t and
prim_id). Writes the `presplit` section of BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _report import machine, replace_section  # noqa: E402
from raycast import MESHES, camera_rays, random_rays  # noqa: E402

import raykernel  # noqa: E402
from raykernel.analysis.anneal import without_specs  # noqa: E402
from raykernel.casting.meshcast import MESH_ACCEL  # noqa: E402

SCENES = ("scene:diamond", "scene:stadium", "scene:teapot-room", "scene:park", "spd:teapot", "spd:gears",
          "spd:mount", "spd:tetra", "spd:sombrero")
SPLITS = (1, 4, 16)


def spec(base: str, split: int) -> str:
    if split == 1:
        return base
    inner = base[base.index("(") + 1:-1] + ", " if "(" in base else ""
    return f"bvh({inner}split={split})"


def render_rows(args):
    rows = []
    for name in SCENES:
        scene = without_specs(raykernel.load(name))
        options = dict(resolution=args.resolution, spd=True, threads=2)
        first, best = {}, {}
        for _ in range(args.rounds):
            for split in SPLITS:
                result = raykernel.render(scene, accel=spec("bvh", split), **options)
                first.setdefault(split, result)
                if split not in best or result.stats["time.trace"] < best[split]["time.trace"]:
                    best[split] = result.stats
        plain = first[1]
        for split in SPLITS:
            same = first[split].image.tobytes() == plain.image.tobytes() and all(
                first[split].stats[k] == plain.stats[k] for k in plain.stats if k.startswith("rays."))
            if not same:
                sys.exit(f"{name}: bvh(split={split}) renders another image or other rays than bvh")
            s = best[split]
            rows.append(f"| {name} | {spec('bvh', split)} | {s['rays.total']:,} | {s['build.refs']:,} "
                        f"| {s['tests.per_ray']:.2f} | {s['bounds.per_ray']:.2f} | {s['time.preprocess']:.3f} "
                        f"| {s['time.trace']:.4f} | {best[1]['time.trace'] / s['time.trace']:.2f}x |")
        print(rows[-1], flush=True)
    return rows


def cast_rows(args):
    import numba
    numba.set_num_threads(2)
    rng = np.random.default_rng(0)
    rows = []
    for name, make in MESHES.items():
        v, f = make()
        rays = {"coherent": camera_rays(v, args.rays), "incoherent": random_rays(v, args.rays, rng)}
        built, build_s = {}, {}
        for split in SPLITS:
            t0 = time.perf_counter()
            built[split] = raykernel.RayScene.from_mesh(v, f, accel=spec(MESH_ACCEL, split))
            build_s[split] = time.perf_counter() - t0
        for kind, (o, d) in rays.items():
            best, hits, stats = {}, {}, {}
            for split in SPLITS:
                built[split].intersect(o[:1000], d[:1000])
            for _ in range(args.rounds):
                for split in SPLITS:
                    t0 = time.perf_counter()
                    h = built[split].intersect(o, d, fields=("t", "prim_id"))
                    sec = time.perf_counter() - t0
                    if sec < best.get(split, np.inf):
                        best[split], hits[split], stats[split] = sec, h, built[split].last_stats
            for split in SPLITS:
                if not (np.array_equal(hits[split].t, hits[1].t) and
                        np.array_equal(hits[split].prim_id, hits[1].prim_id)):
                    sys.exit(f"{name} {kind}: split={split} gives other hits than the plain BVH")
                s = stats[split]
                rows.append(f"| {name} | {len(f):,} | {kind} | {spec(MESH_ACCEL, split)} | {len(o):,} "
                            f"| {build_s[split]:.2f} | {s.get('tests.triangle', 0) / len(o):.2f} "
                            f"| {s.get('bounds.tests', 0) / len(o):.2f} | {len(o) / best[split] / 1e6:.2f} "
                            f"| {best[1] / best[split]:.2f}x |")
            print(rows[-1], flush=True)
    return rows


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--resolution", type=int, default=256)
    parser.add_argument("--rays", type=int, default=500_000)
    parser.add_argument("--rounds", type=int, default=5)
    args = parser.parse_args()
    renders = render_rows(args)
    casts = cast_rows(args)
    text = "\n".join([
        "## Early split clipping (`bvh(split=N)`) against the plain BVH",
        "",
        f"Command: `.venv/bin/python bench/presplit.py --resolution {args.resolution} --rays {args.rays} "
        f"--rounds {args.rounds}`. Machine: {machine()}.",
        "",
        f"Renders: SPD mode, {args.resolution}x{args.resolution}, 2 threads, each scene under one BVH; every "
        "variant renders the same image bytes and casts the same rays (checked). Trace seconds: the best of "
        f"{args.rounds} rounds, the variants alternating. refs: references in the leaves (a primitive split into "
        "pieces can sit in several leaves). speed: the plain BVH's trace time over this one's.",
        "",
        "| scene | structure | rays | refs | tests/ray | bounds/ray | preprocess s | trace s | speed |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|",
        *renders,
        "",
        f"Mesh casting: `RayScene.from_mesh` (the mesh kernel) on the meshes of bench/raycast.py, {args.rays:,} "
        "rays a set, 2 threads, closest hits with t and prim_id; every variant gives the same hits (checked). "
        f"Best of {args.rounds} rounds, alternating. build s: RayScene construction; Mrays/s; speed against the "
        "plain tree.",
        "",
        "| mesh | triangles | rays | structure | rays cast | build s | tests/ray | bounds/ray | Mrays/s | speed |",
        "|---|---:|---|---|---:|---:|---:|---:|---:|---:|",
        *casts,
    ])
    replace_section("presplit", text)
    print(text)


if __name__ == "__main__":
    main()

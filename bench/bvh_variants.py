"""The SAH BVH's variants against the plain tree: early split clipping (`bvh(split=N)`) and
reinsertion (`bvh(optimize=reinsertion)`), on renders and on mesh casting.

    .venv/bin/python bench/bvh_variants.py [--resolution 256] [--rays 500000] [--rounds 5]

Renders: SPD mode at --resolution on 2 threads, the scenes below under one BVH each
(anneal.without_specs), plain, split into up to 4 and 16 pieces, and reinserted; the same
image bytes and ray counts are checked; trace seconds the best of --rounds rounds, the
structures alternating. Mesh casting: RayScene.from_mesh (the mesh kernel, bvh(block=4)) with
the same variants on the meshes of bench/raycast.py, the same coherent and incoherent rays;
the same hits are checked (t and prim_id). Writes the `bvh_variants` section of BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import sys
import time
from datetime import date
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _report import DETAILS, machine, replace_section, subtable  # noqa: E402
from raycast import MESHES, camera_rays, random_rays  # noqa: E402

import raykernel  # noqa: E402
from raykernel.analysis.anneal import without_specs  # noqa: E402
from raykernel.casting.meshcast import MESH_ACCEL  # noqa: E402

RENDER_TABLE = ["| scene | structure | rays | refs | tests/ray | bounds/ray | preprocess s | trace s | speed |",
                "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
# the summary in BENCHMARKS.md: the renders of the scenes where a variant gains or loses most
SUMMARY = ("Renders where a variant gains or loses most (every scene and the mesh casts in the full tables); "
           "speed: the plain BVH's trace time over this one's, the same images and rays on every row.")
SUMMARY_SCENES = ["scene:diamond", "scene:stadium"]
SUMMARY_SPECS = ["bvh", "bvh(split=16)", "bvh(optimize=reinsertion)"]
COLUMNS = ["scene", "structure", "refs", "tests/ray", "trace s", "speed"]

SCENES = ("scene:diamond", "scene:stadium", "scene:teapot-room", "scene:park", "spd:teapot", "spd:gears",
          "spd:mount", "spd:tetra", "spd:sombrero")
VARIANTS = ("", "split=4", "split=16", "optimize=reinsertion")     # "": the plain tree


def spec(base: str, variant: str) -> str:
    if not variant:
        return base
    inner = base[base.index("(") + 1:-1] + ", " if "(" in base else ""
    return f"bvh({inner}{variant})"


def render_rows(args):
    rows = []
    for name in SCENES:
        scene = without_specs(raykernel.load(name))
        options = dict(resolution=args.resolution, spd=True, threads=2)
        first, best = {}, {}
        for _ in range(args.rounds):
            for variant in VARIANTS:
                result = raykernel.render(scene, accel=spec("bvh", variant), **options)
                first.setdefault(variant, result)
                if variant not in best or result.stats["time.trace"] < best[variant]["time.trace"]:
                    best[variant] = result.stats
        plain, plain_t = first[""], best[""]["time.trace"]
        for variant in VARIANTS:
            same = first[variant].image.tobytes() == plain.image.tobytes() and all(
                first[variant].stats[k] == plain.stats[k] for k in plain.stats if k.startswith("rays."))
            if not same:
                sys.exit(f"{name}: {spec('bvh', variant)} renders another image or other rays than bvh")
            s = best[variant]
            rows.append(f"| {name} | {spec('bvh', variant)} | {s['rays.total']:,} | {s['build.refs']:,} "
                        f"| {s['tests.per_ray']:.2f} | {s['bounds.per_ray']:.2f} | {s['time.preprocess']:.3f} "
                        f"| {s['time.trace']:.4f} | {plain_t / s['time.trace']:.2f}x |")
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
        for variant in VARIANTS:
            t0 = time.perf_counter()
            built[variant] = raykernel.RayScene.from_mesh(v, f, accel=spec(MESH_ACCEL, variant))
            build_s[variant] = time.perf_counter() - t0
        for kind, (o, d) in rays.items():
            best, hits, stats = {}, {}, {}
            for variant in VARIANTS:
                built[variant].intersect(o[:1000], d[:1000])
            for _ in range(args.rounds):
                for variant in VARIANTS:
                    t0 = time.perf_counter()
                    h = built[variant].intersect(o, d, fields=("t", "prim_id"))
                    sec = time.perf_counter() - t0
                    if sec < best.get(variant, np.inf):
                        best[variant], hits[variant], stats[variant] = sec, h, built[variant].last_stats
            plain = best[""]
            for variant in VARIANTS:
                if not (np.array_equal(hits[variant].t, hits[""].t) and
                        np.array_equal(hits[variant].prim_id, hits[""].prim_id)):
                    sys.exit(f"{name} {kind}: {variant} gives other hits than the plain BVH")
                s = stats[variant]
                rows.append(f"| {name} | {len(f):,} | {kind} | {spec(MESH_ACCEL, variant)} | {len(o):,} "
                            f"| {build_s[variant]:.2f} | {s.get('tests.triangle', 0) / len(o):.2f} "
                            f"| {s.get('bounds.tests', 0) / len(o):.2f} | {len(o) / best[variant] / 1e6:.2f} "
                            f"| {plain / best[variant]:.2f}x |")
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
        "## The BVH's variants against the plain tree: split clipping and reinsertion",
        "",
        f"Command: `.venv/bin/python bench/bvh_variants.py --resolution {args.resolution} --rays {args.rays} "
        f"--rounds {args.rounds}` ({date.today().isoformat()}). Machine: {machine()}.",
        "",
        SUMMARY,
        "",
        *subtable(RENDER_TABLE + renders, COLUMNS, {"scene": SUMMARY_SCENES, "structure": SUMMARY_SPECS}),
        "",
        DETAILS,
        "",
        f"Renders: SPD mode, {args.resolution}x{args.resolution}, 2 threads, each scene under one BVH; every "
        "variant renders the same image bytes and casts the same rays (checked). Trace seconds: the best of "
        f"{args.rounds} rounds, the variants alternating. refs: references in the leaves (a primitive split into "
        "pieces can sit in several leaves). speed: the plain BVH's trace time over this one's.",
        "",
        *RENDER_TABLE,
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
    replace_section("bvh_variants", text)
    print(text)


if __name__ == "__main__":
    main()

"""What one RayScene.intersect call costs around its kernel: checks, outputs, identities.

    .venv/bin/python bench/overhead.py [--rays 1000000] [--threads 2]

One mesh (an 80k-triangle sphere), coherent rays from a camera; the same rays
for every row. Each row is a way of calling intersect: every field in
float64 (the default), only t and prim_id, the same in float32, and the same
into the arrays of an earlier answer (out=). `kernel` is the query's own
time.trace, `call` the whole call; best of 7 after a warm-up. Writes the
`overhead` section of BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _report import machine, replace_section  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rays", type=int, default=1_000_000)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    import trimesh

    import raykernel
    mesh = trimesh.creation.icosphere(subdivisions=6)
    scene = raykernel.RayScene.from_mesh(mesh.vertices, mesh.faces)
    side = int(np.sqrt(args.rays))
    n = side * side
    u, v = np.meshgrid(np.linspace(-0.6, 0.6, side), np.linspace(-0.6, 0.6, side))
    o = np.tile([0.0, -3.0, 0.0], (n, 1))
    d = np.stack([u.ravel(), np.full(n, 3.0), v.ravel()], 1)
    few = ("t", "prim_id")
    ways = [("every field, float64 (default)", {}),
            ("fields=(t, prim_id)", dict(fields=few)),
            ("fields=(t, prim_id), float32", dict(fields=few, dtype="float32")),
            ("fields=(t, prim_id), float32, out=", dict(fields=few, dtype="float32", out=True))]
    rows = []
    for label, kw in ways:
        if kw.get("out"):
            kw = dict(kw, out=scene.intersect(o, d, fields=few, dtype="float32", threads=args.threads))
        scene.intersect(o, d, threads=args.threads, **kw)
        best_call = best_kernel = np.inf
        for _ in range(7):
            t0 = time.perf_counter()
            h = scene.intersect(o, d, threads=args.threads, **kw)
            best_call = min(best_call, time.perf_counter() - t0)
            best_kernel = min(best_kernel, scene.last_stats["time.trace"])
        mb = sum(getattr(h, f).nbytes for f in ("t", "prim_id", "geom_id", "inst_id", "kind", "uv", "normal",
                                                 "shading_normal") if getattr(h, f) is not None) / 1e6
        rows.append((label, scene.last_stats["rays.cast"], mb, best_kernel, best_call))
        print(f"{label:40s} {mb:7.1f} MB  kernel {best_kernel * 1e3:7.1f} ms  call {best_call * 1e3:7.1f} ms", flush=True)
    lines = ["## RayScene.intersect: the cost of one call around its kernel", "",
             f"`{('python bench/overhead.py ' + ' '.join(sys.argv[1:])).strip()}`: {n:,} coherent rays at an "
             f"80k-triangle sphere (the mesh kernel), {args.threads} threads, best of 7; kernel = the query's "
             "time.trace, call = the whole intersect call (checks, outputs, identities).", "",
             f"Machine: {machine()}.", "",
             "| call | rays | output MB | kernel ms | call ms | outside the kernel ms |", "|---|---:|---:|---:|---:|---:|"]
    for label, rays, mb, k, c in rows:
        lines.append(f"| {label} | {rays:,} | {mb:.0f} | {k * 1e3:.1f} | {c * 1e3:.1f} | {(c - k) * 1e3:.1f} |")
    if not args.no_write:
        replace_section("overhead", "\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

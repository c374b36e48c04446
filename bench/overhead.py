"""What one RayScene.intersect call costs around its kernel: checks, outputs, identities.

    .venv/bin/python bench/overhead.py [--rays 1000000] [--threads 2]

One mesh (an 80k-triangle sphere), coherent rays from a camera; the same rays
for every row. Each row is a way of calling intersect: every field in
float64 (the default), only t and prim_id, the same in float32, and the same
into the arrays of an earlier answer (out=). `kernel` is the query's own
time.trace, `call` the whole call; best of 7 after a warm-up. Then whole calls on
small batches (1 to 10,000 rays, one thread) against embreex's on the same rays.
Writes the `overhead` section of BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import sys
import time
from datetime import date
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _report import DETAILS, machine, replace_section  # noqa: E402
from raycast import PEER_FIELDS  # noqa: E402


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
    o, d = camera(args.rays)
    n = len(o)
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
             f"`{('python bench/overhead.py ' + ' '.join(sys.argv[1:])).strip()}` ({date.today().isoformat()}): "
             f"{n:,} coherent rays at an "
             f"80k-triangle sphere (the mesh kernel), {args.threads} threads, best of 7; kernel = the query's "
             "time.trace, call = the whole intersect call (checks, outputs, identities).", "",
             f"Machine: {machine()}.", "",
             "| call | rays | output MB | kernel ms | call ms | outside the kernel ms |", "|---|---:|---:|---:|---:|---:|"]
    for label, rays, mb, k, c in rows:
        lines.append(f"| {label} | {rays:,} | {mb:.0f} | {k * 1e3:.1f} | {c * 1e3:.1f} | {(c - k) * 1e3:.1f} |")
    lines += ["", DETAILS] + small_batches(mesh, scene)
    if not args.no_write:
        replace_section("overhead", "\n".join(lines) + "\n")
    return 0


def camera(rays: int) -> tuple[np.ndarray, np.ndarray]:
    """Coherent rays from a pinhole camera 3 units from the sphere, on a square grid of about `rays`
    (the centre ray alone for 1)."""
    side = int(np.sqrt(rays))
    n = side * side
    span = np.linspace(-0.6, 0.6, side) if side > 1 else np.zeros(1)
    u, v = np.meshgrid(span, span)
    o = np.tile([0.0, -3.0, 0.0], (n, 1))
    d = np.stack([u.ravel(), np.full(n, 3.0), v.ravel()], 1)
    return o, d


SMALL = (1, 100, 1024, 10000)


def _per_call(fn, seconds=0.3) -> float:
    """Median seconds of one call, over as many calls as fit in `seconds` (after 20 to warm up)."""
    for _ in range(20):
        fn()
    times = []
    end = time.perf_counter() + seconds
    while time.perf_counter() < end or len(times) < 20:
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def small_batches(mesh, scene) -> list:
    """Rows of whole calls on small batches, 1 thread, against embreex's run(output=1) on the same
    rays (its float32 conversion included, as a caller with float64 rays pays it)."""
    try:
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh
    except ImportError as e:
        return ["", f"Small batches: embreex is not installed ({e}); `pip install -e '.[bench]'`."]
    peer = rtcore_scene.EmbreeScene()
    TriangleMesh(peer, np.asarray(mesh.vertices)[np.asarray(mesh.faces)].astype(np.float32))
    lines = ["", "Small batches, one thread, the whole call, median: raykernel `intersect(o, d, fields=(t, prim_id, "
             "geom_id, uv, normal), dtype=\"float32\", threads=1)` against embreex `run(o.astype(float32), "
             "d.astype(float32), output=1)`, the same outputs; the camera above on a coarser grid of the same "
             "field of view.", "", "| rays | raykernel us | embreex us | ratio |", "|---:|---:|---:|---:|"]
    for n in SMALL:
        o, d = camera(n)
        ours = _per_call(lambda: scene.intersect(o, d, fields=PEER_FIELDS, dtype="float32", threads=1))
        theirs = _per_call(lambda: peer.run(o.astype(np.float32), d.astype(np.float32), output=1))
        print(f"{n:6d} rays: raykernel {ours * 1e6:8.1f} us  embreex {theirs * 1e6:8.1f} us", flush=True)
        lines.append(f"| {n:,} | {ours * 1e6:.1f} | {theirs * 1e6:.1f} | {theirs / ours:.2f} |")
    return lines


if __name__ == "__main__":
    raise SystemExit(main())

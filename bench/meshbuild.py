"""Mesh builds: RayScene.from_mesh at each quality against embreex and Open3D, build and first ray.

    .venv/bin/python bench/meshbuild.py [--threads 2] [--big]

A user with a scanned mesh builds a structure and casts a ray before anything
else: each row times that (the build and one ray, best of 3 or of as many as fit in
a second, up to 30, kernels warm: small builds take milliseconds on noisy machines),
each library in its own process pinned to `threads` cores (taskset), with
the mesh's arrays made before the clock starts. first: the first build and ray
of a fresh process that has only numpy and the mesh's arrays, the library's
import included (for raykernel, at medium quality, its kernels loaded from the
cache), as a user's script meets it: it also pays for the memory the process
takes from the system for the first time, which the best of repeated builds,
reusing memory the process already holds, does not. raykernel single:
precision "single" (the vertices rounded to float32, float32 triangle blocks;
the peers store float32). held: the process's resident
memory after the build less before it, a triangle (0 where the build
reused memory the process already held) (the structure and what the
library copied: embreex copies the triangles in float32, Open3D its vertices
and faces); for raykernel also RayScene.stats' own count of its arrays.
SAH: the tree's cost (traversal 1, a triangle test 1) from the build's own
statistics. Casting: 1M coherent (one pinhole camera) and 1M incoherent rays
(origins uniform in the mesh's box, uniform directions), raykernel's closest
hit with t and prim_id. --big adds the 20M-triangle icosphere (subdivision
10) at medium quality. Writes the `meshbuild` section of BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _report import DETAILS, machine, replace_section, subtable  # noqa: E402
from raycast import camera_rays, obj_triangles, random_rays, scene_triangles  # noqa: E402

MESHES = {"stadium": ("scene", "stadium"), "icosphere(6)": ("ico", 6), "tetra-sf8": ("spd", "tetra:8"),
          "icosphere(8)": ("ico", 8), "icosphere(9)": ("ico", 9)}
BIG = {"icosphere(10)": ("ico", 10)}
RAYS = 1_000_000
# the summary in BENCHMARKS.md: the default quality's rows and Open3D's, these columns
SUMMARY = ("The build and a first ray at the default quality (medium), in both precisions, and in Open3D, on every "
           "mesh, seconds: best of repeated builds, and the first of a fresh process (the other qualities, embreex, "
           "memory and casting speed in the full table); vs Open3D: Open3D's seconds over this row's (above 1: "
           "faster than Open3D).")
COLUMNS = ["mesh", "triangles", "library", "precision", "build + 1 ray s", "vs Open3D", "first s", "first vs Open3D",
           "own B/tri"]


def make(kind, arg):
    if kind == "ico":
        import trimesh
        m = trimesh.creation.icosphere(subdivisions=arg)
        return np.ascontiguousarray(m.vertices, np.float64), np.ascontiguousarray(m.faces, np.int64)
    import raykernel
    if kind == "scene":         # the teapot in a stadium: long thin triangles around a small dense cluster
        return obj_triangles(raykernel.load(f"scene:{arg}"))
    return scene_triangles(raykernel.load(f"spd:{arg}"))


def rss() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def timed(build, cast1, repeat=3, budget=1.0, most=30):
    """(best seconds of build + one ray, resident bytes the last build added, the last built):
    `repeat` runs, or more while they have taken less than `budget` seconds, `most` at most."""
    best, held, built = np.inf, 0, None
    start = time.perf_counter()
    runs = 0
    while runs < repeat or (runs < most and time.perf_counter() - start < budget):
        runs += 1
        built = None
        before = rss()
        t0 = time.perf_counter()
        built = build()
        cast1(built)
        best = min(best, time.perf_counter() - t0)
        held = rss() - before
    return best, held, built


def worker(lib, arrays, threads, qualities):
    """The rows of library `lib` on the mesh saved in `arrays`, in this process (see the docstring)."""
    with np.load(arrays) as mesh:
        name, v, f = str(mesh["name"]), mesh["v"], mesh["f"]
    one_o, one_d = np.array([[0.0, 0.0, 1e3]]), np.array([[0.0, 0.0, -1.0]])
    rows = []
    if lib == "raykernel":
        t0 = time.perf_counter()
        from raykernel import RayScene
        RayScene.from_mesh(v, f, threads=threads).intersect(one_o, one_d, threads=threads)
        first = time.perf_counter() - t0
        import numba
        numba.set_num_threads(threads)
        small = make("ico", 2)
        rays = (("coherent", camera_rays(v, RAYS)), ("incoherent", random_rays(v, RAYS, np.random.default_rng(5))))
        for q, precision in [(q, "double") for q in qualities] + [("medium", "single")]:
            RayScene.from_mesh(*small, quality=q, precision=precision).intersect(one_o, one_d)       # warm
            seconds, held, rs = timed(lambda: RayScene.from_mesh(v, f, quality=q, threads=threads, precision=precision),
                                      lambda s: s.intersect(one_o, one_d, threads=threads),
                                      1 if len(f) > 6e6 or q == "high" else 3)
            st = rs.stats
            rates = {}
            for kind, (o, d) in rays:
                rs.intersect(o[:1000], d[:1000], threads=threads, fields=("t", "prim_id"))
                t0 = time.perf_counter()
                rs.intersect(o, d, threads=threads, fields=("t", "prim_id"))
                rates[kind] = len(o) / (time.perf_counter() - t0) / 1e6
            rows.append(dict(lib=f"raykernel {q}", precision=precision, mesh=name, triangles=len(f), seconds=seconds,
                             held=held / len(f), own=st["bytes_per_triangle"], sah=st["sah_cost"], **rates))
            if (q, precision) == ("medium", "double"):
                rows[-1]["first"] = first
        rows[-1]["peak_gb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 / 2 ** 30
    elif lib == "embreex":
        t0 = time.perf_counter()
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh as EmbreeMesh

        def build():
            scene = rtcore_scene.EmbreeScene()
            EmbreeMesh(scene, v.astype(np.float32), f.astype(np.int32))
            return scene
        o32, d32 = one_o.astype(np.float32), one_d.astype(np.float32)
        build().run(o32, d32, output=1)
        first = time.perf_counter() - t0
        seconds, held, _ = timed(build, lambda s: s.run(o32, d32, output=1))
        rows.append(dict(lib="embreex", precision="single", mesh=name, triangles=len(f), seconds=seconds,
                         held=held / len(f), first=first))
    else:
        t0 = time.perf_counter()
        import open3d as o3d

        def build():
            scene = o3d.t.geometry.RaycastingScene(nthreads=threads)
            scene.add_triangles(v.astype(np.float32), f.astype(np.uint32))
            return scene
        ray = o3d.core.Tensor(np.concatenate([one_o, one_d], 1).astype(np.float32))
        build().cast_rays(ray, nthreads=threads)
        first = time.perf_counter() - t0
        seconds, held, _ = timed(build, lambda s: s.cast_rays(ray, nthreads=threads))
        rows.append(dict(lib="open3d", precision="single", mesh=name, triangles=len(f), seconds=seconds,
                         held=held / len(f), first=first))
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--big", action="store_true", help="add the 20M-triangle icosphere (medium quality only)")
    ap.add_argument("--meshes", nargs="*", default=None)
    ap.add_argument("--no-write", action="store_true")
    ap.add_argument("--worker", nargs=3, help=argparse.SUPPRESS)
    ap.add_argument("--qualities", default="fast,medium,high", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        lib, arrays, out = args.worker
        Path(out).write_text(json.dumps(worker(lib, arrays, args.threads, args.qualities.split(","))))
        return
    names = args.meshes or list(MESHES) + (list(BIG) if args.big else [])
    rows = []
    for name in names:
        v, f = make(*{**MESHES, **BIG}[name])
        for lib in ("raykernel", "embreex", "open3d"):
            if name in BIG and lib != "raykernel":
                continue
            qualities = "medium" if name in BIG else ("fast,medium,high" if "(9)" not in name else "fast,medium")
            with tempfile.TemporaryDirectory() as tmp:      # the worker starts with numpy and the mesh alone
                arrays, out = Path(tmp) / "mesh.npz", Path(tmp) / "rows.json"
                np.savez(arrays, name=name, v=v, f=f)
                cmd = ["taskset", "-c", f"0-{args.threads - 1}", sys.executable, __file__, "--threads",
                       str(args.threads), "--qualities", qualities, "--worker", lib, str(arrays), str(out)]
                subprocess.run(cmd, check=True)
                got = json.loads(out.read_text())
            for r in got:
                print(r, flush=True)
            rows += got
    lines = ["## Mesh builds (raykernel vs embreex and Open3D)", "",
             f"Machine: {machine()}.", "", f"Command: `.venv/bin/python bench/meshbuild.py --threads {args.threads}"
             f"{' --big' if args.big else ''}` ({time.strftime('%Y-%m-%d')})", ""]
    table = ["| mesh | triangles | library | precision | build + 1 ray s | vs Open3D | first s | first vs Open3D | "
             "held B/tri | own B/tri | SAH | coherent Mrays/s | incoherent Mrays/s |",
             "|---|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    o3d = {r["mesh"]: r for r in rows if r["lib"] == "open3d"}
    peaks = []
    nan = float("nan")
    for r in rows:
        if "peak_gb" in r:
            peaks.append(f"{r['mesh']} {r['peak_gb']:.1f} GiB")
        peer = o3d.get(r["mesh"], {})
        ratio = peer.get("seconds", nan) / r["seconds"]
        first_ratio = peer.get("first", nan) / r.get("first", nan)
        table.append(f"| {r['mesh']} | {r['triangles']:,} | {r['lib']} | {r['precision']} | {r['seconds']:.3f} | "
                     f"{ratio:.2f} | {r.get('first', nan):.3f} | {first_ratio:.2f} | {r['held']:.0f} | "
                     f"{r.get('own', nan):.0f} | {r.get('sah', nan):.1f} | {r.get('coherent', nan):.2f} | "
                     f"{r.get('incoherent', nan):.2f} |".replace("nan", ""))
    lines += [SUMMARY, "", *subtable(table, COLUMNS, {"library": ["raykernel medium", "open3d"]}), "", DETAILS, "",
              __doc__.split("\n\n")[2].replace("\n", " "), "", *table, ""]
    lines.append("vs Open3D: Open3D's seconds over this row's (above 1: faster than Open3D). Mrays/s at "
                 f"{args.threads} threads, 1,000,000 rays each. Peak resident memory of raykernel's process "
                 f"(making the mesh, every build and the casts): {', '.join(peaks)}.")
    text = "\n".join(lines)
    print(text)
    if not args.no_write:
        replace_section("meshbuild", text)


if __name__ == "__main__":
    main()

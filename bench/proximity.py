"""Point queries: RayScene.contains and closest_points against Open3D and trimesh, same points, same threads.

    .venv/bin/python bench/proximity.py [--points 200000] [--threads 2]

For each closed mesh, the same random points in its box (5% margin) go to
raykernel (`RayScene.contains`, `RayScene.closest_points`), Open3D's
`RaycastingScene` (`compute_occupancy`, `compute_closest_points`, on as
many threads) and trimesh (`mesh.contains` with its ray_triangle engine,
`trimesh.proximity.closest_point`; single-threaded, so on a tenth of the
points against raykernel on 1 thread on the same points). Best of 2
runs, after one warm-up call each. agree: the fraction of points on which the inside answers are equal; |d|: the largest
difference of the distances (Open3D works in float32). `contains` is
called as a user calls it (method="auto": one parity ray a point on a
closed mesh, the winding number on one with holes); the `winding` row
times method="winding" on every mesh, against closest_points' time, and
its agreement with the parity answer. Writes the
`proximity` section of BENCHMARKS.md; a peer that does not install is left
out and named.
"""

from __future__ import annotations

import argparse
import sys
import time
from datetime import date
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _report import DETAILS, machine, replace_section, spd_file, subtable, tables  # noqa: E402

# the summary in BENCHMARKS.md: the first table's times and ratios (columns by place: their headers
# name the thread count)
SUMMARY = ("Seconds, best of 2; ratio = peer seconds / raykernel seconds (above 1: raykernel is faster); "
           "trimesh, which has one thread, against raykernel on 1 thread and a tenth of the points.")
COLUMNS = [0, 2, 3, 4, 5, 7, 8, 9]


def best(fn, repeat=2):
    fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def meshes():
    import trimesh
    out = {"icosphere-20k": trimesh.creation.icosphere(subdivisions=5),
           "torus": trimesh.creation.torus(major_radius=1.0, minor_radius=0.3, major_sections=128,
                                           minor_sections=64)}
    out["teapot-sf6"] = trimesh.load(spd_file("teapot", 6, ".obj"), force="mesh")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=200_000)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    import numba
    import trimesh

    from raykernel import RayScene
    from raykernel.casting.proximity import is_closed
    numba.set_num_threads(args.threads)
    try:
        import open3d as o3d
    except ImportError:
        o3d = None
    rng = np.random.default_rng(1)
    rows = []
    small = trimesh.creation.icosphere(subdivisions=2)      # every kernel compiled before the first timing
    RayScene.from_trimesh(small).contains(small.vertices * 0.5, threads=args.threads)
    for name, mesh in meshes().items():
        lo, hi = mesh.bounds
        pad = 0.05 * (hi - lo)
        p = rng.uniform(lo - pad, hi + pad, (args.points, 3))
        # from the mesh to the first answer, every build included (the BVH, a closed mesh's occupancy grid)
        t0 = time.perf_counter()
        RayScene.from_trimesh(mesh).contains(p, threads=args.threads)          # numba set to args.threads above
        rk_first = time.perf_counter() - t0
        rs = RayScene.from_trimesh(mesh)
        t_in, inside = best(lambda: rs.contains(p, threads=args.threads))
        t_cp, near = best(lambda: rs.closest_points(p, threads=args.threads))
        t_w, wound = best(lambda: rs.contains(p, threads=args.threads, method="winding"))
        parity = rs.contains(p, threads=args.threads, method="parity")
        row = dict(mesh=name, faces=len(mesh.faces), points=len(p), rk_in=t_in, rk_cp=t_cp, rk_w=t_w,
                   w_agree=float(np.mean(wound == parity)), method="parity" if is_closed(rs) else "winding",
                   rk_first=rk_first)
        if o3d is not None:
            def o3d_scene():
                scene = o3d.t.geometry.RaycastingScene(nthreads=args.threads)
                scene.add_triangles(o3d.core.Tensor(np.asarray(mesh.vertices, np.float32)),
                                    o3d.core.Tensor(np.asarray(mesh.faces, np.uint32)))
                return scene
            q = o3d.core.Tensor(p.astype(np.float32))
            t0 = time.perf_counter()
            o3d_scene().compute_occupancy(q, nthreads=args.threads).numpy()     # its BVH is built by the first query
            row["o3d_first"] = time.perf_counter() - t0
            scene = o3d_scene()
            row["o3d_in"], occ = best(lambda: scene.compute_occupancy(q, nthreads=args.threads).numpy())
            row["o3d_cp"], cp = best(lambda: scene.compute_closest_points(q, nthreads=args.threads))
            row["o3d_agree"] = float(np.mean((occ > 0.5) == inside))
            d_o3d = np.linalg.norm(cp["points"].numpy().astype(float) - p, axis=1)
            row["o3d_dd"] = float(np.abs(d_o3d - near.distance).max())
        # trimesh is single-threaded: against raykernel on 1 thread, on the same tenth of the points
        q = p[:max(1, len(p) // 10)]
        native = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
        row["tm_points"] = len(q)
        row["rk1_in"], _ = best(lambda: rs.contains(q, threads=1))
        row["rk1_cp"], _ = best(lambda: rs.closest_points(q, threads=1))
        row["tm_in"], tm_inside = best(lambda: native.contains(q), repeat=1)
        row["tm_agree"] = float(np.mean(tm_inside == inside[:len(q)]))
        try:
            row["tm_cp"], (_, tm_d, _) = best(lambda: trimesh.proximity.closest_point(native, q), repeat=1)
            row["tm_dd"] = float(np.abs(tm_d - near.distance[:len(q)]).max())
        except Exception as e:          # a missing optional dependency of trimesh's proximity code
            row["tm_cp_error"] = f"{type(e).__name__}: {e}"
        rows.append(row)
        print(row, flush=True)
    head = [f"Machine: {machine()}; Open3D {o3d.__version__ if o3d else 'not installed'}, "
            f"trimesh {trimesh.__version__}.", "",
            f"Command: `.venv/bin/python bench/proximity.py --points {args.points} --threads {args.threads}` "
            f"({date.today().isoformat()})", ""]
    lines = [f"{args.points:,} points uniform in each mesh's box (5% margin), the same for every library; raykernel "
             f"and Open3D on {args.threads} threads on all of them; trimesh, which has one thread, against raykernel "
             "on 1 thread on the same tenth of the points (the 1-thread column). Seconds, best of 2 after a "
             "warm-up; ratio = peer seconds / raykernel seconds "
             "(above 1: raykernel is faster). agree: equal inside answers; |d|: largest difference of the "
             "distances to the surface.", "",
             f"| mesh | faces | query | raykernel s ({args.threads} threads) | Open3D s | ratio | agree / abs(d) | "
             "raykernel s (1 thread, 1/10 of the points) | trimesh s | ratio | agree / abs(d) |",
             "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        o3d_in = (f"{r['o3d_in']:.3f} | {r['o3d_in'] / r['rk_in']:.2f} | {r['o3d_agree']:.4f}"
                  if "o3d_in" in r else "- | - | -")
        o3d_cp = (f"{r['o3d_cp']:.3f} | {r['o3d_cp'] / r['rk_cp']:.2f} | {r['o3d_dd']:.1e}"
                  if "o3d_cp" in r else "- | - | -")
        tm_cp = (f"{r['rk1_cp']:.3f} | {r['tm_cp']:.2f} | {r['tm_cp'] / r['rk1_cp']:.2f} | {r['tm_dd']:.1e}"
                 if "tm_cp" in r else f"{r['rk1_cp']:.3f} | ({r.get('tm_cp_error', 'not run')}) | - | -")
        lines.append(f"| {r['mesh']} | {r['faces']:,} | contains ({r['method']}) | {r['rk_in']:.3f} | {o3d_in} | "
                     f"{r['rk1_in']:.3f} | {r['tm_in']:.2f} | {r['tm_in'] / r['rk1_in']:.2f} | {r['tm_agree']:.4f} |")
        lines.append(f"| {r['mesh']} | {r['faces']:,} | closest_points | {r['rk_cp']:.3f} | {o3d_cp} | {tm_cp} |")
    lines += ["", "The winding number (method=\"winding\") against closest_points on the same points and threads:", "",
              "| mesh | winding s | closest_points s | winding / closest_points | agree with parity |",
              "|---|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['mesh']} | {r['rk_w']:.3f} | {r['rk_cp']:.3f} | {r['rk_w'] / r['rk_cp']:.2f} | "
                     f"{r['w_agree']:.4f} |")
    lines += ["", "contains from the mesh to the first answer on each side, every build included (raykernel: its BVH "
              "and a closed mesh's occupancy grid; Open3D: its scene and BVH), on the same points and threads:", "",
              "| mesh | raykernel first call s | Open3D first call s | ratio |", "|---|---:|---:|---:|"]
    for r in rows:
        o3d = f"{r['o3d_first']:.3f} | {r['o3d_first'] / r['rk_first']:.2f}" if "o3d_first" in r else "- | -"
        lines.append(f"| {r['mesh']} | {r['rk_first']:.3f} | {o3d} |")
    text = "\n".join(head + [SUMMARY, "", *subtable(tables(lines)[0], COLUMNS), "", DETAILS, ""] + lines)
    print(text)
    if not args.no_write:
        replace_section("proximity", "## Point queries (raykernel vs Open3D and trimesh)\n\n" + text)


if __name__ == "__main__":
    main()

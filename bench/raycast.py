"""Ray casting speed: raykernel.RayScene against embreex, coherent and incoherent rays.

    .venv/bin/python bench/raycast.py [--rays 1000000]

Each thread count runs in its own process pinned to that many cores
(taskset), so Embree's TBB pool and numba's pool get the same cores. Writes
the `raycast` section of BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _report import SHARED_SPD, machine, replace_section  # noqa: E402

SPD_MESHES = ["gears-sf4", "mount-sf6", "teapot-sf6", "tetra-sf6"]


def meshes():
    import trimesh
    out = {}
    s = trimesh.creation.icosphere(subdivisions=6)
    out["sphere-80k"] = (np.asarray(s.vertices, float), np.asarray(s.faces, np.int64))
    for name in SPD_MESHES:
        path = SHARED_SPD / f"{name}.obj"
        if path.exists():
            m = trimesh.load(path, force="mesh", process=False)
            out[name] = (np.asarray(m.vertices, float), np.asarray(m.faces, np.int64))
    return out


def camera_rays(v, n):
    lo, hi = v.min(axis=0), v.max(axis=0)
    c, r = (lo + hi) / 2, np.linalg.norm(hi - lo) / 2
    eye = c + r * np.array([1.3, -2.1, 1.1])
    fwd = (c - eye) / np.linalg.norm(c - eye)
    right = np.cross(fwd, [0, 0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    k = int(np.sqrt(n))
    s = np.linspace(-0.45, 0.45, k)
    x, y = np.meshgrid(s, s)
    d = fwd + x.reshape(-1, 1) * right + y.reshape(-1, 1) * up
    return np.tile(eye, (len(d), 1)), d / np.linalg.norm(d, axis=1)[:, None]


def random_rays(v, n, rng):
    lo, hi = v.min(axis=0), v.max(axis=0)
    o = rng.uniform(lo, hi, (n, 3))
    d = rng.normal(size=(n, 3))
    return o, d / np.linalg.norm(d, axis=1)[:, None]


def best_of(fn, repeat=2):
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def worker(n_rays, threads):
    import numba
    numba.set_num_threads(threads)
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh as EmbreeMesh

    from raykernel import RayScene
    rng = np.random.default_rng(0)
    rows = []
    for name, (v, f) in meshes().items():
        t0 = time.perf_counter()
        rs = RayScene.from_mesh(v, f)
        build_rk = time.perf_counter() - t0
        t0 = time.perf_counter()
        es = rtcore_scene.EmbreeScene()
        EmbreeMesh(es, v[f].astype(np.float32))
        build_em = time.perf_counter() - t0
        for kind in ("coherent", "incoherent"):
            o, d = camera_rays(v, n_rays) if kind == "coherent" else random_rays(v, n_rays, rng)
            o32, d32 = o.astype(np.float32), d.astype(np.float32)
            rs.intersect(o[:1000], d[:1000])
            sec_rk, h = best_of(lambda: rs.intersect(o, d))
            es.run(o32[:1000], d32[:1000], output=1)
            sec_em, e = best_of(lambda: es.run(o32, d32, output=1))
            hit_rk = np.isfinite(h.t)
            hit_em = np.asarray(e["geomID"]) != -1
            t_em = np.asarray(e["tfar"], float)
            same = hit_rk == hit_em
            both = hit_rk & hit_em
            same[both] = np.abs(h.t[both] - t_em[both]) <= 1e-5 * np.maximum(np.abs(h.t[both]), 1e-30)
            rows.append(dict(mesh=name, tris=len(f), kind=kind, rays=len(o), threads=threads,
                             rk=len(o) / sec_rk / 1e6, em=len(o) / sec_em / 1e6, agree=float(same.mean()),
                             hit=float(hit_rk.mean()), build_rk=build_rk, build_em=build_em,
                             tests=rs.last_stats.get("tests.triangle", 0) / len(o),
                             nodes=rs.last_stats.get("cells.visited", 0) / len(o)))
    print(json.dumps(rows))


JIT_SNIPPET = ("import time; t=time.perf_counter(); import numpy as np; from raykernel import RayScene; "
               "s=RayScene.from_mesh(np.eye(3), [(0,1,2)]); s.intersect(np.zeros(3), np.ones(3)); "
               "s.count_hits(np.zeros(3), np.ones(3)); print(time.perf_counter()-t)")


def jit_times():
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        run = lambda: float(subprocess.run([sys.executable, "-c", JIT_SNIPPET], env=env, capture_output=True,
                                           text=True, check=True).stdout.split()[-1])
        return run(), run()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--rays", type=int, default=1_000_000)
    ap.add_argument("--worker", action="store_true")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--no-report", action="store_true")
    args = ap.parse_args()
    if args.worker:
        worker(args.rays, args.threads)
        return
    rows = []
    for threads in (1, 2):
        cmd = ["taskset", "-c", f"0-{threads - 1}", sys.executable, __file__, "--worker", "--threads", str(threads),
               "--rays", str(args.rays)]
        out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
        rows += json.loads(out.strip().splitlines()[-1])
    cold, warm = jit_times()
    import embreex
    lines = [f"Machine: {machine()}; embreex {getattr(embreex, '__version__', '4.4.0.post1')} (Embree 4, float32).",
             "", f"Command: `.venv/bin/python bench/raycast.py --rays {args.rays}`", "",
             f"{args.rays} rays per set (coherent: one pinhole camera, square grid; incoherent: origins uniform in the "
             "mesh's box, uniform random directions); closest hit with t, ids, uv and normals for raykernel, "
             "closest hit (output=1) for embreex; best of 2 runs. Each thread count runs in a process pinned to "
             "that many cores with taskset. agree: same hit/miss and |t - t_embree| <= 1e-5 t.", "",
             "| mesh | triangles | rays | threads | raykernel Mrays/s | embreex Mrays/s | ratio | agree | "
             "tests/ray | nodes/ray |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['mesh']} | {r['tris']} | {r['kind']} | {r['threads']} | {r['rk']:.2f} | {r['em']:.2f} | "
                     f"{r['rk'] / r['em']:.2f} | {r['agree']:.4f} | {r['tests']:.1f} | {r['nodes']:.1f} |")
    lines += ["", f"JIT compile in a fresh process (import, build a 1-triangle scene, intersect and count_hits): "
              f"cold {cold:.1f} s (empty NUMBA_CACHE_DIR), warm {warm:.1f} s (from the cache)."]
    text = "\n".join(lines)
    print(text)
    if not args.no_report:
        replace_section("raycast", "## Ray casting (raykernel vs embreex)\n\n" + text)


if __name__ == "__main__":
    main()

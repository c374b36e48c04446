"""Ray casting speed: raykernel.RayScene against embreex, coherent and incoherent rays, same rays, same threads.

    .venv/bin/python bench/raycast.py [--rays 1000000]

Each thread count runs in its own process pinned to that many cores
(taskset). embreex's run() is single-threaded (it releases the GIL), so at
2 threads it runs on two Python threads over halves of the rays, as many
threads as raykernel's. raykernel is asked for the outputs embreex returns, in
float32 (PEER_FIELDS); its default call (every field, float64) has a column of its
own. Mitsuba 3 (llvm variant) and Open3D run on the same
rays with their own thread counts set to the same number, where they install
(pip install -e '.[bench]'; Open3D needs Debian's libusb-1.0-0); the table
says why where one does not. Writes the `raycast` section of BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from datetime import date
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _report import DETAILS, machine, replace_section, spd_file, subtable, tables  # noqa: E402

SPD_MESHES = ["gears-sf4", "mount-sf6", "teapot-sf6", "tetra-sf6"]
# what embreex's run(output=1) returns (tfar, primID, geomID, u, v, Ng, float32), asked of raykernel in float32
PEER_FIELDS = ("t", "prim_id", "geom_id", "uv", "normal")
# the summary in BENCHMARKS.md: the table's rows at 2 threads, these columns
SUMMARY = ("At 2 threads, Mrays/s of the same outputs on both sides (t, ids, uv and normal in float32); "
           "ratio = raykernel / peer (above 1: raykernel is faster). raykernel: precision \"double\" (the "
           "default: the vertices as given); single: precision \"single\" (vertices rounded to float32 and "
           "float32 triangle blocks, as Embree stores a mesh). The peers are all single precision.")
COLUMNS = ["mesh", "rays", "raykernel Mrays/s", "embreex Mrays/s", "ratio", "single Mrays/s", "single ratio",
           "mitsuba Mrays/s", "single vs mitsuba", "open3d Mrays/s", "single vs open3d"]


def scene_triangles(scene) -> tuple[np.ndarray, np.ndarray]:
    """Every polygon (fan-triangulated) and mesh triangle of a scene, in world space."""
    from raykernel.scene.convert import walk
    verts, faces, n = [], [], 0
    for group, m, _ in walk(scene):
        for s in group.primitive_sets():
            if s.kind in ("polygon", "patch"):
                v = s.vertices
                tri = np.concatenate([np.stack([np.full(c - 2, a), a + np.arange(1, c - 1), a + np.arange(2, c)], 1)
                                      for a, c in zip(s.start, s.count)])
            elif s.kind == "triangle":
                v, tri = s.vertices, s.faces
            else:
                raise ValueError(f"{s.kind} is not made of triangles")
            verts.append(v @ m[:3, :3].T + m[:3, 3])
            faces.append(tri + n)
            n += len(v)
    return np.concatenate(verts), np.concatenate(faces).astype(np.int64)


def obj_triangles(scene) -> tuple[np.ndarray, np.ndarray]:
    """A scene as triangles through our OBJ export (spheres and cones tessellated), loaded by trimesh."""
    import io

    import trimesh

    from raykernel.scene.convert import scene_to_obj
    obj, _ = scene_to_obj(scene)
    m = trimesh.load(io.StringIO(obj), file_type="obj", force="mesh", process=False)
    return np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)


def _load_obj(path):
    import trimesh
    m = trimesh.load(path, force="mesh", process=False)
    return np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)


def _icosphere():
    import trimesh
    s = trimesh.creation.icosphere(subdivisions=6)
    return np.asarray(s.vertices, float), np.asarray(s.faces, np.int64)


MESHES = {
    "sphere-80k": _icosphere,
    **{name: (lambda name=name: _load_obj(spd_file(name.split("-sf")[0], int(name.split("-sf")[1]), ".obj")))
       for name in SPD_MESHES},
    "tetra-sf10": lambda: scene_triangles(__import__("raykernel").load("spd:tetra:10")),   # 4^10 triangles
    "stadium": lambda: obj_triangles(__import__("raykernel").load("scene:stadium")),     # teapot in a stadium
}


def meshes(names=None):
    return {name: make() for name, make in MESHES.items() if names is None or name in names}


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


def embree_run(scene, o32, d32, threads):
    """Closest hits by embreex on `threads` Python threads, each over its share of the rays:
    embreex's run() is single-threaded and releases the GIL. Returns (geomID, tfar)."""
    if threads == 1:
        e = scene.run(o32, d32, output=1)
        return np.asarray(e["geomID"]), np.asarray(e["tfar"], float)
    from concurrent.futures import ThreadPoolExecutor
    cuts = np.linspace(0, len(o32), threads + 1).astype(int)
    with ThreadPoolExecutor(threads) as pool:
        parts = list(pool.map(lambda k: scene.run(o32[cuts[k]:cuts[k + 1]], d32[cuts[k]:cuts[k + 1]], output=1),
                              range(threads)))
    return (np.concatenate([np.asarray(p["geomID"]) for p in parts]),
            np.concatenate([np.asarray(p["tfar"], float) for p in parts]))


def peers(threads):
    """The optional peers that install here: name -> (build(v, f) -> scene, cast(scene, o32, d32) -> t with inf
    on a miss), and name -> why not for those that do not."""
    ready, missing = {}, {}
    try:
        import mitsuba as mi
        mi.set_variant("llvm_ad_rgb")
        import drjit as dr
        dr.set_thread_count(threads)

        def mi_build(v, f):
            mesh = mi.Mesh("mesh", len(v), len(f))
            params = mi.traverse(mesh)
            params["vertex_positions"] = dr.ravel(mi.Point3f(v.astype(np.float32).T))
            params["faces"] = dr.ravel(mi.Vector3u(f.astype(np.uint32).T))
            params.update()
            return mi.load_dict({"type": "scene", "mesh": mesh})

        def mi_cast(scene, o32, d32):
            # the full closest hit, as the others give it: t, the primitive, uv and the shading normal
            si = scene.ray_intersect(mi.Ray3f(mi.Point3f(o32.T), mi.Vector3f(d32.T)))
            dr.eval(si.t, si.prim_index, si.uv, si.n)       # one kernel for all four
            np.asarray(si.prim_index), np.asarray(si.uv), np.asarray(si.n)
            return np.asarray(si.t, float)      # inf on a miss

        ready["mitsuba"] = (mi_build, mi_cast)
    except Exception as e:      # not installed, or no LLVM for its llvm variant
        missing["mitsuba"] = f"{type(e).__name__}: {e}"
    try:
        import open3d as o3d

        def o3d_build(v, f):
            scene = o3d.t.geometry.RaycastingScene(nthreads=threads)
            scene.add_triangles(v.astype(np.float32), f.astype(np.uint32))
            return scene

        def o3d_cast(scene, o32, d32):
            out = scene.cast_rays(o3d.core.Tensor(np.concatenate([o32, d32], 1)), nthreads=threads)
            return out["t_hit"].numpy().astype(float)

        ready["open3d"] = (o3d_build, o3d_cast)
    except Exception as e:
        missing["open3d"] = f"{type(e).__name__}: {e}"
    return ready, missing


def worker(data_path, threads):
    import numba
    numba.set_num_threads(threads)
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh as EmbreeMesh

    from raykernel import RayScene
    data = np.load(data_path)
    rows = []
    others, missing = peers(threads)
    for name in data["names"]:
        v, f = data[f"{name}/v"], data[f"{name}/f"]
        built = {peer: build(v, f) for peer, (build, _) in others.items()}
        t0 = time.perf_counter()
        rs = RayScene.from_mesh(v, f)
        build_rk = time.perf_counter() - t0
        single = RayScene.from_mesh(v, f, precision="single")
        t0 = time.perf_counter()
        es = rtcore_scene.EmbreeScene()
        EmbreeMesh(es, v[f].astype(np.float32))
        build_em = time.perf_counter() - t0
        for kind in ("coherent", "incoherent"):
            o, d = data[f"{name}/{kind}/o"], data[f"{name}/{kind}/d"]
            o32, d32 = o.astype(np.float32), d.astype(np.float32)
            rs.intersect(o[:1000], d[:1000], fields=PEER_FIELDS, dtype="float32")
            sec_rk, _ = best_of(lambda: rs.intersect(o, d, fields=PEER_FIELDS, dtype="float32"))
            stats = rs.last_stats
            single.intersect(o[:1000], d[:1000], fields=PEER_FIELDS, dtype="float32")
            sec_single, h_single = best_of(lambda: single.intersect(o, d, fields=PEER_FIELDS, dtype="float32"))
            rays_single = single.last_stats.get("rays.cast", 0)
            rs.intersect(o[:1000], d[:1000])
            sec_every, h = best_of(lambda: rs.intersect(o, d))      # the default: every field in float64
            # what the mesh kernel brings: the same rays through the generic traversal
            # (every aggregate kind, nesting, instances)
            mesh, rs._mesh = rs._mesh, None
            rs.intersect(o[:1000], d[:1000], fields=PEER_FIELDS, dtype="float32")
            sec_generic, _ = best_of(lambda: rs.intersect(o, d, fields=PEER_FIELDS, dtype="float32"), repeat=1)
            rs._mesh = mesh
            # the same mesh kernel on the binary tree the 4-wide one is collapsed from
            narrow = RayScene.from_mesh(v, f, accel="bvh(width=2)")
            narrow.intersect(o[:1000], d[:1000], fields=PEER_FIELDS, dtype="float32")
            sec_binary, _ = best_of(lambda: narrow.intersect(o, d, fields=PEER_FIELDS, dtype="float32"), repeat=1)
            nodes_binary = narrow.last_stats.get("cells.visited", 0) / len(o)
            es.run(o32[:1000], d32[:1000], output=1)
            sec_em, (geom_em, t_em) = best_of(lambda: embree_run(es, o32, d32, threads))
            hit_rk = np.isfinite(h.t)
            hit_em = geom_em != -1
            same = hit_rk == hit_em
            both = hit_rk & hit_em
            same[both] = np.abs(h.t[both] - t_em[both]) <= 1e-5 * np.maximum(np.abs(h.t[both]), 1e-30)
            hit_single = np.isfinite(h_single.t)
            same_single = hit_single == hit_em
            both = hit_single & hit_em
            same_single[both] = np.abs(h_single.t[both] - t_em[both]) <= 1e-5 * np.maximum(np.abs(t_em[both]), 1e-30)
            peer_rates, answered = {}, {}
            for peer, (_, cast) in others.items():
                cast(built[peer], o32[:1000], d32[:1000])
                sec, t_peer = best_of(lambda: cast(built[peer], o32, d32))
                t_peer = np.where(t_peer < 1e30, t_peer, np.inf)
                hit_p = np.isfinite(t_peer)
                agree = hit_rk == hit_p
                both_p = hit_rk & hit_p
                agree[both_p] = np.abs(h.t[both_p] - t_peer[both_p]) <= 1e-5 * np.maximum(np.abs(h.t[both_p]), 1e-30)
                peer_rates[peer] = (len(o) / sec / 1e6, float(agree.mean()))
                answered[peer] = len(t_peer)
            rows.append(dict(mesh=str(name), tris=len(f), kind=kind, rays=len(o), threads=threads, peers=peer_rates,
                             missing=missing,
                             rk=len(o) / sec_rk / 1e6, em=len(o) / sec_em / 1e6, agree=float(same.mean()),
                             every=len(o) / sec_every / 1e6, single=len(o) / sec_single / 1e6,
                             agree_single=float(same_single.mean()),
                             cast=", ".join(str(n) for n in (stats.get("rays.cast", 0), rays_single, len(t_em),
                                                              *answered.values())),
                             bytes=rs.build_stats["bytes_per_triangle"],
                             bytes_single=single.build_stats["bytes_per_triangle"],
                             generic=len(o) / sec_generic / 1e6, binary=len(o) / sec_binary / 1e6,
                             nodes_binary=nodes_binary, bounds=stats.get("bounds.tests", 0) / len(o),
                             hit=float(hit_rk.mean()), build_rk=build_rk, build_em=build_em,
                             tests=stats.get("tests.triangle", 0) / len(o),
                             nodes=stats.get("cells.visited", 0) / len(o)))
    print(json.dumps(rows))


def prepare(path, n_rays, names):
    """The meshes and both ray sets, saved once so every process casts exactly the same rays."""
    rng = np.random.default_rng(0)
    arrays, kept = {}, []
    for name, (v, f) in meshes(names).items():
        kept.append(name)
        arrays[f"{name}/v"], arrays[f"{name}/f"] = v, f
        arrays[f"{name}/coherent/o"], arrays[f"{name}/coherent/d"] = camera_rays(v, n_rays)
        arrays[f"{name}/incoherent/o"], arrays[f"{name}/incoherent/d"] = random_rays(v, n_rays, rng)
    np.savez(path, names=np.array(kept), **arrays)


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
    ap.add_argument("--meshes", default=None, help="comma-separated subset of the meshes")
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--no-report", action="store_true")
    args = ap.parse_args()
    if args.worker:
        worker(args.worker, args.threads)
        return
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        data = f"{tmp}/rays.npz"
        prepare(data, args.rays, args.meshes.split(",") if args.meshes else None)
        for threads in (1, 2):
            cmd = ["taskset", "-c", f"0-{threads - 1}", sys.executable, __file__, "--worker", data,
                   "--threads", str(threads)]
            out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
            rows += json.loads(out.strip().splitlines()[-1])
    cold, warm = jit_times()
    import embreex
    command = f".venv/bin/python bench/raycast.py --rays {args.rays}" + (f" --meshes {args.meshes}" if args.meshes else "")
    head = [f"Machine: {machine()}; embreex {getattr(embreex, '__version__', '4.4.0.post1')} (Embree 4, float32).",
            "", f"Command: `{command}` ({date.today().isoformat()})", ""]
    lines = [f"{args.rays} rays per set (coherent: one pinhole camera, square grid; incoherent: origins uniform in the "
             "mesh's box, uniform random directions), the same rays for both libraries and both thread counts; "
             "the same outputs from both: the closest hit's t, triangle and mesh ids, uv and geometric normal in "
             "float32, from embreex's run(output=1) and from raykernel's `RayScene.intersect(o, d, fields=(\"t\", "
             "\"prim_id\", \"geom_id\", \"uv\", \"normal\"), dtype=\"float32\")` (input checks included; "
             "raykernel computes in float64 and stores float32); every field: raykernel's default call, every field "
             "of Hits in float64 (also instance, kind and shading normal: 104 bytes a ray against 32). "
             "embreex's run() is single-threaded and releases the GIL: at 2 threads "
             "it runs on two Python threads over halves of the rays; best of 2 runs. Each thread count runs in a "
             "process pinned to that many cores with taskset, so both libraries get the same cores. agree: same "
             "hit/miss and |t - t_embree| <= 1e-5 t. raykernel casts through its mesh kernel (meshcast.py) on the "
             "4-wide BVH (the default, bvh(width=4)); width 2: the same kernel on the binary tree it is collapsed "
             "from (bvh(width=2)), one run; generic: "
             "raykernel through the general traversal (traverse.py) instead of the mesh kernel, one run. "
             "tests/ray: triangle tests; boxes/ray: child boxes tested (4-wide: one per used child slot of "
             "each node visited); nodes/ray: 4-wide nodes visited, and binary nodes with width 2; ns/node: a ray's "
             "time on one thread (threads / raykernel Mrays/s) over the 4-wide nodes it visits, its triangle tests "
             "included: where incoherent rays' time goes, next to coherent rays' on the same tree.",
             "",
             "Mitsuba 3 (variant llvm_ad_rgb, `scene.ray_intersect`, Embree underneath, its thread count "
             "set with drjit) and Open3D (`RaycastingScene.cast_rays`, nthreads) on the same rays, float32, "
             "conversions from numpy included as for the others; Mitsuba's ray_intersect gives t, the primitive "
             "index, uv and the shading normal (evaluated in one kernel, all four copied out), Open3D's cast_rays t, "
             "ids, uv and normals; ratio = raykernel / peer (above 1: raykernel is "
             "faster); agree against raykernel's t as for embreex.",
             "",
             "single: the same call on `RayScene.from_mesh(v, f, precision=\"single\")` (vertices rounded to "
             "float32, float32 triangle blocks; the same watertight test in float64 on the rounded corners), its "
             "ratio against embreex (and, single vs mitsuba and open3d, against those) and its agreement with embreex; bytes/tri: the kernel's arrays a triangle "
             "(double, single). rays cast: the rays each side answered (raykernel's rays.cast counter, double "
             "and single, then embreex's, Mitsuba's and Open3D's answers). per core: incoherent Mrays/s of one thread (threads = 1 rows), beside tinybvh's "
             "published 4.7 (BVH8, float32) and 4.0 (double) Mrays/s a core for incoherent rays, measured on "
             "its author's machine (not this one).",
             "",
             "| mesh | triangles | rays | threads | raykernel Mrays/s | every field Mrays/s | embreex Mrays/s | "
             "ratio | agree | single Mrays/s | single ratio | single agree | bytes/tri | "
             "mitsuba Mrays/s | ratio | single vs mitsuba | agree | open3d Mrays/s | ratio | single vs open3d | agree | "
             "width 2 Mrays/s | generic Mrays/s | tests/ray | boxes/ray | nodes/ray | nodes/ray width 2 | ns/node | "
             "rays cast |",
             "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
             "---:|---:|---:|---:|---:|---:|---|"]
    for r in rows:
        cells = []
        for peer in ("mitsuba", "open3d"):
            rate, agree = r["peers"].get(peer, (None, None))
            cells += ["-"] * 4 if rate is None else [f"{rate:.2f}", f"{r['rk'] / rate:.2f}", f"{r['single'] / rate:.2f}",
                                                     f"{agree:.4f}"]
        lines.append(f"| {r['mesh']} | {r['tris']} | {r['kind']} | {r['threads']} | {r['rk']:.2f} | {r['every']:.2f} | "
                     f"{r['em']:.2f} | "
                     f"{r['rk'] / r['em']:.2f} | {r['agree']:.4f} | {r['single']:.2f} | {r['single'] / r['em']:.2f} | "
                     f"{r['agree_single']:.4f} | {r['bytes']:.0f}, {r['bytes_single']:.0f} | "
                     f"{' | '.join(cells)} | {r['binary']:.2f} | "
                     f"{r['generic']:.2f} | {r['tests']:.1f} | {r['bounds']:.1f} | {r['nodes']:.1f} | "
                     f"{r['nodes_binary']:.1f} | {r['threads'] * 1e3 / r['rk'] / max(r['nodes'], 1e-9):.0f} | {r['cast']} |")
    for peer, why in (rows[0]["missing"] if rows else {}).items():
        lines += ["", f"{peer} is not in this table: it does not run here ({why})."]
    per_core = [r for r in rows if r["threads"] == 1 and r["kind"] == "incoherent"]
    if per_core:
        lines += ["", "Per core, incoherent rays (1 thread), Mrays/s: " + "; ".join(
            f"{r['mesh']} {r['rk']:.2f} double, {r['single']:.2f} single" for r in per_core)
            + ". tinybvh publishes 4.7 (BVH8, float32) and 4.0 (double) Mrays/s a core for incoherent rays, "
              "on its author's machine, not this one."]
    lines += ["", f"JIT compile in a fresh process (import, build a 1-triangle scene, intersect and count_hits): "
              f"cold {cold:.1f} s (empty NUMBA_CACHE_DIR), warm {warm:.1f} s (from the cache)."]
    text = "\n".join(head + [SUMMARY, "", *subtable(tables(lines)[0], COLUMNS, {"threads": ["2"]}), "", DETAILS, ""]
                     + lines)
    print(text)
    if not args.no_report:
        replace_section("raycast", "## Ray casting (raykernel vs embreex, Mitsuba 3 and Open3D)\n\n" + text)


if __name__ == "__main__":
    main()

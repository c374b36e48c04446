"""Where an incoherent ray's time goes in the mesh kernel: the nodes it visits against the fewest any
order could, and a node visit's cost as the rays lose their coherence, one thread.

    .venv/bin/python bench/incoherent.py [--rays 300000] [--meshes teapot-sf6,sphere-80k]

For each mesh of bench/raycast.py (the same incoherent rays: origins uniform in the mesh's box,
uniform random directions), in both precisions of RayScene.from_mesh (double: the vertices as
given, float64 triangle blocks; single: rounded to float32, float32 blocks, as embreex stores them):

* visited: the 4-wide nodes the kernel visits a ray (its cells.visited counter);
* needed: the 4-wide nodes whose box the ray enters before its closest hit (or at all, on a
  miss), counted by a walk that takes every such node: no order of the children can visit fewer,
  since any of them may hold a closer hit;
* ns/ray of the incoherent rays and of the repeated ones (below), raykernel's and embreex's (the
  outputs embreex returns, float32, as bench/raycast.py asks them);
* ns/node for three ray sets of the same size, closest hits with every field, one thread, best of
  five: the incoherent rays; their origins with one direction for all (the direction's signs and
  dominant axis the same for every ray, so the branches on them are predicted); and the first
  REPEATED of the incoherent rays, each cast n / REPEATED times in a row (each ray's path taken
  over and over: its nodes in cache and its branches learned, the floor for such paths).

Writes the `incoherent` section of BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from datetime import date
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _report import machine, replace_section  # noqa: E402
from raycast import MESHES, PEER_FIELDS, embree_run, meshes, random_rays  # noqa: E402

from raykernel.aggregates.widebvh import CHILD, COUNT, box4_entries, wide_ray  # noqa: E402
from raykernel.geometry.boxes import inverse  # noqa: E402
from raykernel.geometry.config import njit  # noqa: E402

DIRECTION = np.array([1.0, 2.0, 3.0]) / np.sqrt(14.0)
REPEATED = 64


@njit
def needed_nodes(nodes, center, o, d, t_hit, out):
    """out[r]: the 4-wide nodes whose box ray r enters within [0, t_hit[r]] (the kernel's own box test)."""
    t4 = np.empty(4)
    stack = np.empty(4096, np.int64)
    for r in range(o.shape[0]):
        wx, wy, wz, vx, vy, vz, near = wide_ray(center, o[r, 0], o[r, 1], o[r, 2], inverse(d[r, 0]),
                                                inverse(d[r, 1]), inverse(d[r, 2]))
        stack[0] = 0
        sp, n = 1, 0
        while sp > 0:
            sp -= 1
            v = stack[sp]
            n += 1
            mask = box4_entries(nodes, v, wx, wy, wz, vx, vy, vz, near, 0.0, t_hit[r], t4)
            for s in range(4):
                if mask & (1 << s) and nodes[v, COUNT + s] == 0:
                    stack[sp] = nodes[v, CHILD + s]
                    sp += 1
        out[r] = n


def best_ns(cast, n):
    """ns a ray of cast() over n rays, best of 5, after one call to warm it; and its last answer."""
    cast()
    best = np.inf
    for _ in range(5):
        t0 = time.perf_counter()
        answer = cast()
        best = min(best, time.perf_counter() - t0)
    return best / n * 1e9, answer


def timed(rs, o, d):
    """(ns a ray, 4-wide nodes visited a ray, hits) of closest hits of every ray, one thread."""
    ns, hits = best_ns(lambda: rs.intersect(o, d, threads=1), len(o))
    return ns, rs.last_stats.get("cells.visited", 0) / len(o), hits


def against_embree(rs, scene, o, d):
    """The same rays and outputs (embreex's, float32) on one thread: raykernel's and embreex's ns a
    ray, the rays each cast (raykernel's rays.cast counter, embreex's answers), and the share of rays
    on which both give the same hit or miss and t within 1e-5 t."""
    o32, d32 = o.astype(np.float32), d.astype(np.float32)
    rk_ns, hits = best_ns(lambda: rs.intersect(o, d, fields=PEER_FIELDS, dtype="float32", threads=1), len(o))
    rk_rays = rs.last_stats.get("rays.cast", 0)
    em_ns, (geom, t_em) = best_ns(lambda: embree_run(scene, o32, d32, 1), len(o))
    hit_rk, hit_em = np.isfinite(hits.t), geom != -1
    same = hit_rk == hit_em
    both = hit_rk & hit_em
    t_rk = hits.t.astype(float)
    same[both] = np.abs(t_rk[both] - t_em[both]) <= 1e-5 * np.maximum(np.abs(t_rk[both]), 1e-30)
    return rk_ns, em_ns, rk_rays, len(geom), float(same.mean())


def measure(name, v, f, n, precision):
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh

    from raykernel import RayScene
    o, d = random_rays(v, n, np.random.default_rng(1))
    rs = RayScene.from_mesh(v, f, threads=1, precision=precision)
    scene = rtcore_scene.EmbreeScene()
    TriangleMesh(scene, v[f].astype(np.float32))
    ns, visited, hits = timed(rs, o, d)
    needed = np.empty(n, np.int64)
    needed_nodes(*rs._mesh.wide, o, d, np.where(np.isfinite(hits.t), hits.t, np.inf), needed)
    row = dict(mesh=name, precision=precision, tris=len(f), visited=visited, needed=needed.mean(),
               incoherent=ns / visited)
    row["rk_ns"], row["em_ns"], row["rk_rays"], row["em_rays"], row["agree"] = against_embree(rs, scene, o, d)
    ro, rd = np.repeat(o[:REPEATED], n // REPEATED, axis=0), np.repeat(d[:REPEATED], n // REPEATED, axis=0)
    row["rk_rep_ns"], row["em_rep_ns"], *_ = against_embree(rs, scene, ro, rd)
    ns, visited, _ = timed(rs, o, np.tile(DIRECTION, (n, 1)))
    row["one_d"] = ns / visited
    ns, visited, _ = timed(rs, ro, rd)
    row["repeated"] = ns / visited
    return row


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--rays", type=int, default=300_000)
    ap.add_argument("--meshes", default=None, help="comma-separated subset of bench/raycast.py's meshes")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    import numba
    numba.set_num_threads(1)
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})     # both libraries on the same one core
    names = args.meshes.split(",") if args.meshes else list(MESHES)
    rows = []
    for name, (v, f) in meshes(names).items():
        for precision in ("double", "single"):
            rows.append(measure(name, v, f, args.rays, precision))
            print(rows[-1], flush=True)
    command = "`.venv/bin/python bench/incoherent.py" + (f" --rays {args.rays}" if args.rays != 300_000 else "") + \
        (f" --meshes {args.meshes}" if args.meshes else "") + f"` ({date.today().isoformat()})"
    lines = ["## Incoherent rays: where the time goes", "", f"Machine: {machine()}.", "", f"Command: {command}", "",
             f"{args.rays:,} rays a set, one thread, closest hits with every field, best of 5. visited: 4-wide nodes "
             "the mesh kernel visits a ray; needed: those whose box the ray enters before its closest hit, which "
             "any order of the children must visit. ns/node: a ray's time (its triangle tests and outputs "
             "included) over the nodes it visits, for the incoherent rays (bench/raycast.py's), for their origins "
             f"with one direction, and for the first {REPEATED} of them each cast {args.rays // REPEATED:,} times "
             "in a row (the same paths, in cache and predicted). ns/ray: the incoherent rays and the repeated ones "
             "with the outputs embreex returns (float32), raykernel's and embreex's, the process pinned to one core; "
             "ratio: embreex's time over raykernel's; rays: the incoherent rays each cast (raykernel's rays.cast "
             "counter / embreex's answers); agree: same hit or miss and t within 1e-5 t. precision: RayScene's "
             "(double: the vertices as given; single: rounded to float32, as embreex stores them).", "",
             "| mesh | triangles | precision | rays | agree | ns/ray | embreex ns/ray | ratio | repeated ns/ray | "
             "embreex | ratio | visited | needed | ns/node incoherent | one direction | repeated |",
             "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['mesh']} | {r['tris']:,} | {r['precision']} | {r['rk_rays']:,} / {r['em_rays']:,} | "
                     f"{r['agree']:.4f} | "
                     f"{r['rk_ns']:.0f} | {r['em_ns']:.0f} | "
                     f"{r['em_ns'] / r['rk_ns']:.2f} | {r['rk_rep_ns']:.0f} | {r['em_rep_ns']:.0f} | "
                     f"{r['em_rep_ns'] / r['rk_rep_ns']:.2f} | {r['visited']:.2f} | {r['needed']:.2f} | "
                     f"{r['incoherent']:.1f} | {r['one_d']:.1f} | {r['repeated']:.1f} |")
    text = "\n".join(lines)
    print(text)
    if not args.no_write:
        replace_section("incoherent", text)


if __name__ == "__main__":
    main()

"""Trace time of this tree against another revision, in the same run on the same machine.

    .venv/bin/python bench/against.py --rev HEAD~1 [--resolution 128] [--repeat 3] [--scenes balls,teapot]

The other revision is checked out into a temporary git worktree and imported
from there (PYTHONPATH), this tree from src/. Both sides render the same
scenes with the same kinds in SPD mode, each in its own warm process (kernels
compiled before timing), alternating revision by revision for every round;
the table gives the best trace seconds of each side and their ratio, and
checks that both sides made the same image bytes and the same ray counts; the
primitive tests of each side are printed beside them (a walk that visits
the tree in another order, as the 4-wide one does, makes other tests before
an any-hit query stops). The last rows time RayScene.intersect (the mesh kernel) on 512 x 512
coherent and incoherent rays against an 80k-triangle sphere and SPD teapot,
checking the same t and triangle ids. Writes the `against` section of
BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from datetime import date
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _report import DETAILS, ROOT, machine, replace_section  # noqa: E402

KINDS = ("list", "bvh", "bvh(build=gs)", "grid", "hgrid", "octree", "octree(walk=point)", "octree(walk=parametric)",
         "hybrid", "lazyoctree", "rc")
SCENES = ("balls", "gears", "teapot", "tetra", "stadium")

CHILD = r"""
import hashlib, json, sys, time
import numba
import numpy as np
import raykernel
scenes, kinds, res, repeat = json.loads(sys.argv[1])
out = {}
warm = raykernel.load("spd:balls:1")
for k in kinds:
    raykernel.render(warm, accel=k, resolution=8, spd=True)
for name in scenes:
    scene = raykernel.load("scene:stadium" if name == "stadium" else f"spd:{name}")
    for k in kinds:
        if k == "list" and name not in ("balls",):
            continue
        best = None
        for _ in range(repeat):
            r = raykernel.render(scene, accel=k, resolution=res, spd=True)
            best = r.stats["time.trace"] if best is None else min(best, r.stats["time.trace"])
        counts = {c: v for c, v in r.stats.items() if c.startswith(("rays.eye", "rays.reflect", "rays.refract",
                                                                      "rays.shadow")) and isinstance(v, int)}
        counts["threads"] = r.stats.info["threads"]
        out[f"{name}|{k}"] = dict(trace=best, image=hashlib.sha1(np.ascontiguousarray(r.image).tobytes()).hexdigest(),
                                  counts=counts, tests=int(r.stats["tests.total"]))
# the mesh kernel: RayScene.intersect on meshes, coherent (a camera) and incoherent (random) rays
rng = np.random.default_rng(7)
import trimesh
for name, mesh in (("sphere-80k", trimesh.creation.icosphere(subdivisions=6)),
                   ("teapot", raykernel.load("spd:teapot"))):
    rs = raykernel.RayScene.from_mesh(mesh.vertices, mesh.faces) if hasattr(mesh, "faces") else \
        raykernel.RayScene(mesh)
    n = 512 * 512
    u, v = np.meshgrid(np.linspace(-0.6, 0.6, 512), np.linspace(-0.6, 0.6, 512))
    lo, hi = (np.array([-1.0] * 3), np.array([1.0] * 3)) if hasattr(mesh, "faces") else (None, None)
    if lo is None:
        b = rs.geo.agg_bounds[rs.geo.root]
        lo, hi = b[:3], b[3:]
    c, r = (lo + hi) / 2, np.linalg.norm(hi - lo) / 2
    coherent = (np.tile(c + [0.0, -3.0 * r, 0.0], (n, 1)),
                np.stack([u.ravel() * r, np.full(n, 3.0 * r), v.ravel() * r], 1))
    o = c + rng.normal(size=(n, 3)) * r
    incoherent = (o, c + rng.uniform(-0.5, 0.5, (n, 3)) * r - o)
    rs.intersect(*coherent)
    for label, (o, d) in (("coherent", coherent), ("incoherent", incoherent)):
        best = None
        for _ in range(repeat):
            t0 = time.perf_counter()
            h = rs.intersect(o, d)
            dt = time.perf_counter() - t0
            best = dt if best is None else min(best, dt)
        out[f"{name} {label}|RayScene.intersect"] = dict(
            trace=best, image=hashlib.sha1(np.ascontiguousarray(h.t).tobytes() + h.prim_id.tobytes()).hexdigest(),
            counts={"rays.cast": int(n), "hits": int(np.isfinite(h.t).sum()), "threads": numba.get_num_threads()},
            tests=int(sum(v for c, v in rs.last_stats.items() if c.startswith("tests.") and isinstance(v, int))))
print(json.dumps(out))
"""


def run_side(src: Path, args) -> dict:
    env = dict(os.environ, PYTHONPATH=str(src))
    payload = json.dumps([args.scenes.split(","), args.kinds.split(","), args.resolution, args.repeat])
    out = subprocess.run([sys.executable, "-c", CHILD, payload], env=env, capture_output=True, text=True)
    if out.returncode:
        sys.exit(f"{src}: {out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rev", default="HEAD~1", help="the revision to compare against")
    ap.add_argument("--resolution", type=int, default=128)
    ap.add_argument("--repeat", type=int, default=3, help="renders per side and round; the best counts")
    ap.add_argument("--rounds", type=int, default=2, help="alternations of the two sides")
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--kinds", default=",".join(KINDS))
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    rev = subprocess.run(["git", "rev-parse", "--short", args.rev], cwd=ROOT, capture_output=True, text=True,
                         check=True).stdout.strip()
    with tempfile.TemporaryDirectory() as tmp:
        other = Path(tmp) / "other"
        subprocess.run(["git", "worktree", "add", "--detach", str(other), rev], cwd=ROOT, check=True,
                       capture_output=True)
        try:
            sides = {"other": [], "this": []}
            for _ in range(args.rounds):
                sides["other"].append(run_side(other / "src", args))
                sides["this"].append(run_side(ROOT / "src", args))
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(other)], cwd=ROOT, capture_output=True)
    lines = ["## This tree against an earlier revision",
             "",
             f"`{('python bench/against.py ' + ' '.join(sys.argv[1:])).strip()}` ({date.today().isoformat()}): "
             "SPD mode at "
             f"{args.resolution}x{args.resolution}, best trace seconds of {args.repeat} renders x {args.rounds} "
             f"alternating rounds per side; ratio = {rev} / this tree (above 1: this tree is faster). Both sides "
             "made the same image bytes and the same ray counts (checked); the primitive tests of each side are "
             "beside them.",
             "", f"Machine: {machine()}.", "", DETAILS, "",
             f"| scene | structure | rays ({rev}) | rays (this) | tests ({rev}) | tests (this) | threads | "
             f"{rev} trace s | this trace s | ratio |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    ratios = []
    for key in sides["this"][0]:
        a = [r[key] for r in sides["other"]]
        b = [r[key] for r in sides["this"]]
        if a[0]["image"] != b[0]["image"] or a[0]["counts"] != b[0]["counts"]:
            diff = {c: (a[0]["counts"].get(c), v) for c, v in b[0]["counts"].items() if a[0]["counts"].get(c) != v}
            sys.exit(f"{key}: the two revisions differ: image {a[0]['image'] == b[0]['image']}, counts {diff}")
        ta, tb = min(x["trace"] for x in a), min(x["trace"] for x in b)
        ratios.append(ta / tb)
        scene, kind = key.split("|")
        ca, cb = a[0]["counts"], b[0]["counts"]
        rays_a = sum(v for c, v in ca.items() if c.startswith("rays.") and not c.endswith(("_hit", "_blocked")))
        rays_b = sum(v for c, v in cb.items() if c.startswith("rays.") and not c.endswith(("_hit", "_blocked")))
        lines.append(f"| {scene} | `{kind}` | {rays_a:,} | {rays_b:,} | {a[0].get('tests', 0):,} | "
                     f"{b[0].get('tests', 0):,} | {cb['threads']} | {ta:.3f} | {tb:.3f} | {ta / tb:.2f} |")
        print(lines[-1], flush=True)
    verdict = (f"Ratios from {min(ratios):.2f} to {max(ratios):.2f}, geometric mean "
               f"{(__import__('math').prod(ratios)) ** (1 / len(ratios)):.2f}.")
    lines[lines.index(DETAILS):lines.index(DETAILS)] = [verdict, ""]     # the summary: that line alone
    print(verdict)
    if not args.no_write:
        replace_section("against", "\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

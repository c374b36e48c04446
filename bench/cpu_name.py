"""What NUMBA_CPU_NAME=generic costs: kernels compiled for any x86-64 against kernels for this processor.

    .venv/bin/python bench/cpu_name.py [--rounds 5]

A Docker image or a cluster that shares one kernel cache (NUMBA_CACHE_DIR) between machines of
different processors needs kernels that run on all of them: NUMBA_CPU_NAME=generic compiles for
the baseline x86-64 instruction set, without the vector extensions of the machine at hand. For
each setting this script fills an empty cache in a fresh process (compile seconds), then times,
in a second process that loads that cache, an SPD render and a mesh ray cast (best of --rounds),
so both sides do the same work: the same image and the same rays. Writes the `cpu_name` section
of BENCHMARKS.md.
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
from _report import machine, replace_section  # noqa: E402

CHILD = """
import json, sys, time
import numpy as np
import raykernel
rounds = int(sys.argv[1])
t0 = time.perf_counter()
scene = raykernel.load("spd:balls")
render = lambda: raykernel.render(scene, accel="bvh", resolution=512, spd=True)
first = render()
import trimesh
mesh = trimesh.creation.icosphere(subdivisions=6)
rs = raykernel.RayScene.from_mesh(mesh.vertices, mesh.faces)
rng = np.random.default_rng(1)
n = 1_000_000
origins = rng.uniform(-2, 2, (n, 3))
directions = rng.normal(size=(n, 3))
hits = rs.intersect(origins, directions)
start = time.perf_counter() - t0
trace = min(render().stats["time.trace"] for _ in range(rounds))
cast = []
for _ in range(rounds):
    t = time.perf_counter()
    rs.intersect(origins, directions)
    cast.append(time.perf_counter() - t)
print(json.dumps({"start": start, "render_trace": trace, "cast": min(cast), "rays": int(first.stats["rays.total"]),
                  "cast_rays": n, "hits": int(np.isfinite(hits.t).sum())}))
"""


def run(cpu: str, cache: str, rounds: int) -> dict:
    env = dict(os.environ, NUMBA_CACHE_DIR=cache)
    env.pop("NUMBA_CPU_NAME", None)
    if cpu != "host":
        env["NUMBA_CPU_NAME"] = cpu
    out = subprocess.run([sys.executable, "-c", CHILD, str(rounds)], env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    rows = {}
    for cpu in ("host", "generic"):
        with tempfile.TemporaryDirectory() as cache:
            cold = run(cpu, cache, 1)                     # fills the empty cache
            warm = run(cpu, cache, args.rounds)           # loads it, then times the work
        rows[cpu] = {"cold": cold["start"], **warm}
        print(cpu, rows[cpu], flush=True)
    host, generic = rows["host"], rows["generic"]
    assert host["rays"] == generic["rays"] and host["hits"] == generic["hits"], "the two settings did different work"
    lines = [
        "## NUMBA_CPU_NAME=generic: kernels for any x86-64",
        "",
        f"`.venv/bin/python bench/cpu_name.py --rounds {args.rounds}` ({date.today().isoformat()}). "
        f"Machine: {machine()}.",
        "",
        f"SPD balls (sf 4) at 512x512 with `--spd` ({host['rays']:,} rays on both sides) and {host['cast_rays']:,} "
        f"incoherent rays at an 82k-triangle icosphere ({host['hits']:,} hits on both sides), best of {args.rounds}, "
        "each setting with its own cache; first call: the whole first process on an empty cache (compiles included); "
        "ratio: generic's seconds over this processor's (above 1: generic is slower).",
        "",
        "| NUMBA_CPU_NAME | first call s | render trace s | cast s |",
        "|---|---:|---:|---:|",
    ]
    for cpu, r in rows.items():
        lines.append(f"| {cpu if cpu != 'host' else '(unset: this processor)'} | {r['cold']:.1f} | "
                     f"{r['render_trace']:.3f} | {r['cast']:.3f} |")
    lines.append(f"| ratio | {generic['cold'] / host['cold']:.2f} | {generic['render_trace'] / host['render_trace']:.2f} | "
                 f"{generic['cast'] / host['cast']:.2f} |")
    replace_section("cpu_name", "\n".join(lines))


if __name__ == "__main__":
    main()

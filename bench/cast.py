"""Ray casting past one process: `raykernel cast` on a file of a billion rays, and on Dask.

    .venv/bin/python bench/cast.py [--rays 1000000000] [--triangles 1000000] [--batch 10000000]
                                   [--worker-rays 20000000] [--folder bench/.cache/cast] [--small] [--no-write]

One run, four questions, on one mesh (a height field of --triangles triangles, written as PLY) and
incoherent rays (origins above it, directions at random downward; float32 .npy, written once,
a block at a time, into --folder, which needs the disk for them, RAY_BYTES a ray, and HIT_BYTES a ray
for the hits):

1. Memory: `raykernel cast MESH --rays RAYS.npy --out HITS.zarr --fields t,prim_id --dtype float32`
   in a process of its own, the resident memory of its process tree sampled every 50 ms; its peak.
2. Speed: the cast's rays a second (its own casting time: reading, casting, writing; build and
   kernel loading apart) against one in-process `RayScene.intersect` of the first --batch rays of
   the same file, held in memory as float64, same fields, dtype and threads; both ray counts are
   printed, and the in-process hits equal the cast's first --batch hits bit for bit (checked).
3. Workers: the first --worker-rays rays cast on `local:1` and `local:2`, one thread a worker;
   both outputs are the same bytes (checked); each worker's kernel compiling and loading apart.
4. Dask's cost per chunk: tasks that do nothing on two workers (the scheduler's time a task), and
   a chunk's whole fixed cost on a one-thread worker (chunks of a few rays on local:1); from them and the
   single-threaded worker's speed, the chunk size that keeps both under 1% of a chunk's time, and
   the expected time of ten billion rays on 64 such workers, with the limits named.

Also: sending the scene to a worker built (pickled) against building it there from its triangles.
Writes the `cast` section of BENCHMARKS.md (not with --no-write); --small runs every step on small
inputs (a check of the script, not a measurement).
"""

from __future__ import annotations

import argparse
import os
import pickle
import re
import shutil
import subprocess
import sys
import time
from datetime import date
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _report import CACHE, DETAILS, machine, replace_section  # noqa: E402

FIELDS, DTYPE = ("t", "prim_id"), "float32"
RAY_BYTES, HIT_BYTES = 24, 8    # a ray in the file (six float32), its hits (float32 t, int32 prim_id)
TOTAL, WORKERS = 1e10, 64       # the projection's rays and one-thread workers
SHARES = 16                     # chunks of the local:1 / local:2 casts: eight a worker, to balance
SCHEDULER_SHARE = 0.1           # of the scheduler's time the projection may take: it has a core of its own
BLOCK = 10_000_000          # rays generated a block at a time


def height_field(triangles: int):
    """A k x k grid of wavy heights: about `triangles` triangles in [0, 1]^2."""
    k = max(2, int(np.sqrt(triangles / 2)) + 1)
    x, y = np.meshgrid(np.linspace(0, 1, k), np.linspace(0, 1, k))
    v = np.c_[x.ravel(), y.ravel(), 0.1 * np.sin(9 * x.ravel()) * np.cos(7 * y.ravel())]
    q = (np.arange(k - 1)[:, None] * k + np.arange(k - 1)[None]).ravel()
    return v, np.concatenate([np.c_[q, q + 1, q + k], np.c_[q + 1, q + k + 1, q + k]])


def write_mesh(path: Path, triangles: int):
    import trimesh
    v, f = height_field(triangles)
    if not path.exists():
        trimesh.Trimesh(v, f, process=False).export(path)
    return v, f


def write_rays(path: Path, n: int) -> None:
    """n incoherent rays as float32 (n, 6), a block at a time (seeded by block: the same file each time)."""
    if path.exists() and np.load(path, mmap_mode="r").shape == (n, 6):
        return
    out = np.lib.format.open_memmap(path.with_suffix(".tmp.npy"), mode="w+", dtype=np.float32, shape=(n, 6))
    for a in range(0, n, BLOCK):
        b = min(n, a + BLOCK)
        rng = np.random.default_rng(a)
        out[a:b, :2] = rng.uniform(-0.2, 1.2, (b - a, 2))
        out[a:b, 2] = rng.uniform(0.3, 1.0, b - a)
        out[a:b, 3:5] = rng.normal(0, 0.5, (b - a, 2))
        out[a:b, 5] = -1.0
        out.flush()
    del out
    os.replace(path.with_suffix(".tmp.npy"), path)


def first_rays(path: Path, n: int, to: Path) -> Path:
    """A file of the first n rays of `path`."""
    if not to.exists() or np.load(to, mmap_mode="r").shape[0] != n:
        np.save(to, np.load(path, mmap_mode="r")[:n])
    return to


def command_cast(mesh: Path, rays: Path, out: Path, threads: int) -> dict:
    """`raykernel cast` in a process of its own: its report line's figures and the peak resident memory
    of its process tree."""
    import psutil
    shutil.rmtree(out, ignore_errors=True)
    cmd = [sys.executable, "-m", "raykernel", "cast", str(mesh), "--rays", str(rays), "--out", str(out), "--fields",
           ",".join(FIELDS), "--dtype", DTYPE, "--threads", str(threads)]
    start = time.perf_counter()
    child = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    top, peak = psutil.Process(child.pid), 0
    while child.poll() is None:
        try:
            procs = [top] + top.children(recursive=True)
            peak = max(peak, sum(p.memory_info().rss for p in procs))
        except psutil.Error:
            pass
        time.sleep(0.05)
    stdout, stderr = child.communicate()
    if child.returncode:
        sys.exit(f"raykernel cast failed:\n{stderr}")
    found = re.search(r"cast ([\d,]+) now .* in ([\d.]+) s", stdout)
    kernels = re.search(r"chunk\(s\)\) in ([\d.]+) s", stdout)       # the worker line: its kernels' own seconds
    return {"rays": int(found.group(1).replace(",", "")), "seconds": float(found.group(2)), "peak": peak,
            "kernels": float(kernels.group(1)), "wall": time.perf_counter() - start,
            "command": " ".join(["raykernel"] + cmd[3:])}


def load_rays(rays: Path, n: int):
    """The first n rays of the file, in memory as float64 origins and directions."""
    block = np.load(rays, mmap_mode="r")[:n].astype(np.float64)
    return np.ascontiguousarray(block[:, :3]), np.ascontiguousarray(block[:, 3:])


def in_process(scene, o, d, threads: int, times: int = 3) -> dict:
    """RayScene.intersect of these rays, same fields, dtype and threads as the command: the median of
    `times` calls (not the best: the command runs once)."""
    scene.intersect(o[:1000], d[:1000], fields=FIELDS, dtype=DTYPE, threads=threads)
    seconds = []
    for _ in range(times):
        start = time.perf_counter()
        hits = scene.intersect(o, d, fields=FIELDS, dtype=DTYPE, threads=threads)
        seconds.append(time.perf_counter() - start)
    return {"rays": len(o), "seconds": float(np.median(seconds)), "hits": hits}


def same_hits(hits, out: Path) -> None:
    import zarr
    written = zarr.open_group(out, mode="r")
    if not all(np.array_equal(getattr(hits, f), written[f][:len(hits.t)]) for f in FIELDS):
        sys.exit("the cast's hits differ from the in-process call's")


def alternating(scene, mesh: Path, rays: Path, folder: Path, threads: int, rounds: int = 3) -> list:
    """The command and the in-process call on the same rays (a file that fits in memory), one after
    the other, `rounds` times: (command seconds, in-process seconds, in-process rays, command rays) a round. Side by side in
    time, so the machine's drift (this one is shared) meets both alike."""
    o, d = load_rays(rays, np.load(rays, mmap_mode="r").shape[0])
    out = folder / "alternating.zarr"
    pairs = []
    for _ in range(rounds):     # a run of each side a round, so neither takes the best of several
        command = command_cast(mesh, rays, out, threads)
        alone = in_process(scene, o, d, threads, times=1)
        same_hits(alone["hits"], out)
        if command["rays"] != alone["rays"]:
            sys.exit("the command and the in-process call cast different numbers of rays")
        pairs.append((command["seconds"], alone["seconds"], alone["rays"], command["rays"]))
    shutil.rmtree(out, ignore_errors=True)
    return pairs


def on_workers(scene, rays: Path, folder: Path, workers: int, chunk: int) -> dict:
    """The rays cast on local:N, one thread a worker, in chunks of `chunk`."""
    from raykernel.casting.castfile import cast_file
    from raykernel.cluster import Cluster
    out = folder / f"workers-{workers}.zarr"
    shutil.rmtree(out, ignore_errors=True)
    with Cluster(f"local:{workers}") as cluster:
        report = cast_file(scene, rays, out, fields=FIELDS, dtype=DTYPE, threads=1, cluster=cluster, chunk=chunk)
    return {"report": report, "out": out}


def dask_cost(tasks: int) -> float:
    """Seconds of the scheduler a task: `tasks` tasks that do nothing on two one-thread workers."""
    import distributed
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=None,
                                  silence_logs=40) as local, distributed.Client(local) as client:
        client.gather(client.map(abs, range(100), pure=False))
        start = time.perf_counter()
        client.gather(client.map(abs, range(tasks), pure=False))
        return (time.perf_counter() - start) / tasks


def chunk_cost(scene, rays: Path, folder: Path, n: int, chunk: int) -> float:
    """A chunk's fixed cost on a one-thread worker of local:1 (Dask's hand-over, opening, reading,
    writing): n rays in chunks of `chunk` (a few rays), its seconds a chunk."""
    from raykernel.casting.castfile import cast_file
    from raykernel.cluster import Cluster
    out = folder / "tiny.zarr"
    shutil.rmtree(out, ignore_errors=True)
    with Cluster("local:1") as cluster:
        report = cast_file(scene, first_rays(rays, n, folder / "tiny.npy"), out, fields=FIELDS, dtype=DTYPE,
                           threads=1, chunk=chunk, cluster=cluster)
    shutil.rmtree(out, ignore_errors=True)
    return report.seconds / report.chunks


def sending(scene, vertices, faces) -> dict:
    """Seconds to pickle and unpickle the built scene (and its bytes) against building it from its triangles."""
    from raykernel import RayScene
    start = time.perf_counter()
    data = pickle.dumps(scene, protocol=5)
    pickle.loads(data)
    sent = time.perf_counter() - start
    start = time.perf_counter()
    RayScene.from_mesh(vertices, faces, threads=1)
    built = time.perf_counter() - start
    from raykernel.casting.sharedscene import SharedScene
    start = time.perf_counter()
    with SharedScene.write(scene) as shared:
        written = time.perf_counter() - start
        start = time.perf_counter()
        shared.open()
        opened = time.perf_counter() - start
    return {"sent": sent, "bytes": len(data), "built": built, "triangle_bytes": vertices.nbytes + faces.nbytes,
            "written": written, "opened": opened}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rays", type=float, default=1e9)
    ap.add_argument("--triangles", type=float, default=1e6)
    ap.add_argument("--batch", type=float, default=1e7, help="rays of the in-process call")
    ap.add_argument("--worker-rays", type=float, default=2e7, help="rays of the local:1 and local:2 casts")
    ap.add_argument("--folder", default=str(CACHE / "cast"), help="where the mesh, rays and hits are written")
    ap.add_argument("--small", action="store_true", help="small inputs: a check of the script")
    ap.add_argument("--no-write", action="store_true", help="print the section, leave BENCHMARKS.md alone")
    args = ap.parse_args()
    if args.small:
        args.rays, args.triangles, args.batch, args.worker_rays = 2e6, 1e5, 1e6, 1e6
    n, batch, worker_rays = int(args.rays), int(min(args.batch, args.rays)), int(min(args.worker_rays, args.rays))
    threads = os.cpu_count() or 1
    folder = Path(args.folder)
    folder.mkdir(parents=True, exist_ok=True)
    from raykernel import RayScene
    mesh = folder / f"field-{int(args.triangles)}.ply"
    vertices, faces = write_mesh(mesh, int(args.triangles))
    rays = folder / f"rays-{n}.npy"
    write_rays(rays, n)
    scene = RayScene.from_file(mesh)
    o, d = load_rays(rays, batch)
    before = in_process(scene, o, d, threads)
    command = command_cast(mesh, rays, folder / "hits.zarr", threads)
    alone = in_process(scene, o, d, threads)
    same_hits(alone["hits"], folder / "hits.zarr")
    del o, d
    alone["before"] = before["seconds"]
    few = first_rays(rays, worker_rays, folder / f"rays-{worker_rays}.npy")
    pairs = alternating(scene, mesh, few, folder, threads)
    chunk = max(1, worker_rays // SHARES)
    one, two = on_workers(scene, few, folder, 1, chunk), on_workers(scene, few, folder, 2, chunk)
    if sorted(_files(one["out"]).items()) != sorted(_files(two["out"]).items()):
        sys.exit("local:1 and local:2 wrote different bytes")
    task = dask_cost(2000)
    per_chunk = chunk_cost(scene, rays, folder, 20_000, 10)
    send = sending(scene, vertices, faces)
    text = section(args, command, alone, pairs, one["report"], two["report"], task, per_chunk, send, len(faces),
                   threads)
    print(text)
    if not args.no_write:
        replace_section("cast", text)


def _files(folder: Path) -> dict:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def _projection(rate: float, task: float, per_chunk: float) -> tuple[int, float, float]:
    """(chunk, seconds, tasks a second) for 1e10 rays on 64 one-thread workers of `rate` rays a second:
    the chunk keeps the cast's fixed cost a chunk and the scheduler's load each under 1% of a chunk's time."""
    workers, total = WORKERS, TOTAL
    # a chunk's fixed cost under 1% of its casting; the scheduler (one process) busy a SCHEDULER_SHARE of the time
    need = max(100 * per_chunk * rate, workers * task * rate / SCHEDULER_SHARE)
    chunk = 1 << int(np.ceil(np.log2(max(1.0, need))))
    seconds_per_chunk = chunk / rate + per_chunk
    return chunk, total / chunk / workers * seconds_per_chunk, workers * rate / chunk


def section(args, command, alone, pairs, one, two, task, per_chunk, send, triangles, threads) -> str:
    rate = lambda r, s: r / s / 1e6      # noqa: E731
    cast_rate, alone_rate = rate(command["rays"], command["seconds"]), rate(alone["rays"], alone["seconds"])
    before_rate = rate(alone["rays"], alone["before"])
    around = (alone_rate + before_rate) / 2         # the in-process rate before and after the long cast
    ratios = [b / a for a, b, *_ in pairs]           # in-process seconds over the command's: its rate over the call's
    one_rate, two_rate = rate(one.cast, one.seconds), rate(two.cast, two.seconds)
    chunk, seconds, asked = _projection(one_rate * 1e6, task, per_chunk)
    compile_lines = [f"| local:{len(r.workers)} | {w} | {f['compile']:.2f} | {f['load']:.2f} | {f['cast']:.2f} "
                     f"| {f['rays']:,} |" for r in (one, two) for w, f in sorted(r.workers.items())]
    small = " --small" if args.small else ""
    return "\n".join([
        "## Ray casting past one process: `raykernel cast` and Dask",
        "",
        f"Command: `.venv/bin/python bench/cast.py --rays {int(args.rays)} --triangles {int(args.triangles)} "
        f"--batch {int(args.batch)} --worker-rays {int(args.worker_rays)}{small}` ({date.today().isoformat()}). "
        f"Machine: {machine()}.",
        "",
        f"A height field of {triangles:,} triangles, incoherent rays (float32 .npy), fields {', '.join(FIELDS)} in "
        f"{DTYPE}, {threads} threads on both sides of the first rows. The in-process hits equal the cast's first "
        f"{alone['rays']:,} bit for bit; local:1 and local:2 wrote the same bytes.",
        "",
        "| run | rays (command / in-process where both) | seconds | Mrays/s | ratio | peak memory |",
        "|---|---:|---:|---:|---:|---:|",
        f"| `{command['command']}` | {command['rays']:,} | {command['seconds']:.1f} | {cast_rate:.2f} "
        f"| {cast_rate / around:.2f}x | {command['peak'] / 2 ** 30:.2f} GiB |",
        f"| one in-process `RayScene.intersect`, rays in memory, before the command (median of 3) | {alone['rays']:,} "
        f"| {alone['before']:.2f} | {before_rate:.2f} | | |",
        f"| the same, after the command | {alone['rays']:,} | {alone['seconds']:.2f} | {alone_rate:.2f} | | |",
        f"| the command and the in-process call on the same {pairs[0][2]:,} rays, one after the other, "
        f"{len(pairs)} times (median) | {pairs[0][3]:,} / {pairs[0][2]:,} | {np.median([a for a, *_ in pairs]):.2f} "
        f"| {rate(pairs[0][2], np.median([a for a, *_ in pairs])):.2f} | {np.median(ratios):.2f}x | |",
        f"| `cast_file` on local:1, one thread, chunks of {one.chunk:,} | {one.cast:,} | {one.seconds:.2f} "
        f"| {one_rate:.2f} | 1.00x | |",
        f"| `cast_file` on local:2, one thread each | {two.cast:,} | {two.seconds:.2f} | {two_rate:.2f} "
        f"| {two_rate / one_rate:.2f}x | |",
        "",
        f"ratio: the command's rays a second over the in-process call's (the billion rays: over the mean of the "
        f"calls before and after it; the rounds side by side: {', '.join(f'{r:.2f}x' for r in ratios)}). The "
        f"command's wall time, start-up, mesh loading and build included: {command['wall']:.1f} s. Its kernels "
        f"cast for {command['kernels']:.1f} s of its {command['seconds']:.1f} s of casting "
        f"({command['kernels'] / command['seconds']:.0%}; the rest is reading, writing and the ends of kernel calls "
        f"where one thread waits for the other), at {rate(command['rays'], command['kernels']):.2f} Mrays/s: "
        f"{rate(command['rays'], command['kernels']) / around:.2f}x the in-process calls' rate around it, how fast "
        f"this shared machine ran during the long cast against the short calls. Dask's "
        f"scheduler costs {1e3 * task:.2f} ms a task (tasks that do nothing, two workers); a chunk costs a "
        f"one-thread worker {1e3 * per_chunk:.2f} ms beyond its casting (Dask's hand-over, opening, reading and "
        f"writing; chunks of ten rays on local:1). For {TOTAL:.0e} rays on {WORKERS} one-thread workers of "
        f"local:1's speed: chunks of {chunk:,} rays keep that fixed cost "
        f"under 1% of a chunk's time and the scheduler busy under {SCHEDULER_SHARE:.0%} of the time, and ask "
        f"{asked:,.0f} tasks a second of the scheduler, a single process whose limit is about {1 / task:,.0f} "
        f"tasks a second here; expected time {seconds / 60:.1f} min, given a shared file system that reads "
        f"{TOTAL * RAY_BYTES / 2 ** 30:,.0f} GiB of rays and writes {TOTAL * HIT_BYTES / 2 ** 30:,.0f} GiB of hits in "
        f"that time ({TOTAL * (RAY_BYTES + HIT_BYTES) / seconds / 2 ** 30:.1f} GiB/s), the limit past the "
        f"scheduler's.",
        "",
        DETAILS,
        "",
        "Each worker's kernels, compiled or loaded (from the cache), apart from its casting:",
        "",
        "| cluster | worker | compile s | load s | cast s | rays |",
        "|---|---|---:|---:|---:|---:|",
        *compile_lines,
        "",
        f"The scene reaches a worker built: pickling and unpickling it took {send['sent']:.3f} s for "
        f"{send['bytes'] / 2 ** 20:.1f} MiB, against {send['built']:.3f} s to build it from its triangles "
        f"({send['triangle_bytes'] / 2 ** 20:.1f} MiB) on one thread; "
        f"{'sending it built is faster' if send['sent'] < send['built'] else 'building it there would be faster'}. "
        f"The workers of a local cluster instead map one file of it (casting/sharedscene.py): writing it took "
        f"{send['written']:.3f} s, once, and opening it {send['opened']:.4f} s a worker.",
    ])


if __name__ == "__main__":
    main()

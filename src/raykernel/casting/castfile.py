"""Casting the rays of a file into a file of hits, a chunk at a time: bounded memory, resumable.

    report = cast_file(scene, "rays.npz", "hits.zarr", fields=("t", "prim_id"))     # `raykernel cast`
    report = cast_file(scene, "rays.npz", "hits.zarr", cluster=cluster)   # chunks as tasks on a cluster.Cluster
    report.cast, report.seconds, report.workers      # rays cast now; wall time; per worker: compile, load, cast

The rays are cut into chunks (`chunk_size`: at most DEFAULT_CHUNK rays, fewer where the memory
budget needs it); each chunk is read, cast by RayScene.intersect with the fields asked for, and
written (rayfiles.py: the formats, and why every chunk is written whole or not at all). A
chunk already in the results is not cast again, so the same command after a kill goes on
where it stopped and ends with the same bytes as a run never stopped.

Here, the chunks are a pipeline: one is read and another written while a third is cast, each
into buffers kept from chunk to chunk. On a cluster (cluster.Cluster, passed in by the command
line: this layer does not import it) every missing chunk is a task that takes the scene's key
(each worker keeps the copy its warm-up met: on a local cluster, the one file of the built
scene that every worker maps, sharedscene.py), and each worker reads and writes its chunks
itself, into buffers it keeps for the cast. Either way, each place that casts first warms up
(`warm_up`: one ray cast and one read, a chunk's buffers made, the results opened), so the
time it spends compiling or loading the kernels is reported apart from the casting. A chunk is
cast PIECE rays a kernel call: Ctrl-C stops the chunks at work between two calls, unwritten,
and nothing else. A bad ray stops the cast with one line
naming the file, the chunk and the ray; the chunks past that one written meanwhile are
removed, so nothing lies past the last good chunk.
"""

from __future__ import annotations

import contextlib
import os
import socket
import threading
import time
import warnings
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from concurrent.futures import wait as wait_all
from dataclasses import dataclass, field

import numpy as np

from ..aggregates.memory import MemoryBudgetError, describe_bytes, memory_limit
from . import daskcast
from .rayfiles import Buffers, RayFileError, array_in, open_results, open_rays, recorded
from .rayinput import RayInputError, check_ray_values
from .rayqueries import DTYPES, FIELD_COLUMNS, FLOAT_FIELDS, Hits, field_names
from .sharedscene import SharedScene

DEFAULT_CHUNK = 1 << 20     # rays a chunk: a few tenths of a second of casting, and tens of MB
PIECE = 1 << 18             # rays a kernel call within a chunk: how soon Ctrl-C is answered (fewer calls, fewer
                            # ends of a call where one thread waits for the other)
IN_FLIGHT = 2               # chunks whose rays (and whose results) are held at once in this process
READ_BYTES = 2 * 64         # a ray's bytes as read and as converted (origin, direction, tmin, tmax)
DEFAULT_FIELDS = ("t", "prim_id")


class _Stopped(Exception):
    """A chunk left unwritten because the cast was stopped."""


@dataclass
class CastReport:
    """What a cast_file call did."""

    rays: int                   # rays in the file
    chunk: int                  # rays a chunk
    chunks: int                 # chunks in all
    skipped: int                # chunks written before this call
    cast: int                   # rays cast by this call
    seconds: float              # wall-clock time of this call's casting, warm-up excluded
    workers: dict = field(default_factory=dict)     # name -> {"compile", "load", "cast" seconds, "rays", "chunks"}

    @property
    def rays_per_second(self) -> float:
        return self.cast / self.seconds if self.seconds > 0 else 0.0


def result_fields(names, dtype: str) -> dict:
    """The results' arrays: name -> (numpy dtype, the columns a ray has)."""
    floats, ids = DTYPES[dtype]
    return {name: (np.dtype(floats if name in FLOAT_FIELDS else ids), FIELD_COLUMNS.get(name, ())) for name in names}


def chunk_size(rs, names, dtype: str, in_flight: int, max_memory=None) -> int:
    """Rays a chunk: DEFAULT_CHUNK, or fewer where `in_flight` chunks (read, converted, their
    outputs) beside the scene's structures would pass the memory budget; MemoryBudgetError where
    not even one ray fits."""
    out = sum(dt.itemsize * int(np.prod(cols)) for dt, cols in result_fields(names, dtype).values())
    per_ray = READ_BYTES + 2 * out + 16         # the outputs, a piece's own, the general kernel's identities
    room = memory_limit(max_memory) - rs.stats["bytes"]
    fit = room // (per_ray * in_flight)
    if fit < 1:
        raise MemoryBudgetError(f"casting needs {describe_bytes(rs.stats['bytes'])} of structures and "
                                f"{describe_bytes(per_ray * in_flight)} a ray beside them, past the budget of "
                                f"{describe_bytes(memory_limit(max_memory))}; raise --max-memory")
    return int(min(DEFAULT_CHUNK, fit))


def warm_up(rs, names, dtype: str, threads, source=None, out=None, buffers=None) -> dict:
    """Cast one ray with these fields: the kernels compiled or loaded now, their seconds returned.
    With `source`, `out` and `buffers` (a (rays, results) pair of Buffers), also read one ray, make
    a chunk's buffers and open the results' arrays: the first chunk then neither loads the reading
    kernel, nor imports the writer's library, nor meets its buffers' memory for the first time (a
    few tenths of a second in a fresh worker; counted as load)."""
    start = time.perf_counter()
    rs.intersect(np.zeros((1, 3)), np.array([[1.0, 0.0, 0.0]]), threads=threads, fields=names, dtype=dtype)
    stats = rs.last_stats
    figures = {"worker": _here(), "compile": stats.get("time.compile", 0.0), "load": stats.get("time.load", 0.0)}
    if source is not None and source.count:
        source.read(0, 1)
        source.reserve(out.chunk, buffers[0])
        for array in result_arrays(names, dtype, out.chunk, buffers[1]).values():
            array.fill(0)
        out.prepare()
        figures["load"] = time.perf_counter() - start - figures["compile"]
    return figures


def _here() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def read_chunk(source, out, k: int, buffers: Buffers | None = None):
    """Chunk k's rays: origins, directions, tmin and tmax (rayfiles.RaySource.read), into `buffers`
    where given; RayFileError naming the chunk where it cannot be read."""
    a, b = out.rows(k)
    try:
        return source.read(a, b, buffers)
    except RayFileError as e:
        if e.chunk is not None:
            raise
        raise RayFileError(e.message, e.path, k, (a, b)) from None
    except (OSError, ValueError) as e:
        raise RayFileError(f"cannot be read ({type(e).__name__}: {e})", source.name, k, (a, b)) from None


def result_arrays(names, dtype: str, n: int, buffers: Buffers | None = None) -> dict:
    """A chunk's results, not cleared (every ray's are written): name -> array, in `buffers` where given."""
    return {name: array_in(buffers, name, (n,) + cols, dt) for name, (dt, cols) in result_fields(names, dtype).items()}


def cast_rays(rs, source, out, k: int, rays, arrays: dict, names, dtype: str, threads=None, stop=None) -> dict:
    """Cast chunk k's rays (read_chunk's) into `arrays`, PIECE rays a kernel call; its figures (rays,
    seconds of casting, compiling and loading). `stop`: an Event that leaves the chunk unwritten
    (_Stopped) when set."""
    a, b = out.rows(k)
    o, d, lo, hi = rays
    figures = {"worker": _here(), "rays": b - a, "cast": 0.0, "compile": 0.0, "load": 0.0}
    for p in range(0, b - a, PIECE):
        if stop is not None and stop.is_set():
            raise _Stopped
        q = min(b - a, p + PIECE)
        piece = Hits(**{name: arrays[name][p:q] if name in arrays else None for name in Hits.__dataclass_fields__
                        if name not in ("origins", "directions")})
        try:
            rs.intersect(o[p:q], d[p:q], 0.0 if lo is None else lo[p:q], np.inf if hi is None else hi[p:q],
                         threads=threads, fields=names, dtype=dtype, out=piece)
        except RayInputError as e:
            try:
                check_ray_values(o[p:q], d[p:q], offset=a + p)
            except RayInputError as named:
                raise RayFileError(str(named), source.name, k, (a, b)) from None
            raise RayFileError(str(e), source.name, k, (a, b)) from None
        stats = rs.last_stats
        for name in ("compile", "load"):
            figures[name] += stats.get(f"time.{name}", 0.0)
        figures["cast"] += stats.get("time.trace", 0.0)
    if stop is not None and stop.is_set():
        raise _Stopped
    return figures


def cast_chunk(rs, source, out, k: int, names, dtype: str, threads=None, stop=None, buffers=None) -> dict:
    """Read, cast and write chunk k of `source` into `out` (a task of its own), into `buffers` (a
    (rays, results) pair of Buffers) where given; cast_rays' figures."""
    rays_in, results_in = buffers or (None, None)
    rays = read_chunk(source, out, k, rays_in)
    arrays = result_arrays(names, dtype, out.rows(k)[1] - out.rows(k)[0], results_in)
    figures = cast_rays(rs, source, out, k, rays, arrays, names, dtype, threads, stop)
    out.write(k, arrays)
    return figures


def cast_file(rs, rays, out_path, fields=None, dtype: str = "float64", threads=None, max_memory=None, cluster=None,
              progress=None, chunk: int | None = None) -> CastReport:
    """Cast every ray of the file `rays` at RayScene `rs`; the hits' `fields` into `out_path`.

    Parameters
    ----------
    rs : RayScene
        The scene.
    rays : str or path-like
        A .npz, .npy, .zarr or .parquet file of rays (rayfiles.py).
    out_path : str or path-like
        A .zarr or .parquet folder for the results: made, or resumed if an earlier run of the
        same cast made it.
    fields : sequence of str, optional
        The Hits fields to write (default DEFAULT_FIELDS); t is always among them.
    dtype : {"float64", "float32"}
        As for RayScene.intersect.
    threads : int, optional
        Threads a chunk (default: numba's count here; a local worker's share of the cores on a
        cluster).
    max_memory : int or str, optional
        The memory budget the chunks are sized to (default: half of this machine's memory).
    cluster : cluster.Cluster, optional
        Cast the chunks as tasks on it.
    progress : callable, optional
        ``progress(done, total)`` in rays, as chunks are written (chunks written before count as done).
    chunk : int, optional
        Rays a chunk, instead of chunk_size's (a resumed cast keeps the one it started with).

    Returns
    -------
    CastReport

    Raises
    ------
    RayFileError
        The file's arrays are not valid, or a ray of a chunk is not (the message names both).
    OptionError
        `out_path` holds the results of another cast, or is not a .zarr or .parquet folder.
    ClusterError
        The cluster's scheduler was lost: the chunks written so far are kept, and the same call
        goes on from them.
    """
    names = field_names(DEFAULT_FIELDS if fields is None else fields)
    if dtype not in DTYPES:
        raise RayInputError(f"dtype must be one of {', '.join(DTYPES)}, got {dtype!r}")
    source = open_rays(rays)
    before = recorded(out_path)
    if chunk is None:
        chunk = before["chunk"] if before else min(max(1, source.count), chunk_size(rs, names, dtype, IN_FLIGHT,
                                                                                   max_memory))
    about = {**source.describe(), "scene": repr(rs), "fields": list(names), "dtype": dtype, "chunk": chunk}
    out = open_results(out_path, source.count, chunk, result_fields(names, dtype), about)
    out.tidy()
    done = out.done()
    todo = [k for k in range(out.chunks) if k not in done]
    report = CastReport(rays=source.count, chunk=chunk, chunks=out.chunks, skipped=len(done), cast=0, seconds=0.0)
    written = [source.count - sum(b - a for a, b in map(out.rows, todo))]

    def finished(figures: dict) -> None:
        w = report.workers.setdefault(figures["worker"], {"compile": 0.0, "load": 0.0, "cast": 0.0, "rays": 0,
                                                          "chunks": 0})
        for name in ("compile", "load", "cast", "rays"):
            w[name] += figures.get(name, 0)
        w["chunks"] += "rays" in figures
        if "rays" in figures:
            report.cast += figures["rays"]
            written[0] += figures["rays"]
            if progress is not None:
                progress(written[0], source.count)
    if not todo:
        return report
    run = _on_cluster if cluster is not None else _here_in_threads
    run(rs, source, out, todo, names, dtype, threads, finished, report, cluster)
    out.tidy()
    return report


def _here_in_threads(rs, source, out, todo, names, dtype, threads, finished, report, cluster) -> None:
    """The chunks in this process, in order, as a pipeline: a thread reads the next chunk and
    another writes the last while this one casts (so two casts never share the cores); each of
    the IN_FLIGHT sets of buffers holds a chunk's rays and results."""
    rays_in = [Buffers() for _ in range(IN_FLIGHT)]     # a chunk's rays, one being read while one is cast
    results_in = [Buffers() for _ in range(IN_FLIGHT)]  # its results, one being written while one is cast
    finished(warm_up(rs, names, dtype, threads, source, out, (rays_in[0], results_in[0])))
    start = time.perf_counter()
    writes: deque = deque()

    def written(block: bool) -> None:
        while writes and (block or writes[0].done()):
            finished(_result(writes.popleft()))

    def write(k, arrays, figures):
        out.write(k, arrays)
        return figures

    with ThreadPoolExecutor(1, thread_name_prefix="raykernel-read") as reader, \
            ThreadPoolExecutor(1, thread_name_prefix="raykernel-write") as writer:
        try:
            reading = reader.submit(read_chunk, source, out, todo[0], rays_in[0])
            for i, k in enumerate(todo):
                rays = _result(reading)
                if i + 1 < len(todo):       # into the buffers the chunk cast before this one is done with
                    reading = reader.submit(read_chunk, source, out, todo[i + 1], rays_in[(i + 1) % IN_FLIGHT])
                while len(writes) >= IN_FLIGHT:     # these results' buffers written before they are cast into
                    finished(_result(writes.popleft()))
                a, b = out.rows(k)
                arrays = result_arrays(names, dtype, b - a, results_in[i % IN_FLIGHT])
                figures = cast_rays(rs, source, out, k, rays, arrays, names, dtype, threads)
                writes.append(writer.submit(write, k, arrays, figures))
                written(block=False)
            written(block=True)
        except BaseException as e:
            wait_all(writes)        # the chunks cast whole are written; the one at work is left unwritten
            if isinstance(e, RayFileError) and e.chunk is not None:
                out.remove_after(e.chunk)
            raise
        finally:
            report.seconds = time.perf_counter() - start


def _result(future):
    """A future's result, waited for in short steps so that Ctrl-C reaches this thread at once."""
    while True:
        try:
            return future.result(timeout=0.1)
        except TimeoutError:
            continue


# A worker's buffers, kept between the chunks of a cast that it casts (fresh memory each chunk
# costs a page fault every 4 kB), a (rays, results) pair for each task at work at once; those of
# an earlier cast are dropped as the next one starts, and cast_file drops its own at its end.
_spare: dict = {}       # results path -> [(Buffers, Buffers), ...]
_spare_lock = threading.Lock()


@contextlib.contextmanager
def _worker_buffers(out):
    with _spare_lock:
        for path in [p for p in _spare if p != out.path]:
            del _spare[path]
        pool = _spare.setdefault(out.path, [])
        pair = pool.pop() if pool else (Buffers(), Buffers())
    try:
        yield pair
    finally:
        with _spare_lock:
            _spare.setdefault(out.path, []).append(pair)


def _drop_buffers(path) -> None:
    with _spare_lock:
        _spare.pop(path, None)


def _chunk_task(key, source, out, k, names, dtype, threads, scene=None):
    # the scene this worker keeps, or the one given (a worker that did not warm up): a chunk that
    # finds neither is returned unsent, to be sent again with the scene
    rs = daskcast.kept_scene(key) if scene is None else daskcast.worker_scene(scene, key)
    if rs is None:
        return {"worker": _here(), "unsent": k}
    try:     # stopped by the results folder's stop file: a running task cannot be cancelled otherwise
        with _worker_buffers(out) as buffers:
            return cast_chunk(rs, source, out, k, names, dtype, threads, stop=out, buffers=buffers)
    except _Stopped:
        return {"worker": _here()}


def _warm_task(scene, key, names, dtype, threads, source, out):
    with _worker_buffers(out) as buffers:
        return warm_up(daskcast.worker_scene(scene, key), names, dtype, threads, source, out, buffers)


def _on_cluster(rs, source, out, todo, names, dtype, threads, finished, report, cluster) -> None:
    """The chunks as tasks on the cluster: the scene sent to each worker once (its warm-up task,
    which keeps it there), every missing chunk submitted, the results taken as they come."""
    # a local cluster's workers map one file of the built scene (sharedscene.py); others get a copy each,
    # as do a local cluster's where the temporary folder cannot take the file
    given = contextlib.nullcontext(rs)
    if cluster.local is not None:
        with contextlib.suppress(OSError):
            given = SharedScene.write(rs)
    with given as scene:
        _cast_on_cluster(scene, source, out, todo, names, dtype, threads, finished, report, cluster)


def _cast_on_cluster(given, source, out, todo, names, dtype, threads, finished, report, cluster) -> None:
    client = cluster.client
    threads = threads or cluster.threads_per_worker
    with warnings.catch_warnings():     # Dask's advice against large graphs: the scene is in it once, on purpose
        warnings.filterwarnings("ignore", message="Sending large graph")
        scene, key = cluster.share(given)
    warm = [client.submit(_warm_task, scene, key, names, dtype, threads, source, out, workers=[w],
                          allow_other_workers=False, pure=False) for w in client.scheduler_info()["workers"]]
    for _, figures in cluster.completed(warm, doing="loading the kernels on the workers"):
        finished(figures)
    start = time.perf_counter()
    # the chunks take the scene's key, not its future: every worker keeps the copy its warm-up met,
    # and the scheduler hands the chunks to whichever worker is free (daskcast.kept_scene)
    futures = [client.submit(_chunk_task, key, source, out, k, names, dtype, threads, pure=False) for k in todo]
    doing = "casting rays: the chunks written so far are kept, and the same command goes on from them"
    try:
        batch = futures
        while batch:
            unsent = []
            for _, figures in cluster.completed(batch, doing):
                if "unsent" in figures:
                    unsent.append(figures["unsent"])
                else:
                    finished(figures)
            batch = [client.submit(_chunk_task, key, source, out, k, names, dtype, threads, scene, pure=False)
                     for k in unsent]
            futures += batch
        client.run(_drop_buffers, out.path, on_error="ignore")    # (a cast that fails leaves them to the next one)
    except BaseException as e:
        bad = e.chunk if isinstance(e, RayFileError) else None
        out.stop(after=bad)         # before the cancel: tasks at work stop between kernel calls, unwritten
        if client.status == "running":      # (a lost scheduler has nothing to cancel, nor answers)
            client.cancel(futures)
        raise
    finally:
        report.seconds = time.perf_counter() - start

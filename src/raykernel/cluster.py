"""Renders that span processes and machines, on Dask distributed (``pip install raykernel[distributed]``).

::

    from raykernel.cluster import Cluster
    with Cluster("local:2") as cluster:                 # a LocalCluster of 2 worker processes
        result = cluster.render(scene, accel="bvh", spd=True)
    with Cluster("tcp://scheduler:8786") as cluster:    # a running scheduler and its workers
        ...

The command line takes the same addresses: ``raykernel render scene.nff --dask local:2``, and
likewise ``animate``, ``compare`` and ``sweep``.

A render's tiles are Dask tasks. The scene goes to every worker once; each worker
builds its structures on its first task and keeps them (a few renders per worker process),
so its later tasks only trace. Tiles write only their own samples and counter rows, so the
gathered image bytes and counters equal a single-process render's whatever worker traced
what. Lazy structures refine between passes from the counts of the whole pass: each pass's
tasks carry the counts of the passes before it, and a worker that has not seen them (a new
one) replays the refinements first. The frames of an animation and the cells of a
comparison are tasks too (animate.py, analysis/compare.py).

A worker that dies (killed, or out of memory and stopped by its nanny) loses nothing: the
scheduler runs its tasks again elsewhere, and they give the same results (the scene reaches the
workers as a task's result, which the scheduler can make again, not as scattered data, whose
dependents it forgets when a worker is lost with it). Tasks the scheduler cancels anyway are a
ClusterError. A scheduler that
cannot be reached within ``timeout`` seconds is an OptionError naming the address; one lost while
work is on the cluster (the client out of touch with it for LOST_SECONDS) is a ClusterError
naming it, and an animation keeps the frames written so far: the same command goes on from them.
"""

from __future__ import annotations

import asyncio
import itertools
import os
import threading
import time
from collections import OrderedDict
from concurrent.futures import CancelledError

from .errors import OptionError, RayKernelError

__all__ = ["Cluster", "connect"]

TASKS_PER_WORKER = 4       # tasks a pass is cut into per worker: enough to balance, few enough to stay cheap
JOBS_KEPT = 4              # renders a worker keeps built
CONNECT_TIMEOUT = 10.0
LOST_SECONDS = 5.0         # the client out of touch with the scheduler this long: it is lost
POLL_SECONDS = 0.25


class ClusterError(RayKernelError):
    """The Dask scheduler was lost, or cancelled the tasks, while work was on the cluster."""

_jobs: OrderedDict = OrderedDict()      # in each worker process: (scene key, options) -> RenderJob
_jobs_lock = threading.Lock()           # a worker with several threads may run tasks of one job at once


def _import_distributed():
    try:
        import distributed
    except ImportError:
        raise OptionError("--dask needs Dask distributed: pip install 'raykernel[distributed]'") from None
    return distributed


def _options_key(options: dict) -> str:
    return repr(sorted(options.items()))


def _worker_job(scene, scene_key: str, options: dict):
    from .rendering.render import RenderJob
    key = (scene_key, _options_key(options))
    with _jobs_lock:
        job = _jobs.get(key)
        if job is None:
            job = RenderJob(scene, **options)
            _jobs[key] = job
            while len(_jobs) > JOBS_KEPT:
                _jobs.popitem(last=False)
        _jobs.move_to_end(key)
    return job


def _replay(job, history) -> None:
    """Refine job's lazy structures from the passes in history it has not seen."""
    with _jobs_lock:
        for q in range(job.refined, len(history) if job.lazy is not None else 0):
            job.end_pass(q, history[q])


def _plan_task(scene, scene_key, options):
    return _worker_job(scene, scene_key, options).plan()


def _tiles_task(scene, scene_key, options, p, lo, hi, history):
    """Trace tiles lo..hi-1 of pass p on this worker; history: every earlier pass's lazy counts."""
    job = _worker_job(scene, scene_key, options)
    _replay(job, history)
    first = job.passes[p][2]
    job.counts[first + lo:first + hi] = 0      # each task returns its own pass's counts, however often it runs
    job.trace(p, lo, hi, job.threads)
    return job.tile_block(p, lo, hi)


def _final_plan_task(scene, scene_key, options, history):
    """The build statistics once every pass has refined (lazy structures grow while traced)."""
    job = _worker_job(scene, scene_key, options)
    _replay(job, history)
    return job.plan()


def _segment_task(subject, times, indices, pending, options, incremental, threshold):
    """A segment of an animation's frames on this worker (animate.render_segment)."""
    from .rendering.animate import render_segment
    return list(render_segment(subject, times, indices, pending, options, incremental, threshold))


def _given(obj):
    return obj


def _warm_task(options):
    from .rendering.render import render
    from .scene.loading import load
    render(load("spd:balls:1"), resolution=4, **options)
    return os.getpid()


class Cluster:
    """A Dask client, and the cluster it started (``"local"`` or ``"local:N"``) or joined (``"tcp://..."``).

    Use it as a context manager (or call `close`): leaving it closes the client and a local
    cluster it started.

    Parameters
    ----------
    address : str, default "local"
        ``"local"``: a LocalCluster of one worker process a core; ``"local:N"``: of N worker
        processes, each running one task at a time over its share of the cores;
        ``"tcp://HOST:PORT"`` (any ``scheme://`` address): a running scheduler and its
        workers, which use all their cores.
    timeout : float, default CONNECT_TIMEOUT
        Seconds to wait for the scheduler.

    Attributes
    ----------
    address : str
        The address given.
    client : distributed.Client
        The Dask client.

    Raises
    ------
    OptionError
        Dask distributed is not installed, the address is not one of these forms, or the
        scheduler cannot be reached within `timeout` seconds.

    Examples
    --------
    >>> with Cluster("local:2") as cluster:
    ...     result = cluster.render(scene, accel="bvh", spd=True)
    """

    def __init__(self, address: str = "local", timeout: float = CONNECT_TIMEOUT):
        distributed = _import_distributed()
        self.address = address
        self.local = None
        self.threads_per_worker = None      # joined workers use all their cores
        text = str(address).strip()
        if text == "local" or text.startswith("local:"):
            n = text.partition(":")[2] or str(max(1, (os.cpu_count() or 1)))
            try:
                workers = int(n)
            except ValueError:
                workers = 0
            if workers < 1:
                raise OptionError(f"--dask local:N needs a positive number of workers, got {address!r}")
            # each worker runs one task at a time over its share of the cores (numba's threads)
            self.threads_per_worker = max(1, (os.cpu_count() or 1) // workers)
            # no dashboard; the scheduler's HTTP routes (health, metrics) on a free port, not 8787, which
            # another cluster on the machine may hold (Dask then warns that it moved)
            self.local = distributed.LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                                  dashboard_address=None, silence_logs=40,
                                                  scheduler_kwargs={"dashboard_address": ":0"})
            self.client = distributed.Client(self.local, timeout=timeout)
        elif "://" in text:
            try:
                self.client = distributed.Client(text, timeout=timeout)
            except (OSError, TimeoutError) as e:
                raise OptionError(f"cannot reach the Dask scheduler at {text} within {timeout:g} s "
                                  f"({type(e).__name__}: {e}); is it running?") from None
        else:
            raise OptionError(f"--dask takes local, local:N or a scheduler address such as tcp://HOST:8786, "
                              f"got {address!r}")
        self._keys = itertools.count()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        """Close the client, and the local cluster where this Cluster started one."""
        self.client.close()
        if self.local is not None:
            self.local.close()

    @property
    def workers(self) -> int:
        """The number of workers the scheduler has now (at least 1)."""
        return max(1, len(self.client.scheduler_info()["workers"]))

    def worker_pids(self) -> dict:
        """Worker address -> process id (for tests that stop one), as a dict."""
        return self.client.run(os.getpid)

    def task_options(self, options: dict) -> dict:
        """Render options for a task: a local worker's share of the cores unless threads are given.

        Parameters
        ----------
        options : dict
            Keywords of `raykernel.render`.

        Returns
        -------
        dict
            `options`, with ``threads`` set to a local worker's share of the cores where it is
            None or absent.
        """
        if options.get("threads") is None and self.threads_per_worker is not None:
            return {**options, "threads": self.threads_per_worker}
        return options

    def share(self, obj):
        """Send `obj` to the cluster for tasks to take as an argument.

        `obj` becomes the result of a task, not scattered data: a worker lost with it (killed,
        out of memory) has it made again, where the scheduler forgets scattered data's
        dependents.

        Parameters
        ----------
        obj : object
            Anything picklable (a Scene, say).

        Returns
        -------
        future : distributed.Future
            `obj`, for the tasks.
        key : str
            A key that names it in the workers' caches.
        """
        future = self.client.submit(_given, obj, pure=False)
        return future, f"{future.key}-{next(self._keys)}-{time.monotonic_ns()}"

    def warm_up(self, options: dict | None = None) -> None:
        """Compile (or load from the cache) the kernels on every worker before anything is timed.

        Parameters
        ----------
        options : dict, optional
            Keywords of `raykernel.render` for the warm-up render of each worker.
        """
        self.client.run(_warm_task, self.task_options(dict(options or {})))

    def completed(self, futures, doing: str = "rendering"):
        """``(future, result)`` pairs as the futures finish (a generator).

        Parameters
        ----------
        futures : iterable of distributed.Future
            The tasks.
        doing : str, default "rendering"
            What was on the cluster, for the message of a ClusterError.

        Yields
        ------
        tuple
            ``(future, result)`` of each task, in the order they finish.

        Raises
        ------
        ClusterError
            The scheduler is lost, or cancels the tasks, meanwhile.
        Exception
            A task's own error, raised as it is.
        """
        distributed = _import_distributed()
        pending, lost_since = list(futures), None
        while pending:
            try:
                done, left = distributed.wait(pending, timeout=POLL_SECONDS, return_when="FIRST_COMPLETED")
            except TimeoutError:
                done, left = [], pending
            except distributed.client.FuturesCancelledError as e:
                reason = str(e).splitlines()[2].strip() if len(str(e).splitlines()) > 2 else type(e).__name__
                if "connection-lost" in reason or self.client.status != "running":
                    raise self._lost(doing, reason) from None
                raise ClusterError(f"the Dask scheduler at {self.address} cancelled the tasks while {doing} "
                                   f"({reason})") from None
            status = self.client.status
            if status == "running" and not any(f.status == "cancelled" for f in done):
                lost_since = None
            else:
                lost_since = time.monotonic() if lost_since is None else lost_since
                if status in ("closing", "closed") or time.monotonic() - lost_since >= LOST_SECONDS:
                    raise self._lost(doing, f"no answer for {time.monotonic() - lost_since:.0f} s; the client is "
                                            f"{status}")
                continue
            for f in done:
                try:
                    yield f, f.result()
                except (OSError, CancelledError, asyncio.CancelledError) as e:     # the connection went with it
                    if f.status == "error":
                        raise       # the task's own
                    raise self._lost(doing, f"{type(e).__name__}") from None
            pending = list(left)

    def _lost(self, doing: str, why: str) -> ClusterError:
        return ClusterError(f"lost the Dask scheduler at {self.address} while {doing} ({why})")

    def result(self, future, doing: str = "rendering"):
        """The result of one task, or ClusterError if the scheduler is lost first.

        Parameters
        ----------
        future : distributed.Future
            The task.
        doing : str, default "rendering"
            What was on the cluster, for the message of a ClusterError.

        Returns
        -------
        object
            The task's result.
        """
        for _, value in self.completed([future], doing):
            return value

    def map(self, fn, items, progress=None, pure=False, doing: str = "rendering") -> list:
        """``fn(*item)`` for every item, as tasks; the results in the items' order.

        Parameters
        ----------
        fn : callable
            The function each task calls.
        items : iterable of tuple
            Each task's arguments.
        progress : callable, optional
            ``progress(done, total)``, called as each task finishes.
        pure : bool, default False
            Dask's `pure` (False: every task runs, even with equal arguments).
        doing : str, default "rendering"
            What was on the cluster, for the message of a ClusterError.

        Returns
        -------
        list
            The tasks' results, in the items' order.

        Raises
        ------
        ClusterError
            The scheduler is lost, or cancels the tasks, meanwhile.
        """
        futures = [self.client.submit(fn, *item, pure=pure) for item in items]
        results = {}
        for f, value in self.completed(futures, doing):
            results[f.key] = value
            if progress is not None:
                progress(len(results), len(futures))
        return [results[f.key] for f in futures]

    def animate(self, segments, work, finished) -> None:
        """Render animate()'s frames (rendering/animate.py), each segment of them a task.

        Parameters
        ----------
        segments : iterable
            The frames' indices, one sequence a segment (a task).
        work : tuple
            ``(subject, times, pending frames, options, incremental, rebuild threshold)``.
        finished : callable
            ``finished(index, image, record)``, called for each frame as its segment returns.

        Raises
        ------
        ClusterError
            The scheduler is lost meanwhile; the frames handed to `finished` so far are kept.
        """
        subject, times, pending, options, incremental, threshold = work
        future, _ = self.share(subject)
        options = self.task_options(options)
        futures = [self.client.submit(_segment_task, future, times, seg, set(pending), options, incremental,
                                      threshold, pure=False) for seg in segments]
        doing = "animating: the frames written so far are kept, and the same command goes on from them"
        for _, frames in self.completed(futures, doing):
            for i, image, record in frames:
                finished(i, image, record)

    def render(self, scene, progress=None, **options):
        """``render(scene, **options)`` with its tiles traced on the workers: the same image and counters.

        The scene goes to every worker once; each builds its structures on its first task and
        keeps them. Lazy structures refine between passes from the counts of the whole pass.

        Parameters
        ----------
        scene : Scene
            The scene to render.
        progress : callable, optional
            ``progress(done, total)``, called as each task finishes, in samples.
        **options
            Keywords of `raykernel.render` (``builder`` is ignored); ``auto`` specs are
            annealed here, once, before the tasks.

        Returns
        -------
        RenderResult
            As `raykernel.render`'s; ``stats.info["dask"]`` gives the address and the number of
            workers, and the trace time is the wall-clock time of the tasks.

        Raises
        ------
        ClusterError
            The scheduler is lost, or cancels the tasks, meanwhile.
        OptionError
            An option is not valid.
        """
        from .analysis.auto import tune
        from .geometry.compiletime import CompileClock
        from .rendering.render import RenderJob
        options.pop("builder", None)
        scene, options, annealed = tune(scene, options)     # here, once: the workers build what it found
        options = self.task_options(options)
        future, key = self.share(scene)
        plan = self.result(self.client.submit(_plan_task, future, key, options, pure=False))
        job = RenderJob(scene, remote=plan, annealed=annealed, **options)
        done, total = 0, sum(job.work)
        t0 = time.perf_counter()
        history = []
        lazy = job.lazy_columns is not None
        chunk = max(1, -(-job.n_tiles // (TASKS_PER_WORKER * self.workers)))
        # without lazy structures every pass's tasks go at once; with them, one pass after another
        groups = [[p] for p in range(len(job.passes))] if lazy else [list(range(len(job.passes)))]
        with CompileClock() as clock:
            for group in groups:
                items, futures = [], []
                for p in group:
                    n = job.pass_tiles(p)
                    for lo in range(0, n, chunk):
                        items.append((p, lo, min(n, lo + chunk)))
                        futures.append(self.client.submit(_tiles_task, future, key, options, p, lo, min(n, lo + chunk),
                                                          list(history), pure=False))
                where = {f.key: item for f, item in zip(futures, items)}
                for f, block in self.completed(futures):
                    p, lo, hi = where[f.key]
                    job.put_block(p, lo, *block)
                    done += job.work[p] * (hi - lo) // max(1, job.pass_tiles(p))
                    if progress is not None:
                        progress(done, total)
                for p in group:
                    history.append(job.pass_counts[p])
        trace = time.perf_counter() - t0
        build = None
        if lazy:
            build = self.result(self.client.submit(_final_plan_task, future, key, options, history, pure=False))["build"]
        result = job.result(trace, clock.seconds, threads=self.workers, build=build)
        result.stats.info["dask"] = {"address": str(self.address), "workers": self.workers}
        return result


def connect(address: str | None):
    """A Cluster for --dask ADDRESS, or None without one."""
    return None if address is None else Cluster(address)

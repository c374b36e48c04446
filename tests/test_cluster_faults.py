"""Faults on Dask: a scheduler lost mid-render or mid-animation is one ClusterError within seconds,
and the animation goes on from the frames it wrote; a worker stopped for running out of memory
is survived with the same image bytes and counters."""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

distributed = pytest.importorskip("distributed")

from raykernel import cluster as cluster_module  # noqa: E402
from raykernel.cluster import Cluster, ClusterError  # noqa: E402
from raykernel.rendering.animate import animate  # noqa: E402
from raykernel.rendering.render import render  # noqa: E402
from raykernel.scene.loading import load  # noqa: E402

from test_cluster import assert_same  # noqa: E402



def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def scheduler_and_worker():
    """A scheduler and one worker in processes of their own: (address, the scheduler's process)."""
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    quiet = dict(stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    scheduler = subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
                                  "--port", str(port), "--no-dashboard"], **quiet)
    worker = subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_worker", address, "--nthreads", "1",
                               "--no-dashboard", "--no-nanny"], **quiet)
    try:
        yield address, scheduler
    finally:
        for process in (worker, scheduler):
            process.kill()
            process.wait(timeout=30)


def _joined(address) -> Cluster:
    for _ in range(60):
        try:
            c = Cluster(address, timeout=2)
            c.client.wait_for_workers(1, timeout=60)
            c.warm_up()
            return c
        except Exception:       # noqa: BLE001 (the scheduler is still starting)
            time.sleep(0.5)
    raise AssertionError(f"no scheduler at {address}")


def test_a_scheduler_lost_mid_render_is_one_error_within_seconds(scheduler_and_worker, monkeypatch):
    address, scheduler = scheduler_and_worker
    monkeypatch.setattr(cluster_module, "TASKS_PER_WORKER", 64)     # many tasks: most are left at the loss
    c = _joined(address)
    lost = []

    def kill_scheduler(done, total):
        if not lost:
            scheduler.send_signal(signal.SIGKILL)
            lost.append(time.monotonic())
    with pytest.raises(ClusterError, match=f"lost the Dask scheduler at {address} while rendering") as err:
        c.render(load("spd:gears:1"), resolution=96, progress=kill_scheduler)
    assert lost and time.monotonic() - lost[0] < cluster_module.LOST_SECONDS + 10
    assert "\n" not in str(err.value)
    c.client.close(timeout=5)


def test_an_animation_keeps_its_frames_and_goes_on_after_the_scheduler_is_lost(scheduler_and_worker, tmp_path):
    address, scheduler = scheduler_and_worker
    c = _joined(address)
    out = tmp_path / "frames"
    kw = dict(frames=12, resolution=24, segment=1)

    def kill_when_frames_are_written():
        while len(list(out.glob("frame-*.png"))) < 3:
            time.sleep(0.02)
        scheduler.send_signal(signal.SIGKILL)
    threading.Thread(target=kill_when_frames_are_written, daemon=True).start()
    with pytest.raises(ClusterError, match="frames written so far are kept"):
        animate("scene:satellite:prims=300", output=out, cluster=c, **kw)
    kept = sorted(p.name for p in out.glob("frame-*.png"))
    assert 3 <= len(kept) < 12
    c.client.close(timeout=5)
    # the same command again (here without the cluster) renders only what is missing
    again = animate("scene:satellite:prims=300", output=out, **kw)
    assert sorted(f["index"] for f in again.frames if f["skipped"]) == [int(n[6:10]) for n in kept]
    alone = animate("scene:satellite:prims=300", output=tmp_path / "alone", **kw)
    for i in range(12):
        name = f"frame-{i:04d}.png"
        assert (out / name).read_bytes() == (tmp_path / "alone" / name).read_bytes()
    assert [f["index"] for f in alone.frames] == list(range(12))


def test_a_worker_out_of_memory_is_survived(monkeypatch):
    """A worker whose memory passes its limit mid-render is stopped by its nanny and started
    again; its tasks run again elsewhere (the scene with them), and the render is the same."""
    monkeypatch.setattr(cluster_module, "TASKS_PER_WORKER", 64)
    scene = load("spd:gears:1")
    alone = render(scene, resolution=128)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=2, processes=True, memory_limit="1GiB",
                                  dashboard_address=None, silence_logs=50) as local:
        c = Cluster(local.scheduler_address)
        c.warm_up()
        before = c.worker_pids()
        hog = []

        def hog_memory(done, total):
            if hog:
                return
            # 1.6 GB of ones on one worker, past its 1 GiB, beside the render's tasks there; the
            # render waits here until the nanny has stopped that worker
            victim = sorted(before)[0]
            future = c.client.submit(np.ones, 200_000_000, workers=[victim], pure=False, allow_other_workers=False)
            deadline = time.monotonic() + 120
            while victim in c.client.scheduler_info()["workers"] and time.monotonic() < deadline:
                time.sleep(0.05)
            future.cancel()
            hog.append((done, total, victim not in c.client.scheduler_info()["workers"]))
        spread = c.render(scene, resolution=128, progress=hog_memory)
        done, total, stopped = hog[0]
        assert stopped and done < total, "the worker was stopped while the render had work left"
        assert_same(alone, spread)
        c.client.wait_for_workers(2, timeout=60)
        assert set(c.worker_pids().values()) != set(before.values())      # the nanny started a new one
        c.client.close()


def test_a_cast_keeps_its_chunks_and_goes_on_after_the_scheduler_is_lost(scheduler_and_worker, tmp_path):
    from raykernel.casting.castfile import cast_file
    from raykernel.casting.rayscene import RayScene
    from test_cast import _files, _mesh, _write_rays      # (here: that module skips itself without zarr)
    address, scheduler = scheduler_and_worker
    c = _joined(address)
    scene = RayScene.from_mesh(*_mesh())
    rays = _write_rays(tmp_path, 4000)
    lost = []

    def kill_scheduler(done, total):
        if not lost:
            scheduler.send_signal(signal.SIGKILL)
            lost.append(time.monotonic())
    with pytest.raises(ClusterError, match=f"lost the Dask scheduler at {address} while casting rays: the chunks "
                                           "written so far are kept") as err:
        cast_file(scene, rays, tmp_path / "hits.zarr", cluster=c, chunk=20, progress=kill_scheduler)
    assert "\n" not in str(err.value)
    c.client.close(timeout=5)
    # the same call again (here without the cluster) casts only what is missing
    again = cast_file(scene, rays, tmp_path / "hits.zarr")
    assert again.skipped >= 1 and again.cast < 4000
    cast_file(scene, rays, tmp_path / "whole.zarr", chunk=20)
    assert _files(tmp_path / "hits.zarr") == _files(tmp_path / "whole.zarr")

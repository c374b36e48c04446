"""Renders on Dask: a 2-worker LocalCluster gives the single process's image bytes and counters,
also when a worker is killed mid-render; animations and comparisons as tasks; bad addresses."""

from __future__ import annotations

import os
import signal

import numpy as np
import pytest

pytest.importorskip("distributed")

from raykernel import cluster as cluster_module  # noqa: E402
from raykernel.analysis.compare import compare  # noqa: E402
from raykernel.cluster import Cluster  # noqa: E402
from raykernel.errors import OptionError  # noqa: E402
from raykernel.rendering.animate import animate  # noqa: E402
from raykernel.analysis.auto import render  # noqa: E402
from raykernel.scene.loading import load  # noqa: E402

# figures that are the machine's, not the work's
NOT_WORK = ("time.", "build.seconds", "build.refine_seconds")


def assert_same(a, b):
    assert np.array_equal(a.image, b.image)
    work = [k for k in a.stats if not k.startswith(NOT_WORK)]
    assert work and {k: a.stats[k] for k in work} == {k: b.stats[k] for k in work}
    assert a.stats.aggregates == b.stats.aggregates or len(a.stats.aggregates) == len(b.stats.aggregates)


@pytest.fixture(scope="module")
def two_workers():
    with Cluster("local:2") as c:
        c.warm_up()
        yield c


@pytest.mark.parametrize("accel, options", [
    ("bvh", {"spd": True}),
    # the sampling kernel, compiled anew in each worker of a fresh install: make test-all
    pytest.param("grid", {"shading": "hall", "aa": "jitter", "samples": 4, "shadows": "filtered"},
                 marks=pytest.mark.slow),
    ("lazyoctree", {}),        # refined between passes: every worker replays the refinements
    pytest.param("rc", {}, marks=pytest.mark.slow),
])
def test_local_cluster_equals_one_process(two_workers, accel, options):
    scene = load("spd:balls:1")
    alone = render(scene, accel=accel, resolution=40, **options)
    spread = two_workers.render(scene, accel=accel, resolution=40, **options)
    assert_same(alone, spread)
    assert spread.stats.info["dask"]["workers"] == 2


def test_auto_is_annealed_once_here_and_the_workers_build_it(two_workers):
    scene = load("scene:stadium:stadium_prims=600,teapot_prims=200")
    alone = render(scene, accel="auto(evaluations=12)", resolution=24, spd=True)
    spread = two_workers.render(scene, accel="auto(evaluations=12)", resolution=24, spd=True)
    assert_same(alone, spread)
    assert spread.stats["time.anneal"] > 0
    assert spread.stats.info["anneal"][0]["state"] == alone.stats.info["anneal"][0]["state"]


def test_a_worker_killed_mid_render_changes_nothing(two_workers, monkeypatch):
    monkeypatch.setattr(cluster_module, "TASKS_PER_WORKER", 64)    # many small tasks: most are left at the kill
    scene = load("spd:gears:1")
    alone = render(scene, resolution=64)
    before = two_workers.worker_pids()
    killed = []

    def kill_one(done, total):
        if not killed:
            pid = sorted(before.values())[0]
            os.kill(pid, signal.SIGKILL)
            killed.append((pid, done, total))
    spread = two_workers.render(scene, resolution=64, progress=kill_one)
    assert killed and killed[0][1] < killed[0][2] / 2, "killed while most of the work was left"
    assert_same(alone, spread)
    two_workers.client.wait_for_workers(2, timeout=60)
    assert killed[0][0] not in two_workers.worker_pids().values()


def test_animation_on_the_cluster_equals_one_process(two_workers, tmp_path):
    kw = dict(frames=7, resolution=16, segment=3)
    here = animate("scene:satellite:prims=300", output=tmp_path / "here", **kw)
    there = animate("scene:satellite:prims=300", output=tmp_path / "there", cluster=two_workers, **kw)
    for i in range(7):
        name = f"frame-{i:04d}.png"
        assert (tmp_path / "here" / name).read_bytes() == (tmp_path / "there" / name).read_bytes()
        a, b = here.frames[i]["counters"], there.frames[i]["counters"]
        work = [k for k in a if not k.startswith(NOT_WORK)]
        assert {k: a[k] for k in work} == {k: b[k] for k in work}
    assert here.frames[1]["counters"]["build.refit_nodes"] > 0      # incremental within a segment
    assert here.frames[3]["counters"]["build.refit_nodes"] == 0     # a segment starts from scratch


def test_compare_on_the_cluster_equals_one_process(two_workers):
    kw = dict(resolution=16, model=None, warm_up=False, work="cells.visited")
    here = compare(["spd:balls:1", "spd:tetra:1"], ["bvh", "grid"], **kw)
    there = compare(["spd:balls:1", "spd:tetra:1"], ["bvh", "grid"], cluster=two_workers, **kw)
    assert [(r.scene, r.accel) for r in here.runs] == [(r.scene, r.accel) for r in there.runs]
    for a, b in zip(here.runs, there.runs):
        work = [k for k in a.stats if not k.startswith(NOT_WORK)]
        assert {k: a.stats[k] for k in work} == {k: b.stats[k] for k in work}
        assert np.array_equal(a.image, b.image)
        assert np.array_equal(a.work, b.work) and int(b.work.sum()) == b.stats["cells.visited"]   # work images too


def test_a_scheduler_that_cannot_be_reached_is_a_clear_error():
    with pytest.raises(OptionError, match=r"cannot reach the Dask scheduler at tcp://127\.0\.0\.1:9"):
        Cluster("tcp://127.0.0.1:9", timeout=1)


@pytest.mark.parametrize("address", ["local:0", "local:two", "somewhere", ""])
def test_bad_addresses(address):
    with pytest.raises(OptionError, match="--dask"):
        Cluster(address)


def test_sweep_on_the_cluster_equals_one_process(two_workers):
    from raykernel.analysis.compare import sweep
    kw = dict(resolution=12, model=None)
    here = sweep("spd:balls:{sf}", {"sf": ["1", "2"]}, ["bvh"], **kw)
    there = sweep("spd:balls:{sf}", {"sf": ["1", "2"]}, ["bvh"], cluster=two_workers, **kw)
    assert [r.params for r in here.runs] == [r.params for r in there.runs] == [{"sf": "1"}, {"sf": "2"}]
    for a, b in zip(here.runs, there.runs):
        assert a.stats["rays.total"] == b.stats["rays.total"] and a.stats["tests.total"] == b.stats["tests.total"]


def test_work_layers_on_the_cluster_equal_one_process(two_workers):
    scene = load("spd:balls:1")
    alone = render(scene, accel="lazyoctree", resolution=40, work=True)
    spread = two_workers.render(scene, accel="lazyoctree", resolution=40, work=True)
    assert_same(alone, spread)
    assert alone.work.keys() == spread.work.keys()
    for name in alone.work:
        assert np.array_equal(alone.work[name], spread.work[name]), name
    assert int(spread.work["tests.total"].sum()) == spread.stats["tests.total"]


def test_a_local_cluster_says_nothing_when_dasks_usual_port_is_taken():
    # another cluster on the machine may hold 8787 (two commands at once, or two test workers): the
    # scheduler's HTTP routes go to a free port, with no warning for the command to print
    import contextlib
    import socket
    import warnings
    held = socket.socket()
    with contextlib.closing(held), warnings.catch_warnings(record=True) as caught:
        with contextlib.suppress(OSError):      # (taken already: the same situation)
            held.bind(("0.0.0.0", 8787))
            held.listen()
        warnings.simplefilter("always")
        with Cluster("local:1") as c:
            assert c.workers == 1
    assert not [w for w in caught if "8787" in str(w.message)]

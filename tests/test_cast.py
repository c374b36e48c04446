"""Ray casting past one process: RayScene's queries on dask arrays give the numpy call's answers bit for
bit on a 2-worker LocalCluster, whatever the chunking; `raykernel cast` streams a file of rays into a
zarr group or a Parquet folder, here or as Dask tasks, survives a killed worker, resumes after Ctrl-C
or a kill with the bytes of an uninterrupted run, and refuses bad files in one line naming the file
(and the chunk) with nothing written past the last good chunk."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

distributed = pytest.importorskip("distributed")
da = pytest.importorskip("dask.array")
zarr = pytest.importorskip("zarr")
pq = pytest.importorskip("pyarrow.parquet")

import dask  # noqa: E402

from raykernel.casting import daskcast  # noqa: E402
from raykernel.casting.castfile import cast_file  # noqa: E402
from raykernel.casting.rayfiles import Buffers, open_rays  # noqa: E402
from raykernel.casting.rayinput import RayInputError  # noqa: E402
from raykernel.casting.rayscene import RayScene  # noqa: E402
from raykernel.cli import main  # noqa: E402
from raykernel.cluster import Cluster  # noqa: E402

ALL = ("t", "prim_id", "geom_id", "inst_id", "kind", "uv", "normal", "shading_normal")


def _mesh():
    """A closed mesh (an octahedron refined twice, 128 triangles, on the unit sphere)."""
    v = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
    f = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    for _ in range(2):
        edges, faces = {}, []
        verts = list(v)

        def middle(a, b):
            key = (min(a, b), max(a, b))
            if key not in edges:
                m = (verts[a] + verts[b]) / 2
                verts.append(m / np.linalg.norm(m))
                edges[key] = len(verts) - 1
            return edges[key]
        for a, b, c in f:
            ab, bc, ca = middle(a, b), middle(b, c), middle(c, a)
            faces += [[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]
        v, f = np.array(verts), np.array(faces)
    return v, f


def _rays(n: int, seed: int = 1):
    """n rays from around the mesh toward it, a fifth of them away from it (misses), and a tmax each."""
    rng = np.random.default_rng(seed)
    o = rng.uniform(-3, 3, (n, 3))
    d = -o + rng.normal(0, 0.3, (n, 3))
    d[::5] *= -1
    return o, d, rng.uniform(1.0, 6.0, n)


@pytest.fixture(scope="module")
def scene():
    return RayScene.from_mesh(*_mesh())


@pytest.fixture(scope="module")
def two_workers():
    with Cluster("local:2") as c:
        yield c


def _same(a, b):
    a, b = np.asarray(a), np.asarray(b)
    assert a.dtype == b.dtype and a.shape == b.shape
    assert np.array_equal(a, b, equal_nan=a.dtype.kind == "f")


# ----------------------------------------------------------------- dask arrays in, dask arrays out

@pytest.mark.parametrize("n, chunk", [(301, 100), (301, 301), (9, 1)], ids=["uneven last chunk", "one chunk",
                                                                            "chunks of one ray"])
def test_dask_queries_equal_numpy_bit_for_bit(scene, two_workers, n, chunk):
    o, d, tmax = _rays(n)
    do, dd = da.from_array(o, chunks=(chunk, 3)), da.from_array(d, chunks=(max(1, chunk // 2 + 1), 3))
    dtmax = da.from_array(tmax, chunks=chunk)
    p = o / 2.5
    dp = da.from_array(p, chunks=(chunk, 3))
    for dtype in ("float64", "float32"):
        hits = scene.intersect(do, dd, tmin=0.5, tmax=dtmax, dtype=dtype)
        assert all(isinstance(getattr(hits, f), da.Array) for f in ALL)
        want = scene.intersect(o, d, tmin=0.5, tmax=tmax, dtype=dtype)
        for f, got in zip(ALL, dask.compute(*[getattr(hits, f) for f in ALL])):
            _same(got, getattr(want, f))
    some = scene.intersect(do, d[0], fields=("t", "kind"))      # one direction for every ray
    assert some.prim_id is None
    _same(some.t.compute(), scene.intersect(o, d[0], fields=("t", "kind")).t)
    _same(scene.occluded(do, dd, tmax=dtmax).compute(), scene.occluded(o, d, tmax=tmax))
    _same(scene.occluded(o, dd, tmax=tmax).compute(), scene.occluded(o, d, tmax=tmax))     # numpy beside dask
    _same(scene.count_hits(do, dd).compute(), scene.count_hits(o, d))
    _same(scene.contains(dp).compute(), scene.contains(p))
    _same(scene.distance(dp).compute(), scene.distance(p))
    near, want = scene.closest_points(dp), scene.closest_points(p)
    for f, got in zip(("points", "distance", "prim_id", "geom_id", "kind", "normal"),
                      dask.compute(near.points, near.distance, near.prim_id, near.geom_id, near.kind, near.normal)):
        _same(got, getattr(want, f))


def test_an_image_of_rays_keeps_its_shape(scene, two_workers):
    o, d, tmax = _rays(12 * 10)
    shaped = d.reshape(12, 10, 3)
    eye = np.array([0.1, 0.2, 2.5])       # one origin for every ray
    hits = scene.intersect(eye, da.from_array(shaped, chunks=(5, 4, 3)), tmax=tmax.reshape(12, 10))
    want = scene.intersect(eye, shaped, tmax=tmax.reshape(12, 10))
    assert hits.t.shape == (12, 10) and hits.uv.shape == (12, 10, 2)
    _same(hits.t.compute(), want.t)
    _same(hits.points.compute(), want.points)


def test_the_scene_is_kept_on_each_worker_between_calls(scene, two_workers):
    o, d, _ = _rays(200)
    do, dd = da.from_array(o, chunks=(10, 3)), da.from_array(d, chunks=(10, 3))
    ids = lambda: two_workers.client.run(lambda: sorted(id(s) for s in daskcast._kept.values()))   # noqa: E731
    scene.intersect(do, dd).t.compute()
    first = ids()
    assert all(first.values())
    scene.contains(do / 3).compute()
    assert ids() == first          # the same objects: what their first calls built stays built


def test_threads_in_this_process_use_the_scene_itself(scene):
    o, d, _ = _rays(50)
    with dask.config.set(scheduler="threads"):
        t = scene.intersect(da.from_array(o, chunks=(20, 3)), d).t.compute()
    _same(t, scene.intersect(o, d).t)
    assert not any(kept is scene for kept in daskcast._kept.values())     # nothing of the user's held here


def test_a_bad_ray_is_named_by_its_chunk_and_index(scene, two_workers):
    o, d, _ = _rays(301)
    o[170] = np.nan
    with pytest.raises(RayInputError, match=r"chunk \(1,\) \(rays from 100\): origins\[170\] is not finite"):
        scene.intersect(da.from_array(o, chunks=(100, 3)), d).t.compute()
    with pytest.raises(RayInputError, match=r"origins must have shape \(\.\.\., 3\)"):
        scene.intersect(da.from_array(o[:, :2], chunks=(100, 2)), d)
    with pytest.raises(RayInputError, match=r"tmax must be a number or have shape \(301,\)"):
        scene.occluded(da.from_array(o, chunks=(100, 3)), d, tmax=np.ones(5))
    with pytest.raises(RayInputError, match="intersect_all takes numpy arrays"):
        scene.intersect_all(da.from_array(o, chunks=(100, 3)), d)


def test_numpy_calls_import_no_dask():
    code = ("import sys, numpy as np; from raykernel import RayScene; "
            "s = RayScene.from_mesh(np.eye(3), [[0, 1, 2]]); s.intersect(np.ones((2, 3)) * 3, -np.ones((2, 3))); "
            "assert 'dask' not in sys.modules, 'dask imported'")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr


# ----------------------------------------------------------------- raykernel cast

def _files(folder: Path) -> dict:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _write_rays(folder: Path, n: int, fmt: str = "npz") -> Path:
    o, d, tmax = _rays(n)
    if fmt == "npz":
        np.savez(folder / "rays.npz", origins=o, directions=d, tmax=tmax)
    elif fmt == "npy":
        np.save(folder / "rays.npy", np.hstack([o, d]).astype(np.float32))
    elif fmt == "zarr":
        g = zarr.open_group(folder / "rays.zarr", mode="w")
        g["origins"], g["directions"], g["tmax"] = o, d, tmax
    else:
        import pyarrow as pa
        pq.write_table(pa.table({**{c: o[:, i] for i, c in enumerate(("ox", "oy", "oz"))},
                                 **{c: d[:, i] for i, c in enumerate(("dx", "dy", "dz"))}, "tmax": tmax}),
                       folder / "rays.parquet", row_group_size=70)
    return folder / f"rays.{fmt}"


@pytest.mark.parametrize("dtype", ["float32", "float64", ">f8", "int16"])
def test_a_npy_reads_into_kept_buffers_as_numpy_converts_it(tmp_path, dtype):
    rows = np.random.default_rng(3).uniform(-50, 50, (1000, 6)).astype(dtype)
    np.save(tmp_path / "rays.npy", rows)
    source, buffers = open_rays(tmp_path / "rays.npy"), Buffers()
    for a, b in ((0, 400), (400, 800), (800, 1000), (0, 1000)):     # the last chunk smaller, then a larger one
        want = rows[a:b].astype(np.float64)
        for into in (buffers, None):
            o, d, lo, hi = source.read(a, b, into)
            assert o.dtype == d.dtype == np.float64 and lo is None and hi is None
            _same(o, want[:, :3])
            _same(d, want[:, 3:])
    reserved = Buffers()        # a warm-up's: the arrays the next read fills, made beforehand
    source.reserve(1000, reserved)
    made = [reserved.get(name, (1000, 3), np.float64) for name in ("origins", "directions")]
    o, d, _, _ = source.read(0, 1000, reserved)
    assert np.shares_memory(o, made[0]) and np.shares_memory(d, made[1])


def _read(out: Path, names) -> dict:
    if out.suffix == ".zarr":
        g = zarr.open_group(out, mode="r")
        return {n: g[n][:] for n in names}
    table = pq.read_table(out)
    return {n: np.stack(table[n].to_numpy(zero_copy_only=False)) if n in ("uv", "normal", "shading_normal")
            else table[n].to_numpy() for n in names}


@pytest.mark.parametrize("fmt, out", [("npz", "hits.zarr"), ("npy", "hits.parquet"), ("zarr", "hits.parquet"),
                                      ("parquet", "hits.zarr")])
def test_cast_writes_the_hits_of_every_ray(scene, tmp_path, fmt, out):
    rays = _write_rays(tmp_path, 250, fmt)
    names = ("t", "prim_id", "normal", "uv")
    report = cast_file(scene, rays, tmp_path / out, fields=names, chunk=64)
    assert (report.rays, report.chunks, report.cast, report.skipped) == (250, 4, 250, 0)
    o, d, tmax = _rays(250)
    if fmt == "npy":      # float32 rays, no tmax
        o, d, tmax = o.astype(np.float32), d.astype(np.float32), np.inf
    want = scene.intersect(o, d, tmax=tmax, fields=names)
    for name, got in _read(tmp_path / out, names).items():
        _same(got, getattr(want, name))
    again = cast_file(scene, rays, tmp_path / out, fields=names)     # nothing left: the recorded chunk is kept
    assert (again.cast, again.skipped) == (0, 4)


def test_a_cast_on_a_cluster_survives_a_killed_worker(scene, two_workers, tmp_path):
    rays = _write_rays(tmp_path, 4000)
    alone = cast_file(scene, rays, tmp_path / "alone.zarr", fields=("t", "prim_id", "normal"), chunk=20)
    before = two_workers.worker_pids()
    killed = []

    def kill_one(done, total):
        if not killed:
            os.kill(sorted(before.values())[0], signal.SIGKILL)
            killed.append((done, total))
    spread = cast_file(scene, rays, tmp_path / "spread.zarr", fields=("t", "prim_id", "normal"), chunk=20,
                       cluster=two_workers, progress=kill_one)
    assert killed and killed[0][0] < killed[0][1], "killed while work was left"
    assert spread.cast == alone.cast == 4000
    assert len([w for w, f in spread.workers.items() if "compile" in f]) >= 2     # each worker's kernels reported
    assert _files(tmp_path / "spread.zarr") == _files(tmp_path / "alone.zarr")
    two_workers.client.wait_for_workers(2, timeout=60)


def _mapped_scene_files() -> list:
    with open("/proc/self/maps") as f:
        return sorted({line.split(None, 5)[5].strip() for line in f if "raykernel-scene-" in line})


@pytest.mark.skipif(not Path("/proc/self/maps").exists(), reason="reads Linux's /proc")
def test_a_local_clusters_workers_map_one_file_of_the_scene(scene, two_workers, tmp_path):
    # one copy of the built scene on the machine (sharedscene.py), not one a worker
    rays = _write_rays(tmp_path, 400)
    alone = cast_file(scene, rays, tmp_path / "alone.zarr", fields=("t", "prim_id"), chunk=20)
    spread = cast_file(scene, rays, tmp_path / "spread.zarr", fields=("t", "prim_id"), chunk=20, cluster=two_workers)
    assert spread.cast == alone.cast == 400 and len(spread.workers) == 2
    assert _files(tmp_path / "spread.zarr") == _files(tmp_path / "alone.zarr")
    mapped = list(two_workers.client.run(_mapped_scene_files).values())
    assert len(mapped) == 2 and set(mapped[0]) & set(mapped[1])
    assert all(name.endswith("(deleted)") for name in mapped[0]), "the file is removed when the cast ends"


def test_a_local_cluster_without_room_for_the_scenes_file_sends_copies(scene, two_workers, tmp_path, monkeypatch):
    from raykernel.casting import castfile

    def full(rs, folder=None):
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(castfile.SharedScene, "write", full)
    rays = _write_rays(tmp_path, 200)
    alone = cast_file(scene, rays, tmp_path / "alone.zarr", fields=("t", "prim_id"), chunk=20)
    spread = cast_file(scene, rays, tmp_path / "spread.zarr", fields=("t", "prim_id"), chunk=20, cluster=two_workers)
    assert spread.cast == alone.cast == 200
    assert _files(tmp_path / "spread.zarr") == _files(tmp_path / "alone.zarr")


def _forget_scenes():
    daskcast._kept.clear()


def test_a_worker_that_lost_the_scene_gets_its_chunks_again_with_it(scene, two_workers, tmp_path):
    # as a worker restarted mid-cast: the chunks it finds without the scene go back, sent with it
    rays = _write_rays(tmp_path, 2000)
    alone = cast_file(scene, rays, tmp_path / "alone.zarr", fields=("t", "prim_id"), chunk=20)
    forgot = []

    def forget(done, total):
        if not forgot:
            two_workers.client.run(_forget_scenes)
            forgot.append(done)
    spread = cast_file(scene, rays, tmp_path / "spread.zarr", fields=("t", "prim_id"), chunk=20, cluster=two_workers,
                       progress=forget)
    assert forgot and forgot[0] < 2000
    assert spread.cast == alone.cast == 2000
    assert _files(tmp_path / "spread.zarr") == _files(tmp_path / "alone.zarr")


def _command(rays: Path, out: Path, *more) -> list:
    return ["cast", "spd:tetra:1", "--rays", str(rays), "--out", str(out), "--fields", "t,prim_id,normal",
            "--chunk", "100", *more]


def test_the_command_stopped_by_ctrl_c_or_killed_resumes_to_the_same_bytes(tmp_path, capsys):
    rays = _write_rays(tmp_path, 40_000)
    cli = [sys.executable, "-m", "raykernel"]
    out = tmp_path / "hits.zarr"
    chunk_files = lambda: len(list((out / "t" / "c").glob("*")) if (out / "t" / "c").exists() else [])  # noqa: E731
    for sig, status in ((signal.SIGINT, 130), (signal.SIGKILL, -signal.SIGKILL)):
        child = subprocess.Popen(cli + _command(rays, out), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        start = chunk_files()
        while chunk_files() < start + 3 and child.poll() is None:
            time.sleep(0.01)
        child.send_signal(sig)
        _, stderr = child.communicate(timeout=300)
        assert child.returncode == status, stderr
        assert chunk_files() < 400, "the cast ended before it was stopped"
        if sig == signal.SIGINT:
            assert "interrupted" in stderr and "the same command goes on" in stderr and "Traceback" not in stderr
    assert main(_command(rays, out)) == 0
    before = re.search(r"\(([\d,]+) chunk\(s\) written before\)", capsys.readouterr().out)
    assert before and int(before.group(1).replace(",", "")) > 0
    assert main(_command(rays, tmp_path / "whole.zarr")) == 0
    assert _files(out) == _files(tmp_path / "whole.zarr")


def test_a_parquet_cast_missing_chunks_casts_only_those(scene, tmp_path):
    rays = _write_rays(tmp_path, 300)
    whole = tmp_path / "whole.parquet"
    cast_file(scene, rays, whole, chunk=50)
    part = tmp_path / "part.parquet"
    cast_file(scene, rays, part, chunk=50)
    for k in (1, 4):
        (part / f"part-{k:06d}.parquet").unlink()
    report = cast_file(scene, rays, part)
    assert (report.cast, report.skipped) == (100, 4)
    assert _files(part) == _files(whole)


def _bad(folder: Path, case: str) -> tuple[Path, str]:
    o, d, tmax = _rays(1000)
    path = folder / "rays.npz"
    if case == "shape":
        path = folder / "rays.npy"
        np.save(path, np.hstack([o, d])[:, :5])
        return path, r"rays\.npy: must have shape \(N, 6\) \(origin, direction\), got \(1000, 5\)"
    if case == "dtype":
        np.savez(path, origins=o, directions=d.astype(complex))
        return path, r"rays\.npz: directions must hold real numbers, got dtype complex128"
    if case == "missing":
        np.savez(path, origins=o)
        return path, r"rays\.npz: has no array 'directions'"
    if case == "length":
        np.savez(path, origins=o, directions=d[:10])
        return path, r"rays\.npz: directions must have shape \(1000, 3\), got \(10, 3\)"
    if case == "compressed":
        np.savez_compressed(path, origins=o, directions=d)
        return path, r"rays\.npz: origins is compressed"
    if case == "extension":
        path = folder / "rays.csv"
        path.write_text("0,0,0,1,0,0\n")
        return path, r"rays\.csv: unknown ray file type '\.csv'"
    if case == "truncated":     # a .npy cut short after it was written: found at the chunk it cuts
        path = folder / "rays.npy"
        np.save(path, np.hstack([o, d]))
        os.truncate(path, path.stat().st_size - 250 * 48)
        return path, r"rays\.npy: chunk 7 \(rays 700 to 799\): ends before row 800 of 1,000"
    if case in ("nan", "inf"):
        o[730] = np.nan if case == "nan" else np.inf
        np.savez(path, origins=o, directions=d, tmax=tmax)
        return path, r"rays\.npz: chunk 7 \(rays 700 to 799\): origins\[730\] is not finite"
    raise ValueError(case)


@pytest.mark.parametrize("case", ["shape", "dtype", "missing", "length", "compressed", "extension", "nan", "inf",
                                  "truncated"])
def test_a_bad_ray_file_is_one_line_and_nothing_is_written_past_the_last_good_chunk(tmp_path, capsys, case):
    path, message = _bad(tmp_path, case)
    out = tmp_path / "hits.zarr"
    status = main(["cast", "spd:tetra:1", "--rays", str(path), "--out", str(out), "--chunk", "100"])
    err = capsys.readouterr().err
    assert status == 2
    assert err.count("\n") == 1 and err.startswith("raykernel: error: "), err
    assert re.search(message, err), err
    written = sorted(int(p.name) for p in (out / "t" / "c").glob("*")) if out.exists() else []
    if case in ("nan", "inf", "truncated"):
        assert written == list(range(7))          # the chunks before the bad one, none after
    else:
        assert not out.exists()                   # refused before anything was made

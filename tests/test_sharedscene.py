"""A RayScene written once to a file and mapped (casting/sharedscene.py): the same answers bit for bit,
arrays of the file's pages typed as before, a handle that pickles small, and a clear error where
the file is gone or is another one."""

from __future__ import annotations

import pickle
import subprocess
import sys

import numpy as np
import pytest

from raykernel.casting.rayscene import RayScene
from raykernel.casting.sharedscene import SharedScene, SharedSceneError
from numba import typeof


def _scene():
    rng = np.random.default_rng(3)
    v = rng.uniform(-1, 1, (60, 3))
    f = rng.integers(0, 60, (150, 3))
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    normals = v / np.linalg.norm(v, axis=1)[:, None]
    return RayScene.from_mesh(v, f, normals=normals)


def _rays(n=500):
    rng = np.random.default_rng(4)
    o = rng.uniform(-2, 2, (n, 3))
    return o, rng.uniform(-0.3, 0.3, (n, 3)) - o


def _same(a, b):
    a, b = np.asarray(a), np.asarray(b)
    assert a.dtype == b.dtype and a.shape == b.shape
    assert np.array_equal(a, b, equal_nan=a.dtype.kind == "f")


def _arrays(rs) -> list:
    """The mesh kernel's arrays (what its queries read)."""
    k = rs._mesh
    return [a for a in (*k.geo, k.corners, k.prims, k.geoms, *k.wide, k.blocks) if isinstance(a, np.ndarray)]


def test_a_mapped_scene_answers_as_the_scene_bit_for_bit(tmp_path):
    rs = _scene()
    o, d = _rays()
    p = o / 2
    with SharedScene.write(rs, tmp_path) as shared:
        mapped = shared.open()
    assert not list(tmp_path.iterdir()), "the file is deleted when the block ends"
    # the arrays are the file's pages, writable and aligned: numba types them as the built scene's
    assert all(not a.flags.owndata and a.flags.writeable for a in _arrays(mapped) if a.size)
    assert typeof(mapped._mesh) == typeof(rs._mesh)
    want, got = rs.intersect(o, d), mapped.intersect(o, d)      # answered after the file was deleted
    for name in ("t", "prim_id", "geom_id", "uv", "normal", "shading_normal"):
        _same(getattr(got, name), getattr(want, name))
    _same(mapped.occluded(o, d), rs.occluded(o, d))
    _same(mapped.count_hits(o, d), rs.count_hits(o, d))
    _same(mapped.distance(p), rs.distance(p))
    near, want_near = mapped.closest_points(p), rs.closest_points(p)
    _same(near.points, want_near.points)
    _same(near.prim_id, want_near.prim_id)


def test_a_write_to_a_mapped_array_stays_in_its_process(tmp_path):
    # copy-on-write: the file's pages are shared until written; a write is the writer's own
    rs = _scene()
    original = rs._mesh.blocks[0, 0]
    with SharedScene.write(rs, tmp_path) as shared:
        first, second = shared.open(), shared.open()
        first._mesh.blocks[0, 0] = original + 1.0
        assert second._mesh.blocks[0, 0] == original
        assert shared.open()._mesh.blocks[0, 0] == original


def test_the_handle_pickles_small_and_opens_in_another_process(tmp_path):
    rs = _scene()
    o, d = _rays(50)
    with SharedScene.write(rs, tmp_path) as shared:
        sent = pickle.dumps(shared)
        assert len(sent) < 4096 < shared.nbytes
        code = ("import pickle, sys, numpy as np\n"
                "rs = pickle.loads(sys.stdin.buffer.read()).open()\n"
                f"o, d = np.array({o.tolist()}), np.array({d.tolist()})\n"
                "print(rs.intersect(o, d, fields=('t', 'prim_id')).prim_id.tolist())")
        out = subprocess.run([sys.executable, "-c", code], input=sent, capture_output=True, check=True)
    assert eval(out.stdout) == rs.intersect(o, d).prim_id.tolist()


def test_a_deleted_or_other_file_is_refused_by_name(tmp_path):
    rs = _scene()
    shared = SharedScene.write(rs, tmp_path)
    other = SharedScene.write(rs, tmp_path)
    with shared:
        (tmp_path / "elsewhere").write_bytes(open(other.path, "rb").read())
    other.delete()
    with pytest.raises(SharedSceneError, match="not on this machine, or was deleted"):
        shared.open()
    impostor = SharedScene(str(tmp_path / "elsewhere"), shared.token, shared.spans, shared.inband)
    with pytest.raises(SharedSceneError, match="is not the shared scene this handle names"):
        impostor.open()


def test_a_write_that_fails_leaves_no_file(tmp_path, monkeypatch):
    from raykernel.casting import sharedscene
    real = sharedscene.os.fdopen

    class Full:             # a disk that fills after the header
        def __init__(self, f):
            self.f, self.calls = f, 0

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.f.close()

        def tell(self):
            return self.f.tell()

        def write(self, data):
            self.calls += 1
            if self.calls > 2:
                raise OSError(28, "No space left on device")
            return self.f.write(data)
    monkeypatch.setattr(sharedscene.os, "fdopen", lambda fd, mode: Full(real(fd, mode)))
    with pytest.raises(OSError, match="No space"):
        SharedScene.write(_scene(), tmp_path)
    assert not list(tmp_path.iterdir())

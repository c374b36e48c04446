"""raykernel.trimesh.RayMeshIntersector against trimesh's own engine (ray_triangle, with rtree)."""

from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest

trimesh = pytest.importorskip("trimesh")
pytest.importorskip("rtree")

import raykernel.trimesh  # noqa: E402
from raykernel import RayInputError, RayScene  # noqa: E402
from raykernel.casting.trimeshray import RayMeshIntersector  # noqa: E402


def meshes():
    rng = np.random.default_rng(5)
    bumpy = trimesh.creation.icosphere(subdivisions=2)
    bumpy.vertices = bumpy.vertices * rng.uniform(0.7, 1.3, (len(bumpy.vertices), 1))     # closed, not convex
    torus = trimesh.creation.torus(major_radius=1.0, minor_radius=0.3)
    return {"icosphere": trimesh.creation.icosphere(subdivisions=3), "box": trimesh.creation.box((1, 2, 3)),
            "bumpy": bumpy, "torus": torus, "capsule": trimesh.creation.capsule(height=1.0, radius=0.4)}


def rays(mesh, rng, n=800):
    lo, hi = mesh.bounds
    c, size = (lo + hi) / 2, (hi - lo).max()
    o = c + rng.normal(size=(n, 3)) * size
    d = c + rng.uniform(-0.6, 0.6, (n, 3)) * size - o
    return o, d


@pytest.mark.parametrize("name", list(meshes()))
def test_every_query_agrees_with_trimesh_native(name):
    mesh = meshes()[name]
    rng = np.random.default_rng(len(name))
    o, d = rays(mesh, rng)
    ours = RayMeshIntersector(mesh)
    native = trimesh.ray.ray_triangle.RayMeshIntersector(mesh)
    # first hits and any hits
    np.testing.assert_array_equal(ours.intersects_any(o, d), native.intersects_any(o, d))
    first = ours.intersects_first(o, d)
    np.testing.assert_array_equal(first, native.intersects_first(o, d))
    assert (first >= 0).mean() > 0.3
    # every hit along each ray: the same (ray, triangle) pairs, the same points
    tri, ray, loc = ours.intersects_id(o, d, multiple_hits=True, return_locations=True)
    ntri, nray, nloc = native.intersects_id(o, d, multiple_hits=True, return_locations=True)
    assert sorted(zip(ray.tolist(), tri.tolist())) == sorted(zip(nray.tolist(), ntri.tolist()))
    order, norder = np.lexsort((tri, ray)), np.lexsort((ntri, nray))
    np.testing.assert_allclose(loc[order], nloc[norder], atol=1e-9 * np.abs(nloc).max())
    assert np.bincount(ray).max() >= 2
    # nearest first, ray by ray
    t = np.einsum("ij,ij->i", loc - o[ray], d[ray])
    same = ray[1:] == ray[:-1]
    assert np.all(np.diff(ray) >= 0) and np.all(t[1:][same] >= t[:-1][same])
    # only the first hit of each ray, and at most two per ray
    tri1, ray1 = ours.intersects_id(o, d, multiple_hits=False)
    np.testing.assert_array_equal(tri1, first[ray1])
    assert len(ray1) == np.count_nonzero(first >= 0)
    _, ray2 = ours.intersects_id(o, d, max_hits=2)
    np.testing.assert_array_equal(np.bincount(ray2, minlength=len(o)), np.minimum(np.bincount(ray, minlength=len(o)),
                                                                                  2))
    loc_a, ray_a, tri_a = ours.intersects_location(o, d)
    np.testing.assert_array_equal(ray_a, ray)
    np.testing.assert_array_equal(tri_a, tri)


@pytest.mark.parametrize("name", ["icosphere", "box", "torus"])
def test_mesh_contains_through_raykernel(name):
    mesh = meshes()[name]
    rng = np.random.default_rng(2)
    lo, hi = mesh.bounds
    points = rng.uniform(lo - 0.2, hi + 0.2, (2000, 3))
    want = trimesh.ray.ray_triangle.RayMeshIntersector(mesh).contains_points(points)
    mesh.ray = raykernel.trimesh.RayMeshIntersector(mesh)
    got = mesh.contains(points)
    np.testing.assert_array_equal(got, want)
    assert 0.1 < got.mean() < 0.9


def test_the_scene_is_cached_and_rebuilt_when_the_mesh_changes():
    mesh = trimesh.creation.box()
    ray = RayMeshIntersector(mesh)
    o, d = np.array([[0.0, 0, 5]]), np.array([[0.0, 0, -1]])
    first = ray.scene
    assert ray.scene is first
    tri, _, loc = ray.intersects_id(o, d, multiple_hits=False, return_locations=True)
    np.testing.assert_allclose(loc, [[0, 0, 0.5]])
    mesh.vertices = mesh.vertices * 2.0
    assert ray.scene is not first
    _, _, loc = ray.intersects_id(o, d, multiple_hits=False, return_locations=True)
    np.testing.assert_allclose(loc, [[0, 0, 1.0]])


def test_pickle_and_copy_keep_the_mesh_not_the_scene():
    mesh = trimesh.creation.icosphere()
    ray = RayMeshIntersector(mesh, accel="grid")
    o, d = rays(mesh, np.random.default_rng(1), 100)
    want = ray.intersects_first(o, d)
    for other in (pickle.loads(pickle.dumps(ray)), copy.copy(ray), copy.deepcopy(ray)):
        assert other.accel == "grid"
        np.testing.assert_array_equal(other.intersects_first(o, d), want)


def test_empty_and_mismatched_rays():
    ray = RayMeshIntersector(trimesh.creation.box())
    e = np.zeros((0, 3))
    assert ray.intersects_first(e, e).shape == (0,) and ray.intersects_any(e, e).shape == (0,)
    tri, idx, loc = ray.intersects_id(e, e, return_locations=True)
    assert tri.shape == idx.shape == (0,) and loc.shape == (0, 3)
    with pytest.raises(ValueError, match="don't match"):
        ray.intersects_first(np.zeros((2, 3)), np.zeros((3, 3)))


def test_rayscene_from_a_trimesh():
    mesh = trimesh.creation.icosphere()
    o, d = np.array([[0.0, 0, 5]]), np.array([[0.0, 0, -1]])
    for rs in (RayScene.from_trimesh(mesh), RayScene.from_mesh(mesh)):
        assert rs.intersect(o, d).t[0] == pytest.approx(4.0, rel=1e-2)
    with pytest.raises(RayInputError, match="vertices and .faces"):
        RayScene.from_trimesh(np.zeros((3, 3)))
    with pytest.raises(RayInputError, match="needs faces"):
        RayScene.from_mesh(np.zeros((3, 3)))


def test_the_depth_image_example_runs(tmp_path, monkeypatch):
    import runpy
    import sys
    from pathlib import Path
    pytest.importorskip("matplotlib")
    out = tmp_path / "depth.png"
    monkeypatch.setattr(sys, "argv", ["depth_image.py", "-o", str(out)])
    runpy.run_path(str(Path(__file__).parents[1] / "examples" / "depth_image.py"), run_name="__main__")
    assert out.stat().st_size > 10_000


def _trimesh_signatures(module: str) -> dict:
    """Each public method of trimesh's RayMeshIntersector in `module` (read from its source, so
    ray_pyembree needs no embreex) -> its parameter names, and "*" / "**" for *args / **kwargs."""
    import ast
    import importlib.util
    source = open(importlib.util.find_spec(f"trimesh.ray.{module}").origin).read()
    cls = next(n for n in ast.walk(ast.parse(source)) if isinstance(n, ast.ClassDef) and n.name == "RayMeshIntersector")
    out = {}
    for f in cls.body:
        if isinstance(f, ast.FunctionDef) and (f.name == "__init__" or not f.name.startswith("_")):
            names = [a.arg for a in f.args.args + f.args.kwonlyargs][1:]
            out[f.name] = names + (["*"] if f.args.vararg else []) + (["**"] if f.args.kwarg else [])
    return out


@pytest.mark.parametrize("module", ["ray_triangle", "ray_pyembree"])
def test_every_trimesh_signature_is_accepted(module):
    import inspect
    theirs = _trimesh_signatures(module)
    assert "intersects_id" in theirs and "__init__" in theirs
    for name, params in theirs.items():
        ours = inspect.signature(getattr(RayMeshIntersector, name)).parameters
        has_kwargs = any(p.kind is p.VAR_KEYWORD for p in ours.values())
        for p in params:
            if p in ("*", "**"):
                continue
            assert p in ours or has_kwargs, f"{module}.RayMeshIntersector.{name}: no parameter {p!r}"
    mesh = trimesh.creation.icosphere()
    o = np.array([[0.11, 0.13, -3.0], [0.0, 3.0, 0.0]])       # off the poles: no shared vertex or edge
    d = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    native = trimesh.ray.ray_triangle.RayMeshIntersector(mesh)
    for ours in (RayMeshIntersector(mesh, scale_to_box=False), RayMeshIntersector(mesh=mesh)):
        assert ours.mesh is mesh and list(ours.intersects_any(o, d)) == [True, False]
        assert np.array_equal(ours.intersects_first(o, d), native.intersects_first(o, d))
        loc, ray, tri = ours.intersects_location(o, d, multiple_hits=True, max_hits=1)
        assert list(ray) == [0] and np.allclose(loc, [[0.11, 0.13, -0.98]], atol=0.02)
    with pytest.raises(TypeError, match="geometry or as mesh"):
        RayMeshIntersector()

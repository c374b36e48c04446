"""RayScene.from_mesh(..., precision="single"): the vertices rounded to float32, the triangle blocks
stored in float32, and every answer exact for the rounded mesh.

Single precision must give, bit for bit, what double precision gives on the mesh whose vertices
are `vertices.astype(np.float32)` (fields, ids, surfaces, every query), must agree with testing
every triangle of that mesh (the brute-force list), and must refuse in one line a mesh whose
triangles float32 cannot hold where they lie.
"""

from __future__ import annotations

import numpy as np
import pytest
from support import MESHES, rays_through, targets

from raykernel import RayScene
from raykernel.casting.rayinput import RayInputError

FIELDS = ("t", "prim_id", "geom_id", "inst_id", "kind", "uv", "normal", "shading_normal")


def rounded(v):
    return np.asarray(v, np.float64).astype(np.float32).astype(np.float64)


def assert_same_answers(a: RayScene, b: RayScene, o, d, tmin=0.0, tmax=np.inf):
    ha, hb = a.intersect(o, d, tmin, tmax), b.intersect(o, d, tmin, tmax)
    for field in FIELDS:
        assert np.array_equal(getattr(ha, field), getattr(hb, field), equal_nan=True), field
    assert np.array_equal(a.occluded(o, d, tmin, tmax), b.occluded(o, d, tmin, tmax))
    assert np.array_equal(a.count_hits(o, d, tmin, tmax), b.count_hits(o, d, tmin, tmax))
    for x, y in zip(a.intersect_all(o, d, tmin, tmax), b.intersect_all(o, d, tmin, tmax)):
        assert np.array_equal(x, y)
    return ha


@pytest.mark.parametrize("name", list(MESHES))
def test_single_is_double_on_the_rounded_mesh_through_shared_edges_and_vertices(name):
    base, f = MESHES[name]
    base = rounded(base)
    v = base * (1 + 2.0 ** -30)         # coordinates that float32 rounds, to base
    assert np.array_equal(rounded(v), base) and not np.array_equal(v, base)
    single = RayScene.from_mesh(v, f, precision="single")
    double = RayScene.from_mesh(base, f)
    assert single._mesh.blocks.dtype == np.float32 and double._mesh.blocks.dtype == np.float64
    # rays exactly through the rounded mesh's vertices and edges, where the watertight rule decides
    o, d = rays_through(targets(base, f, np.random.default_rng(7)), np.array([2.0 ** -5, -3 * 2.0 ** -7, 2.0 ** -6]))
    h = assert_same_answers(single, double, o, d)
    assert np.all(np.isfinite(h.t))      # closed meshes: no ray through an edge or a vertex slips through


def test_single_is_double_on_the_rounded_mesh_for_intervals_axis_parallel_rays_and_smooth_normals():
    rng = np.random.default_rng(21)
    v, f = MESHES["lumpy-0"]
    v = v * 3.3 - 0.7
    n = v / np.linalg.norm(v, axis=1)[:, None]
    o = rng.normal(size=(2000, 3)) * 6
    d = rng.normal(size=(2000, 3)) * 0.1 - 0.1 * o
    d[:400] = 0.0
    d[np.arange(400), rng.integers(0, 3, 400)] = rng.choice([-1.0, 1.0], 400)
    tmin = rng.uniform(0, 1, 2000)
    tmax = tmin + rng.uniform(0, 60, 2000)
    h = assert_same_answers(RayScene.from_mesh(v, f, normals=n, precision="single"),
                            RayScene.from_mesh(rounded(v), f, normals=n), o, d, tmin, tmax)
    assert 0.1 < np.mean(np.isfinite(h.t)) < 0.9
    # through the general path (an accel given), the same rounded mesh
    assert_same_answers(RayScene.from_mesh(v, f, accel="bvh(width=2)", precision="single"),
                        RayScene.from_mesh(rounded(v), f, accel="bvh(width=2)"), o[:300], d[:300])


@pytest.mark.parametrize("scale, shift", [(1e-6, 0.0), (1.0, 0.0), (1e7, 0.0), (1.0, 1e3)])
def test_single_against_every_triangle_of_the_rounded_mesh(scale, shift):
    v0, f = MESHES["icosphere"]
    rng = np.random.default_rng(16)
    v = v0 * scale * 1.01 + shift
    o = np.r_[rng.normal(size=(600, 3)) * 3, rng.uniform(-0.5, 0.5, (200, 3))] * scale + shift
    d = rng.normal(size=(800, 3))
    d[:150] = 0.0
    d[np.arange(150), rng.integers(0, 3, 150)] = rng.choice([-1.0, 1.0], 150)
    single = RayScene.from_mesh(v, f, precision="single")
    brute = RayScene.from_mesh(rounded(v), f, accel="list")
    a, b = single.intersect(o, d), brute.intersect(o, d)
    assert np.array_equal(a.t, b.t) and np.array_equal(a.prim_id, b.prim_id)
    assert np.array_equal(single.occluded(o, d), brute.occluded(o, d))
    assert np.array_equal(single.count_hits(o, d), brute.count_hits(o, d))
    assert 0.2 < np.mean(np.isfinite(a.t)) < 1.0


def test_single_refuses_triangles_float32_cannot_hold_and_unknown_precisions():
    v, f = MESHES["icosphere"]
    with pytest.raises(RayInputError, match=r"triangle \d+ is smaller than float32 resolves.*precision='double'") as e:
        RayScene.from_mesh(v * 1e-3 + 1e7, f, precision="single")      # float32's step at 1e7 is 1
    assert "\n" not in str(e.value)
    RayScene.from_mesh(v * 1e-3 + 1e7, f)                               # double holds it
    # one such triangle among good ones is named, with the size and place that float32 cannot hold
    tiny = np.array([[1e7, 0.0, 0.0], [1e7 + 0.25, 0.0, 0.0], [1e7, 0.0, 4.0]])
    with pytest.raises(RayInputError, match=rf"triangle {len(f) + 1} is .*corners 0.25 apart at 1e\+07 "):
        RayScene.from_mesh(np.r_[v, tiny], np.r_[f, [[0, 1, 2]], [[len(v), len(v) + 1, len(v) + 2]]],
                           precision="single")
    for bad in ("half", "float32", 32):
        with pytest.raises(RayInputError, match="precision must be one of double, single"):
            RayScene.from_mesh(v, f, precision=bad)


def test_single_takes_fewer_bytes_and_says_so():
    v, f = MESHES["lumpy-1"]
    single, double = RayScene.from_mesh(v, f, precision="single"), RayScene.from_mesh(v, f)
    assert single.build_stats["precision"] == "single" and double.build_stats["precision"] == "double"
    assert single._mesh.blocks.nbytes * 2 == double._mesh.blocks.nbytes
    assert single.build_stats["bytes_per_triangle"] < 0.7 * double.build_stats["bytes_per_triangle"]


def test_mesh_objects_pass_the_precision_on():
    class Mesh:
        vertices, faces = MESHES["cube"][0] * 1.1, MESHES["cube"][1]

    for scene in (RayScene.from_trimesh(Mesh(), precision="single"), RayScene.from_mesh(Mesh(), precision="single")):
        assert scene._mesh.blocks.dtype == np.float32
        assert np.array_equal(scene.scene.root.meshes[0].vertices, rounded(Mesh.vertices))


def test_the_bvh_spec_names_the_precision_as_the_argument_does(tmp_path):
    """accel="bvh(precision=single)" is precision="single": the rounded mesh, float32 blocks, the
    same answers as double precision on the rounded vertices; without either, double."""
    trimesh = pytest.importorskip("trimesh")
    from raykernel.scene.meshfile import mesh_arrays

    v, f = MESHES["lumpy-1"]
    v = v * 1.7 + 0.3
    rng = np.random.default_rng(5)
    o = rng.normal(size=(1500, 3)) * 4
    d = rng.normal(size=(1500, 3)) * 0.2 - 0.1 * o
    path = tmp_path / "lumpy.obj"
    trimesh.Trimesh(v, f, process=False).export(path)
    for spec, blocks in (("bvh(precision=single)", np.float32), ("bvh(leaf=2, precision=single)", np.float32),
                         ("bvh(width=2, precision=single)", None)):
        plain = spec.replace(", precision=single", "").replace("(precision=single)", "")
        for given, single in ((v, RayScene.from_mesh(v, f, accel=spec)),
                              (v, RayScene.from_mesh(v, f, accel=spec, precision="single")),
                              (mesh_arrays(path)[0], RayScene.from_file(path, accel=spec))):
            want = RayScene.from_mesh(rounded(given), f, accel=plain)
            assert single.build_stats["precision"] == "single"
            assert np.array_equal(single.scene.root.meshes[0].vertices, rounded(given))
            if blocks is not None:
                assert single._mesh.blocks.dtype == blocks and want._mesh.blocks.dtype == np.float64
            assert_same_answers(single, want, o, d)
    double = RayScene.from_mesh(v, f, accel="bvh(precision=double)")
    assert double.build_stats["precision"] == "double" and double._mesh.blocks.dtype == np.float64
    assert np.array_equal(double.scene.root.meshes[0].vertices, v)
    assert RayScene.from_mesh(v, f).build_stats["precision"] == "double"


def test_a_precision_given_twice_must_agree_and_single_is_refused_where_it_does_not_apply(tmp_path):
    import raykernel
    from raykernel.cli import main
    from raykernel.errors import OptionError

    v, f = MESHES["cube"]
    with pytest.raises(RayInputError, match="disagree: give the precision once") as e:
        RayScene.from_mesh(v, f, accel="bvh(precision=single)", precision="double")
    assert "\n" not in str(e.value)
    with pytest.raises(OptionError, match="precision must be one of double, single"):
        RayScene.from_mesh(v, f, accel="bvh(precision=half)")
    scene = raykernel.load("spd:tetra")
    for build in (lambda: RayScene(scene, accel="bvh(precision=single)"),
                  lambda: raykernel.render(scene, accel="bvh(precision=single)", resolution=4)):
        with pytest.raises(OptionError, match=r"bvh\(precision=single\) is for the triangle meshes of "
                                              r"RayScene.from_mesh.*traced in double precision"):
            build()
    out = tmp_path / "t.png"
    assert main(["render", "spd:tetra", "--resolution", "4", "--accel", "bvh(precision=single)", "-o", str(out)]) != 0
    assert not out.exists()

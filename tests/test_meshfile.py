"""Model files (OBJ + MTL, PLY, STL, OFF, GLB) read through trimesh: triangles, materials, camera, errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

trimesh = pytest.importorskip("trimesh")

from raykernel import RayScene  # noqa: E402
from raykernel.errors import SceneError  # noqa: E402
from raykernel.rendering.render import render  # noqa: E402
from raykernel.scene.loading import load  # noqa: E402
from raykernel.scene.meshfile import mesh_arrays  # noqa: E402

OBJ = """mtllib m.mtl
v 0 0 0
v 1 0 0
v 0 1 0
v 0 0 1
usemtl red
f 1 2 3
usemtl glass
f 1 2 4
f 1 3 4
"""
MTL = """newmtl red
Kd 0.8 0.1 0.1
Ks 0.5 0.5 0.5
Ns 40
newmtl glass
Kd 0.9 0.9 0.9
d 0.2
Ni 1.5
"""


def _all_in_view(scene, points) -> bool:
    """Every point within the camera's cone of view (angle / 2 around the line of sight)."""
    cam = scene.camera
    axis = (cam.look_at - cam.eye) / np.linalg.norm(cam.look_at - cam.eye)
    to = points - cam.eye
    cos = (to @ axis) / np.linalg.norm(to, axis=1)
    return bool(np.all(cos >= math.cos(math.radians(cam.angle) / 2)))


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("models")
    (d / "m.obj").write_text(OBJ)
    (d / "m.mtl").write_text(MTL)
    sphere = trimesh.creation.icosphere(2)
    sphere.apply_translation([3.0, -1.0, 2.0])
    sphere.visual.face_colors = np.where((np.arange(len(sphere.faces)) % 2 == 0)[:, None], [255, 0, 0, 255],
                                         [0, 0, 255, 255])
    sphere.export(d / "s.ply")
    box = trimesh.creation.box(extents=(2.0, 1.0, 0.5))
    box.export(d / "b.stl")
    box.export(d / "b.off")
    scene = trimesh.Scene()
    scene.add_geometry(box, transform=trimesh.transformations.translation_matrix([0.0, 0.0, -4.0]))
    scene.set_camera(angles=(0.2, 0.3, 0.0), distance=8.0, fov=(50.0, 50.0))
    (d / "c.glb").write_bytes(scene.export(file_type="glb"))
    return d, sphere, box, scene


def test_obj_with_its_mtl(files):
    d, *_ = files
    scene = load(d / "m.obj")
    faces = sum(len(m.faces) for m in scene.root.meshes)
    assert faces == 3
    by_colour = {m.color: m for m in scene.materials}
    red, glass = by_colour[(0.8, 0.1, 0.1)], by_colour[(0.9, 0.9, 0.9)]
    assert (red.ks, red.shine, red.t) == (0.5, 40.0, 0.0)
    assert glass.t == pytest.approx(0.8) and glass.ior == 1.5
    used = sorted(int(i) for m in scene.root.meshes for i in m.material)
    assert used == sorted([scene.materials.index(red)] + 2 * [scene.materials.index(glass)])
    verts = np.concatenate([m.vertices for m in scene.root.meshes])
    assert _all_in_view(scene, verts)


def test_ply_face_colours_become_materials(files):
    d, sphere, *_ = files
    scene = load(d / "s.ply")
    (mesh,) = scene.root.meshes
    assert len(mesh.faces) == len(sphere.faces)
    colours = [scene.materials[i].color for i in mesh.material]
    expect = [(1.0, 0.0, 0.0) if tuple(c[:3]) == (255, 0, 0) else (0.0, 0.0, 1.0) for c in sphere.visual.face_colors]
    # trimesh may reorder faces on load: compare the faces' colours by the faces' centres
    centres = mesh.vertices[mesh.faces].mean(axis=1)
    order = [int(np.argmin(np.linalg.norm(sphere.triangles_center - c, axis=1))) for c in centres]
    assert colours == [expect[k] for k in order]
    assert _all_in_view(scene, mesh.vertices)


@pytest.mark.parametrize("name, up", [("b.stl", 2), ("b.off", 1)])
def test_stl_and_off_are_framed(files, name, up):
    d, _, box, _ = files
    scene = load(d / name)
    verts = np.concatenate([m.vertices for m in scene.root.meshes])
    assert sum(len(m.faces) for m in scene.root.meshes) == len(box.faces)
    assert np.allclose(verts.min(axis=0), box.bounds[0]) and np.allclose(verts.max(axis=0), box.bounds[1])
    assert scene.camera.up[up] == 1.0 and _all_in_view(scene, verts)
    assert scene.materials and all(m.color == (0.8, 0.8, 0.8) for m in scene.materials)


def test_glb_keeps_its_camera_and_transforms(files):
    d, _, box, tm_scene = files
    scene = load(d / "c.glb")
    verts = np.concatenate([m.vertices for m in scene.root.meshes])
    assert np.allclose(verts.min(axis=0), box.bounds[0] + [0, 0, -4]) and np.allclose(verts.max(axis=0),
                                                                                       box.bounds[1] + [0, 0, -4])
    transform = tm_scene.camera_transform
    assert np.allclose(scene.camera.eye, transform[:3, 3])
    sight = (scene.camera.look_at - scene.camera.eye) / np.linalg.norm(scene.camera.look_at - scene.camera.eye)
    assert np.allclose(sight, -transform[:3, 2]) and scene.camera.angle == pytest.approx(50.0)


@pytest.mark.parametrize("name", ["m.obj", "s.ply", "b.stl", "b.off", "c.glb"])
def test_each_renders_and_hits_the_model(files, name):
    d, *_ = files
    scene = load(d / name)
    result = render(scene, accel="bvh", resolution=24, threads=1)
    assert result.stats["rays.eye_hit"] > 0
    background = np.round(np.asarray(scene.background) * 255)
    assert np.any(np.abs(result.image.reshape(-1, 3).astype(float) - background).sum(axis=1) > 3)
    listed = render(scene, accel="list", resolution=24, threads=1)
    assert np.array_equal(listed.image, result.image)


def test_rayscene_from_file_matches_the_mesh(files):
    d, sphere, *_ = files
    rs = RayScene.from_file(d / "s.ply")
    v, f = mesh_arrays(d / "s.ply")
    direct = RayScene.from_mesh(v, f)
    rng = np.random.default_rng(3)
    o = rng.uniform(-3, 3, (500, 3)) + [3.0, -1.0, 2.0]
    dirs = [3.0, -1.0, 2.0] + rng.normal(scale=0.5, size=(500, 3)) - o     # most towards the sphere
    a, b = rs.intersect(o, dirs), direct.intersect(o, dirs)
    assert np.array_equal(a.t, b.t) and np.array_equal(a.prim_id, b.prim_id)
    assert np.isfinite(a.t).sum() > 100
    assert len(f) == len(sphere.faces)


def test_command_line_renders_a_model(files, tmp_path):
    from raykernel.cli import main
    d, *_ = files
    out = tmp_path / "m.png"
    assert main(["render", str(d / "m.obj"), "--resolution", "16", "-o", str(out)]) == 0
    assert out.stat().st_size > 100


@pytest.mark.parametrize("name, content, message", [
    ("bad.ply", b"ply\nformat binary_little_endian 1.0\nelement vertex 100\nproperty float x\nend_header\n\x00",
     "cannot read it as PLY"),
    ("empty.obj", b"this is not an obj\n", "holds no triangles"),
    ("nothing.stl", b"", "holds no triangles"),
])
def test_bad_model_files_give_one_line(tmp_path, capsys, name, content, message):
    from raykernel.cli import main
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(SceneError, match=message):
        load(path)
    assert main(["render", str(path), "--resolution", "8", "-o", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err
    assert name in err and message in err and err.count("\n") == 1
    assert not (tmp_path / "x.png").exists()
    with pytest.raises(SceneError, match="no such file"):
        load(tmp_path / "missing.glb")


def test_view_options_set_the_camera(files, tmp_path, capsys):
    from PIL import Image

    from raykernel.cli import main
    from raykernel.scene import Camera
    d, *_ = files
    out = tmp_path / "v.png"
    assert main(["render", str(d / "b.stl"), "--resolution", "16", "--eye", "4,-5,3", "--look-at", "0,0,0.1",
                 "--up", "0,0,1", "--angle", "35", "-o", str(out)]) == 0
    scene = load(d / "b.stl")
    scene.camera = Camera(eye=[4, -5, 3], look_at=[0, 0, 0.1], up=[0, 0, 1], angle=35.0)
    from raykernel.rendering.imageio import to_uint8
    expect = to_uint8(render(scene, resolution=16).image)
    assert np.array_equal(np.asarray(Image.open(out)), expect)
    assert len(np.unique(expect.reshape(-1, 3), axis=0)) > 3         # the box is in view, not just background
    capsys.readouterr()
    assert main(["render", str(d / "b.stl"), "--resolution", "8", "--eye", "1,1,1", "--look-at", "1,1,1",
                 "-o", str(tmp_path / "w.png")]) == 2
    err = capsys.readouterr().err
    assert "eye and look_at are the same point" in err and err.count("\n") == 1
    with pytest.raises(SystemExit):
        main(["render", str(d / "b.stl"), "--eye", "1,2", "-o", str(tmp_path / "w.png")])
    assert "three numbers" in capsys.readouterr().err
    assert not (tmp_path / "w.png").exists()

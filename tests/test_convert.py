"""Converting scenes to NFF, JSON, Wavefront OBJ and POV-Ray."""

from __future__ import annotations

import math
import re
import shutil
import subprocess

import numpy as np
import pytest
from PIL import Image

import raykernel
from raykernel.cli import main
from raykernel.errors import OptionError, SceneError
from raykernel.scene import Camera, Group, Instance, Material, Scene, TriangleMesh
from raykernel.scene.convert import convert, scene_to_obj, scene_to_pov
from raykernel.scene.jsonscene import read_json
from raykernel.scene.nff import read_nff

POVRAY = shutil.which("povray")
needs_povray = pytest.mark.skipif(POVRAY is None, reason="povray is not installed (Debian package `povray`); "
                                  "the POV-Ray rendering tests need it")

BACKGROUND = (0.1, 0.1, 0.3)


def two_spheres(width=64, height=64) -> Scene:
    """A grey sphere in the middle and a red one on the right (NFF: +x is right
    for a camera on -y looking at the origin with z up)."""
    scene = Scene(camera=Camera(eye=(0, -10, 0), look_at=(0, 0, 0), up=(0, 0, 1), angle=40.0,
                                width=width, height=height), background=BACKGROUND)
    scene.add_light((-5, -10, 10))
    grey = scene.add_material(Material((0.8, 0.8, 0.8), kd=0.9))
    red = scene.add_material(Material((1.0, 0.0, 0.0), kd=0.9))
    scene.root.spheres.add((0, 0, 0), 1.0, grey)
    scene.root.spheres.add((2.4, 0, 0), 1.0, red)
    return scene


def sphere_scene(radius=1.5) -> Scene:
    """One sphere at (1, 2, 3)."""
    scene = Scene(camera=Camera(eye=(1, -8, 3), look_at=(1, 2, 3)))
    scene.add_light((5, -5, 5))
    scene.root.spheres.add((1, 2, 3), radius, scene.add_material(Material((0.2, 0.6, 0.9))))
    return scene


def obj_faces(text: str) -> list[list[str]]:
    return [line.split()[1:] for line in text.splitlines() if line.startswith("f ")]


def obj_vertices(text: str) -> np.ndarray:
    return np.array([[float(x) for x in line.split()[1:]] for line in text.splitlines() if line.startswith("v ")])


# ---- OBJ ----------------------------------------------------------------------------------------


def test_obj_of_the_spd_teapot_loads_in_trimesh(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    written = convert("spd:teapot:6", tmp_path / "teapot.obj")
    assert [p.name for p in written] == ["teapot.obj", "teapot.mtl"]
    scene = raykernel.load("spd:teapot:6")
    patches, quads = len(scene.root.patches), len(scene.root.polygons)
    assert (patches, quads) == (64 * 36 - 8 * 6, 36)
    mesh = trimesh.load(tmp_path / "teapot.obj", force="mesh")
    assert len(mesh.faces) == patches + 2 * quads
    mtl = (tmp_path / "teapot.mtl").read_text()
    assert mtl.count("newmtl ") == len(scene.materials)
    text = (tmp_path / "teapot.obj").read_text()
    assert "mtllib teapot.mtl" in text
    assert len(re.findall(r"^usemtl m\d+$", text, re.M)) >= 2
    # patches carry their normals
    assert sum(1 for f in obj_faces(text) if "//" in f[0]) == patches


@pytest.mark.parametrize("segments", [3, 8, 16, 24])
def test_obj_sphere_faces_depend_on_segments(segments, tmp_path):
    obj, _ = scene_to_obj(sphere_scene(1.5), segments=segments)
    rings = max(2, segments // 2)
    faces = obj_faces(obj)
    assert len(faces) == segments * rings
    triangles = sum(len(f) - 2 for f in faces)
    assert triangles == 2 * segments * (rings - 1)
    v = obj_vertices(obj)
    np.testing.assert_allclose(np.linalg.norm(v - (1, 2, 3), axis=1), 1.5, rtol=1e-9)
    out = tmp_path / f"s{segments}.obj"
    convert(sphere_scene(), out, segments=segments)
    trimesh = pytest.importorskip("trimesh")
    mesh = trimesh.load(out, force="mesh", process=False)
    assert len(mesh.faces) == triangles
    assert mesh.volume > 0                      # closed and facing outwards
    assert mesh.volume < 4 / 3 * math.pi * 1.5 ** 3


def test_obj_sphere_faces_point_outwards():
    obj, _ = scene_to_obj(sphere_scene(2.0), segments=12)
    v = obj_vertices(obj)
    for f in obj_faces(obj):
        idx = [int(x.split("/")[0]) - 1 for x in f]
        p = v[idx]
        n = np.cross(p[1] - p[0], p[2] - p[0])
        if np.linalg.norm(n) == 0:
            n = np.cross(p[2] - p[0], p[3] - p[0])
        assert np.dot(n, p.mean(axis=0) - (1, 2, 3)) > 0


def test_obj_cones_instances_and_group_names():
    scene = two_spheres()
    part = Group(name="leg part")
    part.cones.add((0, 0, 0), 1.0, (0, 0, 2), 0.5, 0)
    part.polygons.add([(0, 0, 0), (1, 0, 0), (1, 1, 0)], 1)
    shift = np.eye(4)
    shift[:3, 3] = (10, 0, 0)
    mirror = np.diag([-1.0, 1.0, 1.0, 1.0])
    scene.root.add(Instance(part, np.eye(4)))
    scene.root.add(Instance(part, shift))
    scene.root.add(Instance(part, mirror))
    obj, _ = scene_to_obj(scene, segments=10)
    names = re.findall(r"^o (.+)$", obj, re.M)
    assert names == ["root", "root/leg_part", "root/leg_part_2", "root/leg_part_3"]
    assert re.findall(r"^g (.+)$", obj, re.M) == names
    blocks = obj.split("\no ")
    v1, v2, v3 = (obj_vertices("\n" + b) for b in blocks[2:5])
    np.testing.assert_allclose(v2, v1 + (10, 0, 0))
    np.testing.assert_allclose(v3, v1 * (-1, 1, 1))
    assert len(obj_faces("\n" + blocks[2])) == 10 + 1
    # under the mirror the triangle's winding is reversed, so it still faces +z
    tri1 = obj_faces("\n" + blocks[2])[-1]
    tri3 = obj_faces("\n" + blocks[4])[-1]

    def normal(face, v, base):
        p = v[[int(x.split("/")[0]) - 1 - base for x in face]]
        return np.cross(p[1] - p[0], p[2] - p[0])
    n_verts = len(obj_vertices("\n" + blocks[0])) + len(obj_vertices("\n" + blocks[1]))
    n1 = normal(tri1, v1, n_verts)
    n3 = normal(tri3, v3, n_verts + 2 * len(v1))
    assert n1[2] > 0 and n3[2] > 0


def test_obj_mesh_and_mtl():
    scene = two_spheres()
    glass = scene.add_material(Material((0.9, 0.9, 1.0), kd=0.2, ks=0.3, shine=50, t=0.6, ior=1.5))
    scene.root.add(TriangleMesh([(0, 0, 0), (1, 0, 0), (0, 1, 0), (1, 1, 0)], [(0, 1, 2), (1, 3, 2)], glass,
                                normals=[(0, 0, 1)] * 4))
    obj, mtl = scene_to_obj(scene, mtl_name="x.mtl")
    assert "mtllib x.mtl" in obj
    last = obj_faces(obj)[-2:]
    n_v = len(obj_vertices(obj))
    n_vn = obj.count("\nvn ")
    assert last == [[f"{n_v - 3}//{n_vn - 3}", f"{n_v - 2}//{n_vn - 2}", f"{n_v - 1}//{n_vn - 1}"],
                    [f"{n_v - 2}//{n_vn - 2}", f"{n_v}//{n_vn}", f"{n_v - 1}//{n_vn - 1}"]]
    assert obj.rstrip().splitlines()[-3] == f"usemtl m{glass}"
    block = mtl.split(f"newmtl m{glass}\n")[1].split("\n\n")[0]
    assert "Kd 0.18 0.18 0.2" in block
    assert "d 0.4" in block and "Ni 1.5" in block and "illum 6" in block
    assert "Ns 50" in block


# ---- NFF and JSON -------------------------------------------------------------------------------


def test_nff_and_json_round_trip(tmp_path):
    src = raykernel.load("spd:teapot:3")
    n = src.count_primitives()
    convert("spd:teapot:3", tmp_path / "t.nff")
    assert read_nff(tmp_path / "t.nff").count_primitives() == n
    convert("spd:teapot:3", tmp_path / "t.json")
    assert read_json(tmp_path / "t.json").count_primitives() == n
    assert main(["convert", "scene:diamond:facets=20", "-o", str(tmp_path / "d.nff")]) == 0
    assert read_nff(tmp_path / "d.nff").count_primitives() == 2 * 20 + 1 + 144


# ---- POV-Ray ------------------------------------------------------------------------------------


def test_pov_text():
    scene = two_spheres(width=512, height=512)
    glass = scene.add_material(Material((1, 1, 1), kd=0.1, ks=0.4, shine=30, t=0.8, ior=1.33))
    scene.root.cones.add((0, 0, 0), 1.0, (0, 0, 1), 0.0, glass)
    scene.root.polygons.add([(0, 0, 0), (2, 0, 0), (2, 0, 2), (1, 0, 1), (0, 0, 2)], 0)
    scene.root.patches.add([(0, 0, 0), (1, 0, 0), (1, 0, 1), (0, 0, 1)], 1, [(0, -1, 0)] * 4)
    scene.root.add(TriangleMesh([(0, 0, 0), (1, 0, 0), (0, 1, 0)], [(0, 1, 2)], 0))
    text = scene_to_pov(scene)
    assert "#version 3.7;" in text
    angle = float(re.search(r"^\s*angle ([0-9.eE+-]+)$", text, re.M).group(1))
    expected = math.degrees(2 * math.atan(512 / 511 * math.tan(math.radians(40.0) / 2)))
    assert angle == pytest.approx(expected, rel=1e-9)
    assert re.search(r"^\s*right <1, 0, 0>$", text, re.M)   # NFF: +x is right for this camera
    assert re.search(r"^\s*up <0, 0, 1>$", text, re.M)
    assert text.count("light_source {") == 1
    assert "background { color rgb <0.1, 0.1, 0.3> }" in text
    assert text.count("\nsphere {") == 2
    assert re.search(r"\ncone \{ <0, 0, 0>, 1, <0, 0, 1>, 0 open texture \{ RK_M2 \} interior \{ RK_I2 \} \}", text)
    assert "#declare RK_I2 = interior { ior 1.33 }" in text
    assert re.search(r"#declare RK_M2 = texture \{ pigment \{ color rgbt <1, 1, 1, 0.8> \} finish \{ ambient 0 "
                     r"diffuse 0.1 phong 0.4 phong_size 30 reflection \{ 0.4 \} \} \}", text)
    # the concave polygon is one polygon object, closed by repeating its first vertex
    assert "polygon { 6, <0, 0, 0>, <2, 0, 0>, <2, 0, 2>, <1, 0, 1>, <0, 0, 2>, <0, 0, 0> texture { RK_M0 } }" in text
    assert text.count("\nsmooth_triangle {") == 2
    assert "mesh {" in text and "  triangle {" in text


def povray(tmp_path, pov_name: str, size: int = 64) -> np.ndarray:
    png = pov_name.replace(".pov", ".png")
    result = subprocess.run([POVRAY, f"+I{pov_name}", f"+O{png}", f"+W{size}", f"+H{size}", "-D", "+FN",
                             "File_Gamma=1.0"], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-2000:]
    return np.asarray(Image.open(tmp_path / png).convert("RGB"), np.float64) / 255.0


@needs_povray
def test_pov_renders_and_is_not_mirrored(tmp_path):
    convert(two_spheres(), tmp_path / "spheres.pov")
    image = povray(tmp_path, "spheres.pov")
    assert image.shape == (64, 64, 3)
    center = image[26:38, 26:38].reshape(-1, 3).mean(axis=0)
    assert np.abs(center - BACKGROUND).max() > 0.2            # the grey sphere is there
    redness = image[:, :, 0] - (image[:, :, 1] + image[:, :, 2]) / 2
    left, right = redness[:, :32].mean(), redness[:, 32:].mean()
    assert right > left + 0.05                                  # the red sphere is on the right


@needs_povray
def test_pov_concave_polygon_stays_concave(tmp_path):
    scene = Scene(camera=Camera(eye=(0, -10, 0), look_at=(0, 0, 0), up=(0, 0, 1), angle=30.0, width=64,
                                height=64), background=(0, 0, 0))
    scene.add_light((0, -10, 0))
    white = scene.add_material(Material((1, 1, 1), kd=1.0))
    # a U: two arms and a base, the notch between the arms open
    scene.root.polygons.add([(-2, 0, -2), (2, 0, -2), (2, 0, 2), (1, 0, 2), (1, 0, -1), (-1, 0, -1), (-1, 0, 2),
                             (-2, 0, 2)], white)
    convert(scene, tmp_path / "u.pov")
    image = povray(tmp_path, "u.pov").mean(axis=2)
    ours = np.clip(raykernel.render(scene).image, 0, 1).mean(axis=2)
    # pixel rows go down, columns right: the notch (x 0, z 1) is dark, the arms (x +-1.5, z 1) lit
    def at(img, x, z):
        half = 10 * math.tan(math.radians(15.0)) * 64 / 63
        col = int((x / half + 1) / 2 * 64)
        row = int((1 - z / half) / 2 * 64)
        return img[row, col]
    for img in (image, ours):
        assert at(img, 0.0, 1.0) < 0.1
        assert at(img, 1.5, 1.0) > 0.5 and at(img, -1.5, 1.0) > 0.5 and at(img, 0.0, -1.5) > 0.5
    assert np.abs(image - ours).mean() < 0.02


@needs_povray
def test_pov_of_the_spd_teapot_matches_our_render(tmp_path):
    convert("spd:teapot:3", tmp_path / "teapot.pov")
    image = povray(tmp_path, "teapot.pov")
    ours = np.round(np.clip(raykernel.render(raykernel.load("spd:teapot:3"), resolution=64).image, 0, 1) * 255) / 255
    assert np.abs(image - ours).mean() < 0.04
    mirrored = ours[:, ::-1]
    assert np.abs(image - mirrored).mean() > 2 * np.abs(image - ours).mean()


# ---- errors -------------------------------------------------------------------------------------


def test_unknown_output_suffix(tmp_path):
    with pytest.raises(OptionError, match=r"\.stl"):
        convert(two_spheres(), tmp_path / "x.stl")
    with pytest.raises(OptionError, match="no suffix"):
        convert(two_spheres(), tmp_path / "x")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("suffix", [".obj", ".pov", ".nff", ".json"])
def test_unwritable_directory(suffix, tmp_path):
    with pytest.raises(SceneError, match="does not exist"):
        convert(two_spheres(), tmp_path / "missing" / f"x{suffix}")
    (tmp_path / "file").write_text("")
    with pytest.raises(SceneError, match="not a directory"):
        convert(two_spheres(), tmp_path / "file" / f"x{suffix}")


def test_bad_segments(tmp_path):
    for bad in (2, 0, -1, 2.5, True, 10_000):
        with pytest.raises(OptionError, match="segments"):
            convert(two_spheres(), tmp_path / "x.obj", segments=bad)
    assert list(tmp_path.iterdir()) == []


def test_bad_material_writes_nothing(tmp_path):
    scene = two_spheres()
    scene.root.spheres.add((0, 0, 5), 1.0, 7)
    (tmp_path / "x.pov").write_text("old")
    for name in ("x.pov", "x.obj"):
        with pytest.raises(SceneError, match="material 7"):
            convert(scene, tmp_path / name)
    assert (tmp_path / "x.pov").read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.pov"]


def test_cli_convert(tmp_path, capsys):
    out = tmp_path / "balls.obj"
    assert main(["convert", "spd:balls:1", "-o", str(out), "--segments", "6"]) == 0
    text = out.read_text()
    assert len(obj_faces(text)) == 10 * 6 * 3 + 1        # 10 spheres of 6 x 3 faces, one polygon
    assert (tmp_path / "balls.mtl").exists()
    assert main(["convert", "spd:balls:1", "-o", str(tmp_path / "balls.pov")]) == 0
    assert "balls.pov" in capsys.readouterr().out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["balls.mtl", "balls.obj", "balls.pov"]
    assert main(["convert", "spd:balls:1", "-o", str(tmp_path / "balls.3ds")]) == 2
    assert ".3ds" in " ".join(capsys.readouterr().err.split())
    assert main(["convert", "spd:balls:1", "-o", str(tmp_path / "no" / "balls.pov")]) == 2
    assert "does not exist" in " ".join(capsys.readouterr().err.split())
    assert main(["convert", "nothing-here.nff", "-o", str(tmp_path / "x.pov")]) == 2
    with pytest.raises(SystemExit):
        main(["convert", "spd:balls:1", "-o", str(tmp_path / "x.obj"), "--segments", "0"])

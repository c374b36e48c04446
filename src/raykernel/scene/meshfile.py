"""Scenes from the model files people have: OBJ (with MTL), PLY, STL, OFF, glTF and GLB, read by trimesh.

    scene = load("bunny.ply")                   # raykernel.load, and every command that takes a scene
    scene = read_mesh_file("car.glb")
    vertices, faces = mesh_arrays("part.stl")   # every mesh of the file in one (RayScene.from_file)

Each mesh of the file becomes a triangle mesh of the scene's root group, placed by the file's
node transforms. Materials become NFF-style ones: an MTL material's Kd colour, Ks (its mean the
specular weight), Ns (the Phong exponent), d or Tr (transmission) and Ni (index of refraction);
a glTF material's base colour, with metallic surfaces specular, smooth ones shiny and blended
alpha transmitted; face or vertex colours one material per distinct colour (at most 216, rounded
to six levels a channel beyond that); anything else light grey. Shading is flat (the facets'
own normals). A glTF camera is used as the file gives it; otherwise the camera is framed around
the model: it looks at the centre of its box from the front, right and above, with the whole box
in view; up is +Z for STL files (CAD and 3D printing) and +Y for the others (glTF's and most
scanners'). Two point lights, one near the eye and one to the other side, light it.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..errors import OptionError, SceneError
from .model import Camera, Light, Material, Scene, TriangleMesh

SUFFIXES = (".obj", ".ply", ".stl", ".off", ".glb", ".gltf")
GREY = Material(color=(0.8, 0.8, 0.8), kd=1.0)
MAX_COLOURS = 216


def _trimesh():
    try:
        import trimesh
    except ImportError:
        raise OptionError("reading model files needs trimesh: pip install 'raykernel[mesh]'") from None
    return trimesh


def _read(path: Path):
    """The file as a trimesh.Scene, or a SceneError naming the file."""
    trimesh = _trimesh()
    if not path.exists():
        raise SceneError("no such file", path=str(path))
    try:
        loaded = trimesh.load(str(path), force="scene")
    except Exception as e:      # trimesh raises many kinds of errors on bad files
        raise SceneError(f"cannot read it as {path.suffix.lower()[1:].upper()}: {e}", path=str(path)) from None
    return loaded


def _placed(loaded):
    """(mesh, 4x4 transform) for every triangle mesh the file's graph places."""
    out = []
    for node in loaded.graph.nodes_geometry:
        transform, name = loaded.graph[node]
        mesh = loaded.geometry.get(name)
        if mesh is not None and hasattr(mesh, "faces") and len(mesh.faces):
            out.append((mesh, np.asarray(transform, np.float64)))
    return out


def mesh_arrays(path) -> tuple[np.ndarray, np.ndarray]:
    """Every mesh of a model file in one: vertices (V, 3) float64 and faces (F, 3) int64."""
    path = Path(path)
    vertices, faces, base = [], [], 0
    for mesh, transform in _placed(_read(path)):
        v = _transformed(np.asarray(mesh.vertices, np.float64), transform, path)
        vertices.append(v)
        faces.append(np.asarray(mesh.faces, np.int64) + base)
        base += len(v)
    if not faces:
        raise SceneError("the file holds no triangles", path=str(path))
    return np.concatenate(vertices), np.concatenate(faces)


def _transformed(v: np.ndarray, transform: np.ndarray, path: Path) -> np.ndarray:
    out = v @ transform[:3, :3].T + transform[:3, 3]
    if not np.all(np.isfinite(out)):
        raise SceneError(f"vertex {int(np.flatnonzero(~np.isfinite(out).all(axis=1))[0])} is not finite",
                         path=str(path))
    return out


def _simple(material) -> Material:
    """An MTL material (trimesh's SimpleMaterial, its raw values in kwargs)."""
    raw = {k.lower(): v for k, v in (getattr(material, "kwargs", None) or {}).items()}

    def number(key, default):
        value = raw.get(key)
        if isinstance(value, (list, tuple)):
            value = value[0] if value else None
        try:
            return float(value) if value is not None else default
        except (TypeError, ValueError):
            return default
    kd = raw.get("kd")
    color = (np.asarray(kd, np.float64)[:3] if kd is not None and len(kd) >= 3
             else np.asarray(material.diffuse, np.float64)[:3] / 255.0)
    ks = raw.get("ks")
    specular = float(np.mean(np.asarray(ks, np.float64)[:3])) if ks is not None and len(ks) >= 3 else 0.0
    t = 1.0 - number("d", 1.0) if "d" in raw else number("tr", 0.0)
    return Material(color=tuple(np.clip(color, 0.0, 1.0)), kd=1.0, ks=min(max(specular, 0.0), 1.0),
                    shine=max(number("ns", 0.0), 0.0), t=min(max(t, 0.0), 1.0), ior=max(number("ni", 1.0), 1.0))


def _pbr(material) -> Material:
    """A glTF material (trimesh's PBRMaterial)."""
    base = np.asarray(material.baseColorFactor if material.baseColorFactor is not None else (255, 255, 255, 255),
                      np.float64)
    base = base / 255.0 if base.max() > 1.0 else base
    metallic = float(material.metallicFactor if material.metallicFactor is not None else 1.0)
    roughness = float(material.roughnessFactor if material.roughnessFactor is not None else 1.0)
    alpha = base[3] if len(base) > 3 and getattr(material, "alphaMode", None) == "BLEND" else 1.0
    a = max(roughness, 0.05) ** 2      # Blinn-Phong's exponent of a GGX roughness
    return Material(color=tuple(np.clip(base[:3], 0.0, 1.0)), kd=1.0 - 0.5 * metallic, ks=0.04 + 0.6 * metallic,
                    shine=min(2.0 / (a * a) - 2.0, 1000.0), t=1.0 - float(alpha), ior=1.5 if alpha < 1.0 else 1.0)


def _colours(mesh):
    """(materials, each face's index into them) from face or vertex colours; None without colours."""
    visual = mesh.visual
    if getattr(visual, "kind", None) not in ("face", "vertex"):
        return None
    rgb = np.asarray(visual.face_colors, np.float64)[:, :3] / 255.0
    unique, index = np.unique(rgb, axis=0, return_inverse=True)
    if len(unique) > MAX_COLOURS:
        rgb = np.round(rgb * 5.0) / 5.0
        unique, index = np.unique(rgb, axis=0, return_inverse=True)
    return [Material(color=tuple(c), kd=1.0) for c in unique], index.reshape(-1)


def _materials(mesh, table: dict) -> np.ndarray | int:
    """The mesh's material index (or each face's), adding what it uses to `table` (Material -> index)."""
    def index(m: Material) -> int:
        return table.setdefault(m, len(table))
    colours = _colours(mesh)
    if colours is not None:
        found, faces = colours
        return np.asarray([index(m) for m in found], np.int32)[faces]
    material = getattr(mesh.visual, "material", None)
    if material is None:
        return index(GREY)
    if hasattr(material, "baseColorFactor"):
        return index(_pbr(material))
    return index(_simple(material))


def _framed(lo: np.ndarray, hi: np.ndarray, up_axis: int) -> Camera:
    centre, radius = (lo + hi) / 2.0, max(float(np.linalg.norm(hi - lo)) / 2.0, 1e-12)
    up = np.zeros(3)
    up[up_axis] = 1.0
    # front, right and above: with Y up, towards +Z, +X and +Y; with Z up, towards -Y, +X and +Z
    toward = np.array([1.0, 0.8, 1.6]) if up_axis == 1 else np.array([1.0, -1.6, 0.8])
    toward /= np.linalg.norm(toward)
    angle = 40.0
    distance = radius / math.sin(math.radians(angle) / 2.0) * 1.05
    return Camera(eye=centre + toward * distance, look_at=centre, up=up, angle=angle,
                  hither=max(distance - radius, distance * 1e-6) * 1e-3)


def _file_camera(loaded, lo, hi) -> Camera | None:
    """The camera the file gives (glTF), if any."""
    if not getattr(loaded, "has_camera", False):
        return None
    transform = np.asarray(loaded.camera_transform, np.float64)
    eye = transform[:3, 3]
    forward = -transform[:3, 2]
    centre = (lo + hi) / 2.0
    distance = max(float(np.dot(centre - eye, forward)), float(np.linalg.norm(hi - lo)) * 1e-3, 1e-12)
    fov = np.asarray(loaded.camera.fov, np.float64)
    return Camera(eye=eye, look_at=eye + forward * distance, up=transform[:3, 1], angle=float(fov.max()),
                  hither=distance * 1e-6)


def read_mesh_file(path) -> Scene:
    """A Scene of a model file (see the module's docstring)."""
    path = Path(path)
    loaded = _read(path)
    placed = _placed(loaded)
    if not placed:
        raise SceneError("the file holds no triangles", path=str(path))
    scene = Scene(source=str(path))
    table: dict = {}
    for mesh, transform in placed:
        vertices = _transformed(np.asarray(mesh.vertices, np.float64), transform, path)
        scene.root.meshes.append(TriangleMesh(vertices, np.asarray(mesh.faces, np.int64), _materials(mesh, table)))
    scene.materials = list(table)
    lo = np.min([m.vertices.min(axis=0) for m in scene.root.meshes], axis=0)
    hi = np.max([m.vertices.max(axis=0) for m in scene.root.meshes], axis=0)
    scene.camera = _file_camera(loaded, lo, hi) or _framed(lo, hi, 2 if path.suffix.lower() == ".stl" else 1)
    eye, centre = scene.camera.eye, (lo + hi) / 2.0
    up = np.asarray(scene.camera.up, np.float64)
    side = np.cross(centre - eye, up)
    side /= max(np.linalg.norm(side), 1e-300)
    reach = float(np.linalg.norm(eye - centre))
    scene.lights = [Light(position=eye + (up - 0.5 * side) * reach * 0.5, color=np.array([0.8, 0.8, 0.8])),
                    Light(position=centre + (side + up) * reach, color=np.array([0.4, 0.4, 0.4]))]
    scene.background = np.array([0.12, 0.12, 0.15])
    return scene

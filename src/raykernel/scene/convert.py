"""Writing scenes for other programs: NFF, our JSON, Wavefront OBJ (with .mtl) and POV-Ray 3.7.

    from raykernel.scene.convert import convert
    convert("spd:teapot:6", "teapot.obj")            # anything raykernel.load accepts, or a Scene
    convert(scene, "scene.pov")
    text = scene_to_pov(scene)
    obj, mtl = scene_to_obj(scene, segments=16, mtl_name="scene.mtl")

The output's suffix picks the format:

.nff   NFF, groups and instances flattened (`nff.write_nff`).
.json  our JSON scene format, groups kept (`jsonscene.write_json`).
.obj   Wavefront OBJ and a material library beside it (same name, .mtl).
       Every group occurrence (an instanced group once per instance) starts
       with `o` and `g` lines naming its path from the root (a/b/c; unnamed
       groups are named group1, group2, ...), instance matrices are applied
       to the vertices (normals by the inverse transpose, the winding
       reversed under a mirroring transform). Polygons are faces; patches are
       faces with `vn` normals; meshes are triangles (with normals when the
       mesh has them). Spheres are tessellated into `segments` slices around
       and segments // 2 (at least 2) rings, segments x rings faces; cones into
       `segments` side faces (open, no caps). `usemtl mK` names scene material
       K; the .mtl gives Kd = colour x Kd, Ks = Ks (grey), Ns = Shine
       (at most 1000), d = 1 - T and Ni = ior for transmitting materials, and
       illum 2 (highlight), 3 (with reflection) or 6 (with refraction).
.pov   a POV-Ray 3.7 scene. The camera reproduces NFF's: `angle` is the
       horizontal field of view across the image width, computed from NFF's
       angle between the centres of the outermost pixel rows; `right`, `up`
       and `direction` are given explicitly from the NFF basis (right = view
       direction x up), which keeps the right-handed picture unmirrored.
       Lights have intensity 1/sqrt(number of lights) as in our renderer. Each
       material is a declared texture: pigment colour (with `transmit T`),
       finish { ambient 0, diffuse Kd, phong Ks, phong_size Shine, reflection
       Ks }, and `interior { ior }` for transmitting materials. Spheres are
       `sphere`, cones `cone { ... open }`, polygons `polygon` (closed by
       repeating the first vertex, so concave outlines stay exact), patches
       fans of `smooth_triangle`, meshes one `mesh` per material. Geometry
       is written in world coordinates; a sphere or cone under a transform
       that is not a similarity keeps its local form and a `matrix`.
       `global_settings { assumed_gamma 1.0 }`: our renderer writes linear
       values, so render with `File_Gamma=1.0` to compare images.

Negative radii (NFF: only the inside is visible) become positive in POV-Ray
(which has no such surface) and inward-facing in OBJ. Every file is written
atomically: to a temporary file in the same directory, then renamed; a
directory that does not exist or cannot be written is a `SceneError`.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..atomicfile import check_output_directory, write_text
from ..errors import OptionError, SceneError
from .model import Group, Instance, Material, Scene

__all__ = ["FORMATS", "convert", "scene_to_obj", "scene_to_pov", "write_obj", "write_pov", "walk",
           "check_output_directory", "DEFAULT_SEGMENTS"]

FORMATS = (".nff", ".json", ".obj", ".pov")
DEFAULT_SEGMENTS = 16
MAX_SEGMENTS = 4096
POV_MAX_DISTANCE = 1.0e7       # POV-Ray ignores intersections farther than this


# ---- common -------------------------------------------------------------------------------------

def _check_segments(segments) -> int:
    if isinstance(segments, bool) or not isinstance(segments, (int, np.integer)) \
            or not 3 <= int(segments) <= MAX_SEGMENTS:
        raise OptionError(f"segments must be a whole number from 3 to {MAX_SEGMENTS}, got {segments!r}")
    return int(segments)


def _format_of(path) -> str:
    suffix = Path(path).suffix.lower()
    if suffix not in FORMATS:
        raise OptionError(f"{path}: unknown output format {suffix or '(no suffix)'!r}; "
                          f"use one of {', '.join(FORMATS)}")
    return suffix


def walk(scene: Scene):
    """(group, 4x4 local-to-world matrix, path name) for every occurrence of
    every group, depth first from the root; a cycle is a SceneError."""
    names: dict[str, int] = {}
    unnamed = [0]

    def label(group: Group) -> str:
        if group.name:
            return "_".join(group.name.split())
        unnamed[0] += 1
        return f"group{unnamed[0]}"

    labels: dict[int, str] = {}

    def visit(group: Group, matrix: np.ndarray, prefix: str, active: tuple):
        if any(g is group for g in active):
            raise SceneError(f"the scene graph has a cycle: group {group.name or '(unnamed)'!r} contains itself")
        if id(group) not in labels:
            labels[id(group)] = label(group)
        path = f"{prefix}/{labels[id(group)]}" if prefix else labels[id(group)]
        seen = names.get(path, 0) + 1
        names[path] = seen
        unique = path if seen == 1 else f"{path}_{seen}"
        yield group, matrix, unique
        for child in group.children:
            if isinstance(child, Instance):
                yield from visit(child.group, matrix @ child.matrix, unique, active + (group,))
            else:
                yield from visit(child, matrix, unique, active + (group,))

    yield from visit(scene.root, np.eye(4), "", ())


def _material(scene: Scene, index: int, what: str) -> Material:
    if not scene.materials and index == 0:
        return Material()
    if not 0 <= index < len(scene.materials):
        raise SceneError(f"{what} uses material {index}, but the scene has {len(scene.materials)} materials")
    return scene.materials[index]


def _materials(scene: Scene) -> list:
    return list(scene.materials) if scene.materials else [Material()]


def _unit_rows(v: np.ndarray) -> np.ndarray:
    with np.errstate(all="ignore"):
        n = np.linalg.norm(v, axis=1)
        out = v / np.where(n > 0.0, n, 1.0)[:, None]
    return out


def _sphere_mesh(segments: int):
    """Unit sphere: vertices (= normals) and faces as lists of vertex indices."""
    around, rings = segments, max(2, segments // 2)
    verts = [(0.0, 0.0, 1.0)]
    for i in range(1, rings):
        theta = math.pi * i / rings
        for j in range(around):
            phi = 2.0 * math.pi * j / around
            verts.append((math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)))
    verts.append((0.0, 0.0, -1.0))
    south = len(verts) - 1
    faces = []
    for j in range(around):
        faces.append((0, 1 + j, 1 + (j + 1) % around))
    for i in range(rings - 2):
        a, b = 1 + i * around, 1 + (i + 1) * around
        for j in range(around):
            j1 = (j + 1) % around
            faces.append((a + j, b + j, b + j1, a + j1))
    last = 1 + (rings - 2) * around
    for j in range(around):
        faces.append((last + j, south, last + (j + 1) % around))
    return np.array(verts), faces


def _cone_frame(axis: np.ndarray):
    """Unit vectors u, v with (u, v, axis) right-handed."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u)
    return u, np.cross(axis, u)


def _cone_mesh(base, r0, apex, r1, segments: int):
    """Local vertices, normals and faces of an open cone (radii as given, signed)."""
    base, apex = np.asarray(base, float), np.asarray(apex, float)
    axis = apex - base
    length = float(np.linalg.norm(axis))
    axis = axis / length
    u, v = _cone_frame(axis)
    a0, a1 = abs(r0), abs(r1)
    phi = 2.0 * np.pi * np.arange(segments) / segments
    e = np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v
    normal = _unit_rows(e * length + axis * (a0 - a1))
    if r0 < 0.0 or r1 < 0.0:
        normal = -normal
    ring0 = base + a0 * e
    ring1 = apex + a1 * e
    verts = np.vstack([ring0, ring1])
    normals = np.vstack([normal, normal])
    faces = []
    for j in range(segments):
        j1 = (j + 1) % segments
        quad = [j, j1, segments + j1, segments + j]
        if a0 == 0.0:
            quad = [j, segments + j1, segments + j]
        elif a1 == 0.0:
            quad = [j, j1, segments + j]
        faces.append(quad[::-1] if (r0 < 0.0 or r1 < 0.0) else quad)
    return verts, normals, faces


def _is_similarity(a: np.ndarray) -> tuple[bool, float]:
    g = a.T @ a
    s2 = float(np.trace(g)) / 3.0
    ok = s2 > 0.0 and np.allclose(g, s2 * np.eye(3), rtol=0.0, atol=1e-9 * s2)
    return ok, math.sqrt(s2) if s2 > 0.0 else 0.0


# ---- OBJ ----------------------------------------------------------------------------------------

_G = "%.12g"


def _num(x: float) -> str:
    s = _G % float(x)
    return "0" if s == "-0" else s


def _vec(v) -> str:
    return " ".join(_num(x) for x in v)


class _ObjWriter:
    def __init__(self, scene: Scene, segments: int):
        self.scene = scene
        self.segments = segments
        self.out: list[str] = []
        self.nv = 0
        self.nn = 0
        self.current = None
        self.faces = 0
        self.sphere = _sphere_mesh(segments)

    def use(self, index: int, what: str):
        _material(self.scene, int(index), what)
        name = f"m{int(index)}"
        if name != self.current:
            self.out.append(f"usemtl {name}")
            self.current = name

    def vertices(self, v: np.ndarray) -> int:
        first = self.nv + 1
        self.out.extend("v " + _vec(p) for p in v)
        self.nv += len(v)
        return first

    def normals(self, n: np.ndarray) -> int:
        first = self.nn + 1
        self.out.extend("vn " + _vec(p) for p in n)
        self.nn += len(n)
        return first

    def face(self, idx, nidx=None):
        if nidx is None:
            self.out.append("f " + " ".join(str(i) for i in idx))
        else:
            self.out.append("f " + " ".join(f"{i}//{k}" for i, k in zip(idx, nidx)))
        self.faces += 1

    def group(self, group: Group, m: np.ndarray, name: str):
        a, t = m[:3, :3], m[:3, 3]
        mirrored = float(np.linalg.det(a)) < 0.0
        nmat = np.linalg.inv(a).T
        self.out.append(f"o {name}")
        self.out.append(f"g {name}")

        def orient(idx):
            return idx[::-1] if mirrored else idx

        s = group.spheres.freeze()
        unit, sfaces = self.sphere
        for i in range(len(s)):
            self.use(s.material[i], f"sphere {i} of group {name}")
            r = float(s.radius[i])
            local = s.center[i] + abs(r) * unit
            v0 = self.vertices(local @ a.T + t)
            normals = _unit_rows(unit @ nmat.T) * (-1.0 if r < 0.0 else 1.0)
            n0 = self.normals(normals)
            for f in sfaces:
                f = orient(f[::-1] if r < 0.0 else f)
                self.face([v0 + k for k in f], [n0 + k for k in f])
        c = group.cones.freeze()
        for i in range(len(c)):
            self.use(c.material[i], f"cone {i} of group {name}")
            verts, normals, cfaces = _cone_mesh(c.base[i], c.base_radius[i], c.apex[i], c.apex_radius[i],
                                                self.segments)
            v0 = self.vertices(verts @ a.T + t)
            n0 = self.normals(_unit_rows(normals @ nmat.T))
            for f in cfaces:
                f = orient(f)
                self.face([v0 + k for k in f], [n0 + k for k in f])
        for polys in (group.polygons.freeze(), group.patches.freeze()):
            if not len(polys):
                continue
            v0 = self.vertices(polys.vertices @ a.T + t)
            n0 = self.normals(_unit_rows(polys.normals @ nmat.T)) if polys.patches else None
            for i in range(len(polys)):
                self.use(polys.material[i], f"{polys.kind} {i} of group {name}")
                idx = orient(list(range(int(polys.start[i]), int(polys.start[i] + polys.count[i]))))
                self.face([v0 + k for k in idx], None if n0 is None else [n0 + k for k in idx])
        for mesh in group.meshes:
            if not len(mesh.faces):
                continue
            v0 = self.vertices(mesh.vertices @ a.T + t)
            n0 = None if mesh.normals is None else self.normals(_unit_rows(mesh.normals @ nmat.T))
            for i, f in enumerate(mesh.faces.tolist()):
                self.use(mesh.material[i], f"mesh triangle {i} of group {name}")
                f = orient(f)
                self.face([v0 + k for k in f], None if n0 is None else [n0 + k for k in f])


def _mtl(scene: Scene) -> str:
    lines = [f"# materials of {scene.source or 'a raykernel scene'}"]
    for k, m in enumerate(_materials(scene)):
        kd = [c * m.kd for c in m.color]
        illum = 6 if m.t > 0.0 else (3 if m.ks > 0.0 else 2)
        lines += ["", f"newmtl m{k}", "Ka 0 0 0", "Kd " + _vec(kd), "Ks " + _vec([m.ks] * 3),
                  "Ns " + _num(min(max(m.shine, 0.0), 1000.0))]
        if m.t > 0.0:
            lines += ["d " + _num(max(0.0, 1.0 - m.t)), "Ni " + _num(m.ior if m.ior > 0.0 else 1.0)]
        lines.append(f"illum {illum}")
    return "\n".join(lines) + "\n"


def scene_to_obj(scene: Scene, segments: int = DEFAULT_SEGMENTS, mtl_name: str | None = None) -> tuple[str, str]:
    """OBJ text and MTL text for `scene`; `mtl_name` is written as the `mtllib`."""
    segments = _check_segments(segments)
    w = _ObjWriter(scene, segments)
    for group, matrix, name in walk(scene):
        w.group(group, matrix, name)
    head = [f"# {scene.source or 'raykernel scene'}: {w.nv} vertices, {w.faces} faces"]
    if mtl_name:
        head.append(f"mtllib {mtl_name}")
    return "\n".join(head + w.out) + "\n", _mtl(scene)


def write_obj(scene: Scene, path, segments: int = DEFAULT_SEGMENTS) -> list[Path]:
    """Write `path` (.obj) and its material library (same name, .mtl); returns both paths."""
    path = Path(path)
    mtl_path = path.with_suffix(".mtl")
    obj, mtl = scene_to_obj(scene, segments, mtl_path.name)
    write_text(mtl_path, mtl)
    write_text(path, obj)
    return [path, mtl_path]


# ---- POV-Ray ------------------------------------------------------------------------------------

def _pv(v) -> str:
    return "<" + ", ".join(_num(x) for x in v) + ">"


def _pov_camera(scene: Scene) -> list[str]:
    cam = scene.camera
    forward, right, up = cam.basis()
    w, h = cam.width, cam.height
    half = w * math.tan(math.radians(cam.angle) / 2.0) / max(h - 1, 1)
    hfov = math.degrees(2.0 * math.atan(half))
    aspect = w / h
    return ["camera {", "  perspective", f"  location {_pv(cam.eye)}", f"  direction {_pv(forward)}",
            f"  right {_pv(right * aspect)}", f"  up {_pv(up)}", f"  angle {_num(hfov)}", "}"]


def _pov_textures(scene: Scene) -> list[str]:
    out = []
    for k, m in enumerate(_materials(scene)):
        color = _pv(m.color)
        pigment = f"color rgb {color}" if m.t <= 0.0 else \
            f"color rgbt <{_num(m.color[0])}, {_num(m.color[1])}, {_num(m.color[2])}, {_num(min(m.t, 1.0))}>"
        finish = f"ambient 0 diffuse {_num(m.kd)}"
        if m.ks > 0.0:
            if m.shine > 0.0:
                finish += f" phong {_num(m.ks)} phong_size {_num(m.shine)}"
            finish += f" reflection {{ {_num(m.ks)} }}"
        out.append(f"#declare RK_M{k} = texture {{ pigment {{ {pigment} }} finish {{ {finish} }} }}")
        if m.t > 0.0:
            out.append(f"#declare RK_I{k} = interior {{ ior {_num(m.ior if m.ior > 0.0 else 1.0)} }}")
    return out


def _newell(v: np.ndarray) -> np.ndarray:
    nxt = np.roll(v, -1, axis=0)
    return np.array([np.sum((v[:, 1] - nxt[:, 1]) * (v[:, 2] + nxt[:, 2])),
                     np.sum((v[:, 2] - nxt[:, 2]) * (v[:, 0] + nxt[:, 0])),
                     np.sum((v[:, 0] - nxt[:, 0]) * (v[:, 1] + nxt[:, 1]))])


class _PovWriter:
    def __init__(self, scene: Scene):
        self.scene = scene
        self.out: list[str] = []
        self.far = []
        self.objects = 0

    def texture(self, index: int, what: str) -> str:
        index = int(index)
        m = _material(self.scene, index, what)
        s = f"texture {{ RK_M{index} }}"
        if m.t > 0.0:
            s += f" interior {{ RK_I{index} }}"
        return s

    def group(self, group: Group, m: np.ndarray, name: str):
        a, t = m[:3, :3], m[:3, 3]
        similar, scale = _is_similarity(a)
        nmat = np.linalg.inv(a).T
        matrix = "matrix <" + ", ".join(_num(x) for x in list(a.T.reshape(-1)) + list(t)) + ">"
        self.out.append(f"// group {name}")
        eye = self.scene.camera.eye
        s = group.spheres.freeze()
        for i in range(len(s)):
            tex = self.texture(s.material[i], f"sphere {i} of group {name}")
            r = abs(float(s.radius[i]))
            if similar:
                center = a @ s.center[i] + t
                self.out.append(f"sphere {{ {_pv(center)}, {_num(r * scale)} {tex} }}")
                if np.linalg.norm(center - eye) - r * scale > POV_MAX_DISTANCE:
                    self.far.append(f"sphere {i} of group {name}")
            else:
                self.out.append(f"sphere {{ {_pv(s.center[i])}, {_num(r)} {matrix} {tex} }}")
            self.objects += 1
        c = group.cones.freeze()
        for i in range(len(c)):
            tex = self.texture(c.material[i], f"cone {i} of group {name}")
            r0, r1 = abs(float(c.base_radius[i])), abs(float(c.apex_radius[i]))
            if similar:
                self.out.append(f"cone {{ {_pv(a @ c.base[i] + t)}, {_num(r0 * scale)}, {_pv(a @ c.apex[i] + t)}, "
                                f"{_num(r1 * scale)} open {tex} }}")
            else:
                self.out.append(f"cone {{ {_pv(c.base[i])}, {_num(r0)}, {_pv(c.apex[i])}, {_num(r1)} open "
                                f"{matrix} {tex} }}")
            self.objects += 1
        polys = group.polygons.freeze()
        if len(polys):
            verts = polys.vertices @ a.T + t
            for i in range(len(polys)):
                v = verts[int(polys.start[i]):int(polys.start[i] + polys.count[i])]
                if not np.any(_newell(v)):
                    continue
                tex = self.texture(polys.material[i], f"polygon {i} of group {name}")
                pts = ", ".join(_pv(p) for p in v) + ", " + _pv(v[0])
                self.out.append(f"polygon {{ {len(v) + 1}, {pts} {tex} }}")
                self.objects += 1
        patches = group.patches.freeze()
        if len(patches):
            verts = patches.vertices @ a.T + t
            norms = _unit_rows(patches.normals @ nmat.T)
            for i in range(len(patches)):
                s0, n = int(patches.start[i]), int(patches.count[i])
                tex = self.texture(patches.material[i], f"patch {i} of group {name}")
                for k in range(1, n - 1):
                    idx = (s0, s0 + k, s0 + k + 1)
                    self.smooth_triangle(verts[list(idx)], norms[list(idx)], tex)
        for k, mesh in enumerate(group.meshes):
            if not len(mesh.faces):
                continue
            verts = mesh.vertices @ a.T + t
            norms = None if mesh.normals is None else _unit_rows(mesh.normals @ nmat.T)
            for mat in np.unique(mesh.material):
                tex = self.texture(mat, f"mesh {k} of group {name}")
                body = []
                for f in mesh.faces[mesh.material == mat]:
                    tri = verts[f]
                    face_n = np.cross(tri[1] - tri[0], tri[2] - tri[0])
                    if not np.any(face_n):
                        continue
                    nn = None if norms is None else self.usable_normals(norms[f], face_n)
                    if nn is None or not self.consistent(nn, face_n):
                        body.append(f"  triangle {{ {_pv(tri[0])}, {_pv(tri[1])}, {_pv(tri[2])} }}")
                    else:
                        body.append("  smooth_triangle { " + ", ".join(f"{_pv(p)}, {_pv(q)}" for p, q in zip(tri, nn))
                                    + " }")
                if body:
                    self.out += [f"mesh {{ // mesh {k} of group {name}"] + body + [f"  {tex}", "}"]
                    self.objects += 1

    @staticmethod
    def usable_normals(normals: np.ndarray, face_normal: np.ndarray) -> np.ndarray:
        fallback = face_normal / np.linalg.norm(face_normal)
        ok = np.all(np.isfinite(normals), axis=1) & np.any(normals != 0.0, axis=1)
        return np.where(ok[:, None], normals, fallback)

    @staticmethod
    def consistent(normals: np.ndarray, face_normal: np.ndarray) -> bool:
        """Whether all vertex normals lie on one side of the face: POV-Ray
        rejects a smooth triangle whose normals do not."""
        side = normals @ face_normal
        return bool(np.all(side > 0.0) or np.all(side < 0.0))

    def smooth_triangle(self, tri: np.ndarray, normals: np.ndarray, tex: str):
        face_n = np.cross(tri[1] - tri[0], tri[2] - tri[0])
        if not np.any(face_n):
            return
        nn = self.usable_normals(normals, face_n)
        if self.consistent(nn, face_n):
            self.out.append("smooth_triangle { " + ", ".join(f"{_pv(p)}, {_pv(q)}" for p, q in zip(tri, nn))
                            + f" {tex} }}")
        else:
            self.out.append(f"triangle {{ {_pv(tri[0])}, {_pv(tri[1])}, {_pv(tri[2])} {tex} }}")
        self.objects += 1


def scene_to_pov(scene: Scene) -> str:
    """POV-Ray 3.7 scene text for `scene`."""
    w = _PovWriter(scene)
    for group, matrix, name in walk(scene):
        w.group(group, matrix, name)
    cam = scene.camera
    n = len(scene.lights)
    head = [f"// {scene.source or 'raykernel scene'}: {w.objects} objects",
            f"// povray +I<this file> +W{cam.width} +H{cam.height} File_Gamma=1.0",
            "#version 3.7;", "global_settings { assumed_gamma 1.0 max_trace_level 5 }",
            f"background {{ color rgb {_pv(scene.background)} }}"]
    if w.far:
        head.append(f"// POV-Ray ignores surfaces more than {POV_MAX_DISTANCE:g} units away: "
                    f"{', '.join(w.far[:5])}{' and more' if len(w.far) > 5 else ''} will not show")
    head += _pov_camera(scene)
    for light in scene.lights:
        color = (np.ones(3) if light.color is None else light.color) / math.sqrt(n)
        head.append(f"light_source {{ {_pv(light.position)} color rgb {_pv(color)} }}")
    head += _pov_textures(scene)
    return "\n".join(head + w.out) + "\n"


def write_pov(scene: Scene, path) -> Path:
    return write_text(path, scene_to_pov(scene))


# ---- dispatch -----------------------------------------------------------------------------------

def convert(source, output, segments: int = DEFAULT_SEGMENTS) -> list[Path]:
    """Write `source` (a Scene, or anything raykernel.load accepts) to `output`
    in the format its suffix names; returns the paths written."""
    fmt = _format_of(output)
    segments = _check_segments(segments)
    output = check_output_directory(output)
    if isinstance(source, Scene):
        scene = source
    else:
        from .loading import load
        scene = load(source)
    if fmt == ".nff":
        from .nff import write_nff
        write_nff(scene, output)
        return [output]
    if fmt == ".json":
        from .jsonscene import write_json
        return [write_json(scene, output)]
    if fmt == ".obj":
        return write_obj(scene, output, segments)
    return [write_pov(scene, output)]

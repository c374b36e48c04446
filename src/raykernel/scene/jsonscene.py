"""Scenes written as JSON: primitives, materials, named groups, instances and NFF includes.

    from raykernel.scene.jsonscene import read_json, write_json
    scene = read_json("scene.json")
    write_json(scene, "copy.json")

Public functions: `read_json(path)`, `parse_json(text, path=None, base_dir=None)`,
`scene_from_json(data, path=None, base_dir=None)` (an already decoded dict),
`scene_to_json(scene) -> dict`, `write_json(scene, path)` and
`transform_matrix(ops) -> 4x4 array`. Every problem is a `SceneError` that
names the file and where in it: the line for malformed JSON, a JSON-pointer
location for anything else, e.g.

    scene.json: /scene/items/3/sphere/radius: expected a number, got 'abc'

The format
==========

The file holds one object; every key is optional:

    {
      "camera": {"eye": [x, y, z], "look_at": [x, y, z], "up": [0, 0, 1],
                 "angle": 45, "hither": 0.001, "resolution": [512, 512]},
      "background": [r, g, b],
      "lights": [{"position": [x, y, z], "color": [r, g, b]}],
      "materials": {"gold": {"color": [1, 0.8, 0.3], "kd": 0.5, "ks": 0.5,
                             "shine": 20, "t": 0, "ior": 1}},
      "groups": {"teapot": {"accel": "bvh", "items": [...]}},
      "scene": {"accel": "bvh", "items": [...]},
      "animation": {"time": [0, 2], "fps": 24}
    }

camera      "eye" and "look_at" are required; "up" defaults to [0, 0, 1],
            "angle" (full field of view in degrees, NFF's meaning) to 45,
            "hither" to 0.001, "resolution" ([width, height] or one number
            for a square image) to 512; "medium" names the material of a
            transparent medium the eye is in (water around the camera; Hall
            shading filters rays by the distance they travel in it). Without
            "camera" the camera of the first included NFF file that has one
            is used, else the default `Camera()`.
background  an RGB colour; without it, the first included NFF file's
            background, else black.
lights      point lights; "position" is required, "color" is optional
            (white). Without "lights", the lights of the first included NFF
            file that has any.
materials   named materials, NFF's fill parameters: "color" (default
            [1, 1, 1]), "kd" (1), "ks" (0), "shine" (0), "t" (0), "ior" (1),
            and "kl" (0), the luminance of Heckbert's minimal ray tracer:
            the surface glows with kl x colour, and a luminous sphere
            lights the scene from its centre.
groups      named group bodies, placed by `{"instance": name}` items. A named
            group is built once however often it is instanced; groups no item
            uses are still checked.
scene       the root group body.

A group body (the "scene" object, each entry of "groups", an inline
"group" item) has the keys "accel" (an accelerator spec such as "bvh",
"bvh(leaf=2)" or "list"; null or absent: the render's default), "items"
(a list, may be empty) and "material" (the default material of the items
in it and in the inline groups within it; it does not reach through
instances, a named group's own "material" applies there). A primitive with
no material anywhere above it gets the default `Material()` (white, kd 1).

Items
-----

Each item is an object with exactly one of these keys:

    {"sphere": {"center": [x, y, z], "radius": r}}
        r may be negative (NFF: only the inside is visible), not zero.
    {"cone": {"base": [x, y, z], "base_radius": r0, "apex": [x, y, z], "apex_radius": r1}}
        an open cone or cylinder; the radii may not both be zero, base and
        apex may not coincide.
    {"polygon": [[x, y, z], ...]}
        a planar polygon of 3 or more vertices.
    {"patch": {"vertices": [[x, y, z], ...], "normals": [[x, y, z], ...]}}
        a polygon with one (nonzero) normal per vertex, shaded smoothly.
    {"mesh": {"vertices": [[x, y, z], ...], "faces": [[i, j, k], ...], "normals": [[x, y, z], ...]}}
        an indexed triangle mesh (at least one face; indices from 0;
        "normals", one per vertex, is optional).
    {"mesh": "file.obj"}
        a mesh file loaded with trimesh (`pip install raykernel[mesh]`).
    {"include": "file.nff"}  or  {"include": {"file": "file.nff", "accel": "bvh"}}
        the NFF file's geometry as a child group (its materials are added to
        the scene's and its material indices remapped). The same file with
        the same accel is read once and its group shared.
    {"group": {"accel": ..., "items": [...], "material": ...}}
        an inline child group.
    {"instance": "name"}
        the named group from "groups", always placed as an `Instance`.
    {"OPERATOR": {"LIST": [items], ..., "material": ...}}
        an operator kind of the registry (`Kind.operands`; the boolean
        operators of aggregates/csg.py: {"difference": {"base": [items],
        "subtract": [items]}}, {"intersection": {"items": [items]}},
        {"union": {"items": [items]}}), with its kind's lists of items
        (`Kind.operand_lists`). Each item is one operand and must be a
        closed solid: spheres, closed meshes, closed polygon sets, or
        groups, instances and operator items of them (cones are open
        surfaces and are refused). An operand is built with the render's
        default structure; give it another as a "group" item with an
        "accel". Stored as a group with the kind's spec (for a
        difference "difference(base=N)", N the items in "base") whose
        children are the operands, the lists' items in order.

and optionally:

    "material"   on sphere, cone, polygon, patch and mesh items: a name from
                 "materials" or an inline material object.
    "transform"  on any item: the item becomes an `Instance` of a group
                 holding it (a primitive: of a one-primitive group; a group,
                 include or named group: of that group).
    "motion"     on any item: keyframes that move it (Animation below); the
                 item becomes an `Instance` as with "transform".

File names (mesh, include) are relative to the JSON file's directory.

Transforms
----------

A transform is one operation object or a list of them, applied to the
item's geometry in the order written (the first operation acts first):

    {"translate": [x, y, z]}
    {"rotate": {"axis": [x, y, z], "degrees": d}}   right-handed: 90 degrees
                                                    about z takes x to y
    {"scale": s}  or  {"scale": [sx, sy, sz]}       nonzero factors
    {"matrix": [[a, b, c, tx], [d, e, f, ty], [g, h, i, tz], [0, 0, 0, 1]]}
                                                    affine, invertible, rows

`transform_matrix(ops)` gives the resulting 4x4 local-to-world matrix.

Animation
---------

An item's "motion" is a list of keyframes in increasing "time":

    {"time": t, "translate": [x, y, z], "rotate": {"axis": [x, y, z], "degrees": d},
     "scale": s or [sx, sy, sz]}          ("quaternion": [w, x, y, z] instead of "rotate")

Omitted parts are the identity. Between keys the translation and scale are
interpolated linearly and the rotation by slerp (the short way: give a key
at least every 180 degrees); before the first key and after the last the
item holds still. At time t the item's matrix is motion(t) @ transform:
its "transform" first, then the key's scale, rotation and translation.
The camera's "path" is a list of keys {"time": t, "eye", "look_at", "up",
"angle"}; each field is interpolated over the keys that give it, and one
no key gives keeps the camera's value. "animation" gives the time range
("time": [t0, t1], default: from the first key of any motion or path to
the last) and the frames per second of a written movie ("fps", 24). A
scene with any of these has `scene.animation` (scene/animation.py); it is
read at its start time.

Nesting
-------

A group may not instance itself, directly or through other groups: such a
cycle is an error naming its groups. Groups nest at most `MAX_NESTING`
(16) levels deep: the root is level 1 and every group within a group or an
instance (inline groups, instances, transformed items, includes) is one
level deeper, so a path from the root passes through at most 16 groups.
This matches the renderer's limit on nested aggregates (which does not count
a child group without an accel of its own, since it is merged into its
parent; the reader counts every group).

Strictness
----------

Unknown keys are errors that list the allowed ones (so a misspelt key is
never ignored); so are duplicate keys, missing required keys, vectors of the
wrong length, booleans or strings where numbers belong, NaN and Infinity
(which Python's JSON reader accepts), unknown material or group names (the
known ones are listed) and missing files. Any object may carry a "comment"
key, whose value is ignored, except "materials" and "groups", where every
key is a name. A file that is empty or whose top level is not
an object is an error; a scene without items is not (it renders the
background).

Writing
-------

`scene_to_json` writes primitives inline (arrays as nested lists, numbers as
floats), materials named m0, m1, ... in the order of `scene.materials`,
groups placed more than once under "groups" (named after the group where
that name is free, else g0, g1, ...), and every instance's matrix as
{"matrix": ...} (a moving instance: its static matrix, and its "motion" as
translate, quaternion and scale keys), and the animation and camera path. A mesh with several materials is written as one mesh item
per material. `write_json` writes the file atomically: a temporary file in
the same directory, then `os.replace`.
"""

from __future__ import annotations

import difflib
import json
import math
import os
from pathlib import Path

import numpy as np

from ..aggregates.registry import KINDS, parse_spec
from ..atomicfile import write_text
from ..errors import OptionError, SceneError
from .animation import CAMERA_FIELDS, Animation, CameraPath, Keyframe, Motion, axis_angle_quaternion, default_span
from .model import MAX_NESTING, Camera, Group, Instance, Light, Material, Scene, TriangleMesh

__all__ = ["MAX_NESTING", "read_json", "parse_json", "scene_from_json", "scene_to_json",
           "write_json", "transform_matrix"]


PRIMITIVE_KINDS = ("sphere", "cone", "polygon", "patch")


def _operators() -> dict:
    """The operator kinds of the registry, by name: each is an item kind of its own."""
    return {name: kind for name, kind in KINDS.items() if kind.operands}


TRANSFORM_OPS = ("translate", "rotate", "scale", "matrix")
TOP_KEYS = ("camera", "background", "lights", "materials", "groups", "scene", "animation")
MATERIAL_KEYS = ("color", "kd", "ks", "shine", "t", "ior", "kl")
CAMERA_KEYS = ("eye", "look_at", "up", "angle", "hither", "resolution", "medium", "path")
ANIMATION_KEYS = ("time", "fps")
MOTION_KEYS = ("time", "translate", "rotate", "quaternion", "scale")
BODY_KEYS = ("accel", "items", "material")
_COMMENT = "comment"

_CONSTANTS = {"NaN": math.nan, "Infinity": math.inf, "-Infinity": -math.inf}


class _Object(dict):
    """A decoded JSON object that remembers keys it saw more than once."""

    __slots__ = ("duplicates",)


def _object_pairs(pairs):
    obj = _Object()
    obj.duplicates = []
    for key, value in pairs:
        if key in obj and key not in obj.duplicates:
            obj.duplicates.append(key)
        obj[key] = value
    return obj


def _describe(value) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        if math.isnan(value):
            return "NaN"
        if math.isinf(value):
            return "Infinity" if value > 0 else "-Infinity"
        return repr(value)
    if isinstance(value, int):
        return repr(value)
    if isinstance(value, str):
        return repr(value if len(value) <= 40 else value[:37] + "...")
    if isinstance(value, dict):
        return "an object"
    if isinstance(value, list):
        if not value:
            return "an empty list"
        return f"a list of {len(value)} item" + ("" if len(value) == 1 else "s")
    return type(value).__name__


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _key(ptr: str, key) -> str:
    return f"{ptr}/{str(key).replace('~', '~0').replace('/', '~1')}"


def _names(names) -> str:
    return ", ".join(names)


def _has_cones(item) -> bool:
    group = item.group if isinstance(item, Instance) else item
    return len(group.cones) > 0 or any(_has_cones(c) for c in group.children)


def _rotation(axis: np.ndarray, degrees: float) -> np.ndarray:
    axis = axis / np.abs(axis).max()
    x, y, z = axis / np.linalg.norm(axis)
    quarter = degrees / 90.0
    if quarter == int(quarter):
        c, s = ((1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0))[int(quarter) % 4]
    else:
        t = math.radians(degrees)
        c, s = math.cos(t), math.sin(t)
    k = 1.0 - c
    m = np.eye(4)
    m[:3, :3] = [[c + x * x * k, x * y * k - z * s, x * z * k + y * s],
                 [y * x * k + z * s, c + y * y * k, y * z * k - x * s],
                 [z * x * k - y * s, z * y * k + x * s, c + z * z * k]]
    return m


class _Reader:
    """Turns a decoded JSON document into a Scene, checking as it goes."""

    def __init__(self, path, base_dir):
        self.path = None if path is None else str(path)
        self.base_dir = Path(base_dir)
        self.scene = Scene(source=self.path or "")
        self.material_names: dict[str, int] = {}
        self.group_defs: dict = {}
        self.built: dict[str, Group] = {}
        self.building: list[str] = []
        self.includes: dict = {}
        self.heights: dict[int, int] = {}
        self.default_material: int | None = None
        self.motions: list = []            # (instance, base matrix, Motion) of each moving item
        self.camera_path: CameraPath | None = None
        self.from_nff: dict = {"camera": None, "lights": None, "background": None}

    # ---- reporting and basic checks -------------------------------------------------

    def fail(self, ptr: str, message: str):
        raise SceneError(f"{ptr}: {message}" if ptr else message, path=self.path)

    def where(self, ptr: str) -> str:
        return f"{self.path}: {ptr}" if self.path else ptr

    def obj(self, value, ptr: str, allowed, required=(), what="an object") -> dict:
        if not isinstance(value, dict):
            self.fail(ptr, f"expected {what}, got {_describe(value)}")
        duplicates = getattr(value, "duplicates", None)
        if duplicates:
            self.fail(_key(ptr, duplicates[0]), "duplicate key (a JSON object may give each key once)")
        if allowed is not None:
            for key in value:
                if key != _COMMENT and key not in allowed:
                    self.unknown_key(ptr, key, allowed)
        for key in required:
            if key not in value:
                self.fail(ptr, f"missing required key {key!r}")
        return value

    def unknown_key(self, ptr, key, allowed):
        hint = difflib.get_close_matches(key, list(allowed), n=1)
        hint = f" (did you mean {hint[0]!r}?)" if hint else ""
        self.fail(_key(ptr, key), f"unknown key {key!r}{hint}; allowed keys: {_names(allowed)}, {_COMMENT}")

    def number(self, value, ptr: str) -> float:
        if not _is_number(value):
            self.fail(ptr, f"expected a number, got {_describe(value)}")
        value = float(value)
        if not math.isfinite(value):
            self.fail(ptr, f"expected a finite number, got {_describe(value)}")
        return value

    def integer(self, value, ptr: str) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            self.fail(ptr, f"expected an integer, got {_describe(value)}")
        return value

    def string(self, value, ptr: str, what="a string") -> str:
        if not isinstance(value, str) or not value:
            self.fail(ptr, f"expected {what}, got {_describe(value)}")
        return value

    def vec3(self, value, ptr: str) -> np.ndarray:
        if not isinstance(value, list) or len(value) != 3:
            self.fail(ptr, f"expected a list of 3 numbers, got {_describe(value)}")
        return np.array([self.number(v, f"{ptr}/{i}") for i, v in enumerate(value)])

    def vectors(self, value, ptr: str, minimum: int, what: str) -> np.ndarray:
        """A list of [x, y, z]; checked element by element only when the fast path fails."""
        if not isinstance(value, list) or len(value) < minimum:
            self.fail(ptr, f"expected a list of at least {minimum} {what} [x, y, z], got {_describe(value)}")
        if all(type(v) is list and len(v) == 3 and type(v[0]) in (int, float) and type(v[1]) in (int, float)
               and type(v[2]) in (int, float) for v in value):
            arr = np.array(value, np.float64).reshape(-1, 3)
            if np.all(np.isfinite(arr)):
                return arr
        for i, v in enumerate(value):
            self.vec3(v, f"{ptr}/{i}")
        return np.array(value, np.float64).reshape(-1, 3)

    def faces(self, value, ptr: str, count: int) -> np.ndarray:
        if not isinstance(value, list) or not value:
            self.fail(ptr, f"expected a list of at least 1 triangle [i, j, k], got {_describe(value)}")
        if not all(type(f) is list and len(f) == 3 and type(f[0]) is int and type(f[1]) is int
                   and type(f[2]) is int for f in value):
            for i, f in enumerate(value):
                fptr = f"{ptr}/{i}"
                if not isinstance(f, list) or len(f) != 3:
                    self.fail(fptr, f"expected a triangle of 3 vertex indices, got {_describe(f)}")
                for j, k in enumerate(f):
                    self.integer(k, f"{fptr}/{j}")
        arr = np.array(value, np.int64).reshape(-1, 3)
        bad = np.nonzero((arr < 0) | (arr >= count))
        if len(bad[0]):
            i, j = int(bad[0][0]), int(bad[1][0])
            self.fail(f"{ptr}/{i}/{j}", f"vertex index {arr[i, j]} out of range: the mesh has {count} "
                                        f"vertices (indices 0 to {count - 1})")
        return arr

    # ---- the document --------------------------------------------------------------

    def read(self, data) -> Scene:
        if not isinstance(data, dict):
            self.fail("", f"expected a JSON object at the top level, got {_describe(data)}")
        top = self.obj(data, "", TOP_KEYS)
        materials = self.obj(top.get("materials", {}), "/materials", None, what="an object of named materials")
        for name, definition in materials.items():
            self.material_names[name] = self.scene.add_material(self.material_def(definition, _key("/materials", name)))
        self.group_defs = dict(self.obj(top.get("groups", {}), "/groups", None, what="an object of named groups"))
        for name, definition in self.group_defs.items():
            if not name:
                self.fail("/groups", "a group name must not be empty")
            if not isinstance(definition, dict):
                self.fail(_key("/groups", name), f"expected a group object, got {_describe(definition)}")
        anim = self.obj(top.get("animation", {}), "/animation", ANIMATION_KEYS, what="an animation object")
        camera = self.camera(top["camera"], "/camera") if "camera" in top else None
        background = self.vec3(top["background"], "/background") if "background" in top else None
        lights = self.lights(top["lights"], "/lights") if "lights" in top else None

        root = self.scene.root
        self.body(top.get("scene", {}), "/scene", root, depth=1, material=None)
        for name in self.group_defs:
            self.named(name, _key("/groups", name))

        self.scene.camera = camera or self.from_nff["camera"] or Camera()
        background = background if background is not None else self.from_nff["background"]
        if background is not None:
            self.scene.background = np.asarray(background, np.float64)
        self.scene.lights = lights if lights is not None else list(self.from_nff["lights"] or [])
        if self.motions or self.camera_path is not None or "animation" in top:
            self.scene.animation = self.animation(anim, "/animation")
        return self.scene

    def animation(self, a: dict, ptr: str) -> Animation:
        span = default_span(self.motions, self.camera_path)
        if "time" in a:
            tptr = f"{ptr}/time"
            if not isinstance(a["time"], list) or len(a["time"]) != 2:
                self.fail(tptr, f"expected [start, end] in seconds, got {_describe(a['time'])}")
            span = tuple(self.number(v, f"{tptr}/{i}") for i, v in enumerate(a["time"]))
            if not span[1] > span[0]:
                self.fail(tptr, f"the end must come after the start, got {list(span)}")
        fps = self.number(a["fps"], f"{ptr}/fps") if "fps" in a else 24.0
        if not fps > 0.0:
            self.fail(f"{ptr}/fps", f"expected frames per second > 0, got {_describe(a['fps'])}")
        animation = Animation(time=span, fps=fps, motions=self.motions, camera=self.camera_path,
                              base_camera=self.scene.camera)
        animation.at(self.scene, span[0])
        return animation

    def keys(self, value, ptr: str, what: str) -> list:
        """A list of keyframe objects with increasing "time"."""
        if not isinstance(value, list) or not value:
            self.fail(ptr, f"expected a list of {what} keyframes (objects with a \"time\"), got {_describe(value)}")
        last = -math.inf
        for i, key in enumerate(value):
            if not isinstance(key, dict) or "time" not in key:
                self.fail(f"{ptr}/{i}", f"expected a keyframe object with a \"time\", got {_describe(key)}")
            t = self.number(key["time"], f"{ptr}/{i}/time")
            if not t > last:
                self.fail(f"{ptr}/{i}/time", f"keyframe times must increase: {t:g} follows {last:g}")
            last = t
        return value

    def motion(self, value, ptr: str) -> Motion:
        frames = []
        for i, key in enumerate(self.keys(value, ptr, "motion")):
            kptr = f"{ptr}/{i}"
            k = self.obj(key, kptr, MOTION_KEYS, required=("time",), what="a motion keyframe")
            frame = Keyframe(time=self.number(k["time"], f"{kptr}/time"))
            if "rotate" in k and "quaternion" in k:
                self.fail(kptr, "a keyframe takes \"rotate\" or \"quaternion\", not both")
            if "translate" in k:
                frame.translate = self.vec3(k["translate"], f"{kptr}/translate")
            if "rotate" in k:
                rptr = f"{kptr}/rotate"
                r = self.obj(k["rotate"], rptr, ("axis", "degrees"), required=("axis", "degrees"))
                axis = self.vec3(r["axis"], f"{rptr}/axis")
                if not np.any(axis != 0.0):
                    self.fail(f"{rptr}/axis", "a rotation axis must not be zero")
                frame.rotate = axis_angle_quaternion(axis, self.number(r["degrees"], f"{rptr}/degrees"))
            if "quaternion" in k:
                q = k["quaternion"]
                qptr = f"{kptr}/quaternion"
                if not isinstance(q, list) or len(q) != 4:
                    self.fail(qptr, f"expected [w, x, y, z], got {_describe(q)}")
                q = np.array([self.number(v, f"{qptr}/{j}") for j, v in enumerate(q)])
                if not np.linalg.norm(q) > 0.0:
                    self.fail(qptr, "a rotation quaternion must not be zero")
                frame.rotate = q / np.linalg.norm(q)
            if "scale" in k:
                frame.scale = self.op_scale(k["scale"], f"{kptr}/scale")[[0, 1, 2], [0, 1, 2]].copy()
            frames.append(frame)
        return Motion(frames)

    def camera_keys(self, value, ptr: str) -> CameraPath:
        keys = []
        for i, key in enumerate(self.keys(value, ptr, "camera")):
            kptr = f"{ptr}/{i}"
            k = self.obj(key, kptr, ("time",) + CAMERA_FIELDS, required=("time",), what="a camera keyframe")
            out = {"time": self.number(k["time"], f"{kptr}/time")}
            for name in ("eye", "look_at", "up"):
                if name in k:
                    out[name] = self.vec3(k[name], f"{kptr}/{name}")
            if "angle" in k:
                out["angle"] = self.number(k["angle"], f"{kptr}/angle")
                if not 0.0 < out["angle"] < 180.0:
                    self.fail(f"{kptr}/angle", f"expected an angle in degrees between 0 and 180, got {out['angle']:g}")
            keys.append(out)
        return CameraPath(keys)

    def camera(self, value, ptr: str) -> Camera:
        c = self.obj(value, ptr, CAMERA_KEYS, required=("eye", "look_at"))
        kw = {"eye": self.vec3(c["eye"], f"{ptr}/eye"), "look_at": self.vec3(c["look_at"], f"{ptr}/look_at")}
        if "up" in c:
            kw["up"] = self.vec3(c["up"], f"{ptr}/up")
        if "angle" in c:
            kw["angle"] = self.number(c["angle"], f"{ptr}/angle")
            if not 0.0 < kw["angle"] < 180.0:
                self.fail(f"{ptr}/angle", f"expected an angle in degrees between 0 and 180, got {_describe(c['angle'])}")
        if "medium" in c:
            kw["medium"] = self.material(c["medium"], f"{ptr}/medium")
        if "path" in c:
            self.camera_path = self.camera_keys(c["path"], f"{ptr}/path")
        if "hither" in c:
            kw["hither"] = self.number(c["hither"], f"{ptr}/hither")
            if kw["hither"] < 0.0:
                self.fail(f"{ptr}/hither", f"expected a distance >= 0, got {_describe(c['hither'])}")
        if "resolution" in c:
            res, rptr = c["resolution"], f"{ptr}/resolution"
            if isinstance(res, list):
                if len(res) != 2:
                    self.fail(rptr, f"expected [width, height] or one number, got {_describe(res)}")
                size = [self.integer(v, f"{rptr}/{i}") for i, v in enumerate(res)]
                bad = [i for i, v in enumerate(size) if v < 1]
                if bad:
                    self.fail(f"{rptr}/{bad[0]}", f"expected a positive pixel count, got {size[bad[0]]}")
            else:
                n = self.integer(res, rptr)
                if n < 1:
                    self.fail(rptr, f"expected a positive pixel count, got {n}")
                size = [n, n]
            kw["width"], kw["height"] = size
        try:
            with np.errstate(over="ignore", invalid="ignore"):
                return Camera(**kw)
        except SceneError as e:
            self.fail(ptr, e.message)

    def lights(self, value, ptr: str) -> list:
        if not isinstance(value, list):
            self.fail(ptr, f"expected a list of lights, got {_describe(value)}")
        lights = []
        for i, light in enumerate(value):
            lptr = f"{ptr}/{i}"
            light = self.obj(light, lptr, ("position", "color"), required=("position",))
            color = self.vec3(light["color"], f"{lptr}/color") if "color" in light else None
            lights.append(Light(self.vec3(light["position"], f"{lptr}/position"), color))
        return lights

    def material_def(self, value, ptr: str) -> Material:
        m = self.obj(value, ptr, MATERIAL_KEYS, what="a material object")
        kw = {}
        for key in MATERIAL_KEYS:
            if key in m:
                kptr = f"{ptr}/{key}"
                kw[key] = tuple(self.vec3(m[key], kptr)) if key == "color" else self.number(m[key], kptr)
        try:
            return Material(**kw)
        except SceneError as e:
            self.fail(ptr, e.message)

    def material(self, value, ptr: str) -> int:
        if isinstance(value, str):
            if value not in self.material_names:
                known = _names(self.material_names) if self.material_names else "none (there is no \"materials\" object)"
                self.fail(ptr, f"unknown material {value!r}; known materials: {known}")
            return self.material_names[value]
        if isinstance(value, dict):
            return self.scene.add_material(self.material_def(value, ptr))
        self.fail(ptr, f"expected a material name or a material object, got {_describe(value)}")

    def default(self, material):
        if material is not None:
            return material
        if self.default_material is None:
            self.default_material = self.scene.add_material(Material())
        return self.default_material

    def accel(self, value, ptr: str):
        if value is None:
            return None
        if not isinstance(value, str) or not value.strip():
            self.fail(ptr, f"expected an accelerator spec such as \"bvh\" (or null), got {_describe(value)}")
        try:
            parse_spec(value)
        except OptionError as e:
            self.fail(ptr, str(e))
        return value.strip()

    # ---- groups and items ------------------------------------------------------------

    def body(self, value, ptr: str, group: Group, depth: int, material):
        b = self.obj(value, ptr, BODY_KEYS, what="a group object")
        if "accel" in b:
            group.accel = self.accel(b["accel"], f"{ptr}/accel")
        if "material" in b:
            material = self.material(b["material"], f"{ptr}/material")
        items = b.get("items", [])
        if not isinstance(items, list):
            self.fail(f"{ptr}/items", f"expected a list of items, got {_describe(items)}")
        for i, item in enumerate(items):
            self.item(item, f"{ptr}/items/{i}", group, depth, material)

    def too_deep(self, ptr: str, level: int, what: str):
        self.fail(ptr, f"{what} nests groups {level} levels deep; at most MAX_NESTING = {MAX_NESTING} levels "
                       f"are allowed (the root is level 1, each group within a group or an instance one more)")

    def place(self, depth: int, group: Group, ptr: str, what: str):
        level = depth + 1 + self.height(group)
        if level > MAX_NESTING:
            self.too_deep(ptr, level, what)

    def height(self, group: Group) -> int:
        h = self.heights.get(id(group))
        if h is None:
            h = 0
            for child in group.children:
                h = max(h, 1 + self.height(child.group if isinstance(child, Instance) else child))
            self.heights[id(group)] = h
        return h

    def item(self, item, ptr: str, group: Group, depth: int, material):
        operators = _operators()
        item_kinds = PRIMITIVE_KINDS + ("mesh", "include", "group", "instance") + tuple(operators)
        if not isinstance(item, dict):
            self.fail(ptr, f"expected an item object with one of {_names(item_kinds)}, got {_describe(item)}")
        kinds = [k for k in item if k in item_kinds]
        if len(kinds) != 1:
            for key in item:
                if key not in item_kinds and key not in ("transform", "motion", "material", _COMMENT):
                    self.unknown_key(ptr, key, item_kinds + ("transform", "motion", "material"))
            got = " and ".join(repr(k) for k in kinds) if kinds else "none"
            self.fail(ptr, f"an item needs exactly one of {_names(item_kinds)}; got {got}")
        kind = kinds[0]
        takes_material = kind in PRIMITIVE_KINDS or kind == "mesh"
        allowed = (kind, "transform", "motion") + (("material",) if takes_material else ())
        if "material" in item and not takes_material:
            hint = ("give the group body a \"material\"" if kind == "group" else
                    f"give the {kind} object a \"material\"" if kind in operators else
                    "materials come from the NFF file" if kind == "include" else
                    "give the named group a \"material\"")
            self.fail(_key(ptr, "material"), f"{'an' if kind[0] in 'aeiou' else 'a'} {kind} item takes no \"material\" ({hint}); "
                                              f"allowed keys: {_names(allowed)}, {_COMMENT}")
        self.obj(item, ptr, allowed)
        kptr = f"{ptr}/{kind}"
        value = item[kind]
        matrix = self.transform(item["transform"], f"{ptr}/transform") if "transform" in item else None
        motion = self.motion(item["motion"], f"{ptr}/motion") if "motion" in item else None
        if motion is not None and matrix is None:
            matrix = np.eye(4)

        if takes_material:
            mat = self.material(item["material"], f"{ptr}/material") if "material" in item else self.default(material)
            if matrix is not None and depth + 1 > MAX_NESTING:
                self.too_deep(_key(ptr, "transform"), depth + 1, "this transformed item")
            target = group if matrix is None else Group(name=kind)
            if kind == "mesh":
                target.add(self.mesh(value, kptr, mat))
            else:
                getattr(self, kind)(value, kptr, target, mat)
            if matrix is not None:
                group.children.append(self.instance(target, matrix, ptr, motion))
            return

        if kind == "group":
            if depth + 1 > MAX_NESTING:
                self.too_deep(kptr, depth + 1, "this group")
            child = Group()
            self.body(value, kptr, child, depth + 1, material)
        elif kind in operators:
            child = self.operator(operators[kind], value, kptr, depth + 1, material)
        elif kind == "instance":
            name = self.string(value, kptr, "a group name")
            child = self.named(name, kptr)
            self.place(depth, child, kptr, f"instancing {name!r} here")
            if matrix is None:
                matrix = np.eye(4)
        else:
            child = self.include(value, kptr)
            self.place(depth, child, kptr, "this include")
        group.children.append(child if matrix is None else self.instance(child, matrix, ptr, motion))

    def operator(self, op, value, ptr: str, depth: int, material) -> Group:
        """An operator item (op: its registered Kind): a group with the kind's spec and one child
        per operand, the items of its lists in order."""
        kind, lists = op.name, tuple(op.operand_lists)
        b = self.obj(value, ptr, lists + ("material",), required=lists, what=f"a {kind} object")
        if depth + 1 > MAX_NESTING:
            self.too_deep(ptr, depth + 1, f"this {kind}'s operands")
        if "material" in b:
            material = self.material(b["material"], f"{ptr}/material")
        group = Group(name=kind)
        counts = {}
        for key in lists:
            items = b[key]
            if not isinstance(items, list):
                self.fail(f"{ptr}/{key}", f"expected a list of items, got {_describe(items)}")
            for i, item in enumerate(items):
                iptr = f"{ptr}/{key}/{i}"
                holder = Group(name=kind)
                self.item(item, iptr, holder, depth + 1, material)
                operand = holder.children[0] if len(holder.children) == 1 and not any(
                    True for _ in holder.primitive_sets()) else holder
                if _has_cones(operand):
                    self.fail(iptr, f"a cone is an open surface, not a closed solid: it cannot be a {kind} operand")
                group.children.append(operand)
            counts[key] = len(items)
        n = len(group.children)
        if op.max_operands and n > op.max_operands:
            self.fail(ptr, f"a {kind} takes at most {op.max_operands} operands, got {n}: "
                           "gather some in an operator item of their own")
        group.accel = op.operand_spec(counts) if op.operand_spec else kind
        return group

    def instance(self, group: Group, matrix: np.ndarray, ptr: str, motion: Motion | None = None) -> Instance:
        """An instance of group; with a motion, its matrix moves: motion(t) @ matrix."""
        try:
            with np.errstate(over="ignore", under="ignore", invalid="ignore"):
                if motion is not None:
                    for i, key in enumerate(motion.keys):
                        Instance(group, motion.matrix(key.time) @ matrix)   # every key's placement is checked
                inst = Instance(group, matrix)
        except SceneError as e:
            self.fail(f"{ptr}/{'transform' if motion is None else 'motion'}", e.message)
        if motion is not None:
            self.motions.append((inst, matrix, motion))
        return inst

    def named(self, name: str, ptr: str) -> Group:
        if name in self.built:
            return self.built[name]
        if name not in self.group_defs:
            known = _names(self.group_defs) if self.group_defs else "none (there is no \"groups\" object)"
            self.fail(ptr, f"unknown group {name!r}; known groups: {known}")
        if name in self.building:
            cycle = self.building[self.building.index(name):] + [name]
            self.fail(ptr, f"groups instance themselves in a cycle: {' -> '.join(repr(n) for n in cycle)}")
        if len(self.building) + 2 > MAX_NESTING:
            self.too_deep(ptr, len(self.building) + 2, f"instancing {name!r} here")
        self.building.append(name)
        group = Group(name=name)
        self.body(self.group_defs[name], _key("/groups", name), group, depth=2, material=None)
        self.building.pop()
        self.built[name] = group
        return group

    # ---- primitives --------------------------------------------------------------------

    def sphere(self, value, ptr, group, material):
        s = self.obj(value, ptr, ("center", "radius"), required=("center", "radius"))
        radius = self.number(s["radius"], f"{ptr}/radius")
        if radius == 0.0:
            self.fail(f"{ptr}/radius", "a sphere radius must not be zero (negative: only the inside is visible)")
        group.spheres.add(self.vec3(s["center"], f"{ptr}/center"), radius, material)

    def cone(self, value, ptr, group, material):
        keys = ("base", "base_radius", "apex", "apex_radius")
        c = self.obj(value, ptr, keys, required=keys)
        base, apex = self.vec3(c["base"], f"{ptr}/base"), self.vec3(c["apex"], f"{ptr}/apex")
        r0 = self.number(c["base_radius"], f"{ptr}/base_radius")
        r1 = self.number(c["apex_radius"], f"{ptr}/apex_radius")
        if np.array_equal(base, apex):
            self.fail(ptr, "a cone's base and apex must differ")
        if r0 == 0.0 and r1 == 0.0:
            self.fail(ptr, "a cone's base_radius and apex_radius must not both be zero")
        group.cones.add(base, r0, apex, r1, material)

    def polygon(self, value, ptr, group, material):
        group.polygons.add(self.vectors(value, ptr, 3, "vertices"), material)

    def patch(self, value, ptr, group, material):
        p = self.obj(value, ptr, ("vertices", "normals"), required=("vertices", "normals"))
        vertices = self.vectors(p["vertices"], f"{ptr}/vertices", 3, "vertices")
        normals = self.vectors(p["normals"], f"{ptr}/normals", 3, "normals")
        if len(normals) != len(vertices):
            self.fail(f"{ptr}/normals", f"expected one normal per vertex: {len(vertices)} vertices, "
                                        f"{len(normals)} normals")
        zero = np.nonzero(~np.any(normals != 0.0, axis=1))[0]
        if len(zero):
            self.fail(f"{ptr}/normals/{zero[0]}", "a normal must not be zero")
        group.patches.add(vertices, material, normals)

    def mesh(self, value, ptr, material) -> TriangleMesh:
        if isinstance(value, str):
            return self.mesh_file(value, ptr, material)
        m = self.obj(value, ptr, ("vertices", "faces", "normals"), required=("vertices", "faces"),
                     what="a mesh object or a mesh file name")
        vertices = self.vectors(m["vertices"], f"{ptr}/vertices", 3, "vertices")
        faces = self.faces(m["faces"], f"{ptr}/faces", len(vertices))
        normals = None
        if "normals" in m:
            normals = self.vectors(m["normals"], f"{ptr}/normals", 1, "normals")
            if len(normals) != len(vertices):
                self.fail(f"{ptr}/normals", f"expected one normal per vertex: {len(vertices)} vertices, "
                                            f"{len(normals)} normals")
        return TriangleMesh(vertices, faces, material, normals)

    def resolve(self, name: str, ptr: str, what: str) -> Path:
        p = Path(name)
        if not p.is_absolute():
            p = self.base_dir / p
        if not p.is_file():
            self.fail(ptr, f"{what} not found: {name!r} (looked for {os.path.abspath(p)})")
        return p

    def mesh_file(self, name, ptr, material) -> TriangleMesh:
        if not name:
            self.fail(ptr, "expected a mesh file name, got an empty string")
        p = self.resolve(name, ptr, "mesh file")
        try:
            import trimesh
        except ImportError:
            self.fail(ptr, f"loading the mesh file {name!r} needs trimesh, an optional extra: "
                           f"pip install raykernel[mesh]")
        try:
            tm = trimesh.load(str(p), force="mesh", process=False)
            vertices = np.asarray(tm.vertices, np.float64).reshape(-1, 3)
            faces = np.asarray(tm.faces, np.int64).reshape(-1, 3)
        except Exception as e:  # trimesh raises many kinds
            self.fail(ptr, f"cannot load the mesh file {str(p)!r}: {e}")
        if len(faces) == 0:
            self.fail(ptr, f"the mesh file {str(p)!r} holds no triangles")
        try:
            return TriangleMesh(vertices, faces, material)
        except SceneError as e:
            self.fail(ptr, f"{p}: {e.message}")

    # ---- includes --------------------------------------------------------------------

    def include(self, value, ptr: str) -> Group:
        accel = None
        if isinstance(value, dict):
            inc = self.obj(value, ptr, ("file", "accel"), required=("file",))
            fptr = f"{ptr}/file"
            name = self.string(inc["file"], fptr, "an NFF file name")
            if "accel" in inc:
                accel = self.accel(inc["accel"], f"{ptr}/accel")
        else:
            fptr = ptr
            name = self.string(value, ptr, "an NFF file name or {\"file\": ..., \"accel\": ...}")
        p = self.resolve(name, fptr, "include file")
        key = (os.path.normcase(os.path.abspath(p)), accel)
        if key in self.includes:
            return self.includes[key]
        try:
            from .nff import read_nff
        except ImportError:
            self.fail(fptr, "NFF includes need raykernel.scene.nff, which is not available")
        try:
            sub = read_nff(p)
        except SceneError as e:
            raise SceneError(f"{e.message} (included from {self.where(fptr)})", path=e.path, line=e.line) from None
        except OSError as e:
            self.fail(fptr, f"cannot read the include file {str(p)!r}: {e.strerror or e}")
        self.adopt_materials(sub, fptr)
        if self.from_nff["camera"] is None and _nff_has_view(sub, p):
            self.from_nff["camera"] = sub.camera
        if self.from_nff["background"] is None and _nff_has_background(sub, p):
            self.from_nff["background"] = np.asarray(sub.background, np.float64)
        if self.from_nff["lights"] is None and sub.lights:
            self.from_nff["lights"] = list(sub.lights)
        group = sub.root
        group.name = p.stem
        if accel is not None:
            group.accel = accel
        self.includes[key] = group
        return group

    def adopt_materials(self, sub: Scene, ptr: str):
        mapping = np.array([self.scene.add_material(m) for m in sub.materials], np.int32)
        seen = set()
        stack = [sub.root]
        while stack:
            g = stack.pop()
            if id(g) in seen:
                continue
            seen.add(id(g))
            for s in (g.spheres, g.cones, g.polygons, g.patches, *g.meshes):
                s.freeze()
                if len(s.material):
                    if s.material.min() < 0 or s.material.max() >= len(mapping):
                        self.fail(ptr, f"the included scene uses material {int(s.material.max())} "
                                       f"but defines {len(mapping)}")
                    s.material = mapping[s.material]
            stack.extend(c.group if isinstance(c, Instance) else c for c in g.children)

    # ---- transforms --------------------------------------------------------------------

    def transform(self, ops, ptr: str) -> np.ndarray:
        if isinstance(ops, dict):
            ops, ptrs = [ops], [ptr]
        elif isinstance(ops, list):
            ptrs = [f"{ptr}/{i}" for i in range(len(ops))]
        else:
            self.fail(ptr, f"expected a transform operation ({_names(TRANSFORM_OPS)}) or a list of them, "
                           f"got {_describe(ops)}")
        matrix = np.eye(4)
        with np.errstate(over="ignore", invalid="ignore"):
            for op, optr in zip(ops, ptrs):
                matrix = self.operation(op, optr) @ matrix
        if not np.all(np.isfinite(matrix)):
            self.fail(ptr, "the transform overflows (its numbers are too large)")
        return matrix

    def operation(self, op, optr: str) -> np.ndarray:
        op = self.obj(op, optr, TRANSFORM_OPS, what=f"a transform operation ({_names(TRANSFORM_OPS)})")
        names = [k for k in op if k != _COMMENT]
        if len(names) != 1:
            got = " and ".join(repr(k) for k in names) if names else "none"
            self.fail(optr, f"a transform operation needs exactly one of {_names(TRANSFORM_OPS)}; got {got}")
        name = names[0]
        return getattr(self, "op_" + name)(op[name], f"{optr}/{name}")

    def op_translate(self, value, ptr):
        m = np.eye(4)
        m[:3, 3] = self.vec3(value, ptr)
        return m

    def op_rotate(self, value, ptr):
        r = self.obj(value, ptr, ("axis", "degrees"), required=("axis", "degrees"))
        axis = self.vec3(r["axis"], f"{ptr}/axis")
        if not np.any(axis != 0.0):
            self.fail(f"{ptr}/axis", "a rotation axis must not be zero")
        return _rotation(axis, self.number(r["degrees"], f"{ptr}/degrees"))

    def op_scale(self, value, ptr):
        if isinstance(value, list):
            factors = self.vec3(value, ptr)
            zero = np.nonzero(factors == 0.0)[0]
            if len(zero):
                self.fail(f"{ptr}/{zero[0]}", "a scale factor must not be zero")
        else:
            if not _is_number(value):
                self.fail(ptr, f"expected a number or a list of 3 numbers, got {_describe(value)}")
            factors = np.full(3, self.number(value, ptr))
            if factors[0] == 0.0:
                self.fail(ptr, "a scale factor must not be zero")
        return np.diag([*factors, 1.0])

    def op_matrix(self, value, ptr):
        if not isinstance(value, list) or len(value) != 4:
            self.fail(ptr, f"expected 4 rows of 4 numbers, got {_describe(value)}")
        rows = []
        for i, row in enumerate(value):
            if not isinstance(row, list) or len(row) != 4:
                self.fail(f"{ptr}/{i}", f"expected a row of 4 numbers, got {_describe(row)}")
            rows.append([self.number(v, f"{ptr}/{i}/{j}") for j, v in enumerate(row)])
        m = np.array(rows)
        if not np.array_equal(m[3], [0.0, 0.0, 0.0, 1.0]):
            self.fail(f"{ptr}/3", f"the last row of an affine matrix must be [0, 0, 0, 1], got {m[3].tolist()}")
        if np.linalg.matrix_rank(m[:3, :3]) < 3:
            self.fail(ptr, "the matrix is singular (it flattens space); it must be invertible")
        return m


def _nff_keyword(sub: Scene, path: Path, attribute: str, keyword: str) -> bool:
    """Whether the NFF file gave an entity: the reader's flag where it keeps
    one, else whether the keyword occurs as a token outside comments (NFF
    keywords are never numbers, so the test is exact)."""
    flag = getattr(sub, attribute, None)
    if isinstance(flag, bool):
        return flag
    try:
        with open(path, encoding="utf-8", errors="replace") as f:
            return any(keyword in line.split("#", 1)[0].split() for line in f)
    except OSError:
        return False


def _nff_has_view(sub: Scene, path: Path) -> bool:
    return _nff_keyword(sub, path, "has_camera", "v")


def _nff_has_background(sub: Scene, path: Path) -> bool:
    return _nff_keyword(sub, path, "has_background", "b")


# ---- public reading API ------------------------------------------------------------------


def transform_matrix(ops) -> np.ndarray:
    """The 4x4 local-to-world matrix of a JSON transform: one operation object
    or a list of them, the first applied first. Raises SceneError for a bad
    operation, located as transform/<index>/<op>/...

        transform_matrix([{"scale": 2}, {"translate": [1, 0, 0]}])   # x -> 2x + 1
    """
    return _Reader(None, ".").transform(ops, "transform")


def scene_from_json(data, path=None, base_dir=None) -> Scene:
    """A Scene from an already decoded JSON document (a dict). `path` names
    the document in error messages; files are found relative to `base_dir`
    (default: the directory of `path`, else the working directory)."""
    if base_dir is None:
        base_dir = Path(path).parent if path is not None else Path.cwd()
    try:
        return _Reader(path, base_dir).read(data)
    except RecursionError:
        raise SceneError("the scene is nested too deeply", path=None if path is None else str(path)) from None


def parse_json(text: str, path=None, base_dir=None) -> Scene:
    """A Scene from JSON text; `path` and `base_dir` as for `scene_from_json`."""
    where = None if path is None else str(path)
    if not text.strip():
        raise SceneError("the file is empty; expected a JSON object", path=where)
    try:
        data = json.loads(text, object_pairs_hook=_object_pairs, parse_constant=_CONSTANTS.__getitem__)
    except json.JSONDecodeError as e:
        raise SceneError(f"invalid JSON: {e.msg} (column {e.colno})", path=where, line=e.lineno) from None
    except RecursionError:
        raise SceneError("invalid JSON: nested too deeply", path=where) from None
    return scene_from_json(data, path=path, base_dir=base_dir)


def read_json(path) -> Scene:
    """Read a JSON scene file (see the module documentation for the format).

    Parameters
    ----------
    path : str or path-like
        The JSON file, UTF-8 (with or without a byte order mark); files it refers to are found
        relative to its directory.

    Returns
    -------
    Scene

    Raises
    ------
    SceneError
        The file cannot be read, is not JSON, or is not a valid scene; the message names the
        file and where in it.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise SceneError("file not found", path=str(path)) from None
    except UnicodeDecodeError as e:
        raise SceneError(f"not UTF-8 text (byte {e.start})", path=str(path)) from None
    except OSError as e:
        raise SceneError(f"cannot read: {e.strerror or e}", path=str(path)) from None
    return parse_json(text, path=path)


# ---- writing -----------------------------------------------------------------------------


def _floats(arr) -> list:
    return np.asarray(arr, np.float64).tolist()


def _material_json(m: Material) -> dict:
    return {"color": [float(c) for c in m.color], "kd": float(m.kd), "ks": float(m.ks),
            "shine": float(m.shine), "t": float(m.t), "ior": float(m.ior), "kl": float(m.kl)}


class _Writer:
    def __init__(self, scene: Scene):
        self.scene = scene
        self.n_materials = len(scene.materials)
        self.refs: dict[int, int] = {}
        self.groups: dict[int, Group] = {}
        self.order: list[int] = []
        self.count(scene.root, [])
        self.names: dict[int, str] = {}
        taken = set()
        shared = [gid for gid in self.order if self.refs.get(gid, 0) > 1]
        for gid in shared:
            name = self.groups[gid].name
            if name and name not in taken and not (name[0] == "g" and name[1:].isdigit()):
                self.names[gid] = name
                taken.add(name)
        k = 0
        for gid in shared:
            if gid not in self.names:
                while f"g{k}" in taken:
                    k += 1
                self.names[gid] = f"g{k}"
                taken.add(f"g{k}")

    def count(self, group: Group, path: list):
        gid = id(group)
        on_path = [i for i, g in enumerate(path) if g is group]
        if on_path:
            names = " -> ".join(repr(g.name or "?") for g in path[on_path[0]:] + [group])
            raise SceneError(f"the scene graph has a cycle: {names}")
        if gid in self.groups:
            return
        self.groups[gid] = group
        self.order.append(gid)
        for child in group.children:
            g = child.group if isinstance(child, Instance) else child
            self.refs[id(g)] = self.refs.get(id(g), 0) + 1
            self.count(g, path + [group])

    def material(self, index: int, where: str) -> str:
        index = int(index)
        if not 0 <= index < self.n_materials:
            raise SceneError(f"{where} uses material {index}, but the scene has {self.n_materials} materials")
        return f"m{index}"

    def body(self, group: Group) -> dict:
        where = f"group {group.name!r}" if group.name else "a group"
        items = []
        s = group.spheres.freeze()
        for c, r, m in zip(s.center, s.radius, s.material):
            items.append({"sphere": {"center": _floats(c), "radius": float(r)},
                          "material": self.material(m, f"a sphere in {where}")})
        c = group.cones.freeze()
        for b, br, a, ar, m in zip(c.base, c.base_radius, c.apex, c.apex_radius, c.material):
            items.append({"cone": {"base": _floats(b), "base_radius": float(br), "apex": _floats(a),
                                   "apex_radius": float(ar)},
                          "material": self.material(m, f"a cone in {where}")})
        for polys in (group.polygons, group.patches):
            polys.freeze()
            for i in range(len(polys)):
                v, n = polys.polygon(i)
                entry = {"vertices": _floats(v), "normals": _floats(n)} if polys.patches else _floats(v)
                items.append({polys.kind: entry, "material": self.material(polys.material[i], f"a {polys.kind} in {where}")})
        for mesh in group.meshes:
            if len(mesh.faces) == 0:
                continue
            items.extend(self.mesh(mesh, where))
        for child in group.children:
            g = child.group if isinstance(child, Instance) else child
            name = self.names.get(id(g))
            item = {"instance": name} if name is not None else {"group": self.body(g)}
            if isinstance(child, Instance):
                moving = self.scene.animation.motion_of(child) if self.scene.animation is not None else None
                item["transform"] = {"matrix": _floats(child.matrix if moving is None else moving[0])}
                if moving is not None:
                    item["motion"] = [{"time": float(k.time), "translate": _floats(k.translate),
                                       "quaternion": _floats(k.rotate), "scale": _floats(k.scale)}
                                      for k in moving[1].keys]
            items.append(item)
        out = {}
        if group.accel is not None:
            out["accel"] = group.accel
        out["items"] = items
        return out

    def mesh(self, mesh: TriangleMesh, where: str) -> list:
        materials = np.unique(mesh.material)
        if len(materials) <= 1:
            parts = [(mesh.faces, mesh.vertices, mesh.normals, materials[0] if len(materials) else 0)]
        else:
            parts = []
            for m in materials:
                faces = mesh.faces[mesh.material == m]
                used, compact = np.unique(faces, return_inverse=True)
                parts.append((compact.reshape(-1, 3), mesh.vertices[used],
                              None if mesh.normals is None else mesh.normals[used], m))
        items = []
        for faces, vertices, normals, m in parts:
            entry = {"vertices": _floats(vertices), "faces": np.asarray(faces, np.int64).tolist()}
            if normals is not None:
                entry["normals"] = _floats(normals)
            items.append({"mesh": entry, "material": self.material(m, f"a mesh in {where}")})
        return items

    def document(self) -> dict:
        scene = self.scene
        cam = scene.camera
        out = {
            "camera": {"eye": _floats(cam.eye), "look_at": _floats(cam.look_at), "up": _floats(cam.up),
                       "angle": float(cam.angle), "hither": float(cam.hither),
                       "resolution": [int(cam.width), int(cam.height)]}
            | ({} if cam.medium is None else {"medium": f"m{cam.medium}"}),
            "background": _floats(scene.background),
            "lights": [{"position": _floats(light.position)}
                       | ({} if light.color is None else {"color": _floats(light.color)})
                       for light in scene.lights],
            "materials": {f"m{i}": _material_json(m) for i, m in enumerate(scene.materials)},
        }
        anim = scene.animation
        if anim is not None:
            if anim.generate is not None:
                raise SceneError(f"{anim.source}: a generated animation (each frame made by its generator) has no "
                                 "JSON form; write one frame, or keyframes")
            if anim.base_camera is not None:
                base = anim.base_camera
                out["camera"].update(eye=_floats(base.eye), look_at=_floats(base.look_at), up=_floats(base.up),
                                     angle=float(base.angle))
            if anim.camera is not None:
                out["camera"]["path"] = [{k: (float(v) if k in ("time", "angle") else _floats(v)) for k, v in key.items()}
                                         for key in anim.camera.keys]
            out["animation"] = {"time": [float(t) for t in anim.time], "fps": float(anim.fps)}
        if self.names:
            out["groups"] = {name: self.body(self.groups[gid]) for gid, name in self.names.items()}
        out["scene"] = self.body(scene.root)
        return out


def scene_to_json(scene: Scene) -> dict:
    """The scene as a JSON-ready dict in the format `read_json` reads."""
    return _Writer(scene).document()


def _scalar(value) -> bool:
    return value is None or isinstance(value, (str, int, float, bool))


def _dumps(value, indent: int = 0) -> str:
    """JSON text with objects indented and lists of numbers kept on one line."""
    pad, inner = "  " * indent, "  " * (indent + 1)
    if isinstance(value, dict):
        if not value:
            return "{}"
        entries = [f"{inner}{json.dumps(k)}: {_dumps(v, indent + 1)}" for k, v in value.items()]
        return "{\n" + ",\n".join(entries) + "\n" + pad + "}"
    if isinstance(value, list):
        if all(_scalar(v) for v in value):
            return "[" + ", ".join(json.dumps(v, allow_nan=False) for v in value) + "]"
        return "[\n" + ",\n".join(inner + _dumps(v, indent + 1) for v in value) + "\n" + pad + "]"
    return json.dumps(value, allow_nan=False)


def write_json(scene: Scene, path) -> Path:
    """Write the scene as JSON, in the format `read_json` reads.

    The file is written atomically: a temporary file in the same directory replaces `path`
    only once it is complete.

    Parameters
    ----------
    scene : Scene
        The scene to write.
    path : str or path-like
        The file to write.

    Returns
    -------
    pathlib.Path
        `path`.
    """
    return write_text(path, _dumps(scene_to_json(scene)) + "\n")

"""Reading and writing NFF, the Neutral File Format of the Standard Procedural Databases.

    scene = read_nff("balls-sf4.nff")          # or parse_nff(text, path="balls.nff")
    write_nff(scene, "copy.nff")               # or text = scene_to_nff(scene)

The reader works on whitespace-separated tokens, not lines: an entity may be
spread over several lines or share one (the SPD writes a whole `c` on one
line), and `#` starts a comment wherever it appears, up to the end of its line.
Every token keeps its line number, so each error is one `SceneError` that
names the file, the line and what was expected there.

A plain file (ASCII, no comments, as the SPD programs write) is read fast:
its tokens found and its numbers read by one compiled pass (tokens.py), and
its spheres, cones, polygons, patches and fills cut out and checked in bulk.
Anything that reading does not accept at once (a comment, a bad token, a
failed check) sends the file to the token-by-token reading, which gives the
same scene or names the error.

How strict the reader is:

* `b`, `l` and `f` are accepted before the `v` block; the SPD itself writes `b`
  first, and none of the three changes the meaning of the scene by its place.
  A sphere, cone, polygon or patch before the view is an error (NFF requires
  the view first), and so is a second `v` block.
* Lights after geometry are accepted: their order has no effect on the scene.
  A later `b` replaces an earlier one.
* The six view parameters may come in any order but all six must be present,
  each once. The resolution must be a whole number from 1 to 65536 (``512.0``
  is read as 512); the angle must lie strictly between 0 and 180 degrees and
  hither must not be negative.
* A sphere radius of zero is an error; a negative radius is kept (NFF: only the
  inside is visible). A cone whose base and apex coincide, or whose two radii
  are both zero, is an error.
* A polygon needs at least 3 vertices, and its first three must make a proper
  corner, since that corner gives the normal: the corner's cross product must
  exceed `CORNER_TOLERANCE` times the squared size of the polygon's bounding
  box. The one exception is a patch with no area at all (every vertex on one
  line): the SPD teapot at size 1 has four such triangles, so they are kept;
  they are invisible. Patch normals must have non-zero length; they are kept
  as written.
* Numbers are decimal, as C's `atof` reads them (``1``, ``-.5``, ``2.5e-3``);
  NaN, infinities and numbers too large for a double are errors.
* The text must be UTF-8 (a byte order mark is skipped) without NUL bytes.
  Line ends may be LF, CRLF or CR.

Materials are registered in the scene when a primitive first uses them, so
`scene.materials` holds exactly the materials in use, each once. Primitives
before any `f` get `Material()` (white, Kd 1).

The writer flattens groups and instances into one list of NFF entities.
Spheres and cones survive only transforms that are similarities (rotation,
reflection, uniform scale, translation); polygons, patches and triangle meshes
take any affine transform, patch normals through the inverse transpose. A
mirroring transform reverses the vertex order so that the front side stays the
front side. Transformed normals are renormalised to unit length; untransformed
ones are written as they are. Zero-area mesh triangles have no NFF form and
are left out. Numbers are written as C's ``%g`` writes them (6 significant
digits), so a round trip is exact for data that came from NFF and good to
about 5e-6 relative otherwise.
"""

from __future__ import annotations

import math
import operator
import os
import re

import numpy as np

from ..atomicfile import write_text
from ..errors import SceneError
from . import tokens
from .model import Camera, Group, Instance, Light, Material, Scene, TriangleMesh
from .nffwriter import NffWriter

__all__ = ["read_nff", "parse_nff", "write_nff", "scene_to_nff", "CORNER_TOLERANCE", "MAX_RESOLUTION"]

ENTITY_KEYWORDS = ("v", "b", "l", "f", "c", "s", "p", "pp")
VIEW_KEYWORDS = ("from", "at", "up", "angle", "hither", "resolution")
_KEYWORDS = frozenset(ENTITY_KEYWORDS + VIEW_KEYWORDS)

CORNER_TOLERANCE = 1e-10
MAX_RESOLUTION = 65536

_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?\Z", re.ASCII)
_INTEGER = re.compile(r"[+-]?\d+\Z", re.ASCII)
_NONFINITE = re.compile(r"[+-]?(?:nan|inf|infinity)\Z", re.IGNORECASE)

_XYZ = ("x", "y", "z")
_RGB = ("red", "green", "blue")
_PATCH_FIELDS = ("x", "y", "z", "normal x", "normal y", "normal z")
_MATERIAL_FIELDS = _RGB + ("Kd", "Ks", "Shine", "T", "ior")
_CONE_FIELDS = ("base x", "base y", "base z", "base radius", "apex x", "apex y", "apex z", "apex radius")
_SPHERE_FIELDS = ("centre x", "centre y", "centre z", "radius")


def _looks_numeric(token: str) -> bool:
    return bool(_NUMBER.match(token) or _NONFINITE.match(token))


def _corner_is_proper(x0, y0, z0, x1, y1, z1, x2, y2, z2, extent) -> bool:
    """Whether the corner v0, v1, v2 spans a plane, relative to `extent` (the
    largest side of the polygon's bounding box)."""
    if not extent > 0.0 or not math.isfinite(extent):
        return False
    ax, ay, az = (x1 - x0) / extent, (y1 - y0) / extent, (z1 - z0) / extent
    bx, by, bz = (x2 - x0) / extent, (y2 - y0) / extent, (z2 - z0) / extent
    cx = ay * bz - az * by
    cy = az * bx - ax * bz
    cz = ax * by - ay * bx
    return cx * cx + cy * cy + cz * cz > CORNER_TOLERANCE * CORNER_TOLERANCE


def _has_zero_area(values, stride: int, extent) -> bool:
    """Whether the polygon in flat `values` (`stride` numbers per vertex, x y z
    first) has no area, relative to `extent`: its Newell normal vanishes."""
    if not extent > 0.0 or not math.isfinite(extent):
        return True
    xs = [x / extent for x in values[0::stride]]
    ys = [y / extent for y in values[1::stride]]
    zs = [z / extent for z in values[2::stride]]
    nx = ny = nz = 0.0
    for k in range(len(xs)):
        j = k - 1
        nx += (ys[j] - ys[k]) * (zs[j] + zs[k])
        ny += (zs[j] - zs[k]) * (xs[j] + xs[k])
        nz += (xs[j] - xs[k]) * (ys[j] + ys[k])
    return not nx * nx + ny * ny + nz * nz > 4.0 * CORNER_TOLERANCE * CORNER_TOLERANCE


def _corners_are_proper(v0, v1, v2, extent) -> np.ndarray:
    """Vectorised `_corner_is_proper` over rows of (k, 3) arrays."""
    with np.errstate(all="ignore"):
        ok = (extent > 0.0) & np.isfinite(extent)
        e = np.where(ok, extent, 1.0)[:, None]
        a = (v1 - v0) / e
        b = (v2 - v0) / e
        cx = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
        cy = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
        cz = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
        return ok & (cx * cx + cy * cy + cz * cz > CORNER_TOLERANCE * CORNER_TOLERANCE)


# ----------------------------------------------------------------------------------------------
# Reading


def _decode(data: bytes, path: str) -> str:
    nul = data.find(b"\0")
    if nul >= 0:
        raise SceneError(f"not a text NFF file (NUL byte at offset {nul})",
                         path=path, line=data.count(b"\n", 0, nul) + 1)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise SceneError(f"not a text NFF file (byte 0x{data[exc.start]:02x} at offset {exc.start} is not UTF-8)",
                         path=path, line=data.count(b"\n", 0, exc.start) + 1) from None
    return text


class _NotPlain(Exception):
    """The fast reading met what only the token-by-token reading handles or reports."""


def _tokens_and_lines(text: str) -> tuple[list[str], list[int]]:
    """The tokens of `text` with comments removed, and the line of each."""
    tokens: list[str] = []
    lines: list[int] = []
    for number, line in enumerate(text.split("\n"), 1):
        cut = line.find("#")
        if cut >= 0:
            line = line[:cut]
        parts = line.split()
        if parts:
            tokens += parts
            lines += [number] * len(parts)
    return tokens, lines


class _Reader:
    def __init__(self, text: str, path: str, fast: bool = False):
        self.path = path
        if text.startswith("\ufeff"):
            text = text[1:]
        nul = text.find("\0")
        if nul >= 0:
            raise SceneError("not a text NFF file (contains a NUL character)",
                             path=path, line=text.count("\n", 0, nul) + 1)
        text = text.replace("\r\n", "\n").replace("\r", "\n")
        self.fast = fast
        if fast:
            if "#" in text or not text.isascii() or "_" in text:
                raise _NotPlain
            self.toks, self._text, self._lines = text.split(), text, None     # lines when a message needs them
        else:
            self.toks, self._lines = _tokens_and_lines(text)
        self.n = len(self.toks)
        breaks = text.count("\n")
        self.eof_line = max(1, breaks if text.endswith("\n") else breaks + 1)
        joined = "" if fast else "".join(self.toks)     # (a fast one is ASCII without "_")
        # float() also reads "1_0" and non-ASCII digits; such files get checked token by token.
        self.strict = not (joined.isascii() and "_" not in joined)
        self.pos = 0

        self.background = np.zeros(3)
        self.lights: list[Light] = []
        self.camera: Camera | None = None
        self.view_start = -1
        self.materials: list[Material] = []
        self.material_ids: dict[Material, int] = {}
        self.material = Material()
        self.material_index: int | None = None
        self.spheres: list = []
        self.cones: list = []
        self.polygons: list = []
        self.patches: list = []

    # -- errors ---------------------------------------------------------------------------------

    @property
    def lines(self) -> list[int]:
        if self._lines is None:
            self._lines = _tokens_and_lines(self._text)[1]
        return self._lines

    def line_of(self, index: int) -> int:
        if index < self.n:
            return self.lines[index]
        return self.lines[-1] if self.n else self.eof_line

    def error(self, message: str, index: int | None = None, line: int | None = None) -> SceneError:
        if line is None:
            line = self.line_of(self.pos if index is None else index)
        return SceneError(message, path=self.path, line=line)

    # -- numbers --------------------------------------------------------------------------------

    def numbers(self, count: int, field, entity: str, start: int) -> list[float]:
        """The next `count` tokens as finite floats; `field(i)` names the i-th
        for messages, `start` is the index of the entity's keyword."""
        p = self.pos
        end = p + count
        if end <= self.n and not self.strict:
            chunk = self.toks[p:end]
            try:
                values = list(map(float, chunk))
            except ValueError:
                values = None
            if values is not None and all(map(math.isfinite, values)):
                self.pos = end
                return values
        values = []
        for i in range(count):
            values.append(self.number(p + i, field(i), entity, start))
        self.pos = end
        return values

    def number(self, index: int, what: str, entity: str, start: int) -> float:
        cut_short = f"the {entity} starting at line {self.line_of(start)} is cut short"
        if index >= self.n:
            raise self.error(f"unexpected end of file: expected a number for the {entity} {what} ({cut_short})",
                             index)
        token = self.toks[index]
        if _NUMBER.match(token):
            value = float(token)
            if math.isfinite(value):
                return value
            raise self.error(f"expected a finite number for the {entity} {what}, got {token!r} (too large)", index)
        if _NONFINITE.match(token):
            raise self.error(f"expected a finite number for the {entity} {what}, got {token!r}", index)
        if token in _KEYWORDS:
            raise self.error(f"expected a number for the {entity} {what}, got keyword {token!r} ({cut_short})",
                             index)
        raise self.error(f"expected a number for the {entity} {what}, got {token!r}", index)

    # -- driver ---------------------------------------------------------------------------------

    def parse(self) -> Scene:
        if self.n == 0:
            raise self.error("empty file: no view and no geometry", line=self.eof_line)
        if self.fast:
            return self.parse_fast()
        handlers = {"v": self.view, "b": self.background_color, "l": self.light, "f": self.fill,
                    "c": self.cone, "s": self.sphere, "p": self.polygon, "pp": self.patch}
        toks = self.toks
        while self.pos < self.n:
            start = self.pos
            handler = handlers.get(toks[start])
            if handler is None:
                self.unexpected(start)
            self.pos += 1
            handler(start)
        if self.camera is None:
            raise self.error("no view block: NFF needs 'v' with from, at, up, angle, hither and resolution",
                             self.n)
        return self.build()

    def unexpected(self, index: int):
        token = self.toks[index]
        keywords = ", ".join(ENTITY_KEYWORDS)
        if _looks_numeric(token):
            raise self.error(f"expected a keyword ({keywords}), got the number {token!r} "
                             "(an extra number after the previous entity?)", index)
        if token in VIEW_KEYWORDS:
            raise self.error(f"{token!r} outside a view block: it belongs right after 'v'", index)
        raise self.error(f"unknown keyword {token!r}: expected one of {keywords}", index)

    def require_view(self, start: int, entity: str):
        if self.camera is None:
            raise self.error(f"{entity} before the view block: NFF requires 'v' (from, at, up, angle, "
                             "hither, resolution) before any geometry", start)

    def current_material(self) -> int:
        if self.material_index is None:
            index = self.material_ids.get(self.material)
            if index is None:
                index = len(self.materials)
                self.materials.append(self.material)
                self.material_ids[self.material] = index
            self.material_index = index
        return self.material_index

    # -- entities -------------------------------------------------------------------------------

    def background_color(self, start: int):
        self.background = np.array(self.numbers(3, _RGB.__getitem__, "background colour", start))

    def view(self, start: int):
        if self.camera is not None:
            raise self.error(f"a second view block (the first is at line {self.line_of(self.view_start)})", start)
        seen: dict[str, tuple[int, list[float]]] = {}
        while len(seen) < len(VIEW_KEYWORDS):
            missing = [k for k in VIEW_KEYWORDS if k not in seen]
            names = ", ".join(repr(k) for k in missing)
            index = self.pos
            if index >= self.n:
                raise self.error(f"unexpected end of file: the view block at line {self.line_of(start)} is "
                                 f"missing {names}", index)
            key = self.toks[index]
            if key not in VIEW_KEYWORDS:
                got = f"the number {key!r}" if _looks_numeric(key) else repr(key)
                raise self.error(f"the view block at line {self.line_of(start)} is missing {names}: expected "
                                 f"{' or '.join(repr(k) for k in missing)}, got {got}", index)
            if key in seen:
                raise self.error(f"a second {key!r} in the view block (the first is at line "
                                 f"{self.line_of(seen[key][0])})", index)
            self.pos += 1
            if key in ("from", "at", "up"):
                values = self.numbers(3, _XYZ.__getitem__, f"view '{key}'", index)
            elif key == "resolution":
                values = self.numbers(2, ("width", "height").__getitem__, "view resolution", index)
                for k, value in enumerate(values):
                    token = self.toks[index + 1 + k]
                    if not value.is_integer():
                        raise self.error(f"expected a whole number for the view resolution "
                                         f"{('width', 'height')[k]}, got {token!r}", index + 1 + k)
                    if not 1 <= value <= MAX_RESOLUTION:
                        raise self.error(f"the view resolution {('width', 'height')[k]} must be from 1 to "
                                         f"{MAX_RESOLUTION}, got {token!r}", index + 1 + k)
            else:
                values = self.numbers(1, lambda i: "value", f"view '{key}'", index)
            seen[key] = (index, values)

        def at(key):
            return self.line_of(seen[key][0])

        eye = np.array(seen["from"][1])
        look_at = np.array(seen["at"][1])
        up = np.array(seen["up"][1])
        angle = seen["angle"][1][0]
        hither = seen["hither"][1][0]
        width, height = (int(x) for x in seen["resolution"][1])
        if np.array_equal(eye, look_at):
            raise self.error("the view 'at' point is the same as 'from': there is no view direction",
                             line=at("at"))
        if not 0.0 < angle < 180.0:
            raise self.error(f"the view angle must be between 0 and 180 degrees (exclusive), got {angle:g}",
                             line=at("angle"))
        if hither < 0.0:
            raise self.error(f"the view hither distance must not be negative, got {hither:g}", line=at("hither"))
        with np.errstate(all="ignore"):
            side = np.linalg.norm(np.cross(look_at - eye, up))
        if not side > 0.0:
            raise self.error("the view 'up' vector is zero or parallel to the view direction", line=at("up"))
        try:
            self.camera = Camera(eye=eye, look_at=look_at, up=up, angle=angle, hither=hither,
                                 width=width, height=height)
        except SceneError as exc:
            raise self.error(exc.message, line=self.line_of(start)) from None
        self.view_start = start

    def light(self, start: int):
        position = self.numbers(3, _XYZ.__getitem__, "light position", start)
        color = None
        if self.pos < self.n and _looks_numeric(self.toks[self.pos]):
            color = self.numbers(3, _RGB.__getitem__, "light colour", start)
        self.lights.append(Light(position, color))

    def fill(self, start: int):
        v = self.numbers(8, _MATERIAL_FIELDS.__getitem__, "material ('f')", start)
        self.material = Material(color=(v[0], v[1], v[2]), kd=v[3], ks=v[4], shine=v[5], t=v[6], ior=v[7])
        self.material_index = None

    def sphere(self, start: int):
        self.require_view(start, "a sphere")
        v = self.numbers(4, _SPHERE_FIELDS.__getitem__, "sphere", start)
        if v[3] == 0.0:
            raise self.error("the sphere radius must not be zero (a negative radius means only the inside "
                             "is visible)", start + 4)
        self.spheres.append((v, self.current_material()))

    def cone(self, start: int):
        self.require_view(start, "a cone")
        v = self.numbers(8, _CONE_FIELDS.__getitem__, "cone", start)
        if v[0:3] == v[4:7]:
            raise self.error("the cone base and apex are the same point", start)
        if v[3] == 0.0 and v[7] == 0.0:
            raise self.error("the cone has zero radius at both ends", start)
        self.cones.append((v, self.current_material()))

    def vertex_count(self, start: int, entity: str, per_vertex: int) -> int:
        index = self.pos
        if index >= self.n:
            raise self.error(f"unexpected end of file: expected the vertex count of the {entity}", index)
        token = self.toks[index]
        if not _INTEGER.match(token):
            if token in _KEYWORDS:
                raise self.error(f"expected the vertex count of the {entity}, got keyword {token!r}", index)
            raise self.error(f"expected a whole number for the vertex count of the {entity}, got {token!r}", index)
        count = int(token) if len(token) <= 20 else (-1 if token.startswith("-") else 10 ** 20)
        if count < 3:
            raise self.error(f"a {entity} needs at least 3 vertices, got a vertex count of {token}", index)
        remaining = self.n - index - 1
        if count * per_vertex > remaining:
            raise self.error(f"the {entity} declares {token} vertices ({count * per_vertex} numbers) but only "
                             f"{remaining} tokens follow: the file is truncated or the count is wrong", index)
        self.pos += 1
        return count

    def polygon(self, start: int):
        self.require_view(start, "a polygon")
        count = self.vertex_count(start, "polygon", 3)
        values = self.numbers(3 * count, lambda i: f"vertex {i // 3 + 1} {_XYZ[i % 3]}", "polygon", start)
        self.check_corner(values, 3, start, "polygon")
        self.polygons.append((values, count, self.current_material()))

    def patch(self, start: int):
        self.require_view(start, "a patch")
        count = self.vertex_count(start, "patch", 6)
        first = self.pos
        values = self.numbers(6 * count, lambda i: f"vertex {i // 6 + 1} {_PATCH_FIELDS[i % 6]}", "patch", start)
        self.check_corner(values, 6, start, "patch", allow_zero_area=True)
        for k in range(count):
            nx, ny, nz = values[6 * k + 3:6 * k + 6]
            length2 = nx * nx + ny * ny + nz * nz
            if not 0.0 < length2 < math.inf:
                problem = "zero length" if length2 == 0.0 else "a length too large to normalise"
                raise self.error(f"the patch normal at vertex {k + 1} has {problem}", first + 6 * k + 3)
        self.patches.append((values, count, self.current_material()))

    # -- the fast reading: the file's structure found in bulk -----------------------------------

    def parse_fast(self) -> Scene:
        """parse()'s scene, reading the entities that make up a plain file's bulk (spheres,
        cones, polygons, patches and fills) with array operations: keywords are the tokens
        that start with a letter, every other token must be a finite number, and each entity's
        numbers must run exactly to the next keyword. The few others (the view, lights and
        background) take their handlers in file order. Anything else: _NotPlain."""
        toks, n = self.toks, self.n
        values, kinds = tokens.scan(self._text.encode("ascii"))
        if len(kinds) != n:
            raise _NotPlain
        is_keyword = kinds == tokens.WORD
        at = np.flatnonzero(is_keyword)             # keywords' token positions
        if len(at) == 0 or at[0] != 0:
            raise _NotPlain
        try:
            code = np.fromiter(map(_CODES.__getitem__, [toks[i] for i in at.tolist()]), np.int64, len(at))
            for i in np.flatnonzero(kinds == tokens.OTHER).tolist():
                values[i] = float(toks[i])          # the few numbers the scan leaves to Python
        except (KeyError, ValueError):
            raise _NotPlain from None
        values = values[~is_keyword]
        if not np.isfinite(values).all():
            raise _NotPlain
        run = np.diff(at, append=n) - 1                 # numbers after each keyword
        number = at - np.arange(len(at))                # index in `values` of each keyword's first number

        # the view, lights and background, in file order (a view consumes its keywords)
        for j in np.flatnonzero(code >= _CODES["v"]).tolist():
            start, c = int(at[j]), int(code[j])
            if start < self.pos:
                continue                                # a view keyword its block has read
            if c in _VIEW_CODES:
                raise _NotPlain
            self.pos = start + 1
            _HANDLERS[c](self, start)
            if self.pos < n and not is_keyword[self.pos]:
                raise _NotPlain                         # numbers left over
        bulk = np.flatnonzero(code < _CODES["f"])
        if self.camera is None or (len(bulk) and at[bulk[0]] < self.view_start):
            raise _NotPlain                             # the token-by-token reading names what is missing

        # materials: each fill's numbers made a Material once, each entity given its last fill's,
        # registered in order of first use
        f = np.flatnonzero(code == _CODES["f"])
        if np.any(run[f] != 8):
            raise _NotPlain
        rows, fill_row = np.unique(values[number[f, None] + np.arange(8)], axis=0, return_inverse=True)
        fills = [Material()] + [Material(color=(r[0], r[1], r[2]), kd=r[3], ks=r[4], shine=r[5], t=r[6], ior=r[7])
                                for r in rows.tolist()]
        # each entity's fill: 0 for none before it, else 1 + its row
        which = np.concatenate(([0], 1 + fill_row.reshape(-1)))[np.searchsorted(f, bulk)]
        used, first_use = np.unique(which, return_index=True)
        ids = np.zeros(len(fills), np.int32)
        for k in used[np.argsort(first_use)].tolist():
            self.material, self.material_index = fills[k], None
            ids[k] = self.current_material()
        material_of = np.zeros(len(at), np.int32)
        material_of[bulk] = ids[which]

        self.bulk = {}
        for kind, per_vertex, counted in (("s", 4, False), ("c", 8, False), ("p", 3, True), ("pp", 6, True)):
            j = np.flatnonzero(code == _CODES[kind])
            first = number[j]
            if counted:
                if np.any(run[j] < 1):
                    raise _NotPlain
                count_tokens = set(_pick(toks, at[j] + 1))
                if not all(_INTEGER.match(t) for t in count_tokens):
                    raise _NotPlain
                count = values[first] if len(j) else np.zeros(0)
                if np.any(count < 3) or np.any(run[j] != 1 + per_vertex * count):
                    raise _NotPlain
                count = count.astype(np.int64)
                first = first + 1
            else:
                count = np.ones(len(j), np.int64)
                if np.any(run[j] != per_vertex):
                    raise _NotPlain
            sizes = per_vertex * count
            offset = np.cumsum(sizes) - sizes
            index = np.repeat(first - offset, sizes) + np.arange(int(sizes.sum()))
            self.bulk[kind] = (values[index].reshape(-1, per_vertex), count, material_of[j])
        return self.build_fast()

    def build_fast(self) -> Scene:
        """build()'s scene from the bulk entities' numbers, after the checks the entities' own
        readers make (any that fails: _NotPlain, and the token-by-token reading names it)."""
        scene = Scene(camera=self.camera, background=self.background, lights=self.lights,
                      materials=self.materials, source=self.path)
        root = scene.root
        v, _, material = self.bulk["s"]
        if np.any(v[:, 3] == 0.0):
            raise _NotPlain
        root.spheres.center, root.spheres.radius, root.spheres.material = v[:, :3].copy(), v[:, 3].copy(), material
        v, _, material = self.bulk["c"]
        if np.any(np.all(v[:, 0:3] == v[:, 4:7], axis=1) | ((v[:, 3] == 0.0) & (v[:, 7] == 0.0))):
            raise _NotPlain
        cones = root.cones
        cones.base, cones.base_radius, cones.apex, cones.apex_radius = (v[:, 0:3].copy(), v[:, 3].copy(),
                                                                       v[:, 4:7].copy(), v[:, 7].copy())
        cones.material = material
        for kind, target in (("p", root.polygons), ("pp", root.patches)):
            v, count, material = self.bulk[kind]
            start = np.cumsum(count) - count
            vertices = np.ascontiguousarray(v[:, :3])
            if len(count):
                extent = (np.maximum.reduceat(vertices, start) - np.minimum.reduceat(vertices, start)).max(axis=1)
                if not _corners_are_proper(vertices[start], vertices[start + 1], vertices[start + 2], extent).all():
                    raise _NotPlain     # (a patch with no area at all is allowed: the slow reading knows)
            if kind == "pp":
                nx, ny, nz = v[:, 3], v[:, 4], v[:, 5]
                with np.errstate(over="ignore"):        # too long for the range: the slow reading names it
                    length2 = nx * nx + ny * ny + nz * nz
                if not np.all((length2 > 0.0) & (length2 < math.inf)):
                    raise _NotPlain
                target.normals = np.ascontiguousarray(v[:, 3:])
            target.vertices, target.start, target.count, target.material = vertices, start, count, material
        return scene

    def check_corner(self, values: list[float], stride: int, start: int, entity: str,
                     allow_zero_area: bool = False):
        xs, ys, zs = values[0::stride], values[1::stride], values[2::stride]
        extent = max(max(xs) - min(xs), max(ys) - min(ys), max(zs) - min(zs))
        if not _corner_is_proper(*values[0:3], *values[stride:stride + 3], *values[2 * stride:2 * stride + 3],
                                 extent):
            if allow_zero_area and _has_zero_area(values, stride, extent):
                return
            raise self.error(f"the {entity}'s first three vertices are coincident or collinear: they must form "
                             "a proper corner, which gives the normal", start)

    # -- result ---------------------------------------------------------------------------------

    def build(self) -> Scene:
        scene = Scene(camera=self.camera, background=self.background, lights=self.lights,
                      materials=self.materials, source=self.path)
        root = scene.root
        for v, material in self.spheres:
            root.spheres.add(v[0:3], v[3], material)
        for v, material in self.cones:
            root.cones.add(v[0:3], v[3], v[4:7], v[7], material)
        for v, count, material in self.polygons:
            root.polygons.add(np.array(v).reshape(count, 3), material)
        for v, count, material in self.patches:
            a = np.array(v).reshape(count, 6)
            root.patches.add(a[:, :3], material, a[:, 3:])
        for s in (root.spheres, root.cones, root.polygons, root.patches):
            s.freeze()
        return scene


# the fast reading's tables: the keywords' codes (the entities read in bulk below "v") and the
# others' handlers
_CODES = {k: i for i, k in enumerate(("s", "c", "p", "pp", "f", "v", "b", "l") + VIEW_KEYWORDS)}
_VIEW_CODES = frozenset(_CODES[k] for k in VIEW_KEYWORDS)
_HANDLERS = {_CODES["v"]: _Reader.view, _CODES["b"]: _Reader.background_color, _CODES["l"]: _Reader.light}


def _pick(items: list, index: np.ndarray) -> list:
    """items[i] for each i of index, as a list."""
    if len(index) == 0:
        return []
    picked = operator.itemgetter(*index.tolist())(items)
    return list(picked) if len(index) > 1 else [picked]


def parse_nff(text: str | bytes, path: str = "<string>") -> Scene:
    """The scene in NFF `text` (bytes are decoded as UTF-8); `path` names it in errors
    and becomes `scene.source`."""
    path = str(path)
    if isinstance(text, (bytes, bytearray, memoryview)):
        text = _decode(bytes(text), path)
    elif not isinstance(text, str):
        raise SceneError(f"NFF text must be str or bytes, not {type(text).__name__}", path=path)
    try:
        return _Reader(text, path, fast=True).parse()
    except (_NotPlain, SceneError):
        return _Reader(text, path).parse()      # the same scene, or the error with its line


def read_nff(path) -> Scene:
    """Read the scene in an NFF file.

    Parameters
    ----------
    path : str or path-like
        The NFF file; it becomes the scene's ``source`` and names the file in errors.

    Returns
    -------
    Scene

    Raises
    ------
    SceneError
        The file cannot be read, or is not valid NFF; the message names the file, the line and
        what was expected there.
    """
    name = os.fspath(path)
    try:
        with open(name, "rb") as fh:
            data = fh.read()
    except FileNotFoundError:
        raise SceneError("no such file", path=name) from None
    except IsADirectoryError:
        raise SceneError("is a directory, not an NFF file", path=name) from None
    except OSError as exc:
        raise SceneError(f"cannot read the file: {exc.strerror or exc}", path=name) from None
    return parse_nff(data, name)


# ----------------------------------------------------------------------------------------------
# Writing


def _round_g(a: np.ndarray) -> np.ndarray:
    """`a` as the reader will see it after printing with %g."""
    a = np.asarray(a, np.float64)
    if a.size == 0:
        return a.copy()
    return np.char.mod("%g", a).astype(np.float64)


def _corner_mask(vertices: np.ndarray, start: np.ndarray, count: np.ndarray) -> np.ndarray:
    """Whether each polygon (rows of `vertices` from start, count of them) will
    pass the reader's corner test once written."""
    if len(start) == 0:
        return np.zeros(0, bool)
    lo = np.minimum.reduceat(vertices, start, axis=0)
    hi = np.maximum.reduceat(vertices, start, axis=0)
    idx = np.stack([start, start + 1, start + 2])
    first = _round_g(vertices[idx.ravel()]).reshape(3, len(start), 3)
    with np.errstate(all="ignore"):
        extent = (hi - lo).max(axis=1)
    return _corners_are_proper(first[0], first[1], first[2], extent)


class _Flattener:
    def __init__(self, scene: Scene, writer: NffWriter):
        self.scene = scene
        self.w = writer
        self.current: Material | None = None

    def use(self, index: int, what: str):
        materials = self.scene.materials
        if not 0 <= index < len(materials):
            raise SceneError(f"{what} uses material {index}, but the scene has {len(materials)} materials")
        m = materials[index]
        if m != self.current:
            self.w.fill(m.color, m.kd, m.ks, m.shine, m.t, m.ior)
            self.current = m

    def group(self, group: Group, matrix: np.ndarray, active: tuple):
        if any(g is group for g in active):
            raise SceneError(f"the scene graph has a cycle: group {group.name or '(unnamed)'!r} contains itself")
        active = active + (group,)
        name = repr(group.name) if group.name else "(unnamed)"
        a = matrix[:3, :3]
        t = matrix[:3, 3]
        det = float(np.linalg.det(a))
        mirrored = det < 0.0
        spheres, cones = group.spheres.freeze(), group.cones.freeze()
        if len(spheres) or len(cones):
            g = a.T @ a
            s2 = float(np.trace(g)) / 3.0
            if not (s2 > 0.0 and np.allclose(g, s2 * np.eye(3), rtol=0.0, atol=1e-9 * s2)):
                kind = "sphere" if len(spheres) else "cone"
                raise SceneError(f"NFF cannot express a non-uniformly scaled or sheared {kind}: group {name} "
                                 "is placed by a transform that is not rotation, uniform scale and translation")
            scale = math.sqrt(s2)
            zero = np.flatnonzero(spheres.radius * scale == 0.0)
            if len(zero):
                raise SceneError(f"sphere {int(zero[0])} of group {name} has radius zero, which NFF cannot express")
            centers = spheres.center @ a.T + t
            for i in range(len(spheres)):
                self.use(int(spheres.material[i]), f"sphere {i} of group {name}")
                self.w.sphere(centers[i], spheres.radius[i] * scale)
            bases = cones.base @ a.T + t
            apexes = cones.apex @ a.T + t
            same = np.all(_round_g(bases) == _round_g(apexes), axis=1)
            flat = (cones.base_radius * scale == 0.0) & (cones.apex_radius * scale == 0.0)
            bad = np.flatnonzero(same | flat)
            if len(bad):
                i = int(bad[0])
                problem = "its base and apex are the same point" if same[i] else "both its radii are zero"
                raise SceneError(f"cone {i} of group {name} cannot be written: {problem}")
            for i in range(len(cones)):
                self.use(int(cones.material[i]), f"cone {i} of group {name}")
                self.w.cone(bases[i], cones.base_radius[i] * scale, apexes[i], cones.apex_radius[i] * scale)
        identity = np.array_equal(matrix, np.eye(4))
        normal_matrix = np.linalg.inv(a).T
        for polys in (group.polygons.freeze(), group.patches.freeze()):
            if not len(polys):
                continue
            kind = polys.kind
            vertices = polys.vertices @ a.T + t
            normals = None
            if polys.patches:
                normals = polys.normals if identity else polys.normals @ normal_matrix.T
                with np.errstate(all="ignore"):
                    length = np.linalg.norm(normals, axis=1)
                    if not identity:
                        normals = normals / length[:, None]
                bad = np.flatnonzero(~np.all(np.isfinite(normals), axis=1) | ~(length > 0.0))
                if len(bad):
                    i = int(np.searchsorted(polys.start, bad[0], side="right") - 1)
                    raise SceneError(f"{kind} {i} of group {name} has a zero-length normal")
            ok = _corner_mask(vertices, polys.start, polys.count)
            if polys.patches:
                for i in np.flatnonzero(~ok):
                    s, c = int(polys.start[i]), int(polys.count[i])
                    v = _round_g(vertices[s:s + c])
                    ok[i] = _has_zero_area(v.ravel().tolist(), 3, float((v.max(axis=0) - v.min(axis=0)).max()))
            if not np.all(ok):
                i = int(np.flatnonzero(~ok)[0])
                raise SceneError(f"{kind} {i} of group {name}: its first three vertices are coincident or "
                                 "collinear (as written with 6 digits), so NFF cannot give it a normal")
            for i in range(len(polys)):
                s, c = int(polys.start[i]), int(polys.count[i])
                order = np.arange(s, s + c)
                if mirrored:
                    order = np.concatenate([order[2::-1], order[:2:-1]])
                self.use(int(polys.material[i]), f"{kind} {i} of group {name}")
                if normals is None:
                    self.w.polygon(vertices[order])
                else:
                    self.w.patch(vertices[order], normals[order])
        for k, mesh in enumerate(group.meshes):
            self.mesh(mesh, a, t, None if identity else normal_matrix, mirrored, f"mesh {k} of group {name}")
        for child in group.children:
            if isinstance(child, Instance):
                self.group(child.group, matrix @ child.matrix, active)
            else:
                self.group(child, matrix, active)

    def mesh(self, mesh: TriangleMesh, a, t, normal_matrix, mirrored: bool, what: str):
        if not len(mesh.faces):
            return
        vertices = mesh.vertices @ a.T + t
        faces = mesh.faces[:, [0, 2, 1]] if mirrored else mesh.faces
        tri = vertices[faces]
        keep = _corner_mask(tri.reshape(-1, 3), np.arange(0, 3 * len(faces), 3), np.full(len(faces), 3))
        normals = None
        if mesh.normals is not None:
            normals = mesh.normals
            if normal_matrix is not None:
                with np.errstate(all="ignore"):
                    normals = normals @ normal_matrix.T
                    normals = normals / np.linalg.norm(normals, axis=1)[:, None]
            corner = _round_g(tri)
            face_normal = np.cross(corner[:, 1] - corner[:, 0], corner[:, 2] - corner[:, 0])
            with np.errstate(all="ignore"):
                face_normal = face_normal / np.linalg.norm(face_normal, axis=1)[:, None]
            tri_normals = normals[faces]
            usable = np.all(np.isfinite(tri_normals), axis=2) & (np.abs(tri_normals).max(axis=2) > 0.0)
            tri_normals = np.where(usable[:, :, None], tri_normals, face_normal[:, None, :])
            normals = tri_normals
        for i in np.flatnonzero(keep):
            self.use(int(mesh.material[i]), f"triangle {i} of {what}")
            if normals is None:
                self.w.polygon(tri[i])
            else:
                self.w.patch(tri[i], normals[i])


def scene_to_nff(scene: Scene) -> str:
    """NFF text for `scene`, with groups and instances flattened."""
    w = NffWriter()
    w.background(scene.background)
    cam = scene.camera
    w.view(cam.eye, cam.look_at, cam.up, cam.angle, cam.hither, (cam.width, cam.height))
    for light in scene.lights:
        w.light(light.position, light.color)
    _Flattener(scene, w).group(scene.root, np.eye(4), ())
    return w.text()


def write_nff(scene: Scene, path) -> None:
    """Write `scene` as NFF, with groups and instances flattened.

    The file is replaced atomically: the text goes to a temporary file in the same directory,
    then takes the name.

    Parameters
    ----------
    scene : Scene
        The scene to write.
    path : str or path-like
        The file to write.
    """
    write_text(path, scene_to_nff(scene))

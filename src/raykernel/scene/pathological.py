"""The pathological scenes of "Ray Tracing News" vol. 2 no. 1: scenes built to
defeat acceleration structures by extreme differences of scale or density.

    from raykernel.scene import pathological
    scene = pathological.load("stadium", ratio=1e6)     # or raykernel.load("scene:stadium")
    scene = pathological.stadium(ratio=1e6)              # the same
    pathological.NAMES                                    # the scene names
    pathological.PARAMS["stadium"]["ratio"]               # (default, help)

Every scene is a function with keyword parameters (each has a default) that
returns a `Scene` whose parts are separate groups (the teapot is one group, the
stadium another, ...), so that nested aggregates can be tried on them.
`load(name, **params)` takes the values as numbers or as strings (as they come
from the command line) and checks them: an unknown parameter, a value that is
not a number (or not a whole number where one is needed) or a value out of
range is an `OptionError` naming the parameter and its allowed range.
`load("stadium:ratio=1e6,teapot_prims=2000")` gives the parameters after the
name, so `raykernel.load("scene:stadium:ratio=1e6")` works too.

All lengths are in feet, z is up.

stadium      Haines's teapot in a football stadium. The stadium, 200 yards
             (600 ft) long from the back of one stand to the back of the
             other, is a field of grass strips and lines, four stands of
             stepped rows with seats, goal posts and four light towers. A
             mirror-shiny teapot sits on the goal line at the origin, its
             largest side stadium_length / ratio; the camera frames the
             teapot and the four tower lights light the scene.
satellite    The earth as one sphere of its real radius and a satellite about
             5 ft across (body boxes, two solar panel wings of many cells, a
             dish of triangles, struts as cylinders) in a circular orbit.
             The origin is the satellite's position at time 0, z pointing
             away from the earth's centre, which lies at (0, 0, -(R + h)):
             the satellite's coordinates stay small, so they survive NFF's
             six significant digits.
             `time` moves the satellite along its orbit with the real period,
             turning it to keep its dish towards the earth.
sun          A neighbourhood of houses, trees and roads lit by the sun: a
             sphere of radius 432,450 miles, `distance_miles` away. The point
             light sits one sun radius in front of the sun's surface, on the
             line from its centre towards the origin: at the centre, the sun's
             own surface would block every shadow ray to it; from there it
             also lights the face of the sun that the camera sees.
teapot-room  A furnished room (walls, floor boards, a table, chairs, a
             bookcase of books, a lamp) with a teapot on the table, so small
             against the room that the first levels of an octree do not
             separate its facets.
park         Arvo's amusement park (scene/park.py): rides, trees and a fractal
             mountain, with his hand-made hierarchy of subspaces on its groups.
diamond      Glassner's case of many facets sharing one vertex: a cut gem
             whose pavilion is a fan of `facets` triangles around the culet,
             with a crown of as many facets and a table.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from ..errors import OptionError
from .model import Camera, Group, Material, Scene, TriangleMesh
from .park import park

__all__ = ["NAMES", "PARAMS", "TIME_SPANS", "load", "describe", "stadium", "satellite", "sun", "teapot_room", "diamond",
           "FEET_PER_MILE", "EARTH_RADIUS_MILES", "SUN_RADIUS_MILES", "SUN_DISTANCE_MILES", "STADIUM_LENGTH"]

FEET_PER_MILE = 5280.0
EARTH_RADIUS_MILES = 3958.8              # mean radius
SUN_RADIUS_MILES = 432450.0
SUN_DISTANCE_MILES = 93.0e6
GM_EARTH = 3.986004418e14 / 0.3048 ** 3  # ft^3 / s^2
STADIUM_LENGTH = 600.0                   # 200 yards


# ---- parameters ------------------------------------------------------------------------------

@dataclass(frozen=True)
class _Param:
    default: float
    lo: float
    hi: float
    integer: bool
    help: str


_SPECS: dict[str, dict[str, _Param]] = {
    "stadium": {
        "ratio": _Param(600.0, 1.0, 1e6, False, "stadium length / teapot size"),
        "stadium_prims": _Param(5000, 500, 1_000_000, True, "primitives in the stadium"),
        "teapot_prims": _Param(5000, 100, 1_000_000, True, "teapot facets, rounded to the nearest SPD teapot size"),
        "teapot_bvh": _Param(0, 0, 1, True, "1: the teapot group gets its own BVH, nested in the structure "
                             "over the stadium (Haines's fix for the problem voxel)"),
    },
    "satellite": {
        "time": _Param(0.0, -1e9, 1e9, False, "seconds along the orbit from the start position"),
        "altitude_miles": _Param(200.0, 1.0, 1e6, False, "height of the orbit above the earth's surface"),
        "prims": _Param(3000, 100, 1_000_000, True, "primitives in the satellite"),
        "scale": _Param(1.0, 1e-3, 1e6, False, "satellite size factor, 1 for its real size of about 5 ft"),
    },
    "sun": {
        "distance_miles": _Param(SUN_DISTANCE_MILES, 1e6, 1e12, False, "distance of the sun's centre"),
        "prims": _Param(3000, 50, 1_000_000, True, "primitives on the ground (houses, trees, roads)"),
    },
    "teapot-room": {
        "teapot_size": _Param(0.75, 1e-6, 4.0, False, "largest side of the teapot in feet (the table is 4 ft)"),
        "teapot_prims": _Param(1000, 100, 1_000_000, True, "teapot facets, rounded to the nearest SPD teapot size"),
        "room_prims": _Param(1000, 400, 1_000_000, True, "primitives in the furnished room"),
    },
    "diamond": {
        "facets": _Param(1000, 3, 1_000_000, True, "triangles sharing the culet (and crown facets)"),
    },
    "park": {
        "rides": _Param(6, 1, 64, True, "triple-decker merry-go-rounds"),
        "horses": _Param(24, 1, 256, True, "horses with riders on each deck of a ride"),
        "trees": _Param(500, 0, 1_000_000, True, "trees (one group, instanced)"),
        "mountain_level": _Param(6, 0, 9, True, "the fractal mountain has 2 x 4^level triangles"),
        "ride_grid": _Param(16, 1, 256, True, "cells along the longest side of each ride's grid"),
        "top": _Param(0, 0, 1, True, "the structure over the park: 0 a coarse grid, 1 ray classification"),
        "seed": _Param(1, 0, 2 ** 31 - 1, True, "random seed of the mountain and the trees' places"),
    },
}

NAMES = tuple(_SPECS)
TIME_SPANS = {"satellite": (0.0, 600.0)}
"""The default time range of the scenes that move (a `time` parameter): ten minutes of the orbit."""


def _fmt(x: float) -> str:
    """1000, 0.75, 1e6, 9.3e7, 1e-6: short forms that parse back as the same number."""
    x = float(x)
    if x.is_integer() and abs(x) < 1e5:
        return str(int(x))
    text = f"{x:g}"
    mantissa, e, exponent = text.partition("e")
    return mantissa + (e + str(int(exponent)) if e else "")


def _range_text(p: _Param) -> str:
    kind = "a whole number" if p.integer else "a number"
    return f"{kind} from {_fmt(p.lo)} to {_fmt(p.hi)}"


PARAMS = {name: {key: ((int(p.default) if p.integer else p.default), f"{p.help} ({_range_text(p)})")
                 for key, p in spec.items()} for name, spec in _SPECS.items()}
"""Scene name -> parameter -> (default, help text with the allowed range)."""


def _convert(scene: str, key: str, p: _Param, value):
    where = f"scene {scene}: parameter {key}"
    if isinstance(value, bool):
        raise OptionError(f"{where} must be {_range_text(p)}, got {value!r}")
    if isinstance(value, str):
        text = value.strip()
        try:
            number = float(text)
        except ValueError:
            raise OptionError(f"{where} must be {_range_text(p)}, got {value!r} (not a number)") from None
    else:
        try:
            number = float(value)
        except (TypeError, ValueError):
            raise OptionError(f"{where} must be {_range_text(p)}, got {value!r} (not a number)") from None
    if not math.isfinite(number):
        raise OptionError(f"{where} must be {_range_text(p)}, got {value!r}")
    if p.integer and not number.is_integer():
        raise OptionError(f"{where} must be {_range_text(p)}, got {value!r} (not a whole number)")
    if not p.lo <= number <= p.hi:
        raise OptionError(f"{where} must be {_range_text(p)}, got {value!r} (out of range)")
    return int(number) if p.integer else number


def _checked(scene: str, params: dict) -> dict:
    spec = _SPECS[scene]
    unknown = [k for k in params if k not in spec]
    if unknown:
        raise OptionError(f"scene {scene} has no parameter {unknown[0]!r}; its parameters are "
                          + ", ".join(spec))
    return {key: _convert(scene, key, p, params.get(key, p.default)) for key, p in spec.items()}


def _split(name: str) -> tuple[str, dict]:
    """'stadium:ratio=5,teapot_prims=100' -> ('stadium', {'ratio': '5', ...})."""
    base, _, rest = str(name).partition(":")
    params = {}
    for item in filter(None, (s.strip() for s in rest.split(","))):
        key, eq, value = item.partition("=")
        if not eq or not key.strip():
            raise OptionError(f"scene {base}: expected KEY=VALUE after the name, got {item!r}")
        params[key.strip()] = value.strip()
    return base, params


def load(name: str, **params) -> Scene:
    """The scene `name` (one of NAMES, optionally followed by ':KEY=VALUE,...')
    with the given parameters (numbers or strings); the rest take their defaults."""
    base, inline = _split(name)
    if base not in _SCENES:
        raise OptionError(f"unknown scene {base!r}; scenes: {', '.join(NAMES)}")
    inline.update(params)
    values = _checked(base, inline)
    scene = _SCENES[base](**values)
    given = ",".join(f"{k}={inline[k]}" for k in inline)
    scene.source = f"scene:{base}" + (f":{given}" if given else "")
    return scene


def describe() -> str:
    """The scenes with their parameters, defaults and ranges, as text."""
    lines = []
    for name in NAMES:
        doc = (_SCENES[name].__doc__ or "").strip().splitlines()[0]
        lines.append(f"{name}: {doc}")
        spec = _SPECS[name]
        width = max(len(f"{key} = {_fmt(p.default)}") for key, p in spec.items())
        for key, p in spec.items():
            lines.append(f"    {f'{key} = {_fmt(p.default)}':<{width}}   {p.help} ({_range_text(p)})")
    return "\n".join(lines)


# ---- geometry helpers ------------------------------------------------------------------------

# corner bits (x, y, z) of the six faces of a box, counter-clockwise seen from outside
_BOX_FACES = {
    "-x": ((0, 0, 0), (0, 0, 1), (0, 1, 1), (0, 1, 0)),
    "+x": ((1, 0, 0), (1, 1, 0), (1, 1, 1), (1, 0, 1)),
    "-y": ((0, 0, 0), (1, 0, 0), (1, 0, 1), (0, 0, 1)),
    "+y": ((0, 1, 0), (0, 1, 1), (1, 1, 1), (1, 1, 0)),
    "-z": ((0, 0, 0), (0, 1, 0), (1, 1, 0), (1, 0, 0)),
    "+z": ((0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)),
}


def _box(group: Group, lo, hi, material: int, skip=(), axes=None, origin=None) -> int:
    """A box of 6 (less `skip`) quads from corner `lo` to `hi`; with `axes`
    (rows: unit x, y, z) and `origin` the box is in that frame. Returns the count."""
    lo = np.asarray(lo, float)
    hi = np.asarray(hi, float)
    n = 0
    for face, corners in _BOX_FACES.items():
        if face in skip:
            continue
        pts = np.array([[hi[i] if b else lo[i] for i, b in enumerate(c)] for c in corners])
        if axes is not None:
            pts = pts @ np.asarray(axes, float)
        if origin is not None:
            pts = pts + np.asarray(origin, float)
        group.polygons.add(pts, material)
        n += 1
    return n


def _cylinder(group: Group, a, b, r: float, material: int):
    group.cones.add(a, r, b, r, material)


def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def _frame_camera(center, radius: float, direction, up=(0, 0, 1), angle: float = 45.0, fill: float = 1.0,
                  width: int = 512, height: int = 512) -> Camera:
    """A camera looking at `center` from `direction`, far enough that a sphere
    of `radius` about the centre just fits the view (divided by `fill`)."""
    distance = radius / math.sin(math.radians(angle) / 2.0) / fill
    eye = np.asarray(center, float) + _unit(direction) * distance
    return Camera(eye=eye, look_at=center, up=up, angle=angle, hither=distance * 1e-3,
                  width=width, height=height)


def _largest_remainder(total: int, weights) -> np.ndarray:
    """Integers proportional to `weights` that add up to `total`."""
    w = np.asarray(weights, float)
    share = total * w / w.sum()
    out = np.floor(share).astype(np.int64)
    rest = total - int(out.sum())
    if rest > 0:
        out[np.argsort(-(share - out), kind="stable")[:rest]] += 1
    return out


def _teapot_size_factor(prims: int) -> int:
    """SPD teapot size n whose 64 n^2 - 8 n facets come nearest `prims`."""
    n = max(2, int(round(math.sqrt(prims / 64.0))))
    best = min(range(max(2, n - 2), n + 3), key=lambda k: (abs(64 * k * k - 8 * k - prims), k))
    return best


@functools.lru_cache(maxsize=8)
def _teapot_patches(size: int):
    """Vertices (k, 3, 3) and normals (k, 3, 3) of the SPD teapot's triangle patches."""
    from . import spd
    from .nff import parse_nff
    scene = parse_nff(spd.generate("teapot", size), path=f"spd:teapot:{size}")
    p = scene.root.patches.freeze()
    if not np.all(p.count == 3):
        raise AssertionError("the SPD teapot's patches are triangles")
    v = p.vertices.reshape(-1, 3, 3)
    n = p.normals.reshape(-1, 3, 3)
    v.setflags(write=False)
    n.setflags(write=False)
    return v, n


def _add_teapot(group: Group, prims: int, size: float, material: int, base=(0.0, 0.0, 0.0)):
    """The SPD teapot scaled so that its largest bounding-box side is `size`,
    centred over `base` in x and y and standing on it."""
    verts, norms = _teapot_patches(_teapot_size_factor(prims))
    flat = verts.reshape(-1, 3)
    lo, hi = flat.min(axis=0), flat.max(axis=0)
    scale = size / float((hi - lo).max())
    shift = np.array([(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0, lo[2]])
    world = (verts - shift) * scale + np.asarray(base, float)
    for v, n in zip(world, norms):
        group.patches.add(v, material, n)
    lo_w = (lo - shift) * scale + base
    hi_w = (hi - shift) * scale + base
    return lo_w, hi_w


def _bake(group: Group, m: np.ndarray):
    """Move every primitive of `group` and its child groups by the rigid 4x4 matrix `m`."""
    a, t = m[:3, :3], m[:3, 3]
    s = group.spheres.freeze()
    s.center = s.center @ a.T + t
    c = group.cones.freeze()
    c.base = c.base @ a.T + t
    c.apex = c.apex @ a.T + t
    for p in (group.polygons.freeze(), group.patches.freeze()):
        p.vertices = p.vertices @ a.T + t
        if p.patches:
            p.normals = p.normals @ a.T
    for mesh in group.meshes:
        mesh.vertices = np.ascontiguousarray(mesh.vertices @ a.T + t)
        if mesh.normals is not None:
            mesh.normals = mesh.normals @ a.T
    for child in group.children:
        _bake(child, m)


# ---- stadium ---------------------------------------------------------------------------------

def stadium(ratio: float = 600.0, stadium_prims: int = 5000, teapot_prims: int = 5000,
            teapot_bvh: int = 0) -> Scene:
    """Haines's teapot in a football stadium.

    ratio          stadium length / teapot size, 1 to 1e6 (default 600: a 1 ft teapot)
    stadium_prims  primitives in the stadium, 500 to 1e6 (default 5000)
    teapot_prims   teapot facets, 100 to 1e6 (default 5000; the SPD teapot size
                   whose facet count is nearest is used: 5112 at the default)
    teapot_bvh     1 gives the teapot group its own BVH, nested inside whatever
                   structure is built over the stadium (default 0: one structure)

    The stadium is 600 ft long (x from -150 to 450) and 420 ft wide; the goal
    line runs along x = 0 and the teapot stands on it at the origin. Groups:
    stadium (field, stands with seats, goalposts, towers) and teapot.
    """
    p = _checked("stadium", dict(ratio=ratio, stadium_prims=stadium_prims, teapot_prims=teapot_prims,
                                 teapot_bvh=teapot_bvh))
    ratio, target = p["ratio"], p["stadium_prims"]
    scene = Scene(background=(0.03, 0.05, 0.12))
    mat = scene.add_material
    grass = (mat(Material((0.16, 0.48, 0.16), kd=0.9)), mat(Material((0.12, 0.40, 0.12), kd=0.9)))
    chalk = mat(Material((0.95, 0.95, 0.95), kd=0.9))
    endzone = mat(Material((0.12, 0.25, 0.60), kd=0.9))
    track = mat(Material((0.55, 0.25, 0.18), kd=0.9))
    concrete = mat(Material((0.55, 0.55, 0.52), kd=0.85))
    seat_colors = (mat(Material((0.70, 0.10, 0.10), kd=0.7, ks=0.2, shine=20.0)),
                   mat(Material((0.10, 0.20, 0.65), kd=0.7, ks=0.2, shine=20.0)))
    goal = mat(Material((1.0, 0.85, 0.10), kd=0.7, ks=0.3, shine=30.0))
    steel = mat(Material((0.5, 0.5, 0.55), kd=0.6, ks=0.4, shine=40.0))
    lamp = mat(Material((1.0, 1.0, 0.9), kd=1.0))
    chrome = mat(Material((0.85, 0.85, 0.9), kd=0.2, ks=0.8, shine=80.0))

    arena = scene.root.add(Group(name="stadium"))
    field = arena.add(Group(name="field"))
    stands = arena.add(Group(name="stands"))
    seats = stands.add(Group(name="seats"))
    posts = arena.add(Group(name="goalposts"))
    towers = arena.add(Group(name="towers"))

    cx = 150.0                       # midfield; the goal lines are x = 0 and x = 300
    half_w = 80.0                    # the field is 160 ft wide (53 1/3 yards, rounded)
    inner_a, inner_b = 200.0, 110.0  # inner edge of the stands (half extents about midfield)
    depth, height = 100.0, 60.0      # of the stands

    # the field: end zones, 5-yard grass strips and lines, all in the plane z = 0
    line = 4.0 / 12.0
    goal_line = 8.0 / 12.0
    xs = [(-30.0, -goal_line / 2, endzone)]
    for k in range(21):
        x = 15.0 * k
        w = goal_line if k in (0, 20) else line
        xs.append((x - w / 2, x + w / 2, chalk))
        if k < 20:
            nxt = goal_line if k + 1 == 20 else line
            xs.append((x + w / 2, x + 15.0 - nxt / 2, grass[k % 2]))
    xs.append((300.0 + goal_line / 2, 330.0, endzone))
    for x0, x1, m in xs:
        field.polygons.add([(x0, -half_w, 0), (x1, -half_w, 0), (x1, half_w, 0), (x0, half_w, 0)], m)
    ax0, ax1, ay = cx - inner_a, cx + inner_a, inner_b
    for y0, y1 in ((-ay, -half_w), (half_w, ay)):     # the apron around the field
        field.polygons.add([(ax0, y0, 0), (ax1, y0, 0), (ax1, y1, 0), (ax0, y1, 0)], track)
    for x0, x1 in ((ax0, -30.0), (330.0, ax1)):
        field.polygons.add([(x0, -half_w, 0), (x1, -half_w, 0), (x1, half_w, 0), (x0, half_w, 0)], track)

    # goal posts on the end lines: post, offset arm, crossbar at 10 ft, uprights 35 ft
    for x, sign in ((-30.0, 1.0), (330.0, -1.0)):
        _cylinder(posts, (x - sign * 6.0, 0, 0), (x - sign * 6.0, 0, 10.0), 0.35, goal)
        _cylinder(posts, (x - sign * 6.0, 0, 10.0), (x, 0, 10.0), 0.3, goal)
        _cylinder(posts, (x, -9.25, 10.0), (x, 9.25, 10.0), 0.3, goal)
        for y in (-9.25, 9.25):
            _cylinder(posts, (x, y, 10.0), (x, y, 45.0), 0.2, goal)

    # light towers on the outer corners, each a pole and a lamp box facing the field
    tower_h = 150.0
    for sx in (-1.0, 1.0):
        for sy in (-1.0, 1.0):
            foot = np.array([cx + sx * (inner_a + depth - 20.0), sy * (inner_b + depth - 20.0), 0.0])
            _cylinder(towers, foot, foot + (0, 0, tower_h), 1.5, steel)
            inward = _unit([cx - foot[0], -foot[1], 0.0])
            side = np.array([-inward[1], inward[0], 0.0])
            axes = np.array([inward, side, [0.0, 0.0, 1.0]])
            _box(towers, (-1.0, -10.0, -6.0), (1.0, 10.0, 6.0), lamp, axes=axes,
                 origin=foot + (0, 0, tower_h) + 2.5 * inward)
            light = foot + (0, 0, tower_h) + 6.0 * inward
            scene.add_light(light, (1.0, 0.97, 0.9))

    # stands: rows of tread and riser on four sides, mitred at the corners, a back wall
    fixed = len(field.polygons) + len(posts.cones) + len(towers.polygons) + len(towers.cones) + 4
    rows = int(min(60, max(4, round(math.sqrt(target) / 3.0))))
    while rows > 4 and fixed + 8 * rows + 2 * 4 * rows > target:
        rows -= 1
    d, h = depth / rows, height / rows

    def ring(o):
        """Corners of the ring at offset o from the inner edge, counter-clockwise."""
        a, b = inner_a + o, inner_b + o
        return np.array([(cx - a, -b), (cx + a, -b), (cx + a, b), (cx - a, b)])

    row_sides = []      # (start, end, inward normal, z of the tread, offset) per row and side
    for k in range(rows):
        inner, outer = ring(k * d), ring((k + 1) * d)
        z0, z1 = k * h, (k + 1) * h
        for i in range(4):
            j = (i + 1) % 4
            a2, b2 = inner[i], inner[j]
            stands.polygons.add([(*a2, z0), (*b2, z0), (*b2, z1), (*a2, z1)], concrete)            # riser
            stands.polygons.add([(*a2, z1), (*outer[i], z1), (*outer[j], z1), (*b2, z1)], concrete)  # tread
            along = _unit(b2 - a2)
            inward = np.array([-along[1], along[0]])
            row_sides.append((a2, b2, along, inward, z1))
    outer = ring(depth)
    for i in range(4):
        j = (i + 1) % 4
        stands.polygons.add([(*outer[i], height), (*outer[j], height), (*outer[j], 0.0), (*outer[i], 0.0)],
                            concrete)

    # seats: a seat and a back per place, as many as the primitive budget allows
    budget = max(0, target - fixed - 8 * rows - 4)
    lengths = [np.linalg.norm(b - a) - 2 * d for a, b, *_ in row_sides]
    per_side = _largest_remainder(budget // 2, lengths)
    seat_h, seat_d = 0.5 * h, 0.35 * d
    for (a2, b2, along, inward, z1), count, length in zip(row_sides, per_side, lengths):
        if count == 0:
            continue
        outward = -inward
        start = a2 + along * d
        width = length / count
        colour = seat_colors[int(round(z1 / h)) % 2]
        for s in range(count):
            u0 = start + along * (s * width + 0.08 * width)
            u1 = start + along * ((s + 1) * width - 0.08 * width)
            front0, front1 = u0 + outward * 0.15 * d, u1 + outward * 0.15 * d
            back0, back1 = front0 + outward * seat_d, front1 + outward * seat_d
            zs = z1 + seat_h
            seats.polygons.add([(*front0, zs), (*front1, zs), (*back1, zs), (*back0, zs)], colour)
            seats.polygons.add([(*back0, zs), (*back1, zs), (*back1, zs + seat_h), (*back0, zs + seat_h)], colour)
    if budget % 2:
        stands.polygons.add([(*outer[0], height + 0.01), (*outer[1], height + 0.01),
                             (*ring(depth - 0.5 * d)[1], height + 0.01)], concrete)

    # the teapot on the goal line
    teapot = scene.root.add(Group(name="teapot", accel="bvh" if teapot_bvh else None))
    size = STADIUM_LENGTH / ratio
    lo, hi = _add_teapot(teapot, p["teapot_prims"], size, chrome)
    center = (lo + hi) / 2.0
    radius = float(np.linalg.norm(hi - lo)) / 2.0
    scene.camera = _frame_camera(center, radius, (1.0, -0.6, 0.35))
    return scene


# ---- satellite -------------------------------------------------------------------------------

def satellite(time: float = 0.0, altitude_miles: float = 200.0, prims: int = 3000, scale: float = 1.0) -> Scene:
    """A satellite in orbit with the earth behind it.

    time            seconds along the circular orbit (default 0), with the real
                    period for the altitude (about 91 minutes at 200 miles)
    altitude_miles  height of the orbit above the surface, 1 to 1e6 (default 200)
    prims           primitives in the satellite, 100 to 1e6 (default 3000)
    scale           satellite size factor, 1e-3 to 1e6 (default 1: real size, about 5 ft)

    Groups: earth (one sphere of radius 3958.8 miles) and satellite (body,
    panels, dish, struts). The origin is the satellite's position at time 0;
    z points away from the earth's centre at (0, 0, -(R + altitude)); the
    orbit lies in the x-z plane, the satellite starting along +x.
    """
    p = _checked("satellite", dict(time=time, altitude_miles=altitude_miles, prims=prims, scale=scale))
    s = p["scale"]
    earth_r = EARTH_RADIUS_MILES * FEET_PER_MILE
    orbit = earth_r + p["altitude_miles"] * FEET_PER_MILE
    period = 2.0 * math.pi * math.sqrt(orbit ** 3 / GM_EARTH)
    theta = 2.0 * math.pi * math.fmod(p["time"] / period, 1.0)
    earth_center = np.array([0.0, 0.0, -orbit])
    radial = np.array([math.sin(theta), 0.0, math.cos(theta)])
    forward = np.array([math.cos(theta), 0.0, -math.sin(theta)])
    sideways = np.array([0.0, 1.0, 0.0])
    position = earth_center + orbit * radial

    scene = Scene(background=(0.0, 0.0, 0.0))
    mat = scene.add_material
    ocean = mat(Material((0.18, 0.32, 0.75), kd=0.9, ks=0.1, shine=10.0))
    foil = mat(Material((0.85, 0.65, 0.20), kd=0.55, ks=0.45, shine=25.0))
    cell = mat(Material((0.06, 0.10, 0.35), kd=0.5, ks=0.5, shine=60.0))
    backing = mat(Material((0.85, 0.85, 0.85), kd=0.8))
    white = mat(Material((0.92, 0.92, 0.92), kd=0.85, ks=0.15, shine=20.0))
    metal = mat(Material((0.6, 0.6, 0.62), kd=0.5, ks=0.5, shine=40.0))
    dark = mat(Material((0.15, 0.15, 0.15), kd=0.7, ks=0.3, shine=30.0))

    earth = scene.root.add(Group(name="earth"))
    earth.spheres.add(earth_center, earth_r, ocean)

    sat = scene.root.add(Group(name="satellite"))
    body = sat.add(Group(name="body"))
    panels = sat.add(Group(name="panels"))
    dish = sat.add(Group(name="dish"))
    struts = sat.add(Group(name="struts"))

    # body (local frame: x along the flight, y along the panel wings, z away from the earth)
    _box(body, (-0.8 * s, -0.6 * s, -0.6 * s), (0.8 * s, 0.6 * s, 0.6 * s), foil)
    _box(body, (-0.3 * s, -0.3 * s, 0.6 * s), (0.3 * s, 0.3 * s, 0.9 * s), white)             # instrument deck
    _box(body, (0.8 * s, -0.15 * s, 0.1 * s), (1.05 * s, 0.15 * s, 0.35 * s), dark)           # star tracker
    body.spheres.add((0.0, 0.0, 0.98 * s), 0.08 * s, metal)                                 # sensor
    body.spheres.add((-0.2 * s, 0.2 * s, 0.93 * s), 0.04 * s, dark)
    for dy in (-0.25, 0.25):                                                                  # thrusters
        for dz in (-0.25, 0.25):
            body.cones.add((-0.8 * s, dy * s, dz * s), 0.04 * s, (-0.98 * s, dy * s, dz * s), 0.09 * s, metal)
    _cylinder(struts, (0.5 * s, 0.4 * s, 0.6 * s), (0.5 * s, 0.4 * s, 1.5 * s), 0.012 * s, metal)  # whip antenna
    _cylinder(struts, (0.5 * s, -0.4 * s, 0.6 * s), (0.5 * s, -0.4 * s, 1.3 * s), 0.012 * s, metal)

    # the dish (a paraboloid of triangles) below the body, facing the earth, with feed and struts
    dish_r, dish_depth, hub = 0.75 * s, 0.18 * s, -0.85 * s
    focal = dish_r ** 2 / (4.0 * dish_depth)          # z = hub - r^2 / (4 focal)
    _cylinder(struts, (0.0, 0.0, -0.6 * s), (0.0, 0.0, hub), 0.06 * s, metal)
    feed_tip = np.array([0.0, 0.0, hub - focal])
    struts.cones.add(feed_tip + (0, 0, 0.05 * s), 0.05 * s, feed_tip - (0, 0, 0.05 * s), 0.025 * s, metal)
    for k in range(3):
        a = 2.0 * math.pi * k / 3.0
        rim = np.array([0.95 * dish_r * math.cos(a), 0.95 * dish_r * math.sin(a),
                        hub - dish_depth * 0.95 ** 2])
        _cylinder(struts, rim, feed_tip + (0, 0, 0.05 * s), 0.01 * s, metal)
    for k in range(2):                                     # wing booms
        sign = 1.0 if k == 0 else -1.0
        _cylinder(struts, (0.0, sign * 0.6 * s, 0.0), (0.0, sign * 0.9 * s, 0.0), 0.03 * s, metal)
    fixed = len(body.polygons) + len(body.spheres) + len(body.cones) + len(struts.cones) + 2
    budget = p["prims"] - fixed
    dish_budget = max(16, int(budget * 0.2))
    segments = max(8, int(round(math.sqrt(dish_budget * 1.5))))
    rings = max(1, int(round((dish_budget / segments + 1) / 2)))
    verts, normals, faces = [(0.0, 0.0, hub)], [(0.0, 0.0, -1.0)], []
    for i in range(1, rings + 1):
        r = dish_r * i / rings
        for j in range(segments):
            a = 2.0 * math.pi * j / segments
            x, y = r * math.cos(a), r * math.sin(a)
            verts.append((x, y, hub - r * r / (4.0 * focal)))
            normals.append(tuple(-_unit([x / (2.0 * focal), y / (2.0 * focal), 1.0])))
    for j in range(segments):
        faces.append((0, 1 + (j + 1) % segments, 1 + j))
    for i in range(1, rings):
        a0, b0 = 1 + (i - 1) * segments, 1 + i * segments
        for j in range(segments):
            j1 = (j + 1) % segments
            faces.append((a0 + j, a0 + j1, b0 + j1))
            faces.append((a0 + j, b0 + j1, b0 + j))
    dish.add(TriangleMesh(np.array(verts), np.array(faces), white, normals=np.array(normals)))

    # solar panel wings: a backing sheet and a grid of cells on each
    cells = max(2, (p["prims"] - fixed - len(faces) - 2) // 2)
    wing_len, wing_w = 1.6 * s, 0.9 * s
    nx = max(1, int(round(math.sqrt(cells * wing_w / wing_len))))
    ny = max(1, cells // nx)
    extra = cells - nx * ny
    for sign in (1.0, -1.0):
        y0, y1 = sign * 0.9 * s, sign * (0.9 * s + wing_len)
        lo_y, hi_y = min(y0, y1), max(y0, y1)
        panels.polygons.add([(-wing_w / 2, lo_y, -0.01 * s), (-wing_w / 2, hi_y, -0.01 * s),
                             (wing_w / 2, hi_y, -0.01 * s), (wing_w / 2, lo_y, -0.01 * s)], backing)
        gap = 0.06
        for i in range(nx):
            rows_here = ny + (1 if i < extra else 0)
            for j in range(rows_here):
                cx0 = -wing_w / 2 + wing_w * (i + gap) / nx
                cx1 = -wing_w / 2 + wing_w * (i + 1 - gap) / nx
                cy0 = lo_y + (hi_y - lo_y) * (j + gap) / rows_here
                cy1 = lo_y + (hi_y - lo_y) * (j + 1 - gap) / rows_here
                panels.polygons.add([(cx0, cy0, 0.0), (cx1, cy0, 0.0), (cx1, cy1, 0.0), (cx0, cy1, 0.0)], cell)

    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = forward, sideways, radial, position
    _bake(sat, m)

    # the camera a few feet up and aside, looking down at the satellite and the earth beyond
    eye = position + s * (3.0 * radial + 5.0 * forward + 2.5 * sideways)
    scene.camera = Camera(eye=eye, look_at=position, up=radial, angle=45.0, hither=0.01 * s)
    sun_dir = _unit(0.35 * forward - 0.45 * sideways + 0.82 * radial)
    scene.add_light(position + SUN_DISTANCE_MILES * FEET_PER_MILE * sun_dir)
    return scene


# ---- sun -------------------------------------------------------------------------------------

def sun(distance_miles: float = SUN_DISTANCE_MILES, prims: int = 3000) -> Scene:
    """A neighbourhood lit by the sun, a sphere 432,450 miles in radius.

    distance_miles  distance of the sun's centre from the origin, 1e6 to 1e12 (default 93e6)
    prims           primitives on the ground, 50 to 1e6 (default 3000): houses
                    (walls, gable roof, door, windows, chimney), trees (trunk and
                    crown) and roads

    Groups: ground (the land and roads), houses, trees, sun. The sun's centre
    lies distance_miles * 5280 ft from the origin, about 13 degrees above the
    horizon and 15 degrees right of the view, so it is in the picture. The
    sunlight is a point light one sun radius in front of the sun's surface,
    on the line from its centre to the origin, and a dim sky light above the
    camera fills the shadows.
    """
    p = _checked("sun", dict(distance_miles=distance_miles, prims=prims))
    target = p["prims"]
    rng = np.random.default_rng(1987)
    scene = Scene(background=(0.45, 0.65, 0.95))
    mat = scene.add_material
    lawn = mat(Material((0.25, 0.55, 0.2), kd=0.9))
    asphalt = mat(Material((0.25, 0.25, 0.27), kd=0.9))
    walls = [mat(Material(c, kd=0.85)) for c in ((0.9, 0.85, 0.7), (0.75, 0.8, 0.85), (0.85, 0.6, 0.5),
                                                  (0.95, 0.95, 0.9))]
    roofs = [mat(Material(c, kd=0.8, ks=0.1, shine=10.0)) for c in ((0.45, 0.2, 0.15), (0.3, 0.3, 0.32))]
    door = mat(Material((0.4, 0.25, 0.1), kd=0.8))
    glass = mat(Material((0.2, 0.3, 0.4), kd=0.3, ks=0.6, shine=80.0))
    brick = mat(Material((0.6, 0.3, 0.2), kd=0.85))
    bark = mat(Material((0.35, 0.22, 0.12), kd=0.9))
    leaves = [mat(Material(c, kd=0.9)) for c in ((0.15, 0.45, 0.12), (0.2, 0.5, 0.15), (0.1, 0.35, 0.15))]
    sun_mat = mat(Material((1.0, 0.92, 0.6), kd=1.0))

    ground = scene.root.add(Group(name="ground"))
    houses = scene.root.add(Group(name="houses"))
    trees = scene.root.add(Group(name="trees"))
    sun_group = scene.root.add(Group(name="sun"))

    per_lot = 22
    lots = max(1, int(round((target - 5) / (per_lot + 1.0))))
    cols = max(1, int(math.ceil(math.sqrt(lots))))
    nrows = int(math.ceil(lots / cols))
    lot_w, lot_d, road = 90.0, 110.0, 30.0
    block_w, block_d = cols * lot_w, nrows * (lot_d + road)
    x0, y0 = -block_w / 2.0, -block_d / 2.0
    extent = max(block_w, block_d) * 4.0 + 2000.0
    ground.polygons.add([(-extent, -extent, 0), (extent, -extent, 0), (extent, extent, 0), (-extent, extent, 0)],
                        lawn)
    for r in range(nrows):
        ry = y0 + r * (lot_d + road)
        ground.polygons.add([(x0 - 60, ry, 0.05), (x0 + block_w + 60, ry, 0.05),
                             (x0 + block_w + 60, ry + road, 0.05), (x0 - 60, ry + road, 0.05)], asphalt)
    for rx in (x0 - 60.0, x0 + block_w + 30.0):
        ground.polygons.add([(rx, y0 - 60, 0.06), (rx + 30, y0 - 60, 0.06),
                             (rx + 30, y0 + block_d + 60, 0.06), (rx, y0 + block_d + 60, 0.06)], asphalt)

    def count():
        return len(ground.polygons) + len(houses.polygons) + len(trees.spheres) + len(trees.cones) + 1

    def house(cxh, cyh):
        w = rng.uniform(28, 42)
        dd = rng.uniform(24, 32)
        wall_h = rng.choice([10.0, 19.0])
        ridge = wall_h + rng.uniform(7, 11)
        wm, rm = walls[rng.integers(len(walls))], roofs[rng.integers(len(roofs))]
        origin = np.array([cxh, cyh, 0.0])

        def P(pts):
            return np.asarray(pts, float) + origin
        hw, hd = w / 2, dd / 2
        _box(houses, (-hw, -hd, 0.0), (hw, hd, wall_h), wm, skip=("-z", "+z"), origin=origin)
        houses.polygons.add(P([(-hw, -hd, wall_h), (-hw, hd, wall_h), (-hw, 0, ridge)]), wm)
        houses.polygons.add(P([(hw, -hd, wall_h), (hw, 0, ridge), (hw, hd, wall_h)]), wm)
        houses.polygons.add(P([(-hw - 1, -hd - 1.2, wall_h - 0.6), (hw + 1, -hd - 1.2, wall_h - 0.6),
                               (hw + 1, 0, ridge), (-hw - 1, 0, ridge)]), rm)
        houses.polygons.add(P([(-hw - 1, 0, ridge), (hw + 1, 0, ridge),
                               (hw + 1, hd + 1.2, wall_h - 0.6), (-hw - 1, hd + 1.2, wall_h - 0.6)]), rm)
        front = -hd - 0.1
        houses.polygons.add(P([(-2, front, 0.0), (2, front, 0.0), (2, front, 7.0), (-2, front, 7.0)]), door)
        for wx in (-hw * 0.6, hw * 0.6):
            for wz in ((3.0,) if wall_h < 15 else (3.0, 12.0)):
                houses.polygons.add(P([(wx - 2.5, front, wz), (wx + 2.5, front, wz), (wx + 2.5, front, wz + 4),
                                       (wx - 2.5, front, wz + 4)]), glass)
        chim = hw * 0.5
        _box(houses, (chim - 1.2, 1.0, wall_h), (chim + 1.2, 3.4, ridge + 3.0), brick, skip=("-z",),
             origin=origin)

    def tree(x, y):
        trunk_h = rng.uniform(6, 12)
        trees.cones.add((x, y, 0.0), 0.9, (x, y, trunk_h), 0.5, bark)
        leaf = leaves[rng.integers(len(leaves))]
        if rng.random() < 0.5:
            trees.cones.add((x, y, trunk_h - 1.0), rng.uniform(6, 9), (x, y, trunk_h + rng.uniform(18, 30)), 0.0,
                            leaf)
        else:
            r = rng.uniform(6, 10)
            trees.spheres.add((x, y, trunk_h + r * 0.8), r, leaf)

    done = False
    for r in range(nrows):
        for c in range(cols):
            if count() + per_lot > target:
                done = True
                break
            lx = x0 + (c + 0.5) * lot_w
            ly = y0 + r * (lot_d + road) + road + lot_d / 2.0
            house(lx, ly)
            tree(lx - lot_w * 0.35, ly + rng.uniform(-30, 30))
            if count() + 2 <= target:
                tree(lx + lot_w * 0.38, ly + rng.uniform(-40, 40))
        if done:
            break
    while count() + 2 <= target:          # fill the rest of the budget with a park of trees
        k = len(trees.cones) + len(trees.spheres)
        tree(x0 - 150.0 - (k % 7) * 25.0, y0 + (k // 7) * 25.0 % max(block_d, 25.0))

    # the sun, ahead of the camera and above the horizon
    view = _unit([0.35, 1.0, 0.0])
    right = np.cross(view, [0.0, 0.0, 1.0])
    sun_dir = _unit(view + right * math.tan(math.radians(15.0)) + np.array([0.0, 0.0, math.tan(math.radians(13.0))]))
    sun_r = SUN_RADIUS_MILES * FEET_PER_MILE
    sun_center = sun_dir * (p["distance_miles"] * FEET_PER_MILE)
    sun_group.spheres.add(sun_center, sun_r, sun_mat)
    scene.add_light(sun_center - sun_dir * 2.0 * sun_r, (1.3, 1.25, 1.1))
    eye = np.array([x0 + 0.3 * block_w, y0 - 40.0, 22.0])
    scene.camera = Camera(eye=eye, look_at=eye + view * 100.0 + (0, 0, -8.0), up=(0, 0, 1), angle=50.0,
                          hither=0.1)
    scene.add_light(eye + (-2000.0, -3000.0, 8000.0), (0.55, 0.6, 0.7))
    return scene


# ---- teapot room -----------------------------------------------------------------------------

def teapot_room(teapot_size: float = 0.75, teapot_prims: int = 1000, room_prims: int = 1000) -> Scene:
    """A teapot on a table in a furnished room.

    teapot_size   largest side of the teapot in feet, 1e-6 to 4 (default 0.75)
    teapot_prims  teapot facets, 100 to 1e6 (default 1000; the nearest SPD
                  teapot size is used: 992 facets at the default)
    room_prims    primitives in the room and its furniture, 400 to 1e6
                  (default 1000; the floor boards and books take up the budget)

    The room is 16 x 12 x 8 ft (x from -8 to 8, y from -6 to 6), the table
    top's centre at (0, 0, 2.5). Groups: room (walls, floor), furniture
    (table, chairs, bookcase, books, lamp) and teapot.
    """
    p = _checked("teapot-room", dict(teapot_size=teapot_size, teapot_prims=teapot_prims, room_prims=room_prims))
    target = p["room_prims"]
    scene = Scene(background=(0.0, 0.0, 0.0))
    mat = scene.add_material
    plaster = mat(Material((0.85, 0.82, 0.75), kd=0.9))
    ceiling = mat(Material((0.95, 0.95, 0.95), kd=0.9))
    boards = [mat(Material(c, kd=0.7, ks=0.2, shine=30.0)) for c in ((0.55, 0.35, 0.18), (0.5, 0.31, 0.16))]
    wood = mat(Material((0.45, 0.28, 0.14), kd=0.7, ks=0.25, shine=40.0))
    fabric = mat(Material((0.2, 0.35, 0.3), kd=0.9))
    rug = mat(Material((0.55, 0.12, 0.12), kd=0.9))
    glass = mat(Material((0.6, 0.75, 0.9), kd=0.3, ks=0.5, shine=100.0))
    frame_m = mat(Material((0.8, 0.7, 0.3), kd=0.6, ks=0.4, shine=40.0))
    shade = mat(Material((0.95, 0.9, 0.75), kd=0.9))
    book_colors = [mat(Material(c, kd=0.8, ks=0.1, shine=10.0)) for c in
                   ((0.6, 0.1, 0.1), (0.1, 0.3, 0.6), (0.15, 0.45, 0.2), (0.75, 0.65, 0.3), (0.3, 0.2, 0.4))]
    porcelain = mat(Material((0.95, 0.95, 0.92), kd=0.6, ks=0.4, shine=60.0))

    room = scene.root.add(Group(name="room"))
    furniture = scene.root.add(Group(name="furniture"))
    books = furniture.add(Group(name="books"))
    X, Y, Z = 8.0, 6.0, 8.0

    room.polygons.add([(-X, -Y, Z), (-X, Y, Z), (X, Y, Z), (X, -Y, Z)], ceiling)
    room.polygons.add([(-X, -Y, 0), (X, -Y, 0), (X, -Y, Z), (-X, -Y, Z)], plaster)
    room.polygons.add([(X, Y, 0), (-X, Y, 0), (-X, Y, Z), (X, Y, Z)], plaster)
    room.polygons.add([(-X, Y, 0), (-X, -Y, 0), (-X, -Y, Z), (-X, Y, Z)], plaster)
    room.polygons.add([(X, -Y, 0), (X, Y, 0), (X, Y, Z), (X, -Y, Z)], plaster)
    room.polygons.add([(X - 0.02, -3.0, 3.0), (X - 0.02, 1.0, 3.0), (X - 0.02, 1.0, 6.5), (X - 0.02, -3.0, 6.5)],
                      glass)
    room.polygons.add([(-3.0, Y - 0.02, 4.0), (-6.0, Y - 0.02, 4.0), (-6.0, Y - 0.02, 6.0), (-3.0, Y - 0.02, 6.0)],
                      frame_m)
    room.polygons.add([(-4.5, -3.5, 0.01), (4.5, -3.5, 0.01), (4.5, 3.5, 0.01), (-4.5, 3.5, 0.01)], rug)

    # the table and four chairs
    _box(furniture, (-2.0, -1.25, 2.35), (2.0, 1.25, 2.5), wood)
    for sx in (-1.0, 1.0):
        for sy in (-1.0, 1.0):
            lx, ly = sx * 1.75, sy * 1.0
            _box(furniture, (lx - 0.1, ly - 0.1, 0.0), (lx + 0.1, ly + 0.1, 2.35), wood, skip=("-z", "+z"))
    for cx_, cy_, facing in ((-1.0, -1.9, 1.0), (1.0, -1.9, 1.0), (-1.0, 1.9, -1.0), (1.0, 1.9, -1.0)):
        _box(furniture, (cx_ - 0.7, cy_ - 0.7, 1.45), (cx_ + 0.7, cy_ + 0.7, 1.6), fabric)
        for sx in (-1.0, 1.0):
            for sy in (-1.0, 1.0):
                lx, ly = cx_ + sx * 0.6, cy_ + sy * 0.6
                _box(furniture, (lx - 0.06, ly - 0.06, 0.0), (lx + 0.06, ly + 0.06, 1.45), wood, skip=("-z", "+z"))
        by = cy_ - facing * 0.7
        _box(furniture, (cx_ - 0.7, min(by, by - facing * 0.12), 1.6), (cx_ + 0.7, max(by, by - facing * 0.12), 3.4),
             wood)

    # the bookcase against the back wall, and the lamp
    case_x0, case_x1, case_y0, case_y1 = 1.5, 6.5, Y - 1.2, Y - 0.05
    shelves = 5
    _box(furniture, (case_x0, case_y0, 0.0), (case_x0 + 0.1, case_y1, 6.5), wood, skip=("-z",))
    _box(furniture, (case_x1 - 0.1, case_y0, 0.0), (case_x1, case_y1, 6.5), wood, skip=("-z",))
    for k in range(shelves + 1):
        z = k * 6.4 / shelves
        _box(furniture, (case_x0 + 0.1, case_y0, z), (case_x1 - 0.1, case_y1, z + 0.1), wood)
    furniture.cones.add((0.0, 0.0, 6.6), 1.0, (0.0, 0.0, 7.6), 0.5, shade)
    _cylinder(furniture, (0.0, 0.0, 7.6), (0.0, 0.0, Z), 0.03, frame_m)

    # floor boards, then books until the budget is spent
    fixed = len(room.polygons) + len(furniture.polygons) + len(furniture.cones)
    n_boards = int(max(4, min(2000, (target - fixed) * 0.25)))
    edges = np.linspace(-Y, Y, n_boards + 1)
    for k in range(n_boards):
        room.polygons.add([(-X, edges[k], 0), (X, edges[k], 0), (X, edges[k + 1], 0), (-X, edges[k + 1], 0)],
                          boards[k % 2])
    n_books = max(0, (target - fixed - n_boards) // 5)
    rng = np.random.default_rng(7)
    per_shelf = max(1, int(math.ceil(n_books / shelves)))
    width = (case_x1 - case_x0 - 0.2) / per_shelf
    placed = 0
    for k in range(shelves):
        z = k * 6.4 / shelves + 0.1
        for j in range(per_shelf):
            if placed == n_books:
                break
            x = case_x0 + 0.1 + j * width
            h = (6.4 / shelves - 0.1) * rng.uniform(0.6, 0.9)
            depth = rng.uniform(0.55, 0.95)
            _box(books, (x + 0.05 * width, case_y1 - depth, z), (x + 0.95 * width, case_y1 - 0.02, z + h),
                 book_colors[int(rng.integers(len(book_colors)))], skip=("-z",))
            placed += 1
    leftover = target - (fixed + n_boards + 5 * placed)
    for k in range(max(0, leftover)):       # picture frames along the left wall make up the count
        y = -Y + 0.5 + (2 * Y - 1.0) * (k + 0.1) / max(leftover, 1)
        w = 0.8 * (2 * Y - 1.0) / max(leftover, 1)
        room.polygons.add([(-X + 0.02, y, 4.5), (-X + 0.02, y + w, 4.5), (-X + 0.02, y + w, 5.5),
                           (-X + 0.02, y, 5.5)], frame_m)

    teapot = scene.root.add(Group(name="teapot"))
    _add_teapot(teapot, p["teapot_prims"], p["teapot_size"], porcelain, base=(0.0, 0.0, 2.5))
    scene.add_light((0.0, 0.0, 6.4), (1.0, 0.95, 0.85))
    scene.add_light((X - 1.0, -1.0, 5.5), (0.8, 0.85, 0.95))
    scene.camera = Camera(eye=(6.8, -5.2, 5.4), look_at=(0.0, 0.0, 2.6), up=(0, 0, 1), angle=55.0, hither=0.01)
    return scene


# ---- diamond ---------------------------------------------------------------------------------

def diamond(facets: int = 1000) -> Scene:
    """Glassner's case: many facets sharing one vertex, as a cut gem.

    facets  triangles of the pavilion, all sharing the culet (the gem's
            point), 3 to 1e6 (default 1000); the crown has as many
            four-sided facets and the table is one polygon of `facets` sides

    The gem is 2 units across at the girdle, its culet at the origin, standing
    on a checkerboard of 144 squares in the plane z = 0. Groups: diamond
    (pavilion, crown) and display.
    """
    p = _checked("diamond", dict(facets=facets))
    n = p["facets"]
    scene = Scene(background=(0.35, 0.4, 0.5))
    mat = scene.add_material
    stone = mat(Material((1.0, 1.0, 1.0), kd=0.1, ks=0.3, shine=200.0, t=0.7, ior=2.42))
    tiles = (mat(Material((0.85, 0.85, 0.8), kd=0.9)), mat(Material((0.15, 0.1, 0.3), kd=0.9)))

    gem = scene.root.add(Group(name="diamond"))
    pavilion = gem.add(Group(name="pavilion"))
    crown = gem.add(Group(name="crown"))
    display = scene.root.add(Group(name="display"))

    apex = np.zeros(3)
    girdle_z, crown_z, table_r = 0.86, 1.18, 0.56
    angles = 2.0 * np.pi * np.arange(n) / n
    girdle = np.stack([np.cos(angles), np.sin(angles), np.full(n, girdle_z)], axis=1)
    table = np.stack([table_r * np.cos(angles), table_r * np.sin(angles), np.full(n, crown_z)], axis=1)
    for i in range(n):
        j = (i + 1) % n
        pavilion.polygons.add(np.array([apex, girdle[j], girdle[i]]), stone)
    for i in range(n):
        j = (i + 1) % n
        crown.polygons.add(np.array([girdle[i], girdle[j], table[j], table[i]]), stone)
    crown.polygons.add(table, stone)
    for i in range(12):                 # a checkerboard under the gem, seen through it
        for j in range(12):
            x0, y0 = -6.0 + i, -6.0 + j
            display.polygons.add([(x0, y0, 0), (x0 + 1, y0, 0), (x0 + 1, y0 + 1, 0), (x0, y0 + 1, 0)],
                                 tiles[(i + j) % 2])

    scene.add_light((4.0, -6.0, 9.0))
    scene.add_light((-7.0, -2.0, 6.0), (0.9, 0.9, 1.0))
    scene.add_light((2.0, 5.0, 7.0), (1.0, 0.95, 0.9))
    scene.camera = _frame_camera((0.0, 0.0, 0.6), 1.25, (0.35, -1.0, 0.75), angle=40.0)
    return scene


_SCENES = {"stadium": stadium, "satellite": satellite, "sun": sun, "teapot-room": teapot_room,
           "diamond": diamond, "park": park}

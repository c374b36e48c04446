"""The scene model: what a scene *is*, independent of file formats and kernels.

    scene = Scene(camera=Camera(eye=(0, -5, 0), look_at=(0, 0, 0)))
    m = scene.add_material(Material(color=(1, 0, 0), kd=0.8))
    scene.root.spheres.add((0, 0, 0), 1.0, m)

Primitives are stored in bulk, one set per kind per group (arrays, not one
Python object per primitive), so a million-triangle mesh costs arrays, not
objects. A `Group` holds primitive sets, child groups and instances; its
`accel` names the acceleration structure built over it (None: the render's
default). An `Instance` places a group through a 4x4 affine matrix; the same
group may be instanced many times and is built only once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import SceneError
from ..geometry.limits import MAX_COORDINATE, MAX_NESTING  # noqa: F401  (MAX_NESTING: the deepest level a group may sit at)


def _vec3(value, what: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64).reshape(-1)
    if arr.shape != (3,):
        raise SceneError(f"{what} must have 3 numbers, got {arr.size}")
    if not np.all(np.isfinite(arr)):
        raise SceneError(f"{what} must be finite, got {arr.tolist()}")
    if np.any(np.abs(arr) > MAX_COORDINATE):
        raise SceneError(f"{what} {arr.tolist()} lies beyond +-{MAX_COORDINATE:g}, the range raykernel answers "
                         f"exactly; scale the scene")
    return arr


@dataclass
class Camera:
    """A pinhole camera as NFF defines it: `angle` is the full field of view in
    degrees between the centres of the outermost pixel columns; `up` need not
    be unit length nor perpendicular to the view direction."""

    eye: np.ndarray = field(default_factory=lambda: np.array([0.0, -10.0, 0.0]))
    look_at: np.ndarray = field(default_factory=lambda: np.zeros(3))
    up: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    angle: float = 45.0
    hither: float = 1e-3
    width: int = 512
    height: int = 512
    medium: int | None = None   # the material (index) of a transparent medium the eye is in; None: air

    def __post_init__(self):
        self.eye = _vec3(self.eye, "camera eye")
        self.look_at = _vec3(self.look_at, "camera look_at")
        self.up = _vec3(self.up, "camera up")
        if not (0.0 < float(self.angle) < 180.0):
            raise SceneError(f"camera angle must be in (0, 180) degrees, got {self.angle}")
        if np.linalg.norm(self.look_at - self.eye) == 0.0:
            raise SceneError("camera eye and look_at are the same point")
        if np.linalg.norm(np.cross(self.look_at - self.eye, self.up)) == 0.0:
            raise SceneError("camera up is parallel to the view direction")
        if int(self.width) < 1 or int(self.height) < 1:
            raise SceneError(f"camera resolution must be positive, got {self.width}x{self.height}")
        self.angle = float(self.angle)
        self.hither = float(self.hither)
        self.width = int(self.width)
        self.height = int(self.height)
        if self.medium is not None:
            if isinstance(self.medium, bool) or not isinstance(self.medium, (int, np.integer)) or self.medium < 0:
                raise SceneError(f"camera medium must be a material index, got {self.medium!r}")
            self.medium = int(self.medium)

    def basis(self):
        """(forward, right, up) unit vectors; right = forward x up (NFF's
        right-handed convention: +x to the right on screen when up is +z)."""
        forward = self.look_at - self.eye
        forward = forward / np.linalg.norm(forward)
        right = np.cross(forward, self.up)
        right = right / np.linalg.norm(right)
        up = np.cross(right, forward)
        return forward, right, up


@dataclass
class Light:
    """A point light; `color` None means white (NFF lights have no colour by default)."""

    position: np.ndarray
    color: np.ndarray | None = None

    def __post_init__(self):
        self.position = _vec3(self.position, "light position")
        if self.color is not None:
            self.color = _vec3(self.color, "light colour")


@dataclass(frozen=True)
class Material:
    """NFF's `f` line: colour, diffuse weight Kd, specular weight Ks (reflection
    and Phong highlight), Phong exponent `shine`, transmitted fraction T and
    index of refraction `ior`; beyond NFF, the luminance `kl` of Heckbert's
    minimal ray tracer: the surface glows with kl x colour, and a luminous
    sphere lights the scene from its centre with that colour."""

    color: tuple = (1.0, 1.0, 1.0)
    kd: float = 1.0
    ks: float = 0.0
    shine: float = 0.0
    t: float = 0.0
    ior: float = 1.0
    kl: float = 0.0

    def __post_init__(self):
        color = tuple(float(c) for c in self.color)
        if len(color) != 3:
            raise SceneError(f"material colour must have 3 numbers, got {len(color)}")
        object.__setattr__(self, "color", color)
        for name in ("kd", "ks", "shine", "t", "ior", "kl"):
            value = float(getattr(self, name))
            if not math.isfinite(value):
                raise SceneError(f"material {name} must be finite, got {value}")
            object.__setattr__(self, name, value)
        if self.kl < 0.0:
            raise SceneError(f"material kl (luminance) must be at least 0, got {self.kl}")


class _PrimitiveSet:
    """Base of the bulk primitive sets: arrays that grow by `add` or `extend`."""

    kind = ""

    def __len__(self) -> int:
        return len(self.material)


class Spheres(_PrimitiveSet):
    """Spheres; a negative radius means only the inside is visible (NFF)."""

    kind = "sphere"

    def __init__(self, center=None, radius=None, material=None):
        self.center = np.zeros((0, 3)) if center is None else np.asarray(center, np.float64).reshape(-1, 3)
        self.radius = np.zeros(0) if radius is None else np.asarray(radius, np.float64).reshape(-1)
        self.material = np.zeros(0, np.int32) if material is None else np.asarray(material, np.int32).reshape(-1)
        self._pending: list = []

    def add(self, center, radius: float, material: int = 0):
        self._pending.append((_vec3(center, "sphere centre"), float(radius), int(material)))
        return self

    def freeze(self):
        if self._pending:
            c, r, m = zip(*self._pending)
            self.center = np.vstack([self.center, np.array(c)])
            self.radius = np.concatenate([self.radius, np.array(r)])
            self.material = np.concatenate([self.material, np.array(m, np.int32)])
            self._pending = []
        return self

    def __len__(self):
        return len(self.material) + len(self._pending)


class Cones(_PrimitiveSet):
    """Open cones and cylinders without caps, from `base` (radius `base_radius`)
    to `apex` (radius `apex_radius`); negative radii: only the inside is visible."""

    kind = "cone"

    def __init__(self, base=None, base_radius=None, apex=None, apex_radius=None, material=None):
        self.base = np.zeros((0, 3)) if base is None else np.asarray(base, np.float64).reshape(-1, 3)
        self.base_radius = np.zeros(0) if base_radius is None else np.asarray(base_radius, np.float64).reshape(-1)
        self.apex = np.zeros((0, 3)) if apex is None else np.asarray(apex, np.float64).reshape(-1, 3)
        self.apex_radius = np.zeros(0) if apex_radius is None else np.asarray(apex_radius, np.float64).reshape(-1)
        self.material = np.zeros(0, np.int32) if material is None else np.asarray(material, np.int32).reshape(-1)
        self._pending: list = []

    def add(self, base, base_radius: float, apex, apex_radius: float, material: int = 0):
        self._pending.append((_vec3(base, "cone base"), float(base_radius), _vec3(apex, "cone apex"),
                              float(apex_radius), int(material)))
        return self

    def freeze(self):
        if self._pending:
            b, br, a, ar, m = zip(*self._pending)
            self.base = np.vstack([self.base, np.array(b)])
            self.base_radius = np.concatenate([self.base_radius, np.array(br)])
            self.apex = np.vstack([self.apex, np.array(a)])
            self.apex_radius = np.concatenate([self.apex_radius, np.array(ar)])
            self.material = np.concatenate([self.material, np.array(m, np.int32)])
            self._pending = []
        return self

    def __len__(self):
        return len(self.material) + len(self._pending)


class Polygons(_PrimitiveSet):
    """Planar polygons of any vertex count (concave allowed), stored as one
    vertex array and per-polygon `start`/`count`. With `normals` (one per
    vertex) they are NFF polygonal patches, shaded smoothly."""

    def __init__(self, patches: bool = False):
        self.patches = patches
        self.kind = "patch" if patches else "polygon"
        self.vertices = np.zeros((0, 3))
        self.normals = np.zeros((0, 3)) if patches else None
        self.start = np.zeros(0, np.int64)
        self.count = np.zeros(0, np.int64)
        self.material = np.zeros(0, np.int32)
        self._pending: list = []

    def add(self, vertices, material: int = 0, normals=None):
        v = np.asarray(vertices, np.float64)
        if v.ndim != 2 or v.shape[1] != 3 or len(v) < 3:
            raise SceneError(f"a {self.kind} needs at least 3 vertices of 3 numbers, got shape {v.shape}")
        n = None
        if self.patches:
            if normals is None:
                raise SceneError("a patch needs one normal per vertex")
            n = np.asarray(normals, np.float64)
            if n.shape != v.shape:
                raise SceneError(f"a patch needs one normal per vertex: {len(v)} vertices, {len(n)} normals")
        elif normals is not None:
            raise SceneError("plain polygons take no vertex normals; use a patch set")
        self._pending.append((v, n, int(material)))
        return self

    def freeze(self):
        if self._pending:
            verts = [p[0] for p in self._pending]
            counts = np.array([len(v) for v in verts], np.int64)
            base = len(self.vertices)
            starts = base + np.concatenate([[0], np.cumsum(counts)[:-1]])
            self.vertices = np.vstack([self.vertices] + verts)
            if self.patches:
                self.normals = np.vstack([self.normals] + [p[1] for p in self._pending])
            self.start = np.concatenate([self.start, starts])
            self.count = np.concatenate([self.count, counts])
            self.material = np.concatenate([self.material, np.array([p[2] for p in self._pending], np.int32)])
            self._pending = []
        return self

    def polygon(self, i: int):
        """Vertices (and normals for patches) of polygon i."""
        self.freeze()
        s, c = self.start[i], self.count[i]
        return self.vertices[s:s + c], (self.normals[s:s + c] if self.patches else None)

    def __len__(self):
        return len(self.material) + len(self._pending)


class TriangleMesh(_PrimitiveSet):
    """An indexed triangle mesh; optional per-vertex `normals` give smooth shading."""

    kind = "triangle"

    def __init__(self, vertices, faces, material=0, normals=None):
        self.vertices = np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 3)
        self.faces = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
        if not np.all(np.isfinite(self.vertices)):
            raise SceneError("mesh vertices must be finite")
        if len(self.faces) and (self.faces.min() < 0 or self.faces.max() >= len(self.vertices)):
            raise SceneError(f"mesh face indices must lie in [0, {len(self.vertices)})")
        mat = np.asarray(material, np.int32).reshape(-1)
        # one material for all: a read-only view of it, not a copy a face
        self.material = np.broadcast_to(mat[:1], len(self.faces)) if mat.size == 1 else mat
        if len(self.material) != len(self.faces):
            raise SceneError("mesh needs one material per face or a single material")
        self.normals = None if normals is None else np.asarray(normals, np.float64).reshape(-1, 3)
        if self.normals is not None and len(self.normals) != len(self.vertices):
            raise SceneError("mesh normals must be one per vertex")

    def freeze(self):
        return self


@dataclass
class Group:
    """A node of the scene graph. Its primitives and children are gathered
    into one aggregate, built with `accel` (a spec such as "bvh"; None
    inherits the render's default)."""

    name: str = ""
    accel: str | None = None
    spheres: Spheres = field(default_factory=Spheres)
    cones: Cones = field(default_factory=Cones)
    polygons: Polygons = field(default_factory=Polygons)
    patches: Polygons = field(default_factory=lambda: Polygons(patches=True))
    meshes: list = field(default_factory=list)
    children: list = field(default_factory=list)  # Group or Instance

    def add(self, item):
        """Add a TriangleMesh, a child Group or an Instance."""
        if isinstance(item, TriangleMesh):
            self.meshes.append(item)
        elif isinstance(item, (Group, Instance)):
            self.children.append(item)
        else:
            raise SceneError(f"a group holds meshes, groups and instances, not {type(item).__name__}")
        return item

    def primitive_sets(self):
        for s in (self.spheres, self.cones, self.polygons, self.patches, *self.meshes):
            s.freeze()
            if len(s):
                yield s

    def count_primitives(self) -> int:
        """Primitives reachable from this group, instances counted each time."""
        n = sum(len(s) for s in self.primitive_sets())
        return n + sum(child.count_primitives() for child in self.children)


@dataclass
class Instance:
    """`group` placed by the affine 4x4 `matrix` (local to world)."""

    group: Group
    matrix: np.ndarray = field(default_factory=lambda: np.eye(4))

    def __post_init__(self):
        m = np.asarray(self.matrix, np.float64)
        if m.shape != (4, 4):
            raise SceneError(f"an instance matrix must be 4x4, got shape {m.shape}")
        if not np.all(np.isfinite(m)):
            raise SceneError("an instance matrix must be finite")
        if not np.allclose(m[3], [0, 0, 0, 1]):
            raise SceneError("an instance matrix must be affine (last row 0 0 0 1)")
        if abs(np.linalg.det(m[:3, :3])) < 1e-300:
            raise SceneError("an instance matrix must be invertible")
        self.matrix = m

    def count_primitives(self) -> int:
        return self.group.count_primitives()


@dataclass
class Scene:
    """A whole scene: camera, background, lights, materials and the root group of the geometry.

    Attributes
    ----------
    camera : Camera
        The pinhole camera (NFF's view).
    background : (3,) float64 array
        The background colour.
    lights : list of Light
        The point lights.
    materials : list of Material
        The materials; primitives refer to them by index.
    root : Group
        The root of the scene graph: primitive sets, child groups and instances.
    source : str
        Where the scene came from (a path, ``spd:NAME:SIZE``, ...), for reports.
    parse_seconds : float
        Seconds spent reading it from its file or generator (``load``); 0 when built in Python.
    compile_seconds : float
        Of that reading, the seconds spent compiling its kernels (left out of `parse_seconds`).
    load_seconds : float
        And the seconds spent loading them from the cache (start-up, left out of
        `parse_seconds`).
    animation : object
        An ``animation.Animation``: what moves over time (JSON ``animation`` and ``motion``);
        None for a still scene.

    Examples
    --------
    >>> scene = Scene(camera=Camera(eye=(0, -5, 0), look_at=(0, 0, 0)))
    >>> m = scene.add_material(Material(color=(1, 0, 0), kd=0.8))
    >>> scene.root.spheres.add((0, 0, 0), 1.0, m)
    """

    camera: Camera = field(default_factory=Camera)
    background: np.ndarray = field(default_factory=lambda: np.zeros(3))
    lights: list = field(default_factory=list)
    materials: list = field(default_factory=list)
    root: Group = field(default_factory=lambda: Group(name="root"))
    source: str = ""
    parse_seconds: float = 0.0  # reading it from its file or generator (loading.load); 0 when built in Python
    compile_seconds: float = 0.0    # of that reading, compiling its kernels (left out of parse_seconds)
    load_seconds: float = 0.0   # and loading them from the cache (start-up, left out of parse_seconds)
    animation: object = None    # an animation.Animation: what moves over time (JSON "animation" and "motion")

    def __post_init__(self):
        self.background = _vec3(self.background, "background colour")

    def add_material(self, material: Material) -> int:
        """Add a material and return its index (identical materials are shared).

        Parameters
        ----------
        material : Material
            The material to add.

        Returns
        -------
        int
            The index primitives use to refer to it: that of an identical material already in
            the scene, else the new one's.
        """
        try:
            return self.materials.index(material)
        except ValueError:
            self.materials.append(material)
            return len(self.materials) - 1

    def add_light(self, position, color=None) -> Light:
        """Add a point light.

        Parameters
        ----------
        position : (3,) array_like
            Where the light is.
        color : (3,) array_like, optional
            Its colour; None means white (NFF lights have no colour by default).

        Returns
        -------
        Light
            The light added.

        Raises
        ------
        SceneError
            The position or colour is not 3 finite numbers within the range raykernel answers
            exactly.
        """
        light = Light(position, color)
        self.lights.append(light)
        return light

    def count_primitives(self) -> int:
        """The number of primitives reachable from the root, those of instances counted each time.

        Returns
        -------
        int
        """
        return self.root.count_primitives()

    def __repr__(self):
        return (f"Scene({self.source or 'unnamed'}: {self.count_primitives()} primitives, "
                f"{len(self.lights)} lights, {len(self.materials)} materials)")

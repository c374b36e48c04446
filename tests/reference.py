"""A brute-force reference ray caster, written to be read rather than to be fast.

    prims = world_primitives(scene)                   # every primitive in world space
    t, kind, index, instance = cast(prims, origins, directions, tmin, tmax)

One small function per primitive kind answers "where does each ray of a
batch first meet this primitive within [tmin, tmax]?" as an array of ray
parameters (inf where it misses). `cast` asks every primitive and keeps the
nearest answer; there is no acceleration structure at all.

The formulas deliberately differ from the kernels' (chord halves around the
closest approach for spheres, the cone's own coordinate frame, Newell normals
and winding numbers for polygons, edge functions for triangles), and every
computation is done in extended precision (np.longdouble) on vectors taken
relative to a point of the primitive, so that the reference is at least as
accurate as the code it checks.

Identities follow the kernels: a primitive is (kind, index, instance), where
index counts within the kind's arrays in the order `flatten` builds them
(polygons and patches share one index range) and instance is the innermost
instance id, or -1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from raykernel.geometry.primitives import CONE, KIND_SHIFT, PATCH, POLYGON, SPHERE, TRIANGLE
from raykernel.scene import Group, Instance, Polygons, Scene, TriangleMesh

REAL = np.longdouble
INF = np.inf


# ----------------------------------------------------------------- small vector helpers

def _rays(origins, directions, tmin, tmax):
    """Rays as extended-precision arrays: origins (N, 3), directions (N, 3), tmin (N,), tmax (N,)."""
    o = np.asarray(origins, REAL).reshape(-1, 3)
    d = np.asarray(directions, REAL).reshape(-1, 3)
    n = len(o)
    lo = np.broadcast_to(np.asarray(tmin, REAL), (n,))
    hi = np.broadcast_to(np.asarray(tmax, REAL), (n,))
    return o, d, lo, hi


def dot(a, b):
    return (a * b).sum(axis=-1)


def cross(a, b):
    return np.cross(a, b)


def unit(v):
    """v scaled to length 1 (each row, for an array of vectors)."""
    return v / np.sqrt(dot(v, v))[..., None]


def first_in_interval(candidates, tmin, tmax):
    """The smallest candidate ray parameter inside [tmin, tmax], per ray; inf when there is none.
    NaN candidates (roots that do not exist) never count."""
    best = np.full(len(tmin), INF, REAL)
    for t in candidates:
        inside = (t >= tmin) & (t <= tmax) & (t < best)
        best = np.where(inside, t, best)
    return best


def quadratic_roots(a, b, c):
    """Real roots of a t^2 + b t + c = 0, per ray, as two arrays (NaN where a root does
    not exist). Uses q = -(b + sign(b) sqrt(b^2 - 4ac)) / 2, roots q/a and c/q, which
    loses no digits to cancellation; a = 0 leaves the single root -c/b."""
    with np.errstate(all="ignore"):
        disc = b * b - 4 * a * c
        root = np.sqrt(np.where(disc >= 0, disc, np.nan))
        q = -0.5 * (b + np.where(b >= 0, root, -root))
        r1 = np.where(a != 0, q / a, np.where(b != 0, -c / b, np.nan))
        r2 = np.where(a != 0, c / q, np.nan)
    return r1, r2


# ----------------------------------------------------------------- one function per primitive kind

def hit_sphere(center, radius, origins, directions, tmin=0.0, tmax=INF):
    """Where each ray meets the sphere. Along the ray, the point of closest
    approach to the centre splits the chord into two halves of equal length;
    the ray enters one half before it and leaves one half after. A negative
    radius shows only the inside: the ray counts only where it leaves the ball."""
    o, d, tmin, tmax = _rays(origins, directions, tmin, tmax)
    r = REAL(radius)
    to_center = np.asarray(center, REAL) - o
    dd = dot(d, d)
    t_closest = dot(to_center, d) / dd
    miss = to_center - t_closest[:, None] * d          # from the closest point to the centre
    half_sq = (r * r - dot(miss, miss)) / dd
    with np.errstate(invalid="ignore"):
        half = np.sqrt(np.where(half_sq >= 0, half_sq, np.nan))
    enter, leave = t_closest - half, t_closest + half
    if r > 0:
        return first_in_interval([enter, leave], tmin, tmax)
    return first_in_interval([leave], tmin, tmax)


def cone_frame(base, apex):
    """Rows: two unit vectors across the axis and the unit axis from base to apex; and the height."""
    axis = np.asarray(apex, REAL) - np.asarray(base, REAL)
    height = np.sqrt(dot(axis, axis))
    w = axis / height
    helper = np.zeros(3, REAL)
    helper[np.argmin(np.abs(w))] = 1
    u = unit(cross(w, helper))
    v = cross(w, u)
    return np.stack([u, v, w]), height


def hit_cone(base, base_radius, apex, apex_radius, origins, directions, tmin=0.0, tmax=INF):
    """Where each ray meets the open cone (no caps). In the cone's own frame,
    with z along the axis from the base (z = 0) to the apex (z = height), the
    surface is x^2 + y^2 = r(z)^2 with r(z) = r0 + (r1 - r0) z / height for
    0 <= z <= height. Negative radii show only the inside: a hit counts only
    where the ray crosses from inside (x^2 + y^2 < r(z)^2) to outside."""
    o, d, tmin, tmax = _rays(origins, directions, tmin, tmax)
    frame, height = cone_frame(base, apex)
    inside_only = base_radius < 0 or apex_radius < 0
    r0, r1 = abs(REAL(base_radius)), abs(REAL(apex_radius))
    k = (r1 - r0) / height
    base = np.asarray(base, REAL)
    # solve from the ray's closest approach to the cone's middle, where the quadratic is well
    # conditioned even for a small cone far from the ray origin; t = t_mid + (root)
    t_mid = dot(base + 0.5 * height * frame[2] - o, d) / dot(d, d)
    p = ((o - base) + t_mid[:, None] * d) @ frame.T     # that point in the cone's frame
    q = d @ frame.T                                      # direction in the cone's frame
    rp = r0 + k * p[:, 2]                                # radius at the origin's height ...
    rq = k * q[:, 2]                                     # ... and how it changes along the ray
    a = q[:, 0] ** 2 + q[:, 1] ** 2 - rq * rq
    b = 2 * (p[:, 0] * q[:, 0] + p[:, 1] * q[:, 1] - rp * rq)
    c = p[:, 0] ** 2 + p[:, 1] ** 2 - rp * rp
    candidates = []
    for s in quadratic_roots(a, b, c):
        t = t_mid + s
        x, y, z = (p[:, i] + s * q[:, i] for i in range(3))
        keep = (z >= 0) & (z <= height)
        if inside_only:
            # d/dt of x^2 + y^2 - r(z)^2 along the ray: positive where the ray leaves the inside
            keep &= x * q[:, 0] + y * q[:, 1] - (r0 + k * z) * rq >= 0
        candidates.append(np.where(keep, t, np.nan))
    return first_in_interval(candidates, tmin, tmax)


def newell_normal(vertices):
    """The (unnormalised) area vector of a planar polygon, convex or not
    (taken about the first vertex, so that far-away polygons keep their digits)."""
    v = np.asarray(vertices, REAL)
    v = v - v[0]
    return 0.5 * cross(v, np.roll(v, -1, axis=0)).sum(axis=0)


def winding_number(polygon, points):
    """Winding number of the closed 2D polyline `polygon` (M, 2) around each of `points` (N, 2):
    +1 for each counter-clockwise turn, -1 for each clockwise turn."""
    px, py = points[:, 0], points[:, 1]
    wn = np.zeros(len(points), np.int64)
    for a, b in zip(polygon, np.roll(polygon, -1, axis=0)):
        left = (b[0] - a[0]) * (py - a[1]) - (px - a[0]) * (b[1] - a[1])   # > 0: point left of a -> b
        upward = (a[1] <= py) & (b[1] > py)
        downward = (a[1] > py) & (b[1] <= py)
        wn += (upward & (left > 0)).astype(np.int64)
        wn -= (downward & (left < 0)).astype(np.int64)
    return wn


def plane_coordinates(vertices):
    """An orthonormal basis (e1, e2) of the polygon's plane and its unit normal."""
    v = np.asarray(vertices, REAL)
    n = unit(newell_normal(v))
    helper = np.zeros(3, REAL)
    helper[np.argmin(np.abs(n))] = 1
    e1 = unit(cross(n, helper))
    return e1, cross(n, e1), n


def inside_polygon(vertices, points, relative=False):
    """Whether each 3D point (lying in the polygon's plane) is inside the simple polygon;
    with `relative` the points are given relative to the first vertex."""
    v = np.asarray(vertices, REAL)
    e1, e2, _ = plane_coordinates(v)
    rel_v = v - v[0]
    rel_p = np.asarray(points, REAL) if relative else np.asarray(points, REAL) - v[0]
    poly2d = np.stack([dot(rel_v, e1), dot(rel_v, e2)], axis=1)
    pts2d = np.stack([dot(rel_p, e1), dot(rel_p, e2)], axis=1)
    return winding_number(poly2d, pts2d) != 0


def hit_polygon(vertices, origins, directions, tmin=0.0, tmax=INF):
    """Where each ray meets a planar, simple polygon (any vertex count,
    concave allowed): the plane of its Newell normal, then the winding number
    of the hit point."""
    o, d, tmin, tmax = _rays(origins, directions, tmin, tmax)
    v = np.asarray(vertices, REAL)
    n = newell_normal(v)
    with np.errstate(all="ignore"):
        t = dot(v[0] - o, n) / dot(d, n)
        t = np.where(np.isfinite(t), t, np.nan)          # rays parallel to the plane miss
    rel = (o - v[0]) + np.where(np.isfinite(t), t, 0)[:, None] * d      # hit point relative to v[0]
    t = np.where(inside_polygon(v, rel, relative=True), t, np.nan)
    return first_in_interval([t], tmin, tmax)


def hit_triangle(v0, v1, v2, origins, directions, tmin=0.0, tmax=INF):
    """Where each ray meets the triangle: its plane, then the hit point must lie
    on the inner side of all three edges (edge functions), boundary included."""
    o, d, tmin, tmax = _rays(origins, directions, tmin, tmax)
    v0, v1, v2 = (np.asarray(v, REAL) for v in (v0, v1, v2))
    n = cross(v1 - v0, v2 - v0)
    with np.errstate(all="ignore"):
        t = dot(v0 - o, n) / dot(d, n)
        t = np.where(np.isfinite(t), t, np.nan)
    rel = (o - v0) + np.where(np.isfinite(t), t, 0)[:, None] * d    # hit point relative to v0
    inside = np.ones(len(o), bool)
    for a, b in ((v0, v1), (v1, v2), (v2, v0)):
        inside &= dot(cross(b - a, rel - (a - v0)), n) >= 0
    return first_in_interval([np.where(inside, t, np.nan)], tmin, tmax)


# ----------------------------------------------------------------- primitives in world space

@dataclass
class Primitive:
    """One primitive placed in world space, with the identity the kernels report."""

    kind: int            # SPHERE, POLYGON, PATCH, CONE or TRIANGLE
    index: int           # index within the kind's arrays, in flatten order
    instance: int        # innermost instance id, -1 outside instances
    shape: tuple         # world-space geometry: the leading arguments of the kind's hit function
    normals: object = None   # vertex normals of a patch (world space)

    @property
    def ref(self) -> int:
        return (self.kind << KIND_SHIFT) | self.index

    def hit(self, origins, directions, tmin=0.0, tmax=INF):
        return HIT[self.kind](*self.shape, origins, directions, tmin, tmax)

    def size(self) -> float:
        """Largest extent of the primitive's bounding box."""
        pts = self.points()
        return float(np.max(pts.max(axis=0) - pts.min(axis=0)))

    def points(self) -> np.ndarray:
        """Points whose bounding box is the primitive's bounding box (spheres and cones padded)."""
        if self.kind == SPHERE:
            c, r = np.asarray(self.shape[0], float), abs(self.shape[1])
            return np.array([c - r, c + r])
        if self.kind == CONE:
            b, r0, a, r1 = self.shape
            r = max(abs(r0), abs(r1))
            return np.array([np.asarray(b) - r, np.asarray(b) + r, np.asarray(a) - r, np.asarray(a) + r])
        if self.kind == TRIANGLE:
            return np.array(self.shape, float)
        return np.asarray(self.shape[0], float)


HIT = {SPHERE: hit_sphere, CONE: hit_cone, POLYGON: hit_polygon, PATCH: hit_polygon, TRIANGLE: hit_triangle}


def _similarity_scale(linear: np.ndarray) -> float:
    """s where linear = s * (an orthogonal matrix); ValueError for any other map."""
    s = abs(np.linalg.det(linear)) ** (1.0 / 3.0)
    if not np.allclose(linear @ linear.T, s * s * np.eye(3), rtol=0, atol=1e-12 * s * s):
        raise ValueError("spheres and cones can only be placed by similarity maps (rotation, uniform "
                         "scale, translation); transform the rays instead")
    return s


def _place(kind, shape, normals, matrix):
    """Map a primitive's geometry by the 4x4 affine `matrix` (None: identity)."""
    if matrix is None:
        return shape, normals
    linear, shift = matrix[:3, :3], matrix[:3, 3]

    def point(p):
        return linear @ np.asarray(p, float) + shift

    if kind == SPHERE:
        center, radius = shape
        return (point(center), radius * _similarity_scale(linear)), None
    if kind == CONE:
        base, r0, apex, r1 = shape
        s = _similarity_scale(linear)
        return (point(base), r0 * s, point(apex), r1 * s), None
    if kind == TRIANGLE:
        return tuple(point(p) for p in shape), None
    vertices = np.asarray(shape[0], float) @ linear.T + shift
    if normals is not None:
        normals = normals @ np.linalg.inv(linear)          # normals map by the inverse transpose
    return (vertices,), normals


@dataclass
class _Placement:
    """A child aggregate, placed through an instance (matrix and id) or not (None, None)."""

    matrix: object
    instance: object
    items: list


class _Walker:
    """Visits a scene graph in the order flatten builds it, numbering primitives and instances.

    A group's own primitive sets come first (spheres, cones, polygons, patches,
    meshes), then its children in order: a child group without an accel spec
    is merged in place, a child group with a spec or an instanced group is
    numbered once, the first time it is met. An instance gets its id after
    the group it shows has been numbered."""

    def __init__(self):
        self.next_index = {SPHERE: 0, CONE: 0, POLYGON: 0, TRIANGLE: 0}
        self.next_instance = 0
        self.aggregates = {}

    def _number(self, kind, count):
        key = POLYGON if kind == PATCH else kind
        first = self.next_index[key]
        self.next_index[key] += count
        return range(first, first + count)

    def aggregate(self, group: Group) -> list:
        if id(group) not in self.aggregates:
            self.aggregates[id(group)] = self.collect(group)
        return self.aggregates[id(group)]

    def collect(self, group: Group) -> list:
        items = []
        for s in group.primitive_sets():
            if s.kind == "sphere":
                for i, k in enumerate(self._number(SPHERE, len(s))):
                    items.append((SPHERE, k, (s.center[i].copy(), float(s.radius[i])), None))
            elif s.kind == "cone":
                for i, k in enumerate(self._number(CONE, len(s))):
                    items.append((CONE, k, (s.base[i].copy(), float(s.base_radius[i]), s.apex[i].copy(),
                                            float(s.apex_radius[i])), None))
            elif isinstance(s, Polygons):
                kind = PATCH if s.patches else POLYGON
                for i, k in enumerate(self._number(kind, len(s))):
                    verts, normals = s.polygon(i)
                    items.append((kind, k, (verts.copy(),), None if normals is None else normals.copy()))
            elif isinstance(s, TriangleMesh):
                for f, k in zip(s.faces, self._number(TRIANGLE, len(s.faces))):
                    items.append((TRIANGLE, k, tuple(s.vertices[j].copy() for j in f), None))
        for child in group.children:
            if isinstance(child, Instance):
                inner = self.aggregate(child.group)
                items.append(_Placement(child.matrix, self.next_instance, inner))
                self.next_instance += 1
            elif child.accel is None:
                items.extend(self.collect(child))
            else:
                items.append(_Placement(None, None, self.aggregate(child)))
        return items


def _expand(items, matrix, instance, out):
    for item in items:
        if isinstance(item, _Placement):
            if item.matrix is None:
                _expand(item.items, matrix, instance, out)
            else:
                m = item.matrix if matrix is None else matrix @ item.matrix
                _expand(item.items, m, item.instance, out)
        else:
            kind, index, shape, normals = item
            shape, normals = _place(kind, shape, normals, matrix)
            out.append(Primitive(kind, index, instance, shape, normals))


def world_primitives(scene_or_group) -> list[Primitive]:
    """Every primitive reachable from the scene's root, placed in world space
    (instances multiplied out), with the identity the kernels report."""
    root = scene_or_group.root if isinstance(scene_or_group, Scene) else scene_or_group
    out: list[Primitive] = []
    _expand(_Walker().aggregate(root), None, -1, out)
    return out


def flattened_scene(prims: list[Primitive], accel: str = "list"):
    """A scene with every primitive of `prims` directly in its root group (no
    instances, no nested groups), and `identity`: identity[(kind, index in the
    new scene)] = (kind, index, instance) of the original primitive."""
    scene = Scene()
    scene.root.accel = accel
    identity = {}
    by_kind = {k: [p for p in prims if p.kind == k] for k in (SPHERE, CONE, POLYGON, PATCH, TRIANGLE)}
    for i, p in enumerate(by_kind[SPHERE]):
        scene.root.spheres.add(p.shape[0], p.shape[1])
        identity[(SPHERE, i)] = (p.kind, p.index, p.instance)
    for i, p in enumerate(by_kind[CONE]):
        scene.root.cones.add(*p.shape)
        identity[(CONE, i)] = (p.kind, p.index, p.instance)
    for i, p in enumerate(by_kind[POLYGON]):
        scene.root.polygons.add(p.shape[0])
        identity[(POLYGON, i)] = (p.kind, p.index, p.instance)
    offset = len(by_kind[POLYGON])
    for i, p in enumerate(by_kind[PATCH]):
        scene.root.patches.add(p.shape[0], normals=p.normals)
        identity[(PATCH, offset + i)] = (p.kind, p.index, p.instance)
    tris = by_kind[TRIANGLE]
    if tris:
        verts = np.array([v for p in tris for v in p.shape], float)
        scene.root.add(TriangleMesh(verts, np.arange(len(verts)).reshape(-1, 3)))
        for i, p in enumerate(tris):
            identity[(TRIANGLE, i)] = (p.kind, p.index, p.instance)
    return scene, identity


# ----------------------------------------------------------------- the caster

def all_hits(prims, origins, directions, tmin=0.0, tmax=INF) -> np.ndarray:
    """(n_prims, n_rays) extended-precision t of every ray with every primitive (inf: miss)."""
    o, d, lo, hi = _rays(origins, directions, tmin, tmax)
    if not prims:
        return np.full((0, len(o)), INF, REAL)
    return np.stack([p.hit(o, d, lo, hi) for p in prims])


def _id_table(prims):
    """Per primitive position: kind, index, instance and tagged reference, with one extra
    entry of -1s at the end so that position -1 (a miss) looks up "no primitive"."""
    table = np.array([[p.kind, p.index, p.instance, p.ref] for p in prims] + [[-1, -1, -1, -1]], np.int64)
    return table.reshape(-1, 4)


def closest(prims, hits):
    """From all_hits: the position in `prims` of each ray's closest hit (-1: miss).
    Ties at equal t go to the smaller tagged reference, then the smaller instance id."""
    table = _id_table(prims)
    n = hits.shape[1]
    best = np.full(n, -1, np.int64)
    best_t = np.full(n, INF, REAL)
    for i, p in enumerate(prims):
        t = hits[i]
        prev_ref, prev_inst = table[best, 3], table[best, 2]
        smaller = (p.ref < prev_ref) | ((p.ref == prev_ref) & (p.instance < prev_inst))
        better = (t < best_t) | ((t == best_t) & (t < INF) & smaller)
        best = np.where(better, i, best)
        best_t = np.where(better, t, best_t)
    return best


def identities(prims, which):
    """(kind, index, instance) arrays for positions in `prims` (-1 everywhere for a miss)."""
    table = _id_table(prims)
    return table[which, 0], table[which, 1], table[which, 2]


def _closest_t(hits, which):
    t = np.full(len(which), INF, REAL)
    found = which >= 0
    t[found] = hits[which[found], np.flatnonzero(found)]
    return t


def cast(prims, origins, directions, tmin=0.0, tmax=INF):
    """Closest hit of each ray: (t, kind, index, instance), t float64 (inf on a miss)
    and identities -1 on a miss, like raykernel.engine.traverse.cast_rays."""
    hits = all_hits(prims, origins, directions, tmin, tmax)
    which = closest(prims, hits)
    return (_closest_t(hits, which).astype(np.float64), *identities(prims, which))


def unstable(prims, origins, directions, delta, tmin=0.0, tmax=INF, slack=100.0):
    """Rays whose answer is sensitive to tiny changes: those within about
    `delta` (scalar or per ray, absolute) of a silhouette, an edge, a rim or
    an apex, whose hit lies within about delta of tmin or tmax, that meet a
    surface at a grazing angle, or whose closest hit is nearly tied with
    another primitive's, or that lie within delta of the plane of a polygon or
    triangle or cross that plane within delta of an edge (sharp corners can
    hide from the moves below). A ray is unstable when moving its origin by +-delta along any
    axis changes the primitive it hits, or moves the hit by more than `slack`
    * delta along the ray. Exact answers may legitimately differ on these
    rays; they get sanity checks only."""
    with np.errstate(invalid="ignore"):
        return _unstable(prims, origins, directions, delta, tmin, tmax, slack)


def _unstable(prims, origins, directions, delta, tmin, tmax, slack):
    o, d, lo, hi = _rays(origins, directions, tmin, tmax)
    n = len(o)
    delta = np.broadcast_to(np.asarray(delta, REAL), (n,))
    table = _id_table(prims)
    hits = all_hits(prims, o, d, lo, hi)
    which = closest(prims, hits)
    t = _closest_t(hits, which)
    reach = slack * delta / np.sqrt(dot(d, d))          # how far t may move for a stable ray
    flag = np.zeros(n, bool)
    # a nearly tied second primitive (the same primitive met twice at the same t is no tie)
    best_id = table[which, :3]
    for i, p in enumerate(prims):
        other = hits[i]
        same_id = np.all(best_id == table[i, :3], axis=1)
        same = (which == i) | ((other == t) & same_id)
        flag |= (np.abs(other - t) <= reach) & ~same & np.isfinite(other) & np.isfinite(t)
    for p in prims:
        if p.kind in (POLYGON, PATCH, TRIANGLE):
            flag |= _in_plane(p, o, d, delta) | _near_edge(p, o, d, delta)
    for axis in range(3):
        for sign in (-1, 1):
            moved = o.copy()
            moved[:, axis] += sign * delta
            h = all_hits(prims, moved, d, lo, hi)
            w = closest(prims, h)
            tm = _closest_t(h, w)
            flag |= np.any(table[w, :3] != best_id, axis=1)
            flag |= np.isfinite(tm) & np.isfinite(t) & (np.abs(tm - t) > reach)
    return flag


def _in_plane(prim, o, d, delta):
    """Rays within delta of the primitive's plane both at their origin and where they
    pass closest to its first vertex."""
    v = np.asarray(prim.shape if prim.kind == TRIANGLE else prim.shape[0], REAL)
    n = unit(newell_normal(v))
    to_v0 = v[0] - o
    at_origin = dot(o - v[0], n)
    t_close = dot(to_v0, d) / dot(d, d)
    at_closest = at_origin + t_close * dot(d, n)
    return (np.abs(at_origin) <= delta) & (np.abs(at_closest) <= delta)


def _near_edge(prim, o, d, delta):
    """Rays that cross the primitive's plane within delta of one of its edges."""
    v = np.asarray(prim.shape if prim.kind == TRIANGLE else prim.shape[0], REAL)
    n = newell_normal(v)
    with np.errstate(all="ignore"):
        t = dot(v[0] - o, n) / dot(d, n)
    t = np.where(np.isfinite(t), t, 0)
    rel = (o - v[0]) + t[:, None] * d                     # crossing point relative to v[0]
    near = np.zeros(len(o), bool)
    corners = v - v[0]
    for a, b in zip(corners, np.roll(corners, -1, axis=0)):
        ab = b - a
        s = np.clip(dot(rel - a, ab) / dot(ab, ab), 0, 1)
        gap = rel - (a + s[:, None] * ab)
        near |= dot(gap, gap) <= delta * delta
    return near

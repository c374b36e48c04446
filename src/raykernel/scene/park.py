"""Arvo's amusement park (RTN 2(1), "Subspaces and Simulated Annealing"): a scene with three
natural levels of detail, and the hand-made hierarchy of subspaces he describes for it.

    scene = raykernel.load("scene:park")                       # the defaults below
    scene = raykernel.load("scene:park:rides=3,top=1")         # fewer rides, ray classification on top

The park: a ground, a fractal mountain (midpoint displacement, 2 x 4^mountain_level
triangles), `trees` trees and a fence, and `rides` triple-decker merry-go-rounds on a ring.
A ride: three decks (platform, canopy and a ring of lamps each), a centre column, a roof and
on each deck `horses` poles with a horse and a rider. The detail: one horse with its rider
(body, head, neck, legs, tail, and the rider's body, head and arms), one group instanced on
every pole; a tree is one group instanced with its place and size. The camera stands close
to the first ride, whose chrome poles and mirror column reflect the rest of the park.

Its groups carry Arvo's hand-made hierarchy: a coarse grid over the park (`top` 0) or ray
classification (`top` 1, his later variant), a grid of about `ride_grid` cells along its
longest side over each ride, an octree over the mountain and bounding-box hierarchies
around the small clusters (a horse and rider, a tree). All lengths in feet, z up.
"""

from __future__ import annotations

import math

import numpy as np

from .model import Camera, Group, Instance, Scene, TriangleMesh


def _disc(group: Group, centre, radius: float, z: float, sides: int, material: int):
    a = np.linspace(0, 2 * math.pi, sides, endpoint=False)
    pts = np.stack([centre[0] + radius * np.cos(a), centre[1] + radius * np.sin(a), np.full(sides, z)], axis=1)
    group.polygons.add(pts, material)


def _horse_and_rider(body: int, saddle: int, skin: int) -> Group:
    """One horse (facing +x, hooves at z=0, about 6 ft long) with a rider: 14 primitives."""
    g = Group(name="horse", accel="bvh")
    g.spheres.add((0.0, 0.0, 3.2), 1.1, body)                 # body
    g.spheres.add((2.2, 0.0, 4.7), 0.55, body)                # head
    g.cones.add((1.0, 0.0, 3.6), 0.45, (2.0, 0.0, 4.5), 0.3, body)     # neck
    for x in (-0.7, 0.7):
        for y in (-0.35, 0.35):
            g.cones.add((x, y, 2.6), 0.18, (x * 1.1, y, 0.0), 0.1, body)    # legs
    g.cones.add((-1.0, 0.0, 3.4), 0.12, (-1.9, 0.0, 2.2), 0.04, body)  # tail
    g.cones.add((0.0, 0.0, 4.2), 0.45, (0.0, 0.0, 5.8), 0.3, saddle)    # rider's body
    g.spheres.add((0.0, 0.0, 6.25), 0.4, skin)                # rider's head
    for y in (-0.45, 0.45):
        g.cones.add((0.0, y, 5.6), 0.12, (0.8, y * 0.8, 4.9), 0.08, skin)  # arms
    g.cones.add((0.0, 0.0, 4.3), 0.5, (0.0, 0.0, 4.1), 0.7, saddle)     # saddle
    return g


def _tree(trunk: int, leaves: int) -> Group:
    """A tree 1 ft tall at the origin (instanced with its size): a trunk and three crowns."""
    g = Group(name="tree", accel="bvh")
    g.cones.add((0, 0, 0), 0.05, (0, 0, 0.55), 0.035, trunk)
    g.spheres.add((0, 0, 0.6), 0.22, leaves)
    g.spheres.add((0.12, 0.05, 0.78), 0.16, leaves)
    g.spheres.add((-0.08, -0.06, 0.9), 0.12, leaves)
    return g


def _ride(name: str, centre, radius: float, horses: int, horse: Group, mats: dict, ride_grid: int) -> Group:
    """A triple-decker merry-go-round about `centre`, decks 9 ft apart."""
    g = Group(name=name)
    cx, cy = centre
    deck_h = 9.0
    for d in range(3):
        z = d * deck_h
        _disc(g, (cx, cy), radius, z + 0.5, 48, mats["deck"])                 # platform
        _disc(g, (cx, cy), radius * 1.02, z + deck_h - 0.3, 48, mats["canopy"])   # canopy above it
        for k in range(48):                                                    # lamps on the canopy's rim
            a = 2 * math.pi * (k + 0.5) / 48
            g.spheres.add((cx + radius * 1.02 * math.cos(a), cy + radius * 1.02 * math.sin(a), z + deck_h - 0.5),
                          0.18, mats["lamp"])
        for k in range(horses):
            a = 2 * math.pi * (k + 0.5 * d) / horses
            r = radius * 0.72
            px, py = cx + r * math.cos(a), cy + r * math.sin(a)
            g.cones.add((px, py, z + 0.5), 0.09, (px, py, z + deck_h - 0.3), 0.09, mats["chrome"])   # pole
            lift = 0.6 * math.sin(3 * a + d)                                        # horses up and down
            heading = a + math.pi / 2                                               # facing along the ring
            m = np.eye(4)
            m[:3, :3] = np.array([[math.cos(heading), -math.sin(heading), 0],
                                  [math.sin(heading), math.cos(heading), 0], [0, 0, 1]]) * 0.8
            m[:3, 3] = (px, py, z + 0.5 + lift)
            g.add(Instance(horse, m))
    g.cones.add((cx, cy, 0.0), radius * 0.18, (cx, cy, 3 * deck_h), radius * 0.18, mats["mirror"])   # column
    g.cones.add((cx, cy, 3 * deck_h), radius * 1.05, (cx, cy, 3 * deck_h + radius * 0.5), 0.05,
                mats["canopy"])                                                     # roof
    items = 3 * (2 + 48 + 2 * horses) + 2
    g.accel = f"grid(res=woo, density={ride_grid / items ** (1 / 3):.4g})"
    return g


def _mountain(level: int, centre, size: float, height: float, seed: int, material: int) -> Group:
    """A fractal mountain: midpoint displacement on a (2^level + 1)^2 height field, as triangles."""
    rng = np.random.default_rng(seed)
    n = 2 ** level + 1
    h = np.zeros((n, n))
    h[n // 2, n // 2] = height
    step, scale = n - 1, height * 0.5
    while step > 1:
        half = step // 2
        for y in range(half, n, step):          # diamond step: centres of squares
            for x in range(half, n, step):
                h[y, x] = max(h[y, x], 0.25 * (h[y - half, x - half] + h[y - half, x + half] + h[y + half, x - half]
                                              + h[y + half, x + half])) + scale * rng.uniform(-1, 1)
        for y in range(0, n, half):             # square step: edge midpoints
            for x in range((y + half) % step, n, step):
                nb = [h[yy, xx] for yy, xx in ((y - half, x), (y + half, x), (y, x - half), (y, x + half))
                      if 0 <= yy < n and 0 <= xx < n]
                h[y, x] = float(np.mean(nb)) + scale * rng.uniform(-1, 1)
        step, scale = half, scale * 0.55
    u = np.linspace(-0.5, 0.5, n) * size
    yy, xx = np.meshgrid(u, u, indexing="ij")
    r = np.hypot(xx, yy) / (0.5 * size)
    z = np.maximum(h, 0.0) * np.clip(1.2 - r, 0.0, 1.0)     # down to the ground at the rim
    verts = np.stack([xx + centre[0], yy + centre[1], z], axis=-1).reshape(-1, 3)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    faces = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])
    g = Group(name="mountain", accel="octree")
    g.add(TriangleMesh(verts, faces, material))
    return g


def park(rides: int = 6, horses: int = 24, trees: int = 500, mountain_level: int = 6, ride_grid: int = 16,
         top: int = 0, seed: int = 1) -> Scene:
    """Arvo's amusement park.

    rides           triple-decker merry-go-rounds on a ring, 1 to 64 (default 6)
    horses          horses (with riders) per deck, 1 to 256 (default 24)
    trees           trees, instanced, 0 to 1e6 (default 500)
    mountain_level  the fractal mountain has 2 x 4^level triangles, 0 to 9 (default 6: 8,192)
    ride_grid       cells along the longest side of each ride's grid, 1 to 256 (default 16)
    top             the structure over the park: 0 a coarse grid, 1 ray classification
    seed            random seed of the mountain and the trees' places

    With the defaults, 9,361 primitives besides the mountain (instances counted each time).
    """
    scene = Scene(background=np.array([0.55, 0.7, 0.95]))
    mats = {name: scene.add_material(m) for name, m in (
        ("ground", _m((0.3, 0.55, 0.25), 0.9)), ("rock", _m((0.55, 0.5, 0.45), 0.9)),
        ("deck", _m((0.6, 0.35, 0.2), 0.8, 0.1, 10)), ("canopy", _m((0.85, 0.2, 0.25), 0.7, 0.2, 20)),
        ("lamp", _m((1.0, 0.95, 0.6), 0.9, 0.1, 30)), ("chrome", _m((0.9, 0.9, 0.9), 0.2, 0.8, 80)),
        ("mirror", _m((0.95, 0.95, 0.95), 0.05, 0.9, 100)), ("horse", _m((0.95, 0.92, 0.85), 0.7, 0.3, 40)),
        ("saddle", _m((0.2, 0.3, 0.8), 0.7, 0.2, 20)), ("skin", _m((0.9, 0.7, 0.55), 0.8)),
        ("trunk", _m((0.4, 0.25, 0.1), 0.9)), ("leaves", _m((0.15, 0.45, 0.15), 0.9)),
        ("fence", _m((0.9, 0.9, 0.85), 0.8, 0.1, 10)),
    )}
    rng = np.random.default_rng(seed)
    root = scene.root
    root.name = "park"
    root.accel = "rc" if top else "grid(density=0.25)"
    half = 1000.0
    root.polygons.add([(-half, -half, 0), (half, -half, 0), (half, half, 0), (-half, half, 0)], mats["ground"])
    ring, radius = 180.0, 24.0
    horse = _horse_and_rider(mats["horse"], mats["saddle"], mats["skin"])
    centres = [(ring * math.cos(2 * math.pi * k / rides), ring * math.sin(2 * math.pi * k / rides))
               for k in range(rides)]
    for k, c in enumerate(centres):
        root.add(_ride(f"ride{k}", c, radius, horses, horse, mats, ride_grid))
    root.add(_mountain(mountain_level, (0.0, 650.0), 700.0, 260.0, seed, mats["rock"]))
    tree = _tree(mats["trunk"], mats["leaves"])
    placed = 0
    while placed < trees:
        x, y = rng.uniform(-half * 0.9, half * 0.9, 2)
        if min(math.hypot(x - cx, y - cy) for cx, cy in centres) < radius * 1.6 or math.hypot(x, y - 650) < 380:
            continue
        m = np.eye(4)
        m[:3, :3] *= rng.uniform(20.0, 45.0)
        m[:3, 3] = (x, y, 0.0)
        root.add(Instance(tree, m))
        placed += 1
    fence = Group(name="fence", accel="bvh")
    for k in range(400):
        a = 2 * math.pi * k / 400
        x, y = 0.95 * half * math.cos(a), 0.95 * half * math.sin(a)
        fence.cones.add((x, y, 0.0), 0.3, (x, y, 4.0), 0.3, mats["fence"])
    root.add(fence)
    scene.add_light((-600.0, -900.0, 1200.0))
    scene.add_light((500.0, -300.0, 400.0), (0.6, 0.6, 0.55))
    # close to the first ride, with a lamp beside the camera
    cx, cy = centres[0]
    scene.add_light((cx + radius * 2.5, cy - radius * 2.0, 14.0), (0.5, 0.5, 0.45))
    scene.camera = Camera(eye=(cx + radius * 1.5, cy - radius * 1.1, 11.0), look_at=(cx, cy, 11.0),
                          up=(0, 0, 1), angle=70.0, hither=0.05)
    return scene


def _m(color, kd, ks=0.0, shine=0.0):
    from .model import Material
    return Material(color=color, kd=kd, ks=ks, shine=shine)

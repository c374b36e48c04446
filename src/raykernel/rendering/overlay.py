"""A structure's edges drawn over a render, hidden where the scene's surfaces cover them.

    image = draw_structure(result.image, scene, "octree", depth=3)   # boxes 0-3 deep in their structure
    image = draw_structure(result.image, scene, "hybrid")            # every box
    image = draw_boxes(image, scene, boxes, eye_depth(scene, "bvh", width, height))   # any structure.Boxes

The boxes are rendering/structure.py's. Each edge is sampled about once a pixel and projected with
the render's own camera (render.camera_vectors: the pixel centres); a sample is drawn where it lies
in front of the surface the pixel's eye ray hits (the eye rays are cast again for their depth),
within a thousandth of that depth, so edges lying on a surface show. Colours tell the nesting
levels apart (level 0 yellow, 1 cyan, 2 magenta, ...), lighter for shallower boxes.
"""

from __future__ import annotations

import numpy as np

from ..errors import OptionError
from .render import camera_vectors
from .structure import select, structure_boxes

LEVEL_COLOURS = np.array([[1.0, 0.85, 0.1], [0.1, 0.9, 1.0], [1.0, 0.3, 0.9], [0.5, 1.0, 0.3], [1.0, 0.5, 0.2]])
# the 12 edges of a box, as pairs of corners that differ in one axis
EDGES = np.array([(a, b) for a in range(8) for b in range(8) if a < b and bin(a ^ b).count("1") == 1])
ALPHA = 0.85
MAX_SAMPLES = 50_000_000        # edge samples drawn in all (a bound on the memory it takes)


def eye_depth(scene, accel: str, width: int, height: int) -> np.ndarray:
    """(height, width) distance along the line of sight to what each pixel centre's eye ray hits (inf: nothing)."""
    from ..casting.rayscene import RayScene
    v = camera_vectors(scene.camera, width, height, corners=False)
    eye, first, right, down = v[:3], v[3:6], v[6:9], v[9:12]
    d = first + np.arange(width)[None, :, None] * right + np.arange(height)[:, None, None] * down
    hits = RayScene.from_scene(scene, accel=accel).intersect(np.broadcast_to(eye, d.shape).reshape(-1, 3),
                                                             d.reshape(-1, 3), fields=("t",))
    forward, _, _ = scene.camera.basis()
    return (hits.t.reshape(height, width) * (d @ forward)).astype(np.float64)


def project_points(camera, width: int, height: int, points: np.ndarray) -> tuple:
    """(column, row, distance along the line of sight) of world points in a width x height render
    by `camera`: pixel (row i, column j) at its centre (j, i); meaningful where the distance > 0."""
    forward, right, up = camera.basis()
    spacing = float(np.linalg.norm(camera_vectors(camera, width, height, corners=False)[6:9]))
    rel = np.asarray(points, np.float64) - camera.eye
    z = rel @ forward
    safe = np.where(z > 0, z, 1.0)
    return (rel @ right) / safe / spacing + (width - 1) / 2.0, (height - 1) / 2.0 - (rel @ up) / safe / spacing, z


def draw_structure(image: np.ndarray, scene, accel: str, depth: int | None = None, max_memory=None) -> np.ndarray:
    """`image` (a render of `scene`, (h, w, 3)) with the edges of `accel`'s boxes `depth` or fewer
    deep in their structures (None: all) drawn over it; the same dtype and scale."""
    if depth is not None and depth < 0:
        raise OptionError(f"--draw: depth must be 0 or more, got {depth}")
    boxes = structure_boxes(scene, accel, max_memory=max_memory)
    if depth is not None:
        boxes = select(boxes, boxes.depth <= depth)
    return draw_boxes(image, scene, boxes, eye_depth(scene, accel, image.shape[1], image.shape[0]))


def draw_boxes(image: np.ndarray, scene, boxes, surface: np.ndarray) -> np.ndarray:
    """`image` with the edges of `boxes` (structure.Boxes) drawn where they lie in front of
    `surface` (eye_depth's); the same dtype and scale."""
    h, w = image.shape[:2]
    cam = scene.camera
    forward = cam.basis()[0]
    near = max(float(cam.hither), 1e-12)

    def project(points):
        return project_points(cam, w, h, points)

    a = boxes.corners[:, EDGES[:, 0]].reshape(-1, 3)
    b = boxes.corners[:, EDGES[:, 1]].reshape(-1, 3)
    level = np.repeat(boxes.level, len(EDGES))
    shade = np.repeat(1.0 / (1.0 + 0.25 * boxes.depth), len(EDGES))
    # keep the part of each edge in front of the near plane
    za, zb = (a - cam.eye) @ forward, (b - cam.eye) @ forward
    front = (za > near) | (zb > near)
    a, b, za, zb, level, shade = a[front], b[front], za[front], zb[front], level[front], shade[front]
    cut = np.clip((near - za) / np.where(zb != za, zb - za, 1.0), 0.0, 1.0)
    a = np.where((za < near)[:, None], a + cut[:, None] * (b - a), a)
    cut = np.clip((near - zb) / np.where(za != zb, za - zb, 1.0), 0.0, 1.0)
    b = np.where((zb < near)[:, None], b + cut[:, None] * (a - b), b)
    xa, ya, _ = project(a)
    xb, yb, _ = project(b)
    length = np.hypot(np.clip(xb - xa, -4 * w, 4 * w), np.clip(yb - ya, -4 * h, 4 * h))
    samples = np.ceil(length).astype(np.int64) + 2
    if samples.sum() > MAX_SAMPLES:
        raise OptionError(f"--draw: {int(samples.sum()):,} edge samples is too many to draw; draw fewer levels "
                          "(--draw DEPTH) or a smaller image")
    edge = np.repeat(np.arange(len(a)), samples)
    u = (np.arange(int(samples.sum())) - np.repeat(np.cumsum(samples) - samples, samples)) / np.repeat(samples - 1,
                                                                                                        samples)
    p = a[edge] + u[:, None] * (b[edge] - a[edge])
    x, y, z = project(p)
    col, row = np.rint(x).astype(np.int64), np.rint(y).astype(np.int64)
    inside = (col >= 0) & (col < w) & (row >= 0) & (row < h) & (z > near)
    col, row, z, edge = col[inside], row[inside], z[inside], edge[inside]
    seen = z <= surface[row, col] * (1.0 + 1e-3)
    col, row, edge = col[seen], row[seen], edge[seen]
    colour = LEVEL_COLOURS[level[edge] % len(LEVEL_COLOURS)] * shade[edge, None]
    scale = 255.0 if image.dtype == np.uint8 else 1.0
    out = np.asarray(image, np.float64).copy()
    out[row, col] = (1.0 - ALPHA) * out[row, col] + ALPHA * colour * scale
    return np.clip(out, 0, 255).astype(np.uint8) if image.dtype == np.uint8 else out.astype(image.dtype)

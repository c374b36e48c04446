"""SPD "tree": a binary tree of cones with a sphere at each joint, grown by
Aono & Kunii's method, standing on a square field. Seven lights.

    from raykernel.scene import spd
    text = spd.generate("tree", 11)      # NFF text, same as `tree -s 11`

Size factor SF (default 11): 2^(SF+1) - 1 cones and as many spheres, plus
1 ground quad (sf 11: 4095 of each).
"""

from __future__ import annotations

import numpy as np

from ..nffwriter import NffWriter
from ._common import PI, SKY_BLUE, X_AXIS, Z_AXIS, identity, material, polygon, rotation, scale_translate

DEFAULT_SIZE = 11
SIZE_RULE = "2^(SF+1)-1 cones and as many spheres, plus 1 ground quad"
MAX_SIZE = 21

#: (branching angle in degrees, divergence angle in degrees, length
#: contraction) of the two branches that grow from every branch tip.
BRANCHES = ((40.0, 90.0, 0.65), (25.0, 140.0 + 90.0, 0.70))
#: Branch radius at the tip over radius at the base (also the next branch's thickness ratio).
BR_DIAMETER = 0.67
#: Base radius of a branch over its length.
WIDTH_HEIGHT_RATIO = 0.15


def _branch_transforms():
    """For each branch: the transform from its parent's frame to its own
    (tip at z = 1 in the parent frame, tilted, turned and shrunk)."""
    transforms = []
    for angle, divergence, contraction in BRANCHES:
        turn = rotation(X_AXIS, angle * PI / 180.0) @ rotation(Z_AXIS, divergence * PI / 180.0)
        transforms.append(turn @ scale_translate(contraction, (0.0, 0.0, 1.0)))
    return transforms


def _grow(w: NffWriter, branches, frame: np.ndarray, scale: float, depth: int):
    base = frame[3, :3]
    apex = (frame[2, :3] + frame[3, :3]).tolist()
    base_radius = scale * WIDTH_HEIGHT_RATIO
    apex_radius = base_radius * BR_DIAMETER
    w.cone(base.tolist(), base_radius, apex, apex_radius)
    w.sphere(apex, apex_radius)
    if depth > 0:
        for branch in branches:
            _grow(w, branches, branch @ frame, scale * BR_DIAMETER, depth - 1)


def generate(size: int) -> str:
    w = NffWriter()
    w.background(SKY_BLUE)
    w.view((4.5, 0.4, 2.0), (0.0, 0.0, 1.5), (0.0, 0.0, 1.0), 45.0, 1.0, 512)
    for light in ((-5.0, 5.0, 50.0), (30.0, -30.0, 30.0), (-40.0, -30.0, 20.0), (10.0, 30.0, 40.0),
                  (-30.0, 40.0, 10.0), (50.0, 25.0, 20.0), (-10.0, -60.0, 30.0)):
        w.light(light)

    material(w, (0.2, 0.7, 0.2), kd=1.0, ks=0.0)
    polygon(w, [(50.0, 50.0, 0.0), (-50.0, 50.0, 0.0), (-50.0, -50.0, 0.0), (50.0, -50.0, 0.0)])

    material(w, (0.55, 0.4, 0.2), kd=1.0, ks=0.0)
    _grow(w, _branch_transforms(), identity(), 1.0, size)
    return w.text()

"""Built-in example scenes: `raykernel render example:heckbert`, `raykernel render example:csg`.

    scene = examples.load("heckbert")

heckbert: the five spheres of Paul Heckbert's minimal ray tracer (the
business-card ray tracer printed in "Ray Tracing News" vol. 2 no. 1): a
glass sphere in front of an orange and a cyan sphere, lit by two large
luminous spheres behind the eye, as listed there: eye at the origin looking
along +y, z up, 25 degrees field of view, ray depth 3, ambient (0.02, 0.02,
0.02). It renders with the program's own model by default
(`--shading heckbert`, rendering/heckbert.py); under Whitted shading the
luminous spheres glow and light the others from their centres.

csg: constructive solid geometry as aggregates (Arvo, in the same issue): a
die drilled with 21 pips, the rounded cube the intersection of a cube mesh
and a sphere, and a glass lens cut from two spheres in front of it (the
scene file csg.json beside this module).
"""

from __future__ import annotations

from pathlib import Path

from ..errors import OptionError
from .model import Camera, Material, Scene

# centre, colour, radius, kd, ks, kt, luminance, index of refraction
_HECKBERT = [
    ((0.0, 6.0, 0.5), (1.0, 1.0, 1.0), 0.9, 0.05, 0.2, 0.85, 0.0, 1.7),
    ((-1.0, 8.0, -0.5), (1.0, 0.5, 0.2), 1.0, 0.7, 0.3, 0.0, 0.05, 1.2),
    ((1.0, 8.0, -0.5), (0.1, 0.8, 0.8), 1.0, 0.3, 0.7, 0.0, 0.0, 1.2),
    ((3.0, -6.0, 15.0), (1.0, 0.8, 1.0), 7.0, 0.0, 0.0, 0.0, 0.6, 1.5),
    ((-3.0, -3.0, 12.0), (0.8, 1.0, 1.0), 5.0, 0.0, 0.0, 0.0, 0.5, 1.5),
]


def heckbert(resolution: int = 256) -> Scene:
    scene = Scene(camera=Camera(eye=(0, 0, 0), look_at=(0, 1, 0), up=(0, 0, 1), angle=25.0, hither=1e-7,
                                width=resolution, height=resolution),
                  background=(0.02, 0.02, 0.02))
    scene.source = "example:heckbert"
    for center, color, radius, kd, ks, kt, kl, ior in _HECKBERT:
        m = scene.add_material(Material(color=color, kd=kd, ks=ks, shine=20.0, t=kt, ior=ior, kl=kl))
        scene.root.spheres.add(center, radius, m)
    return scene


def csg() -> Scene:
    from .jsonscene import read_json
    scene = read_json(Path(__file__).with_name("csg.json"))
    scene.source = "example:csg"
    return scene


EXAMPLES = {"heckbert": (heckbert, {"max_depth": 3, "shading": "heckbert"}), "csg": (csg, {})}


def load(name: str) -> Scene:
    if name not in EXAMPLES:
        raise OptionError(f"unknown example {name!r}; examples: {', '.join(EXAMPLES)}")
    return EXAMPLES[name][0]()


def render_defaults(name: str) -> dict:
    return dict(EXAMPLES[name][1]) if name in EXAMPLES else {}

"""raykernel: a ray tracer for comparing acceleration structures.

    import raykernel
    scene = raykernel.load("balls-sf4.nff")
    result = raykernel.render(scene, accel="bvh")
    result.image, result.stats

`import raykernel` loads nothing heavy: each name below is imported on first use, so a
process that only reads scenes never imports numba, and one that renders imports what
rendering needs when it first renders.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

__version__ = "0.1.0"

# public name -> the module that defines it
_HOMES = {
    "render": "analysis.auto",
    "camera_rays": "casting.camera",
    "Hits": "casting.rayscene", "RayInputError": "casting.rayscene", "RayScene": "casting.rayscene",
    "OptionError": "errors", "RayKernelError": "errors", "SceneError": "errors",
    "RenderResult": "rendering.render",
    "explore": "explorer.server",
    "read_json": "scene.jsonscene", "write_json": "scene.jsonscene",
    "load": "scene.loading",
    **{name: "scene.model" for name in ("Camera", "Cones", "Group", "Instance", "Light", "Material", "Polygons",
                                         "Scene", "Spheres", "TriangleMesh")},
    "parse_nff": "scene.nff", "read_nff": "scene.nff", "write_nff": "scene.nff",
}

__all__ = [
    "Camera", "Cones", "Group", "Instance", "Light", "Material", "Polygons", "Scene", "Spheres",
    "TriangleMesh", "OptionError", "RayKernelError", "SceneError", "load", "render", "RenderResult",
    "read_nff", "parse_nff", "write_nff", "read_json", "write_json", "RayScene", "Hits", "RayInputError",
    "camera_rays", "explore",
]


def __getattr__(name: str):
    home = _HOMES.get(name)
    if home is None:
        raise AttributeError(f"module 'raykernel' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{home}", __name__), name)
    globals()[name] = value         # later lookups skip this function
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))


if TYPE_CHECKING:
    from .analysis.auto import render
    from .casting.camera import camera_rays
    from .casting.rayscene import Hits, RayInputError, RayScene
    from .errors import OptionError, RayKernelError, SceneError
    from .explorer.server import explore
    from .rendering.render import RenderResult
    from .scene.jsonscene import read_json, write_json
    from .scene.loading import load
    from .scene.model import Camera, Cones, Group, Instance, Light, Material, Polygons, Scene, Spheres, TriangleMesh
    from .scene.nff import parse_nff, read_nff, write_nff

"""raykernel: a ray tracer for comparing acceleration structures.

    import raykernel
    scene = raykernel.load("balls-sf4.nff")
    result = raykernel.render(scene, accel="bvh")
    result.image, result.stats
"""

from .analysis.auto import render
from .casting.camera import camera_rays
from .casting.rayscene import Hits, RayInputError, RayScene
from .errors import OptionError, RayKernelError, SceneError
from .rendering.render import RenderResult
from .scene.jsonscene import read_json, write_json
from .scene.loading import load
from .scene.model import Camera, Cones, Group, Instance, Light, Material, Polygons, Scene, Spheres, TriangleMesh
from .scene.nff import parse_nff, read_nff, write_nff

__version__ = "0.1.0"

__all__ = [
    "Camera", "Cones", "Group", "Instance", "Light", "Material", "Polygons", "Scene", "Spheres",
    "TriangleMesh", "OptionError", "RayKernelError", "SceneError", "load", "render", "RenderResult",
    "read_nff", "parse_nff", "write_nff", "read_json", "write_json", "RayScene", "Hits", "RayInputError",
    "camera_rays",
]

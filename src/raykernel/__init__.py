"""raykernel: a ray tracer for comparing acceleration structures.

    import raykernel
    scene = raykernel.load("balls-sf4.nff")
    result = raykernel.render(scene, accel="bvh")
    result.image, result.stats
"""

from .errors import OptionError, RayKernelError, SceneError
from .loading import load
from .render import RenderResult, render
from .scene import Camera, Cones, Group, Instance, Light, Material, Polygons, Scene, Spheres, TriangleMesh

__version__ = "0.1.0"

__all__ = [
    "Camera", "Cones", "Group", "Instance", "Light", "Material", "Polygons", "Scene", "Spheres",
    "TriangleMesh", "OptionError", "RayKernelError", "SceneError", "load", "render", "RenderResult",
]

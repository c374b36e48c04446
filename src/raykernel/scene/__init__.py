"""The scene layer: the model, its file formats and generators, and loading.

    from raykernel.scene import Scene, Group, Instance     # the model (model.py)
    scene = loading.load("spd:balls")                      # nff, jsonscene, spd, pathological, examples

Imports nothing above it: every other layer reads scenes.
"""

from .model import MAX_NESTING, Camera, Cones, Group, Instance, Light, Material, Polygons, Scene, Spheres, TriangleMesh

__all__ = ["MAX_NESTING", "Camera", "Cones", "Group", "Instance", "Light", "Material", "Polygons", "Scene",
           "Spheres", "TriangleMesh"]

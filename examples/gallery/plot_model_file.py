"""
Rendering a model file
======================

``raykernel render model.obj`` reads OBJ (with its MTL materials), PLY, STL, OFF, glTF and GLB
through trimesh, maps the materials to NFF-style ones and frames a camera around the model
(glTF files bring their own). Here a small OBJ with two materials is written with trimesh and
rendered through a BVH, as ``raykernel render`` does.
"""

import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import trimesh

import raykernel

folder = Path(tempfile.mkdtemp())
knot = trimesh.creation.torus(major_radius=1.0, minor_radius=0.35, major_sections=96, minor_sections=32)
knot.visual = trimesh.visual.TextureVisuals(material=trimesh.visual.material.SimpleMaterial(
    diffuse=[200, 80, 40, 255], specular=[120, 120, 120, 255], glossiness=40))
floor = trimesh.creation.box(extents=(5, 5, 0.1))
floor.apply_translation((0, 0, -0.45))
floor.visual = trimesh.visual.TextureVisuals(material=trimesh.visual.material.SimpleMaterial(
    diffuse=[180, 180, 190, 255]))
trimesh.Scene([knot, floor]).export(folder / "torus.obj")
print(sorted(p.name for p in folder.iterdir()))

scene = raykernel.load(str(folder / "torus.obj"))
result = raykernel.render(scene, accel="bvh", resolution=320)
print(f"{result.stats['build.refs']:,} triangles; {result.stats['rays.total']:,} rays")
fig, ax = plt.subplots(figsize=(6, 6))
ax.imshow(np.clip(result.image, 0, 1))
ax.set_axis_off()
plt.show()

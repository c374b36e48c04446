"""
Constructive solid geometry
===========================

A die (a rounded cube: the intersection of a cube and a sphere) drilled with 21 pips by
difference, behind a glass lens made by intersecting two spheres. Every CSG operator is an
aggregate like any other and nests in any structure (`example:csg`, the scene file
src/raykernel/scene/csg.json).
"""

import matplotlib.pyplot as plt

import raykernel

scene = raykernel.load("example:csg")
result = raykernel.render(scene, resolution=400)
print(f"CSG crossings {result.stats['csg.crossings']:,}, resolves {result.stats['csg.resolves']:,}")
fig, ax = plt.subplots(figsize=(6, 6))
ax.imshow(result.image.clip(0, 1))
ax.set_axis_off()
plt.show()
